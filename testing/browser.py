"""Open an HTML report in headless Chromium as a person opens it from the run folder (``file://``, no
server, no network) and check what the page did and shows: console errors, requests that left the file,
the 3-D views drawn (plotly's WebGL canvas, software-rendered by SwiftShader), tables, pictures, the verdict.

Used by the report tests of every job and by benchmarks/report_screenshot.py::

    from weldcell.testing.browser import assert_report_page, needs_chromium

    @needs_chromium
    def test_my_jobs_page(tmp_path):
        check = assert_report_page(run / "report" / "report.html", tmp_path / "shot.png")
        assert check.dom["tables"] >= 3

The browser is Debian's ``chromium`` package, driven over the Chrome DevTools protocol (its websocket,
with the ``websockets`` package).
"""

from __future__ import annotations

import asyncio
import base64
import importlib.util
import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

try:
    import pytest
except ImportError:  # benchmarks/report_screenshot.py runs without pytest
    pytest = None

CHROMIUM_NAMES = ("chromium", "chromium-headless-shell", "chromium-browser", "google-chrome")

# what the page shows, read from its DOM once plotly has drawn (see weldcell.sdk.html_report)
_DOM_PROBE = """JSON.stringify({
  scenes: document.querySelectorAll('.wc-scene').length,
  plotly_divs: document.querySelectorAll('.wc-scene .plotly-graph-div').length,
  scenes_drawn: Array.from(document.querySelectorAll('.wc-scene .plotly-graph-div')).filter(
      d => d.querySelector('.gl-container canvas') && d.querySelector('.main-svg')).length,
  webgl_missing: document.body.innerText.includes('WebGL is not supported'),
  scene_notes: Array.from(document.querySelectorAll('.wc-scene .warn')).map(p => p.textContent),
  unpack: window.wcUnpack || null,
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
    # Chromium's helper processes can still write to the profile while it is removed after the browser
    # exited: a cleanup error must not fail the check (the folder is removed once they are gone).
    with tempfile.TemporaryDirectory(prefix="wc-chromium-", ignore_cleanup_errors=True) as profile:
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


def chromium_available() -> bool:
    """True when a Chromium binary and the ``websockets`` package (to drive it) are installed."""
    return find_chromium() is not None and importlib.util.find_spec("websockets") is not None


needs_chromium = (
    None
    if pytest is None
    else pytest.mark.skipif(
        not chromium_available(),
        reason="no Chromium installed (Debian: apt-get install chromium; bootstrap.sh installs it) "
        "or no websockets package (to drive it)",
    )
)
"""A pytest mark: skip (with the reason) when no Chromium can be driven."""


def assert_report_page(
    html: str | Path,
    screenshot: str | Path | None = None,
    *,
    verdict: str | None = None,
    timeout: float = 90.0,
    full_page: bool = False,
) -> PageCheck:
    """Load a weldcell report page in headless Chromium and assert what every report must do: no console
    error, nothing fetched from outside the file, the verdict first (``verdict``: its expected status),
    every 3-D view drawn, every picture shown. ``screenshot``: a PNG of the first screen (``full_page``: of
    the whole page, slower). Returns the :class:`PageCheck` for job-specific checks."""
    check = inspect_page(html, screenshot, timeout=timeout, full_page=full_page)
    d = check.dom
    assert check.console_errors == [], check.console_errors
    assert check.outside_requests == [], check.outside_requests
    assert d["verdict_first"], d
    if verdict is not None:
        assert f"verdict-{verdict}" in (d["verdict"] or ""), d["verdict"]
    assert not d["webgl_missing"], "WebGL is not available in this Chromium"
    assert d["scenes_drawn"] == d["scenes"] == d["plotly_divs"], d
    assert d["images"] == d["images_total"], d
    return check


__all__ = [
    "PageCheck",
    "assert_report_page",
    "chromium_available",
    "find_chromium",
    "inspect_page",
    "needs_chromium",
]
