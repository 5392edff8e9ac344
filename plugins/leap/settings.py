"""Settings of the Leap Motion adapter (no vendor import here)."""

from __future__ import annotations

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class LeapSettings(Settings):
    """A Leap Motion controller through the Leap service's WebSocket (protocol v6, SDK 2.x/3.x)."""

    url: str = Field("ws://127.0.0.1:6437/v6.json", description="WebSocket URL of the Leap service")
    background: bool = Field(True, description="receive frames while another application has focus")
    focused: bool = Field(True, description="ask the service to treat this client as focused")
    enable_gestures: bool = Field(False, description="ask the service for its built-in gestures (not used)")
    open_timeout: Duration = Field(2.0, gt=0, description="WebSocket connect timeout [s]")
    frame_timeout: Duration = Field(1.0, gt=0, description="no frame for this long is a fault [s]")
    reconnect_attempts: int = Field(5, ge=1, description="reconnect tries after the service drops us")
    reconnect_delay: Duration = Field(
        0.05, gt=0, description="first wait between reconnect tries [s] (doubles)"
    )
