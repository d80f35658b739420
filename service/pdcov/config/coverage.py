"""The mission config's ``coverage`` section: the grid's range and revisit options, the
lowest camera height evaluated (m) and how one person's looks combine."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import number, opt_number
from pdcov.core.detector import DetectorModel
from pdcov.core.looks import LooksConfig, LooksRule, ViewpointBins
from pdcov.errors import ConfigError, where


@dataclass(frozen=True, slots=True)
class CoverageSection:
    """``coverage``: CoverageGrid's max_range_m and min_revisit_s (None: its defaults),
    min_height_m: frames with the camera lower than this above the ground are not
    evaluated, looks: how one person's looks combine (core/looks.py) and viewpoint: the
    bins of ``looks: viewpoint``."""

    max_range_m: float | None = None
    min_revisit_s: float | None = None
    min_height_m: float = 1.0
    looks: LooksRule = LooksRule.INDEPENDENT
    viewpoint: ViewpointBins | None = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> CoverageSection:
        rule = doc.get("looks", str(LooksRule.INDEPENDENT))
        if rule not in tuple(str(r) for r in LooksRule):
            raise ConfigError(f"{where(src, 'coverage.looks')}: expected one of "
                              f"{', '.join(str(r) for r in LooksRule)}, got {rule!r}")
        view = doc.get("viewpoint")
        bins = None
        if view is not None:
            if rule != LooksRule.VIEWPOINT:
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: only used with "
                                  f"coverage.looks: viewpoint (it says {rule})")
            if not isinstance(view, dict):
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: expected a mapping "
                                  f"of azimuth_bins and elevation_bins, got {view!r}")
            try:
                bins = ViewpointBins(**view)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{where(src, 'coverage.viewpoint')}: {exc}") from None
        return cls(opt_number(doc, "max_range_m", src, "coverage"),
                   opt_number(doc, "min_revisit_s", src, "coverage"),
                   number(doc, "min_height_m", src, "coverage", default=1.0),
                   LooksRule(rule), bins)

    def looks_config(self, detector: DetectorModel, src: str | None,
                     at: str = "coverage.looks") -> LooksConfig:
        """The grid's looks; ``correlated`` needs the detector model's looks section (``at``:
        the key the error names, e.g. cameras[1].detector)."""
        if self.looks is LooksRule.CORRELATED and detector.looks is None:
            rule = "correlated" if at == "coverage.looks" else "coverage.looks correlated"
            raise ConfigError(
                f"{where(src, at)}: {rule} needs the detector model's "
                f"looks section (looks.correlation per size bin, written by pdcov detector "
                f"fit from tracked sequences); {detector.source or 'the detector model'} has "
                "none. Use looks: independent or viewpoint, or fit the model on tracks")
        return LooksConfig(self.looks, self.viewpoint or ViewpointBins())
