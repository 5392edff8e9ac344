"""pyubx2 / pynmeagps messages -> :class:`~weldcell.hal.readings.GnssFix` (pure functions, no I/O)."""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np
from weldcell.hal.readings import GnssFix

PVT_FIX_TYPES = {0: "none", 1: "dead-reckoning", 2: "2d", 3: "3d", 4: "gnss+dr", 5: "time-only"}
GGA_QUALITY = {0: "none", 1: "3d", 2: "dgnss", 3: "3d", 4: "rtk-fixed", 5: "rtk-float", 6: "dead-reckoning"}

_A = 6378137.0
_F = 1 / 298.257223563
_E2 = _F * (2 - _F)


def geodetic_to_ecef(lat: float, lon: float, h: float) -> np.ndarray:
    la, lo = math.radians(lat), math.radians(lon)
    n = _A / math.sqrt(1 - _E2 * math.sin(la) ** 2)
    return np.array(
        [
            (n + h) * math.cos(la) * math.cos(lo),
            (n + h) * math.cos(la) * math.sin(lo),
            (n * (1 - _E2) + h) * math.sin(la),
        ]
    )


def geodetic_to_enu(lat: float, lon: float, h: float, origin: tuple[float, float, float]) -> np.ndarray:
    """East/north/up (m) of a WGS-84 point relative to ``origin`` (lat, lon, ellipsoidal height)."""
    d = geodetic_to_ecef(lat, lon, h) - geodetic_to_ecef(*origin)
    la, lo = math.radians(origin[0]), math.radians(origin[1])
    R = np.array(
        [
            [-math.sin(lo), math.cos(lo), 0.0],
            [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
            [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
        ]
    )
    return R @ d


def _utc(date: _dt.date | None, time: _dt.time | None, nano: int = 0) -> float | None:
    if date is None or not isinstance(time, _dt.time):
        return None
    t = _dt.datetime.combine(date, time).replace(tzinfo=_dt.UTC)
    return t.timestamp() + nano * 1e-9


def fix_from_pvt(msg, stamp: float, frame: str, origin=None) -> GnssFix:
    """NAV-PVT -> GnssFix. No fix (or gnssFixOk = 0) gives fix_type "none" with NaN coordinates."""
    kind = PVT_FIX_TYPES.get(msg.fixType, "none")
    if kind in ("2d", "3d", "gnss+dr"):
        if msg.carrSoln == 2:
            kind = "rtk-fixed"
        elif msg.carrSoln == 1:
            kind = "rtk-float"
        elif msg.diffSoln:
            kind = "dgnss"
    if not msg.gnssFixOk and kind != "time-only":
        kind = "none"
    device_stamp = None
    if msg.validDate and msg.validTime:
        try:
            d = _dt.date(msg.year, msg.month, msg.day)
            device_stamp = _utc(d, _dt.time(msg.hour, msg.min, min(msg.second, 59)), msg.nano)
        except ValueError:
            device_stamp = None
    h_acc, v_acc = msg.hAcc / 1000.0, msg.vAcc / 1000.0
    vel = np.array([msg.velE, msg.velN, -msg.velD], float) / 1000.0
    if kind in ("none", "time-only"):
        lat = lon = alt = math.nan
        enu = cov = None
    else:
        lat, lon, alt = float(msg.lat), float(msg.lon), msg.height / 1000.0
        enu = None if origin is None else geodetic_to_enu(lat, lon, alt, origin)
        cov = np.diag([h_acc**2 / 2, h_acc**2 / 2, v_acc**2])
    return GnssFix(
        stamp,
        lat,
        lon,
        alt,
        enu=enu,
        covariance=cov,
        fix_type=kind,
        frame=frame,
        device_stamp=device_stamp,
        h_acc=h_acc,
        v_acc=v_acc,
        num_sv=int(msg.numSV),
        velocity_enu=vel if kind not in ("none", "time-only") else None,
    )


def _num(v) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def fix_from_gga(msg, stamp: float, frame: str, origin=None, date=None, gst=None) -> GnssFix:
    """NMEA GGA (+ the last RMC's date and GST's sigmas when present) -> GnssFix."""
    kind = GGA_QUALITY.get(int(msg.quality or 0), "3d")
    lat, lon, alt, sep = _num(msg.lat), _num(msg.lon), _num(msg.alt), _num(msg.sep)
    if lat is None or lon is None:
        kind = "none"
    h_acc = v_acc = None
    if gst is not None:
        sl, so, sa = _num(gst.stdLat), _num(gst.stdLong), _num(gst.stdAlt)
        if sl is not None and so is not None:
            h_acc = math.hypot(sl, so)
        v_acc = sa
    if kind == "none":
        lat = lon = height = math.nan
        enu = cov = None
    else:
        height = (alt or 0.0) + (sep or 0.0) if alt is not None else math.nan
        enu = (
            None if origin is None or not math.isfinite(height) else geodetic_to_enu(lat, lon, height, origin)
        )
        cov = None if h_acc is None or v_acc is None else np.diag([h_acc**2 / 2, h_acc**2 / 2, v_acc**2])
    return GnssFix(
        stamp,
        lat,
        lon,
        height,
        enu=enu,
        covariance=cov,
        fix_type=kind,
        frame=frame,
        device_stamp=_utc(date, msg.time),
        h_acc=h_acc,
        v_acc=v_acc,
        num_sv=int(msg.numSV) if isinstance(msg.numSV, int) else None,
    )
