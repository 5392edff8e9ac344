"""Malformed PLY and PCD files through ``weldcell seam`` (and a few through ``reconstruct`` and the
PhoXi file reader): each refused with one line and a fix, exit 2, nothing from Open3D/RPly printed."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from weldcell.sdk.cloud import PointCloud, load_cloud_file, read_cloud
from weldcell.sdk.errors import DataError

from .conftest import assert_refused

N = 2000
PTS = np.random.default_rng(0).uniform([0.3, -0.15, 0.0], [0.6, 0.15, 0.05], (N, 3))


def ply_header(n=N, fmt="binary_little_endian", props=("float x", "float y", "float z"), extra=()) -> bytes:
    lines = ["ply", f"format {fmt} 1.0", "comment weldcell test", f"element vertex {n}"]
    lines += [f"property {p}" for p in props] + list(extra) + ["end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def ply_binary(pts=PTS, n=None, order="<", typ="f4", **kw) -> bytes:
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    name = {"f4": "float", "f8": "double"}[typ]
    props = (f"{name} x", f"{name} y", f"{name} z")
    return ply_header(len(pts) if n is None else n, fmt, props, **kw) + np.asarray(pts, order + typ).tobytes()


def ply_ascii(rows=None, n=N) -> bytes:
    rows = [" ".join(f"{v:.6f}" for v in p) for p in PTS] if rows is None else rows
    return ply_header(n, "ascii") + ("\n".join(rows) + "\n").encode("ascii")


def pcd_header(
    n=N, data="binary", fields="x y z", size="4 4 4", typ="F F F", count="1 1 1", width=None, extra=()
) -> bytes:
    lines = [
        "# .PCD v0.7",
        "VERSION 0.7",
        f"FIELDS {fields}",
        f"SIZE {size}",
        f"TYPE {typ}",
        f"COUNT {count}",
        f"WIDTH {n if width is None else width}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {n}",
        *extra,
        f"DATA {data}",
    ]
    return ("\n".join(lines) + "\n").encode("ascii")


def pcd_binary(n=N, body=None, **kw) -> bytes:
    return pcd_header(n, **kw) + (PTS.astype("<f4").tobytes() if body is None else body)


def pcd_ascii(rows=None, n=N) -> bytes:
    rows = [" ".join(f"{v:.6f}" for v in p) for p in PTS] if rows is None else rows
    return pcd_header(n, "ascii") + ("\n".join(rows) + "\n").encode("ascii")


GOOD_PLY = ply_binary()
GOOD_PCD = pcd_binary()
ROWS = [" ".join(f"{v:.6f}" for v in p) for p in PTS]

# name -> (file name, bytes, words the error must contain)
PLY_CASES = {
    "empty": (b"", "empty"),
    "not-ply-magic": (b"plx\n" + GOOD_PLY[4:], "not a PLY file"),
    "random-bytes": (bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)), "not a PLY"),
    "pcd-content": (GOOD_PCD, "not a PLY file"),
    "magic-only": (b"ply\n", "end_header"),
    "no-end-header": (ply_header()[:-11] + b"\n" * 3, "end_header"),
    "header-only": (ply_header()[:-1], "no data"),
    "cut-at-10pct": (GOOD_PLY[: len(ply_header()) + N * 12 // 10], "cut short"),
    "cut-at-half": (GOOD_PLY[: len(GOOD_PLY) // 2], "cut short"),
    "cut-one-byte": (GOOD_PLY[:-1], "cut short"),
    "declares-50M-binary": (ply_binary(n=50_000_000), "50000000 points"),
    "declares-50M-ascii": (ply_ascii(n=50_000_000), "cut short"),
    "declares-fewer": (ply_binary(n=N // 2), "more data than its header"),
    "big-endian-cut": (ply_binary(order=">")[:-100], "cut short"),
    "double-cut": (ply_binary(typ="f8")[:-8], "cut short"),
    "format-unknown": (GOOD_PLY.replace(b"binary_little_endian", b"binary_middle_endian"), "unsupported PLY"),
    "format-missing": (GOOD_PLY.replace(b"format binary_little_endian 1.0\n", b""), "no 'format'"),
    "format-twice": (GOOD_PLY.replace(b"comment weldcell test", b"format ascii 1.0"), "format"),
    "type-unknown": (GOOD_PLY.replace(b"property float x", b"property float128 x"), "property TYPE NAME"),
    "no-z": (GOOD_PLY.replace(b"property float z\n", b""), "no z"),
    "no-xyz": (
        GOOD_PLY.replace(b"property float x\nproperty float y\nproperty float z", b"property float a"),
        "no x/y/z",
    ),
    "no-vertex-element": (GOOD_PLY.replace(b"element vertex", b"element point"), "no 'vertex'"),
    "count-text": (GOOD_PLY.replace(b"element vertex 2000", b"element vertex lots"), "not a whole number"),
    "count-negative": (GOOD_PLY.replace(b"element vertex 2000", b"element vertex -5"), "negative"),
    "count-missing": (GOOD_PLY.replace(b"element vertex 2000", b"element vertex"), "element NAME COUNT"),
    "count-zero": (ply_header(0), "no points"),
    "vertex-list": (ply_header(extra=["property list uchar int idx"]) + b"\0" * (N * 13), "list"),
    "property-first": (
        GOOD_PLY.replace(b"element vertex 2000\n", b"").replace(
            b"end_header", b"element vertex 2000\nend_header"
        ),
        "property before any element",
    ),
    "property-twice": (GOOD_PLY.replace(b"property float z", b"property float y"), "twice"),
    "header-not-utf8": (
        GOOD_PLY.replace(b"comment weldcell test", b"comment \xff\xfe\x00 binary"),
        "not text",
    ),
    "unknown-keyword": (GOOD_PLY.replace(b"comment weldcell test", b"colour red"), "unknown PLY keyword"),
    "ascii-text-value": (ply_ascii([*ROWS[:10], "0.1 abc 0.2", *ROWS[11:]]), "not a number"),
    "ascii-short-row": (ply_ascii([*ROWS[:10], "0.1 0.2", *ROWS[11:]]), "row 11 has 2 values"),
    "ascii-long-row": (ply_ascii([*ROWS[:10], "0.1 0.2 0.3 0.4", *ROWS[11:]]), "row 11 has 4 values"),
    "ascii-cut": (ply_ascii(ROWS[: N // 2]), "cut short"),
    "ascii-extra-rows": (ply_ascii(ROWS + ROWS[:5]), "more rows"),
    "ascii-binary-junk": (ply_ascii(ROWS[:5] + ["\x00\x01\x02 x y"] + ROWS[6:]), "not a number"),
    "all-nan": (ply_binary(np.full((N, 3), np.nan)), "NaN"),
    "garbage-values": (ply_binary(np.full((N, 3), 1e30)), "no scan in m or mm"),
    "mm-values-as-m": (ply_binary(PTS * 1000.0), "looks like mm"),
}

PCD_CASES = {
    "empty": (b"", "empty"),
    "short-body": (pcd_binary()[:-100], "cut short"),
    "half-body": (pcd_binary()[: len(pcd_header()) + N * 6], "cut short"),
    "declares-50M": (pcd_binary(n=50_000_000), "50000000 points"),
    "extra-body": (pcd_binary(body=PTS.astype("<f4").tobytes() * 2), "more data"),
    "width-mismatch": (pcd_binary(width=N + 1), "WIDTH x HEIGHT"),
    "size-count-mismatch": (pcd_binary(size="4 4"), "SIZE"),
    "no-z-field": (pcd_binary(fields="x y w"), "no z"),
    "bad-type-size": (pcd_binary(size="2 4 4"), "not a PCD type"),
    "unknown-data": (pcd_binary(data="binary_lzma"), "unknown PCD DATA"),
    "no-data-line": (pcd_header().replace(b"DATA binary\n", b""), "no DATA"),
    "unknown-key": (pcd_binary(extra=["COLOUR red"]), "unknown PCD header key"),
    "repeated-key": (pcd_binary(extra=["POINTS 5"]), "repeats POINTS"),
    "negative-width": (pcd_binary(width=-3), "negative"),
    "points-text": (pcd_binary().replace(b"POINTS 2000", b"POINTS many"), "not a whole number"),
    "zero-points": (pcd_header(0), "no points"),
    "header-not-utf8": (pcd_binary().replace(b"# .PCD v0.7", b"# \xff\xfe PCD"), "not text"),
    "random-bytes": (bytes(np.random.default_rng(2).integers(0, 256, 3000, dtype=np.uint8)), "PCD"),
    "ascii-cut": (pcd_ascii(ROWS[:100]), "cut short"),
    "ascii-text-value": (pcd_ascii([*ROWS[:3], "1 2 x", *ROWS[4:]]), "not a number"),
    "ascii-long-row": (pcd_ascii([*ROWS[:3], "1 2 3 4", *ROWS[4:]]), "row 4 has 4 values"),
    "ascii-extra-rows": (pcd_ascii(ROWS + ROWS[:3]), "more rows"),
    "compressed-wrong-size": (
        pcd_header(data="binary_compressed") + struct.pack("<II", 10, 99) + b"\0" * 10,
        "unpacks to 99 bytes",
    ),
    "compressed-cut": (
        pcd_header(data="binary_compressed") + struct.pack("<II", 5000, N * 12) + b"\0" * 10,
        "cut short",
    ),
    # sizes right, LZF data garbage: passes the header checks, Open3D fails (and prints: silenced)
    "compressed-garbage": (
        pcd_header(data="binary_compressed") + struct.pack("<II", 400, N * 12) + b"\xff" * 400,
        "declares 2000 points but 0 could be read",
    ),
    "compressed-no-sizes": (pcd_header(data="binary_compressed") + b"\0\0", "size fields"),
    "all-nan": (pcd_ascii(["nan nan nan"] * N), "NaN"),
    "garbage-values": (pcd_binary(body=np.full((N, 3), 3e35, "<f4").tobytes()), "no scan in m or mm"),
}


@pytest.fixture(scope="module")
def good_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("good")
    files = {
        "a.ply": GOOD_PLY,
        "b.ply": ply_ascii(),
        "c.pcd": GOOD_PCD,
        "d.pcd": pcd_ascii(),
        "e.ply": ply_binary(order=">", typ="f8"),
    }
    for name, data in files.items():
        (d / name).write_bytes(data)
    return d


@pytest.mark.parametrize("name", ["a.ply", "b.ply", "c.pcd", "d.pcd", "e.ply"])
def test_the_corpus_bases_are_valid_files(good_files, name):
    """The malformed files are mutations of these: each is read intact (so each refusal below is
    caused by its one defect)."""
    cloud = read_cloud(good_files / name)
    assert np.allclose(cloud.points, PTS, atol=1e-5)


@pytest.mark.parametrize("case", sorted(PLY_CASES))
def test_seam_refuses_a_malformed_ply(tmp_path, capfd, case):
    data, words = PLY_CASES[case]
    f = tmp_path / f"{case}.ply"
    f.write_bytes(data)
    assert_refused(capfd, ["seam", f, "-o", tmp_path / "path.json"], 2, str(f), words)
    assert not (tmp_path / "path.json").exists()


@pytest.mark.parametrize("case", sorted(PCD_CASES))
def test_seam_refuses_a_malformed_pcd(tmp_path, capfd, case):
    data, words = PCD_CASES[case]
    f = tmp_path / f"{case}.pcd"
    f.write_bytes(data)
    assert_refused(capfd, ["seam", f, "-o", tmp_path / "path.json"], 2, str(f), words)
    assert not (tmp_path / "path.json").exists()


def test_seam_refuses_other_formats_and_missing_files(tmp_path, capfd):
    (tmp_path / "cloud.xyz").write_text("0 0 0\n")
    assert_refused(capfd, ["seam", tmp_path / "cloud.xyz", "-o", tmp_path / "p.json"], 2, "unsupported")
    assert_refused(capfd, ["seam", tmp_path / "absent.ply", "-o", tmp_path / "p.json"], 2, "not found")
    (tmp_path / "dir.ply").mkdir()
    assert_refused(capfd, ["seam", tmp_path / "dir.ply", "-o", tmp_path / "p.json"], 2, "not found")


@pytest.mark.parametrize(
    "case", ["cut-at-half", "declares-50M-binary", "ascii-text-value", "header-not-utf8"]
)
def test_reconstruct_refuses_a_malformed_scan(tmp_path, capfd, case):
    """A scan of a scans.json is read by the same checked reader."""
    (tmp_path / "000.ply").write_bytes(GOOD_PLY)
    (tmp_path / "001.ply").write_bytes(PLY_CASES[case][0])
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.0, 0.5]
    recs = [{"cloud": f"00{i}.ply", "T_base_flange": pose.tolist(), "stamp": float(i)} for i in range(2)]
    (tmp_path / "scans.json").write_text(
        json.dumps({"schema": "weldcell/posed-scans@1", "units": "m", "scans": recs})
    )
    args = ["reconstruct", tmp_path, "-o", tmp_path / "m.ply", "--mount", "0,0,0.1,0,0,0"]
    assert_refused(capfd, args, 2, "001.ply", PLY_CASES[case][1])
    assert not (tmp_path / "m.ply").exists()


@pytest.mark.parametrize("case", ["cut-at-half", "declares-50M-binary", "ascii-cut", "count-text", "no-z"])
def test_phoxi_file_reader_refuses_a_malformed_ply(tmp_path, case):
    from weldcell.plugins.phoxi.ply import read_ply_grid

    f = tmp_path / "scan.ply"
    f.write_bytes(PLY_CASES[case][0])
    with pytest.raises(DataError) as e:
        read_ply_grid(f)
    assert PLY_CASES[case][1] in e.value.message and e.value.fix


def test_declared_count_must_match_what_open3d_reads(tmp_path, monkeypatch):
    """Should the library read fewer points than the header declares, the file is refused."""
    import open3d as o3d

    f = tmp_path / "a.ply"
    f.write_bytes(GOOD_PLY)
    real = o3d.io.read_point_cloud
    monkeypatch.setattr(o3d.io, "read_point_cloud", lambda *a, **k: real(*a, **k).select_by_index(range(10)))
    with pytest.raises(DataError, match="declares 2000 points but 10 could be read"):
        load_cloud_file(f)
    assert isinstance(PointCloud(PTS), PointCloud)


def test_native_output_is_kept_off_the_terminal(capfd):
    """What a native library writes to file descriptors 1 and 2 while a file is read is captured (for
    the error message), not shown."""
    import ctypes
    import os

    from weldcell.sdk.cloudfile import quiet_native_output

    capfd.readouterr()
    with quiet_native_output() as said:
        os.write(2, b"\x1b[1;33m[Open3D WARNING] Read PLY failed\x1b[0m\n\x00\xff raw\n")
        libc = ctypes.CDLL(None)
        libc.printf(b"ply_read: buffered stdout\n")
    out = capfd.readouterr()
    assert out.out == "" and out.err == ""
    assert said == ["Read PLY failed raw ply_read: buffered stdout"]
    os.write(2, b"after\n")  # the descriptors are restored
    assert capfd.readouterr().err == "after\n"
