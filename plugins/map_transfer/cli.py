"""``weldcell map segment | serve | fetch``: segment a posed map, serve it from the robot, fetch it on
the operator's computer (docs/methods/map-transfer.md)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import click
from weldcell.sdk.errors import UsageError

TOKEN_ENV = "WELDCELL_MAP_TOKEN"


def token_from_env(name: str | None) -> str | None:
    """The shared token from the environment variable ``name`` (default WELDCELL_MAP_TOKEN), or None.

    A name given explicitly must be set. The value is registered for redaction and never printed."""
    from weldcell.sdk.secrets import register

    var = name or TOKEN_ENV
    value = os.environ.get(var)
    if name and not value:
        raise UsageError(f"--token-env {name}: the variable is not set", f"export {name}=<token> first")
    if value:
        register(value, f"${{env:{var}}}")
    return value or None


@click.command("segment")
@click.argument("cloud", type=click.Path(exists=True, path_type=Path))
@click.option(
    "--trajectory",
    type=click.Path(exists=True, path_type=Path),
    help="TUM file or keyframes.json (default: CLOUD/keyframes.json when CLOUD is a map folder)",
)
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="segmented map folder")
@click.option("--max-distance", default=15.0, show_default=True, help="travel per local map [m]")
@click.option("--max-points", default=500_000, show_default=True, help="points per local map")
@click.option(
    "--encoding",
    type=click.Choice(["quantised", "draco", "ply"]),
    default="quantised",
    show_default=True,
    help="quantised: <= --max-error-mm grid, deflated (fast to decode); draco: DracoPy; ply: lossless",
)
@click.option(
    "--units",
    type=click.Choice(["m", "cm", "mm"]),
    default="m",
    show_default=True,
    help="units of CLOUD's coordinates",
)
@click.option("--max-error-mm", default=1.0, show_default=True, help="largest quantisation error [mm]")
def segment_command(
    cloud, trajectory, output, max_distance, max_points, encoding, units, max_error_mm
) -> None:
    """Cut a posed map CLOUD (PLY/PCD in the world frame, or a map folder) into local maps."""
    from weldcell.plugins.map_transfer.segments import SegmentSettings, read_trajectory, write_segmented_map
    from weldcell.sdk.cli import out
    from weldcell.sdk.cloud import read_cloud

    if cloud.is_dir():  # a map folder of the mapping job: map.ply + keyframes.json
        trajectory = trajectory or cloud / "keyframes.json"
        cloud = cloud / "map.ply"
        if not cloud.is_file():
            raise UsageError(f"{cloud} does not exist", "give a map folder with map.ply, or a cloud file")
    if trajectory is None:
        raise UsageError("no trajectory given", "add --trajectory TUM_FILE (or keyframes.json)")
    s = SegmentSettings(
        max_distance=max_distance, max_points=max_points, encoding=encoding, max_error=max_error_mm / 1000.0
    )
    # a site map spans tens to hundreds of metres: the workpiece-scale unit guess does not apply
    c = read_cloud(cloud, units=units, frame="world", check_scale=False)
    m = write_segmented_map(output, c.points, c.colors, read_trajectory(trajectory), s, source=str(cloud))
    for e in m["segments"]:
        q = e["quantisation"]
        err = f", error max {q['max_error_m'] * 1e3:.3f} mm rms {q['rms_error_m'] * 1e3:.3f} mm" if q else ""
        out.print(
            f"segment {e['id']}: {e['points']} points, {e['bytes'] / 1e6:.2f} MB, "
            f"{e['distance_m']:.1f} m{err}",
            markup=False,
        )
    out.print(f"wrote {len(m['segments'])} segments to {output}", markup=False)


@click.command("serve")
@click.argument("map_dir", type=click.Path(path_type=Path))
@click.option(
    "--bind",
    default="tcp://127.0.0.1:5599",
    show_default=True,
    help="ZeroMQ endpoint; loopback by default, e.g. tcp://0.0.0.0:5599 for the robot's network",
)
@click.option("--token-env", default=None, help=f"environment variable with the shared token ({TOKEN_ENV})")
@click.option("--seconds", default=0.0, help="stop after this long (0: until Ctrl-C)")
def serve_command(map_dir, bind, token_env, seconds) -> None:
    """Serve the segmented map MAP_DIR (it may still be growing) to `weldcell map fetch`."""
    from weldcell.plugins.map_transfer.server import MapServer
    from weldcell.sdk.cli import console

    token = token_from_env(token_env)
    auth = "token required" if token else "no token (anyone who can reach it may fetch)"
    srv = MapServer(map_dir, bind, token=token)
    # Everything after the socket is bound sits inside try: a Ctrl-C that lands before the loop (a client
    # can be served as soon as start() returns) must still stop the thread and close the socket, or the
    # interpreter's exit waits forever on the ZeroMQ context the serving thread holds.
    try:
        console.print(f"serving {map_dir} on {srv.address} ({auth}); Ctrl-C stops", markup=False)
        srv.start()
        t_end = time.monotonic() + seconds if seconds > 0 else None
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.2)
    finally:
        srv.stop()
        console.print(f"served {srv.stats['chunks']} chunks, {srv.stats['bytes'] / 1e6:.1f} MB", markup=False)


@click.command("fetch")
@click.argument("address")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="local map folder")
@click.option("--token-env", default=None, help=f"environment variable with the shared token ({TOKEN_ENV})")
@click.option(
    "--wait", default=60.0, show_default=True, help="give up after this long without a new segment [s]"
)
@click.option("--timeout", default=2.0, show_default=True, help="re-ask after this silence [s]")
def fetch_command(address, output, token_env, wait, timeout) -> None:
    """Fetch the map served at ADDRESS (e.g. tcp://robot:5599) into OUTPUT, segment by segment;
    an interrupted fetch resumes where it stopped when run again."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn
    from weldcell.plugins.map_transfer.client import FetchSettings, MapClient
    from weldcell.sdk.cli import console

    token = token_from_env(token_env)
    bars: dict[int, int] = {}
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        console=console,
    ) as prog:

        def progress(e: dict, done: int) -> None:
            if e["id"] not in bars:
                bars[e["id"]] = prog.add_task(f"segment {e['id']} ({e['points']} pts)", total=e["bytes"])
            prog.update(bars[e["id"]], completed=done)

        with MapClient(address, output, token, FetchSettings(wait=wait, timeout=timeout)) as c:
            rep = c.fetch(on_progress=progress)
    state = "complete" if rep.complete else "not complete yet (run again to continue)"
    console.print(
        f"received {len(rep.segments)} segments ({rep.bytes / 1e6:.1f} MB, {rep.seconds:.2f} s), "
        f"{len(rep.skipped)} already here, {rep.bad_chunks} damaged chunks re-fetched; map {state}",
        markup=False,
    )
