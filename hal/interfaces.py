"""The HAL device interfaces, one per device kind.

Adapters subclass one of these and implement the ``_``-prefixed methods (and the lifecycle hooks
of :class:`~weldcell.hal.lifecycle.Device`). The public methods check the lifecycle state first
(and, for robots, the safety gate: see :mod:`weldcell.hal.robot`).
"""

from __future__ import annotations

import numpy as np
from weldcell.hal.lifecycle import Device
from weldcell.hal.readings import (
    DepthFrame,
    Displacement,
    GnssFix,
    HandsFrame,
    Image,
    ImuReading,
    Intrinsics,
    Projection,
)
from weldcell.hal.stream import StreamingDevice, StreamStatus  # noqa: F401 - re-exported


class DepthCamera(Device):
    """A depth camera (structured light, stereo, ToF). Readings are in its optical frame."""

    kind = "depth_camera"

    def capture(self, timeout: float = 2.0) -> DepthFrame:
        """The next depth frame; :class:`DeviceError` when none arrives within ``timeout`` seconds."""
        self.require_active()
        frame = self._capture(timeout)
        self.mark_reading()
        return frame

    def intrinsics(self) -> Intrinsics:
        """Intrinsics of the depth stream (available once configured)."""
        return self._intrinsics()

    def _capture(self, timeout: float) -> DepthFrame:
        raise NotImplementedError

    def _intrinsics(self) -> Intrinsics:
        raise NotImplementedError


class GestureSensor(Device):
    """A hand tracker (Leap Motion). Positions in metres in the sensor frame."""

    kind = "gesture_sensor"

    def read(self, timeout: float = 1.0) -> HandsFrame:
        """The newest hands frame; :class:`DeviceError` when the sensor is silent or disconnected."""
        self.require_active()
        frame = self._read(timeout)
        self.mark_reading()
        return frame

    def _read(self, timeout: float) -> HandsFrame:
        raise NotImplementedError


class DisplacementSensor(StreamingDevice):
    """A 1-D laser displacement sensor (streams: see :mod:`weldcell.hal.stream`)."""

    kind = "displacement_sensor"

    def read(self, timeout: float = 0.5) -> Displacement:
        """One reading (``distance`` None when the target is out of range)."""
        self.require_active()
        self._refuse_while_streaming()
        r = self._read(timeout)
        self.mark_reading()
        return r

    def _read(self, timeout: float) -> Displacement:
        raise NotImplementedError


class LaserProjector(Device):
    """A laser/video projector drawing guidance lines onto the work (segments in the world frame, m)."""

    kind = "laser_projector"

    def project(self, segments: np.ndarray, label: str = "") -> Projection:
        """Draw line segments (N, 2, 3) in the world frame, replacing what was drawn."""
        self.require_active()
        seg = np.asarray(segments, dtype=float)
        if seg.ndim != 3 or seg.shape[1:] != (2, 3):
            from weldcell.sdk.errors import DataError

            raise DataError(
                f"segments must be (N, 2, 3), got {seg.shape}", "pass start/end points per segment"
            )
        self._project(seg, label)
        return Projection(stamp=self.mark_reading(), segments=seg, label=label)

    def clear(self) -> None:
        self.require_active()
        self._clear()

    def _project(self, segments: np.ndarray, label: str) -> None:
        raise NotImplementedError

    def _clear(self) -> None:
        raise NotImplementedError


class TactileCamera(Device):
    """The camera inside a soft tactile finger, watching a marker."""

    kind = "tactile_camera"

    def capture(self, timeout: float = 1.0) -> Image:
        self.require_active()
        img = self._capture(timeout)
        self.mark_reading()
        return img

    def _capture(self, timeout: float) -> Image:
        raise NotImplementedError


class Imu(StreamingDevice):
    """An inertial measurement unit (optionally with a magnetometer); streams: :mod:`weldcell.hal.stream`."""

    kind = "imu"

    def read(self, timeout: float = 0.5) -> ImuReading:
        """One reading; :class:`DeviceError` when none arrives within ``timeout`` or while streaming."""
        self.require_active()
        self._refuse_while_streaming()
        r = self._read(timeout)
        self.mark_reading()
        return r

    def _read(self, timeout: float) -> ImuReading:
        raise NotImplementedError


class Gnss(StreamingDevice):
    """A GNSS receiver (streams: :mod:`weldcell.hal.stream`). No fix is a reading with fix_type "none"."""

    kind = "gnss"
    stream_read_timeout = 1.5

    def read(self, timeout: float = 1.5) -> GnssFix:
        """The next solution; :class:`DeviceError` when none arrives within ``timeout`` or while streaming."""
        self.require_active()
        self._refuse_while_streaming()
        r = self._read(timeout)
        self.mark_reading()
        return r

    def _read(self, timeout: float) -> GnssFix:
        raise NotImplementedError


INTERFACES: dict[str, type[Device]] = {
    "depth_camera": DepthCamera,
    "gesture_sensor": GestureSensor,
    "displacement_sensor": DisplacementSensor,
    "laser_projector": LaserProjector,
    "tactile_camera": TactileCamera,
    "imu": Imu,
    "gnss": Gnss,
}
"""Device kind -> interface class (``robot`` is added by :mod:`weldcell.hal.robot`)."""
