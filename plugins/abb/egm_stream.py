"""The EGM side of the ABB adapter: abb-robot-client's :class:`~abb_robot_client.egm.EGM` on a background
thread that time-stamps every feedback message (250 Hz) and, while a pose servo runs, answers each one
with the next streamed target (``EgmSensor.planned.cartesian``)."""

from __future__ import annotations

import collections
import logging
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np
from abb_robot_client.egm import EGM, EGMRobotState
from weldcell.plugins.abb.rapid_values import T_from_abb, T_to_abb
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec

log = logging.getLogger("weldcell.abb.egm")


@dataclass(frozen=True)
class EgmSample:
    """One EGM feedback message: host arrival time, joints (rad), flange pose (m), status flags."""

    stamp: float
    seqno: int
    device_stamp: float
    """The controller's own clock (EgmHeader.tm, ms -> s): for latency estimation against ``stamp``."""
    q: np.ndarray
    T_base_flange: np.ndarray
    motors_on: bool
    rapid_running: bool
    mci_running: bool


class _BoundEGM(EGM):
    """The library's EGM client bound to a chosen local address (its constructor binds all interfaces)."""

    def __init__(self, host: str, port: int) -> None:  # noqa: D107 - same state as EGM.__init__
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind((host, port))
        self.send_sequence_number = 0
        self.egm_addr = None
        self.count = 0


def _sample(st: EGMRobotState, stamp: float) -> EgmSample | None:
    msg = st.robot_message
    if st.joint_angles is None or st.cartesian is None:
        return None
    return EgmSample(
        stamp=stamp,
        seqno=int(msg.header.seqno),
        device_stamp=float(msg.header.tm) / 1000.0,
        q=np.radians(np.asarray(st.joint_angles[:6], dtype=float)),
        T_base_flange=T_from_abb(st.cartesian[0], st.cartesian[1]),
        motors_on=bool(st.motors_on),
        rapid_running=bool(st.rapid_running),
        mci_running=msg.HasField("mciState") and msg.mciState.state == msg.mciState.MCI_RUNNING,
    )


class EgmStream:
    """Receives EGM feedback on a thread; keeps the latest sample and a time-stamped history."""

    def __init__(self, host: str, port: int, history: int = 4096) -> None:
        self.egm = _BoundEGM(host, port)
        self.port = int(self.egm.socket.getsockname()[1])
        self._lock = threading.Lock()
        self._latest: EgmSample | None = None
        self._history: collections.deque[EgmSample] = collections.deque(maxlen=history)
        self.overruns = 0
        self._servo_T: np.ndarray | None = None
        self._twist = np.zeros(6)
        self._twist_until = 0.0
        self._last_send = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"egm-{self.port}", daemon=True)
        self._thread.start()

    # -- reading ---------------------------------------------------------------------------------
    @property
    def latest(self) -> EgmSample | None:
        with self._lock:
            return self._latest

    def drain(self) -> list[EgmSample]:
        """Every sample received since the last call, oldest first (``overruns`` counts those dropped)."""
        with self._lock:
            out = list(self._history)
            self._history.clear()
        return out

    def wait_newer(self, stamp: float, count: int, timeout: float) -> bool:
        """Wait (bounded) until ``count`` samples newer than ``stamp`` arrived."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                n = sum(1 for s in self._history if s.stamp > stamp)
                if self._latest is not None and self._latest.stamp > stamp and n >= count:
                    return True
            time.sleep(0.001)
        return False

    # -- pose servo ------------------------------------------------------------------------------
    def servo(self, twist: np.ndarray, duration: float) -> None:
        """Move the streamed target with ``twist`` (flange, base frame, m/s and rad/s) for ``duration`` s."""
        with self._lock:
            if self._servo_T is None:
                self._servo_T = None if self._latest is None else self._latest.T_base_flange.copy()
            self._twist = np.asarray(twist, dtype=float).copy()
            self._twist_until = time.monotonic() + duration

    def hold(self) -> None:
        """Stop integrating: the target stays where it is (the robot converges and EGMRunPose ends)."""
        with self._lock:
            self._twist = np.zeros(6)

    def end_servo(self) -> None:
        with self._lock:
            self._servo_T, self._twist = None, np.zeros(6)

    def _correction(self, s: EgmSample) -> tuple[np.ndarray, np.ndarray] | None:
        with self._lock:
            if self._servo_T is None:
                return None
            now = time.monotonic()
            dt = min(now - self._last_send, 0.02) if self._last_send else 0.004
            self._last_send = now
            if now < self._twist_until and s.mci_running:
                tw = self._twist
                T = self._servo_T.copy()
                T[:3, 3] += tw[:3] * dt
                T[:3, :3] = T_from_rotvec(tw[3:] * dt)[:3, :3] @ T[:3, :3]
                self._servo_T = T
            return T_to_abb(self._servo_T)

    # -- thread ----------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ok, st = self.egm.receive_from_robot(timeout=0.05)
            except (OSError, ValueError) as e:  # socket closed under us, or a bad datagram
                if self._stop.is_set():
                    return
                log.debug("EGM receive failed: %s", e)
                continue
            except Exception as e:  # noqa: BLE001 - protobuf DecodeError: skip the datagram
                log.warning("EGM message dropped: %s", e)
                continue
            if not ok or st is None:
                continue
            try:
                s = _sample(st, time.time())
            except DataError as e:
                log.warning("EGM message dropped: %s", e.message)
                continue
            if s is None:
                continue
            with self._lock:
                if len(self._history) == self._history.maxlen:
                    self.overruns += 1
                self._latest = s
                self._history.append(s)
            corr = self._correction(s)
            if corr is not None:
                self.egm.send_to_robot_cart(corr[0], corr[1])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        try:
            self.egm.close()
        except Exception as e:  # noqa: BLE001 - closing a broken socket must not raise
            log.debug("EGM close: %s", e)
