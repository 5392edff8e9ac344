"""WebSocket client transport over the ``websockets`` sync client (extra ``leap``), imported on open."""

from __future__ import annotations

import json
from typing import Any

from weldcell.hal.transports.base import Backoff, Transport
from weldcell.sdk.errors import DataError, MissingExtraError


def _ws_client():
    try:
        from websockets.sync import client  # noqa: PLC0415 - vendor library, imported lazily on purpose
    except ImportError:
        raise MissingExtraError("the WebSocket transport", "websockets", "leap") from None
    return client


class WebSocketTransport(Transport):
    """A WebSocket client; a frame is one message (``str`` for text, ``bytes`` for binary)."""

    what = "WebSocket"

    def __init__(
        self,
        url: str,
        timeout: float = 1.0,
        open_timeout: float = 2.0,
        backoff: Backoff | None = None,
        max_size: int | None = 2**22,
    ) -> None:
        super().__init__(timeout, backoff)
        self.url = url
        self.open_timeout = float(open_timeout)
        self.max_size = max_size
        self._ws = None

    def describe(self) -> str:
        return self.url

    def fix_hint(self) -> str:
        return f"check that the service behind {self.url} is running and reachable"

    @property
    def is_open(self) -> bool:
        return self._ws is not None

    def _open(self) -> None:
        client = _ws_client()
        from websockets.exceptions import InvalidHandshake, InvalidURI  # noqa: PLC0415

        try:
            ws = client.connect(
                self.url, open_timeout=self.open_timeout, max_size=self.max_size, compression=None
            )
            # entering the connection is what ``with connect(...)`` does; it is closed in close()
            self._ws = ws.__enter__()
        except InvalidURI as e:
            from weldcell.sdk.errors import UsageError

            raise UsageError(
                f"invalid WebSocket URL {self.url!r}: {e}", "write it like ws://127.0.0.1:6437/v6.json"
            ) from e
        except InvalidHandshake as e:
            raise OSError(f"handshake refused ({e})") from e

    def _close(self) -> None:
        ws, self._ws = self._ws, None
        if ws is not None:
            ws.close()

    def send(self, data: str | bytes) -> None:
        """Send one message."""
        self.require_open()
        from websockets.exceptions import ConnectionClosed  # noqa: PLC0415

        try:
            self._ws.send(data)  # type: ignore[union-attr]
        except ConnectionClosed as e:
            self._close()
            raise self.closed(f"connection closed ({e})") from e

    def send_json(self, obj: Any) -> None:
        self.send(json.dumps(obj))

    def recv(self, timeout: float | None = None) -> str | bytes:
        """The next message; TransportTimeout when none arrives, TransportClosed when the peer closed."""
        self.require_open()
        from websockets.exceptions import ConnectionClosed  # noqa: PLC0415

        t = self.timeout if timeout is None else timeout
        try:
            return self._ws.recv(timeout=t)  # type: ignore[union-attr]
        except TimeoutError as e:
            raise self.timed_out("message", t) from e
        except ConnectionClosed as e:
            self._close()
            raise self.closed(f"connection closed by the peer ({e})") from e
        except OSError as e:
            self._close()
            raise self.closed(f"connection lost ({e})") from e

    read_frame = recv

    def recv_json(self, timeout: float | None = None) -> Any:
        """The next message decoded as JSON (DataError when it is not JSON)."""
        msg = self.recv(timeout)
        try:
            return json.loads(msg)
        except (ValueError, TypeError) as e:
            raise DataError(
                f"{self.url} sent a message that is not JSON: {str(msg)[:60]!r}",
                "check that the URL points at the device's JSON service",
            ) from e
