"""ABB IRC5 arms through Robot Web Services + EGM (device ``robot.abb-rws``). Registration only: no
vendor import here (abb-robot-client is imported by the adapter, extra ``abb``)."""

from __future__ import annotations

from pathlib import Path

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import DeviceError, MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "robot.abb-rws"
RAPID_MODULE = Path(__file__).parent / "rapid" / "WeldcellServer.mod"
"""The RAPID server module to load into the controller's motion task (docs/devices/abb.md)."""


def _factory(settings, ctx):
    try:
        from weldcell.plugins.abb.adapter import ABBRobot
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "abb_robot_client", "abb") from None
    from weldcell.hal.kinematics import get_model
    from weldcell.hal.safety import SafetyGate

    gate = SafetyGate(ctx.safety, model=get_model(settings.model))
    return ABBRobot(settings, name=ctx.role, gate=gate, dry_run=ctx.dry_run)


def probe(settings) -> str:
    """Ask the controller's RWS for its state (needs abb-robot-client and the credentials)."""
    try:
        from abb_robot_client.rws import RWS
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "abb_robot_client", "abb") from None
    if settings.password is None:
        raise DeviceError(f"no RWS password for {settings.url}", 'set password = "${env:ABB_RWS_PASSWORD}"')
    rws = RWS(settings.url.rstrip("/"), settings.username, settings.password.get_secret_value())
    try:
        ctrl, mode = rws.get_controller_state(), rws.get_operation_mode()
        execution = rws.get_execution_state().ctrlexecstate
    except Exception as e:  # noqa: BLE001 - any failure means "not reachable" here
        raise DeviceError(
            f"ABB controller at {settings.url} does not answer RWS: {e}",
            "check the IP address (WAN port), the credentials and that the PC is on the robot's network",
        ) from None
    finally:
        rws.close()
    return f"ABB controller at {settings.url}: {ctrl}, {mode}, RAPID {execution} (RWS 1.0)"


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.abb.settings import ABBSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="robot",
            summary="ABB IRC5 (RobotWare 6) arm over Robot Web Services 1.0 + EGM (abb-robot-client)",
            settings=ABBSettings,
            factory=_factory,
            probe=probe,
            requires={"abb_robot_client": "abb"},
        )
    )
