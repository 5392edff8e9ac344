"""Reading PhoXi Control / PCL PLY exports with their grid organisation (vendor-free).

PhoXi Control's "organised" PLY keeps one vertex per sensor pixel in row-major order. The grid size is
taken, in this order, from a PCL ``camera`` element (``viewportx`` = columns, ``viewporty`` = rows), from
``obj_info num_cols/num_rows`` or ``comment Width/Height`` header lines. Scalar vertex properties are read
(``x y z``, optional ``nx ny nz``, ``red green blue``, ``intensity``/``texture``); ascii and binary files.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from weldcell.sdk.cloudfile import HEADER_LIMIT, check_ply, parse_ply_header
from weldcell.sdk.errors import DataError

_REEXPORT = "the export is damaged or cut short; export it again"


@dataclass
class PlyGrid:
    """The vertices of one PLY file and its grid (``rows`` x ``cols``; 1 x N when unorganised)."""

    path: Path
    vertex: dict[str, np.ndarray]
    rows: int
    cols: int
    organised: bool
    header: list[str] = field(default_factory=list)

    @property
    def xyz(self) -> np.ndarray:
        return np.column_stack([self.vertex["x"], self.vertex["y"], self.vertex["z"]]).astype(np.float64)

    def grid(self, arr: np.ndarray) -> np.ndarray:
        """Per-vertex values reshaped to (rows, cols, ...)."""
        return np.asarray(arr).reshape(self.rows, self.cols, *np.asarray(arr).shape[1:])


def read_ply_grid(path: str | Path) -> PlyGrid:
    """Read a PLY export with its grid organisation (see the module docstring)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read {path}: {e}", "check the file path in the phoxi settings") from e
    check_ply(path, raw[:HEADER_LIMIT], len(raw))  # header, x/y/z, counts against the body, numbers
    h = parse_ply_header(path, raw[:HEADER_LIMIT])
    fmt, lines, pos = h.fmt, h.lines, h.body_start
    elements = [(e.name, e.count, e.props) for e in h.elements]
    values: dict[str, dict[str, np.ndarray]] = {}
    if fmt == "ascii":
        text = raw[pos:].decode("ascii", "replace").splitlines()
        row = 0
        for name, count, props in elements:
            if any(t == "list" for t, _ in props):
                if name == "vertex":
                    raise DataError(
                        f"{path}: list properties in vertices are not supported", "export points only"
                    )
                row += count
                continue
            block = text[row : row + count]
            row += count
            if len(block) < count:
                raise DataError(
                    f"{path}: file ends after {len(block)} of {count} '{name}' rows",
                    "the export is truncated; export it again",
                )
            try:
                arr = np.array(" ".join(block).split(), dtype=np.float64)
            except ValueError:
                raise DataError(
                    f"{path}: a '{name}' row holds a value that is not a number", _REEXPORT
                ) from None
            if arr.size != count * len(props):
                raise DataError(
                    f"{path}: '{name}' rows do not have {len(props)} values each", "the export is malformed"
                )
            arr = arr.reshape(count, len(props))
            values[name] = {p: arr[:, i] for i, (_, p) in enumerate(props)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        for name, count, props in elements:
            if any(t == "list" for t, _ in props):
                if name == "vertex":
                    raise DataError(
                        f"{path}: list properties in vertices are not supported", "export points only"
                    )
                break  # cannot skip variable-length rows; nothing after this is needed
            dt = np.dtype([(p, order + t) for t, p in props])
            need = dt.itemsize * count
            if pos + need > len(raw):
                raise DataError(f"{path}: file ends inside the '{name}' element", "the export is truncated")
            rec = np.frombuffer(raw, dtype=dt, count=count, offset=pos)
            pos += need
            with np.errstate(invalid="ignore"):  # damaged values become NaN/inf; callers check them
                values[name] = {p: rec[p].astype(np.float64) for _, p in props}
    vertex = values.get("vertex")
    if vertex is None or not all(k in vertex for k in "xyz"):
        raise DataError(f"{path}: no vertex x/y/z", "export the point cloud (not a mesh-only file)")
    n = len(vertex["x"])
    rows, cols = 1, n
    cam = values.get("camera")
    header_text = "\n".join(lines)
    m_cols = re.search(r"(?:obj_info\s+num_cols|comment\s+width)\s+(\d+)", header_text, re.I)
    m_rows = re.search(r"(?:obj_info\s+num_rows|comment\s+height)\s+(\d+)", header_text, re.I)
    if cam is not None and "viewportx" in cam and "viewporty" in cam and len(cam["viewportx"]):
        cols, rows = (int(v) if np.isfinite(v) else 0 for v in (cam["viewportx"][0], cam["viewporty"][0]))
    elif m_cols and m_rows:
        cols, rows = int(m_cols.group(1)), int(m_rows.group(1))
    if rows * cols != n:
        rows, cols = 1, n
    return PlyGrid(
        path=path, vertex=vertex, rows=rows, cols=cols, organised=rows > 1 and cols > 1, header=lines
    )


def write_ply_grid(
    path: str | Path, xyz: np.ndarray, normals: np.ndarray | None = None, binary: bool = True
) -> Path:
    """Write an organised (H, W, 3) point map as a PCL-style PLY (``camera`` element = grid size)."""
    xyz = np.asarray(xyz, dtype=np.float32)
    h, w = xyz.shape[:2]
    cols = {"x": xyz[..., 0].ravel(), "y": xyz[..., 1].ravel(), "z": xyz[..., 2].ravel()}
    if normals is not None:
        nm = np.asarray(normals, dtype=np.float32)
        cols.update({"nx": nm[..., 0].ravel(), "ny": nm[..., 1].ravel(), "nz": nm[..., 2].ravel()})
    fmt = "binary_little_endian" if binary else "ascii"
    head = ["ply", f"format {fmt} 1.0", "comment weldcell organised point map", f"element vertex {h * w}"]
    head += [f"property float {k}" for k in cols]
    cam_props = [
        "view_px",
        "view_py",
        "view_pz",
        "x_axisx",
        "x_axisy",
        "x_axisz",
        "y_axisx",
        "y_axisy",
        "y_axisz",
        "z_axisx",
        "z_axisy",
        "z_axisz",
        "focal",
        "scalex",
        "scaley",
        "centerx",
        "centery",
    ]
    head += ["element camera 1"] + [f"property float {p}" for p in cam_props]
    head += [
        "property int viewportx",
        "property int viewporty",
        "property float k1",
        "property float k2",
        "end_header",
    ]
    cam_f = [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0]
    path = Path(path)
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        if binary:
            rec = np.empty(h * w, dtype=[(k, "<f4") for k in cols])
            for k, v in cols.items():
                rec[k] = v
            f.write(rec.tobytes())
            f.write(
                np.array(cam_f, "<f4").tobytes()
                + np.array([w, h], "<i4").tobytes()
                + np.array([0, 0], "<f4").tobytes()
            )
        else:
            np.savetxt(f, np.column_stack(list(cols.values())), fmt="%.9g")
            f.write((" ".join(str(v) for v in cam_f) + f" {w} {h} 0 0\n").encode("ascii"))
    return path
