"""Frames per second and one-way latency of one tick's frames through the drivers (CanNode: encode, E2E,
send, recv, decode, check) on a SocketCAN channel, next to python-can's in-process `virtual` bus measured
in the same run.

    python benchmarks/can_path.py                                  # virtual only (no vcan0 here)
    $VCAN_VM -- .venv/bin/python benchmarks/can_path.py --socketcan vcan0 --emulated   # the VM .ci/run uses

Inside vcan-vm the CPU is emulated (QEMU TCG, ~18x slower than the host): the figures are labelled so and
say what the path costs relative to the virtual bus on the same emulated CPU, not what a bench will see.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from can_roundtrip import TICK  # one tick's frames, shared with the other CAN benchmark

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, open_bus, private_channel


def measure(config: BusConfig, frames: int) -> tuple[float, np.ndarray]:
    """Send a frame, receive it on a second handle of the channel, one at a time: frames/s, latencies (s)."""
    a, b = open_bus(config), open_bus(config)
    tx, rx = CanNode(a, name="tx"), CanNode(b, name="rx")
    latency = np.empty(frames)
    try:
        for i in range(min(200, frames)):  # warm-up
            name, values = TICK[i % len(TICK)]
            tx.send(name, values)
            rx.recv(1.0)
        start = time.perf_counter()
        for i in range(frames):
            name, values = TICK[i % len(TICK)]
            t0 = time.perf_counter()
            tx.send(name, values)
            got = rx.recv(1.0)
            latency[i] = time.perf_counter() - t0
            if got is None or got.name != name or not got.ok:
                raise RuntimeError(f"frame {i} ({name}) lost or damaged: {got}")
        rate = frames / (time.perf_counter() - start)
    finally:
        a.shutdown()
        b.shutdown()
    return rate, latency


def report(label: str, rate: float, latency: np.ndarray) -> None:
    us = latency * 1e6
    print(
        f"  {label:<22} {rate:8.0f} frames/s   send->decoded p50 {np.percentile(us, 50):7.0f} µs   "
        f"p99 {np.percentile(us, 99):7.0f} µs   max {us.max():7.0f} µs"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=5000)
    parser.add_argument("--socketcan", default=None, help="a vcan/can interface to measure too, e.g. vcan0")
    parser.add_argument(
        "--emulated", action="store_true", help="label the figures as measured under emulation"
    )
    args = parser.parse_args()
    where = "under CPU emulation (vcan-vm, QEMU TCG)" if args.emulated else "on this host"
    print(f"one tick's frames through CanNode, one at a time, {args.frames} frames, measured {where}:")
    v_rate, v_lat = measure(BusConfig(channel=private_channel("bench")), args.frames)
    report("virtual (in-process)", v_rate, v_lat)
    if args.socketcan:
        s_rate, s_lat = measure(BusConfig(interface="socketcan", channel=args.socketcan), args.frames)
        report(f"socketcan {args.socketcan}", s_rate, s_lat)
        print(
            f"  socketcan / virtual: {s_rate / v_rate:.2f}x the frame rate, "
            f"{np.median(s_lat) / np.median(v_lat):.2f}x the p50 latency"
        )


if __name__ == "__main__":
    main()
