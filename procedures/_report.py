"""The ``report`` step shared by the procedures (the last step of their plans, :data:`REPORT_STEP`):
analysis → tables, figures, report.html, certificate.json.

Calls :func:`reports.build.build_report` on the run folder (a pure function of it). The report is built
before the run's ``stop`` document exists, as the run's last step (``in_run``: the certificate says the
run is finishing normally); the procedure's verdict is taken from the criteria: passed when every
criterion is evaluated and passes. ``certificate_result`` (PASS / FAIL / INCOMPLETE) goes back to the
runner, whose outcome and exit code then agree with the certificate (INCOMPLETE is not a pass: exit 1).

The step issues the run's certificate once: a run resumed after its certificate was written keeps it
(``rig report RUN`` makes revisions; see :mod:`reports.build`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rig.run.plan import PlanStep
from rig.run.procedure import Context

if TYPE_CHECKING:
    from reports.scope import Scope

__all__ = ["REPORT_STEP", "evaluated_summary", "report_step", "verdict_of"]

# the report is a step of the plan, so the run's step count is known from its start; its time is the host's
# analysis, which the plan (rig time: motion, settling, recording) does not estimate
REPORT_STEP = PlanStep("report", 0.0, what="analysis, tables, figures, report.html, certificate.json "
                                           "(host time, not in the estimate)")


def verdict_of(certificate: dict[str, Any]) -> tuple[bool, str]:
    """(passed, summary) from the certificate's criteria rows (``status`` PASS / FAIL / NOT EVALUATED)."""
    rows = certificate.get("criteria") or []
    failed = [r.get("id", "?") for r in rows if r["status"] == "FAIL"]
    missing = [r.get("id", "?") for r in rows
               if r["status"] not in ("PASS", "FAIL")]
    passed = bool(rows) and not failed and not missing
    parts = [f"{sum(r['status'] == 'PASS' for r in rows)}/{len(rows)} criteria pass"]
    if failed:
        parts.append("failed: " + ", ".join(map(str, failed)))
    if missing:
        parts.append("not evaluated: " + ", ".join(map(str, missing)))
    return passed, "; ".join(parts)


def evaluated_summary(result: dict[str, Any]) -> str:
    """For a procedure that covers only part of the certification: the criteria its run evaluated."""
    done = [f"{k} {v}" for k, v in result["criteria"].items() if v in ("PASS", "FAIL")]
    return f"report {result['report']}; " + (", ".join(done) if done else "no acceptance criterion evaluated")


def report_step(ctx: Context, scope: Scope | None = None) -> dict[str, Any]:
    """Build the report as step ``report``; return the verdict dict (``passed``, ``summary``, paths).
    ``scope``: the comparison methods and figures (default: the rig's ``[report]``, as the run recorded
    it)."""
    from reports.build import build_report, issued_certificate

    with ctx.step(REPORT_STEP.name) as step:
        certificate = issued_certificate(ctx.run_dir)
        if certificate is None:
            ctx.progress(None, "report: analysis, tables, figures, certificate")
            # an abort requested during the report ends the step before the next analysis, else before the
            # certificate is issued
            result = build_report(ctx.run_dir, scope=scope, in_run=True, checkpoint=ctx.checkpoint)
            certificate = result.certificate
        # else: issued before this session (a resumed run): the certificate is issued once, never rebuilt
        if not step.skipped:
            for name in ("report.html", "certificate.json"):
                step.output(name)
    passed, summary = verdict_of(certificate)
    return {"passed": passed, "summary": summary, "report": str(ctx.run_dir / "report.html"),
            "certificate_result": certificate.get("result"),
            "certificate": str(ctx.run_dir / "certificate.json"),
            "criteria": {r.get("id", "?"): r["status"] for r in certificate.get("criteria") or []}}
