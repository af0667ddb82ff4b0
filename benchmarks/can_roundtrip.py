"""Cost per CAN frame through the drivers (encode + E2E + send + recv + decode + E2E check) on python-can's
`virtual` bus, against bare python-can send + recv of the same frames measured in the same run.

    python benchmarks/can_roundtrip.py [--frames N]
"""

from __future__ import annotations

import argparse
import statistics
import time

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel
from drivers.can_codec import Catalog

# One tick's worth of frames, in the order the rig and the controller send them.
TICK = [
    ("DRIVE1_FEEDBACK", {"Position": 123456, "Velocity": 12.34, "Enabled": 1}),
    ("DRIVE2_FEEDBACK", {"Position": -654321, "Velocity": -3.21, "Enabled": 1}),
    ("DRIVE3_FEEDBACK", {"Position": 42, "Velocity": 0.5, "Enabled": 1}),
    ("IMU_ATTITUDE", {"Roll": 0.01, "Pitch": -0.02, "Yaw": 1.5, "Valid": 1}),
    ("IMU_RATE", {"RateX": 0.1, "RateY": -0.2, "RateZ": 0.05, "Valid": 1}),
    ("IMU_ACCEL", {"AccX": 0.3, "AccY": -0.1, "AccZ": 9.81, "Valid": 1}),
    ("SYNC", {"Tick": 7}),
    ("DRIVE1_COMMAND", {"Torque": 1.25, "Tick": 7, "Enable": 1}),
    ("DRIVE2_COMMAND", {"Torque": -0.75, "Tick": 7, "Enable": 1}),
    ("DRIVE3_COMMAND", {"Torque": 0.5, "Tick": 7, "Enable": 1}),
    ("CONTROLLER_HEARTBEAT", {"State": 3, "Mode": 1}),
]


def per_frame_us(fn, frames: int, batch: int = 500) -> tuple[float, float]:
    means = []
    for _ in range(max(frames // batch, 1)):
        t0 = time.perf_counter_ns()
        for i in range(batch):
            fn(i)
        means.append((time.perf_counter_ns() - t0) / batch / 1e3)
    means.sort()
    return statistics.median(means), means[int(0.99 * (len(means) - 1))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=50000)
    args = parser.parse_args()
    catalog = Catalog()
    config = BusConfig(channel=private_channel("bench"))
    a, b = open_bus(config), open_bus(config)
    tx, rx = CanNode(a, catalog, "tx"), CanNode(b, catalog, "rx")
    prebuilt = [tx.message(name, values) for name, values in TICK]

    def bare(i):
        a.send(prebuilt[i % len(prebuilt)])
        b.recv(0)

    def drivers(i):
        name, values = TICK[i % len(TICK)]
        tx.send(name, values)
        rx.decode(b.recv(0))

    def cantools_codec(i):
        name, values = TICK[i % len(TICK)]
        m = catalog.database.get_message_by_name(name)
        m.decode(m.encode({s.name: values.get(s.name, 0) for s in m.signals}), decode_choices=False)

    def our_codec(i):
        name, values = TICK[i % len(TICK)]
        c = catalog[name]
        c.decode(c.encode(values))

    rows = [
        ("bare python-can send+recv (baseline)", *per_frame_us(bare, args.frames)),
        ("drivers: encode+E2E+send+recv+decode+E2E", *per_frame_us(drivers, args.frames)),
        ("cantools encode+decode (no bus)", *per_frame_us(cantools_codec, args.frames // 5)),
        ("compiled codec encode+decode (no bus)", *per_frame_us(our_codec, args.frames)),
    ]
    base = rows[0][1]
    print(f"CAN per-frame cost on the virtual bus ({args.frames} frames; p50 / p99 of batch means)")
    print(f"{'path':<44} {'p50 us':>8} {'p99 us':>8} {'x baseline':>11}")
    for label, p50, p99 in rows:
        print(f"{label:<44} {p50:8.2f} {p99:8.2f} {p50 / base:11.2f}")
    print(f"one tick of {len(TICK)} frames through the drivers: {rows[1][1] * len(TICK):.0f} us (p50)")
    assert not rx.stats.e2e and not rx.stats.malformed, rx.stats
    a.shutdown()
    b.shutdown()


if __name__ == "__main__":
    main()
