"""Human-readable listings for ``weldcell plugins`` and ``weldcell devices``."""

from __future__ import annotations

import json
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table
from weldcell.sdk.errors import WeldcellError
from weldcell.sdk.plugins import CATEGORIES, PluginManager


def plugin_rows(pm: PluginManager) -> list[dict]:
    """One dict per registered thing: category, name, kind, plugin, distribution, version, status."""
    reg = pm.registry
    rows = []
    for category in CATEGORIES:
        for entry in reg.all(category):
            d = entry.descriptor
            missing = d.missing_extras() if hasattr(d, "missing_extras") else []
            rows.append(
                {
                    "category": category,
                    "name": d.name,
                    "kind": getattr(d, "kind", ""),
                    "summary": getattr(d, "summary", ""),
                    "plugin": entry.provider.plugin,
                    "distribution": entry.provider.distribution,
                    "version": entry.provider.version,
                    "status": "ok"
                    if not missing
                    else "needs " + ", ".join(f"weldcell[{x}]" for _, x in missing),
                }
            )
    return rows


def plugin_table(pm: PluginManager, out: Console, as_json: bool = False) -> None:
    """Print every plugin, what it registers, and failures/conflicts."""
    reg = pm.registry
    rows = plugin_rows(pm)
    if as_json:
        out.print_json(
            json.dumps(
                {
                    "registered": rows,
                    "failures": [
                        {
                            "plugin": f.provider.plugin,
                            "distribution": f.provider.distribution,
                            "entry_point": f.provider.entry_point,
                            "stage": f.stage,
                            "error": f.error,
                        }
                        for f in reg.failures
                    ],
                    "conflicts": [str(c) for c in reg.conflicts.values()],
                }
            )
        )
        return
    plugins: dict[str, list[dict]] = {}
    for r in rows:
        plugins.setdefault(r["plugin"], []).append(r)
    for name in sorted(plugins):
        first = plugins[name][0]
        dist = (
            f"{first['distribution']} {first['version']}" if first["distribution"] else "(registered by hand)"
        )
        t = Table(title=f"plugin [bold]{name}[/bold] — {dist}", title_justify="left", show_edge=False)
        _add_columns(t, ("category", "name", "kind", "status", "summary"))
        for r in plugins[name]:
            status = "[green]ok[/green]" if r["status"] == "ok" else f"[yellow]{escape(r['status'])}[/yellow]"
            t.add_row(r["category"], r["name"], r["kind"], status, escape(r["summary"]))
        out.print(t)
        out.print()
    if reg.failures:
        out.print("[bold red]failed to load:[/bold red]")
        for f in reg.failures:
            out.print(f"  - {escape(str(f))}")
    if reg.conflicts:
        out.print("[bold red]conflicts:[/bold red]")
        for c in reg.conflicts.values():
            out.print(f"  - {escape(str(c))}")


def _add_columns(t: Table, cols: tuple[str, ...]) -> None:
    """Columns of a listing: names are never wrapped (users type them); the last column takes the rest."""
    for col in cols[:-1]:
        t.add_column(col, no_wrap=True)
    t.add_column(cols[-1], overflow="fold", min_width=16)


def device_report(pm: PluginManager, out: Console, profile: Path | None) -> int:
    """Print device plugins and their needs; with a profile, probe each device. Returns an exit code."""
    reg = pm.registry
    if profile is None:
        t = Table(show_edge=False)
        wide = out.width >= 100  # a narrow terminal shows the summaries in `weldcell plugins`
        _add_columns(t, ("device plugin", "kind", "sim", "needs", "summary")[: 5 if wide else 4])
        for e in reg.all("device"):
            d = e.descriptor
            missing = d.missing_extras()
            needs = escape(", ".join(f"weldcell[{x}]" for x in sorted(set(d.requires.values()))) or "-")
            if missing:
                needs = f"[yellow]{needs} (missing: {', '.join(m for m, _ in missing)})[/yellow]"
            t.add_row(d.name, d.kind, "yes" if d.simulated else "", needs, *[escape(d.summary)][: int(wide)])
        out.print(t)
        return 0
    from weldcell.sdk.jobs import prepare

    loaded, resolved = prepare(profile, pm)
    code = 0
    for role, (spec, settings) in resolved.devices.items():
        if spec.probe is None:
            out.print(f"  {role}: {spec.name}: [dim]no reachability probe[/dim]")
            continue
        try:
            out.print(f"  {role}: {spec.name}: [green]reachable[/green] {escape(spec.probe(settings))}")
        except WeldcellError as e:
            code = 5
            out.print(
                f"  {role}: {spec.name}: [red]not reachable[/red]: {escape(e.message)}"
                + (f" ({escape(e.fix)})" if e.fix else "")
            )
    return code
