"""Exporters of weld paths: URScript, ABB RAPID, KUKA KRL, FANUC TP, CSV and JSON (docs/exporters.md)."""

from __future__ import annotations

from weldcell.sdk.descriptors import ExporterSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_exporters(register) -> None:
    from weldcell.plugins.exporters import controllers, programs

    register(
        ExporterSpec(
            name="export.urscript",
            kind="exporter",
            summary="URScript program (movej/movel/movep, arc on/off, a function per seam)",
            settings=programs.URScriptSettings,
            export=programs.to_urscript,
            suffix=".script",
        )
    )
    register(
        ExporterSpec(
            name="export.abb-rapid",
            kind="exporter",
            summary="ABB RAPID module (declared data, ArcLStart/ArcL/ArcLEnd, a PROC per seam)",
            settings=programs.RapidSettings,
            export=programs.to_rapid,
            suffix=".mod",
        )
    )
    register(
        ExporterSpec(
            name="export.kuka-krl",
            kind="exporter",
            summary="KUKA KRL .src (E6POS, LIN/PTP, C_DIS, $OUT arc signal, a DEF per seam)",
            settings=controllers.KrlSettings,
            export=controllers.to_krl,
            suffix=".src",
            files=controllers.krl_files,
        )
    )
    register(
        ExporterSpec(
            name="export.fanuc-tp",
            kind="exporter",
            summary="FANUC TP program .ls (P[n] POS data, L/J, FINE/CNT, Arc Start/End)",
            settings=controllers.FanucSettings,
            export=controllers.to_fanuc,
            suffix=".ls",
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
