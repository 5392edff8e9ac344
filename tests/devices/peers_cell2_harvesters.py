"""A fake of the ``harvesters`` API surface used by the PhoXi adapter, with a simulated PhoXi behind it.

Mirrors harvesters 1.4 (checked against the installed package): ``Harvester()`` with ``add_file(file_path,
check_existence=False, check_validity=False)``, ``update()``, ``device_info_list`` (objects with
``property_dict`` keyed like ``DeviceInfo.search_keys``), ``create(search_key)``, ``reset()``;
``ImageAcquirer`` with ``remote_device.node_map``, ``start(*, run_as_thread=False)``, ``fetch(*, timeout)``
returning a ``Buffer`` context manager (``payload.components``, ``timestamp_ns``), ``stop()``, ``destroy()``;
components with ``data`` (1-D numpy), ``width``, ``height``, ``data_format``. The node map behaves like
Photoneo's GenICam features: ``ComponentSelector``/``ComponentEnable``/``ComponentIDValue``,
``TriggerSelector``/``TriggerMode``/``TriggerSource``/``TriggerSoftware``, ``Scan3d*`` intrinsics.
Parts of the
multi-part payload come in increasing component-ID order, as Photoneo documents. A fetch with no triggered
scan raises genicam's ``TimeoutException`` (after at most 50 ms here, to keep tests fast).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

try:
    from genicam.gentl import GenericException, TimeoutException
except Exception:  # pragma: no cover - genicam ships with harvesters

    class GenericException(Exception):  # type: ignore[no-redef]
        pass

    class TimeoutException(GenericException):  # type: ignore[no-redef]
        pass


COMPONENT_IDS = {"Intensity": 1, "Range": 4, "Confidence": 7, "Normal": 10, "Event": 11, "ColorCamera": 12}


@dataclass
class SimPhoXi:
    """The scene and optics of the simulated scanner (mm, camera frame: z forward)."""

    serial: str = "TER-008"
    width: int = 96
    height: int = 72
    f: float = 110.0
    aspect: float = 1.02
    cu: float = 47.3
    cv: float = 35.8
    plane_z: float = 800.0
    sphere_c: tuple = (10.0, -5.0, 700.0)
    sphere_r: float = 60.0
    unplugged: bool = False
    scans: int = 0

    def render(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Organised XYZ (H, W, 3) mm (zeros where nothing is measured), normals, Mono12 texture."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        d = np.stack(
            [(u - self.cu) / self.f, (v - self.cv) / (self.f * self.aspect), np.ones_like(u)], axis=2
        )
        # tilted plane z = plane_z + 0.3 x
        t_plane = self.plane_z / (d[..., 2] - 0.3 * d[..., 0])
        t = t_plane.copy()
        n = np.broadcast_to(np.array([-0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0), d.shape).copy()
        c = np.asarray(self.sphere_c)
        dd = np.einsum("hwk,hwk->hw", d, d)
        b = np.einsum("hwk,k->hw", d, c)
        disc = b * b - dd * (c @ c - self.sphere_r**2)
        hit = disc > 0
        ts = np.where(hit, (b - np.sqrt(np.where(hit, disc, 0.0))) / dd, np.inf)
        closer = hit & (ts < t)
        t = np.where(closer, ts, t)
        xyz = d * t[..., None]
        n[closer] = (xyz[closer] - c) / self.sphere_r
        n[closer] *= -1.0  # toward the camera
        n[~closer] *= -1.0
        shadow = (u < 4) | ((u - 70) ** 2 + (v - 20) ** 2 < 30)  # unmeasured pixels (occlusion / border)
        xyz[shadow] = 0.0
        n[shadow] = 0.0
        tex = (1000 + 2000 * np.abs(n[..., 2])).astype(np.uint16)
        tex[shadow] = 0
        return xyz.astype(np.float32), n.astype(np.float32), tex


class _Node:
    def __init__(self, value=None, on_set=None, on_get=None, choices=None):
        self._value, self._on_set, self._on_get, self._choices = value, on_set, on_get, choices

    @property
    def value(self):
        return self._on_get() if self._on_get else self._value

    @value.setter
    def value(self, v):
        if self._choices is not None and v not in self._choices:
            raise GenericException(f"invalid enumeration value {v!r}")
        if self._on_set:
            self._on_set(v)
        else:
            self._value = v


class _Command:
    def __init__(self, fn):
        self._fn = fn

    def execute(self) -> None:
        self._fn()


class FakeNodeMap:
    """Photoneo GenICam features (the subset the adapter and PhoXi Control use)."""

    def __init__(self, acq: FakeImageAcquirer) -> None:
        sim = acq.sim
        self._acq = acq
        self._selected = "Intensity"
        self.enabled = {
            "Intensity": True,
            "Range": True,
            "Confidence": False,
            "Normal": True,
            "Event": False,
            "ColorCamera": False,
        }
        self.Width = _Node(sim.width)
        self.Height = _Node(sim.height)
        self.TriggerSelector = _Node("FrameStart", choices=("FrameStart",))
        self.TriggerMode = _Node("Off", choices=("On", "Off"))
        self.TriggerSource = _Node("Line1", choices=("Software", "Line1"))
        self.Scan3dOutputMode = _Node("CalibratedABC_Grid", choices=("CalibratedABC_Grid", "ProjectedC"))
        self.Scan3dFocalLength = _Node(sim.f)
        self.Scan3dAspectRatio = _Node(sim.aspect)
        self.Scan3dPrincipalPointU = _Node(sim.cu)
        self.Scan3dPrincipalPointV = _Node(sim.cv)
        self.ComponentSelector = _Node(on_set=self._select, on_get=lambda: self._selected)
        self.ComponentEnable = _Node(
            on_set=lambda v: self.enabled.__setitem__(self._selected, bool(v)),
            on_get=lambda: self.enabled[self._selected],
        )
        self.ComponentIDValue = _Node(on_get=lambda: COMPONENT_IDS[self._selected])
        self.TriggerSoftware = _Command(acq._trigger)

    def _select(self, name: str) -> None:
        if name not in COMPONENT_IDS:
            raise GenericException(f"ComponentSelector has no entry {name!r}")
        self._selected = name


@dataclass
class _Component:
    data: np.ndarray
    width: int
    height: int
    data_format: str


@dataclass
class _Payload:
    components: list


class FakeBuffer:
    def __init__(self, components: list, stamp_ns: int) -> None:
        self.payload = _Payload(components)
        self.timestamp_ns = stamp_ns
        self.queued = False

    def queue(self) -> None:
        self.queued = True

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.queue()


class _RemoteDevice:
    def __init__(self, node_map: FakeNodeMap) -> None:
        self.node_map = node_map


class FakeImageAcquirer:
    def __init__(self, sim: SimPhoXi) -> None:
        self.sim = sim
        self.remote_device = _RemoteDevice(FakeNodeMap(self))
        self.started = False
        self.destroyed = False
        self._pending = 0
        self._lock = threading.Lock()

    def _trigger(self) -> None:
        nm = self.remote_device.node_map
        if self.sim.unplugged:
            raise GenericException("device not reachable (GenTL error)")
        if not self.started or nm.TriggerMode.value != "On" or nm.TriggerSource.value != "Software":
            raise GenericException("TriggerSoftware is not available (trigger mode / acquisition)")
        with self._lock:
            self._pending += 1

    def start(self, *, run_as_thread: bool = False) -> None:
        if self.destroyed:
            raise GenericException("acquirer destroyed")
        self.started = True

    def stop(self) -> None:
        self.started = False

    def destroy(self) -> None:
        self.stop()
        self.destroyed = True

    def fetch(self, *, timeout: float = 0, is_raw: bool = False, cycle_s: float | None = None) -> FakeBuffer:
        with self._lock:
            ready = self._pending > 0 and not self.sim.unplugged
            if ready:
                self._pending -= 1
        if not ready:
            time.sleep(min(timeout, 0.05))
            raise TimeoutException("fetch timed out")
        nm = self.remote_device.node_map
        xyz, normals, tex = self.sim.render()
        if nm.Scan3dOutputMode.value == "ProjectedC":
            rng = _Component(xyz[..., 2].ravel().copy(), self.sim.width, self.sim.height, "Coord3D_C32f")
        else:
            rng = _Component(xyz.ravel().copy(), self.sim.width, self.sim.height, "Coord3D_ABC32f")
        parts = {
            "Intensity": _Component(tex.ravel().copy(), self.sim.width, self.sim.height, "Mono12"),
            "Range": rng,
            "Confidence": _Component(
                np.where(xyz[..., 2] > 0, 255, 0).astype(np.uint8).ravel(),
                self.sim.width,
                self.sim.height,
                "Confidence8",
            ),
            "Normal": _Component(normals.ravel().copy(), self.sim.width, self.sim.height, "Coord3D_ABC32f"),
        }
        comps = [parts[n] for n in sorted(parts, key=COMPONENT_IDS.get) if nm.enabled.get(n)]
        self.sim.scans += 1
        return FakeBuffer(comps, time.time_ns())


@dataclass
class _DeviceInfo:
    property_dict: dict


@dataclass
class FakeGenTLSystem:
    """What a PhoXi Control GenTL producer would expose: the .cti file and its scanners."""

    cti: Path
    scanners: list[SimPhoXi] = field(default_factory=list)
    acquirers: list[FakeImageAcquirer] = field(default_factory=list)

    def harvester(self) -> FakeHarvester:
        return FakeHarvester(self)


class FakeHarvester:
    def __init__(self, system: FakeGenTLSystem) -> None:
        self._system = system
        self.files: list[str] = []
        self.device_info_list: list[_DeviceInfo] = []

    def add_file(self, file_path: str, check_existence: bool = False, check_validity: bool = False) -> None:
        if check_existence and not Path(file_path).is_file():
            raise FileNotFoundError(file_path)
        if check_validity and Path(file_path).resolve() != Path(self._system.cti).resolve():
            raise OSError(f"{file_path} is not a valid GenTL producer")
        self.files.append(file_path)

    def update(self) -> None:
        self.device_info_list = (
            []
            if not self.files
            else [
                _DeviceInfo(
                    {
                        "id_": f"PhotoneoTL_DEV_{s.serial}",
                        "serial_number": s.serial,
                        "model": "PhoXi3DScanner",
                        "vendor": "Photoneo",
                        "display_name": f"PhoXi {s.serial}",
                        "user_defined_name": "",
                        "access_status": 1,
                        "tl_type": "Custom",
                        "version": "1.13.0",
                    }
                )
                for s in self._system.scanners
                if not s.unplugged
            ]
        )

    def create(self, search_key=None, *, config=None) -> FakeImageAcquirer:
        if isinstance(search_key, int):
            info = self.device_info_list[search_key]
        else:
            raise ValueError("the fake supports an index search key, as the adapter uses")
        sim = next(s for s in self._system.scanners if s.serial == info.property_dict["serial_number"])
        ia = FakeImageAcquirer(sim)
        self._system.acquirers.append(ia)
        return ia

    def reset(self) -> None:
        self.files, self.device_info_list = [], []
