"""The stage objects of the localization method (kinds ``edges`` and ``localize`` of weldcell.sdk.stages)."""

from __future__ import annotations

from .edges import EdgePoints, EdgeSettings, extract_edges
from .fit import Localization, LocalizeSettings, localize
from .scan_io import LaserScan
from .template import Template


class EdgeExtractor:
    """kind ``edges``: ``(scan, template) -> EdgePoints`` (two-stage step kernels, CAD heights, slots)."""

    def __init__(self, settings: EdgeSettings | None = None) -> None:
        self.settings = settings or EdgeSettings()

    def __call__(self, scan: LaserScan, template: Template) -> EdgePoints:
        return extract_edges(scan, template, self.settings)


class Localizer:
    """kind ``localize``: ``(template, edges) -> Localization`` (``weldcell/localization@1``)."""

    def __init__(self, settings: LocalizeSettings | None = None) -> None:
        self.settings = settings or LocalizeSettings()

    def __call__(self, template: Template, edges: EdgePoints) -> Localization:
        return localize(template, edges, self.settings)
