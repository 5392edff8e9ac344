"""``weldcell seam --report DIR`` writes the scan-and-plan job's self-contained report for one cloud:
report.html (verdict, seam table, 3-D view, cross-sections), report.md, the PNGs and summary.txt; the page
loads in headless Chromium with no console error and nothing fetched from outside the file.

The seam stage is a fixed line on the groove's root (the report is under test here; the real seam stage on
the same cloud is tested in test_scan_plan_cli.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from weldcell.sdk.cli import main
from weldcell.sdk.cloud import write_cloud
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.testing.browser import assert_report_page, needs_chromium

from .test_scan_plan_cli import SEAM_Z, FixedLinePlugin, groove_cloud


@pytest.fixture(scope="module")
def seam_report(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("seam-report")
    cloud = tmp / "groove.ply"
    write_cloud(cloud, groove_cloud(n=60_000))
    profile = tmp / "cell.toml"
    profile.write_text(
        'schema = "weldcell/profile@1"\nname = "t"\n[job]\nname = "scan-and-plan"\n'
        f'[stages.seam]\nplugin = "seam.fixed-line"\nsettings = {{ z = {SEAM_Z} }}\n'
    )
    args = ["seam", cloud, "-o", tmp / "path.json", "--export", "csv", "--report", tmp / "rep"]
    with get_plugin_manager().plugin(FixedLinePlugin(), "fixed-line-report-test"):
        res = CliRunner().invoke(main, [str(a) for a in [*args, "--profile", profile, "--no-denoise"]])
    assert res.exit_code == 0, res.output
    assert "report.html" in res.output
    return tmp / "rep"


def test_seam_report_files(seam_report):
    rep = seam_report
    for name in ("report.html", "report.md", "seams.png", "seam_s7.png", "summary.txt"):
        assert (rep / name).stat().st_size > 200, name
    page = (rep / "report.html").read_text()
    assert page.index('id="verdict"') < page.index('class="wc-scene"')  # the verdict first
    assert "verdict-ok" in page and "seam s7: groove" in page
    assert "path.json" in page and "path.csv" in page  # the files table names what the command wrote
    assert "<script" in page and "<script src=" not in page  # the JavaScript inline, nothing to fetch
    md = (rep / "report.md").read_text()
    assert md.startswith("# Seam report: groove.ply\n\n**OK:") and "![Seam s7: does the torch" in md
    assert "s7" in (rep / "summary.txt").read_text()


@needs_chromium
def test_seam_report_page_in_chromium(seam_report, tmp_path):
    check = assert_report_page(seam_report / "report.html", tmp_path / "shot.png", verdict="ok")
    d = check.dom
    assert d["scenes"] == 1 and d["tables"] == 2  # seams, files
    assert d["table_rows"][0] >= 1 and d["images"] >= 2  # overview + one cross-section per seam
    assert (tmp_path / "shot.png").read_bytes()[:4] == b"\x89PNG"
