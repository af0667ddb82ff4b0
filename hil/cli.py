"""`pure-hil` command line. Exit codes: 0 pass, 1 fail (e.g. the robot fell), 2 usage or config error.

Every command that touches the bench reads one bench file (`--bench`, default `embedded`; hil/bench/bench.py)
and takes the same few overrides: --can, --controller, --law, --supervisor, --hub, --certs (and --clock where
a scenario runs).
"""

from __future__ import annotations

import os

# Tiny LAPACK calls (LQR, ARE) are 10-20x slower with OpenBLAS's thread pool on small machines.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import functools
import json
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import msgspec

from drivers.config import MAX_DURATION, load_toml
from drivers.resources import find, shipped
from hil.console.roles import PERSON_ROLES

if TYPE_CHECKING:
    from hil.bench.bench import Bench

WHERE = ("embedded", "spawned", "external")


def package_version() -> str:
    """pure-hil's installed version (`--version`)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pure-hil")
    except PackageNotFoundError:
        return "unknown (run from a source tree that is not installed)"


# ------------------------------------------------------------------------------------------ the bench
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
            choices=("3d", "planar"),
            default=None,
            help="the plant: 3d (MuJoCo rigid bodies) or planar (two planes and yaw, for regression; "
            "default: the bench's sim settings, 3d)",
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


# ---------------------------------------------------------------------------------------------- runs
def _simulate(args: argparse.Namespace) -> int:
    from hil.run.plant_run import default_intent, format_summary, run_plant
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


def _progress(status) -> None:
    """The run's live status line (a terminal only)."""
    width = 20
    done = int(width * min(status.t / status.duration, 1.0))
    print(
        f"\r  [{'#' * done}{'.' * (width - done)}] {status.t:7.2f} / {status.duration:g} s "
        f"{status.speed_factor:5.1f}x  {status.speed:4.2f} m/s  tilt {status.tilt_deg:4.1f} deg  "
        f"{status.supervisor:<8} overruns {status.overruns}\x1b[K",
        end="",
        file=sys.stderr,
        flush=True,
    )


def _out_folder(args: argparse.Namespace, bench: Bench, name: str) -> Path:
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


def _number(kind: type, low: float, high: float = math.inf, low_open: bool = False):
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


SEED = _number(int, 0)
COUNT = _number(int, 1)
DURATION = _number(float, 0.0, MAX_DURATION, low_open=True)


def _run(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.pipeline import check_start, load_scenario, run
    from hil.report.folder import format_table
    from hil.run.build import RunOptions

    scenario = load_scenario(args.scenario)
    bench = bench_from(args)
    check_start(scenario, bench, str(find(args.scenario, "scenarios")))
    check(bench)
    out = _out_folder(args, bench, scenario.name)
    show_progress = sys.stderr.isatty() and not args.quiet
    print(f"pure-hil run: {scenario.name} on bench {bench.name} -> {out}")
    stop = _stop_on_signals()  # Ctrl-C ends the run at the next tick; what ran is judged and written
    result = run(
        scenario,
        bench,
        out=out,
        seed=args.seed,
        options=RunOptions(progress=_progress if show_progress else None, stop=stop),
    )
    if show_progress:
        print(file=sys.stderr)
    failure = result.trace.failure
    if failure is not None and not len(result.trace.t):
        print(
            f"pure-hil run: {failure.error} ({failure.stage}; summary: {out}/summary.json)", file=sys.stderr
        )
        return 2 if failure.config else 1
    print(format_table(result))
    written = sorted(p.name for p in out.iterdir() if p.is_file() and p.name != "summary.json")
    print(f"outputs: {out}/summary.json, {', '.join(written)}")
    if result.trace.stopped_early:
        simulated = float(result.trace.t[-1]) if len(result.trace.t) else 0.0
        print(f"pure-hil run: stopped at t = {simulated:.2f} s of {scenario.duration:g} s", file=sys.stderr)
        return 130
    return {"PASSED": 0, "ESTOPPED": 3}.get(result.verdict, 1)


def _campaign(args: argparse.Namespace) -> int:
    """A campaign's cases in parallel processes: progress, a report (worst first; Markdown, JSON, HTML) and
    JUnit XML."""
    from hil.bench.parts import check
    from hil.history import History, NoHistory
    from hil.suites.campaign import (
        distributable,
        expand,
        junit_xml,
        load_campaign,
        report,
        report_json,
        run_campaign,
    )
    from hil.suites.html_report import html_report

    try:
        campaign = load_campaign(args.file)
        cases = expand(campaign, args.select)
    except ValueError as exc:
        print(f"pure-hil campaign: {exc}", file=sys.stderr)
        return 2
    if args.bench is None:
        args.bench = campaign.bench  # the bench its cases need, unless the command names another
    bench = bench_from(args)
    check(bench)
    out = _out_folder(args, bench, f"campaign-{campaign.name}")
    out.mkdir(parents=True, exist_ok=True)
    where = f"the cluster at {args.scheduler}" if args.scheduler else f"{args.workers} worker(s)"
    print(f"campaign {campaign.name}: {len(cases)} cases on {where}, bench {bench.name} -> {out}")
    if args.scheduler and not distributable(bench):
        print(
            f"pure-hil campaign: bench {bench.name} cannot run on a cluster: every part must be in the rig's "
            "process on an in-process bus (e.g. the embedded bench)",
            file=sys.stderr,
        )
        return 2

    bar = _bar(len(cases), "case")
    counts = {"PASS": 0, "FAIL": 0, "ERROR": 0}

    def progress(done: int, total: int, r) -> None:
        verdict = "ERROR" if r.error else "PASS" if r.passed else "FAIL"
        counts[verdict] += 1
        lines = [f"[{done}/{total}] {verdict:5s} {r.case_id} ({r.wall:.1f} s)"]
        lines += [f"        {line}" for line in (r.message().splitlines() if not r.passed else ())]
        if bar is None:
            print("\n".join(lines), flush=True)
            return
        for line in lines if not r.passed else ():  # above the bar: what failed and why
            bar.write(line)
        bar.set_postfix(passed=counts["PASS"], failed=counts["FAIL"], errors=counts["ERROR"])
        bar.update()

    if args.workers > 1 and not (bench.self_contained and bench.can.in_process):
        print(
            f"pure-hil campaign: on bench {bench.name} cases run one at a time (a shared bus)",
            file=sys.stderr,
        )
    # The bench's history (the console lists it) holds a campaign in the bench's folder beside the
    # service's runs; one put elsewhere with --out was meant to stay apart.
    outputs = Path(bench.outputs.folder).resolve()
    history = History(outputs) if out.resolve().is_relative_to(outputs) else NoHistory()
    controller = f"{bench.controller.where} {bench.controller.plugin}"
    entry = history.begin(out, f"campaign {campaign.name}", bench.name, controller, "lockstep")
    try:
        try:
            results = run_campaign(cases, args.workers, out, progress, bench, args.scheduler)
        except OSError as exc:  # the scheduler cannot be reached (distributed: OSError after its timeout)
            print(f"pure-hil campaign: scheduler {args.scheduler}: {exc}", file=sys.stderr)
            history.end(entry, "ERROR", error=f"scheduler {args.scheduler}: {exc}")
            return 2
        finally:
            if bar is not None:
                bar.close()
        text = report(campaign.name, results)
        (out / "report.md").write_text(text)
        (out / "report.json").write_bytes(report_json(campaign.name, results))
        (out / "junit.xml").write_bytes(junit_xml(campaign.name, results))
        (out / "report.html").write_text(html_report(campaign.name, results, out))
        print(text)
        reports = "  ".join(str(out / name) for name in ("report.md", "report.json", "report.html"))
        print(f"report: {reports}  junit: {out / 'junit.xml'}")
        passed = all(r.passed for r in results)
        history.end(entry, "PASSED" if passed else "FAILED")
        return 0 if passed else 1
    except BaseException as exc:  # Ctrl-C or a crash: the history says how it ended, then it goes on up
        history.end(entry, "STOPPED" if isinstance(exc, KeyboardInterrupt) else "ERROR", error=str(exc))
        raise
    finally:
        history.close()


def _compare(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.pipeline import load_scenario
    from hil.suites.compare import compare, write
    from hil.suites.paper import load_paper
    from plant.params import RiderParams

    scenarios = [load_scenario(s) for s in args.scenarios]
    riders = tuple(args.riders) if args.riders else tuple(load_paper().riders)
    for rider in riders:
        load_toml(find(rider, "riders"), RiderParams)  # a bad rider file fails now, not after an hour of runs
    bench = bench_from(args)
    check(bench)
    log = sys.stderr if args.json else sys.stdout  # --json: stdout holds the object alone
    print(
        f"pure-hil compare: {len(scenarios)} scenario(s) x {len(riders)} rider(s) x {args.trials} trial(s) "
        f"x HACS/iHACS, lockstep, bench {bench.name}",
        file=log,
    )
    bar = _bar(len(scenarios) * len(riders) * args.trials * 2, "run")

    def progress(line: str) -> None:
        if bar is None:
            print(line, file=log, flush=True)
        else:
            bar.write(line)
            bar.update()

    try:
        paths = tuple(str(find(r, "riders")) for r in riders)
        result = compare(scenarios, paths, args.trials, progress=progress, bench=bench, workers=args.workers)
    finally:
        if bar is not None:
            bar.close()
    out = _out_folder(args, bench, "compare")
    write(result, out)
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print(result.table())
    print(
        f"outputs: {out}/compare.md, compare.json"
        + (", compare.png" if (out / "compare.png").exists() else "")
    )
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from hil.suites.calibrate import Unknown, calibrate, sensitivity, write
    from hil.suites.paper import load_paper

    try:
        unknowns = [Unknown.parse(text) for text in args.fit or args.sensitivity]
    except ValueError as exc:
        print(f"pure-hil calibrate: {exc}", file=sys.stderr)
        return 2
    target = load_paper(args.target)
    bench = bench_from(args)
    if args.sensitivity:
        names = [u.name for u in unknowns]
        moved = f"{', '.join(names)} (±{args.step:.0%})"
        print(f"pure-hil calibrate: how each cell of {args.target} moves with {moved}")
        result = sensitivity(target, names, bench, args.step, args.workers)
        out = _out_folder(args, bench, "sensitivity")
        metrics = [m.name for m in target.metric]
        result.write(out, metrics)
        print("\n\n".join(result.table(m) for m in metrics))
        print(f"outputs: {out}/sensitivity.md, sensitivity.json")
        return 0
    print(
        f"pure-hil calibrate: {', '.join(u.name for u in unknowns)} to {args.target} ({len(target.tasks)} "
        f"task(s) x {len(target.riders)} rider(s) x HACS/iHACS per evaluation, at most {args.budget})"
    )
    say = functools.partial(print, flush=True)
    calibration = calibrate(target, unknowns, bench, budget=args.budget, workers=args.workers, progress=say)
    out = _out_folder(args, bench, "calibrate")
    fitted = write(calibration, out)
    print(calibration.table())
    print(f"outputs: {out}/calibrate.md, calibrate.json; fitted files: {Path(fitted.robot).parent}")
    return 0


def _adversary(args: argparse.Namespace) -> int:
    from hil.pipeline import load_scenario
    from hil.suites.adversary import requirement, search, summary, write_worst

    scenario = load_scenario(args.scenario)
    if args.law:
        scenario = msgspec.structs.replace(scenario, law=args.law)
    bench = bench_from(args)
    try:
        requirement(args.objective, scenario, bench)
    except ValueError as exc:
        print(f"pure-hil adversary: {exc}", file=sys.stderr)
        return 2
    print(
        f"pure-hil adversary: {scenario.name} ({scenario.law}), objective {args.objective}, sampler "
        f"{args.sampler} seed {args.seed}, {args.budget} lockstep runs, {args.workers} at a time"
    )
    found = search(
        scenario,
        args.objective,
        args.budget,
        args.workers,
        args.seed,
        bench,
        functools.partial(print, flush=True),
        args.sampler,
    )
    out = _out_folder(args, bench, "adversary")
    path = write_worst(found, out, bench)
    print(summary(found))
    print(f"worst profile: {path} (pure-hil run {path}); its run folder: {out / 'run'}")
    return 0


def _replay(args: argparse.Namespace) -> int:
    from hil.suites.replay import replay

    run_dir = Path(args.run_dir)
    if not (run_dir / "can.log").exists() or not (run_dir / "zenoh_inputs.msgpack").exists():
        print(
            f"pure-hil replay: {run_dir} is not a run folder (needs can.log and zenoh_inputs.msgpack)",
            file=sys.stderr,
        )
        return 2
    try:
        clock = json.loads((run_dir / "summary.json").read_text())["as_run"]["clock"]
    except (OSError, ValueError, KeyError, TypeError):
        clock = "lockstep"  # replay() says what is wrong with the folder
    if clock != "lockstep":
        print(
            f"pure-hil replay: {run_dir} ran on the {clock} clock: only a lockstep run can be "
            "compared tick for tick (a real-time run's frames met its controller at times no replay repeats)",
            file=sys.stderr,
        )
        return 2
    result = replay(run_dir, bench_from(args), limit=args.limit)
    print(
        f"pure-hil replay {run_dir}: {result.ticks} ticks, {result.frames_compared} controller frames "
        f"compared, {len(result.mismatches)} tick(s) differ"
    )
    for line in result.mismatches[:10]:
        print("  " + line)
    return 0 if result.identical else 1


# ----------------------------------------------------------------------------- the bench's processes
def _bar(total: int, unit: str):
    """A progress bar with counts and ETA on a terminal (stderr); None elsewhere (CI logs keep lines)."""
    if not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, file=sys.stderr, dynamic_ncols=True)


def _stop_on_signals() -> threading.Event:
    """An event SIGINT or SIGTERM sets: the long-running commands' clean stop."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def _until_interrupted(message: str) -> None:
    """Print `message`, then block until SIGINT or SIGTERM; from then on a second one ends the process at
    once (what the first started, e.g. writing a run's folder, is left unfinished)."""
    stop = _stop_on_signals()
    print(message, flush=True)
    stop.wait()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def _serve(args: argparse.Namespace) -> int:
    from hil.bench.parts import check
    from hil.service import RigService

    bench = bench_from(args)
    check(bench)
    view = None
    if args.view:
        import rerun as rr

        # The operator's own viewer (`rerun` on their machine); the rig connects out to it and never serves.
        view = rr.GrpcSink(args.view)
    session, _ = bench.zenoh.open_rig(
        fallback=False
    )  # operators find it where the bench says: it never moves
    service = RigService(session, bench, out_root=Path(args.out or bench.outputs.folder), view=view)
    _until_interrupted(
        f"pure-hil serve: bench {bench.name}, hub {service.endpoint}, queryables {service.keys.rig('*')}; "
        "Ctrl-C to stop"
    )
    if service.state == "running":
        print(
            "pure-hil serve: stopping the run and writing its folder (a second Ctrl-C: at once)", flush=True
        )
    service.close()
    session.close()
    print("pure-hil serve: stopped")
    return 0


def _supervisor(args: argparse.Namespace) -> int:
    """The supervisor as its own process, on its own timer (what runs beside a real robot): the bench's
    supervisor plug, as the rig starts it (drivers/plugs.py)."""
    from contextlib import ExitStack

    from drivers.keys import Keys
    from drivers.registry import SUPERVISORS, find_plug
    from drivers.zenoh_link import ZenohLink
    from hil.bench.parts import check
    from hil.bench.rigs import announce
    from hil.run.build import supervisor_spec
    from hil.run.scenario import Scenario

    bench = bench_from(args)
    if bench.can.in_process:
        print(
            "pure-hil supervisor: needs a bus shared with other processes (e.g. --can socketcan:vcan0)",
            file=sys.stderr,
        )
        return 2
    try:  # the rules as a run would hand them over: the bench's, with a scenario's overrides
        scenario = Scenario(name="overrides", robot=args.robot, safety=json.loads(args.safety or "{}"))
    except (ValueError, msgspec.ValidationError) as exc:
        print(f"pure-hil supervisor: --safety: {exc}", file=sys.stderr)
        return 2
    spec = supervisor_spec(
        bench,
        scenario,
        can=bench.can,
        zenoh=bench.zenoh,
        tick_hz=args.tick_hz,
        lockstep=args.clock == "lockstep",
    )
    check(bench)  # the bus and the plug, before any session: a missing vcan0 is one line and exit 2
    start = find_plug(SUPERVISORS, bench.supervisor.plugin, "supervisor")
    hub = bench.zenoh.mode == "loopback" and args.role == "hub"
    # Its session as this command's role says (the rig's hub, or --identity's certificate), lent to the plug.
    session = bench.zenoh.open_rig(fallback=False)[0] if hub else bench.zenoh.open(args.identity)
    link = ZenohLink(session, Keys(bench.zenoh.prefix))
    try:
        handle = start(spec, link=link)
        with ExitStack() as announced:
            where = f"zenoh {bench.zenoh.mode}"
            if hub:
                endpoint = bench.zenoh.hub_endpoint()
                announced.enter_context(
                    announce(session, bench.zenoh.prefix, bench.name, endpoint, "supervisor")
                )
                where = f"zenoh hub {endpoint}"
            _until_interrupted(
                f"pure-hil supervisor: on {bench.can.interface}:{bench.can.channel}, {where}; Ctrl-C to stop"
            )
        handle.stop()
    finally:
        link.close()
        session.close()
    node = handle.node
    for e in node.events:
        print(f"  t={e.t:9.3f}  {e.kind:<14} {e.from_state} -> {e.to_state} ({e.cause}) {e.detail}")
    # What it missed on the bus (a reader that falls behind loses frames silently on vcan: docs/bench.md),
    # where the plug keeps the reference's bus counters (the contract does not ask for them).
    can_node = getattr(node, "can", None)
    if can_node is not None:
        stats = can_node.stats.as_dict()
        print(f"  bus: lost {stats['lost_frames']}, E2E {stats['e2e']}, malformed {stats['malformed']}")
    return 0


def _part(args: argparse.Namespace) -> int:
    """A bench part's plug in this process, on a thread of its own, until SIGINT or SIGTERM (the rig
    spawns its parts so: drivers/plugs.py)."""
    from drivers.dut import DutSpec
    from drivers.plugs import SupervisorSpec
    from drivers.registry import CONTROLLERS, SUPERVISORS, PlugNotFound, find_plug

    spec_type: type[DutSpec] | type[SupervisorSpec] = DutSpec if args.kind == "controller" else SupervisorSpec
    group = CONTROLLERS if args.kind == "controller" else SUPERVISORS
    try:
        spec: DutSpec | SupervisorSpec = msgspec.json.decode(Path(args.spec).read_bytes(), type=spec_type)
        start = find_plug(group, args.plugin, args.kind)
    except OSError as exc:
        print(f"pure-hil part: {args.spec}: cannot read: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except msgspec.MsgspecError as exc:
        print(f"pure-hil part: {args.spec}: {exc}", file=sys.stderr)
        return 2
    except PlugNotFound as exc:
        print(f"pure-hil part: {exc}", file=sys.stderr)
        return 2
    if spec.driven:
        print(
            f"pure-hil part: {args.spec}: driven = true is for a part in the rig's own process",
            file=sys.stderr,
        )
        return 2
    handle = start(spec)
    try:
        bus = f"{spec.can.interface}:{spec.can.channel}"
        _until_interrupted(f"pure-hil part: {args.kind} {args.plugin} on {bus}; Ctrl-C to stop")
    finally:
        handle.stop()
    return 0


def controller_command(bench, rider: str, robot: str, law: str, lockstep: bool) -> list[str]:
    """`pure-controller` on this bench: its bus, its zenoh (with the controller's certificate on a router)."""
    script = Path(sys.executable).with_name("pure-controller")
    zenoh = bench.zenoh
    command = [str(script) if script.exists() else "pure-controller"]
    command += ["--can", f"{bench.can.interface}:{bench.can.channel}", "--prefix", zenoh.prefix]
    command += ["--zenoh", str(zenoh.config_path)]
    if zenoh.endpoint:
        command += ["--hub", zenoh.endpoint]
    if zenoh.mode == "router":
        command += ["--certs", str(zenoh.certs), "--identity", "controller"]
        command += ["--allow-network"] if zenoh.network else []
    command += ["--rider", str(find(rider, "riders")), "--robot", str(find(robot, "robot"))]
    command += ["--config", str(find(bench.controller.config, "controller")), "--law", law]
    if not bench.devices.pure:
        command += ["--devices", msgspec.json.encode(bench.devices).decode()]
    return command + (["--lockstep"] if lockstep else [])


def _controller(args: argparse.Namespace) -> int:
    """The reference controller as its own process on this bench (the rig never imports a controller).
    This process becomes pure-controller (exec), so a signal to it (the rig stopping what it spawned)
    reaches the controller itself: a wrapper would exit and leave the controller running on the bus."""
    bench = bench_from(args)
    law = args.law or (bench.controller.law if bench.controller.law != "scenario" else "hacs")
    command = controller_command(
        bench, args.rider, args.robot or bench.controller.robot or "pure", law, args.lockstep
    )
    sys.stdout.flush()
    os.execvp(command[0], command)


# -------------------------------------------------------------------------------------------- operators
def _join_rig(args: argparse.Namespace):
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


def _estop(args: argparse.Namespace) -> int:
    """Operator e-stop or reset over zenoh; waits for the supervisor to confirm its state."""
    import getpass
    import socket

    from drivers.keys import Keys
    from drivers.vocabulary import OperatorCommand
    from drivers.zenoh_link import ZenohLink
    from hil.bench.operator import command

    action: OperatorCommand = "reset" if args.reset else "cut_power" if args.cut_power else "estop"
    source = args.source or f"{getpass.getuser()}@{socket.gethostname()}"
    bench, session, card = _join_rig(args)
    rig = f"rig {card.describe()}" if card else f"bench {bench.name}"
    link = ZenohLink(session, Keys(bench.zenoh.prefix))
    try:
        answer = command(link, action, source, args.timeout)
    finally:
        link.close()
        session.close()
    if not answer.heard:
        print(f"pure-hil estop: no supervisor listens on {link.keys.safety_estop}", file=sys.stderr)
        return 1
    if answer.confirmed and action != "reset":
        print(
            f"pure-hil estop: {action} by {source} latched on {rig}: {answer.seen()}; "
            "it ends in ESTOP and waits for a reset"
        )
        return 0
    refused = answer.state is not None and "reset refused" in answer.state.reason
    if action == "reset" and (answer.confirmed or refused):
        print(f"pure-hil estop: reset by {source} on {rig}: {answer.seen()}")
        return 0 if answer.confirmed else 1
    what = "it reset" if action == "reset" else f"its {action} latched"
    print(
        f"pure-hil estop: {action} sent to {rig}, but nothing confirmed {what} within {args.timeout:g} s; "
        f"{answer.seen()}",
        file=sys.stderr,
    )
    return 1


def _rig(args: argparse.Namespace) -> int:
    return _ask_service(args, args.action, args.arg or "", f"pure-hil rig {args.action}")


def _ask_service(args: argparse.Namespace, name: str, payload: str, who: str) -> int:
    """One query to a running `pure-hil serve` (pure/rig/NAME); prints its JSON reply; 0 if it says ok."""
    from drivers.keys import Keys

    bench, session, _card = _join_rig(args)
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


def _console(args: argparse.Namespace) -> int:
    """The rig's screen in a browser: a zenoh client of `pure-hil serve` that serves one page over HTTP."""
    import getpass
    import socket
    from dataclasses import asdict

    from drivers.keys import Keys
    from hil.console import accounts
    from hil.console.events import Broadcast
    from hil.console.rig_link import RigLink, fault_catalog
    from hil.console.server import Console, ListenError, check_exposure, parse_listen, tls_context

    try:  # the options first: a mistake costs no zenoh session
        listen = parse_listen(args.listen)
        tls = tls_context(args.tls_cert, args.tls_key)
        people = accounts.load(args.accounts) if args.accounts else None
        check_exposure(listen, tls, bool(people))
    except (ListenError, accounts.AccountsError) as exc:
        print(f"pure-hil console: {exc}", file=sys.stderr)
        return 2
    source = (args.source or f"console {args.identity} {getpass.getuser()}@{socket.gethostname()}")[:64]
    bench, session, card = _join_rig(args)
    link = RigLink(
        session,
        Keys(bench.zenoh.prefix),
        args.identity,
        source,
        Broadcast(),
        None if card is None else asdict(card),
    )
    info = {"bench": bench.name, "faults": fault_catalog()}
    try:  # its output is its audit log: who did what, from where, and the answer
        console = Console(link, info, listen, tls, people, audit=lambda line: print(line, flush=True))
        console.start()
    except ListenError as exc:
        link.close()
        session.close()
        print(f"pure-hil console: {exc}", file=sys.stderr)
        return 2
    rig = card.describe() if card else f"bench {bench.name} through its router"
    login = f", {len(people)} accounts" if people else ""
    _until_interrupted(
        f"pure-hil console: {rig}, role {args.identity}{login}; Ctrl-C to stop\nconsole: {console.url}"
    )
    console.close()
    link.close()
    session.close()
    return 0


def _accounts(args: argparse.Namespace) -> int:
    """Who may log in to a console: add (or change), remove, list the accounts of a file."""
    import getpass

    from hil.console import accounts

    path = Path(args.file)
    try:
        people = accounts.load(path) if path.exists() or args.action != "add" else {}
        if args.action == "list":
            for person in people.values():
                print(f"{person.name}\t{person.role}")
            return 0
        if args.name is None:
            raise accounts.AccountsError(
                f"pure-hil accounts {args.action} FILE NAME: give the account's NAME"
            )
        if args.action == "remove":
            if people.pop(args.name, None) is None:
                raise accounts.AccountsError(f"{path}: no account {args.name!r}")
            if not people:
                raise accounts.AccountsError(f"{path}: {args.name} is its last account (delete the file)")
        else:
            if sys.stdin.isatty():
                password = getpass.getpass(f"password for {args.name}: ")
                if getpass.getpass("again: ") != password:
                    raise accounts.AccountsError("the two passwords differ")
            else:  # a script: the first line of stdin
                password = sys.stdin.readline().rstrip("\n")
            accounts.check_new(args.name, args.role, password)
            people[args.name] = accounts.Account(args.name, args.role, accounts.hash_password(password))
        accounts.save(path, people)
    except accounts.AccountsError as exc:
        print(f"pure-hil accounts: {exc}", file=sys.stderr)
        return 2
    done = "removed" if args.action == "remove" else f"{args.role}, scrypt"
    print(f"pure-hil accounts: {args.name} {done} in {path} ({len(people)} accounts, mode 0600)")
    return 0


def _fault(args: argparse.Namespace) -> int:
    """The fault catalog, or live injection into a running `pure-hil serve` over its zenoh API."""
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
            fault[name] = _parameter(value)
        if args.within is not None and (args.expect or "none").lower() == "none":
            print("pure-hil fault inject: --within times the reaction --expect names", file=sys.stderr)
            return 2
        if args.expect is not None:
            fault["expect"] = _expectation(args.expect, args.within)
        try:
            parse_fault(fault, "pure-hil fault inject")  # the same check the service makes, before sending
        except ValueError as exc:
            print(exc, file=sys.stderr)
            return 2
        key, payload = "fault/inject", json.dumps(fault)
    else:
        if args.kind is not None and not args.kind.isdigit():
            print(
                f"pure-hil fault clear: {args.kind!r}: expected a fault's number (pure-hil rig status)",
                file=sys.stderr,
            )
            return 2
        key, payload = "fault/clear", "" if args.kind is None else args.kind
    return _ask_service(args, key, payload, f"pure-hil fault {args.action}")


def _parameter(value: str) -> object:
    """A --param value: JSON (a number, true, a list), a number however Python spells it (nan, inf: refused
    by name later, not taken for words), else the word itself (a channel, a message)."""
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        pass
    try:
        return float(value)
    except ValueError:
        return value


def _expectation(text: str, within: float | None) -> dict:
    """`--expect` as a fault's `expect` (docs/faults.md): none, STATE, CAUSE or STATE/CAUSE; the fault's
    own check names what is wrong with it."""
    from drivers.vocabulary import State

    if text.lower() == "none":
        return {"reaction": "none"}
    state, _, cause = text.upper().rpartition("/")
    if not state and cause in State.__members__:
        state, cause = cause, ""
    expect: dict = {"state": state} if state else {}
    expect |= {"cause": cause} if cause else {}
    return expect if within is None else {**expect, "within": within}


def _certs(args: argparse.Namespace) -> int:
    from hil.bench.certs import init

    try:
        paths = init(args.folder, days=args.days, force=args.force, hosts=args.host)
    except FileExistsError as exc:
        print(f"pure-hil certs: {exc}", file=sys.stderr)
        return 2
    print(
        f"pure-hil certs: CA and {len(paths) - 1} certificates in {args.folder} "
        "(keys 0600; never commit them)"
    )
    for name, path in paths.items():
        print(f"  {name:<14} {path}")
    return 0


def _router(args: argparse.Namespace) -> int:
    from drivers.zenoh_link import CONFIG_DIR, open_session

    config = args.config or CONFIG_DIR / "bench-router.json5"
    session = open_session(
        config, hub_endpoint=args.listen, allow_network=args.allow_network, certs=args.certs
    )
    _until_interrupted(f"pure-hil router: {config} (mutual TLS, ACL default deny); Ctrl-C to stop")
    session.close()
    return 0


# ------------------------------------------------------------------------------------------- the parser
class _Parser(argparse.ArgumentParser):
    """argparse's, its errors in one line (the usage is a --help away); its sub-commands' parsers too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pure-hil", description="Hardware-in-the-loop rig for the PURE ballbot")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="plant-only run: PURE + rider on the ideal balancer")
    sim.add_argument("--robot", default="pure", help="robot file or shipped name")
    sim.add_argument("--rider", default="ref_60kg_180", help="rider file or shipped name")
    sim.add_argument("--no-rider", action="store_true", help="robot alone")
    sim.add_argument("--sim", default="default", help="simulation settings file or shipped name")
    sim.add_argument(
        "--duration", type=DURATION, default=10.0, help="simulated seconds (> 0, at most one day)"
    )
    sim.add_argument("--lean", type=float, default=15.0, help="forward torso lean the rider holds, deg")
    sim.add_argument("--tilt", type=float, default=3.0, help="initial chassis tilt, deg")
    sim.add_argument("--seed", type=SEED, default=None, help="the noise seed (>= 0)")
    sim.set_defaults(func=_simulate)

    run = sub.add_parser("run", help="run a scenario on the bench; exit 0 pass, 1 fail, 2 usage/config")
    run.add_argument("scenario", help="a shipped scenario's name (balance, ...) or a scenario file")
    add_bench_options(run, clock=True)
    run.add_argument("--seed", type=SEED, default=None, help="the scenario's seed instead (>= 0)")
    run.add_argument("--out", default=None, help="run folder (default: the bench's folder/NAME-TIMESTAMP)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_run)

    cmp_ = sub.add_parser("compare", help="HACS vs iHACS over scenarios and riders: the paper's table")
    cmp_.add_argument("scenarios", nargs="+", help="shipped scenario names or files")
    cmp_.add_argument("--riders", nargs="*", default=None, help="riders (default: the paper's four)")
    cmp_.add_argument("--trials", type=COUNT, default=1, help="seeds per rider")
    cmp_.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    cmp_.add_argument("--json", action="store_true", help="print one JSON object (cells, orderings, runs)")
    cmp_.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    add_bench_options(cmp_, plant=True)
    cmp_.set_defaults(func=_compare)

    cal = sub.add_parser("calibrate", help="fit unknown parameters to a target table (bounded least squares)")
    what = cal.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--fit",
        nargs="+",
        metavar="NAME[=LO:HI]",
        help="parameters to fit, e.g. rider.lean_rate_deg rider.lean_amplitude_deg=10:35 (docs/riders.md)",
    )
    what.add_argument(
        "--sensitivity", nargs="+", metavar="NAME", help="instead: each cell at each parameter moved ±--step"
    )
    cal.add_argument("--step", type=float, default=0.2, help="relative move for --sensitivity")
    cal.add_argument("--target", default="paper/ihacs_table2.toml", help="a table in the paper's format")
    cal.add_argument("--budget", type=COUNT, default=40, help="at most this many evaluations")
    cal.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    cal.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    add_bench_options(cal, plant=True)
    cal.set_defaults(func=_calibrate)

    adv = sub.add_parser("adversary", help="search the worst rider for an STL requirement")
    adv.add_argument("scenario", help="shipped scenario name or file")
    adv.add_argument(
        "--objective",
        choices=("overspeed", "tilt", "rmse"),
        default="overspeed",
        help="what the worst rider maximises (docs/riders.md)",
    )
    adv.add_argument("--budget", type=COUNT, default=50, help="lockstep runs")
    adv.add_argument("--workers", type=COUNT, default=1, help="runs at a time, each in its own process")
    adv.add_argument("--seed", type=SEED, default=0, help="the search's seed: the same seed, the same search")
    adv.add_argument(
        "--sampler",
        choices=("random", "qmc", "cmaes"),
        default="random",
        help="optuna's uniform random, Sobol or CMA-ES sampling (docs/riders.md: which finds it sooner)",
    )
    adv.add_argument(
        "--out", default=None, help="output folder (default: the bench's outputs.folder/NAME-TIMESTAMP)"
    )
    add_bench_options(adv, plant=True)
    adv.set_defaults(func=_adversary)

    cam = sub.add_parser("campaign", help="scenarios x riders x faults x seeds in parallel; report + JUnit")
    cam.add_argument("file", help="a shipped campaign's name or a campaign file")
    cam.add_argument("--workers", type=COUNT, default=1, help="parallel processes (lockstep runs)")
    cam.add_argument(
        "--scheduler",
        default=None,
        help="run the cases on a Dask cluster, e.g. tcp://127.0.0.1:8786 (needs pip install '.[cluster]')",
    )
    cam.add_argument("--out", default=None, help="report folder (default runs/campaign-NAME-TIMESTAMP)")
    cam.add_argument(
        "--select",
        action="append",
        metavar="TEXT",
        help="only the cases whose id contains TEXT (and their twins); repeat for more",
    )
    add_bench_options(cam, plant=True)
    cam.set_defaults(func=_campaign)

    rep = sub.add_parser("replay", help="replay a run's CAN log and zenoh inputs into a fresh controller")
    rep.add_argument("run_dir", help="a lockstep run's folder (can.log, zenoh_inputs.msgpack)")
    rep.add_argument("--limit", type=COUNT, default=None, help="replay only the first N ticks")
    add_bench_options(rep)
    rep.set_defaults(func=_replay)

    srv = sub.add_parser("serve", help="the long-running rig service, controlled over zenoh (pure/rig/*)")
    add_bench_options(srv, clock=True)
    srv.add_argument("--out", default=None, help="where run folders go (default: the bench's folder)")
    srv.add_argument(
        "--view",
        default=None,
        metavar="URL",
        help="stream every run live to a rerun viewer you run, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    srv.set_defaults(func=_serve)

    sup = sub.add_parser("supervisor", help="the safety supervisor as its own process, on the bench's bus")
    add_bench_options(sup)
    sup.add_argument("--robot", default="pure", help="robot file or shipped name (its geometry)")
    sup.add_argument("--tick-hz", type=float, default=400.0, help="the rig's SYNC rate (time stamps)")
    sup.add_argument(
        "--clock",
        choices=("realtime", "lockstep"),
        default="realtime",
        help="realtime: its own 400 Hz timer; lockstep: the SYNC tick's time (beside a lockstep rig)",
    )
    sup.add_argument(
        "--role", choices=("member", "hub"), default="member", help="loopback: hub without a rig"
    )
    sup.add_argument("--identity", default="supervisor", help="its certificate's role (secured bench)")
    sup.add_argument("--safety", default=None, help="a scenario's [safety] overrides, as JSON")
    sup.set_defaults(func=_supervisor)

    ctl = sub.add_parser("controller", help="the reference controller as its own process on the bench")
    add_bench_options(ctl)
    ctl.add_argument("--rider", required=True, help="rider file or shipped name (iHACS uses its model)")
    ctl.add_argument(
        "--robot", default=None, help="the controller's robot model (default: the bench's, or pure)"
    )
    ctl.add_argument("--lockstep", action="store_true", help="beside a lockstep rig")
    ctl.set_defaults(func=_controller)

    prt = sub.add_parser(
        "part",
        help="a bench part's plug in a process of its own, from the spec the rig wrote (the rig's spawned "
        "parts run so)",
    )
    prt.add_argument("kind", choices=("controller", "supervisor"), help="which part")
    prt.add_argument("plugin", help="its entry point in pure_hil.controllers or pure_hil.supervisors")
    prt.add_argument(
        "spec", help="the part's spec as JSON (drivers/dut.py DutSpec, drivers/plugs.py SupervisorSpec)"
    )
    prt.set_defaults(func=_part)

    est = sub.add_parser("estop", help="operator e-stop (or --reset) to the supervisor over zenoh")
    what = est.add_mutually_exclusive_group()
    what.add_argument("--reset", action="store_true", help="reset a latched e-stop (at standstill only)")
    what.add_argument(
        "--cut-power",
        action="store_true",
        help="category 0: the drives' power off at once, even in motion (docs/safety.md)",
    )
    est.add_argument("--source", default=None, help="who (default user@host)")
    est.add_argument(
        "--timeout", type=float, default=5.0, help="s to wait for the supervisor's confirmation (default 5)"
    )
    est.add_argument("--identity", default="operator", help="its certificate's role (secured bench)")
    add_bench_options(est)
    est.set_defaults(func=_estop)

    rig = sub.add_parser(
        "rig", help="talk to a running `pure-hil serve`: status, start FILE, stop, intent JSON"
    )
    rig.add_argument(
        "action", choices=("status", "start", "stop", "intent"), help="what to ask the service (docs/rig.md)"
    )
    rig.add_argument("arg", nargs="?", default=None, help="scenario (start) or intent JSON (intent)")
    rig.add_argument("--identity", default="operator", help="its certificate's role (secured bench)")
    add_bench_options(rig)
    rig.set_defaults(func=_rig)

    flt = sub.add_parser("fault", help="the fault catalog (list), or inject/clear a fault in a running serve")
    flt.add_argument(
        "action", choices=("list", "inject", "clear"), help="the catalog, or a live fault (docs/faults.md)"
    )
    flt.add_argument("kind", nargs="?", default=None, help="inject: the fault's kind; clear: its number")
    flt.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="a fault parameter")
    flt.add_argument(
        "--at", type=_number(float, 0.0, MAX_DURATION), default=0.0, help="seconds from now (simulated)"
    )
    flt.add_argument("--duration", type=DURATION, default=None, help="seconds (default: until cleared)")
    flt.add_argument(
        "--expect",
        default=None,
        metavar="CAUSE",
        help="the supervisor's reaction the run's verdict expects: a cause (WRENCH_SILENT), a state "
        "(RECOVERY), STATE/CAUSE, or none (ridden through); without it a stop the fault causes fails the run",
    )
    flt.add_argument(
        "--within", type=DURATION, default=None, help="seconds from the fault's start for --expect (0.1)"
    )
    flt.add_argument("--identity", default="fault-injector", help="its certificate's role (secured bench)")
    add_bench_options(flt)
    flt.set_defaults(func=_fault)

    con = sub.add_parser(
        "console", help="the rig's screen in a browser: a client of `pure-hil serve` (docs/rig.md)"
    )
    con.add_argument(
        "--listen",
        default="127.0.0.1:0",
        metavar="IP:PORT",
        help="where the page is served (port 0: a free one); off loopback it needs --tls-cert and --tls-key",
    )
    con.add_argument(
        "--tls-cert", default=None, metavar="PEM", help="serve HTTPS with this certificate (chain)"
    )
    con.add_argument("--tls-key", default=None, metavar="PEM", help="the private key of --tls-cert")
    con.add_argument(
        "--identity",
        default="operator",
        help="its certificate's role (secured bench); the page offers that role's actions only: operator "
        "(start, stop, e-stop, reset), fault-injector (faults), any other watches",
    )
    con.add_argument(
        "--source",
        default=None,
        help="who its e-stops say they are from (default: console ROLE user@host; with --accounts: "
        "console ROLE NAME, the person logged in)",
    )
    con.add_argument(
        "--accounts",
        default=None,
        metavar="FILE",
        help="who may log in, each with a bench role (pure-hil accounts); needed off loopback",
    )
    add_bench_options(con)
    con.set_defaults(func=_console)

    acc = sub.add_parser(
        "accounts", help="who may log in to a console: names, roles, scrypt hashes (docs/security.md)"
    )
    acc.add_argument("action", choices=("add", "remove", "list"), help="add (or change), remove, list")
    acc.add_argument("file", help="the accounts file (JSON, kept mode 0600)")
    acc.add_argument("name", nargs="?", default=None, help="the account's name (add, remove)")
    acc.add_argument(
        "--role",
        default="monitor",
        choices=PERSON_ROLES,
        help="its bench role (add); the password is asked twice on a terminal, else read from stdin",
    )
    acc.set_defaults(func=_accounts)

    crt = sub.add_parser("certs", help="certificates for the secured bench router (docs/security.md)")
    crt.add_argument("action", choices=("init",), help="make a CA and every role's certificate")
    crt.add_argument("folder", help="where the certificates go (keys 0600)")
    crt.add_argument("--days", type=COUNT, default=365, help="validity of the certificates")
    crt.add_argument("--force", action="store_true", help="replace the certificates in a non-empty folder")
    crt.add_argument(
        "--host",
        action="append",
        default=None,
        help="an address the router is reached at (default 127.0.0.1)",
    )
    crt.set_defaults(func=_certs)

    rtr = sub.add_parser("router", help="the secured bench router: mutual TLS + ACL (docs/security.md)")
    rtr.add_argument("--certs", required=True, help="certificate folder (pure-hil certs init)")
    rtr.add_argument("--config", default=None, help="default: configs/zenoh/bench-router.json5")
    rtr.add_argument(
        "--listen", default=None, help="endpoint, e.g. tls/BENCH_HOST_IP:7448 (default loopback)"
    )
    rtr.add_argument("--allow-network", action="store_true", help="needed for a non-loopback endpoint")
    rtr.set_defaults(func=_router)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Every command ends in one line, never a traceback: 2 for what the user can fix (a config, a bus, a
    port, a bench part), 1 for a failure; an unexpected error leaves its traceback in a file, named."""
    import zenoh

    from hil.bench.parts import BenchUnavailable
    from hil.bench.rigs import WrongRig
    from hil.run.trace import CONFIG_ERRORS

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (*CONFIG_ERRORS, BenchUnavailable) as exc:
        print(f"pure-hil {args.command}: {exc}", file=sys.stderr)
        return 2
    except WrongRig as exc:
        print(f"pure-hil {args.command}: {exc}", file=sys.stderr)
        return 1
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
