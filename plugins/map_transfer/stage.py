"""The ``map-transfer`` stage: what a job (the cell-4 ``map`` job) uses to write its local maps in the
``weldcell/map-segments@1`` folder, serve them over ZeroMQ while it drives, fetch them like the operator's
computer would, and read them back. A job reaches it through the stage registry (``ctx.stage``), never
through this plugin's modules.

Stage interface (kind ``map-transfer``; :class:`MapTransfer`)::

    writer = stage.writer(root, source, cut={"max_distance": .., "max_points": ..})
    writer.add(id, points_local, colors, T_world_segment, distance_m, keyframes, extra) -> manifest entry
    writer.add_existing(src_root, entry) -> entry (a segment carried over byte for byte)
    writer.finish()
    server = stage.serve(root)            # started; server.address, server.stop()
    report = stage.fetch(address, out)    # FetchReport (segments, first_segment_s, complete, ...)
    manifest = stage.manifest(root); pts, cols = stage.world_cloud(root)
    seg = stage.segment(root, entry)      # .points (segment frame), .colors, .T_world_segment
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration, Length


class TransferSettings(Settings):
    """Encoding of the local maps and the loopback/robot endpoint they are served on."""

    encoding: Literal["quantised", "draco", "ply"] = Field(
        "quantised",
        description="segment file encoding: quantised (<= max_error grid, deflated; fast to decode), draco "
        "(<= max_error, DracoPy) or ply (lossless float32)",
    )
    max_error: Length = Field(0.001, gt=0, description="largest quantisation error (quantised, draco) [m]")
    bind: str = Field(
        "tcp://127.0.0.1:*", description="ZeroMQ endpoint of the map server (loopback, any free port)"
    )
    token_env: str | None = Field(None, description="environment variable with the shared token")
    fetch_wait: Duration = Field(
        3600.0, gt=0, description="a fetch gives up after this long without a new segment [s]"
    )


class _Writer:
    def __init__(self, inner) -> None:
        self._w = inner
        self.root = inner.root

    @property
    def manifest(self) -> dict:
        return self._w.manifest

    def add(self, id, points, colors, T_world_segment, distance, keyframes, extra=None) -> dict:  # noqa: A002
        from .segments import Segment

        seg = Segment(
            int(id),
            np.asarray(points, float),
            colors,
            np.asarray(T_world_segment, float),
            float(distance),
            [int(k) for k in keyframes],
        )
        return self._w.add(seg, extra)

    def add_existing(self, src_root, entry: dict, new_id: int | None = None) -> dict:
        return self._w.add_existing(src_root, entry, new_id)

    def finish(self, extra: dict | None = None) -> dict:
        if extra:
            self._w.manifest.update(extra)
        return self._w.finish()


class MapTransfer:
    """Factory object of the ``map-transfer.zmq`` stage (see the module docstring)."""

    def __init__(self, settings: TransferSettings | None = None) -> None:
        self.settings = settings or TransferSettings()

    def writer(self, root: str | Path, source: str = "", cut: dict | None = None) -> _Writer:
        from .segments import SegmentSettings, SegmentWriter

        s = SegmentSettings(encoding=self.settings.encoding, max_error=self.settings.max_error, **(cut or {}))
        return _Writer(SegmentWriter(root, s, source))

    def _token(self) -> str | None:
        from .cli import token_from_env

        return token_from_env(self.settings.token_env) if self.settings.token_env else None

    def serve(self, root: str | Path):
        from .server import MapServer

        return MapServer(root, self.settings.bind, token=self._token()).start()

    def fetch(self, address: str, out: str | Path):
        from .client import FetchSettings, MapClient

        with MapClient(address, out, self._token(), FetchSettings(wait=self.settings.fetch_wait)) as c:
            return c.fetch()

    def manifest(self, root: str | Path) -> dict:
        from .segments import read_manifest

        return read_manifest(root)

    def world_cloud(self, root: str | Path):
        from .segments import load_world_cloud

        return load_world_cloud(root)

    def segment(self, root: str | Path, entry: dict):
        from .segments import load_segment

        return load_segment(root, entry)
