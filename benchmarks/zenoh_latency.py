"""zenoh put -> subscriber callback latency on loopback (two sessions, hub + member, tcp/127.0.0.1), with the
TES wrench payload, paced at 1 kHz; plus the msgpack encode/decode cost of that payload.

    python benchmarks/zenoh_latency.py [--samples N]
"""

from __future__ import annotations

import argparse
import socket
import threading
import time

from drivers.keys import Keys
from drivers.schemas import TesWrench, decode, encode
from drivers.zenoh_link import ZenohLink, open_session


def percentile(sorted_values, q):
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--samples", type=int, default=5000)
    args = parser.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    hub = open_session(role="hub", hub_endpoint=endpoint)
    member = open_session(role="member", hub_endpoint=endpoint)
    key = Keys().tes_wrench
    latencies: list[float] = []
    done = threading.Event()

    def on_sample(sample):
        now = time.perf_counter()
        msg = decode(sample.payload.to_bytes(), TesWrench)
        latencies.append(now - msg.stamp)
        if len(latencies) >= args.samples:
            done.set()

    member.declare_subscriber(key, on_sample)
    link = ZenohLink(hub)
    pub = link.publisher(key)
    while not pub.matching_status.matching:
        time.sleep(0.01)
    next_t = time.perf_counter()
    for seq in range(args.samples):
        next_t += 0.001
        while time.perf_counter() < next_t:
            time.sleep(max(next_t - time.perf_counter() - 0.0002, 0))
        msg = TesWrench(
            seq=seq,
            stamp=time.perf_counter(),
            force=(1.0, 2.0, -600.0),
            moment=(0.1, 27.0, 0.0),
            cop=(0.04, 0.0),
        )
        pub.put(encode(msg))
    done.wait(10)
    lat = sorted(x * 1e6 for x in latencies)
    sample = TesWrench(seq=1, stamp=1.0, force=(1.0, 2.0, -600.0), moment=(0.1, 27.0, 0.0), cop=(0.04, 0.0))
    raw = encode(sample)
    n = 20000
    t0 = time.perf_counter()
    for _ in range(n):
        encode(sample)
    enc = (time.perf_counter() - t0) / n * 1e6
    t0 = time.perf_counter()
    for _ in range(n):
        decode(raw, TesWrench)
    dec = (time.perf_counter() - t0) / n * 1e6
    print(
        f"zenoh put -> callback, 2 sessions over {endpoint}, TesWrench ({len(raw)} B), 1 kHz, "
        f"{len(lat)}/{args.samples} received"
    )
    print(
        f"  latency us: p50 {percentile(lat, 0.5):.0f}  p99 {percentile(lat, 0.99):.0f}  "
        f"p99.9 {percentile(lat, 0.999):.0f}  max {lat[-1]:.0f}"
    )
    print(f"  msgpack encode {enc:.2f} us, validated decode {dec:.2f} us per payload")
    member.close()
    hub.close()


if __name__ == "__main__":
    main()
