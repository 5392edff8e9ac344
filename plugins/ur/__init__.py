"""Universal Robots arms through ur-rtde (device ``robot.ur-rtde``). Registration only: no vendor import."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import DeviceError, MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "robot.ur-rtde"


def gate_model(model: str):
    """weldcell's kinematic model of a UR ``model`` for the safety gate, or None when there is none."""
    from weldcell.hal.kinematics import get_model
    from weldcell.sdk.errors import DataError

    try:
        return get_model(model)
    except DataError:
        return None


def _factory(settings, ctx):
    try:
        from weldcell.plugins.ur.adapter import URRobot
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "rtde_control", "ur") from None
    from weldcell.hal.safety import SafetyGate

    gate = SafetyGate(ctx.safety, model=gate_model(settings.model))
    return URRobot(settings, name=ctx.role, gate=gate, dry_run=ctx.dry_run)


def probe(settings) -> str:
    """Connect to the controller's RTDE port and read its version (no ur-rtde needed)."""
    from weldcell.plugins.ur.rtde_client import rtde_handshake

    try:
        v = rtde_handshake(settings.host, timeout=min(settings.connect_timeout, 2.0))
    except DeviceError as e:
        raise DeviceError(
            f"UR controller at {settings.host} does not answer on RTDE port 30004: {e.message}",
            "check the robot is on, the IP address, and that the PC is on the robot's network",
        ) from None
    return f"UR controller {v[0]}.{v[1]}.{v[2]}.{v[3]} at {settings.host} (RTDE protocol 2)"


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.ur.settings import URSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="robot",
            summary="Universal Robots CB3/e-Series arm over RTDE (ur-rtde)",
            settings=URSettings,
            factory=_factory,
            probe=probe,
            requires={"rtde_control": "ur", "rtde_receive": "ur", "dashboard_client": "ur"},
        )
    )
