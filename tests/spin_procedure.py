"""A procedure file for the standalone-mock safety tests (``rig run tests/spin_procedure.py``): spin the
exciter and the rotor through their real drivers, hold while polling both (with checkpoints, like an
acquisition or a sweep), then a ``report`` step without checkpoints. Events: ``spinning`` once both run,
``hold`` and ``report_tick`` as it goes (the tests wait on them). The report step lasts ``report_s`` or
until a file ``END_REPORT`` appears in the working directory (a test that has seen its signal handled ends
the step there: the step then completes as a real report step does, without a checkpoint).

Why not ``rig run sweep``: on stand-alone mocks each mock has its own twin world, so the station's
simulated cameras film a world where the arm never moves, and the sweep's calibrate step fails before
anything spins. This file drives the same drivers over the same protocols.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.run.procedure import param

NAME = "spin"
END_REPORT = "end_report"


@dataclass(frozen=True)
class Parameters:
    exciter_hz: float = field(default=3.0, metadata=param(lo=0.1, hi=30.0))
    rotor_hz: float = field(default=5.0, metadata=param(lo=0.1, hi=30.0))
    hold_s: float = field(default=600.0, metadata=param(lo=0.0, hi=3600.0))
    report_s: float = field(default=0.0, metadata=param(lo=0.0, hi=3600.0))
    poll_s: float = field(default=0.1, metadata=param(lo=0.01, hi=1.0))


def run(ctx: Any, params: Parameters) -> dict[str, Any]:
    exciter, rotor = ctx.device("exciter"), ctx.device("rotor")
    with ctx.step("spin"):
        exciter.set_frequency(params.exciter_hz, wait=False)
        rotor.set_frequency(params.rotor_hz, wait=False)
        exciter.wait_until_reached(params.exciter_hz)
        rotor.wait_until_reached(params.rotor_hz)
        ctx.event("spinning", {"exciter_hz": params.exciter_hz, "rotor_hz": params.rotor_hz})
        t_end = ctx.clock.now_s() + params.hold_s
        while ctx.clock.now_s() < t_end:
            ctx.event("hold", {name: dataclasses.asdict(axis.read_sample())
                               for name, axis in (("exciter", exciter), ("rotor", rotor))})
            ctx.checkpoint()
            ctx.clock.sleep_s(params.poll_s)
    with ctx.step("report"):  # no checkpoint here, as in the real report step; the drives keep running
        t_end = ctx.clock.now_s() + params.report_s
        while ctx.clock.now_s() < t_end and not Path(END_REPORT).exists():
            ctx.event("report_tick", {"t_s": ctx.clock.now_s()})
            ctx.clock.sleep_s(params.poll_s)
    return {"passed": True, "summary": "spun"}
