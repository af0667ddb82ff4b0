"""`pure-hil router`: its options and its handler (its summary: hil/cli.py COMMANDS)."""

from __future__ import annotations

import argparse

from hil.commands.common import until_interrupted


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--certs", required=True, help="certificate folder (pure-hil certs init)")
    parser.add_argument("--config", default=None, help="default: configs/zenoh/bench-router.json5")
    parser.add_argument(
        "--listen", default=None, help="endpoint, e.g. tls/BENCH_HOST_IP:7448 (default loopback)"
    )
    parser.add_argument("--allow-network", action="store_true", help="needed for a non-loopback endpoint")


def handle(args: argparse.Namespace) -> int:
    from drivers.zenoh_link import CONFIG_DIR, open_session

    config = args.config or CONFIG_DIR / "bench-router.json5"
    session = open_session(
        config, hub_endpoint=args.listen, allow_network=args.allow_network, certs=args.certs
    )
    until_interrupted(f"pure-hil router: {config} (mutual TLS, ACL default deny); Ctrl-C to stop")
    session.close()
    return 0
