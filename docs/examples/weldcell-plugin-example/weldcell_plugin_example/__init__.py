"""weldcell plugin: registration only. Keep this module cheap: weldcell imports it at start-up.

The entry point ``example = "weldcell_plugin_example"`` in pyproject.toml points here; weldcell calls
the ``weldcell_register_*`` functions below with a ``register`` callback.
"""

from __future__ import annotations

from weldcell.sdk.descriptors import ExporterSpec, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell_plugin_example.height_step import HeightStepSeams, HeightStepSettings

    register(
        StageSpec(
            name="seam.height-step",
            kind="seam",
            summary="seams where the surface height steps (lap joints), found with a KD-tree",
            settings=HeightStepSettings,
            factory=HeightStepSeams,
        )
    )


@hookimpl
def weldcell_register_exporters(register) -> None:
    from weldcell_plugin_example.gcode import GcodeSettings, to_gcode

    register(
        ExporterSpec(
            name="export.gcode-like",
            kind="exporter",
            summary="G-code-like program (mm, mm/min, torch angles in degrees)",
            settings=GcodeSettings,
            export=to_gcode,
            suffix=".nc",
        )
    )
