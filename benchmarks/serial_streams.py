"""Buffered serial streams end to end over a pseudo-terminal: optoNCDT 1402 at 1.5 kHz, HFI-A9 IMU.

For each device a protocol peer (tests/devices/peers_*.py) streams for ``--seconds``; the adapter's
HAL stream (hal/stream.py) collects everything. Reported: readings delivered per second, readings
lost (peer sent - delivered), overruns, the stamps' period error against the device rate (median and
99th percentile of |dt - 1/rate|), and the process CPU time (peer thread included) per reading.

    .venv/bin/python benchmarks/serial_streams.py --seconds 5
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from weldcell.plugins.imu_serial.adapter import SerialImu  # noqa: E402
from weldcell.plugins.imu_serial.settings import ImuSerialSettings  # noqa: E402
from weldcell.plugins.optoncdt.adapter import OptoNcdt  # noqa: E402
from weldcell.plugins.optoncdt.settings import OptoNcdtSettings  # noqa: E402

from tests.devices.peers_imu_serial import ImuPeer  # noqa: E402
from tests.devices.peers_optoncdt import OptoNcdtPeer  # noqa: E402


def run(dev, peer, sent, rate: float, seconds: float) -> dict:
    got = []
    with dev:
        dev.start_stream()
        c0 = time.process_time()
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            got += dev.read_available(timeout=0.05)
        cpu = time.process_time() - c0
        got += dev.stop_stream()
        st = dev.stream_status()
    n_sent = sent()
    dt = np.diff([r.stamp for r in got])
    err = np.abs(dt - 1.0 / rate)
    return {
        "delivered/s": len(got) / seconds,
        "sent": n_sent,
        "delivered": len(got),
        "overruns": st.overruns,
        "period err median [us]": 1e6 * float(np.median(err)),
        "period err p99 [us]": 1e6 * float(np.percentile(err, 99)),
        "CPU per reading [us]": 1e6 * cpu / max(1, len(got)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    a = ap.parse_args()
    rows = []
    pe = OptoNcdtPeer(rate=1500).start()
    try:
        dev = OptoNcdt(OptoNcdtSettings(port=pe.path, rate_hz=1500), name="laser")
        rows.append(("optoNCDT 1402 @ 1500 Hz", run(dev, pe, lambda: len(pe.sent_values), 1500, a.seconds)))
    finally:
        pe.close()
    for proto, rate in (("hfi-a9", 400.0), ("witmotion", 200.0)):
        pe = ImuPeer(protocol=proto, rate=rate).start()
        try:
            dev = SerialImu(ImuSerialSettings(port=pe.path, protocol=proto, rate_hz=rate), name="imu")
            r = run(dev, pe, lambda p=pe: p.samples, rate, a.seconds)
            rows.append((f"IMU {proto} @ {rate:.0f} Hz", r))
        finally:
            pe.close()
    keys = list(rows[0][1])
    print("| device | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, r in rows:
        cells = [f"{r[k]:.1f}" if isinstance(r[k], float) else str(r[k]) for k in keys]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
