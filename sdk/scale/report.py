"""The summary table (CSV) and the page (self-contained HTML) of a batch or a study.

Batch page: a verdict (how many inputs ran, failed, were already done), one plot per metric across the
inputs (bars by input, or a histogram for many inputs), the failures with their error line, then every
input. Study page: the metrics' distribution (mean, σ, percentiles), failure rate, a histogram per
metric and each metric against each varied setting.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk import artifacts
from weldcell.sdk.html_report import HtmlReport

MAX_PLOTS = 12


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _margins(fig: Any) -> None:
    """Fixed margins (in inches, for tick labels and axis titles) instead of ``tight_layout``, which
    measured every tick label and was half of a study report's time."""
    w, h = fig.get_size_inches()
    fig.subplots_adjust(
        left=0.75 / w, right=1 - 0.2 / w, bottom=0.6 / h, top=1 - 0.3 / h, wspace=0.45, hspace=0.65
    )


def _csv(columns: list[str], rows: list[list[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    w.writerows(rows)
    return buf.getvalue()


def varying_metrics(records: list[dict[str, Any]], key: str = "metrics") -> list[str]:
    """Metric names that some record has, those that differ between records first."""
    names: dict[str, set] = {}
    for r in records:
        for k, v in (r.get(key) or {}).items():
            names.setdefault(k, set()).add(v)
    varying = [k for k, vals in names.items() if len(vals) > 1]
    constant = [k for k, vals in names.items() if len(vals) <= 1]
    return sorted(varying) + sorted(constant)


def _short(path: str, n: int = 28) -> str:
    name = Path(path).name
    return name if len(name) <= n else name[: n - 1] + "…"


# ------------------------------------------------------------------------------------------------ batch
def batch_rows(index: dict[str, Any]) -> tuple[list[str], list[list[Any]], list[str]]:
    """CSV columns, rows (one per input) and the metric names."""
    records = list(index["items"].values())
    metrics = varying_metrics(records)
    columns = ["input", "status", "resumed", "seconds", "attempts", "worker", "error", *metrics]
    rows = []
    for r in records:
        m = r.get("metrics") or {}
        rows.append(
            [
                r["input"],
                r["status"],
                int(bool(r.get("resumed"))),
                r.get("seconds", ""),
                r.get("attempts", ""),
                r.get("worker", ""),
                (r.get("error") or {}).get("line", ""),
                *[m.get(k, "") for k in metrics],
            ]
        )
    return columns, rows, metrics


def write_batch_report(out_dir: Path, index: dict[str, Any]) -> list[Path]:
    """``summary.csv`` and ``index.html`` of a batch (atomic writes)."""
    columns, rows, metrics = batch_rows(index)
    written = [artifacts.write_text(out_dir / "summary.csv", _csv(columns, rows))]
    records = list(index["items"].values())
    counts = index.get("counts", {})
    failed = [r for r in records if r["status"] == "failed"]
    pending = [r for r in records if r["status"] == "pending"]
    ok = [r for r in records if r["status"] == "ok"]
    rep = HtmlReport(
        f"weldcell batch {index['command']}",
        subtitle=f"{len(records)} inputs on {index.get('runner', '?')}",
        meta={"run": index.get("run", ""), "started": index.get("started", "")},
    )
    status = "ok" if not failed and not pending else ("failed" if not ok else "attention")
    rep.set_verdict(
        status,
        f"{len(ok)} of {len(records)} inputs done ({counts.get('resumed', 0)} from an earlier run), "
        f"{len(failed)} failed" + (f", {len(pending)} not run" if pending else ""),
        refused=[f"{_short(r['input'], 60)}: {(r.get('error') or {}).get('line', '')}" for r in failed[:20]],
        attention=[f"{len(pending)} inputs did not run (interrupted): run the same command again"]
        if pending
        else [],
    )
    plots = [k for k in metrics if any((r.get("metrics") or {}).get(k) for r in ok)][:MAX_PLOTS]  # not all 0
    if plots:
        sec = rep.section("Metrics per input", "The figures the command reports, across the finished inputs.")
        _embed(
            sec, _metrics_figure(ok, plots), "Each figure per input (a histogram when there are many inputs)."
        )
    if failed:
        sec = rep.section("Failures", "Each failed input with its error; its folder is failed/<key>/.")
        sec.table(
            ["input", "error", "exit code", "fix", "attempts"],
            [
                [
                    r["input"],
                    (r.get("error") or {}).get("line", ""),
                    (r.get("error") or {}).get("exit_code", ""),
                    (r.get("error") or {}).get("fix") or "",
                    r.get("attempts", ""),
                ]
                for r in failed
            ],
            row_status=["bad"] * len(failed),
        )
    sec = rep.section("Inputs", "Every input: results/<key>/ holds its output, log.txt and checksums.")
    sec.table(
        ["input", "status", "seconds", "attempts", "key"],
        [
            [
                r["input"],
                r["status"] + (" (earlier run)" if r.get("resumed") else ""),
                r.get("seconds", ""),
                r.get("attempts", ""),
                r.get("key", ""),
            ]
            for r in records
        ],
        row_status=[
            "ok" if r["status"] == "ok" else ("bad" if r["status"] == "failed" else "warn") for r in records
        ],
    )
    written.append(rep.write(out_dir / "index.html"))
    return written


def _embed(sec: Any, fig: Any, caption: str) -> None:
    """Embed a matplotlib figure as PNG, then free it."""
    sec.figure(fig, caption)
    _plt().close(fig)


def _metrics_figure(records: list[dict[str, Any]], keys: list[str]):
    """One small plot per metric: bars by input (up to 40 inputs), else a histogram."""
    plt = _plt()
    cols = min(3, len(keys))
    rows = -(-len(keys) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.9 * rows), squeeze=False)
    for ax, key in zip(axes.flat, keys, strict=False):
        vals = [(r["input"], r["metrics"][key]) for r in records if key in (r.get("metrics") or {})]
        if len(vals) <= 40:
            ax.bar(range(len(vals)), [v for _, v in vals], color="#4477aa")
            ax.set_xticks(
                range(len(vals)), [_short(n, 16) for n, _ in vals], rotation=60, ha="right", fontsize=6
            )
        else:
            ax.hist([v for _, v in vals], bins=min(40, max(10, len(vals) // 5)), color="#4477aa")
            ax.set_ylabel("inputs", fontsize=8)
        ax.set_title(key, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(keys) :]:
        ax.axis("off")
    _margins(fig)
    return fig


# ------------------------------------------------------------------------------------------------ study
STAT_COLUMNS = ["metric", "n", "mean", "std", "min", "p5", "p25", "p50", "p75", "p95", "max"]


def statistics(values: list[float]) -> dict[str, float]:
    """n, mean, σ (sample, ddof=1), min, 5/25/50/75/95th percentiles, max of finite values."""
    a = np.asarray([v for v in values if np.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"n": 0}
    p = np.percentile(a, [5, 25, 50, 75, 95])
    return {
        "n": int(a.size),
        "mean": float(a.mean()),
        "std": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "min": float(a.min()),
        "p5": float(p[0]),
        "p25": float(p[1]),
        "p50": float(p[2]),
        "p75": float(p[3]),
        "p95": float(p[4]),
        "max": float(a.max()),
    }


def write_study_report(out_dir: Path, study: dict[str, Any]) -> list[Path]:
    """``trials.csv``, ``statistics.csv`` and ``index.html`` of a study."""
    trials = list(study["trials"].values())
    varied = list(study["vary"])
    metrics = varying_metrics(trials, "figures")
    columns = ["trial", "seed", "status", "error", *varied, *metrics]
    rows = [
        [
            t["trial"],
            t.get("seed", ""),
            t["status"],
            (t.get("error") or {}).get("line", ""),
            *[(t.get("values") or {}).get(k, "") for k in varied],
            *[(t.get("figures") or {}).get(k, "") for k in metrics],
        ]
        for t in trials
    ]
    written = [artifacts.write_text(out_dir / "trials.csv", _csv(columns, rows))]
    stats = study.get("statistics", {})
    srows = [[k, *[stats[k].get(c, "") for c in STAT_COLUMNS[1:]]] for k in stats]
    written.append(artifacts.write_text(out_dir / "statistics.csv", _csv(STAT_COLUMNS, srows)))
    by, groups = study.get("by"), study.get("groups") or {}
    grows = [
        [value, k, *[g["statistics"][k].get(c, "") for c in STAT_COLUMNS[1:]]]
        for value, g in groups.items()
        for k in g.get("statistics", {})
    ]
    if by:
        written.append(artifacts.write_text(out_dir / "groups.csv", _csv([by, *STAT_COLUMNS], grows)))
    rep = _study_page(study, trials, varied, stats, srows, grows)
    written.append(rep.write(out_dir / "index.html"))
    return written


def _study_page(
    study: dict[str, Any], trials: list[dict], varied: list[str], stats: dict, srows: list, grows: list
) -> HtmlReport:
    """The study's HTML page: verdict, varied settings, statistics (per group), histograms, scatter
    plots against the varied settings, and the failed trials."""
    by, groups = study.get("by"), study.get("groups") or {}
    done = [t for t in trials if t["status"] in ("ok", "failed")]
    failed = [t for t in trials if t["status"] == "failed"]
    lost = [t for t in trials if t["status"] not in ("ok", "failed")]
    what = Path(study["profile"]).name if study.get("profile") else study.get("function", "?")
    rep = HtmlReport(
        f"weldcell study {what}",
        subtitle=f"{len(trials)} trials of {'job' if study.get('profile') else 'function'} "
        f"'{study.get('job', '?')}', seed {study['seed']}",
        meta={"runner": study.get("runner", "")},
    )
    rate = study.get("failure_rate", 0.0)
    rep.set_verdict(
        "ok" if not lost and rate == 0 else ("attention" if done else "failed"),
        f"{len(done)} of {len(trials)} trials ran; failure rate {rate * 100:.1f} %",
        refused=[f"trial {t['trial']}: {(t.get('error') or {}).get('line', '')}" for t in failed[:10]],
        attention=[f"{len(lost)} trials did not finish (see the table): run the same command again"]
        if lost
        else [],
    )
    sec = rep.section("Varied settings", "Each setting drawn per trial, in SI units (m, rad, s).")
    sec.table(["key", "distribution"], [[k, v] for k, v in study["vary"].items()])
    sec = rep.section(
        "Distribution of the metrics", "Over the trials whose job finished (failed ones left out)."
    )
    sec.table(STAT_COLUMNS, srows, digits=4)
    if by:
        sec = rep.section(f"By {by}", f"The same statistics per value of {by} (groups.csv).")
        sec.table(
            [by, "trials", "failure rate"],
            [[v, g["counts"]["trials"], f"{g['failure_rate'] * 100:.1f} %"] for v, g in groups.items()],
        )
        sec.table([by, *STAT_COLUMNS], grows, digits=4)
    ok = [t for t in trials if t["status"] == "ok"]
    spread = [k for k in stats if stats[k].get("n", 0) > 0 and stats[k].get("std", 0) > 0]
    plots = sorted(spread, key=lambda k: ("error" not in k.lower(), k))[:MAX_PLOTS]  # accuracy first
    if plots and ok:
        sec = rep.section("Histograms", "How each metric is spread over the trials.")
        for k in plots:
            _embed(
                sec,
                _histogram([t["figures"].get(k, np.nan) for t in ok], k, stats[k]),
                f"{k} over the trials.",
            )
        if varied:
            sec = rep.section(
                "Metrics against the varied settings", "Which drawn setting drives which metric."
            )
            for k in plots[:6]:
                _embed(sec, _scatter(ok, varied, k), f"{k} against each varied setting.")
    if failed or lost:
        how = (
            "Re-run one alone with `weldcell run trials/<n>/profile.toml`."
            if study.get("profile")
            else "Each one's output and traceback: trials/<n>/log.txt."
        )
        sec = rep.section("Failed trials", how)
        bad = failed + lost
        sec.table(
            ["trial", "status", "error"],
            [[t["trial"], t["status"], (t.get("error") or {}).get("line", "")] for t in bad],
            row_status=["bad"] * len(bad),
        )
    return rep


def _histogram(values: list[float], key: str, st: dict[str, float]):
    plt = _plt()
    a = np.asarray([v for v in values if np.isfinite(v)], dtype=float)
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.hist(a, bins=min(40, max(8, a.size // 4)), color="#4477aa")
    for q, style in (("mean", "-"), ("p5", ":"), ("p95", ":")):
        ax.axvline(st[q], color="#aa3377", linestyle=style, label=q)
    ax.set_xlabel(key)
    ax.set_ylabel("trials")
    ax.legend(fontsize=8)
    _margins(fig)
    return fig


def _scatter(trials: list[dict[str, Any]], varied: list[str], key: str):
    plt = _plt()
    fig, axes = plt.subplots(1, len(varied), figsize=(3.4 * len(varied), 3.0), squeeze=False)
    for ax, v in zip(axes[0], varied, strict=True):
        xs = [t["values"].get(v) for t in trials]
        ys = [t["figures"].get(key, np.nan) for t in trials]
        if all(isinstance(x, int | float) for x in xs):
            ax.plot(xs, ys, ".", color="#4477aa")
        else:
            cats = sorted({str(x) for x in xs})
            ax.plot([cats.index(str(x)) for x in xs], ys, ".", color="#4477aa")
            ax.set_xticks(range(len(cats)), cats, fontsize=7)
        ax.set_xlabel(v, fontsize=8)
        ax.set_ylabel(key, fontsize=8)
    _margins(fig)
    return fig
