"""Map update (§II-E end): free-space change detection and versioned maps whose unchanged local maps stay
bit-identical."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from weldcell.plugins.map_transfer.stage import MapTransfer, TransferSettings
from weldcell.plugins.mapping.map_update import View, detect_changes, start_versions, write_version
from weldcell.sdk.errors import DataError

K = SimpleNamespace(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)


def _plane(x0, x1, y0, y1, z, step=0.05):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _wall(x, y0, y1, h, step=0.05):
    y, z = np.meshgrid(np.arange(y0, y1, step), np.arange(0.0, h, step))
    return np.column_stack([np.full(y.size, x), y.ravel(), z.ravel()])


def _render(points, T_world_cam):
    """Z-buffer depth image of a point cloud (the simulated key frame's depth)."""
    Ti = np.linalg.inv(T_world_cam)
    P = points @ Ti[:3, :3].T + Ti[:3, 3]
    P = P[P[:, 2] > 0.1]
    u = np.round(P[:, 0] / P[:, 2] * K.fx + K.cx).astype(int)
    v = np.round(P[:, 1] / P[:, 2] * K.fy + K.cy).astype(int)
    ok = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    d = np.full((K.height, K.width), np.inf)
    np.minimum.at(d, (v[ok], u[ok]), P[ok, 2])
    d[~np.isfinite(d)] = 0.0
    return d.astype(np.float32)


def _cam(x):
    """A camera at (x, 1, 1) looking along +y (optical z = world y, x = world x, y = -world z)."""
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    T[:3, 3] = [x, -3.0, 1.0]
    return T


@pytest.fixture
def scene():
    ground = _plane(0.0, 12.0, 0.0, 6.0, 0.0, 0.08)
    back = np.column_stack(
        [
            _plane(0, 12, 0, 2.5, 0, 0.05)[:, 0],
            np.full(len(_plane(0, 12, 0, 2.5, 0, 0.05)), 6.0),
            _plane(0, 12, 0, 2.5, 0, 0.05)[:, 1],
        ]
    )
    old_wall = _wall(2.0, 2.0, 3.0, 1.5)  # removed before the new visit
    new_box = _wall(9.0, 2.0, 3.0, 1.2)  # added before the new visit
    prior = np.vstack([ground, back, old_wall])
    current = np.vstack([ground, back, new_box]) + np.random.default_rng(1).normal(0, 0.003, (1, 3))
    views_p = [View(_cam(x), _render(prior, _cam(x)), K) for x in (1.0, 3.0, 6.0, 9.0, 11.0)]
    views_c = [View(_cam(x), _render(current, _cam(x)), K) for x in (1.0, 3.0, 6.0, 9.0, 11.0)]
    return prior, current, views_p, views_c, len(ground) + len(back)


def test_changes_found_from_free_space(scene):
    prior, current, vp, vc, n_static = scene
    ch = detect_changes(prior, current, vp, vc, change_distance=0.15, min_points=20, max_depth=10.0)
    removed = prior[ch.removed]
    added = current[ch.added]
    assert len(removed) > 100 and np.all(np.abs(removed[:, 0] - 2.0) < 0.2)  # the old wall, nothing else
    assert len(added) > 100 and np.all(np.abs(added[:, 0] - 9.0) < 0.2)  # the new box, nothing else
    assert {g["kind"] for g in ch.groups} == {"added", "removed"}


def _segmented(root, prior, transfer):
    w = transfer.writer(root, cut={"max_distance": 5.0})
    for i, (x0, x1) in enumerate([(-1, 4), (4, 8), (8, 13)]):
        m = (prior[:, 0] >= x0) & (prior[:, 0] < x1)
        T = np.eye(4)
        T[:3, 3] = [x0, 0.0, 0.0]
        w.add(i, prior[m] - T[:3, 3], None, T, 4.0, [i])
    w.finish()


@pytest.mark.parametrize("encoding", ["quantised", "draco", "ply"])
def test_new_version_keeps_unchanged_segments_bit_identical(scene, tmp_path, encoding):
    prior, current, vp, vc, _ = scene
    transfer = MapTransfer(TransferSettings(encoding=encoding))
    _segmented(tmp_path / "map", prior, transfer)
    v1 = start_versions(transfer, tmp_path / "map", tmp_path / "versions")
    from weldcell.plugins.mapping.map_update import prior_points

    p1, _ = prior_points(transfer, v1)
    ch = detect_changes(p1, current, vp, vc, 0.15, 20, 10.0)
    entry = write_version(transfer, tmp_path / "versions", ch, current, None, {"status": "ok"})
    assert entry["version"] == "v2" and entry["changed_segments"] == [0, 2]
    assert entry["unchanged_segments"] == [1]
    m1 = json.loads((v1 / "manifest.json").read_text())["segments"]
    m2 = json.loads((tmp_path / "versions" / "v2" / "manifest.json").read_text())["segments"]
    f1 = (v1 / m1[1]["file"]).read_bytes()
    assert (tmp_path / "versions" / "v2" / m2[1]["file"]).read_bytes() == f1  # unchanged: byte for byte
    assert (tmp_path / "map" / m1[1]["file"]).read_bytes() == f1
    p2, _ = prior_points(transfer, tmp_path / "versions" / "v2")

    def wall(P, x):
        return int(np.sum((np.abs(P[:, 0] - x) < 0.03) & (P[:, 1] > 2.0) & (P[:, 1] < 3.0) & (P[:, 2] > 0.1)))

    assert wall(p1, 2.0) > 300 and wall(p2, 2.0) < 0.1 * wall(
        p1, 2.0
    )  # the old wall is gone (edges seen once stay)
    assert wall(p1, 9.0) == 0 and wall(p2, 9.0) > 300  # the new box is in v2
    idx = json.loads((tmp_path / "versions" / "index.json").read_text())
    assert idx["current"] == "v2" and [v["version"] for v in idx["versions"]] == ["v1", "v2"]


def test_a_map_with_one_segment_updates_and_an_empty_one_is_refused(scene, tmp_path):
    prior, current, vp, vc, _ = scene
    transfer = MapTransfer(TransferSettings(encoding="ply"))
    w = transfer.writer(tmp_path / "one")
    w.add(0, prior, None, np.eye(4), 12.0, [0])
    w.finish()
    start_versions(transfer, tmp_path / "one", tmp_path / "v")
    ch = detect_changes(prior, current, vp, vc, 0.15, 20, 10.0)
    assert write_version(transfer, tmp_path / "v", ch, current, None)["changed_segments"] == [0]
    transfer.writer(tmp_path / "empty").finish()
    with pytest.raises(DataError, match="no local maps"):
        start_versions(transfer, tmp_path / "empty", tmp_path / "v_empty") and write_version(
            transfer, tmp_path / "v_empty", ch, current, None
        )
