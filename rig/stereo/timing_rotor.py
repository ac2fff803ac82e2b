"""The paper's delay estimate from a marker rotating at constant angular velocity (for comparison).

Per camera: every observation's ray is intersected with the rotor plane (centre and axis from the rig's
geometry, e.g. the ``rotation`` event), which maps the projected ellipse back to the circle; a circle is
fitted in the plane, the marker's angle about the fitted centre is unwrapped and a straight line
θ(t) = θ₀ + ω·t fitted to it (the rotation rate). For every frame of camera A the closest frame of camera B
is taken, and the delay follows from their angular difference: δ = wrap(θ_B − θ_A)/ω − (τ_B − τ_A).
The offset is the mean over all frame pairs (drift ignored: ``epoch_s`` is the mean time stamp of the
paired frames of B), its uncertainty the standard error of that mean.

As in the paper, by default the frame time stamps are used as they are: the rolling shutter is **not**
corrected, so the delay carries a once-per-revolution ripple of amplitude ≈ line time × the spread of
v_B − v_A and a bias of line time × mean(v_B − v_A) (metrology notes §4). With ``estimate_line_time=True``
the ripple is the measurement: every pair's delay is δ + ℓ·(v_B − v_A) + d·(τ_B − epoch) (rows in px, d the
clock drift), so a plane fitted to the delays against the row difference and the time gives the offset δ,
the line time ℓ (common to both cameras) and the drift, with standard uncertainties from the fit. The
result is determined modulo one revolution;
``offset_guess_s`` selects the revolution. Units: seconds, mm, radians.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from rig.stereo._arrays import BoolArray, FloatArray, IntArray
from rig.stereo._series import as_times
from rig.stereo.errors import InputArrayError, NotRotatingError, TooFewSamplesError
from rig.stereo.normalize import Camera, projection_matrix
from rig.stereo.timing_model import TimingResult

MIN_FRAMES = 12


def plane_points_mm(P: FloatArray, uv_px: FloatArray, centre_mm: FloatArray, axis: FloatArray) -> FloatArray:
    """Intersect the rays of ``uv_px`` (N, 2) through camera ``P`` with the plane (centre, normal axis)."""
    M, p4 = P[:, :3], P[:, 3]
    cam_centre = np.asarray(-np.linalg.solve(M, p4), dtype=np.float64)
    rays = np.linalg.solve(M, np.column_stack([uv_px, np.ones(len(uv_px))]).T).T
    denom = rays @ axis
    if np.any(np.abs(denom) < 1e-12 * np.linalg.norm(rays, axis=1)):
        raise NotRotatingError(
            "a camera looks along the rotor plane; the projected circle degenerates to a line"
        )
    s = ((centre_mm - cam_centre) @ axis) / denom
    return cam_centre + s[:, None] * rays


def rotor_angles(
    P: FloatArray, uv_px: FloatArray, centre_mm: FloatArray, axis: FloatArray, camera: str
) -> tuple[FloatArray, float, float]:
    """Unwrapped rotor angle (rad) of each observation, fitted radius (mm) and radial scatter (mm)."""
    X = plane_points_mm(P, uv_px, centre_mm, axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    xy = np.column_stack([(X - centre_mm) @ e1, (X - centre_mm) @ e2])
    # Algebraic (Kåsa) circle fit: x² + y² = 2ax + 2by + c.
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    (a, b, c), *_ = np.linalg.lstsq(A, np.sum(xy**2, axis=1), rcond=None)
    radius = float(np.sqrt(max(c + a * a + b * b, 0.0)))
    r_each = np.hypot(xy[:, 0] - a, xy[:, 1] - b)
    scatter = float(np.std(r_each - radius))
    if radius <= 0 or scatter > 0.2 * radius or np.ptp(xy[:, 0]) < 1e-6:
        raise NotRotatingError(
            f"camera {camera}: the marker does not move on a circle in the rotor plane "
            f"(fitted radius {radius:.3g} mm, radial scatter {scatter:.3g} mm); is the rotor turning?"
        )
    theta = np.unwrap(np.arctan2(xy[:, 1] - b, xy[:, 0] - a))
    return theta, radius, scatter


def _rate(theta: FloatArray, tau: FloatArray, camera: str) -> tuple[float, float]:
    """Angular rate (rad/s) by a straight-line fit, checked for a steady non-zero rotation."""
    steps = np.diff(theta)
    if np.any(np.abs(steps) > 0.8 * np.pi):
        raise NotRotatingError(
            f"camera {camera}: the angle jumps by up to {np.degrees(np.abs(steps).max()):.0f}° "
            "between frames; "
            "the rotor turns too fast for the frame rate (must stay below about fs/2.5 revolutions/s)"
        )
    A = np.column_stack([np.ones_like(tau), tau - tau.mean()])
    (th0, omega), *_ = np.linalg.lstsq(A, theta, rcond=None)
    resid = theta - (th0 + omega * (tau - tau.mean()))
    turns = abs(omega) * np.ptp(tau) / (2 * np.pi)
    if turns < 1.0 or np.std(resid) > 0.25 * np.pi:
        raise NotRotatingError(
            f"camera {camera}: {turns:.2f} revolutions at {omega / (2 * np.pi):+.3f} rev/s with "
            "angle scatter "
            f"{np.degrees(np.std(resid)):.1f}° about a constant rate; the paper's method needs at least one "
            "revolution at constant angular velocity"
        )
    return float(omega), float(np.std(resid))


class _Series(NamedTuple):
    """One camera's rotor track: frame time stamps (s), unwrapped angle (rad), mean rate (rad/s), radius
    (mm), angle scatter about the constant rate (rad) and the exposed rows (px)."""

    tau: FloatArray
    theta: FloatArray
    omega: float
    radius_mm: float
    angle_scatter_rad: float
    rows_px: FloatArray


def _camera_series(cam: str, P: FloatArray, obs: object, rows_px: object, *, centre: FloatArray,
                   axis: FloatArray) -> _Series:
    """The rotor track of one camera's observations (``obs`` = (timestamp_s, uv_px))."""
    if not (isinstance(obs, tuple | list) and len(obs) == 2):
        raise InputArrayError(f"observations of camera {cam} must be one pair (timestamp_s, uv_px)")
    t, uv = obs
    tau = as_times(t, f"t_{cam}_s", min_count=MIN_FRAMES)
    uvv = np.asarray(uv, dtype=float)
    if uvv.shape != (tau.size, 2) or not np.isfinite(uvv).all():
        raise InputArrayError(
            f"uv of camera {cam} must be finite with shape ({tau.size}, 2), got {uvv.shape}")
    theta, radius, _scatter = rotor_angles(P, uvv, centre, axis, cam)
    omega, ang_scatter = _rate(theta, tau, cam)
    rows = uvv[:, 1] if rows_px is None else np.asarray(rows_px, float).reshape(-1)
    if rows.shape != tau.shape:
        raise InputArrayError(f"rows_px of camera {cam} must have {tau.size} values, got {rows.shape}")
    return _Series(tau, theta, omega, radius, ang_scatter, rows)


def _offset_from_delays(delays: FloatArray, d_rows: FloatArray | None, dt_s: FloatArray
                        ) -> tuple[FloatArray, FloatArray]:
    """(offset s, line time s, drift ppm) and their standard uncertainties: the mean delay, or with the row
    differences ``d_rows`` (px) the least-squares plane delay = δ + ℓ·d_rows + drift·1e-6·dt_s (``dt_s``:
    B's time stamps about the epoch; δ at equal rows and the epoch)."""
    if d_rows is None:
        std = float(np.std(delays, ddof=1) / np.sqrt(delays.size))
        return np.array([float(np.mean(delays)), 0.0, 0.0]), np.array([std, 0.0, 0.0])
    A = np.column_stack([np.ones_like(d_rows), d_rows - d_rows.mean(), dt_s * 1e-6])
    coef, *_ = np.linalg.lstsq(A, delays, rcond=None)
    resid = delays - A @ coef
    s2 = float(resid @ resid) / max(delays.size - 3, 1)
    cov = s2 * np.linalg.inv(A.T @ A)
    # δ = c0 − ℓ·mean(d_rows): its variance from the covariance of (c0, ℓ)
    g = np.array([1.0, -d_rows.mean(), 0.0])
    value = np.array([coef[0] - coef[1] * d_rows.mean(), coef[1], coef[2]])
    std = np.sqrt(np.array([g @ cov @ g, cov[1, 1], cov[2, 2]]))
    return value, std


def _rotor_plane(rotor_centre_mm: object, rotor_axis: object) -> tuple[FloatArray, FloatArray]:
    """The rotor plane's centre (mm) and unit normal, validated."""
    centre = np.asarray(rotor_centre_mm, dtype=float).reshape(-1)
    axis = np.asarray(rotor_axis, dtype=float).reshape(-1)
    if (
        centre.shape != (3,)
        or axis.shape != (3,)
        or not np.isfinite(centre).all()
        or np.linalg.norm(axis) == 0
    ):
        raise InputArrayError("rotor_centre_mm and rotor_axis must be finite 3-vectors, the axis non-zero")
    return centre, axis / np.linalg.norm(axis)


def _closest_frames(ta: FloatArray, tb: FloatArray, offset_guess_s: float) -> tuple[IntArray, BoolArray]:
    """For each frame of A the closest frame ``j`` of B, B's time stamps shifted by the guess onto A's clock,
    and ``keep`` where they lie within 0.75 frame; TooFewSamplesError under MIN_FRAMES such pairs."""
    tb_on_a = tb + offset_guess_s
    idx = np.clip(np.searchsorted(tb_on_a, ta), 1, tb.size - 1)
    left_closer = np.abs(tb_on_a[idx - 1] - ta) < np.abs(tb_on_a[idx] - ta)
    j = idx - left_closer
    gap = np.abs(tb_on_a[j] - ta)
    keep = gap <= 0.75 * float(np.median(np.diff(tb)))
    if np.count_nonzero(keep) < MIN_FRAMES:
        raise TooFewSamplesError(
            f"only {np.count_nonzero(keep)} frame pairs of the two cameras overlap in time "
            f"(need {MIN_FRAMES})"
        )
    return j, keep


def estimate_rotor(
    camera_a: Camera,
    camera_b: Camera,
    observations_a: object,
    observations_b: object,
    *,
    rotor_centre_mm: object,
    rotor_axis: object,
    names: tuple[str, str] = ("a", "b"),
    offset_guess_s: float = 0.0,
    estimate_line_time: bool = False,
    rows_px: tuple[object, object] | None = None,
) -> TimingResult:
    """Delay of camera B relative to camera A by the paper's rotating-marker method (see module doc).

    ``rotor_centre_mm`` (3,) and ``rotor_axis`` (3,) give the rotor plane in the cameras' world frame.
    ``estimate_line_time``: fit the rolling-shutter line time from the delays' dependence on the row
    difference (module doc); ``rows_px``: the observed (distorted) image rows of each camera's observations,
    default the v of ``uv``. Raises TooFewSamplesError (< 12 frames per camera), NonMonotonicTimestampsError,
    NotRotatingError.
    """
    P_a, P_b = projection_matrix(camera_a), projection_matrix(camera_b)
    centre, axis = _rotor_plane(rotor_centre_mm, rotor_axis)
    series = [_camera_series(cam, P, obs, None if rows_px is None else rows_px[k], centre=centre, axis=axis)
              for k, (cam, P, obs) in enumerate(((names[0], P_a, observations_a),
                                                  (names[1], P_b, observations_b)))]
    (ta, tha, wa, ra, sa, _), (tb, thb, wb, rb, sb, _) = series
    if np.sign(wa) != np.sign(wb):
        raise NotRotatingError("the two cameras see opposite senses of rotation; check the rotor axis")
    omega = 0.5 * (wa + wb)
    j, keep = _closest_frames(ta, tb, offset_guess_s)
    d_theta = thb[j[keep]] - tha[keep]
    period = 2 * np.pi / abs(omega)
    # Delay δ with θ_B(τ_B + δ) = θ_A(τ_A): pick the revolution nearest to the guess.
    raw = d_theta / omega - (tb[j[keep]] - ta[keep])
    delays = offset_guess_s + (raw - offset_guess_s + 0.5 * period) % period - 0.5 * period
    a, b = names
    d_rows = series[1].rows_px[j[keep]] - series[0].rows_px[keep] if estimate_line_time else None
    epoch = float(np.mean(tb[j[keep]]))
    (delay, line, drift), (std, u_line, u_drift) = _offset_from_delays(delays, d_rows, tb[j[keep]] - epoch)
    details: dict[str, Any] = {
        "rotation_hz": omega / (2 * np.pi),
        "radius_mm": {a: ra, b: rb},
        "angle_scatter_rad": {a: sa, b: sb},
        "n_pairs": int(delays.size),
        "delay_spread_s": float(np.std(delays, ddof=1)),
    }
    return TimingResult(
        reference_camera=a,
        offset_s={a: 0.0, b: float(delay)},
        line_time_s={a: float(line), b: float(line)},
        drift_ppm={a: 0.0, b: float(drift)},
        method="rotor",
        uncertainty={"offset_s": {a: 0.0, b: float(std)}, "line_time_s": {a: float(u_line), b: float(u_line)},
                     "drift_ppm": {a: 0.0, b: float(u_drift)}},
        epoch_s={a: 0.0, b: epoch},
        details=details,
    )
