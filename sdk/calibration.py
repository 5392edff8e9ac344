"""The ``calibrate`` job's settings: the public contract of online hand-eye calibration.

Public (in the sdk, not in the hand-eye plugin) because other jobs run the calibration as a phase and
embed these settings in their own (``calibrate-and-track``'s ``[job.settings.calibrate]``), so that the
profile reference lists them and a profile is checked before any device opens. The job itself is
looked up by name in the registry (``registry.get("job", CALIBRATE_JOB)``), never imported.
"""

from __future__ import annotations

from pydantic import Field, model_validator
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length

#: the registered name of the online hand-eye calibration job
CALIBRATE_JOB = "calibrate"

Vec3 = tuple[Length, Length, Length]


class CalibrateSettings(Settings):
    """Settings of the online hand-eye calibration job."""

    box_min: Vec3 = Field(
        description="lower corner of the box the flange (eye-in-hand: the camera) visits, base frame [m]"
    )
    box_max: Vec3 = Field(description="upper corner of that box, robot base frame [m]")
    n_poses: int = Field(30, ge=4, le=500, description="calibration poses planned")
    max_tilt: Angle = Field(
        0.3,
        ge=0,
        le=1.2,
        description="largest random tilt of the flange away from facing the camera (eye-in-hand: of the "
        "camera away from facing the feature), about each of its x and y axes [rad] (§3.1: 0.3)",
    )
    max_spin: Angle = Field(
        0.3, ge=0, le=3.1416, description="largest random turn about the flange (camera) axis [rad]"
    )
    face_toward: Vec3 | None = Field(
        None,
        description="point the flange faces (eye-in-hand: the camera looks at), robot base frame [m]; "
        "default: the camera's nominal mount in the profile (eye-in-hand: feature_prior)",
    )
    feature_prior: Vec3 | None = Field(
        None,
        description="eye-in-hand: rough position of the fixed feature (the face centre of the flange plate "
        "the camera looks at), robot base frame, e.g. by tape measure [m]; the job estimates the exact one",
    )
    min_rotation: Angle = Field(
        0.1,
        ge=0,
        le=1.5,
        description="eye-in-hand: the first min_poses planned poses must turn the camera at least this much "
        "(rms) about every axis, else the feature cannot be told from the camera offset [rad]",
    )
    seed: int | None = Field(None, description="seed of the pose plan; default: the cell's seed")
    min_poses: int = Field(8, ge=4, description="the job may stop only after this many flange centres")
    stop_at_target: bool = Field(
        True,
        description="stop once Algorithm 1's cost (eye-in-hand: the fit's predicted error) reaches "
        "e_required",
    )
    verification_scan: bool = Field(
        True,
        description="eye-on-base: scan the flange at the box centre first (the "
        "verification cloud of the ICP metric, eq. 13)",
    )
    min_points: int = Field(200, ge=10, description="a scan with fewer valid points has no flange")
    reconnects: int = Field(2, ge=0, description="reconnection attempts when the camera drops")
    save_clouds: bool = Field(True, description="keep every scan (cropped to the stage's box) in captures/")

    @model_validator(mode="after")
    def _box(self) -> CalibrateSettings:
        for axis, lo, hi in zip("xyz", self.box_min, self.box_max, strict=True):
            if lo > hi:
                raise ValueError(f"box_min.{axis} ({lo}) must not exceed box_max.{axis} ({hi})")
        return self
