"""Settings of the Photoneo PhoXi adapter (no vendor import here)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class PhoXiSettings(Settings):
    """``camera.phoxi``: a PhoXi 3D scanner over GenICam/GenTL (``mode = "device"``) or replayed PLY exports
    of PhoXi Control (``mode = "file"``)."""

    mode: Literal["device", "file"] = Field(
        "device", description="'device' (GenTL through harvesters) or 'file' (replay PLY exports)"
    )
    cti_path: str = Field(
        "",
        description="GenTL producer (.cti) of PhoXi Control; empty: the file named by "
        "the PHOXI_CTI environment variable, else a photoneo*.cti in GENICAM_GENTL64_PATH",
    )
    device_id: str = Field(
        "",
        description="scanner ID / serial as shown by PhoXi Control (e.g. 'TER-008'); "
        "empty: the only scanner found",
    )
    texture: bool = Field(True, description="also transfer the Intensity (texture) component")
    normals: bool = Field(True, description="also transfer the Normal component")
    confidence: bool = Field(False, description="also transfer the Confidence component")
    scan_timeout: Duration = Field(10.0, gt=0, description="longest wait for one triggered scan [s]")
    files: str = Field(
        "", description="file mode: a folder (all *.ply, sorted), a glob pattern or one PLY file"
    )
    units: Literal["mm", "m", "auto"] = Field(
        "mm", description="file mode: units of the PLY coordinates (PhoXi Control exports mm)"
    )
    loop: bool = Field(True, description="file mode: start again at the first file after the last one")
    intrinsics: tuple[float, float, float, float] | None = Field(
        None,
        description="file mode: (fx, fy, cx, cy) in pixels of the exported grid; default: fitted "
        "to the organised XYZ map, or a virtual camera for unorganised exports",
    )
