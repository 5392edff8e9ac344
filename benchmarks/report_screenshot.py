"""Open an HTML report in headless Chromium (Debian's ``chromium`` package), as a person opens it from the
run folder (``file://``, no server, no network): screenshot it and check the page.

    .venv/bin/python benchmarks/report_screenshot.py runs/cell1-sim-.../report/report.html -o shot.png
    .venv/bin/python benchmarks/report_screenshot.py --demo -o /tmp/report.png   # build a demo report first
    .venv/bin/python benchmarks/report_screenshot.py PAGE --compare 4   # plotly.js raw vs packed, 4 each

Prints what the browser saw: console errors, requests that left the file, the 3-D views rendered
(plotly's WebGL canvas), tables, the verdict, and the time to load. Exit 1 when the page has a console
error, touched the network, or a 3-D view did not render.

The browser is driven over the Chrome DevTools protocol (its websocket, with the ``websockets``
package) by :mod:`weldcell.testing.browser`, which the report tests use too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# the browser driver is weldcell.testing.browser (shared with the report tests of every job)
from weldcell.testing.browser import PageCheck, find_chromium, inspect_page  # noqa: F401  (re-exported)


def demo_report(path: Path) -> Path:
    """A report with every kind of block, on a synthetic V-groove plate (no job run needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from weldcell.sdk.html_report import Cell, HtmlReport, Scene3D

    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.1, 0.1, (60000, 2))
    z = np.maximum(0.0, 0.008 - np.abs(xy[:, 1]))  # a V groove along x
    cloud = np.column_stack([xy, -z + rng.normal(0, 2e-4, len(xy))])
    seam = np.column_stack([np.linspace(-0.09, 0.09, 60), np.zeros(60), np.full(60, -0.008)])
    poses = np.tile(np.eye(4), (60, 1, 1))
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])
    poses[:, :3, 3] = seam + [0, 0, 0.015]
    rep = HtmlReport("Demo report", "synthetic V-groove plate")
    rep.set_verdict("ok", "1 seam found, path planned", found=["s0 groove 180 mm"])
    sec = rep.section("Seams", "One row per seam.")
    sec.table(["seam", "joint", "length [mm]", "error [mm]"], [["s0", "groove", 180.0, Cell(0.41, "ok")]])
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(seam[:, 0] * 1e3, seam[:, 2] * 1e3)
    sec.figure(fig, "The seam's height along x.")
    sec.scene(Scene3D("plate").cloud(cloud).line(seam, "s0").frames(poses, "torch s0"), "Drag to turn.")
    return rep.write(path)


def variants(html: Path) -> dict[str, Path]:
    """The page with plotly.js embedded raw and packed (gzip + base64, weldcell.sdk.html_report), same
    content otherwise: whichever of the two ``html`` is not is written beside it."""
    import re

    import weldcell.sdk.html_report as hr

    page = html.read_text(encoding="utf-8")
    raw, packed = hr._plotly_js(False), hr._plotly_js(True)
    deferred = '<script type="text/x-wc-scene">'
    if raw in page:
        other = page.replace(raw, packed)
        other = re.sub(
            r'(<div class="wc-scene">.*?)<script(?: type="text/javascript")?>',
            rf"\1{deferred}",
            other,
            flags=re.S,
        )
        out = {"raw": html, "packed": html.with_name(html.stem + "_packed.html")}
        out["packed"].write_text(other, encoding="utf-8")
    elif packed in page:
        other = page.replace(packed, raw).replace(deferred, "<script>")
        out = {"raw": html.with_name(html.stem + "_raw.html"), "packed": html}
        out["raw"].write_text(other, encoding="utf-8")
    else:
        raise SystemExit(f"{html}: no plotly.js bundle of this plotly version in the page")
    return out


def compare(html: Path, n: int) -> int:
    """Load the raw and the packed page in turn ``n`` times each; print sizes and load times."""
    import statistics

    pages = variants(html)
    times: dict[str, list[float]] = {k: [] for k in pages}
    unpack = []
    for _ in range(n):
        for k, p in pages.items():
            c = inspect_page(p, None)
            if c.console_errors or c.outside_requests or c.dom["scenes_drawn"] < c.dom["scenes"]:
                print(f"{k}: {c.console_errors} {c.outside_requests} {c.dom}")
                return 1
            times[k].append(c.load_seconds)
            if c.dom.get("unpack"):
                unpack.append(c.dom["unpack"])
    for k, p in pages.items():
        t = times[k]
        print(
            f"{k:7s} {p.stat().st_size / 1e6:5.2f} MB  loaded + drawn median {statistics.median(t):.2f} s "
            f"(min {min(t):.2f}, max {max(t):.2f}, {len(t)} loads)"
        )
    if unpack:
        print(
            "packed: unpack "
            + ", ".join(f"{u['unpack_ms'] / 1e3:.2f}" for u in unpack)
            + " s; run plotly "
            + ", ".join(f"{u['run_ms'] / 1e3:.2f}" for u in unpack)
            + " s"
        )
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("html", nargs="?", type=Path, help="report.html to open")
    ap.add_argument("-o", "--output", type=Path, default=Path("report_screenshot.png"))
    ap.add_argument("--demo", action="store_true", help="build a demo report next to the screenshot first")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument(
        "--compare", type=int, metavar="N", help="load the page with plotly.js raw and packed, N each"
    )
    a = ap.parse_args()
    if a.compare:
        return compare(a.html, a.compare)
    html = a.html
    if a.demo:
        html = demo_report(a.output.with_suffix(".html"))
    if html is None:
        ap.error("give a report.html or --demo")
    check = inspect_page(html, a.output, width=a.width)
    d = check.dom
    print(f"page            {html} ({html.stat().st_size / 1e6:.1f} MB)")
    print(f"loaded + drawn  {check.load_seconds:.2f} s")
    if d.get("unpack"):
        u = d["unpack"]
        print(f"plotly.js       unpacked in {u['unpack_ms'] / 1e3:.2f} s, ran in {u['run_ms'] / 1e3:.2f} s")
    print(f"verdict         {d.get('verdict')} (first: {d.get('verdict_first')})")
    print(f"3-D views       {d.get('scenes_drawn')} of {d.get('scenes')} drawn")
    print(f"tables          {d.get('tables')} (rows {d.get('table_rows')})")
    print(f"pictures        {d.get('images')} of {d.get('images_total')} shown")
    print(f"console errors  {len(check.console_errors)}")
    for e in check.console_errors:
        print(f"  {e}")
    print(f"network         {len(check.outside_requests)} request(s) outside the file")
    for u in check.outside_requests:
        print(f"  {u}")
    print(f"screenshot      {check.screenshot}")
    bad = check.console_errors or check.outside_requests or d.get("scenes_drawn", 0) < d.get("scenes", 0)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
