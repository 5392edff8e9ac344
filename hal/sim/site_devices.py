"""Simulated site sensors: the IMU and the GNSS receiver on a frame of the simulated world (on the site's
mobile base they measure its true motion along its route), streaming repeatably on the simulated clock.
"""

from __future__ import annotations

import threading

import numpy as np
from weldcell.hal.interfaces import Gnss, Imu
from weldcell.hal.readings import GnssFix, ImuReading
from weldcell.hal.sim.world import SimWorld
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import transform_points


class _SimClockStream:
    """Streaming on the simulated site, repeatable: every read delivers exactly the samples up to the
    simulated clock.

    The buffered stream's reader thread (:mod:`weldcell.hal.stream`) polls at wall-clock moments that
    the machine's load decides; on its own it would hand the consumer a different cut of samples each
    run (a GNSS fix one frame later, IMU noise drawn in other chunks). Here the reader thread and
    ``read_available`` both *catch up* to the simulated clock under one lock and push what they produced
    in order; so a read after the clock reached t holds every sample up to t, as a real device that kept
    up would have delivered by then, and nothing depends on the threads' timing.
    """

    def _site_burst(self) -> list:
        raise NotImplementedError

    def _on_site(self) -> bool:
        return getattr(self.world, "site", None) is not None

    def _catch_up(self) -> None:
        with self._clock_lock:
            readings = self._site_burst()
            s = self._stream
            if readings and s is not None:
                s._push(readings)  # noqa: SLF001 - under the lock: bursts stay in time order

    def _read_burst(self, timeout: float) -> list:
        if not self._on_site():
            return [self._read(timeout)]
        self._catch_up()
        return []

    def read_available(self, timeout: float = 0.0) -> list:
        if self._on_site() and self.streaming:
            try:
                self._catch_up()
            except DeviceError:
                pass  # a silent device: the reader thread hits it too and fails the stream (reported there)
        return super().read_available(timeout)


class SimImu(_SimClockStream, Imu):
    """A 9-axis IMU on a frame of the simulated world with its real model's errors (:mod:`.inertial`):
    white noise, bias random walk and turn-on bias of gyro and accelerometer, saturation, and a
    magnetometer with hard/soft iron and disturbance near steel.

    Mounted on the site's mobile base (frame ``base``) it measures the base's true motion along its
    route; on any other frame it measures a frame at rest. ``read()`` returns the next sample (and
    advances the simulated clock to it); a stream (``start_stream``) delivers every sample up to the
    simulated clock, stamped ``site epoch + simulated time`` (``device_stamp``: simulated time).
    ``stop_after`` (seconds of simulated time) makes the IMU fall silent (a pulled cable).
    """

    def __init__(
        self,
        world: SimWorld,
        parent: str = "world",
        T_parent_imu: np.ndarray | None = None,
        name: str = "imu",
        model=None,
        seed: int = 0,
        stop_after: float | None = None,
    ) -> None:
        from weldcell.hal.sim.inertial import ImuModel

        super().__init__(name, frame=name)
        self.world = world
        self.parent = parent
        self.T_parent_imu = np.eye(4) if T_parent_imu is None else np.asarray(T_parent_imu, float)
        self.model = model or ImuModel()
        self.seed = seed
        self.stop_after = stop_after
        self.connected = True
        self.sim = None
        self.stream_rate_hz = 100.0
        self._clock_lock = threading.Lock()

    def on_configure(self) -> None:
        from weldcell.hal.sim.inertial import ImuSimulator

        if not self.connected:
            raise DeviceError(f"simulated IMU '{self.name}' is not connected", "recover() reconnects")
        site = getattr(self.world, "site", None)
        if site is not None and self.parent == _SITE_BASE:
            route_kin = site.route.kinematics

            def kin(t):
                R, v, a, w = route_kin(t)
                return R, v, a, w, site.route.pos(np.clip(t, 0.0, site.route.duration))

            sim = ImuSimulator(self.model, kin, self.T_parent_imu, self.seed, site.distance_to_steel)
        else:
            T = self.world.T_world(self.parent)

            def kin(t):
                n = len(np.atleast_1d(t))
                z = np.zeros((n, 3))
                return np.tile(T[:3, :3], (n, 1, 1)), z, z, z, np.tile(T[:3, 3], (n, 1))

            sim = ImuSimulator(self.model, kin, self.T_parent_imu, self.seed)
        if self.sim is not None:  # a reconfigure keeps the sensor's own biases and time
            sim.b_g, sim.b_a, sim.t_next = self.sim.b_g, self.sim.b_a, self.sim.t_next
        sim.t_next = max(sim.t_next, self.world.clock.t)
        self.sim = sim

    def on_recover(self) -> None:
        self.connected = True

    def _epoch(self) -> float:
        site = getattr(self.world, "site", None)
        return site.epoch if site is not None else 0.0

    def _readings(self, t_end: float) -> list[ImuReading]:
        if not self.connected or (self.stop_after is not None and self.sim.t_next > self.stop_after):
            self.connected = False
            raise self.fault("no IMU data (the serial link is silent)")
        t, acc, gyr, mag, _ = self.sim.samples_until(t_end)
        e = self._epoch()
        return [
            ImuReading(e + t[i], acc[i], gyr[i], mag=mag[i], frame=self.name, device_stamp=float(t[i]))
            for i in range(len(t))
        ]

    def _read(self, timeout: float) -> ImuReading:
        t = self.sim.t_next
        if self.world.clock.t < t:
            self.world.clock.advance(t - self.world.clock.t)
        return self._readings(t)[0]

    def _site_burst(self) -> list:
        return self._readings(self.world.clock.t)


class SimGnss(_SimClockStream, Gnss):
    """A GNSS receiver (:mod:`.gnss_model`: u-blox M8T standalone or RTK) on a frame of the world;
    the world origin is at ``origin`` (lat, lon, alt), the world frame is the local ENU frame.

    On the site's mobile base it loses its fix under roofs and degrades near steel; fixes stream at
    ``model.rate`` up to the simulated clock (like :class:`SimImu`); a no-fix solution is a reading
    with ``fix_type`` "none" and NaN coordinates.
    """

    def __init__(
        self,
        world: SimWorld,
        parent: str = "world",
        name: str = "gnss",
        origin: tuple[float, float, float] = (22.5966, 113.9976, 30.0),
        model=None,
        seed: int = 0,
        T_parent_antenna: np.ndarray | None = None,
    ) -> None:
        from weldcell.hal.sim.gnss_model import GnssModel

        super().__init__(name, frame="enu")
        self.world = world
        self.parent = parent
        self.origin = origin
        self.model = model or GnssModel(mode="rtk")
        self.model.origin = origin
        self.seed = seed
        self.T_parent_antenna = np.eye(4) if T_parent_antenna is None else np.asarray(T_parent_antenna, float)
        self.sim = None
        self.stream_rate_hz = 20.0
        self._clock_lock = threading.Lock()

    def on_configure(self) -> None:
        from weldcell.hal.sim.gnss_model import GnssSimulator

        site = getattr(self.world, "site", None)
        lever = self.T_parent_antenna[:3, 3]
        if site is not None and self.parent == _SITE_BASE:

            def pos(t):
                return transform_points(site.route.pose(t), lever[None])[0]

            sim = GnssSimulator(self.model, pos, site.under_roof, site.distance_to_steel, self.seed)
        else:
            T = self.world.T_world(self.parent)

            def pos(t):
                return transform_points(T, lever[None])[0]

            sim = GnssSimulator(self.model, pos, seed=self.seed)
        if self.sim is not None:
            sim.t_next = self.sim.t_next
        sim.t_next = max(sim.t_next, self.world.clock.t)
        self.sim = sim

    def _fix(self, s: dict) -> GnssFix:
        from weldcell.hal.sim.gnss_model import enu_to_geodetic

        site = getattr(self.world, "site", None)
        stamp = (site.epoch if site is not None else 0.0) + s["t"]
        if s["enu"] is None:
            nan = float("nan")
            return GnssFix(stamp, nan, nan, nan, fix_type="none", device_stamp=s["t"], num_sv=2)
        lat, lon, alt = enu_to_geodetic(s["enu"], self.origin)
        cov = np.diag([s["sigma_h"] ** 2, s["sigma_h"] ** 2, s["sigma_v"] ** 2])
        return GnssFix(
            stamp,
            lat,
            lon,
            alt,
            enu=s["enu"],
            covariance=cov,
            fix_type=s["fix_type"],
            device_stamp=s["t"],
            h_acc=s["sigma_h"],
            v_acc=s["sigma_v"],
            num_sv=14,
        )

    def _read(self, timeout: float) -> GnssFix:
        t = self.sim.t_next
        if self.world.clock.t < t:
            self.world.clock.advance(t - self.world.clock.t)
        return self._fix(self.sim.samples_until(t)[0])

    def _site_burst(self) -> list:
        return [self._fix(s) for s in self.sim.samples_until(self.world.clock.t)]


_SITE_BASE = "base"  # the site's mobile base (hal.sim.site.BASE_FRAME)
