"""The tactile-tracking report (plugins/tactile/report.py) from a synthetic recording: pictures, the
verdict of a run that ended normally and of a safe stop, and the page read back from the document."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from weldcell.plugins.tactile import report as tr
from weldcell.sdk import artifacts


class _Ctx:
    def __init__(self, run_dir: Path) -> None:
        self.profile = SimpleNamespace(name="synthetic")
        self.run_dir = run_dir

    def path(self, name: str) -> Path:
        p = self.run_dir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_json(self, name, data):
        return artifacts.write_json(self.path(name), data)


def _data(n: int = 200, lost: tuple[int, int] = (0, 0)) -> tr.TrackData:
    t = np.linspace(0.0, 10.0, n)
    x = np.linspace(0.0, 0.15, n)
    seam = np.column_stack([x, np.zeros(n), np.full(n, 0.01)])
    plan = seam + [0.0, 0.0008 * np.sin(20 * x)[0], 0.0]
    plan[:, 1] = 0.0008 * np.sin(40 * x)
    tcp = seam + [0.0, -0.001, 0.0]
    flags = np.zeros(n, bool)
    flags[lost[0] : lost[1]] = True
    twist = np.zeros((n, 6))
    twist[:, 0] = 0.015
    return tr.TrackData(
        t,
        tcp,
        tcp + [0, 0, 0.02],
        twist,
        np.full(n, 0.00098),
        np.full(n, 0.0001),
        np.full(n, 0.001),
        flags,
        plan,
        seam + [0.0, 0.00002, 0.0],
        seam + [0.0, 0.00001, 0.0],
        seam,
    )


FIG_OK = {
    "stop_reason": "contact lost",
    "final_state": "stopped",
    "safe_stop": None,
    "refined_length_mm": 150.0,
    "refined_points": 200.0,
    "duration_s": 10.0,
    "frames": 200.0,
    "marker_lost_frames": 0.0,
    "refined_seam_rms_mm": 0.013,
    "refined_seam_max_mm": 0.09,
    "plan_rms_mm": 0.55,
    "refined_coverage": 0.95,
}


def test_pictures_and_page_of_a_normal_run(tmp_path):
    ctx = _Ctx(tmp_path)
    d = _data()
    files = tr.pictures(ctx, d)
    assert set(files) == {"fig13", "deformation", "error_along_seam"}
    for f in files.values():
        assert (tmp_path / f).read_bytes()[:4] == b"\x89PNG"
    page = tr.write_html(ctx, d, {**FIG_OK, "files": files}).read_text()
    assert "verdict-ok" in page and "seam followed by touch for 150 mm" in page
    assert page.count('<img src="data:image/png;base64,') == 3 and 'class="wc-scene"' in page
    assert '<td>camera frames</td><td class="num">200</td>' in page  # counts as whole numbers


def test_a_safe_stop_and_a_lost_marker_are_in_the_verdict(tmp_path):
    fig = {**FIG_OK, "safe_stop": "safety: the seam leaves the workspace box", "marker_lost_frames": 12.0}
    status, head, found, refused, attention = tr.verdict(fig)
    assert status == "failed" and "stopped safely" in head
    assert refused == [f"safe stop: {fig['safe_stop']} (the robot stopped; everything recorded is kept)"]
    assert any("lost the marker in 12 of 200 frames" in a for a in attention)
    assert tr.verdict({**FIG_OK, "refined_coverage": 0.5})[0] == "attention"


def test_the_page_is_rebuilt_from_the_track_document(tmp_path):
    d = _data(lost=(50, 60))
    doc = {
        "planned_path": d.plan.tolist(),
        "refined_path": d.refined.tolist(),
        "seam_estimate": (d.seam_est - [0, 0, 0.004]).tolist(),
        "settings": {"track": {"tip_height": 0.004}},
        "frames": {
            "t": d.t.tolist(),
            "tcp": d.tcp.tolist(),
            "torch": d.torch.tolist(),
            "twist": d.twist.tolist(),
            "delta_n": [None if i < 3 else v for i, v in enumerate(d.delta_n.tolist())],
            "delta_t": d.delta_t.tolist(),
            "delta_d": d.delta_d.tolist(),
            "marker_lost": d.lost.tolist(),
        },
    }
    back = tr.TrackData.from_document(doc, d.truth_seam)
    np.testing.assert_allclose(back.seam_est, d.seam_est)
    assert np.isnan(back.delta_n[:3]).all() and back.lost.sum() == 10
    ctx = _Ctx(tmp_path)
    page = tr.write_html(
        ctx, back, FIG_OK, before=lambda rep: rep.section("Calibration").paragraph("cal")
    ).read_text()
    assert page.index("Calibration") < page.index("Tracking figures")
