"""Open an HTML report in headless Chromium (Debian's ``chromium`` package), as a person opens it from the
run folder (``file://``, no server, no network): screenshot it and check the page.

    .venv/bin/python benchmarks/report_screenshot.py runs/cell1-sim-.../report/report.html -o shot.png
    .venv/bin/python benchmarks/report_screenshot.py --demo -o /tmp/report.png   # build a demo report first

Prints what the browser saw: console errors, requests that left the file, the 3-D views rendered
(plotly's WebGL canvas), tables, the verdict, and the time to load. Exit 1 when the page has a console
error, touched the network, or a 3-D view did not render.

The browser is driven over the Chrome DevTools protocol (its websocket, with the ``websockets``
package); tests/sdk/test_html_report.py uses :func:`inspect_page` from here.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM_NAMES = ("chromium", "chromium-headless-shell", "chromium-browser", "google-chrome")

# what the page shows, read from its DOM once plotly has drawn (see weldcell.sdk.html_report)
_DOM_PROBE = """JSON.stringify({
  scenes: document.querySelectorAll('.wc-scene').length,
  plotly_divs: document.querySelectorAll('.wc-scene .plotly-graph-div').length,
  scenes_drawn: Array.from(document.querySelectorAll('.wc-scene .plotly-graph-div')).filter(
      d => d.querySelector('.gl-container canvas') && d.querySelector('.main-svg')).length,
  webgl_missing: document.body.innerText.includes('WebGL is not supported'),
  tables: document.querySelectorAll('table.wc-table').length,
  table_rows: Array.from(document.querySelectorAll('table.wc-table')).map(t => t.tBodies[0].rows.length),
  images: Array.from(document.images).filter(i => i.complete && i.naturalWidth > 0).length,
  images_total: document.images.length,
  verdict: (document.querySelector('#verdict') || {}).className || null,
  verdict_first: (document.querySelector('main > section') || {}).id === 'verdict',
  title: document.title,
})"""


@dataclass
class PageCheck:
    """What headless Chromium saw on a page."""

    console_errors: list[str] = field(default_factory=list)
    outside_requests: list[str] = field(default_factory=list)
    dom: dict = field(default_factory=dict)
    load_seconds: float = 0.0
    screenshot: Path | None = None


def find_chromium() -> str | None:
    """The path of a Chromium binary, or None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class _Cdp:
    """A minimal DevTools-protocol client: calls with ids, events collected."""

    def __init__(self, ws) -> None:
        self.ws, self.next_id, self.pending, self.events = ws, 0, {}, []
        self.reader = asyncio.get_running_loop().create_task(self._read())

    async def _read(self) -> None:
        async for raw in self.ws:
            msg = json.loads(raw)
            if "id" in msg and msg["id"] in self.pending:
                self.pending.pop(msg["id"]).set_result(msg)
            else:
                self.events.append(msg)

    async def call(self, method: str, session: str | None = None, **params):
        self.next_id += 1
        fut = asyncio.get_running_loop().create_future()
        self.pending[self.next_id] = fut
        msg = {"id": self.next_id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        await self.ws.send(json.dumps(msg))
        reply = await fut
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply.get("result", {})

    async def wait_event(self, method: str, timeout: float) -> dict:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            for e in self.events:
                if e.get("method") == method:
                    return e
            await asyncio.sleep(0.05)
        raise TimeoutError(f"no {method} within {timeout} s")


def _errors(events: list[dict]) -> list[str]:
    out = []
    for e in events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            out.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            out.append(
                "console.error: " + " ".join(str(a.get("value", a.get("description"))) for a in p["args"])
            )
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            out.append(f"log: {p['entry'].get('text')} ({p['entry'].get('url', '')})")
    return out


def _outside(events: list[dict]) -> list[str]:
    urls = [e["params"]["request"]["url"] for e in events if e.get("method") == "Network.requestWillBeSent"]
    return [u for u in urls if not u.startswith(("file:", "data:", "blob:", "about:"))]


async def _inspect(ws_url, url, screenshot, timeout, full_page) -> PageCheck:
    import websockets

    check = PageCheck()
    async with websockets.connect(ws_url, max_size=None) as ws:
        cdp = _Cdp(ws)
        target = await cdp.call("Target.createTarget", url="about:blank")
        sid = (await cdp.call("Target.attachToTarget", targetId=target["targetId"], flatten=True))[
            "sessionId"
        ]
        for domain in ("Page", "Runtime", "Log", "Network"):
            await cdp.call(f"{domain}.enable", session=sid)
        t0 = time.monotonic()
        await cdp.call("Page.navigate", session=sid, url=url)
        await cdp.wait_event("Page.loadEventFired", timeout)
        dom: dict = {}
        while time.monotonic() - t0 < timeout:  # plotly draws after load: wait until every view is drawn
            res = await cdp.call("Runtime.evaluate", session=sid, expression=_DOM_PROBE, returnByValue=True)
            dom = json.loads(res["result"]["value"])
            if dom["scenes_drawn"] >= dom["scenes"] or dom["webgl_missing"]:
                break
            await asyncio.sleep(0.1)
        check.load_seconds = time.monotonic() - t0
        await asyncio.sleep(0.3)  # late console messages
        check.dom = dom
        if screenshot is not None:
            params: dict = {"format": "png"}
            if full_page:
                size = (await cdp.call("Page.getLayoutMetrics", session=sid))["cssContentSize"]
                params.update(
                    captureBeyondViewport=True,
                    clip={"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1},
                )
            shot = await cdp.call("Page.captureScreenshot", session=sid, **params)
            Path(screenshot).write_bytes(base64.b64decode(shot["data"]))
            check.screenshot = Path(screenshot)
        check.console_errors = _errors(cdp.events)
        check.outside_requests = _outside(cdp.events)
        cdp.reader.cancel()
    return check


def inspect_page(
    html: str | Path,
    screenshot: str | Path | None = None,
    *,
    chromium: str | None = None,
    width: int = 1280,
    height: int = 900,
    timeout: float = 60.0,
    full_page: bool = True,
) -> PageCheck:
    """Load ``html`` from its ``file://`` URL in headless Chromium; return what the page did and shows.
    ``screenshot``: write a PNG of the whole page (``full_page``) or of the first screen.

    Software WebGL (SwiftShader) draws the 3-D views with no GPU. Raises FileNotFoundError when no
    Chromium is installed, TimeoutError when the page does not load in ``timeout`` seconds.
    """
    chromium = chromium or find_chromium()
    if chromium is None:
        raise FileNotFoundError("no chromium binary (Debian: apt-get install chromium)")
    url = Path(html).resolve().as_uri()
    with tempfile.TemporaryDirectory(prefix="wc-chromium-") as profile:
        args = [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--enable-unsafe-swiftshader",
            "--use-angle=swiftshader",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",
            "--disable-component-update",
            f"--user-data-dir={profile}",
            "--remote-debugging-port=0",
            "--remote-debugging-address=127.0.0.1",
            f"--window-size={width},{height}",
            "about:blank",
        ]
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            t_end = time.monotonic() + timeout
            while not (port_file.is_file() and len(port_file.read_text().splitlines()) >= 2):
                if proc.poll() is not None:
                    raise RuntimeError(f"{chromium} exited with {proc.returncode} before it listened")
                if time.monotonic() > t_end:
                    raise TimeoutError("chromium did not open its DevTools port")
                time.sleep(0.05)
            port, path = port_file.read_text().splitlines()[:2]
            ws_url = f"ws://127.0.0.1:{port}{path}"
            return asyncio.run(_inspect(ws_url, url, screenshot, timeout, full_page))
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("html", nargs="?", type=Path, help="report.html to open")
    ap.add_argument("-o", "--output", type=Path, default=Path("report_screenshot.png"))
    ap.add_argument("--demo", action="store_true", help="build a demo report next to the screenshot first")
    ap.add_argument("--width", type=int, default=1280)
    a = ap.parse_args()
    html = a.html
    if a.demo:
        html = demo_report(a.output.with_suffix(".html"))
    if html is None:
        ap.error("give a report.html or --demo")
    check = inspect_page(html, a.output, width=a.width)
    d = check.dom
    print(f"page            {html} ({html.stat().st_size / 1e6:.1f} MB)")
    print(f"loaded + drawn  {check.load_seconds:.2f} s")
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
