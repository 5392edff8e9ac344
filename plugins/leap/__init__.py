"""Leap Motion through its WebSocket service (device ``gesture.leap``). Registration only."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import DeviceError, MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "gesture.leap"


def _factory(settings, ctx):
    try:
        from weldcell.plugins.leap.adapter import LeapMotion
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "websockets", "leap") from None
    return LeapMotion(settings, name=ctx.role)


def probe(settings) -> str:
    """Connect to the service's WebSocket and read its version message."""
    from weldcell.hal.transports import TransportTimeout, WebSocketTransport

    ws = WebSocketTransport(settings.url, open_timeout=min(settings.open_timeout, 2.0))
    try:
        ws.open()
        try:
            first = ws.recv_json(timeout=1.0)
        except TransportTimeout:
            first = {}
    except DeviceError as e:
        raise DeviceError(
            f"Leap service not reachable at {settings.url}: {e.message}",
            "start the Leap service with 'Allow Web Apps' enabled",
        ) from None
    finally:
        ws.close()
    version = first.get("serviceVersion") if isinstance(first, dict) else None
    return f"Leap service {version or '(version not sent)'} at {settings.url}"


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.leap.settings import LeapSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="gesture_sensor",
            summary="Leap Motion hand tracker (WebSocket service v6)",
            settings=LeapSettings,
            factory=_factory,
            probe=probe,
            requires={"websockets": "leap"},
        )
    )
