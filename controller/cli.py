"""`pure-controller`: the reference controller as its own process, on any python-can bus and zenoh.

    pure-controller --can socketcan:vcan0 --zenoh configs/zenoh/loopback.json5 --rider configs/riders/X.toml

Stops cleanly on SIGINT or SIGTERM. Exit codes: 0 clean stop, 2 usage or configuration error.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # LQR on small matrices: 10-20x faster single-threaded

import argparse
import logging
import signal
import sys
import threading

import msgspec

from controller.config import ControllerConfig
from controller.embedded import start
from drivers.bus_config import BusConfigError, parse_can_spec
from drivers.config import ConfigError, load_toml
from drivers.devices import Devices
from drivers.dut import DutSpec
from drivers.resources import find
from drivers.zenoh_access import ZenohAccess
from drivers.zenoh_link import LOOPBACK, ZenohConfigError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="pure-controller", description="The reference PURE controller (device under test)"
    )
    p.add_argument("--can", default="pure_shared", help="INTERFACE[:CHANNEL], e.g. socketcan:vcan0")
    p.add_argument("--zenoh", default=str(LOOPBACK), help="zenoh config file (loopback by default)")
    p.add_argument("--hub", default=None, help="override the config's hub endpoint, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--certs", default=None, help="certificate folder on a secured bench (bench-client.json5)")
    p.add_argument("--identity", default="controller", help="its certificate's role on a secured bench")
    p.add_argument("--allow-network", action="store_true", help="a router on another host")
    p.add_argument("--prefix", default="pure", help="zenoh key prefix")
    p.add_argument("--rider", required=True, help="rider TOML (name and height are used)")
    p.add_argument("--robot", default="robot/pure.toml", help="the controller's robot model")
    p.add_argument("--config", default="controller/default.toml")
    p.add_argument(
        "--law",
        "--mode",
        dest="mode",
        choices=("hacs", "ihacs"),
        default=None,
        help="override the config's law (--mode: its old name)",
    )
    p.add_argument("--lockstep", action="store_true", help="wait for each tick's seat sample (lockstep rigs)")
    p.add_argument(
        "--devices",
        default=None,
        help="the drives' and IMU's device profile as JSON, e.g. '{\"drives\": \"odrive\"}' "
        "(a bench's [devices], docs/devices.md; default: the contract's own frames)",
    )
    return p


def parse_devices(text: str | None) -> Devices:
    """--devices JSON -> Devices; ConfigError names the flag, the field and what was expected."""
    if text is None:
        return Devices()
    try:
        return msgspec.json.decode(text, type=Devices)
    except msgspec.MsgspecError as exc:
        raise ConfigError("--devices", str(exc)) from exc


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        config_path = find(args.config, "controller")
        config = load_toml(config_path, ControllerConfig)
        mode = args.mode or config.mode
        spec = DutSpec(
            can=parse_can_spec(args.can),
            zenoh=ZenohAccess(
                mode="router" if args.certs else "loopback",
                endpoint=args.hub,
                certs=args.certs,
                config=args.zenoh,
                network=args.allow_network,
                prefix=args.prefix,
            ),
            identity=args.identity,
            mode=mode,
            robot=str(find(args.robot, "robot")),
            rider=str(find(args.rider, "riders")),
            controller_config=str(config_path),
            devices=parse_devices(args.devices),
            lockstep=args.lockstep,
            tick_hz=config.timing.tick_hz,
        )
        handle = start(spec)  # the rig's embedded plug, on a thread of its own: one wiring
    except (ConfigError, BusConfigError, ZenohConfigError) as exc:
        print(f"pure-controller: {exc}", file=sys.stderr)
        return 2
    logging.info("pure-controller (%s) on %s, zenoh %s: running", mode, args.can, args.zenoh)
    try:
        while not stop.wait(0.25):
            if not handle.alive():  # its thread ended on an error (on stderr): not a process left idle
                logging.error("pure-controller: the controller's thread ended on its own")
                return 1
    finally:
        handle.stop()
    # What it missed on the bus, as `pure-hil supervisor` says it (a reader that falls behind loses frames
    # silently on vcan: docs/bench.md).
    stats = handle.node.can.stats.as_dict()
    logging.info(
        "pure-controller: stopped; bus: lost %s, E2E %s, malformed %s, send errors %s",
        stats["lost_frames"],
        stats["e2e"],
        stats["malformed"],
        stats["send_errors"],
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
