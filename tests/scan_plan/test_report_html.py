"""The scan-and-plan report (plugins/scan_plan/report.py) on a synthetic V-groove: the measured torch
angles and standoff, the verdict, the files, and the HTML page in a real browser."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from weldcell.plugins.scan_plan.job import evaluate
from weldcell.plugins.scan_plan.report import write_report
from weldcell.plugins.scan_plan.report_figures import torch_angles
from weldcell.plugins.scan_plan.seams import SeamPolyline
from weldcell.plugins.scan_plan.torch_path import plan_torch_path, weld_path
from weldcell.sdk import artifacts
from weldcell.sdk.cloud import PointCloud

REPO = Path(__file__).resolve().parents[2]


def _groove(n: int = 120, y_offset: float = 0.0):
    """A V-groove plate along x (groove 8 mm deep, 16 mm wide), its seam line and the true seam."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([-0.12, -0.05], [0.12, 0.05], (40000, 2))
    z = -np.maximum(0.0, 0.008 - np.abs(xy[:, 1]))
    cloud = np.column_stack([xy, z + rng.normal(0, 1e-4, len(xy))])
    x = np.linspace(-0.1, 0.1, n)
    truth = np.column_stack([x, np.zeros(n), np.full(n, -0.008)])
    found = truth + [0.0, y_offset, 0.0]
    approach = np.tile([0.0, 0.0, -1.0], (n, 1))
    true_seam = SimpleNamespace(
        id="groove", points=truth, approach=approach, travel=np.tile([1.0, 0, 0], (n, 1))
    )
    seam = SeamPolyline(0, "groove", found, approach, False, 0.2)
    return cloud, seam, [("0:v-groove-butt", true_seam)]


class _Ctx:
    """What write_report uses of a RunContext."""

    def __init__(self, run_dir: Path, figures: dict) -> None:
        self.profile = SimpleNamespace(name="synthetic")
        self.run_dir, self.figures, self.timings = run_dir, figures, {"scan": 1.0, "seams (x)": 0.5}

    def path(self, name: str) -> Path:
        p = self.run_dir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_text(self, name: str, text: str) -> Path:
        return artifacts.write_text(self.path(name), text)

    def save_figure(self, fig, name: str, **kw) -> Path:
        return artifacts.save_figure(fig, self.path(name), **kw)


def _rec(n_views: int = 4):
    corr = [np.eye(4) for _ in range(n_views)]
    corr[2] = np.eye(4)
    corr[2][:3, 3] = [0.003, 0.0, 0.0]
    return SimpleNamespace(
        cloud=np.zeros((1000, 3)),
        fitness_before=[1.0, 0.8, 0.6, 0.5][:n_views],
        fitness=[1.0, 0.81, 0.7, 0.45][:n_views],
        accepted=[True, True, True, False][:n_views],
        corrections=corr,
    )


def test_torch_angles_are_measured_back_from_the_poses():
    """Work angle (AWS): the torch axis's tilt away from the joint's approach in the plane across the
    seam; travel angle: its lean towards travel (angle from the plane perpendicular to the seam)."""
    from weldcell.sdk.weldpath import SeamPath

    _, seam, _ = _groove()
    w, th, d = np.radians(20.0), np.radians(-7.0), 0.012
    a, x = np.array([0.0, 0, -1]), np.array([1.0, 0, 0])
    y = np.cross(a, x)
    z = np.sin(th) * x + np.cos(th) * (np.cos(w) * a - np.sin(w) * y)
    xt = x - (x @ z) * z
    xt /= np.linalg.norm(xt)
    T = np.tile(np.eye(4), (len(seam.points), 1, 1))
    T[:, :3, :3] = np.column_stack([xt, np.cross(z, xt), z])
    T[:, :3, 3] = seam.points - d * z
    sp = SeamPath("s0", "groove", seam.points, T, extra={"approach": seam.normals.tolist()})
    work, travel, standoff = torch_angles(sp)
    assert np.degrees(work) == pytest.approx(20.0, abs=0.01)
    assert np.degrees(travel) == pytest.approx(-7.0, abs=0.01)
    assert standoff == pytest.approx(d, abs=1e-4)


def _write(tmp_path: Path, figures: dict, y_offset: float = 0.0005):
    cloud, seam, gt = _groove(y_offset=y_offset)
    path = weld_path([seam], [plan_torch_path(seam, standoff=0.015, travel_angle=np.radians(10))])
    path.metrics = evaluate(path, gt, 0.015)
    ctx = _Ctx(
        tmp_path, {"hand_eye_source": "handeye.json", "programs": ["programs/weld_path.script"], **figures}
    )
    write_report(ctx, [1, 2, 3, 4], _rec(), PointCloud(cloud), None, path, gt, notes=["a note"])
    return tmp_path


@pytest.fixture(scope="module")
def refused_run(tmp_path_factory):
    """One report, written once for the tests below: execution refused, a seam 0.5 mm off the truth."""
    return _write(
        tmp_path_factory.mktemp("run"), {"execute": {"status": "refused", "reason": "seam s0: out of reach"}}
    )


def test_report_files_verdict_and_seam_table(refused_run):
    run = refused_run
    report = run / "report"
    for name in ("report.html", "report.md", "seams.png", "seam_s0.png", "seam_error.png", "fitness.png"):
        assert (report / name).stat().st_size > 1000, name
    page = (report / "report.html").read_text()
    verdict = page[page.index('id="verdict"') : page.index("</section>")]
    assert "verdict-attention" in verdict and "execution refused" in verdict
    assert "seam s0: out of reach (nothing was sent to the robot)" in verdict
    assert "view 3: the ICP correction was rejected" in verdict
    table = page[page.index('<table class="wc-table">') :]
    table = table[: table.index("</table>")]
    cells = [c.split(">", 1)[1] for c in table.split("<td")[1:]]
    cells = [c[: c.index("</td>")] for c in cells]
    # seam, joint, length, points, poses, work, travel, standoff, truth, RMS, max, orientation
    assert cells[0] == "s0" and cells[1] == "groove" and cells[5] == "0.0" and cells[6] == "10.0"
    assert cells[7].startswith("15.0") and cells[8] == "0:v-groove-butt/groove"
    assert float(cells[9]) == pytest.approx(0.5, abs=0.05)  # the 0.5 mm offset we put in
    md = (report / "report.md").read_text()
    assert md.startswith("# Scan-and-plan report\n\n**ATTENTION:")
    assert "![Seam s0: does the torch point into the joint" in md
    assert "report/report.html" in (run / "summary.txt").read_text()


def test_a_seam_far_from_the_truth_needs_a_person(tmp_path):
    from weldcell.plugins.scan_plan.report import verdict
    from weldcell.plugins.scan_plan.report_figures import seam_measures

    _, seam, gt = _groove(y_offset=0.004)
    path = weld_path([seam], [plan_torch_path(seam, standoff=0.015)])
    path.metrics = evaluate(path, gt, 0.015)
    ctx = _Ctx(tmp_path, {"execute": {"status": "done", "dry_run": True}, "hand_eye_source": "handeye.json"})
    v = verdict(ctx, _rec(), path, gt, seam_measures(path, gt))
    assert v.status == "attention" and v.headline == "1 seam found and planned; executed (dry run)"
    assert any("seam s0 strays up to 4.0 mm from the true seam" in a for a in v.attention)
    _, seam, gt = _groove(y_offset=0.0)
    path = weld_path([seam], [plan_torch_path(seam, standoff=0.015)])
    path.metrics = evaluate(path, gt, 0.015)
    rec = _rec()
    rec.accepted = [True] * 4
    v = verdict(ctx, rec, path, gt, seam_measures(path, gt))
    assert v.status == "ok" and v.attention == [] and v.refused == []


def _browser():
    spec = importlib.util.spec_from_file_location(
        "report_screenshot", REPO / "benchmarks" / "report_screenshot.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("report_screenshot", mod)
    spec.loader.exec_module(mod)
    return mod


def test_the_scan_and_plan_page_in_chromium(refused_run):
    """report.html opened from its file:// URL: no console error, nothing fetched from outside the file,
    the 3-D view drawn (WebGL canvas), the tables and every picture shown, the verdict first."""
    browser = _browser()
    if browser.find_chromium() is None:
        pytest.skip("no Chromium installed (Debian: apt-get install chromium; bootstrap.sh installs it)")
    pytest.importorskip("websockets", reason="the browser is driven over its DevTools websocket")
    run = refused_run
    check = browser.inspect_page(run / "report" / "report.html", run / "screenshot.png", full_page=False)
    assert check.console_errors == [] and check.outside_requests == []
    d = check.dom
    assert d["verdict_first"] and d["scenes_drawn"] == d["scenes"] == 1
    assert d["tables"] == 3 and d["table_rows"][0] == 1  # seams, ICP per view, files
    assert d["images"] == d["images_total"] == 4
    assert not d["webgl_missing"]
    png = (run / "screenshot.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000  # the first screen, drawn
