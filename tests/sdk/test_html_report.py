"""The self-contained HTML report (weldcell.sdk.html_report), checked as HTML and in a real browser.

The browser tests load the page from its file:// URL in headless Chromium (Debian's ``chromium``),
collect console errors and network requests over the DevTools protocol, and read the DOM once plotly
has drawn (benchmarks/report_screenshot.py). They skip only when no Chromium is installed.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from weldcell.sdk.html_report import Cell, HtmlReport, Scene3D, decimate, format_value

REPO = Path(__file__).resolve().parents[2]


def _browser():
    spec = importlib.util.spec_from_file_location(
        "report_screenshot", REPO / "benchmarks" / "report_screenshot.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("report_screenshot", mod)  # dataclasses resolve annotations through it
    spec.loader.exec_module(mod)
    return mod


browser = _browser()
needs_chromium = pytest.mark.skipif(
    browser.find_chromium() is None or importlib.util.find_spec("websockets") is None,
    reason="no Chromium installed (Debian: apt-get install chromium; bootstrap.sh installs it) "
    "or no websockets package (to drive it)",
)


def _report(
    tmp_path: Path, *, with_scene=True, script: str = "", n_points: int = 5000, compress_js: bool = True
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(1)
    cloud = rng.uniform(-0.1, 0.1, (50000, 3)) * [1, 1, 0.05]
    seam = np.column_stack([np.linspace(-0.08, 0.08, 40), np.zeros(40), np.zeros(40)])
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, :3, 3] = seam + [0, 0, 0.015]
    rep = HtmlReport("Test <report>", "a & b", compress_js=compress_js)
    rep.set_verdict("failed", "nothing to weld", refused=["s1: out of reach <gate>"], attention=["look"])
    sec = rep.section("Seams", "intro")
    sec.table(
        ["seam", "length [mm]"],
        [["s0", 12.345], ["s1", Cell(1.5, "outlier", "an outlier")]],
        row_status=["", "bad"],
        caption="per seam",
    )
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    sec.figure(fig, "a line")
    plt.close(fig)
    if with_scene:
        sec.scene(Scene3D("part").cloud(cloud, max_points=n_points).line(seam, "s0").frames(poses, "torch"))
    page = rep.render()
    if script:  # a page with a deliberate fault, to prove the browser check sees it
        page = page.replace("</body>", f"<script>{script}</script></body>")
    out = tmp_path / "report.html"
    out.write_text(page, encoding="utf-8")
    return out


def test_page_is_self_contained_escaped_and_verdict_first(tmp_path):
    page = _report(tmp_path).read_text()
    assert page.index('id="verdict"') < page.index('class="wc-section"')  # the verdict comes first
    assert "verdict-failed" in page and "out of reach &lt;gate&gt;" in page
    assert "<title>Test &lt;report&gt;</title>" in page
    # nothing loaded from outside the file: no src/href to http(s), plotly.js inline, pictures as data URIs
    markup = re.sub(r"<script>.*?</script>", "", page, flags=re.S)  # the page's own tags
    assert not re.search(r"""(src|href)=["']?(https?:)?//""", markup)
    assert "<script src" not in page and "<link" not in page
    assert "data:image/png;base64," in page
    assert page.count("plotly.js v") >= 1 and page.count("<script") >= 2
    assert 'class="num outlier" title="an outlier"' in page and '<tr class="bad">' in page


def test_plotly_is_packed_whole_and_the_view_waits_for_it(tmp_path):
    """The bundled plotly.js is gzip + base64 in a block the browser does not run: it unpacks to exactly
    the installed plotly's bundle, and the 3-D view's plotly call is deferred until it is unpacked."""
    import base64
    import gzip

    from plotly.offline import get_plotlyjs

    page = _report(tmp_path).read_text()
    packed = re.search(r'<script id="wc-plotly-gz" type="application/octet-stream">([^<]*)</script>', page)
    assert gzip.decompress(base64.b64decode(packed.group(1))).decode() == get_plotlyjs()
    assert get_plotlyjs()[:5000] not in page  # not also raw
    assert page.count('<script type="text/x-wc-scene">') == 1 and "Plotly.newPlot" in page
    assert "DecompressionStream('gzip')" in page
    assert len(page) < 0.5 * len(get_plotlyjs())  # the whole page: about 2.2 MB, plotly alone is 4.8 MB
    raw = _report(tmp_path, compress_js=False).read_text()  # the old way, for any browser
    assert get_plotlyjs()[:5000] in raw and "wc-plotly-gz" not in raw and "text/x-wc-scene" not in raw
    assert len(raw) > len(get_plotlyjs())


@needs_chromium
def test_a_browser_without_decompression_says_so_in_place_of_the_view(tmp_path):
    """A browser older than Chrome 80 / Firefox 113 / Safari 16.4 (no DecompressionStream): the page
    still loads, and says in the view's place why there is no 3-D view and which browsers show it."""
    html = _report(tmp_path)
    page = html.read_text().replace("<head>", "<head><script>delete window.DecompressionStream;</script>", 1)
    html.write_text(page)
    check = browser.inspect_page(html, None, timeout=8)
    assert check.dom["scenes_drawn"] == 0 and check.outside_requests == []
    assert any("could not be unpacked" in e for e in check.console_errors)
    assert check.dom["tables"] == 1 and check.dom["verdict_first"]
    (note,) = check.dom["scene_notes"]
    assert "3-D view not shown" in note and "Firefox 113+" in note


def test_no_plotly_bundle_without_a_scene(tmp_path):
    page = _report(tmp_path, with_scene=False).read_text()
    assert "plotly.js v" not in page and len(page) < 200_000


def test_render_refuses_a_report_without_verdict_and_bad_tables():
    rep = HtmlReport("x")
    rep.section("s").paragraph("p")
    with pytest.raises(ValueError, match="verdict"):
        rep.render()
    with pytest.raises(ValueError, match="status"):
        rep.set_verdict("maybe", "x")
    with pytest.raises(ValueError, match="2 values for 3 columns"):
        rep.section("t").table(["a", "b", "c"], [[1, 2]])


def test_without_plotly_the_page_says_so_and_is_written(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "plotly.io", None)  # import plotly.io -> ImportError
    rep = HtmlReport("x")
    rep.set_verdict("ok", "fine")
    rep.section("3-D").scene(Scene3D("part").cloud(np.zeros((10, 3))))
    page = rep.write(tmp_path / "r.html").read_text()
    assert "not shown, plotly is not installed" in page and "weldcell[report]" in page
    assert "plotly.js v" not in page


def test_decimate_bounds_the_count_and_keeps_the_extent():
    rng = np.random.default_rng(0)
    dense = rng.normal(0, 0.002, (80000, 3))  # a dense blob near a camera ...
    sparse = rng.uniform(-0.2, 0.2, (20000, 3))  # ... and the rest of the part
    P = np.vstack([dense, sparse, [[np.nan, 0, 0]]])
    idx = decimate(P, 10000)
    assert len(idx) <= 10000 and np.all(np.isfinite(P[idx]))
    Q = P[idx]
    assert np.ptp(Q, axis=0).min() > 0.35  # the whole part is still covered
    assert np.mean(np.linalg.norm(Q, axis=1) < 0.01) < 0.5  # the blob no longer dominates
    assert len(decimate(P[:100], 10000)) == 100


def test_format_value():
    assert format_value(None) == "–" and format_value(float("nan")) == "–"
    assert format_value(123.456) == "123.5" and format_value(0.00123) == "0.00123"
    assert format_value(True) == "yes" and format_value(7) == "7"


def test_write_is_atomic_and_follows_the_umask(tmp_path):
    import os

    old = os.umask(0o027)
    try:
        out = HtmlReport("x")
        out.set_verdict("ok", "fine")
        path = out.write(tmp_path / "r" / "report.html")
    finally:
        os.umask(old)
    assert path.read_text().startswith("<!DOCTYPE html>")
    assert (path.stat().st_mode & 0o777) == 0o640
    assert [p.name for p in path.parent.iterdir()] == ["report.html"]  # no temporary left behind


@needs_chromium
def test_the_browser_check_sees_a_console_error(tmp_path):
    """The browser check itself: a page with a deliberate script error is caught (the pages of a job
    with a 3-D view are loaded in tests/scan_plan/test_report_html.py)."""
    html = _report(tmp_path, with_scene=False, script="console.error('boom'); undefined_function();")
    check = browser.inspect_page(html, tmp_path / "shot.png")
    assert any("boom" in e for e in check.console_errors)
    assert any("undefined_function" in e for e in check.console_errors)
    assert check.outside_requests == []
    d = check.dom
    assert d["verdict_first"] and "verdict-failed" in d["verdict"]
    assert d["tables"] == 1 and d["table_rows"] == [2] and d["images"] == d["images_total"] == 1
    assert (tmp_path / "shot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
