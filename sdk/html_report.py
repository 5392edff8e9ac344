"""Self-contained HTML reports: one file a person opens from the run folder, with no server and no network.

A report is a verdict first (what was found, what was refused and why, what needs a person), then
sections of details: paragraphs, tables, pictures (embedded as PNG ``data:`` URIs) and interactive 3-D
views (plotly, with its JavaScript bundled once into the file, gzip-compressed and unpacked by the
browser: see :class:`HtmlReport`). Nothing in the page loads anything from outside the file. Any job's
report uses it the same way::

    from weldcell.sdk.html_report import HtmlReport, Scene3D

    rep = HtmlReport("Scan-and-plan: cell1", subtitle="run cell1-20260101-120000")
    rep.set_verdict("attention", "2 seams found; execution refused",
                    found=["s0 fillet 120 mm"], refused=["s1: out of reach (safety gate)"],
                    attention=["check the clamp before welding s1"])
    sec = rep.section("Seams", "One row per seam, in welding order.")
    sec.table(["seam", "joint", "length [mm]"], [["s0", "fillet", 120.0]], caption="...")
    sec.figure(matplotlib_figure, "What this picture answers, in one sentence.")
    sec.scene(Scene3D("Part").cloud(points).line(seam_points, "s0").frames(poses, "torch s0"))
    rep.write(run_dir / "report" / "report.html")   # atomic, durable

Units: a :class:`Scene3D` takes points in metres (SI inside) and shows millimetres by default.
The rendered page is stable for tests: the verdict is ``<section id="verdict" class="verdict
verdict-<status>">``, each table a ``<table class="wc-table">``, each 3-D view a ``<div
class="wc-scene">`` holding plotly's ``<div class="plotly-graph-div">``. The 3-D views and plotly.js's
packing are in :mod:`weldcell.sdk.report_scene`.
"""

from __future__ import annotations

import base64
import html
import io
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk.report_scene import SCENE_SCRIPT as _SCENE_SCRIPT
from weldcell.sdk.report_scene import Scene3D, decimate
from weldcell.sdk.report_scene import plotly_script as _plotly_js

__all__ = [
    "ROW_STATUSES",
    "VERDICT_STATUSES",
    "Cell",
    "HtmlReport",
    "Scene3D",
    "Section",
    "decimate",
    "figure_png",
    "format_value",
    "png_data_uri",
]

VERDICT_STATUSES = ("ok", "attention", "failed")
"""``ok``: the result can be used as it is; ``attention``: usable after a person checks what is listed;
``failed``: the result must not be used (or there is none)."""

ROW_STATUSES = ("", "ok", "warn", "bad", "outlier")
"""Row or cell marks of a table: ``warn`` amber, ``bad`` red, ``outlier`` a colour of its own (purple)."""

_VERDICT_WORDS = {"ok": "OK", "attention": "NEEDS ATTENTION", "failed": "FAILED"}

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1b1f24;
background:#f6f7f9;line-height:1.45}
main{max-width:1180px;margin:0 auto;padding:16px 24px 48px}
header h1{font-size:1.55em;margin:12px 0 2px}
header .sub{color:#57606a;margin:0 0 4px}
header .meta{color:#57606a;font-size:.85em}
nav{font-size:.9em;margin:8px 0 16px}
nav a{margin-right:14px;color:#0b61c4;text-decoration:none}
section.wc-section{background:#fff;border:1px solid #d8dee4;border-radius:6px;padding:12px 18px;margin:14px 0}
section.wc-section h2{font-size:1.2em;margin:4px 0 8px}
section.wc-section h3{font-size:1.02em;margin:14px 0 6px}
.verdict{border-radius:6px;padding:12px 18px;margin:12px 0;border:2px solid}
.verdict h2{margin:0 0 6px;font-size:1.3em}
.verdict .badge{display:inline-block;font-weight:700;padding:1px 8px;border-radius:4px;color:#fff;
margin-right:8px;font-size:.85em;vertical-align:middle}
.verdict-ok{background:#eaf7ee;border-color:#2da44e}.verdict-ok .badge{background:#2da44e}
.verdict-attention{background:#fff8e5;border-color:#bf8700}.verdict-attention .badge{background:#9a6700}
.verdict-failed{background:#ffebe9;border-color:#cf222e}.verdict-failed .badge{background:#cf222e}
.verdict h3{font-size:.95em;margin:8px 0 2px}
.verdict ul{margin:2px 0 4px 0;padding-left:22px}
table.wc-table{border-collapse:collapse;margin:6px 0;font-size:.9em}
table.wc-table caption{caption-side:top;text-align:left;color:#57606a;padding:2px 0 4px}
table.wc-table th,table.wc-table td{border:1px solid #d8dee4;padding:3px 9px;text-align:left}
table.wc-table td.num{text-align:right;font-variant-numeric:tabular-nums}
table.wc-table th{background:#f0f3f6}
.warn{background:#fff1c2}.bad{background:#ffd7d5}.outlier{background:#eadcff}.ok{background:#dafbe1}
figure{margin:8px 0 14px}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#3d444d;font-size:.9em;margin-top:4px}
pre{background:#f6f8fa;padding:8px;overflow:auto;font-size:.85em}
dl.kv{display:grid;grid-template-columns:max-content auto;gap:2px 14px;margin:6px 0}
dl.kv dt{color:#57606a}dl.kv dd{margin:0}
.wc-scene{border:1px solid #d8dee4;margin:6px 0}
@media print{nav{display:none}section.wc-section{break-inside:avoid}}
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _slug(text: str, taken: set[str]) -> str:
    base = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"
    slug, n = base, 1
    while slug in taken:
        n += 1
        slug = f"{base}-{n}"
    taken.add(slug)
    return slug


def format_value(v: Any, digits: int = 3) -> str:
    """A table cell as text: floats to ``digits`` significant digits but at least one decimal
    (``123.5``, ``1.23``, ``0.00123``), None and NaN as an en dash, booleans yes/no, else ``str``."""
    if v is None:
        return "–"
    if isinstance(v, bool | np.bool_):
        return "yes" if v else "no"
    if isinstance(v, float | np.floating):
        f = float(v)
        if not np.isfinite(f):
            return "–"
        if f == 0:
            return "0"
        if abs(f) < 1 or abs(f) >= 1e6:
            return f"{f:.{digits}g}"
        return f"{f:.{max(digits - 1 - int(np.floor(np.log10(abs(f)))), 1)}f}"
    return str(v)


@dataclass
class Cell:
    """A table cell with a mark of its own (one of :data:`ROW_STATUSES`) and an optional tooltip."""

    value: Any
    status: str = ""
    title: str = ""


def png_data_uri(png: bytes) -> str:
    """``data:image/png;base64,...`` of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def figure_png(fig: Any, dpi: int = 110) -> bytes:
    """A matplotlib figure as PNG bytes (``bbox_inches="tight"``)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


@dataclass
class Section:
    """A titled part of a report; blocks render in the order they were added."""

    title: str
    intro: str = ""
    blocks: list[str] = field(default_factory=list)
    scenes: int = 0
    _report: HtmlReport | None = field(default=None, repr=False)

    def heading(self, text: str) -> Section:
        """A sub-heading inside the section."""
        self.blocks.append(f"<h3>{_e(text)}</h3>")
        return self

    def paragraph(self, text: str) -> Section:
        """A paragraph of plain text (escaped)."""
        self.blocks.append(f"<p>{_e(text)}</p>")
        return self

    def bullets(self, items: Iterable[str]) -> Section:
        """A bulleted list of plain-text items."""
        lis = "".join(f"<li>{_e(i)}</li>" for i in items)
        if lis:
            self.blocks.append(f"<ul>{lis}</ul>")
        return self

    def keyvalues(self, pairs: dict[str, Any] | Iterable[tuple[str, Any]]) -> Section:
        """A two-column list of labels and values (values formatted with :func:`format_value`)."""
        items = pairs.items() if isinstance(pairs, dict) else pairs
        body = "".join(f"<dt>{_e(k)}</dt><dd>{_e(format_value(v))}</dd>" for k, v in items)
        self.blocks.append(f'<dl class="kv">{body}</dl>')
        return self

    def preformatted(self, text: str) -> Section:
        """Text shown as written (e.g. a summary.txt)."""
        self.blocks.append(f"<pre>{_e(text)}</pre>")
        return self

    def table(
        self,
        columns: Sequence[str],
        rows: Iterable[Sequence[Any]],
        *,
        caption: str = "",
        row_status: Sequence[str] | None = None,
        digits: int = 3,
    ) -> Section:
        """A table: ``columns`` headers (put units in them, e.g. ``"length [mm]"``), ``rows`` of values
        (numbers right-aligned and formatted with :func:`format_value`; a :class:`Cell` marks one
        cell), ``row_status`` one mark of :data:`ROW_STATUSES` per row."""
        rows = [list(r) for r in rows]
        marks = list(row_status) if row_status is not None else [""] * len(rows)
        if len(marks) != len(rows):
            raise ValueError(f"row_status has {len(marks)} entries for {len(rows)} rows")
        head = "".join(f"<th>{_e(c)}</th>" for c in columns)
        body = []
        for r, mark in zip(rows, marks, strict=True):
            if len(r) != len(columns):
                raise ValueError(f"a row has {len(r)} values for {len(columns)} columns: {r!r}")
            if mark not in ROW_STATUSES:
                raise ValueError(f"unknown row status {mark!r}; use one of {ROW_STATUSES}")
            tds = []
            for v in r:
                c = v if isinstance(v, Cell) else Cell(v)
                num = isinstance(c.value, int | float | np.integer | np.floating) and not isinstance(
                    c.value, bool
                )
                cls = " ".join(x for x in ("num" if num else "", c.status) if x)
                attrs = (f' class="{cls}"' if cls else "") + (f' title="{_e(c.title)}"' if c.title else "")
                tds.append(f"<td{attrs}>{_e(format_value(c.value, digits))}</td>")
            body.append(f"<tr{f' class={chr(34)}{mark}{chr(34)}' if mark else ''}>{''.join(tds)}</tr>")
        cap = f"<caption>{_e(caption)}</caption>" if caption else ""
        self.blocks.append(
            f'<table class="wc-table">{cap}<thead><tr>{head}</tr></thead>'
            f"<tbody>{''.join(body)}</tbody></table>"
        )
        return self

    def figure(self, fig: Any, caption: str, *, alt: str = "", dpi: int = 110) -> Section:
        """A picture embedded as a PNG data URI: a matplotlib figure, PNG bytes, or a PNG file path.
        ``caption`` says in one sentence what the picture answers."""
        if isinstance(fig, bytes | bytearray):
            png = bytes(fig)
        elif isinstance(fig, str | Path):
            png = Path(fig).read_bytes()
        else:
            png = figure_png(fig, dpi)
        if png[:8] != b"\x89PNG\r\n\x1a\n":
            raise ValueError("figure(): not PNG data")
        self.blocks.append(
            f'<figure><img src="{png_data_uri(png)}" alt="{_e(alt or caption)}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>"
        )
        return self

    def scene(self, scene: Scene3D, caption: str = "") -> Section:
        """An interactive 3-D view (drag to turn, scroll to zoom, click a legend entry to hide it).
        Without plotly (the ``report`` extra) the page says so in its place and is written all the same."""
        try:
            import plotly.io as pio
        except ImportError:
            self.blocks.append(
                f'<p class="warn">{_e(scene.title or "3-D view")}: not shown, plotly is not installed '
                "(pip install 'weldcell[report]')</p>"
            )
            return self
        if self._report is None:
            raise ValueError("add scenes through HtmlReport.section()")
        self._report._scene_count += 1
        div_id = f"wc-scene-{self._report._scene_count}"
        div = pio.to_html(
            scene.figure(),
            full_html=False,
            include_plotlyjs=False,
            include_mathjax=False,
            div_id=div_id,
            config={"displaylogo": False, "responsive": True, "scrollZoom": True},
        )
        if self._report.compress_js:  # drawn once the packed plotly.js is unpacked (see report_scene.LOADER)
            div, n = re.subn(r'<script(?: type="text/javascript")?>', f'<script type="{_SCENE_SCRIPT}">', div)
            if n != 1:
                raise RuntimeError(f"plotly's HTML for a 3-D view has {n} scripts, expected 1")
        cap = f"<figcaption>{_e(caption)}</figcaption>" if caption else ""
        self.blocks.append(f'<figure><div class="wc-scene">{div}</div>{cap}</figure>')
        return self


class HtmlReport:
    """One self-contained HTML page: title, verdict (always rendered first), then sections.

    ``write(path)`` renders and writes it atomically; the page needs nothing outside itself.
    ``compress_js``: bundle plotly.js gzip-compressed (about 2 MB instead of 4.8 MB, unpacked by the
    browser's DecompressionStream: Chrome/Edge 80+, Firefox 113+, Safari 16.4+); False embeds it raw
    (any browser with WebGL).
    """

    def __init__(
        self,
        title: str,
        subtitle: str = "",
        *,
        meta: dict[str, Any] | None = None,
        compress_js: bool = True,
    ) -> None:
        self.title, self.subtitle = title, subtitle
        self.compress_js = bool(compress_js)
        self.meta = dict(meta or {})
        self.sections: list[Section] = []
        self.verdict: dict[str, Any] | None = None
        self.created = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
        self._scene_count = 0

    def set_verdict(
        self,
        status: str,
        headline: str,
        *,
        found: Iterable[str] = (),
        refused: Iterable[str] = (),
        attention: Iterable[str] = (),
    ) -> None:
        """The job's verdict: ``status`` one of :data:`VERDICT_STATUSES`, a one-line ``headline``, and
        lists of what was found, what was refused (with why) and what needs a person."""
        if status not in VERDICT_STATUSES:
            raise ValueError(f"unknown verdict status {status!r}; use one of {VERDICT_STATUSES}")
        self.verdict = {
            "status": status,
            "headline": headline,
            "found": list(found),
            "refused": list(refused),
            "attention": list(attention),
        }

    def section(self, title: str, intro: str = "") -> Section:
        """A new section (appended after the earlier ones); returns it to add blocks to."""
        s = Section(title, intro, _report=self)
        self.sections.append(s)
        return s

    def _verdict_html(self) -> str:
        v = self.verdict
        if v is None:
            raise ValueError("a report needs a verdict: call set_verdict() before rendering")
        parts = [
            f'<section id="verdict" class="verdict verdict-{v["status"]}">',
            f'<h2><span class="badge">{_VERDICT_WORDS[v["status"]]}</span>{_e(v["headline"])}</h2>',
        ]
        for key, label in (
            ("found", "What was found"),
            ("refused", "What was refused, and why"),
            ("attention", "What needs a person"),
        ):
            if v[key]:
                lis = "".join(f"<li>{_e(x)}</li>" for x in v[key])
                parts.append(f'<h3>{label}</h3><ul class="verdict-{key}">{lis}</ul>')
        parts.append("</section>")
        return "".join(parts)

    def render(self) -> str:
        """The whole page as one HTML string. Its text (not the bundled JavaScript) has every registered
        secret written as its reference (:func:`weldcell.sdk.secrets.redact`)."""
        from weldcell.sdk.secrets import redact

        taken: set[str] = {"verdict"}
        slugs = [_slug(s.title, taken) for s in self.sections]
        nav = "".join(
            f'<a href="#{sl}">{_e(s.title)}</a>' for s, sl in zip(self.sections, slugs, strict=True)
        )
        body = []
        for s, sl in zip(self.sections, slugs, strict=True):
            intro = f"<p>{_e(s.intro)}</p>" if s.intro else ""
            body.append(
                f'<section class="wc-section" id="{sl}"><h2>{_e(s.title)}</h2>'
                f"{intro}{''.join(s.blocks)}</section>"
            )
        js = ""
        if self._scene_count:  # plotly.js once, inline: the page loads nothing from outside itself
            js = _plotly_js(self.compress_js)
        meta = " · ".join(_e(f"{k}: {v}") for k, v in {"created": self.created, **self.meta}.items())
        head = (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            '<meta name="generator" content="weldcell.sdk.html_report">'
            f"<title>{redact(_e(self.title))}</title><style>{_CSS}</style>"
        )
        page = (
            f"<body><main><header><h1>{_e(self.title)}</h1>"
            + (f'<p class="sub">{_e(self.subtitle)}</p>' if self.subtitle else "")
            + f'<p class="meta">{meta}</p></header>'
            + self._verdict_html()
            + (f"<nav>{nav}</nav>" if nav else "")
            + "".join(body)
            + "</main></body></html>\n"
        )
        return head + js + "</head>" + redact(page)

    def write(self, path: str | Path) -> Path:
        """Render and write the page atomically and durably (``weldcell.sdk.artifacts.write_text``).
        In a run use ``rep.write(ctx.path("report/report.html"))`` (not ``ctx.write_text``, whose
        redaction would also run over the bundled JavaScript)."""
        from weldcell.sdk.artifacts import write_text

        return write_text(path, self.render())
