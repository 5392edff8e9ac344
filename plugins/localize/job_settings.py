"""Settings of the job ``localize-and-weld`` (docs/jobs/localize-and-weld.md), the simulated worker's
among them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.plugins.localize.acquisition import AcquisitionSettings
from weldcell.plugins.localize.guidance import (
    GuidanceSettings,
)
from weldcell.plugins.localize.plans import PlanSettings
from weldcell.plugins.localize.sim_trial import SimScanSettings
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length, Speed


class SimWorkerSettings(Settings):
    """The simulated worker who places the weldment (simulated cell only; ignored on hardware)."""

    placement_offset: Length = Field(
        0.015, ge=0, description="placement error, uniform in ± this per axis [m]"
    )
    placement_angle: Angle = Field(0.349, ge=0, description="placement error, uniform in ± this angle [rad]")
    member_variation: Length = Field(0.002, ge=0, description="as-built members differ from CAD by up to [m]")
    placement: tuple[Length, Length, Angle] | None = Field(
        None, description="a fixed placement error (dx, dy, dtheta) instead of a random one (tests)"
    )
    placement_x: Length | None = Field(
        None,
        description="scope 'localize': a fixed placement error in x instead of a random one (studies) [m]",
    )
    placement_y: Length | None = Field(
        None,
        description="scope 'localize': a fixed placement error in y instead of a random one (studies) [m]",
    )
    placement_theta: Angle | None = Field(
        None, description="scope 'localize': a fixed placement error in theta instead of a random one [rad]"
    )


class LocalizeAndWeldSettings(Settings):
    """The job's settings (docs/jobs/localize-and-weld.md)."""

    scope: Literal["full", "localize"] = Field(
        "full",
        description="full: the whole job; localize (simulated cell only): template, the worker's placement, "
        "the plan scanned by the sensor model, edges and localization against the truth, without robot "
        "motion, projector or weld (Monte-Carlo studies: the Table 1 protocol, sim_trial.py)",
    )
    sim_scan: SimScanSettings = Field(
        default_factory=SimScanSettings, description="scope 'localize': the laser sensor model"
    )

    template: str = Field(
        "ladder",
        description="the workpiece: a template file (weldcell/template@1 .json, .dxf, .stl/.ply/.obj; "
        "relative "
        "to the profile) or a built-in flat weldment: ladder, truss, spaceframe",
    )
    template_units: str | None = Field(None, description="units of a DXF/mesh template when not in the file")
    guidance: GuidanceSettings = Field(
        default_factory=GuidanceSettings,
        description="placement guidance: envelope, projector views, fixture marks, worker confirmation",
    )
    calibrate_projector: bool = Field(
        True, description="calibrate the projector from a projected dot pattern first (simulated cell)"
    )
    plan: PlanSettings = Field(
        default_factory=PlanSettings,
        description="inspection plan: zig-zag or spiral, span, line spacing, speed",
    )
    acquisition: AcquisitionSettings = Field(
        default_factory=AcquisitionSettings,
        description="laser acquisition: rate, latency estimation, pose synchronisation",
    )
    worker: SimWorkerSettings = Field(
        default_factory=SimWorkerSettings,
        description="simulated worker only: placement error and member variation drawn per run",
    )
    execute: bool = Field(True, description="weld the re-planned path with the robot (simulated: measured)")
    weld_speed: Speed = Field(0.008, gt=0, description="travel speed along the seam [m/s]")
    allow_unobserved_members: bool = Field(
        False,
        description="weld although members were not seen by the inspection (default: such a fit fails: a "
        "member beyond the inspected envelope leaves the pose along the others unconstrained)",
    )
    approach_distance: Length = Field(0.05, gt=0, description="approach/retract distance along the torch [m]")
    seam_spacing: Length = Field(0.01, gt=0, description="spacing of the seam points handed to the path [m]")
