"""``weldcell map relocalize PRIOR CURRENT -o result.json``: relocalize a map (paper 004 §II-E).

Exit codes: 0 relocalized (verified), 1 failed (the result file is still written, with the reason),
2 bad input (missing or damaged file, malformed option).
"""

from __future__ import annotations

from pathlib import Path

import click
from weldcell.sdk.artifacts import write_json
from weldcell.sdk.errors import JobError

from .inputs import load_map, parse_position, parse_yaw, sample_keyframes
from .local_reg import METHODS


@click.command("relocalize")
@click.argument("prior", type=click.Path(path_type=Path))
@click.argument("current", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Result JSON to write.")
@click.option("--yaw", help="Heading of the current map in the prior map, degrees, e.g. 45 or 45±10.")
@click.option("--position", help="Origin of the current map in the prior map, metres, e.g. 3,-2,0±2.")
@click.option(
    "--method",
    type=click.Choice(METHODS),
    default="gicp",
    show_default=True,
    help="Fine registration after NDT's coarse levels.",
)
@click.option(
    "--min-overlap",
    type=click.FloatRange(0.05, 1.0),
    default=0.9,
    show_default=True,
    help="Share of the current map that must fit the prior map (lower only for partly overlapping scans).",
)
def relocalize_command(
    prior: Path, current: Path, output: Path, yaw, position, method: str, min_overlap: float
):
    """Find T_prior_current between a prior map and the current map/cloud (weldcell/relocalization@1)."""
    from .relocalize import Priors, RelocalizeSettings, relocalize

    yaw_v, yaw_s = parse_yaw(yaw)
    pos_v, pos_s = parse_position(position)
    pm, cm = load_map(prior), load_map(current)
    settings = RelocalizeSettings(method=method, min_overlap=min_overlap)
    kf = None
    if pos_v is None and pm.keyframe_positions is not None:
        kf = sample_keyframes(pm.keyframe_positions, cm.keyframe_positions, spacing=2.0)
    res = relocalize(pm.points, cm.points, Priors(yaw_v, yaw_s, pos_v, pos_s, kf), settings)
    write_json(output, res.to_json())
    g = res.gamma
    click.echo(
        f"{res.status}: overlap {res.overlap:.1%}, confidence {res.confidence:.2f}, "
        f"Γ = [{g[0]:.3f}, {g[1]:.3f}, {g[2]:.3f} m, {g[3]:.4f}, {g[4]:.4f}, {g[5]:.4f} rad] "
        f"({', '.join(res.priors_used)}; {res.seconds:.2f} s) -> {output}"
    )
    for note in res.notes:
        click.echo(f"  note: {note}")
    if res.status != "ok":
        raise JobError(f"relocalization failed: {res.reason}", f"the result is in {output}; {_FIX}")


_FIX = "check that both maps show the same site, or give --yaw / --position priors"
