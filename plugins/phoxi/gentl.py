"""PhoXi over GenICam/GenTL with ``harvesters`` (PhoXi Control's GenTL producer or the GigE Vision firmware).

Feature use follows Photoneo's GigE Vision/GenTL notes (firmware >= 1.13): software trigger through
``TriggerSelector = FrameStart``, ``TriggerMode = On``, ``TriggerSource = Software``, ``TriggerSoftware``;
components chosen with ``ComponentSelector`` / ``ComponentEnable``; ``Scan3dOutputMode =
CalibratedABC_Grid`` so the ``Range`` component is the organised XYZ point map (``Coord3D_ABC32f``, mm).
Multi-part payload parts arrive in increasing ``ComponentIDValue`` order, which is how parts are named here.
Intrinsics come from ``Scan3dFocalLength``, ``Scan3dAspectRatio``, ``Scan3dPrincipalPointU/V``.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from harvesters.core import Harvester
from weldcell.hal.interfaces import DepthCamera
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.sdk.errors import DeviceError

from .frames import fit_intrinsics, point_map_frame
from .settings import PhoXiSettings

#: component name -> settings flag deciding whether it is transferred (Range always is)
COMPONENTS = ("Intensity", "Range", "Confidence", "Normal", "Event", "ColorCamera")
DEVICE_KEYS = ("serial_number", "id_", "user_defined_name", "display_name", "model")


def find_cti(settings: PhoXiSettings) -> str:
    """The GenTL producer: the setting, else ``$PHOXI_CTI``, else a *.cti in ``$GENICAM_GENTL64_PATH``."""
    if settings.cti_path:
        cand = settings.cti_path
    elif os.environ.get("PHOXI_CTI"):
        cand = os.environ["PHOXI_CTI"]
    else:
        found: list[str] = []
        for d in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
            if d:
                found += sorted(glob.glob(os.path.join(d, "*.cti")))
        photoneo = [f for f in found if "photoneo" in Path(f).name.lower()]
        if not (photoneo or found):
            raise DeviceError(
                "no GenTL producer (.cti) for the PhoXi: cti_path is empty, PHOXI_CTI is unset and "
                "GENICAM_GENTL64_PATH holds no .cti",
                "install PhoXi Control and set cti_path "
                "(e.g. /opt/Photoneo/PhoXiControl/API/lib/photoneo.cti) "
                "or export PHOXI_CTI",
            )
        cand = (photoneo or found)[0]
    if not Path(cand).is_file():
        raise DeviceError(f"GenTL producer {cand!r} does not exist", "fix cti_path / PHOXI_CTI")
    return cand


def _label(info: Any) -> str:
    d = info.property_dict
    return str(d.get("serial_number") or d.get("id_"))


def _node(nm: Any, name: str) -> Any:
    return getattr(nm, name, None)


def _set(nm: Any, name: str, value: Any, required: bool = True) -> bool:
    node = _node(nm, name)
    if node is None:
        if required:
            raise DeviceError(
                f"the scanner has no GenICam feature {name!r}",
                "update the PhoXi firmware / PhoXi Control to 1.13 or newer",
            )
        return False
    node.value = value
    return True


class PhoXiGenTLCamera(DepthCamera):
    """A PhoXi scanner triggered in software; each ``capture()`` is one scan."""

    def __init__(
        self,
        settings: PhoXiSettings,
        name: str = "phoxi",
        frame: str | None = None,
        harvester_factory: Callable[[], Any] = Harvester,
    ) -> None:
        super().__init__(name, frame)
        self.settings = settings
        self._factory = harvester_factory
        self._h: Any = None
        self._ia: Any = None
        self._ids: dict[str, int] = {}
        self._intr: Intrinsics | None = None
        self.device_info: dict = {}

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        cti = find_cti(self.settings)
        self._h = self._factory()
        self._h.add_file(cti, check_existence=True, check_validity=True)
        self._h.update()
        infos = list(self._h.device_info_list)
        if not infos:
            raise DeviceError(
                "the GenTL producer lists no PhoXi scanner",
                "switch the scanner on, check the network and that PhoXi Control sees it",
            )
        index = self._select(infos)
        self.device_info = dict(infos[index].property_dict)
        self._ia = self._h.create(index)
        nm = self._ia.remote_device.node_map
        _set(nm, "TriggerSelector", "FrameStart", required=False)
        _set(nm, "TriggerMode", "On")
        _set(nm, "TriggerSource", "Software")
        _set(nm, "Scan3dOutputMode", "CalibratedABC_Grid", required=False)
        want = {
            "Intensity": self.settings.texture,
            "Range": True,
            "Confidence": self.settings.confidence,
            "Normal": self.settings.normals,
            "Event": False,
            "ColorCamera": False,
        }
        self._ids = {}
        for comp, on in want.items():
            try:
                nm.ComponentSelector.value = comp
            except Exception:
                if comp == "Range":
                    raise DeviceError(
                        "the scanner has no 'Range' component", "update the PhoXi firmware"
                    ) from None
                continue
            nm.ComponentEnable.value = bool(on)
            if on:
                idv = _node(nm, "ComponentIDValue")
                self._ids[comp] = int(idv.value) if idv is not None else COMPONENTS.index(comp)
        self._intr = self._read_intrinsics(nm)

    def _select(self, infos: list) -> int:
        want = self.settings.device_id.strip()
        if not want:
            if len(infos) > 1:
                names = [_label(i) for i in infos]
                raise DeviceError(
                    f"{len(infos)} scanners found ({', '.join(names)}); which one?",
                    "set device_id to the scanner's ID",
                )
            return 0
        for i, info in enumerate(infos):
            d = info.property_dict
            if any(str(d.get(k) or "").endswith(want) for k in DEVICE_KEYS):
                return i
        seen = [_label(i) for i in infos]
        raise DeviceError(f"no scanner with ID {want!r} (found: {', '.join(seen)})", "fix device_id")

    def _read_intrinsics(self, nm: Any) -> Intrinsics | None:
        w, h = _node(nm, "Width"), _node(nm, "Height")
        f = _node(nm, "Scan3dFocalLength")
        if w is None or h is None or f is None:
            return None  # fitted to the first point map instead
        ar = _node(nm, "Scan3dAspectRatio")
        pu, pv = _node(nm, "Scan3dPrincipalPointU"), _node(nm, "Scan3dPrincipalPointV")
        fx = float(f.value)
        return Intrinsics(
            width=int(w.value),
            height=int(h.value),
            fx=fx,
            fy=fx * (float(ar.value) if ar is not None else 1.0),
            cx=float(pu.value) if pu is not None else (int(w.value) - 1) / 2.0,
            cy=float(pv.value) if pv is not None else (int(h.value) - 1) / 2.0,
        )

    def on_activate(self) -> None:
        self._ia.start()

    def on_deactivate(self) -> None:
        if self._ia is not None:
            try:
                self._ia.stop()
            except Exception:
                pass

    def on_close(self) -> None:
        ia, h = self._ia, self._h
        self._ia = self._h = None
        for fn in (getattr(ia, "destroy", None), getattr(h, "reset", None)):
            if fn is not None:
                try:
                    fn()
                except Exception:
                    pass

    # -- readings --------------------------------------------------------------------------------
    def _capture(self, timeout: float) -> DepthFrame:
        wait = max(timeout, self.settings.scan_timeout)
        try:
            self._ia.remote_device.node_map.TriggerSoftware.execute()
            with self._ia.fetch(timeout=wait) as buffer:
                parts = list(buffer.payload.components)
                stamp_ns = getattr(buffer, "timestamp_ns", None)
                frame = self._parse(parts)
        except DeviceError:
            raise
        except Exception as e:
            raise self.fault(f"no scan within {wait:.1f} s ({type(e).__name__}: {e})") from e
        frame.meta["device_timestamp_ns"] = stamp_ns
        return frame

    def _parse(self, parts: list) -> DepthFrame:
        names = [n for n, _ in sorted(self._ids.items(), key=lambda kv: kv[1])]
        if len(parts) != len(names):
            raise self.fault(f"scan has {len(parts)} parts but {len(names)} components are enabled ({names})")
        by = dict(zip(names, parts, strict=True))
        rng = by["Range"]
        w, h = int(rng.width), int(rng.height)
        data = np.asarray(rng.data)
        fmt = str(rng.data_format)
        if fmt.startswith("Coord3D_ABC"):
            xyz = data.reshape(h, w, 3).astype(np.float64) * 1e-3
        elif fmt.startswith("Coord3D_C") and self._intr is not None:
            z = data.reshape(h, w).astype(np.float64) * 1e-3
            k = self._intr
            u, v = np.meshgrid(np.arange(w), np.arange(h))
            xyz = np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], axis=2)
        else:
            raise self.fault(
                f"unsupported Range pixel format {fmt!r}",
            )
        normals = texture = None
        if "Normal" in by and str(by["Normal"].data_format).startswith("Coord3D_ABC"):
            normals = np.asarray(by["Normal"].data).reshape(h, w, 3)
        if "Intensity" in by:
            t = by["Intensity"]
            ch = 3 if str(t.data_format).startswith("RGB") else 1
            arr = np.asarray(t.data).reshape(int(t.height), int(t.width), ch)
            texture = arr if ch == 3 else arr[..., 0]
        meta: dict = {"range_format": fmt}
        if "Confidence" in by:
            meta["confidence"] = np.asarray(by["Confidence"].data).reshape(h, w)
        if self._intr is None or (self._intr.width, self._intr.height) != (w, h):
            self._intr, res = fit_intrinsics(xyz)
            meta["intrinsics_fit_rms_px"] = res
        return point_map_frame(xyz, self._intr, self.frame, normals=normals, texture=texture, meta=meta)

    def _intrinsics(self) -> Intrinsics:
        if self._intr is None:
            raise DeviceError(
                f"depth_camera '{self.name}': intrinsics are read at configure() "
                "(or fitted to the first scan when the scanner does not publish them)",
                "configure the device (and capture once) first",
            )
        return self._intr


def probe_gentl(settings: PhoXiSettings, harvester_factory: Callable[[], Any] = Harvester) -> str:
    """List the scanners the GenTL producer sees; raise :class:`DeviceError` when the wanted one is absent."""
    h = harvester_factory()
    try:
        h.add_file(find_cti(settings), check_existence=True, check_validity=True)
        h.update()
        infos = [dict(i.property_dict) for i in h.device_info_list]
    finally:
        try:
            h.reset()
        except Exception:
            pass
    ids = [str(d.get("serial_number") or d.get("id_")) for d in infos]
    if not infos:
        raise DeviceError("no PhoXi scanner visible through GenTL", "switch it on and check PhoXi Control")
    want = settings.device_id.strip()
    if want and not any(want in (str(d.get(k) or "") for k in DEVICE_KEYS) for d in infos):
        raise DeviceError(f"scanner {want!r} not found (visible: {', '.join(ids)})", "fix device_id")
    return f"PhoXi GenTL: {len(infos)} scanner(s): {', '.join(ids)}"
