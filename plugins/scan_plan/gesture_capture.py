"""The gesture-guided scan of ``scan-and-plan`` (paper 000, Algorithm 1 in a loop), resumable capture by
capture.

The operator moves the eye-in-hand camera with hand gestures, captures on 'ok' and stops with a fist.
Every capture is a checkpoint in ``state.json`` (file + size + SHA-256, pose, joints, scan time, gesture
frames used, the controller's state); a resumed scan continues after the last intact one. A device that
drops is recovered and retried (:func:`retry_device`).
"""

from __future__ import annotations

import re
import time
from typing import TYPE_CHECKING

import numpy as np
from rich.markup import escape
from weldcell.plugins.scan_plan.gesture import GestureScanController
from weldcell.sdk.cloud import drop_invalid, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import invert
from weldcell.sdk.scan import PosedScan

if TYPE_CHECKING:
    from weldcell.plugins.scan_plan.job import ScanAndPlanSettings

SCAN = "scan (gesture-guided)"


def _plain(e: DeviceError) -> str:
    """A device error's message for the operator: without an embedded API hint ('fix: call recover()')."""
    return re.split(r"\s+fix:\s", e.message)[0]


def retry_device(ctx, device, what: str, fn, attempts: int, delay: float = 0.0):
    """Call ``fn``; on a DeviceError recover the device and retry (captures are already saved).

    A recovery that itself fails (the device is still gone) counts as an attempt; attempts after the
    first wait ``delay`` seconds, doubled each time. When every attempt fails, a JobError tells how to
    resume the run.
    """
    last: DeviceError | None = None
    for k in range(attempts + 1):
        if k > 0:
            line = f"{what}: {_plain(last)}; reconnecting ({k}/{attempts})"
            ctx.reporter.info(f"[yellow]{escape(line)}[/yellow]")
            if delay > 0 and k > 1:
                time.sleep(delay * 2 ** (k - 2))
            try:
                device.recover()
                device.configure()
                device.activate()
            except DeviceError as e:
                last = e
                continue
        try:
            return fn()
        except DeviceError as e:
            last = e
    raise JobError(
        f"{what}: {_plain(last)} (after {attempts} reconnection attempt{'s' if attempts != 1 else ''})",
        f"captures so far are saved in {ctx.run_dir}; fix the device and run again with "
        f"`weldcell run {ctx.loaded.path} --resume {ctx.run_dir}`",
    ) from last


def _to_json(v):
    if isinstance(v, np.ndarray):
        return {"array": v.tolist()}
    if isinstance(v, tuple):
        return {"tuple": [_to_json(x) for x in v]}
    if isinstance(v, np.generic):
        return v.item()
    return v


def _from_json(v):
    if isinstance(v, dict) and "array" in v:
        return np.asarray(v["array"], dtype=float)
    if isinstance(v, dict) and "tuple" in v:
        return tuple(_from_json(x) for x in v["tuple"])
    return v


def controller_state(ctl: GestureScanController) -> dict:
    """The controller's running state (smoothed palm, hold timers, clutch, ...), exactly, as JSON."""
    return {k: _to_json(v) for k, v in vars(ctl).items() if k.startswith("_")}


def restore_controller(ctl: GestureScanController, state: dict) -> None:
    """Put a :func:`controller_state` snapshot back."""
    for k, v in state.items():
        if k.startswith("_") and hasattr(ctl, k):
            setattr(ctl, k, _from_json(v))


def _replays_script(sensor) -> bool:
    """A gesture sensor that replays a script (the simulated hand) starts it again when reopened; a
    live tracker simply continues with the operator's hand."""
    return getattr(sensor, "player", None) is not None


def _generator_state(device) -> dict | None:
    """The random generator state of a simulated device (its noise), so a resumed scan continues it."""
    rng = getattr(device, "rng", None)
    return rng.bit_generator.state if isinstance(rng, np.random.Generator) else None


def load_captures(ctx) -> list[PosedScan]:
    """Scans recorded in state.json (after a resume), each verified against its recorded size and
    SHA-256 and read back from the run folder.

    A damaged capture while the scan is still open is taken out (with the ones after it; their files
    are kept, renamed) and the scan continues from the capture before it. When the scan had finished, a
    damaged capture stops the run with an error: re-scanning moves the robot, so it needs ``--redo scan``.
    """
    st = ctx.state
    bad = st.first_damaged_capture()
    if bad is not None:
        i, problem = bad
        if st.step_done(SCAN) and not ctx.redoing(SCAN):
            raise DataError(
                f"{problem}; the scan had finished, so it is not taken again automatically",
                f"restore the file, or re-scan from capture {i} on (the {i} before it are kept) with "
                f"`{ctx.resume_command} --redo scan`",
            )
        n = len(st.captures) - i
        ctx.reporter.info(
            f"[yellow]{escape(problem)}: it is captured again ({n} capture(s) taken out)[/yellow]"
        )
        st.discard_captures(i, problem)
    elif ctx.redoing(SCAN) and st.captures:
        ctx.reporter.info(f"--redo scan: {len(st.captures)} earlier capture(s) set aside, scanning again")
        st.discard_captures(0, "--redo scan")
    scans = []
    for rec in st.captures:
        f = ctx.run_dir / rec["file"]
        cloud = read_cloud(f, units="m", frame="camera", check_scale=False)
        if "points" in rec and len(cloud) != rec["points"]:
            raise DataError(
                f"capture {rec['file']} holds {len(cloud)} points, {rec['points']} were recorded",
                f"restore the file, or re-scan with `{ctx.resume_command} --redo scan`",
            )
        scans.append(PosedScan(cloud, np.asarray(rec["T_base_flange"], dtype=float), float(rec["stamp"])))
    return scans


class _ScanClock:
    """Scan time: sensor time since the scan began, continued across resumes (stamps restart)."""

    def __init__(self, base: float = 0.0, gap: float = 0.0) -> None:
        self.base, self.gap, self.first = base, gap, None

    def __call__(self, stamp: float) -> float:
        if self.first is None:
            self.first = stamp
        return self.base + self.gap + (stamp - self.first)


def _continue_scan(ctx, ctl, robot, sensor, camera, read) -> _ScanClock:
    """Put the scan back where its last capture left it: controller state, the simulated hand's script
    position and noise generators, and the robot at that capture's joints (one gated joint move)."""
    if not ctx.state.captures:
        return _ScanClock()
    last = ctx.state.captures[-1]
    if "controller" not in last:  # a run folder from before checkpoints: continue from here
        return _ScanClock(float(last.get("scan_time", 0.0)), 1.0 / ctl.rate_hint)
    restore_controller(ctl, last["controller"])
    if _replays_script(sensor):
        # the hand script replays from its start: skip the frames the scan already used, timing them
        # as the first attempt did (scan time counts from the script's first frame)
        clock = _ScanClock()
        for _ in range(int(last["frames"])):
            clock(read().stamp)
    else:  # a live tracker: the operator's hand continues now
        clock = _ScanClock(float(last["scan_time"]), 1.0 / ctl.rate_hint)
    replay = last.get("replay") or {}
    if replay.get("camera_rng") is not None and _generator_state(camera) is not None:
        camera.rng.bit_generator.state = replay["camera_rng"]
    q = np.asarray(last.get("q", []), dtype=float)
    now = robot.state().q
    if q.shape == now.shape and np.max(np.abs(q - now)) > 1e-6:
        ctx.reporter.info(f"returning the robot to where capture {len(ctx.state.captures) - 1} was taken")
        robot.move_joint(q)
    return clock


def gesture_scan(ctx, T_flange_camera: np.ndarray) -> list[PosedScan]:
    """Algorithm 1 in a loop: move the camera by hand gestures, capture on 'ok', stop on a fist.

    Every capture is a checkpoint (file + size + SHA-256, pose, joints, scan time, gesture frames used,
    controller state): a resumed scan continues after the last one, never capturing a view twice.
    """
    s: ScanAndPlanSettings = ctx.settings
    robot, camera, sensor = ctx.device("robot"), ctx.device("camera"), ctx.device("gesture")
    scans = load_captures(ctx)
    resumed = len(scans)
    if ctx.state.step_done(SCAN) and not ctx.redoing(SCAN):
        ctx.reporter.info(f"scan: done in an earlier attempt ({len(scans)} captures), not repeated")
        ctx.figures["scan"] = {"captures": len(scans), "resumed_captures": resumed, "refused_targets": 0}
        return scans
    if scans:
        ctx.reporter.info(f"resuming with {len(scans)} capture(s) already taken")

    def retry(device, what, fn):
        return retry_device(ctx, device, what, fn, s.reconnects, s.reconnect_delay)

    # gesture frames read since the scan began (a scripted sensor's resume re-reads them from 0)
    frames = int(ctx.state.captures[-1].get("frames", 0)) if scans and not _replays_script(sensor) else 0

    def read():
        nonlocal frames
        frame = retry(sensor, "gesture sensor", sensor.read)
        frames += 1
        return frame

    ctl = GestureScanController(s.gesture)
    refused = 0
    with ctx.step(SCAN, total=s.max_captures, kind="checkpointed") as advance:
        clock = _continue_scan(ctx, ctl, robot, sensor, camera, read)
        advance(len(scans), s.max_captures, "captures")
        while len(scans) < s.max_captures:
            frame = read()
            t = clock(frame.stamp)
            if t > s.max_scan_time or getattr(sensor, "finished", False):
                break
            state = retry(robot, "robot", robot.state)
            cmd = ctl.update(frame, state.T_base_flange @ T_flange_camera, stamp=t)
            if cmd.capture:
                scan = _capture(ctx, ctl, retry, len(scans), t, frames)
                if scan is None:
                    continue
                scans.append(scan)
                advance(len(scans), s.max_captures, f"{len(scan.cloud)} pts")
            if cmd.stop:
                break
            if cmd.target is not None:
                refused += _follow(
                    ctx, retry, cmd.target @ invert(T_flange_camera) @ robot.T_flange_tcp, refused
                )
        if len(scans) < s.min_captures:
            raise JobError(
                f"the scan ended with {len(scans)} capture(s); at least {s.min_captures} are needed",
                "make the 'ok' sign with the right hand while the part is in view",
            )
    ctx.figures["scan"] = {"captures": len(scans), "resumed_captures": resumed, "refused_targets": refused}
    return scans


def _capture(ctx, ctl: GestureScanController, retry, index: int, t: float, frames: int) -> PosedScan | None:
    """One capture on 'ok': the depth frame and the robot's pose, written and recorded as a checkpoint at
    once; None (and a note) when the frame has too few valid points."""
    robot, camera = ctx.device("robot"), ctx.device("camera")
    depth = retry(camera, "camera", camera.capture)
    state = retry(robot, "robot", robot.state)
    cloud = drop_invalid(depth.to_cloud())
    if len(cloud) < ctx.settings.min_depth_points:
        ctx.reporter.info(
            f"[yellow]capture refused: only {len(cloud)} valid points (is the part "
            "in view and in range?)[/yellow]"
        )
        return None
    name = f"scans/{index:03d}.ply"
    write_cloud(ctx.path(name), cloud)
    ctx.state.add_capture(
        {
            "file": name,
            "T_base_flange": state.T_base_flange.tolist(),
            "q": state.q.tolist(),
            "stamp": depth.stamp,
            "points": len(cloud),
            "scan_time": t,
            "frames": frames,
            "controller": controller_state(ctl),
            "replay": {"camera_rng": _generator_state(camera)},
        }
    )
    return PosedScan(cloud, state.T_base_flange, depth.stamp)


def _follow(ctx, retry, T_tcp: np.ndarray, refused: int) -> int:
    """Move the camera to the gesture's target through the safety gate; 1 when the gate refused it."""
    robot = ctx.device("robot")
    try:
        retry(robot, "robot", lambda T=T_tcp: robot.move_linear(T))
    except SafetyError as e:
        if refused + 1 == 1 or (refused + 1) % 50 == 0:
            ctx.reporter.info(  # expected while following a hand: the gate keeps the arm safe
                "gesture target refused by the safety gate (expected now and then: the camera "
                f"stays where it is and follows the next target): {e.message}"
            )
        return 1
    return 0
