"""Segment-wise map transmission (paper 004 §II-D, Table II): the segmented map folder
``weldcell/map-segments@1``, a ZeroMQ map server and a resumable client, and the commands
``weldcell map segment | serve | fetch``. Registration only: every module is imported lazily."""

from __future__ import annotations

from weldcell.sdk.descriptors import CommandSpec, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.map_transfer import stage

    register(
        StageSpec(
            name="map-transfer.zmq",
            kind="map-transfer",
            summary="local maps in weldcell/map-segments@1 (quantised, Draco, PLY) served and fetched "
            "over ZeroMQ",
            settings=stage.TransferSettings,
            factory=stage.MapTransfer,
            requires={"zmq": "transfer", "DracoPy": "transfer"},
        )
    )


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.map_transfer import cli

    register(
        CommandSpec(
            name="map segment",
            command=cli.segment_command,
            summary="cut a posed map into local maps (weldcell/map-segments@1)",
        )
    )
    register(
        CommandSpec(
            name="map serve",
            command=cli.serve_command,
            summary="serve a segmented map over ZeroMQ (robot side)",
        )
    )
    register(
        CommandSpec(
            name="map fetch",
            command=cli.fetch_command,
            summary="fetch a served map segment by segment, resumably (operator side)",
        )
    )
