"""Serial-port transport over pyserial (extra ``serial``), imported only when a port is opened."""

from __future__ import annotations

import time

from weldcell.hal.transports.base import Backoff, StreamTransport
from weldcell.sdk.errors import MissingExtraError


def _pyserial():
    try:
        import serial  # noqa: PLC0415 - vendor library, imported lazily on purpose
    except ImportError:
        raise MissingExtraError("the serial transport", "serial", "serial") from None
    return serial


class SerialTransport(StreamTransport):
    """A serial port (``/dev/ttyUSB0``, ``COM3`` or a pyserial URL such as ``loop://``).

    Reads poll the port for ``timeout`` seconds; a vanished device (USB unplugged) raises
    :class:`~weldcell.hal.transports.base.TransportClosed` and ``reconnect()`` reopens the port.
    """

    what = "serial"

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        timeout: float = 1.0,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: float = 1,
        rtscts: bool = False,
        xonxoff: bool = False,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(timeout, backoff)
        self.port = port
        self.options = dict(
            baudrate=int(baudrate),
            bytesize=bytesize,
            parity=parity,
            stopbits=stopbits,
            rtscts=rtscts,
            xonxoff=xonxoff,
        )
        self._ser = None

    def describe(self) -> str:
        return f"serial port {self.port} @ {self.options['baudrate']} baud"

    def fix_hint(self) -> str:
        return (
            f"check that {self.port} exists, the device is plugged in and powered, you may open it "
            "(e.g. member of the 'dialout' group), and no other program holds it"
        )

    @property
    def is_open(self) -> bool:
        return self._ser is not None and bool(self._ser.is_open)

    def _open(self) -> None:
        serial = _pyserial()
        self._buf.clear()
        try:
            self._ser = serial.serial_for_url(
                self.port, timeout=0, write_timeout=self.timeout, **self.options
            )
        except serial.SerialException as e:
            self._ser = None
            raise OSError(str(e)) from e
        except ValueError as e:
            from weldcell.sdk.errors import UsageError

            raise UsageError(
                f"invalid serial settings for {self.port}: {e}",
                "use a standard baud rate, bytesize 5-8, parity N/E/O/M/S, stopbits 1/1.5/2",
            ) from e

    def _close(self) -> None:
        ser, self._ser = self._ser, None
        self._buf.clear()
        if ser is not None:
            ser.close()

    def _read_some(self, timeout: float) -> bytes:
        serial = _pyserial()
        ser = self._ser
        if ser is None:
            raise self.closed("not open")
        deadline = time.monotonic() + timeout
        while True:
            try:
                n = ser.in_waiting
                data = ser.read(max(1, n))
            except (serial.SerialException, OSError) as e:
                self._close()
                raise self.closed(f"the port failed ({e}); the device may have been unplugged") from e
            if data:
                return data
            left = deadline - time.monotonic()
            if left <= 0:
                return b""
            time.sleep(min(0.002, left))

    def _write(self, data: bytes) -> None:
        serial = _pyserial()
        ser = self._ser
        if ser is None:
            raise self.closed("not open")
        try:
            ser.write(data)
            ser.flush()
        except serial.SerialTimeoutException as e:
            raise self.timed_out("room to send", self.timeout) from e
        except (serial.SerialException, OSError) as e:
            self._close()
            raise self.closed(f"write failed ({e})") from e
