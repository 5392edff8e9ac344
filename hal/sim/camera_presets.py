"""Depth-camera presets: each model's published resolution, field of view (as pinhole intrinsics), working
range and depth-noise model (active stereo, structured light, time of flight), and the ZED's video modes.
:class:`~weldcell.hal.sim.camera_model.RaycastCamera` renders with them; sources in docs/simulated-cell.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.sdk.errors import DataError

STEREO_SUBPIXEL = 0.08
"""Sub-pixel disparity RMS (pixels) of Intel's depth RMS-error formula (typical for D4xx)."""


STEREO_MAX_DISPARITY = 126
"""Disparity search range (pixels) of the D4xx at disparity shift 0: sets the minimum range."""


@dataclass(frozen=True)
class CameraPreset:
    """A depth camera model: pinhole intrinsics, working range (m) and noise/dropout model.

    Pixel centres are at integer coordinates (OpenCV convention). ``baseline`` is the offset (m) of the
    second view along the camera's +x used for shadowing (0 disables it); ``edge_jump`` is the relative
    depth jump between neighbouring pixels that counts as a discontinuity.
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    min_range: float
    max_range: float
    sigma0: float = 0.0
    sigma1: float = 0.0
    sigma2: float = 0.0
    principle: str = "stereo"
    baseline: float = 0.0
    grazing_dropout_deg: float = 75.0
    edge_dropout: float = 0.5
    edge_jump: float = 0.02
    edge_width: int = 1
    random_dropout: float = 0.001
    min_cos: float = 0.1
    decimation: int = 1
    source: str = ""

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise DataError(
                f"camera '{self.name}': image size {self.width}x{self.height} is empty",
                "give width and height >= 1",
            )
        for n in ("fx", "fy"):
            if not getattr(self, n) > 0:
                raise DataError(f"camera '{self.name}': {n} must be > 0 pixels", f"give a positive {n}")
        if not 0 <= self.min_range < self.max_range:
            raise DataError(
                f"camera '{self.name}': range {self.min_range}..{self.max_range} m is empty or negative",
                "give 0 <= min_range < max_range (metres)",
            )
        for n in ("sigma0", "sigma1", "sigma2", "baseline"):
            if getattr(self, n) < 0:
                raise DataError(f"camera '{self.name}': {n} must be >= 0", f"give {n} >= 0")
        for n in ("edge_dropout", "random_dropout"):
            if not 0 <= getattr(self, n) <= 1:
                raise DataError(f"camera '{self.name}': {n} is a probability", f"give {n} in [0, 1]")
        if not 0 < self.grazing_dropout_deg <= 90:
            raise DataError(
                f"camera '{self.name}': grazing_dropout_deg must be in (0, 90]",
                "give the incidence angle (degrees) where dropouts start, e.g. 75",
            )
        if not 0 < self.min_cos <= 1:
            raise DataError(f"camera '{self.name}': min_cos must be in (0, 1]", "give e.g. 0.1")

    @property
    def intrinsics(self) -> Intrinsics:
        """The pinhole intrinsics (pixels) of the depth image."""
        return Intrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    @property
    def K(self) -> np.ndarray:
        return self.intrinsics.K

    def sigma(self, z: np.ndarray | float, cos_incidence: np.ndarray | float | None = None) -> np.ndarray:
        """Depth noise standard deviation (m) at depth ``z``, grown by ``1/max(cos θ, min_cos)``."""
        z = np.asarray(z)
        z = z if z.dtype.kind == "f" else z.astype(float)
        s = self.sigma0 + self.sigma1 * z + self.sigma2 * z * z
        if cos_incidence is not None:
            c = np.abs(np.asarray(cos_incidence, dtype=z.dtype))
            s = s / np.maximum(c, z.dtype.type(self.min_cos))
        return s

    def decimated(self, factor: int) -> CameraPreset:
        """The same camera with the image subsampled by ``factor`` (like RealSense's decimation filter).

        The noise model is kept: depth is still computed at the native resolution, only fewer pixels
        are reported (Intel recommends decimating after capture rather than lowering the resolution).
        """
        if not isinstance(factor, int | np.integer) or factor < 1:
            raise DataError(f"decimation must be a positive integer, got {factor!r}", "give 1, 2, 4, ...")
        if factor == 1:
            return self
        return replace(
            self,
            width=self.width // factor,
            height=self.height // factor,
            fx=self.fx / factor,
            fy=self.fy / factor,
            cx=(self.cx + 0.5) / factor - 0.5,
            cy=(self.cy + 0.5) / factor - 0.5,
            decimation=self.decimation * factor,
        )

    def with_overrides(self, **overrides: object) -> CameraPreset:
        """A copy with some fields replaced; unknown names raise :class:`DataError`."""
        valid = [f.name for f in fields(self)]
        unknown = sorted(set(overrides) - set(valid))
        if unknown:
            raise DataError(
                f"camera preset has no field {', '.join(repr(u) for u in unknown)}",
                f"use only {', '.join(valid)}",
            )
        return replace(self, **overrides) if overrides else self


def _from_fov(
    name: str, width: int, height: int, hfov_deg: float, vfov_deg: float, **kw: object
) -> CameraPreset:
    """A preset whose focal lengths come from the published field of view: f = (W/2) / tan(FOV/2)."""
    fx = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    fy = (height / 2) / math.tan(math.radians(vfov_deg) / 2)
    return CameraPreset(name, width, height, fx, fy, (width - 1) / 2, (height - 1) / 2, **kw)


def _stereo(
    name: str,
    width: int,
    height: int,
    hfov_deg: float,
    vfov_deg: float,
    baseline: float,
    max_range: float,
    min_range: float | None = None,
    subpixel: float = STEREO_SUBPIXEL,
    **kw: object,
) -> CameraPreset:
    """Active/passive stereo: Intel's RMS error sigma_z = z² · subpixel / (f_px · baseline).

    Without a published minimum range it is the depth at the largest disparity searched:
    z_min = f_px · baseline / 126.
    """
    fx = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    zmin = fx * baseline / STEREO_MAX_DISPARITY if min_range is None else min_range
    return _from_fov(
        name,
        width,
        height,
        hfov_deg,
        vfov_deg,
        min_range=zmin,
        max_range=max_range,
        sigma2=subpixel / (fx * baseline),
        principle="stereo",
        baseline=baseline,
        **kw,
    )


def _structured_light(
    name: str,
    width: int,
    height: int,
    area_at_sweet: tuple[float, float],
    sweet: float,
    noise_at_sweet: float,
    min_range: float,
    max_range: float,
    **kw: object,
) -> CameraPreset:
    """Structured light: FOV from the scanning area at the sweet spot; noise ∝ z² through the sweet spot."""
    hfov = 2 * math.degrees(math.atan(area_at_sweet[0] / 2 / sweet))
    vfov = 2 * math.degrees(math.atan(area_at_sweet[1] / 2 / sweet))
    return _from_fov(
        name,
        width,
        height,
        hfov,
        vfov,
        min_range=min_range,
        max_range=max_range,
        sigma2=noise_at_sweet / sweet**2,
        principle="structured-light",
        **kw,
    )


PRESETS: dict[str, CameraPreset] = {
    "realsense-d415": _stereo(
        "realsense-d415",
        1280,
        720,
        65.0,
        40.0,
        baseline=0.055,
        max_range=10.0,
        source="Intel RealSense D400 datasheet (depth FOV 65°x40° at 1280x720, baseline 55 mm); "
        "RMS-error formula from Intel's 'Tuning depth cameras for best performance'",
    ),
    "realsense-d435": _stereo(
        "realsense-d435",
        1280,
        720,
        87.0,
        58.0,
        baseline=0.050,
        max_range=10.0,
        source="Intel RealSense D400 datasheet (depth FOV 87°x58° at 1280x720, baseline 50 mm); "
        "RMS-error formula from Intel's 'Tuning depth cameras for best performance'",
    ),
    "phoxi-s": _structured_light(
        "phoxi-s",
        2064,
        1544,
        (0.360, 0.286),
        sweet=0.442,
        noise_at_sweet=0.05e-3,
        min_range=0.384,
        max_range=0.520,
        edge_dropout=0.3,
        random_dropout=0.0005,
        source="Photoneo PhoXi 3D Scanner S datasheet (3.2 MP 2064x1544, range 384-520 mm, sweet spot "
        "442 mm, area 360x286 mm, temporal noise 0.05 mm); paper 003 §3.2.1",
    ),
    "phoxi-m": _structured_light(
        "phoxi-m",
        2064,
        1544,
        (0.590, 0.404),
        sweet=0.650,
        noise_at_sweet=0.1e-3,
        min_range=0.458,
        max_range=1.118,
        edge_dropout=0.3,
        random_dropout=0.0005,
        source="Photoneo PhoXi 3D Scanner M datasheet (3.2 MP 2064x1544, range 458-1118 mm, sweet spot "
        "650 mm, area ~590x404 mm); sigma 0.1 mm at the sweet spot; paper 003 §3.2.1 and §3.3",
    ),
    "azure-kinect": _from_fov(
        "azure-kinect",
        640,
        576,
        75.0,
        65.0,
        min_range=0.5,
        max_range=3.86,
        sigma0=0.0017,
        sigma1=0.001,
        principle="tof",
        edge_dropout=0.8,
        random_dropout=0.002,
        source="Azure Kinect DK hardware specification (NFOV unbinned 640x576, 75°x65°, 0.5-3.86 m); "
        "noise 1.7 mm + 0.1% of z (typical measured precision; the spec bounds random error at 17 mm)",
    ),
    "zed2i": _stereo(
        "zed2i",
        1280,
        720,
        110.0,
        70.0,
        baseline=0.120,
        max_range=20.0,
        min_range=0.3,
        random_dropout=0.002,
        source="Stereolabs ZED 2i datasheet (HD720, 2.1 mm lens FOV 110°x70°, baseline 120 mm, "
        "0.3-20 m, <1% error up to 3 m); stereo RMS-error formula with subpixel 0.08",
    ),
}


def get_preset(name: str | CameraPreset) -> CameraPreset:
    """The preset called ``name`` (a key of ``PRESETS``), or ``name`` itself if it already is one."""
    if isinstance(name, CameraPreset):
        return name
    key = str(name).strip().lower().replace("_", "-")
    if key not in PRESETS:
        raise DataError(f"unknown camera preset '{name}'", f"use one of {', '.join(PRESETS)}")
    return PRESETS[key]


ZED_RESOLUTIONS: dict[str, tuple[int, int, float]] = {
    "2K": (2208, 1242, 2.0),
    "FHD": (1920, 1080, 2.0),
    "HD": (1280, 720, 1.0),
    "VGA": (672, 376, 0.5),
}
"""The ZED 2i's video modes (HD2K, HD1080, HD720, VGA; per-eye pixels, the keys of its calibration file)
and each mode's focal length relative to HD720: the factory calibration files give fx(2K) = fx(FHD) =
2 fx(HD) = 4 fx(VGA) (2K and FHD read the sensor at full scale, FHD cropped; HD and VGA bin it)."""


def zed_mode(resolution: str, preset: str | CameraPreset = "zed2i") -> CameraPreset:
    """The ZED preset at one of its real video modes (:data:`ZED_RESOLUTIONS`): image size, focal length
    and principal point of that mode, and the stereo noise of depth computed at that resolution
    (sigma_z = subpixel · z² / (f · baseline) grows as f shrinks). Unlike ``decimation`` (which keeps the
    native mode's depth noise and only reports fewer pixels), this is what the camera delivers in the mode.
    """
    key = str(resolution).strip().upper()
    aliases = {"HD2K": "2K", "HD1080": "FHD", "HD720": "HD"}
    key = aliases.get(key, key)
    if key not in ZED_RESOLUTIONS:
        raise DataError(
            f"unknown ZED resolution {resolution!r}",
            f"use one of {', '.join(ZED_RESOLUTIONS)} (HD2K 2208x1242, HD1080, HD720 1280x720, VGA 672x376)",
        )
    p = get_preset(preset)
    if p.principle != "stereo" or not p.name.startswith("zed"):
        raise DataError(f"camera preset '{p.name}' is not a ZED", "use preset 'zed2i' with a ZED resolution")
    w, h, scale = ZED_RESOLUTIONS[key]
    return replace(
        p,
        name=f"{p.name}-{key.lower()}",
        width=w,
        height=h,
        fx=p.fx * scale,
        fy=p.fy * scale,
        cx=(w - 1) / 2,
        cy=(h - 1) / 2,
        sigma2=p.sigma2 / scale,
    )
