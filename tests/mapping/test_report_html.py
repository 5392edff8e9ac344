"""The map job's report page (plugins/mapping/report.py, ``report/report.html``) on the job's real outputs
(a 4 m route of profiles/cell4-map-sim.toml), loaded in headless Chromium; and its verdict when tracking
was lost, relocalization failed or the second visit found changes."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from types import SimpleNamespace

import pytest
from weldcell.plugins.mapping.report import write_html
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.testing.browser import assert_report_page, needs_chromium

PROFILE = Path(__file__).resolve().parents[2] / "profiles" / "cell4-map-sim.toml"
SHORT = (
    "[job.settings]\nroute = { length = 4.0, cruise_speed = 1.0 }\n"
    "revisit = { enabled = false }\nsegmentation = { max_distance = 1.5, evaluate_ae = false }\n"
)


@pytest.fixture(scope="module")
def map_run(tmp_path_factory):
    """A 4 m route of the shipped profile, cut into local maps every 1.5 m (the installed plugins)."""
    folder = tmp_path_factory.mktemp("cell4-report")
    p = folder / "short.toml"
    p.write_text(f'extends = "{PROFILE}"\n{SHORT}')
    run, result = run_job(p, get_plugin_manager(), runs_dir=folder / "runs")
    assert result["status"] == "ok", result.get("error")
    return run, result["figures"]


def _ctx(run: Path, out: Path):
    return SimpleNamespace(
        profile=SimpleNamespace(name="cell4-test"),
        run_dir=run,
        path=lambda name: out / name if name.endswith(".html") else run / name,
    )


def test_the_map_page_and_its_verdicts(map_run, tmp_path):
    run, figures = map_run
    page = (run / "report" / "report.html").read_text(encoding="utf-8")
    assert page.index('id="verdict"') < page.index('class="wc-section"')
    assert f"map of {figures['keyframes']} key frames" in page
    for caption in (
        "Map accuracy and run figures",
        "Local maps (segments)",
        "Weld regions",
        "Estimator events",
    ):
        assert caption in page, caption
    assert "trajectory (truth, aligned)" in page and page.count('class="wc-scene"') == 1
    assert "report.html" in (run / "report" / "report.md").read_text()
    # the verified hand-over at a cut is information, not a fallback
    seg = json.loads((run / "map" / "manifest.json").read_text())["segments"]
    assert all(
        "PnP pose kept" not in e["handover"]["note"] for e in seg[1:] if e["handover"]["method"] == "verified"
    )

    # what needs a person: tracking lost, relocalization failed, changes found
    lost = copy.deepcopy(json.loads((run / "events.json").read_text()))
    lost["events"].append({"t": 3.2, "kind": "lost", "message": "too few features"})
    alt = tmp_path / "alt"
    alt.mkdir()
    for name in ("regions.json", "trajectory_keyframes.tum", "truth_keyframes.tum"):
        (alt / name).write_bytes((run / name).read_bytes())
    (alt / "events.json").write_text(json.dumps(lost))
    f2 = dict(figures, visit2={"relocalization_status": "failed", "changes": []})
    page = write_html(_ctx(alt, tmp_path / "o1"), f2).read_text()
    assert 'class="verdict verdict-attention"' in page
    assert "tracking was lost 1 time(s) (at t = 3.2 s)" in page
    assert "second visit: relocalization failed: the map was not updated from it" in page
    # a plate the views do not determine is reported, not measured by a guess
    why = "only one key frame has depth there"
    f4 = dict(figures, ae_unmeasured=[{"plate": "weld-plate-7", "reason": why}])
    page = write_html(_ctx(alt, tmp_path / "o4"), f4).read_text()
    assert "weld-plate-7 not measured: only one key frame has depth there (left out of the AE)" in page
    change = {
        "kind": "added",
        "points": 300,
        "center": [4.0, 8.0, 0.4],
        "min": [3.8, 7.8, 0],
        "max": [4.2, 8.2, 0.8],
    }
    f3 = dict(
        figures,
        visit2={
            "relocalization_status": "ok",
            "relocalization_overlap": 0.9,
            "changes": [change],
            "map_version": "v2",
        },
    )
    page = write_html(_ctx(run, tmp_path / "o2"), f3).read_text()
    assert "1 change(s) found against the map: added structure near (4.0, 8.0, 0.4) m" in page
    assert "Changes found against the map" in page and "change 1: added" in page


@needs_chromium
def test_the_map_page_loads_in_chromium_with_no_error(map_run, tmp_path):
    run, _ = map_run
    check = assert_report_page(run / "report" / "report.html", tmp_path / "cell4.png")
    d = check.dom
    assert d["scenes_drawn"] == 1 and d["tables"] >= 4 and d["images"] >= 2
