"""The certification: calibrate → sync → accuracy → sweep → band → analysis → report → certificate.

One run folder holds everything: ``calibration.json`` (calibrate), ``timing.json`` (sync, which also records
the rotor's radius and frequency), the static poses (accuracy), the crank's frequency sweep, the shaker's
sweep over the band beyond it (:mod:`procedures._band`: amplitude and phase against the generator's own
waveform, up to the pair's combined Nyquist limit), then the report (:func:`reports.build.build_report`:
analysis, tables, figures, ``report.html``, ``certificate.json``). The whole plan (arm poses and speeds, rotor
and exciter frequencies, amplitudes, accelerations, the sweep's slope; :func:`plan`) is checked against the
rig's limits **before any device is connected**: a violation is refused with exit code 4 and no run folder.
The verdict: passed when every acceptance criterion of the certificate is evaluated and passes (exit 0), else
exit 1.

``preset = "full"`` is the certification (grid 3³, 10 ISO 9283 cycles, 4 marker-frame poses, sweep 1 → 30 Hz
in 24 s, band 27 → 50 Hz in 9 s on the shaker, the comparison analyses of ``[report]``: by default the
paper's linear sync beside ours); ``"fast"`` is a short check of the whole chain (grid 2³, 3 cycles, 2 frame
poses, sweep 2 → 12 Hz in 8 s, no band step — its plan says so —, no comparison analysis). The ``sweep_*``,
``band*``, ``accuracy_*``, ``calibrate_*`` and ``compare_paper_sync`` parameters override the preset;
``figures`` and ``compare_paper_sync`` override ``[report]`` (:func:`report_scope`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, TypedDict, TypeVar

from procedures import _band, accuracy, calibrate, sweep, sync
from procedures._report import REPORT_STEP, report_step
from procedures.params.certify import DESCRIPTION, NAME, PRESETS, Parameters  # noqa: F401 (its declaration)
from reports.scope import Scope
from rig.config.rig_config import RigConfig
from rig.run.plan import Plan
from rig.run.procedure import Context, ParameterError

P = TypeVar("P")


# the steps' parameters that certify sets (as in --set sweep_max_hz=…), named so in its plan's checks
PARAMETER_NAMES = {"sweep.start_hz": "certify.sweep_start_hz", "sweep.max_hz": "certify.sweep_max_hz",
                   "sweep.duration_s": "certify.sweep_duration_s",
                   "band.max_hz": "certify.band_max_hz", "band.duration_s": "certify.band_duration_s",
                   "accuracy.grid_points": "certify.accuracy_grid_points",
                   "accuracy.cycles": "certify.accuracy_cycles",
                   "calibrate.slide_positions_mm": "certify.calibrate_slide_positions_mm"}


class SubParameters(TypedDict):
    """The parameters of the procedures (and the band step) certify runs."""

    calibrate: calibrate.Parameters
    sync: sync.Parameters
    accuracy: accuracy.Parameters
    sweep: sweep.Parameters
    band: _band.BandParameters


def sub_parameters(params: Parameters) -> SubParameters:
    """The four procedures' parameters: the preset, then the explicit overrides."""
    chosen = {k: dict(v) for k, v in PRESETS[params.preset].items()}
    overrides: dict[str, dict[str, object]] = {
        "sweep": {"start_hz": params.sweep_start_hz, "max_hz": params.sweep_max_hz,
                  "duration_s": params.sweep_duration_s},
        "accuracy": {"grid_points": params.accuracy_grid_points, "cycles": params.accuracy_cycles},
        "band": {"max_hz": params.band_max_hz, "duration_s": params.band_duration_s, "enabled": params.band},
        "calibrate": {"slide_positions_mm": params.calibrate_slide_positions_mm or None}}
    for name, values in overrides.items():
        chosen[name].update({k: v for k, v in values.items() if v is not None})

    def build(name: str, parameters: Callable[..., P]) -> P:
        try:
            return parameters(**chosen[name])
        except ValueError as exc:
            raise ParameterError(f"certify.{name}", str(exc)) from exc

    return SubParameters(calibrate=build("calibrate", calibrate.Parameters),
                         sync=build("sync", sync.Parameters),
                         accuracy=build("accuracy", accuracy.Parameters),
                         sweep=build("sweep", sweep.Parameters),
                         band=build("band", _band.BandParameters))


def plan(params: Parameters, config: RigConfig) -> Plan:
    """Every step of the certification (calibrate, sync, accuracy, sweep, band, report), from the preset and
    the overrides; the runner checks it as a whole before any device is connected."""
    sub = sub_parameters(params)
    steps = (calibrate.plan(sub["calibrate"], config).steps + sync.plan(sub["sync"], config).steps
             + accuracy.own_plan(sub["accuracy"], config).steps + sweep.own_plan(sub["sweep"], config).steps
             + _band.own_plan(sub["band"], config).steps + (REPORT_STEP,))
    return Plan(NAME, steps).renamed(PARAMETER_NAMES)


def report_scope(params: Parameters, config: RigConfig) -> Scope:
    """The report's scope: the rig's ``[report]``, with certify's ``figures`` and ``compare_paper_sync`` when
    given, and no comparison on the fast preset unless ``compare_paper_sync`` asks for it."""
    scope = Scope.of_config(config.report)
    if params.figures is not None:
        scope = dataclasses.replace(scope, figures=params.figures,
                                    figures_why=f"certify figures = {str(params.figures).lower()}")
    if params.compare_paper_sync is not None:
        scope = dataclasses.replace(scope, comparison=("linear",) if params.compare_paper_sync else (),
                                    comparison_why=f"certify compare_paper_sync = "
                                                   f"{str(params.compare_paper_sync).lower()}")
    elif params.preset != "full":
        scope = dataclasses.replace(scope, comparison=(),
                                    comparison_why=f"certify preset = {params.preset!r}")
    return scope


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    sub = sub_parameters(params)  # their whole plan (:func:`plan`) was checked before the station opened
    ctx.log.info("certify (%s): %s", params.preset,
                 {"calibrate": dataclasses.asdict(sub["calibrate"]), "sync": dataclasses.asdict(sub["sync"]),
                  "accuracy": dataclasses.asdict(sub["accuracy"]), "sweep": dataclasses.asdict(sub["sweep"]),
                  "band": dataclasses.asdict(sub["band"])})
    if note := _band.left_out_note(sub["band"], ctx.config):  # said before the first move, not after the run
        ctx.log.warning("certify (%s): %s", params.preset, note)
    calibrate.run_step(ctx, sub["calibrate"])
    sync.run_step(ctx, sub["sync"])
    accuracy.run_steps(ctx, sub["accuracy"])
    sweep.run_step(ctx, sub["sweep"])
    _band.run_step(ctx, sub["band"])
    result = report_step(ctx, report_scope(params, ctx.config))
    return {"passed": result["passed"], "summary": result["summary"], "report": result["report"],
            "certificate": result["certificate"], "certificate_result": result["certificate_result"],
            "preset": params.preset, "criteria": result["criteria"]}
