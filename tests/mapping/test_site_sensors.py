"""The simulated site and its sensors carry their real models' characteristics."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.sim.gnss_model import GnssModel, GnssSimulator
from weldcell.hal.sim.inertial import ImuModel, ImuSimulator
from weldcell.hal.sim.site import GRAVITY, Route, RouteSettings
from weldcell.sdk.errors import DataError


def test_site_is_large_and_the_route_drives_at_the_papers_speeds(site):
    x0, y0, x1, y1 = site.layout.extent
    assert x1 - x0 >= 30 and y1 - y0 >= 10
    r = site.route
    t = np.linspace(0, r.duration, 4000)
    v = r.speed(t)
    assert v.max() <= 5.0 and v[0] == pytest.approx(0, abs=1e-6) and v[-1] == pytest.approx(0, abs=1e-6)
    p = r.pos(t)[:, :2]
    near = np.min(np.linalg.norm(p[:, None] - site.work_points()[None, :, :2], axis=2), axis=1) < 1.5
    assert v[near].mean() < 0.6 * v[~near].mean()  # slow near the work
    assert np.sum(np.linalg.norm(np.diff(r.pos(t), axis=0), axis=1)) == pytest.approx(30.0, rel=0.03)


def test_route_derivatives_match_the_pose():
    r = Route.build(RouteSettings(length=20.0))
    t = np.array([5.0, 9.3, 14.0])
    R, v, a, w = r.kinematics(t)
    dt = 1e-4
    for i, ti in enumerate(t):
        np.testing.assert_allclose((r.pos(ti + dt) - r.pos(ti - dt)) / (2 * dt), v[i], atol=1e-5)
        R0, R1 = r.rotation(ti)[0], r.rotation(ti + dt)[0]
        from scipy.spatial.transform import Rotation

        np.testing.assert_allclose(Rotation.from_matrix(R0.T @ R1).as_rotvec() / dt, w[i], atol=1e-3)


def test_route_refuses_speeds_beyond_the_paper():
    with pytest.raises(DataError, match="5 m/s"):
        RouteSettings(cruise_speed=6.0)


def _static_imu(model, seed=1):
    def kin(t):
        n = len(np.atleast_1d(t))
        z = np.zeros((n, 3))
        return np.tile(np.eye(3), (n, 1, 1)), z, z, z, z

    return ImuSimulator(model, kin, np.eye(4), seed)


def test_imu_white_noise_and_bias_have_the_model_statistics():
    m = ImuModel(rate=200.0, gyro_turn_on_bias=0.01, accel_turn_on_bias=0.05)
    sim = _static_imu(m)
    b_g, b_a = sim.b_g.copy(), sim.b_a.copy()
    t, acc, gyr, mag, truth = sim.samples_until(20.0)
    assert len(t) == 4001
    np.testing.assert_allclose(gyr.std(0), m.gyro_noise_density * np.sqrt(200), rtol=0.1)
    np.testing.assert_allclose(acc.std(0), m.accel_noise_density * np.sqrt(200), rtol=0.1)
    np.testing.assert_allclose(gyr[:200].mean(0), b_g, atol=5e-4)
    np.testing.assert_allclose(acc.mean(0) - truth["b_a"].mean(0), [0, 0, GRAVITY], atol=2e-3)
    assert not np.allclose(b_a, 0)


def test_imu_bias_random_walk_grows_with_the_square_root_of_time():
    m = ImuModel(gyro_random_walk=1e-3)
    drifts = []
    for seed in range(40):
        sim = _static_imu(m, seed)
        b0 = sim.b_g.copy()
        sim.samples_until(25.0)
        drifts.append(sim.b_g - b0)
    std = np.std(np.array(drifts))
    assert std == pytest.approx(1e-3 * np.sqrt(25.0), rel=0.25)


def test_magnetometer_is_disturbed_near_steel():
    m = ImuModel(hard_iron=0.0, soft_iron=0.0, mag_noise=0.0)

    def kin_at(p):
        def kin(t):
            n = len(np.atleast_1d(t))
            z = np.zeros((n, 3))
            return np.tile(np.eye(3), (n, 1, 1)), z, z, z, np.tile(p, (n, 1))

        return kin

    steel = np.array([[0.0, 0.0, 0.0]])

    def dist(p):
        return np.min(np.linalg.norm(p[:, None] - steel[None], axis=2), axis=1)

    far = ImuSimulator(m, kin_at(np.array([20.0, 0, 0])), np.eye(4), 0, dist).samples_until(0.0)[3][0]
    near = ImuSimulator(m, kin_at(np.array([0.5, 0, 0])), np.eye(4), 0, dist).samples_until(0.0)[3][0]
    earth = np.array(m.mag_earth)
    assert np.linalg.norm(far - earth) < 0.1
    assert np.linalg.norm(near - earth) > 20  # tens of uT next to a steel column: heading unusable


def test_gnss_standalone_is_metre_level_and_loses_the_fix_under_the_roof(site):
    sim = GnssSimulator(
        GnssModel(mode="standalone", rate=5.0),
        lambda t: site.route.pos(t),
        site.under_roof,
        site.distance_to_steel,
        seed=2,
    )
    fixes = sim.samples_until(site.route.duration)
    ok = [f for f in fixes if f["enu"] is not None]
    err = np.array([f["enu"] - f["truth"] for f in ok])
    h = np.sqrt(np.mean(err[:, :2] ** 2))
    assert 0.3 < h < 6.0
    roofed = [f for f in fixes if site.under_roof(f["truth"][None])[0]]
    assert roofed and all(f["fix_type"] == "none" for f in roofed)


def test_gnss_rtk_is_centimetre_level(site):
    sim = GnssSimulator(GnssModel(mode="rtk"), lambda t: np.array([1.0, 2.0, 0.0]), seed=3)
    err = np.array([f["enu"] - f["truth"] for f in sim.samples_until(60.0)])
    assert np.sqrt(np.mean(err[:, :2] ** 2)) < 0.03


def test_zed_video_modes_have_their_own_intrinsics_and_depth_noise():
    """A real ZED 2i mode (VGA 672x376) is not HD720 decimated: half HD720's focal length (the factory
    calibration files' ratio) and depth computed at that resolution, so twice the stereo noise."""
    from weldcell.hal.sim.camera_model import get_preset, zed_mode

    hd, vga = get_preset("zed2i"), zed_mode("VGA")
    assert (vga.width, vga.height) == (672, 376) and zed_mode("HD720").width == 1280
    assert vga.fx == pytest.approx(hd.fx / 2) and vga.cx == pytest.approx(335.5)
    assert vga.sigma(3.0) == pytest.approx(2 * hd.sigma(3.0))
    assert zed_mode("HD2K").width == 2208 and zed_mode("2K").fx == pytest.approx(2 * hd.fx)
    with pytest.raises(DataError, match="ZED resolution"):
        zed_mode("640x360")
    with pytest.raises(DataError, match="not a ZED"):
        zed_mode("VGA", "realsense-d435")


def test_profile_selects_a_zed_mode_for_the_simulated_camera():
    """`resolution = "VGA"` in a profile gives the camera the ZED's VGA mode; on a camera that is not a ZED
    the profile is refused with what to change."""
    from pydantic import ValidationError
    from weldcell.plugins.sim.settings import SimCameraSettings

    assert SimCameraSettings(preset="zed2i", resolution="VGA").resolution == "VGA"
    with pytest.raises(ValidationError, match="use preset = 'zed2i' or remove resolution"):
        SimCameraSettings(preset="realsense-d415", resolution="VGA")
    with pytest.raises(ValidationError):
        SimCameraSettings(preset="zed2i", resolution="640x360")
