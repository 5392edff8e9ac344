"""PhoXi file mode: replay PLY exports of PhoXi Control as depth frames (no scanner, no vendor library)."""

from __future__ import annotations

import glob
import time
from pathlib import Path

import numpy as np
from weldcell.hal.interfaces import DepthCamera
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.sdk.cloud import guess_units
from weldcell.sdk.errors import DataError, DeviceError

from .frames import fit_intrinsics, point_map_frame, virtual_camera, virtual_grid
from .ply import PlyGrid, read_ply_grid
from .settings import PhoXiSettings


def resolve_files(spec: str) -> list[Path]:
    """PLY files named by ``spec``: a folder (its *.ply, sorted), a glob pattern, or one file."""
    if not spec:
        raise DeviceError(
            "phoxi file mode needs 'files' (a folder, glob or PLY file)",
            'set files = "scans/*.ply" in the device settings',
        )
    p = Path(spec).expanduser()
    if p.is_dir():
        files = sorted(p.glob("*.ply"))
    elif any(c in spec for c in "*?["):
        files = sorted(Path(f) for f in glob.glob(str(p)))
    else:
        files = [p] if p.is_file() else []
    if not files:
        raise DeviceError(
            f"no PLY file found at {spec!r}", "check the path/pattern in the phoxi 'files' setting"
        )
    return files


class PhoXiFileCamera(DepthCamera):
    """Replays organised (or cropped, unorganised) PhoXi PLY exports, one file per ``capture()``.

    Organised files keep their grid; intrinsics are fitted to it (:func:`fit_intrinsics`) unless given.
    Unorganised files (cropped exports, 1 x N) are z-buffered into a virtual pinhole grid
    (:func:`virtual_grid`); ``meta["xyz"]`` then holds the points kept per pixel, and ``meta["points"]``
    every point of the file (metres), so no data is lost.
    """

    def __init__(self, settings: PhoXiSettings, name: str = "phoxi", frame: str | None = None) -> None:
        super().__init__(name, frame)
        self.settings = settings
        self._files: list[Path] = []
        self._next = 0
        self._intr: Intrinsics | None = None
        self._first: DepthFrame | None = None

    def on_configure(self) -> None:
        self._files = resolve_files(self.settings.files)
        self._next = 0
        self._intr = None
        # unorganised exports share one virtual camera whose image covers every file of the replay
        loose = []
        for path in self._files:
            ply = self._read(path)
            if not ply.organised:
                loose.append(ply.xyz * self._scale(ply.xyz, path))
        if loose:
            if self.settings.intrinsics is None:
                self._intr = virtual_camera(loose)
            else:
                fx, fy, cx, cy = self.settings.intrinsics
                allp = np.concatenate(loose)
                allp = allp[np.isfinite(allp).all(axis=1) & (allp[:, 2] > 0)]
                self._intr = Intrinsics(
                    width=int(np.ceil((fx * allp[:, 0] / allp[:, 2] + cx).max())) + 1,
                    height=int(np.ceil((fy * allp[:, 1] / allp[:, 2] + cy).max())) + 1,
                    fx=fx,
                    fy=fy,
                    cx=cx,
                    cy=cy,
                )
        self._first = self._load(self._files[0])
        if self._intr is None:
            self._intr = self._first.intrinsics

    def on_close(self) -> None:
        self._first = None

    def on_recover(self) -> None:
        self._first = None

    def _scale(self, pts: np.ndarray, path: Path) -> float:
        units = self.settings.units
        if units == "auto":
            units = guess_units(pts[np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)]) or "mm"
        return 1e-3 if units == "mm" else 1.0

    @staticmethod
    def _read(path: Path) -> PlyGrid:
        try:
            return read_ply_grid(path)
        except DataError as e:
            raise DeviceError(f"cannot replay {path.name}: {e.message}", e.fix) from e

    def _load(self, path: Path) -> DepthFrame:
        ply = self._read(path)
        pts = ply.xyz
        s = self._scale(pts, path)
        pts = pts * s
        normals = None
        if all(k in ply.vertex for k in ("nx", "ny", "nz")):
            normals = np.column_stack([ply.vertex["nx"], ply.vertex["ny"], ply.vertex["nz"]])
        meta = {"file": str(path), "organised": ply.organised}
        if ply.organised:
            xyz = ply.grid(pts)
            if self.settings.intrinsics is not None:
                fx, fy, cx, cy = self.settings.intrinsics
                k = Intrinsics(width=ply.cols, height=ply.rows, fx=fx, fy=fy, cx=cx, cy=cy)
            else:
                k, res = fit_intrinsics(xyz)
                meta["intrinsics_fit_rms_px"] = res
            nmap = ply.grid(normals) if normals is not None else None
        else:
            xyz, owner, k = virtual_grid(pts, self._intr)
            meta["points"] = pts[np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)]
            nmap = None
            if normals is not None:
                good = np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)
                n_ok = normals[good]
                nmap = np.zeros(xyz.shape)
                nmap[owner >= 0] = n_ok[owner[owner >= 0]]
        return point_map_frame(xyz, k, self.frame, normals=nmap, meta=meta)

    def _capture(self, timeout: float) -> DepthFrame:
        if self._next >= len(self._files):
            if not self.settings.loop:
                raise self.fault(f"all {len(self._files)} PLY files were replayed")
            self._next = 0
        i = self._next
        self._next += 1
        if i == 0 and self._first is not None:
            f = self._first
        else:
            f = self._load(self._files[i])
        return DepthFrame(
            stamp=time.time(),
            depth=f.depth,
            intrinsics=f.intrinsics,
            frame=f.frame,
            color=f.color,
            meta=dict(f.meta, index=i),
        )

    def _intrinsics(self) -> Intrinsics:
        if self._intr is None:
            raise DeviceError(
                f"depth_camera '{self.name}': intrinsics are known once configured", "call configure() first"
            )
        return self._intr
