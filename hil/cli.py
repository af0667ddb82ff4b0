"""`pure-hil` command line. Exit codes: 0 pass, 1 fail (e.g. the robot fell), 2 usage or config error."""

from __future__ import annotations

import os

# Tiny LAPACK calls (LQR, ARE) are 10-20x slower with OpenBLAS's thread pool on small machines.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
import time
from pathlib import Path

import msgspec

from drivers.config import ConfigError, load_toml
from drivers.resources import find


def _simulate(args: argparse.Namespace) -> int:
    from hil.plant_run import default_intent, format_summary, run_plant
    from plant.params import RiderParams, RobotParams, SimParams

    robot = load_toml(find(args.robot, "robot"), RobotParams)
    rider = None if args.no_rider else load_toml(find(args.rider, "riders"), RiderParams)
    sim = load_toml(find(args.sim, "sim"), SimParams)
    if args.seed is not None:
        sim = msgspec.structs.replace(sim, seed=args.seed)
    started = time.perf_counter()
    summary = run_plant(robot, rider, sim, default_intent(args.lean, args.duration), args.duration, args.tilt)
    wall = time.perf_counter() - started
    print(
        f"pure-hil simulate: plant-only run of {robot.name} on the ideal truth balancer, "
        f"rider leaning {args.lean:g} deg"
    )
    print(format_summary(summary))
    print(f"  {'wall time':<24}  {wall:.2f} s ({summary.sim_time / wall:.1f}x real time)")
    return 1 if summary.fallen else 0


def _progress(t: float, duration: float) -> None:
    width = 30
    done = int(width * min(t / duration, 1.0))
    print(
        f"\r  [{'#' * done}{'.' * (width - done)}] {t:6.2f} / {duration:g} s",
        end="",
        file=sys.stderr,
        flush=True,
    )


def _run(args: argparse.Namespace) -> int:
    from drivers.can_bus import BusConfigError, parse_can_spec
    from hil.runner import format_table, load_scenario, run_scenario

    scenario = load_scenario(find(args.scenario, "scenarios"))
    try:
        can = parse_can_spec(args.can) if args.can else None
    except BusConfigError as exc:
        print(f"pure-hil: {exc}", file=sys.stderr)
        return 2
    controller = args.controller or scenario.controller
    mode = controller if controller in ("hacs", "ihacs") else "hacs"
    if args.spawn_controller:
        controller = "external"
    shared_bus = can is not None and can.interface != "virtual"
    for what, external in (
        ("--controller", controller == "external"),
        ("--supervisor", args.supervisor == "external"),
    ):
        if external and not shared_bus:
            print(
                f"pure-hil: {what} external needs a bus shared with another process "
                "(e.g. --can socketcan:vcan0)",
                file=sys.stderr,
            )
            return 2
    out = Path(args.out) if args.out else Path("runs") / f"{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    show_progress = sys.stderr.isatty() and not args.quiet
    clock = args.clock or scenario.clock
    print(f"pure-hil run: {scenario.name} ({controller}, {clock}) -> {out}")
    spawned = _spawn_controller(args.can, scenario, mode, clock, args.hub) if args.spawn_controller else None
    try:
        result = run_scenario(
            scenario,
            controller=controller,
            can=can,
            clock=args.clock,
            seed=args.seed,
            out=out,
            progress=_progress if show_progress else None,
            supervisor=args.supervisor,
            hub_endpoint=args.hub,
        )
    finally:
        if spawned is not None:
            _stop(spawned)
    if show_progress:
        print(file=sys.stderr)
    failure = result.trace.failure
    if failure is not None and not len(result.trace.t):
        print(f"pure-hil: {failure.error} ({failure.stage}; summary: {out}/summary.json)", file=sys.stderr)
        return 2 if failure.config else 1
    print(format_table(result))
    print(f"outputs: {out}/summary.json, can.log, recording.rrd, plots.png")
    return 0 if result.passed else 1


def _spawn_controller(can_spec: str, scenario, mode: str, clock: str, hub: str | None):
    """`pure-controller` as a subprocess on the rig's bus (the rig is the zenoh hub it joins)."""
    import subprocess

    script = Path(sys.executable).with_name("pure-controller")
    command = [str(script) if script.exists() else "pure-controller", "--can", can_spec]
    command += [
        "--rider",
        str(find(scenario.rider, "riders")),
        "--robot",
        str(find(scenario.robot, "robot")),
        "--mode",
        mode,
    ]
    if clock == "lockstep":
        command.append("--lockstep")
    if hub is not None:
        command += ["--hub", hub]
    print(f"pure-hil run: spawned {' '.join(command)}")
    return subprocess.Popen(command)


def _stop(proc) -> None:
    import signal
    import subprocess

    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()


def _campaign(args: argparse.Namespace) -> int:
    """A campaign's cases in parallel processes: progress, a report (worst first) and JUnit XML."""
    from hil.campaign import expand, junit_xml, load_campaign, report, run_campaign

    try:
        campaign = load_campaign(find(args.file, "campaigns"))
        cases = expand(campaign, args.select)
    except ValueError as exc:
        print(f"pure-hil campaign: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out or f"runs/campaign-{campaign.name}-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    print(f"campaign {campaign.name}: {len(cases)} cases on {args.workers} worker(s) -> {out}", flush=True)

    def progress(done: int, total: int, r) -> None:
        verdict = "ERROR" if r.error else "PASS" if r.passed else "FAIL"
        print(f"[{done}/{total}] {verdict:5s} {r.case_id} ({r.wall:.1f} s)", flush=True)
        for line in r.message().splitlines() if not r.passed else ():
            print(f"        {line}", flush=True)

    if args.can and args.workers > 1:
        print("pure-hil campaign: on a shared bus (--can) cases run one at a time", file=sys.stderr)
    results = run_campaign(cases, args.workers, out, progress, args.can, args.controller)
    text = report(campaign.name, results)
    (out / "report.md").write_text(text)
    (out / "junit.xml").write_bytes(junit_xml(campaign.name, results))
    print(text)
    print(f"report: {out / 'report.md'}  junit: {out / 'junit.xml'}")
    return 0 if all(r.passed for r in results) else 1


def _compare(args: argparse.Namespace) -> int:
    from hil.compare import PAPER_RIDERS, compare, write
    from hil.runner import load_scenario
    from plant.params import RiderParams

    scenarios = [load_scenario(find(s, "scenarios")) for s in args.scenarios]
    riders = tuple(args.riders) if args.riders else PAPER_RIDERS
    for rider in riders:
        load_toml(find(rider, "riders"), RiderParams)  # a bad rider file fails now, not after an hour of runs
    print(
        f"pure-hil compare: {len(scenarios)} scenario(s) x {len(riders)} rider(s) x {args.trials} trial(s) "
        f"x HACS/iHACS, lockstep"
    )
    result = compare(scenarios, tuple(str(find(r, "riders")) for r in riders), args.trials)
    out = Path(args.out) if args.out else Path("runs") / f"compare-{time.strftime('%Y%m%d-%H%M%S')}"
    write(result, out)
    print(result.table())
    print(f"outputs: {out}/compare.md, compare.json")
    return 0


def _controller(args: argparse.Namespace) -> int:
    """Start the reference controller as its own process (the rig never imports a controller)."""
    import subprocess

    script = Path(sys.executable).with_name("pure-controller")
    command = [str(script) if script.exists() else "pure-controller", *args.args]
    try:
        return subprocess.call(command)
    except KeyboardInterrupt:
        return 0


def _replay(args: argparse.Namespace) -> int:
    from hil.replay import replay

    run_dir = Path(args.run_dir)
    if not (run_dir / "can.log").exists() or not (run_dir / "zenoh_inputs.msgpack").exists():
        print(
            f"pure-hil: {run_dir} is not a run folder (needs can.log and zenoh_inputs.msgpack)",
            file=sys.stderr,
        )
        return 2
    result = replay(run_dir, limit=args.limit)
    print(
        f"pure-hil replay {run_dir}: {result.ticks} ticks, {result.frames_compared} controller frames "
        f"compared, {len(result.mismatches)} tick(s) differ"
    )
    for line in result.mismatches[:10]:
        print("  " + line)
    return 0 if result.identical else 1


def _until_interrupted(message: str) -> None:
    """Print `message`, then block until SIGINT or SIGTERM (the long-running commands' clean stop)."""
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(message, flush=True)
    stop.wait()


def _serve(args: argparse.Namespace) -> int:

    from drivers.can_bus import parse_can_spec
    from drivers.zenoh_link import LOOPBACK, open_hub
    from hil.service import RigService

    view = None
    if args.view:
        import rerun as rr

        # The operator's own viewer (`rerun` on their machine); the rig connects out to it and never serves.
        view = rr.GrpcSink(args.view)
    session, _ = open_hub(args.zenoh or LOOPBACK, args.hub)  # operators find it there: it never moves
    service = RigService(
        session,
        can=parse_can_spec(args.can) if args.can else None,
        controller=args.controller,
        clock=args.clock,
        out_root=Path(args.out),
        hub_endpoint=args.hub,
        view=view,
    )
    _until_interrupted(
        f"pure-hil serve: queryables {service.keys.rig('{status,start,stop,intent}')}; Ctrl-C to stop"
    )
    service.close()
    session.close()
    print("pure-hil serve: stopped")
    return 0


def _rig(args: argparse.Namespace) -> int:
    return _ask_service(args, args.action, args.arg or "", f"pure-hil rig {args.action}")


def _ask_service(args: argparse.Namespace, name: str, payload: str, who: str) -> int:
    """One query to a running `pure-hil serve` (pure/rig/NAME); prints its JSON reply; 0 if it says ok."""
    import json

    from drivers.keys import Keys
    from drivers.zenoh_link import LOOPBACK, open_session

    session = open_session(args.zenoh or LOOPBACK, "member", args.hub)
    try:
        replies = list(session.get(Keys().rig(name), payload=payload, timeout=10.0))
    finally:
        session.close()
    if not replies or replies[0].ok is None:
        print(f"{who}: no answer (is `pure-hil serve` running?)", file=sys.stderr)
        return 1
    body = replies[0].ok.payload.to_string()
    print(body)
    return 0 if json.loads(body).get("ok") else 1


def _fault(args: argparse.Namespace) -> int:
    """The fault catalog, or live injection into a running `pure-hil serve` over its zenoh API."""
    import json

    from hil.faults import describe_catalog, parse_fault

    if args.action == "list":
        print(describe_catalog())
        return 0
    if args.action == "inject":
        if not args.kind:
            print("pure-hil fault inject: which fault? (pure-hil fault list)", file=sys.stderr)
            return 2
        fault: dict = {"kind": args.kind, "at": args.at}
        if args.duration is not None:
            fault["duration"] = args.duration
        for item in args.param:
            name, sep, value = item.partition("=")
            if not sep:
                print(f"pure-hil fault inject: --param {item!r}: expected NAME=VALUE", file=sys.stderr)
                return 2
            try:
                fault[name] = json.loads(value)
            except json.JSONDecodeError:
                fault[name] = value  # a bare word: a channel, a message name
        try:
            parse_fault(fault, "pure-hil fault inject")  # the same check the service makes, before sending
        except ValueError as exc:
            print(f"pure-hil: {exc}", file=sys.stderr)
            return 2
        key, payload = "fault/inject", json.dumps(fault)
    else:
        key, payload = "fault/clear", "" if args.kind is None else args.kind
    return _ask_service(args, key, payload, f"pure-hil fault {args.action}")


def _supervisor(args: argparse.Namespace) -> int:
    """The supervisor as its own process, on its own timer (what runs beside a real robot)."""

    from drivers.can_bus import BusConfigError, CanNode, open_bus, parse_can_spec
    from drivers.zenoh_link import LOOPBACK, ZenohLink, open_hub, open_session
    from safety.config import RobotGeometry, SupervisorConfig
    from safety.node import SupervisorNode, SupervisorThread

    config = load_toml(find(args.config, "safety"), SupervisorConfig)
    robot = load_toml(find(args.robot, "robot"), RobotGeometry)
    try:
        can = parse_can_spec(args.can)
    except BusConfigError as exc:
        print(f"pure-hil: {exc}", file=sys.stderr)
        return 2
    if can.interface == "virtual":
        print(
            "pure-hil supervisor: needs a bus shared with other processes (e.g. --can socketcan:vcan0)",
            file=sys.stderr,
        )
        return 2
    bus = open_bus(can)
    if args.role == "hub" and not args.certs:
        session, _ = open_hub(args.zenoh or LOOPBACK, args.hub)
    else:
        session = open_session(
            args.zenoh or LOOPBACK, args.role, args.hub, certs=args.certs, identity=args.identity
        )
    link = ZenohLink(session)
    node = SupervisorNode(CanNode(bus, name="supervisor"), link, config, robot, tick_hz=args.tick_hz)
    thread = SupervisorThread(node, sync=args.clock == "sync").start()
    _until_interrupted(
        f"pure-hil supervisor: on {can.interface}:{can.channel}, zenoh {args.role}; Ctrl-C to stop"
    )
    thread.stop()
    link.close()
    session.close()
    bus.shutdown()
    for e in node.events:
        print(f"  t={e.t:9.3f}  {e.kind:<14} {e.from_state} -> {e.to_state} ({e.cause}) {e.detail}")
    return 0


def _estop(args: argparse.Namespace) -> int:
    """Operator e-stop or reset over zenoh; waits for the supervisor to confirm its state."""
    import getpass
    import socket

    from drivers.keys import Keys
    from drivers.schemas import EstopCommand, SafetyState
    from drivers.zenoh_link import LOOPBACK, ZenohLink, open_session

    action = "reset" if args.reset else "estop"
    source = args.source or f"{getpass.getuser()}@{socket.gethostname()}"
    session = open_session(
        args.zenoh or LOOPBACK, "member", args.hub, certs=args.certs, identity=args.identity
    )
    link = ZenohLink(session, Keys())
    try:
        states = link.subscribe(link.keys.safety_state, SafetyState)
        pub = link.publisher(link.keys.safety_estop)
        deadline = time.monotonic() + args.timeout
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        if not pub.matching_status.matching:
            print(f"pure-hil estop: no supervisor listens on {link.keys.safety_estop}", file=sys.stderr)
            return 1
        link.put(link.keys.safety_estop, EstopCommand(seq=1, stamp=time.time(), action=action, source=source))
        want = {"estop": ("STOPPING", "ESTOP"), "reset": ("NORMAL",)}[action]
        last = None
        while time.monotonic() < deadline:
            states.wait(max(deadline - time.monotonic(), 0.0))
            for state in states.drain():
                last = state
                if state.state in want or "reset refused" in state.reason:
                    print(f"pure-hil estop: {action} by {source}: supervisor {state.state} ({state.reason})")
                    return 0 if state.state in want else 1
        print(
            f"pure-hil estop: {action} sent; supervisor state {last.state if last else 'unknown'}",
            file=sys.stderr,
        )
        return 1
    finally:
        link.close()
        session.close()


def _certs(args: argparse.Namespace) -> int:
    from hil.certs import init

    try:
        paths = init(args.folder, days=args.days, force=args.force)
    except FileExistsError as exc:
        print(f"pure-hil certs: {exc}", file=sys.stderr)
        return 2
    print(
        f"pure-hil certs: CA and {len(paths) - 1} certificates in {args.folder} "
        "(keys 0600; never commit them)"
    )
    for name, path in paths.items():
        print(f"  {name:<11} {path}")
    return 0


def _router(args: argparse.Namespace) -> int:

    from drivers.zenoh_link import CONFIG_DIR, ZenohConfigError, open_session

    config = args.config or CONFIG_DIR / "bench-router.json5"
    try:
        session = open_session(
            config, hub_endpoint=args.listen, allow_network=args.allow_network, certs=args.certs
        )
    except ZenohConfigError as exc:
        print(f"pure-hil router: {exc}", file=sys.stderr)
        return 2
    _until_interrupted(f"pure-hil router: {config} (mutual TLS, ACL default deny); Ctrl-C to stop")
    session.close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pure-hil", description="Hardware-in-the-loop rig for the PURE ballbot"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="plant-only run: PURE + rider on the ideal balancer")
    sim.add_argument("--robot", default="configs/robot/pure.toml")
    sim.add_argument("--rider", default="configs/riders/ref_60kg_180.toml")
    sim.add_argument("--no-rider", action="store_true", help="robot alone")
    sim.add_argument("--sim", default="configs/sim/default.toml")
    sim.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    sim.add_argument("--lean", type=float, default=15.0, help="forward torso lean the rider holds, deg")
    sim.add_argument("--tilt", type=float, default=3.0, help="initial chassis tilt, deg")
    sim.add_argument("--seed", type=int, default=None)
    sim.set_defaults(func=_simulate)

    run = sub.add_parser(
        "run", help="run a scenario against a controller; exit 0 pass, 1 fail, 2 usage/config"
    )
    run.add_argument("scenario", help="configs/scenarios/*.toml")
    run.add_argument("--controller", choices=("hacs", "ihacs", "external"), default=None)
    run.add_argument("--can", default=None, help="virtual (default) | socketcan:vcan0 | INTERFACE:CHANNEL")
    run.add_argument("--clock", choices=("lockstep", "realtime"), default=None)
    run.add_argument(
        "--supervisor",
        choices=("embedded", "external"),
        default="embedded",
        help="embedded: in the rig's tick (default); external: `pure-hil supervisor` on the shared bus",
    )
    run.add_argument(
        "--spawn-controller",
        action="store_true",
        help="start pure-controller (the scenario's mode) as a subprocess on the same shared bus",
    )
    run.add_argument("--seed", type=int, default=None)
    run.add_argument(
        "--hub",
        default=None,
        help="the rig's zenoh hub endpoint (default tcp/127.0.0.1:7447; a run with every part in this "
        "process moves to a free port when that one is taken)",
    )
    run.add_argument("--out", default=None, help="run folder (default runs/NAME-TIMESTAMP)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_run)

    cmp_ = sub.add_parser("compare", help="HACS vs iHACS over scenarios and riders: the paper's table")
    cmp_.add_argument("scenarios", nargs="+", help="configs/scenarios/*.toml")
    cmp_.add_argument(
        "--riders", nargs="*", default=None, help="rider files (default: the paper's four riders)"
    )
    cmp_.add_argument("--trials", type=int, default=1, help="seeds per rider")
    cmp_.add_argument("--out", default=None)
    cmp_.set_defaults(func=_compare)

    cam = sub.add_parser(
        "campaign", help="scenarios x riders x faults x seeds in parallel; report + JUnit; exit 0 all pass"
    )
    cam.add_argument("file", help="configs/campaigns/*.toml")
    cam.add_argument("--workers", type=int, default=1, help="parallel processes (lockstep runs)")
    cam.add_argument("--out", default=None, help="report folder (default runs/campaign-NAME-TIMESTAMP)")
    cam.add_argument(
        "--select",
        action="append",
        metavar="TEXT",
        help="only the cases whose id contains TEXT (and their twins); repeat for more",
    )
    cam.add_argument(
        "--can", default=None, help="the lab's bus, e.g. socketcan:vcan0 (default: private virtual)"
    )
    cam.add_argument("--controller", choices=("hacs", "ihacs", "external"), default=None)
    cam.set_defaults(func=_campaign)

    srv = sub.add_parser("serve", help="the long-running rig service, controlled over zenoh (pure/rig/*)")
    srv.add_argument("--can", default=None)
    srv.add_argument("--controller", choices=("hacs", "ihacs", "external"), default=None)
    srv.add_argument("--clock", choices=("lockstep", "realtime"), default=None)
    srv.add_argument("--zenoh", default=None, help="zenoh config (default: loopback)")
    srv.add_argument("--hub", default=None, help="hub endpoint override, e.g. tcp/127.0.0.1:7447")
    srv.add_argument("--out", default="runs", help="where run folders go")
    srv.add_argument(
        "--view",
        default=None,
        metavar="URL",
        help="stream every run live to a rerun viewer you run, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    srv.set_defaults(func=_serve)

    rig = sub.add_parser(
        "rig", help="talk to a running `pure-hil serve`: status, start FILE, stop, intent JSON"
    )
    rig.add_argument("action", choices=("status", "start", "stop", "intent"))
    rig.add_argument("arg", nargs="?", default=None, help="scenario file (start) or intent JSON (intent)")
    rig.add_argument("--zenoh", default=None)
    rig.add_argument("--hub", default=None)
    rig.set_defaults(func=_rig)

    flt = sub.add_parser(
        "fault", help="the fault catalog (list), or inject/clear a fault in a running `pure-hil serve`"
    )
    flt.add_argument("action", choices=("list", "inject", "clear"))
    flt.add_argument("kind", nargs="?", default=None, help="inject: the fault's kind; clear: its number")
    flt.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="a fault parameter")
    flt.add_argument("--at", type=float, default=0.0, help="seconds from now (simulated)")
    flt.add_argument("--duration", type=float, default=None, help="seconds (default: until cleared)")
    flt.add_argument("--zenoh", default=None)
    flt.add_argument("--hub", default=None)
    flt.set_defaults(func=_fault)

    rep = sub.add_parser("replay", help="replay a run's CAN log and zenoh inputs into a fresh controller")
    rep.add_argument("run_dir")
    rep.add_argument("--limit", type=int, default=None, help="replay only the first N ticks")
    rep.set_defaults(func=_replay)

    sup = sub.add_parser("supervisor", help="the safety supervisor as its own process, on a shared bus")
    sup.add_argument("--can", default="socketcan:vcan0", help="bus shared with the rig and the controller")
    sup.add_argument("--config", default="configs/safety/default.toml")
    sup.add_argument("--robot", default="configs/robot/pure.toml")
    sup.add_argument("--tick-hz", type=float, default=400.0, help="the rig's SYNC rate (time stamps)")
    sup.add_argument(
        "--clock",
        choices=("wall", "sync"),
        default="wall",
        help="wall: its own 400 Hz timer (real time); sync: the SYNC tick's time (beside a lockstep rig)",
    )
    sup.add_argument("--role", choices=("member", "hub"), default="member")
    sup.add_argument("--zenoh", default=None)
    sup.add_argument("--hub", default=None)
    sup.add_argument("--certs", default=None, help="certificate folder, with --zenoh bench-client.json5")
    sup.add_argument("--identity", default="supervisor", help="the certificate's role (secured bench)")
    sup.set_defaults(func=_supervisor)

    est = sub.add_parser("estop", help="operator e-stop (or --reset) to the supervisor over zenoh")
    est.add_argument("--reset", action="store_true", help="reset a latched e-stop (at standstill only)")
    est.add_argument("--source", default=None, help="who (default user@host)")
    est.add_argument("--timeout", type=float, default=5.0)
    est.add_argument("--zenoh", default=None, help="e.g. configs/zenoh/bench-client.json5 on a secured bench")
    est.add_argument("--hub", default=None)
    est.add_argument("--certs", default=None, help="certificate folder (pure-hil certs init)")
    est.add_argument("--identity", default="operator", help="the certificate's role (secured bench)")
    est.set_defaults(func=_estop)

    crt = sub.add_parser("certs", help="certificates for the secured bench router (docs/security.md)")
    crt.add_argument("action", choices=("init",))
    crt.add_argument("folder")
    crt.add_argument("--days", type=int, default=365)
    crt.add_argument("--force", action="store_true", help="replace the certificates in a non-empty folder")
    crt.set_defaults(func=_certs)

    rtr = sub.add_parser("router", help="the secured bench router: mutual TLS + ACL (docs/security.md)")
    rtr.add_argument("--certs", required=True, help="certificate folder (pure-hil certs init)")
    rtr.add_argument("--config", default=None, help="default: configs/zenoh/bench-router.json5")
    rtr.add_argument(
        "--listen", default=None, help="endpoint, e.g. tls/BENCH_HOST_IP:7448 (default loopback)"
    )
    rtr.add_argument("--allow-network", action="store_true", help="needed for a non-loopback endpoint")
    rtr.set_defaults(func=_router)

    ctl = sub.add_parser(
        "controller", help="start the reference controller as its own process (pure-controller)"
    )
    ctl.add_argument("args", nargs=argparse.REMAINDER, help="arguments for pure-controller (see --help)")
    ctl.set_defaults(func=_controller)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Every command ends in one line, never a traceback: 2 for what the user can fix (a config, a bus, a
    port), 1 for a failure; an unexpected error leaves its traceback in a file and says where."""
    import zenoh

    from drivers.can_bus import BusConfigError
    from drivers.zenoh_link import ZenohConfigError
    from hil.faults import FaultError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, BusConfigError, ZenohConfigError, FaultError) as exc:
        print(f"pure-hil {args.command}: {exc}", file=sys.stderr)
        return 2
    except zenoh.ZError as exc:  # an endpoint taken or unreachable, a certificate refused
        print(f"pure-hil {args.command}: zenoh: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        import tempfile
        import traceback

        with tempfile.NamedTemporaryFile("w", prefix="pure-hil-error-", suffix=".txt", delete=False) as f:
            traceback.print_exc(file=f)
        print(
            f"pure-hil {args.command}: unexpected {type(exc).__name__}: {exc} (traceback: {f.name})",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
