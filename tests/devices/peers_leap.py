"""A stand-in for the Leap service: a local WebSocket server replaying a real recording as v6 JSON frames.

It sends ``{"serviceVersion": ..., "version": 6}`` first, then frames at ``fps`` from a shared cursor (a
reconnecting client continues where the stream was). ``drop_after(n)`` closes the connection after n
more frames; ``accepting = False`` refuses new connections with HTTP 503 (the service is down).
"""

from __future__ import annotations

import json
import threading
import time

from websockets.sync.server import serve


class LeapReplayServer:
    def __init__(self, frames: list[dict], fps: float = 200.0) -> None:
        self.frames = frames
        self.period = 1.0 / fps
        self.cursor = 0
        self.sent_ids: list[int] = []
        self.received: list[dict] = []
        self.connections = 0
        self.accepting = True
        self.paused = False
        self._drop_after: int | None = None
        self._lock = threading.Lock()
        self._closing = False
        self.server = serve(self._handler, "127.0.0.1", 0, process_request=self._gate)
        self.port = self.server.socket.getsockname()[1]
        self.url = f"ws://127.0.0.1:{self.port}/v6.json"
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def _gate(self, connection, request):
        if not self.accepting:
            return connection.respond(503, "Leap service is not running\n")
        return None

    def drop_after(self, n: int) -> None:
        self._drop_after = n

    def _handler(self, ws) -> None:
        self.connections += 1
        ws.send(json.dumps({"serviceVersion": "2.3.1+31549", "version": 6}))

        def listen():
            try:
                for msg in ws:
                    self.received.append(json.loads(msg))
            except Exception:  # noqa: BLE001 - the connection ends
                return

        threading.Thread(target=listen, daemon=True).start()
        try:
            while not self._closing:
                if self.paused:
                    time.sleep(0.01)
                    continue
                with self._lock:
                    if self._drop_after is not None:
                        if self._drop_after <= 0:
                            self._drop_after = None
                            ws.close()
                            return
                        self._drop_after -= 1
                    frame = self.frames[self.cursor % len(self.frames)]
                    self.cursor += 1
                    self.sent_ids.append(frame["id"])
                ws.send(json.dumps(frame))
                time.sleep(self.period)
        except Exception:  # noqa: BLE001 - client went away
            return

    def frame_by_id(self, fid: int) -> dict:
        return next(f for f in self.frames if f["id"] == fid)

    def close(self) -> None:
        self._closing = True
        self.server.shutdown()
        self._thread.join(2)
