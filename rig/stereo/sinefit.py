"""IEEE Std 1057 sine fits on arbitrary (e.g. row-corrected, non-uniform) time stamps, and sliding fits.

Model: ``x(t) = amplitude·cos(2πf·(t − t_ref) + phase_rad) + offset``.

- Three-parameter fit (``frequency_hz`` given): linear least squares in a·cos + b·sin + c.
- Four-parameter fit (``frequency_hz=None``): the frequency starts at the interpolated peak of the
  windowed DTFT (or a periodogram search on irregular time stamps) and is refined by Gauss–Newton on
  (a, b, c, ω) (IEEE 1057 §4.1.2); it reaches the Cramér–Rao bound under white Gaussian noise when the record
  holds at least a period or so (Händel 2000); fewer than 1.0 period raises TooFewSamplesError.

Standard uncertainties come from the covariance s²·(JᵀJ)⁻¹ with s the residual RMS (white noise assumed).
No interpolation is involved, so there is no amplitude bias from sampling (metrology notes §6.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo._series import as_times, as_values
from rig.stereo.errors import InputArrayError, TimingError, TooFewSamplesError
from rig.stereo.spectrum import refine_peak, window_weights


@dataclass(frozen=True)
class SineFit:
    """Result of a sine fit; ``*_std`` are standard uncertainties (same units as the value)."""

    amplitude: float
    phase_rad: float
    offset: float
    frequency_hz: float
    t_ref_s: float
    residual_rms: float
    n_samples: int
    amplitude_std: float
    phase_std_rad: float
    offset_std: float
    frequency_std_hz: float  # 0.0 for a three-parameter fit (frequency given)

    def evaluate(self, t_s: object) -> FloatArray:
        """The fitted sinusoid at ``t_s`` (s)."""
        t = np.asarray(t_s, dtype=float)
        return (
            self.amplitude * np.cos(2 * np.pi * self.frequency_hz * (t - self.t_ref_s) + self.phase_rad)
            + self.offset
        )


def _lstsq(A: FloatArray, b: FloatArray) -> FloatArray:
    """Least-squares solution of A·x ≈ b."""
    return np.asarray(np.linalg.lstsq(A, b, rcond=None)[0], dtype=np.float64)


def _design(tc: FloatArray, omega: float) -> FloatArray:
    return np.column_stack([np.cos(omega * tc), np.sin(omega * tc), np.ones_like(tc)])


def initial_frequency(t: FloatArray, x: FloatArray, *, max_frequency_hz: float | None = None) -> float:
    """Frequency of the largest Hann-windowed DTFT peak above 1.5/duration, refined within ±1 bin (Hz)."""
    duration = t[-1] - t[0]
    fs_nominal = 1.0 / float(np.median(np.diff(t)))
    f_max = 0.5 * fs_nominal if max_frequency_hz is None else float(max_frequency_hz)
    df = 1.0 / (4.0 * duration)
    grid = np.arange(1.5 / duration, f_max, df)
    if grid.size == 0:
        raise TooFewSamplesError(f"record of {duration:.4g} s is too short for a frequency search")
    w = window_weights("hann", t.size)
    xc = x - x.mean()
    tc = t - t[0]
    mags = np.empty(grid.size)
    for start in range(0, grid.size, 256):  # chunks keep memory small on long records
        f = grid[start : start + 256]
        mags[start : start + 256] = np.abs(np.exp(-2j * np.pi * np.outer(f, tc)) @ (w * xc))
    f0 = float(grid[int(np.argmax(mags))])
    return refine_peak(t, xc, w, f0, 2 * df)[0]


def fit_sine(
    t_s: object,
    x: object,
    *,
    frequency_hz: float | None = None,
    t_ref_s: float | None = None,
    max_iterations: int = 50,
    initial_frequency_hz: float | None = None,
) -> SineFit:
    """Fit ``amplitude·cos(2πf(t − t_ref) + phase) + offset`` to samples at any increasing times.

    ``frequency_hz`` given → three-parameter fit; None → four-parameter fit (frequency estimated).
    ``t_ref_s`` is the phase reference instant (default: the record's mid time, where the phase is least
    correlated with the frequency). ``initial_frequency_hz``: where the four-parameter fit starts (e.g. a
    spectral peak already located; default: the largest DTFT peak, searched densely). Raises
    TooFewSamplesError (< 4 samples for 3 parameters, < 6 for 4, or a record shorter than one period in the
    four-parameter fit) and TimingError if the iteration diverges.
    """
    t = as_times(t_s, min_count=4)
    xv = as_values(x, t.size)
    if xv.ndim != 1:
        raise InputArrayError(f"x must be 1-D, got shape {xv.shape}")
    t_ref = 0.5 * (t[0] + t[-1]) if t_ref_s is None else float(t_ref_s)
    tc = t - t_ref
    if frequency_hz is not None:
        omega, p, J = _three_parameter_fit(tc, xv, frequency_hz)
    else:
        if t.size < 6:
            raise TooFewSamplesError(f"a four-parameter sine fit needs at least 6 samples, got {t.size}")
        f_start = initial_frequency(t, xv) if initial_frequency_hz is None else float(initial_frequency_hz)
        omega, p, J = _four_parameter_fit(tc, xv, 2 * np.pi * f_start, float(t[-1] - t[0]), max_iterations)
    return _sine_result(tc, xv, t_ref, omega=omega, p=p, J=J)


def _three_parameter_fit(
    tc: FloatArray, x: FloatArray, frequency_hz: float
) -> tuple[float, FloatArray, FloatArray]:
    """Linear least squares in a·cos + b·sin + c at the given frequency: (ω rad/s, [a, b, c], Jacobian)."""
    if not np.isfinite(frequency_hz) or frequency_hz <= 0:
        raise InputArrayError(f"frequency_hz must be a positive finite number, got {frequency_hz!r}")
    omega = 2 * np.pi * float(frequency_hz)
    D = _design(tc, omega)
    return omega, _lstsq(D, x), D


def _four_parameter_fit(
    tc: FloatArray, x: FloatArray, omega: float, duration_s: float, max_iterations: int
) -> tuple[float, FloatArray, FloatArray]:
    """Gauss–Newton on (a, b, c, ω) from ω (IEEE 1057 §4.1.2): (ω rad/s, [a, b, c], Jacobian at the
    solution). TimingError when it diverges or does not converge, TooFewSamplesError under one period."""
    p = _lstsq(_design(tc, omega), x)
    for _ in range(max_iterations):
        J = _four_parameter_jacobian(tc, omega, p)
        c, s = J[:, 0], J[:, 1]
        r = x - (p[0] * c + p[1] * s + p[2])
        step = _lstsq(J, r)
        p = p + step[:3]
        omega += step[3]
        if not np.isfinite(omega) or omega <= 0:
            raise TimingError("four-parameter sine fit diverged (frequency left the positive axis)")
        if abs(step[3]) * duration_s < 1e-10:
            break
    else:
        raise TimingError(f"four-parameter sine fit did not converge in {max_iterations} iterations")
    if omega * duration_s < 2 * np.pi:
        raise TooFewSamplesError(
            f"record of {duration_s:.4g} s holds {omega * duration_s / (2 * np.pi):.2f} periods at "
            f"{omega / (2 * np.pi):.4g} Hz; the four-parameter fit needs at least 1, give frequency_hz"
        )
    return omega, p, _four_parameter_jacobian(tc, omega, p)


def _four_parameter_jacobian(tc: FloatArray, omega: float, p: FloatArray) -> FloatArray:
    """∂model/∂(a, b, c, ω) at times ``tc`` about the phase reference (N, 4)."""
    c, s = np.cos(omega * tc), np.sin(omega * tc)
    return np.column_stack([c, s, np.ones_like(tc), tc * (-p[0] * s + p[1] * c)])


def _sine_result(
    tc: FloatArray, x: FloatArray, t_ref: float, *, omega: float, p: FloatArray, J: FloatArray
) -> SineFit:
    """The :class:`SineFit` of a solution [a, b, c] at ω: amplitude and phase from (a, b), standard
    uncertainties from s²·(JᵀJ)⁻¹ (the frequency's only when J has the ω column)."""
    a, b, off = p[:3]
    resid = x - (a * np.cos(omega * tc) + b * np.sin(omega * tc) + off)
    dof = tc.size - J.shape[1]
    s2 = float(resid @ resid) / dof if dof > 0 else 0.0
    cov = s2 * np.linalg.pinv(J.T @ J)
    amp = float(np.hypot(a, b))
    phase = float(np.arctan2(-b, a))  # a cos + b sin = amp cos(θ + phase)
    # Propagate (a, b) → (amplitude, phase).
    if amp > 0:
        g_amp = np.array([a, b]) / amp
        g_ph = np.array([b, -a]) / amp**2
    else:
        g_amp = g_ph = np.zeros(2)
    cab = cov[:2, :2]
    return SineFit(
        amplitude=amp,
        phase_rad=phase,
        offset=float(off),
        frequency_hz=float(omega / (2 * np.pi)),
        t_ref_s=t_ref,
        residual_rms=float(np.sqrt(np.mean(resid**2))),
        n_samples=int(tc.size),
        amplitude_std=float(np.sqrt(max(float(g_amp @ cab @ g_amp), 0.0))),
        phase_std_rad=float(np.sqrt(max(float(g_ph @ cab @ g_ph), 0.0))),
        offset_std=float(np.sqrt(max(cov[2, 2], 0.0))),
        frequency_std_hz=float(np.sqrt(max(cov[3, 3], 0.0)) / (2 * np.pi)) if J.shape[1] == 4 else 0.0,
    )


@dataclass(frozen=True)
class SlidingSineFit:
    """Sine fits in sliding windows: instantaneous frequency and amplitude of a sweep over time.

    Arrays are per window; ``time_s`` is the window's mid time (the phase and frequency reference);
    ``frequency_rate_hz_s`` is the fitted sweep rate (0 where ``chirp=False``)."""

    time_s: FloatArray
    frequency_hz: FloatArray
    amplitude: FloatArray
    phase_rad: FloatArray
    residual_rms: FloatArray
    frequency_std_hz: FloatArray
    amplitude_std: FloatArray
    frequency_rate_hz_s: FloatArray


def fit_chirp(
    tc: FloatArray, x: FloatArray, omega0: float, *, max_iterations: int = 50
) -> tuple[FloatArray, ...]:
    """Gauss–Newton fit of a·cos θ + b·sin θ + c with θ = ω·tc + ½·ω̇·tc² (a linear chirp about tc = 0).

    Returns (p = [a, b, c, ω, ω̇], covariance, residuals); starts at ω0 with ω̇ = 0.
    """
    theta = omega0 * tc
    p3, *_ = np.linalg.lstsq(np.column_stack([np.cos(theta), np.sin(theta), np.ones_like(tc)]), x, rcond=None)
    p = np.r_[p3, omega0, 0.0]
    span = float(np.ptp(tc))
    for _ in range(max_iterations):
        th = p[3] * tc + 0.5 * p[4] * tc**2
        c, s = np.cos(th), np.sin(th)
        d = -p[0] * s + p[1] * c
        J = np.column_stack([c, s, np.ones_like(tc), tc * d, 0.5 * tc**2 * d])
        r = x - (p[0] * c + p[1] * s + p[2])
        step, *_ = np.linalg.lstsq(J, r, rcond=None)
        p = p + step
        if abs(step[3]) * span + abs(step[4]) * span**2 < 1e-10:
            break
    else:
        raise TimingError(f"chirp fit did not converge in {max_iterations} iterations")
    th = p[3] * tc + 0.5 * p[4] * tc**2
    c, s = np.cos(th), np.sin(th)
    d = -p[0] * s + p[1] * c
    J = np.column_stack([c, s, np.ones_like(tc), tc * d, 0.5 * tc**2 * d])
    r = x - (p[0] * c + p[1] * s + p[2])
    dof = max(tc.size - 5, 1)
    cov = float(r @ r) / dof * np.linalg.pinv(J.T @ J)
    return p, cov, r


def sliding_sine_fit(
    t_s: object, x: object, *, window_s: float, step_s: float, chirp: bool = True
) -> SlidingSineFit:
    """Sine fits in windows of ``window_s`` advanced by ``step_s`` (any time stamps): a sweep's
    instantaneous frequency and amplitude at each window's mid time (the paper's Figs. 15 and 17).

    ``chirp=True`` (default) fits a linear chirp per window (five parameters: the frequency and its rate at
    the mid time), which removes the bias a sweep causes in a plain four-parameter fit (its quadratic phase
    π·rate·(window/2)² at the window edges); ``chirp=False`` fits four parameters. Each window needs at
    least one period of the local frequency and 6 samples (TooFewSamplesError otherwise).
    """
    t = as_times(t_s, min_count=6)
    xv = as_values(x, t.size)
    if window_s <= 0 or step_s <= 0:
        raise InputArrayError(f"window_s and step_s must be positive, got {window_s!r}, {step_s!r}")
    if window_s > t[-1] - t[0] + 1e-12:
        raise TooFewSamplesError(f"window_s = {window_s} s exceeds the record length {t[-1] - t[0]:.4g} s")
    starts = np.arange(t[0], t[-1] - window_s + 1e-12, step_s)
    rows = []
    for s0 in starts:
        m = (t >= s0) & (t < s0 + window_s)
        tm = t[m]
        t_mid = 0.5 * (tm[0] + tm[-1])
        fit = fit_sine(tm, xv[m], t_ref_s=t_mid)
        if not chirp:
            rows.append(
                (
                    t_mid,
                    fit.frequency_hz,
                    fit.amplitude,
                    fit.phase_rad,
                    fit.residual_rms,
                    fit.frequency_std_hz,
                    fit.amplitude_std,
                    0.0,
                )
            )
            continue
        p, cov, r = fit_chirp(tm - t_mid, xv[m], 2 * np.pi * fit.frequency_hz)
        amp = float(np.hypot(p[0], p[1]))
        g = np.array([p[0], p[1]]) / amp
        rows.append(
            (
                t_mid,
                p[3] / (2 * np.pi),
                amp,
                float(np.arctan2(-p[1], p[0])),
                float(np.sqrt(np.mean(r**2))),
                float(np.sqrt(max(cov[3, 3], 0.0))) / (2 * np.pi),
                float(np.sqrt(max(float(g @ cov[:2, :2] @ g), 0.0))),
                p[4] / (2 * np.pi),
            )
        )
    cols = np.array(rows, dtype=float).T if rows else np.zeros((8, 0))
    return SlidingSineFit(*cols)
