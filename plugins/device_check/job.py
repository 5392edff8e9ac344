"""Open every device, read it once, and write what each returned (a cell's smoke test)."""

from __future__ import annotations

import numpy as np
from pydantic import Field
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.settings import Settings


class CheckSettings(Settings):
    """Settings of the check-devices job."""

    readings: int = Field(3, ge=1, le=1000, description="readings taken from each device")
    timeout: float = Field(2.0, gt=0, description="seconds to wait for each reading [s]")


def _read(device, timeout: float):
    kind = device.kind
    if kind == "robot":
        return device.state()
    if kind in ("depth_camera", "tactile_camera"):
        return device.capture(timeout)
    if kind == "laser_projector":
        return device.project(np.array([[[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]]]), label="check")
    return device.read(timeout)


def _describe(reading) -> str:
    if hasattr(reading, "T_base_tcp"):
        return "TCP at [" + ", ".join(f"{v:.3f}" for v in reading.T_base_tcp[:3, 3]) + "] m"
    if hasattr(reading, "depth"):
        valid = reading.depth[reading.depth > 0]
        return f"{reading.depth.shape[1]}x{reading.depth.shape[0]} depth, {valid.size} valid px"
    if hasattr(reading, "hands"):
        return f"{len(reading.hands)} hand(s)"
    if hasattr(reading, "distance"):
        return "out of range" if reading.distance is None else f"{reading.distance * 1000:.3f} mm"
    if hasattr(reading, "image"):
        return f"image {reading.image.shape}"
    if hasattr(reading, "accel"):
        return "accel [" + ", ".join(f"{v:.2f}" for v in reading.accel) + "] m/s^2"
    if hasattr(reading, "latitude"):
        return f"{reading.latitude:.6f}, {reading.longitude:.6f}"
    if hasattr(reading, "segments"):
        return f"projected {len(reading.segments)} segment(s)"
    return type(reading).__name__


def run(ctx) -> dict:
    s: CheckSettings = ctx.settings
    report, lines = {}, [f"weldcell check-devices: {ctx.profile.name}", ""]
    failed = 0
    for role, device in ctx.devices.items():
        with ctx.step(f"check {role}"):
            try:
                last = None
                for _ in range(s.readings):
                    last = _read(device, s.timeout)
                h = device.health()
                report[role] = {
                    "ok": True,
                    "kind": device.kind,
                    "reading": _describe(last),
                    "stamp": float(getattr(last, "stamp", 0.0)),
                    "frame": getattr(last, "frame", ""),
                    "state": h.state.value,
                }
            except DeviceError as e:
                failed += 1
                report[role] = {"ok": False, "kind": device.kind, "error": e.message, "fix": e.fix}
        r = report[role]
        lines.append(
            f"{role:<12} {r['kind']:<20} " + (f"ok     {r['reading']}" if r["ok"] else f"FAILED {r['error']}")
        )
    ctx.write_json("devices.json", report)
    ctx.write_text("summary.txt", "\n".join(lines) + "\n")
    ctx.figures["devices"] = report
    if failed:
        raise DeviceError(f"{failed} device(s) failed the check", f"see {ctx.run_dir / 'devices.json'}")
    return {"devices": len(report)}
