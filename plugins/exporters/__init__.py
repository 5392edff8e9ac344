"""Exporters of weld paths: URScript, ABB RAPID, CSV and JSON."""

from __future__ import annotations

from weldcell.sdk.descriptors import ExporterSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_exporters(register) -> None:
    from weldcell.plugins.exporters import programs

    register(
        ExporterSpec(
            name="export.urscript",
            kind="exporter",
            summary="URScript program (movel/movep)",
            settings=programs.URScriptSettings,
            export=programs.to_urscript,
            suffix=".script",
        )
    )
    register(
        ExporterSpec(
            name="export.abb-rapid",
            kind="exporter",
            summary="ABB RAPID module (robtargets + MoveL)",
            settings=programs.RapidSettings,
            export=programs.to_rapid,
            suffix=".mod",
        )
    )
    register(
        ExporterSpec(
            name="export.csv",
            kind="exporter",
            summary="CSV table of torch poses (mm, quaternion)",
            settings=programs.CsvSettings,
            export=programs.to_csv,
            suffix=".csv",
        )
    )
    register(
        ExporterSpec(
            name="export.json",
            kind="exporter",
            summary="the weld-path JSON itself",
            export=programs.to_json,
            suffix=".json",
        )
    )
