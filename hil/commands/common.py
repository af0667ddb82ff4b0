"""What the commands share: the bench and its overrides, number options, run folders, progress, signals,
the operator's way to a rig."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from drivers.bounds import MAX_DURATION
from drivers.resources import shipped

if TYPE_CHECKING:
    from hil.bench.bench import Bench

WHERE = ("embedded", "spawned", "external")


def add_bench_options(parser: argparse.ArgumentParser, clock: bool = False, plant: bool = False) -> None:
    """The bench and the few options that override one part of it; `clock` and `plant` for the commands
    that run scenarios (`clock` implies `plant`)."""
    group = parser.add_argument_group("the bench (configs/benches/*.toml; docs/bench.md)")
    group.add_argument(
        "--bench",
        default=None,
        help=f"bench file or shipped name: {', '.join(shipped('benches'))} (default embedded; a campaign: "
        "its own bench, else embedded)",
    )
    group.add_argument(
        "--can", default=None, help="override the bus: INTERFACE:CHANNEL, e.g. socketcan:vcan0"
    )
    group.add_argument("--controller", choices=WHERE, default=None, help="where the controller runs")
    group.add_argument(
        "--law", choices=("hacs", "ihacs"), default=None, help="the reference controller's law"
    )
    group.add_argument("--supervisor", choices=WHERE, default=None, help="where the supervisor runs")
    group.add_argument("--hub", default=None, help="zenoh endpoint: the rig's hub (loopback) or the router's")
    group.add_argument(
        "--certs", default=None, help="certificate folder on a secured bench (pure-hil certs init)"
    )
    if clock:
        group.add_argument(
            "--clock",
            choices=("lockstep", "realtime"),
            default=None,
            help="lockstep: as fast as the loop goes, the controller answering each SYNC; realtime: 400 Hz "
            "of wall time (default: the scenario's, or the bench's)",
        )
    if clock or plant:
        group.add_argument(
            "--plant",
            metavar="NAME",
            default=None,
            help="an installed plant: 3d (MuJoCo rigid bodies), planar (two planes and yaw, for regression) "
            "or a lab's own (entry points pure_hil.plants; default: the bench's sim settings, 3d)",
        )


def bench_from(args: argparse.Namespace):
    from drivers.bus_config import parse_can_spec
    from drivers.zenoh_link import check_endpoint
    from hil.bench.bench import EMBEDDED, load_bench

    bench = load_bench(args.bench or EMBEDDED)
    return bench.with_overrides(
        can=None if args.can is None else parse_can_spec(args.can, bench.can),
        controller=args.controller,
        law=args.law,
        supervisor=args.supervisor,
        hub=None if args.hub is None else check_endpoint(args.hub, "--hub", bench.zenoh.network),
        certs=args.certs,
        clock=getattr(args, "clock", None),
        plant=getattr(args, "plant", None),
    )


def out_folder(args: argparse.Namespace, bench: Bench, name: str) -> Path:
    """`--out`, or a fresh NAME-TIMESTAMP folder under the bench's output folder (every command alike),
    made now: a path that cannot be a folder is a usage error before anything runs."""
    from drivers.config import ConfigError

    if args.out:
        out, origin = Path(args.out), "--out"
    else:
        out = Path(bench.outputs.folder) / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
        origin = f"bench {bench.name} outputs.folder"
    if out.exists() and not out.is_dir():
        raise ConfigError(origin, f"{out} exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(origin, f"cannot make the folder {out}: {exc.strerror or exc}") from None
    return out


def number(kind: type, low: float, high: float = math.inf, low_open: bool = False):
    """An argparse type: a finite number of `kind` within [low, high] ((low, high] if low_open)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        below = value <= low if low_open else value < low
        if not math.isfinite(value) or below or value > high:
            bounds = f"{'>' if low_open else '>='} {low:g}" + (f" and <= {high:g}" if high < math.inf else "")
            raise argparse.ArgumentTypeError(f"expected {bounds}, got {text}")
        return value

    return parse


SEED = number(int, 0)
COUNT = number(int, 1)
DURATION = number(float, 0.0, MAX_DURATION, low_open=True)


def progress_bar(total: int, unit: str):
    """A progress bar with counts and ETA on a terminal (stderr); None elsewhere (CI logs keep lines)."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, file=sys.stderr, dynamic_ncols=True)


def stop_on_signals() -> threading.Event:
    """An event SIGINT or SIGTERM sets: the long-running commands' clean stop."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def until_interrupted(
    message: str,
    alive: Callable[[], bool] | None = None,
    then: Callable[[int, FrameType | None], object] | None = None,
    stop: threading.Event | None = None,
) -> bool:
    """Print `message`, then block until SIGINT or SIGTERM (True), or until `alive()` says the part it
    started has ended on its own (False: its thread's error is already on stderr); from then on a second
    signal ends the process at once (what the first started, e.g. writing a run's folder, is left
    unfinished): by the OS, or by `then(signum, frame)`, which records what it must and leaves itself.
    `stop`: stop_on_signals()'s, taken before the part started (a signal while it starts is then a clean
    stop, not a KeyboardInterrupt)."""
    stop = stop or stop_on_signals()
    print(message, flush=True)
    interrupted = True
    # Never an untimed wait: a signal the kernel hands to another thread (zenoh's, a run's) only trips
    # Python's flag, and its handler runs when the main thread next runs bytecode; blocked for good in
    # the Event's lock, it never would (a served run once ignored its Ctrl-C for 15 minutes).
    while not stop.wait(ALIVE_CHECK):
        if alive is not None and not alive():
            interrupted = False
            break
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL if then is None else then)
    return interrupted


ALIVE_CHECK = 0.25
"""s between looks at whether a part a command runs is still alive, and at a signal another thread took."""


def part_ended(command: str, part: str, node: object, interrupted: bool) -> int:
    """A part command's last words: what the part missed on the bus, where its plug keeps the reference's
    counters (a reader that falls behind loses frames silently on vcan: docs/bench.md; the contract does not
    ask for them), and its exit code: 1 if the part ended on its own, not on a signal."""
    can_node = getattr(node, "can", None)
    if can_node is not None:
        stats = can_node.stats.as_dict()
        print(f"  bus: lost {stats['lost_frames']}, E2E {stats['e2e']}, malformed {stats['malformed']}")
    if not interrupted:
        print(f"pure-hil {command}: the {part} ended on its own (its error is above)", file=sys.stderr)
        return 1
    return 0


def join_rig(args: argparse.Namespace):
    """An operator client's bench, zenoh session and the card of the rig it reached: the hub from --hub,
    $PURE_HIL_HUB, the one live rig of the bench on this machine, or the bench file; a rig of another
    bench is refused unless the hub was named (hil/bench/rigs.py; docs/rig.md "Which rig")."""
    from drivers.zenoh_link import check_endpoint
    from hil.bench.rigs import HUB_VARIABLE, choose_hub, greet

    bench = bench_from(args)
    named = args.hub or os.environ.get(HUB_VARIABLE)
    if named and not args.hub:
        named = check_endpoint(named, HUB_VARIABLE, bench.zenoh.network)
    if bench.zenoh.mode != "loopback":
        return bench, bench.zenoh.open(args.identity), None
    bench = bench.with_overrides(hub=choose_hub(bench.name, named, bench.zenoh.endpoint))
    session = bench.zenoh.open(args.identity)
    try:
        return bench, session, greet(session, bench.zenoh.prefix, None if named else bench.name)
    except BaseException:
        session.close()
        raise


def ask_service(args: argparse.Namespace, name: str, payload: str, who: str) -> int:
    """One query to a running `pure-hil serve` (pure/rig/NAME); prints its JSON reply; 0 if it says ok."""
    from drivers.keys import Keys

    bench, session, _card = join_rig(args)
    try:
        replies = list(session.get(Keys(bench.zenoh.prefix).rig(name), payload=payload, timeout=10.0))
    finally:
        session.close()
    if not replies or replies[0].ok is None:
        print(
            f"{who}: no answer (is `pure-hil serve` running, and may {args.identity} ask it?)",
            file=sys.stderr,
        )
        return 1
    body = replies[0].ok.payload.to_string()
    print(body)
    reply = json.loads(body)
    return 0 if reply.get("ok") else 2 if reply.get("refused") else 1
