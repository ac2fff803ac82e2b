"""The window the offset between two videos lies in, from their containers' creation times
(:mod:`drivers.camera.container_times`) or from the options.

Camera B's offset (s to add to B's time stamps to put them on A's clock) is, if each container's creation
time C marks its first frame (time stamp t0), δ = (C_B − C_A) + t0_A − t0_B. What the containers cannot say
is allowed for, each as a half-width added to the window:

- their **resolution** r (MP4/MOV and AVI: whole seconds) — a time rounded or truncated, the container does
  not say which: ± (r_A + r_B);
- whether C marks the **start or the end** of the recording (cameras differ): the end convention gives
  δ − (D_B − D_A) with the containers' durations D; the window spans both;
- the **cameras' clocks** agree only as well as they were set: ± ``clock_agreement_s`` (an option; the
  files cannot tell).

Both creation times must be on the same kind of clock (both UTC, or both an unstated local time). The
options win: ``prior_offset_s`` given → the window is centred there (± ``max_offset_s`` or
:data:`FALLBACK_MAX_OFFSET_S`); only ``max_offset_s`` given → centred on the containers' estimate when they
have one. Without usable times: 0 ± :data:`FALLBACK_MAX_OFFSET_S`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.camera.container_times import ContainerError, ContainerTimes
from rig.deploy.choices import DEFAULT_CLOCK_AGREEMENT_S

__all__ = ["DEFAULT_CLOCK_AGREEMENT_S", "FALLBACK_MAX_OFFSET_S", "OffsetWindow", "offset_window"]

FALLBACK_MAX_OFFSET_S = 10.0  # cameras started by hand within a few seconds of each other (s)


@dataclass(frozen=True)
class OffsetWindow:
    """``prior_offset_s`` ± ``max_offset_s`` (s); ``source``: "options", "containers" or "default";
    ``statement``: one sentence for the notes; ``containers``: each camera's container times (or the
    reason they are unusable) and, when used, the estimate's parts."""

    prior_offset_s: float
    max_offset_s: float
    source: str
    statement: str
    containers: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"prior_offset_s": self.prior_offset_s, "max_offset_s": self.max_offset_s,
                "source": self.source, "statement": self.statement, "containers": self.containers}


def _container_estimate(a: ContainerTimes, b: ContainerTimes, first_a_s: float, first_b_s: float,
                        clock_agreement_s: float) -> tuple[float, float, dict[str, Any]] | str:
    """(centre s, half-width s, parts) of the offset from two containers' times, or why there is none."""
    ca, cb = a.creation_s(), b.creation_s()
    if ca is None or cb is None:
        if ca is None and cb is None:
            return "neither container states a creation time"
        return f"the {'reference' if ca is None else 'other'} video's container states no creation time"
    if a.creation_utc_known != b.creation_utc_known:
        return "one container states UTC and the other an unstated local time: not comparable"
    start = (cb - ca) + first_a_s - first_b_s
    end = start - ((b.duration_s or 0.0) - (a.duration_s or 0.0)) if a.duration_s and b.duration_s else start
    res_a, res_b = float(a.creation_resolution_s or 0.0), float(b.creation_resolution_s or 0.0)
    resolution = res_a + res_b
    lo, hi = min(start, end), max(start, end)
    half = 0.5 * (hi - lo) + resolution + clock_agreement_s
    parts = {"offset_if_start_s": start, "offset_if_end_s": end, "resolution_s": [res_a, res_b],
             "clock_agreement_s": clock_agreement_s, "sources": [a.creation_source, b.creation_source]}
    return 0.5 * (lo + hi), half, parts


def offset_window(times: dict[str, ContainerTimes | ContainerError], first_stamp_s: dict[str, float], *,
                  reference: str, prior_offset_s: float | None = None, max_offset_s: float | None = None,
                  clock_agreement_s: float = DEFAULT_CLOCK_AGREEMENT_S) -> OffsetWindow:
    """The offset window for the camera other than ``reference`` (module doc). ``times``: camera → its
    container times or the error reading them; ``first_stamp_s``: camera → its first frame's time stamp."""
    if not clock_agreement_s >= 0:
        raise ValueError(f"clock_agreement_s={clock_agreement_s!r}; allowed: ≥ 0 s")
    other = next(c for c in times if c != reference)
    listed: dict[str, Any] = {c: (t.to_dict() if isinstance(t, ContainerTimes) else {"error": str(t)})
                              for c, t in times.items()}
    a, b = times[reference], times[other]
    est: tuple[float, float, dict[str, Any]] | str
    if isinstance(a, ContainerError) or isinstance(b, ContainerError):
        est = "a container could not be read"
    else:
        est = _container_estimate(a, b, first_stamp_s.get(reference, 0.0), first_stamp_s.get(other, 0.0),
                                  clock_agreement_s)
    if isinstance(est, tuple):
        listed["estimate"] = est[2]
    if prior_offset_s is not None:
        half = max_offset_s if max_offset_s is not None else FALLBACK_MAX_OFFSET_S
        return OffsetWindow(prior_offset_s, half, "options",
                            f"offset window {prior_offset_s:+.3f} ± {half:.3f} s (the options)", listed)
    if isinstance(est, str):
        half = max_offset_s if max_offset_s is not None else FALLBACK_MAX_OFFSET_S
        why = "--max-offset-s" if max_offset_s is not None else "the default: cameras started by hand"
        return OffsetWindow(0.0, half, "options" if max_offset_s is not None else "default",
                            f"offset window 0 ± {half:.3f} s ({why}; containers: {est})", listed)
    centre, half, parts = est
    if max_offset_s is not None:
        half = max_offset_s
    res_a, res_b = parts["resolution_s"]
    return OffsetWindow(centre, half, "containers",
                        f"offset window {centre:+.3f} ± {half:.3f} s from the containers' creation times "
                        f"({' / '.join(map(str, parts['sources']))}, resolution {res_a:g} / {res_b:g} s"
                        f"{' — whole seconds' if max(res_a, res_b) >= 1 else ''}; start or end of recording: "
                        f"{parts['offset_if_start_s']:+.3f} or {parts['offset_if_end_s']:+.3f} s; the "
                        f"cameras' clocks taken to agree within {clock_agreement_s:g} s"
                        f"{'' if max_offset_s is None else '; half-width from --max-offset-s'})", listed)
