"""The localize-and-weld report page (plugins/localize/report.py, ``report/report.html``) on the job's real
outputs: the small-frame run of tests/localize/test_job.py, loaded in headless Chromium; and the verdict
of the same run when members, welds or the fit itself go wrong."""

from __future__ import annotations

import copy
import re
from types import SimpleNamespace

import numpy as np
import pytest
from weldcell.plugins.localize import report
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.testing.browser import assert_report_page, needs_chromium

from .test_job import write_profile


@pytest.fixture(scope="module")
def cell3_run(tmp_path_factory):
    """The job run once on test_job.py's small frame (30 mm line spacing: 40 mm leaves a rung unseen),
    with the report's own inputs kept."""
    folder = tmp_path_factory.mktemp("cell3-report")
    seen: dict = {}
    real = report.write_html

    def spy(ctx, *args):
        seen["args"], seen["figures"] = args, copy.deepcopy(ctx.figures)
        seen["settings"] = ctx.stage_settings("localize")
        return real(ctx, *args)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(report, "write_html", spy)
        run, result = run_job(
            write_profile(folder, spacing="30 mm"), get_plugin_manager(), runs_dir=folder / "runs"
        )
    assert result["status"] == "ok", result.get("error")
    return run, seen


def _page(run) -> str:
    return (run / "report" / "report.html").read_text(encoding="utf-8")


def test_the_page_has_the_verdict_placement_members_welds_and_3d_view(cell3_run):
    run, seen = cell3_run
    page = _page(run)
    assert page.index('id="verdict"') < page.index('class="wc-section"')
    assert re.search(r'class="verdict verdict-(ok|attention)"', page)
    assert "Part localized, 4 welds re-planned" in page and "4 seams welded" in page
    for caption in ("Placement found", "Covariance of (x, y, θ)", "Per-member residuals", "Per-weld status"):
        assert caption in page, caption
    assert "error against truth (simulation)" in page and page.count('class="wc-scene"') == 1
    for member in ("rail-a", "rail-b", "rung-1", "rung-2"):
        assert f"<td>{member}</td>" in page
    # the terminal reader's files stay, and point to the page
    assert "report/report.html" in (run / "report.md").read_text()
    assert (run / "localization.png").stat().st_size > 500


@needs_chromium
def test_the_page_loads_in_chromium_with_no_error(cell3_run, tmp_path):
    run, _ = cell3_run
    check = assert_report_page(run / "report" / "report.html", tmp_path / "cell3.png")
    d = check.dom
    assert d["scenes_drawn"] == 1 and d["tables"] == 4
    assert d["table_rows"][2] == 4 and d["table_rows"][3] == 4  # four members, four welds
    assert d["images"] == 4  # members, localization, inspection, scan


def _ctx(run, tmp_path, seen):
    out = tmp_path / "run"

    def path(name):
        src = run / name
        return src if src.suffix == ".png" else out / name

    return SimpleNamespace(
        profile=SimpleNamespace(name="cell3-test"),
        run_dir=out,
        figures=seen["figures"],
        stage_settings=lambda name: seen["settings"],
        path=path,
    )


def test_the_verdict_names_what_needs_a_person_and_what_was_refused(cell3_run, tmp_path):
    run, seen = cell3_run
    template, plan, scan, edges, loc, path, truth = seen["args"]
    bad = copy.deepcopy(loc)
    bad.members[1].status = "outside_tolerance"
    bad.members[1].offset = np.array([0.003, 0.001])
    bad.welds[0]["status"] = "uncertain"
    page = report.write_html(_ctx(run, tmp_path, seen), template, plan, scan, edges, bad, path, truth)
    page = page.read_text()
    assert 'class="verdict verdict-attention"' in page
    assert f"member {bad.members[1].id} is 3.2 mm" in page and "OUT OF TOLERANCE" in page
    assert f"weld {bad.welds[0]['id']}: the scan places it only to" in page
    assert '<tr class="bad">' in page and '<tr class="warn">' in page

    failed = copy.deepcopy(loc)
    failed.status, failed.message = "ambiguous", "ambiguous: two distinct placements fit almost equally"
    page = report.write_html(_ctx(run, tmp_path, seen), template, plan, scan, edges, failed, None, truth)
    page = page.read_text()
    assert 'class="verdict verdict-failed"' in page and "Localization ambiguous: nothing welded" in page
    assert "two distinct placements" in page and "weld this workpiece by hand" in page
