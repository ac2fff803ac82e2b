"""What a report computes beyond the certificate (:class:`Scope`): the rig's ``[report]`` as the run recorded
it (:mod:`rig.config.report`), unless the caller (certify's parameters, ``--no-figures``) decides otherwise,
and the notes saying what was left out and why. Neither choice changes a criterion of the certificate."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rig.config.report import ReportConfig
from rig.config.schema import build

__all__ = ["Scope"]


@dataclass(frozen=True)
class Scope:
    """``comparison``: sync methods analysed beside the primary one (``()``: none); ``figures``: draw the PNG
    figures. ``comparison_why`` / ``figures_why``: the setting that left one out, as the notes name it
    (empty: the ``[report]`` field)."""

    comparison: tuple[str, ...] = ReportConfig().comparison
    figures: bool = ReportConfig().figures
    comparison_why: str = ""
    figures_why: str = ""

    @classmethod
    def of_snapshot(cls, rig: dict[str, Any]) -> Scope:
        """The ``[report]`` of a run's rig snapshot (``start`` document); the defaults for a run recorded
        before the table existed. A snapshot edited out of range raises
        :class:`rig.config.schema.ConfigError`."""
        table = rig.get("report")
        cfg = build(ReportConfig, table, "report") if isinstance(table, dict) else ReportConfig()
        return cls.of_config(cfg)

    @classmethod
    def of_config(cls, cfg: ReportConfig) -> Scope:
        """The scope ``[report]`` sets."""
        return cls(cfg.comparison, cfg.figures)

    @property
    def figures_note(self) -> str | None:
        """Why no figure was drawn (None when they are)."""
        why = self.figures_why or "[report] figures = false"
        return None if self.figures else f"figures not drawn: {why}"

    def notes(self) -> list[str]:
        """What the report leaves out and why, one note each."""
        out = [] if self.comparison else [
            f"no sync method analysed for comparison: {self.comparison_why or '[report] comparison = []'}"]
        return out + ([self.figures_note] if self.figures_note else [])

