"""Interactive 3-D views of the HTML reports (plotly) and how plotly.js travels inside the page.

:class:`Scene3D` collects clouds, lines, markers and torch frames (metres in, millimetres shown);
:func:`decimate` thins a cloud evenly for the page. :func:`plotly_script` gives the ``<script>`` blocks
that carry plotly.js: raw, or gzip + base64 unpacked by the browser (:data:`LOADER`), after which every
view's own script (type :data:`SCENE_SCRIPT`) runs. :mod:`weldcell.sdk.html_report` places them.
"""

from __future__ import annotations

import base64
import functools
import gzip
import html
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

SCENE_SCRIPT = "text/x-wc-scene"  # a 3-D view's plotly call, run once plotly is unpacked

# Unpacks the gzip'd plotly.js (base64 in a non-executed <script> block) with the browser's own
# DecompressionStream, runs it as an inline script, then draws every 3-D view. Nothing is fetched:
# Blob and Response here only wrap bytes already in the page.
LOADER = """(function(){
var SCENES='script[type="%(scene)s"]';
function fail(why){
  console.error('weldcell report: the 3-D viewer could not be unpacked: '+why);
  document.querySelectorAll('.wc-scene').forEach(function(d){
    var p=document.createElement('p');p.className='warn';
    p.textContent='3-D view not shown: this browser cannot unpack it ('+why+'). Open the page in '+
      'Chrome/Edge 80+, Firefox 113+ or Safari 16.4+.';
    d.appendChild(p);});
}
function draw(){
  document.querySelectorAll(SCENES).forEach(function(s){
    var r=document.createElement('script');r.textContent=s.textContent;s.replaceWith(r);});
}
function ready(f){
  if(document.readyState==='loading'){document.addEventListener('DOMContentLoaded',f);}else{f();}
}
if(typeof DecompressionStream==='undefined'){ready(function(){fail('no DecompressionStream');});return;}
try{
  var t0=performance.now();
  var b64=document.getElementById('wc-plotly-gz').textContent, bin=atob(b64), n=bin.length;
  var bytes=new Uint8Array(n);for(var i=0;i<n;i++){bytes[i]=bin.charCodeAt(i);}
  var stream=new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
  new Response(stream).text().then(function(code){
    var t1=performance.now();
    var s=document.createElement('script');s.textContent=code;document.head.appendChild(s);
    if(typeof Plotly==='undefined'){throw new Error('plotly did not load');}
    window.wcUnpack={unpack_ms:t1-t0,run_ms:performance.now()-t1};
    ready(draw);
  }).catch(function(e){ready(function(){fail(String(e));});});
}catch(e){ready(function(){fail(String(e));});}
})();"""


@functools.lru_cache(maxsize=1)
def plotly_bundle_gz() -> tuple[str, str]:
    """plotly.js (the installed plotly's bundle) gzip-compressed and base64-encoded, and its version."""
    from plotly.offline import get_plotlyjs

    js = get_plotlyjs()
    m = re.search(r"plotly\.js v([0-9][0-9A-Za-z.\-]*)", js[:2000])
    packed = base64.b64encode(gzip.compress(js.encode("utf-8"), compresslevel=9, mtime=0)).decode("ascii")
    return packed, m.group(1) if m else "unknown"


def plotly_script(compress: bool) -> str:
    """The ``<script>`` blocks that give the page plotly.js: raw, or packed (see :data:`LOADER`)."""
    if not compress:
        from plotly.offline import get_plotlyjs

        return "<script>" + get_plotlyjs().replace("</script", "<\\/script") + "</script>"
    packed, version = plotly_bundle_gz()
    return (
        f"<!-- plotly.js v{version}, gzip + base64 ({len(packed) / 1e6:.1f} MB), unpacked in the page -->"
        f'<script id="wc-plotly-gz" type="application/octet-stream">{packed}</script>'
        f"<script>{LOADER % {'scene': SCENE_SCRIPT}}</script>"
    )


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _trace(**kw: Any) -> dict[str, Any]:
    """A plotly ``scatter3d`` trace as a plain dict (plotly itself is imported only to render);
    coordinates as float32 (plotly writes them as compact typed arrays; 0.1 um at 1 m in mm)."""
    for k in ("x", "y", "z"):
        kw[k] = np.asarray(kw[k], dtype=np.float32)
    return {"type": "scatter3d", **{k: v for k, v in kw.items() if v is not None}}


def decimate(points: np.ndarray, max_points: int, seed: int = 0) -> np.ndarray:
    """At most ``max_points`` of ``points`` (N, 3), spread evenly over the cloud: one point per voxel
    with the voxel grown until the count fits (dense regions near a camera do not dominate), then a
    seeded random subset if still needed. Returns indices into ``points``."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    ok = np.flatnonzero(np.all(np.isfinite(P), axis=1))
    if len(ok) <= max_points:
        return ok
    Q = P[ok]
    extent = np.ptp(Q, axis=0)
    vol = float(np.prod(np.maximum(extent, 1e-9)))
    area = float(sorted(np.maximum(extent, 1e-9))[-1] * sorted(np.maximum(extent, 1e-9))[-2])
    voxel = max((area / max_points) ** 0.5, (vol / max_points) ** (1 / 3) * 0.25, 1e-9)
    idx = ok
    for _ in range(40):
        cells = np.floor((Q - Q.min(axis=0)) / voxel).astype(np.int64)
        keys = np.ravel_multi_index(cells.T, tuple(cells.max(axis=0) + 1), mode="wrap")  # one int per voxel
        _, first = np.unique(keys, return_index=True)
        idx = ok[np.sort(first)]
        if len(idx) <= max_points:
            break
        voxel *= 1.25
    if len(idx) > max_points:
        idx = np.sort(np.random.default_rng(seed).choice(idx, size=max_points, replace=False))
    return idx


class Scene3D:
    """An interactive 3-D view: clouds, lines (seams), markers and short-axis frames (torch poses).

    Points are given in metres and shown in ``unit`` (``scale`` per metre). Every method returns the
    scene, so calls chain. Axes keep equal scale (``aspectmode="data"``).
    """

    AXIS_COLOURS = ("#e8590c", "#2f9e44", "#1c7ed6")  # x travel, y, z approach

    def __init__(
        self, title: str = "", *, scale: float = 1000.0, unit: str = "mm", height: int = 620
    ) -> None:
        self.title, self.scale, self.unit, self.height = title, float(scale), unit, int(height)
        self.traces: list[Any] = []

    def _xyz(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, dtype=float).reshape(-1, 3) * self.scale

    def cloud(
        self,
        points: np.ndarray,
        name: str = "cloud",
        *,
        max_points: int = 20000,
        color: str | None = None,
        size: float = 1.6,
        opacity: float = 0.75,
        seed: int = 0,
    ) -> Scene3D:
        """A point cloud (N, 3) decimated to at most ``max_points`` (:func:`decimate`); coloured by
        height (z) unless ``color`` is given."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        idx = decimate(P, max_points, seed)
        Q = self._xyz(P[idx])
        marker: dict[str, Any] = {"size": size, "opacity": opacity}
        if color is None:
            marker.update(
                color=Q[:, 2].astype(np.float32),
                colorscale="Greys",
                cmin=float(Q[:, 2].min(initial=0)) - 1e-9,
                reversescale=False,
            )
        else:
            marker["color"] = color
        shown = f"{name} ({len(idx):,} of {len(P):,} points)" if len(idx) < len(P) else name
        self.traces.append(
            _trace(
                x=Q[:, 0], y=Q[:, 1], z=Q[:, 2], mode="markers", name=shown, marker=marker, hoverinfo="skip"
            )
        )
        return self

    def line(
        self,
        points: np.ndarray,
        name: str,
        *,
        color: str = "#d62728",
        width: float = 5.0,
        dash: str | None = None,
        closed: bool = False,
    ) -> Scene3D:
        """A polyline (K, 3), e.g. a seam; ``dash`` ("dash", "dot") for e.g. the ground truth."""
        Q = self._xyz(points)
        if closed and len(Q) > 2:
            Q = np.vstack([Q, Q[:1]])
        self.traces.append(
            _trace(
                x=Q[:, 0],
                y=Q[:, 1],
                z=Q[:, 2],
                mode="lines",
                name=name,
                line={"color": color, "width": width, **({"dash": dash} if dash else {})},
                hovertemplate=f"{_e(name)}<br>%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}} {self.unit}<extra></extra>",
            )
        )
        return self

    def markers(
        self,
        points: np.ndarray,
        name: str,
        *,
        color: str = "#111",
        size: float = 4.0,
        labels: Sequence[str] | None = None,
        symbol: str = "circle",
    ) -> Scene3D:
        """Individual points, with ``labels`` shown next to them (e.g. sample ids)."""
        Q = self._xyz(points)
        self.traces.append(
            _trace(
                x=Q[:, 0],
                y=Q[:, 1],
                z=Q[:, 2],
                mode="markers+text" if labels is not None else "markers",
                name=name,
                text=list(labels) if labels is not None else None,
                textposition="top center",
                marker={"size": size, "color": color, "symbol": symbol},
            )
        )
        return self

    def frames(
        self,
        poses: np.ndarray,
        name: str = "frames",
        *,
        length: float = 0.008,
        max_frames: int = 40,
        axes: str = "xz",
    ) -> Scene3D:
        """Short axes of 4x4 poses (N, 4, 4) (at most ``max_frames``, evenly picked): x orange (travel),
        y green, z blue (approach); ``axes`` picks which are drawn; ``length`` in metres."""
        T = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
        if len(T) == 0:
            return self
        pick = np.unique(np.linspace(0, len(T) - 1, min(max_frames, len(T))).round().astype(int))
        T = T[pick]
        o = self._xyz(T[:, :3, 3])
        for k, axis in enumerate("xyz"):
            if axis not in axes:
                continue
            tip = o + T[:, :3, k] * length * self.scale
            seg = np.full((3 * len(o), 3), np.nan)
            seg[0::3], seg[1::3] = o, tip
            self.traces.append(
                _trace(
                    x=seg[:, 0],
                    y=seg[:, 1],
                    z=seg[:, 2],
                    mode="lines",
                    name=f"{name} {axis}",
                    line={"color": self.AXIS_COLOURS[k], "width": 4},
                    hoverinfo="skip",
                    legendgroup=name,
                    connectgaps=False,
                )
            )
        return self

    def figure(self) -> Any:
        """The plotly Figure of this scene."""
        import plotly.graph_objects as go

        fig = go.Figure(self.traces)
        ax = {"showbackground": False}
        fig.update_layout(
            title={"text": self.title} if self.title else None,
            height=self.height,
            margin={"l": 0, "r": 0, "t": 36 if self.title else 8, "b": 0},
            legend={"itemsizing": "constant", "x": 0.0, "y": 1.0, "bgcolor": "rgba(255,255,255,0.7)"},
            scene={
                "aspectmode": "data",
                "xaxis": {"title": {"text": f"x [{self.unit}]"}, **ax},
                "yaxis": {"title": {"text": f"y [{self.unit}]"}, **ax},
                "zaxis": {"title": {"text": f"z [{self.unit}]"}, **ax},
            },
        )
        return fig
