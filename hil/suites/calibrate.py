"""`pure-hil calibrate`: fit named unknown parameters of the world (the rider's lean amplitude and rate, the
chassis's mass, height and inertia, friction) to a target table — the paper's Table II or a lab's own, in
the same format (configs/paper/ihacs_table2.toml) — by bounded least squares (scipy.optimize.least_squares)
on the cells' distances in SD. Each evaluation is a `compare` of the table's tasks and riders, in lockstep.

The controller keeps its own nominal robot model (the bench's controller.robot): what is fitted is the
world it does not know, as on a real bench. docs/riders.md.
"""

from __future__ import annotations

import functools
import math
import operator
import tempfile
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import msgspec
import numpy as np

from drivers.config import dump_toml, load_toml
from drivers.resources import find
from hil.bench.bench import Bench, load_bench
from hil.run.scenario import Scenario
from hil.suites.campaign import distributable, run_pool
from hil.suites.compare import Comparison, compare
from hil.suites.paper import LAWS, PaperTable
from plant.params import RiderParams, RobotParams

UNKNOWNS: dict[str, tuple[float, float]] = {
    "rider.lean_amplitude_deg": (5.0, 45.0),
    "rider.lean_rate_deg": (0.5, 20.0),
    "rider.trunk_stiffness": (100.0, 5000.0),
    "rider.trunk_damping": (10.0, 1000.0),
    "robot.body.mass": (15.0, 60.0),
    "robot.body.com_height": (0.1, 0.5),
    "robot.body.inertia_pitch": (0.1, 4.0),
    "robot.friction.rolling_viscous": (0.0, 3.0),
    "robot.friction.drivetrain_viscous": (0.0, 3.0),
    "controller.lqr.q_tilt": (10.0, 1000.0),
    "controller.lqr.q_ball_rate": (0.1, 10.0),
    "controller.pi.kp": (0.5, 10.0),
    "controller.pi.ki": (1.0, 50.0),
}
"""Parameters `calibrate` may fit, with the bounds used when none are given: `rider.*` applies to every
rider of the table, `robot.*` to the plant's robot; `controller.*` is the reference controller's tuning
(a what-if on the device under test, not the world: its file is written beside the world's and the bench's
controller points to it)."""


@dataclass(frozen=True, slots=True)
class Unknown:
    name: str
    lower: float
    upper: float

    @classmethod
    def parse(cls, text: str) -> Unknown:
        """`name` or `name=lower:upper`."""
        name, _, bounds = text.partition("=")
        if name not in UNKNOWNS:
            raise ValueError(f"unknown parameter {name!r}: one of {', '.join(UNKNOWNS)}")
        lower, upper = UNKNOWNS[name]
        if bounds:
            try:
                lower, upper = (float(v) for v in bounds.split(":"))
            except ValueError:
                raise ValueError(f"{text!r}: bounds are lower:upper, e.g. {name}=1:10") from None
        if not lower < upper:
            raise ValueError(f"{text!r}: the lower bound must be below the upper")
        return cls(name, lower, upper)


def _apply(tree: dict, values: dict[str, float], head: str) -> dict:
    """A config file's contents (`tree`) with the unknowns named `head.*` set in place."""
    for name, value in values.items():
        first, *tables, key = name.split(".")
        if first == head:
            functools.reduce(operator.getitem, tables, tree)[key] = value
    return tree


_Record = TypeVar("_Record", bound=msgspec.Struct)


def with_values(record: _Record, values: dict[str, float], head: str) -> _Record:
    """`record` with the unknowns named `head.*` set, validated as its config file is."""
    return msgspec.convert(_apply(msgspec.to_builtins(record), values, head), type(record))


@dataclass(frozen=True, slots=True)
class World:
    """The files one evaluation runs with: the riders', the robot's and the controller's tuning, with the
    unknowns set."""

    riders: tuple[str, ...]
    robot: str
    controller: str

    def on(self, bench: Bench) -> Bench:
        """`bench` with its controller reading this world's tuning."""
        part = msgspec.structs.replace(bench.controller, config=self.controller)
        return msgspec.structs.replace(bench, controller=part)


def write_world(
    values: dict[str, float], riders: list[str], robot: str, folder: Path, controller: str = "default"
) -> World:
    folder.mkdir(parents=True, exist_ok=True)
    # The controller's file is its own format (the rig never imports the controller): edited as TOML.
    tuning = _apply(msgspec.toml.decode(find(controller, "controller").read_bytes()), values, "controller")
    controller_path = folder / "controller.toml"
    controller_path.write_bytes(msgspec.toml.encode(tuning))
    robot_path = folder / "robot.toml"
    robot_path.write_bytes(
        dump_toml(with_values(load_toml(find(robot, "robot"), RobotParams), values, "robot"))
    )
    paths = []
    for rider in riders:
        params = with_values(load_toml(find(rider, "riders"), RiderParams), values, "rider")
        path = folder / f"{params.name}.toml"
        path.write_bytes(dump_toml(params))
        paths.append(str(path))
    return World(tuple(paths), str(robot_path), str(controller_path))


class Evaluations:
    """Runs the target's tasks and riders with given unknowns set, each evaluation a `compare` in lockstep
    on its own world files; one process pool and one scratch folder for all of them (a context manager).
    The controller keeps the nominal robot file: what is fitted or moved is the world it does not know."""

    def __init__(
        self,
        target: PaperTable,
        bench: Bench | None = None,
        scenarios: list[Scenario] | None = None,
        workers: int = 1,
        laws: tuple[str, ...] = LAWS,
    ):
        from hil.pipeline import load_scenario

        self.target = target
        self.laws = laws
        self.scenarios = scenarios or [load_scenario(t) for t in target.tasks]
        self.robot = self.scenarios[0].robot
        bench = bench or load_bench()
        nominal = msgspec.structs.replace(
            bench.controller, robot=str(find(bench.controller.robot or self.robot, "robot"))
        )
        self.bench = msgspec.structs.replace(bench, controller=nominal)
        self.controller = self.bench.controller.config
        self.workers = workers if distributable(self.bench) else 1
        self.count = 0
        self._stack = ExitStack()

    def __enter__(self) -> Evaluations:
        self._tmp = Path(self._stack.enter_context(tempfile.TemporaryDirectory(prefix="pure-hil-calibrate-")))
        self._pool = self._stack.enter_context(run_pool(self.workers)) if self.workers > 1 else None
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()

    def __call__(self, values: dict[str, float]) -> Comparison:
        world = self.write(values, self._tmp / f"eval-{self.count}")
        self.count += 1
        runs = [msgspec.structs.replace(s, robot=world.robot) for s in self.scenarios]
        bench = world.on(self.bench)
        return compare(
            runs, world.riders, progress=None, bench=bench, paper=self.target, pool=self._pool, laws=self.laws
        )

    def write(self, values: dict[str, float], folder: Path) -> World:
        return write_world(values, self.target.riders, self.robot, folder, self.controller)

    def shipped(self) -> dict[str, float]:
        """The unknowns' values in the files as shipped (a rider's from the table's first rider)."""
        trees = {
            "rider": msgspec.to_builtins(load_toml(find(self.target.riders[0], "riders"), RiderParams)),
            "robot": msgspec.to_builtins(load_toml(find(self.robot, "robot"), RobotParams)),
            "controller": msgspec.toml.decode(find(self.controller, "controller").read_bytes()),
        }
        out = {}
        for name in UNKNOWNS:
            head, *path = name.split(".")
            out[name] = float(functools.reduce(operator.getitem, path, trees[head]))
        return out


@dataclass
class Calibration:
    unknowns: list[Unknown]
    start: dict[str, float]
    fitted: dict[str, float]
    before: Comparison
    after: Comparison
    evaluations: int
    message: str
    write_files: Callable[[dict[str, float], Path], World]
    """Writes a world's files with given values (the fitted ones: `write`)."""

    @property
    def cost_before(self) -> float:
        return cost(self.before)

    @property
    def cost_after(self) -> float:
        return cost(self.after)

    def table(self) -> str:
        lines = ["| parameter | start | fitted | bounds |", "|---|---:|---:|---|"]
        lines += [
            f"| {u.name} | {self.start[u.name]:.4g} | {self.fitted[u.name]:.4g} | {u.lower:g}..{u.upper:g} |"
            for u in self.unknowns
        ]
        before, _ = self.before.checked()
        after = {(c.metric, c.task, c.law): c for c in self.after.checked()[0]}
        lines += ["", "| cell | target | before | after |", "|---|---:|---:|---:|"]
        for c in before:
            a = after[(c.metric, c.task, c.law)]
            lines.append(
                f"| {c.task} {c.law.upper()} {c.metric} | {c.paper_mean:.3g} ({c.paper_sd:.3g}) | "
                f"{c.mean:.3g}, {c.distance:.1f} SD | {a.mean:.3g}, {a.distance:.1f} SD |"
            )
        within = (sum(c.within for c in before), sum(c.within for c in after.values()))
        lines.append(
            f"\ncells within 2 SD: {within[0]} -> {within[1]} of {len(before)}; sum of squared distances "
            f"{self.cost_before:.2f} -> {self.cost_after:.2f}; {self.evaluations} evaluations "
            f"({self.message})"
        )
        return "\n".join(lines)


class _BudgetSpent(Exception):
    pass


def residuals(comparison: Comparison) -> np.ndarray:
    """Each target cell's signed distance in its SD (an SD printed as 0 counts as half its last digit)."""
    cells, _ = comparison.checked()
    return np.array([math.copysign(c.distance, c.mean - c.paper_mean) for c in cells])


def cost(comparison: Comparison) -> float:
    """The sum of the squared distances: what the fit minimises."""
    return float(np.sum(residuals(comparison) ** 2))


def calibrate(
    target: PaperTable,
    unknowns: list[Unknown],
    bench: Bench | None = None,
    scenarios: list[Scenario] | None = None,
    start: dict[str, float] | None = None,
    budget: int = 40,
    workers: int = 1,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit `unknowns` to `target` (its tasks and riders; `scenarios` in place of the shipped tasks), at most
    `budget` evaluations, starting from `start` or the shipped files' values."""
    from scipy.optimize import least_squares

    names = [u.name for u in unknowns]
    lower, upper = np.array([u.lower for u in unknowns]), np.array([u.upper for u in unknowns])
    seen: dict[tuple[float, ...], Comparison] = {}
    with Evaluations(target, bench, scenarios, workers) as evaluations:
        shipped = evaluations.shipped()
        x0 = np.clip([(start or {}).get(n, shipped[n]) for n in names], lower, upper)

        def evaluate(x: np.ndarray) -> Comparison:
            key = tuple(float(v) for v in x)
            if key not in seen:
                if len(seen) >= budget:
                    raise _BudgetSpent
                values = dict(zip(names, key, strict=True))
                seen[key] = evaluations(values)
                if progress:
                    shown = ", ".join(f"{n}={v:.4g}" for n, v in values.items())
                    progress(
                        f"  evaluation {len(seen)}: {shown}: sum of squared distances {cost(seen[key]):.2f}"
                    )
            return seen[key]

        before = evaluate(x0)
        # Relative steps of 5 %: a lockstep run is deterministic, but a rider's reaction moves its metrics in
        # small jumps, so a finite difference must span several of them; for the same reason a step below
        # 1 % of a parameter cannot improve the fit (xtol).
        try:
            fit = least_squares(
                lambda x: residuals(evaluate(x)), x0, bounds=(lower, upper), diff_step=0.05, xtol=0.01
            )
            best, message = fit.x, fit.message
        except _BudgetSpent:  # every run counts, the Jacobian's too: the best point seen
            best = np.array(min(seen, key=lambda k: cost(seen[k])))
            message = f"the budget of {budget} evaluations is spent"
        after = evaluate(best)
    return Calibration(
        unknowns,
        dict(zip(names, map(float, x0), strict=True)),
        dict(zip(names, map(float, best), strict=True)),
        before,
        after,
        len(seen),
        message,
        evaluations.write,
    )


def write(calibration: Calibration, out: Path) -> World:
    """The fitted parameter files (riders, robot, controller tuning) under out/fitted, and calibrate.md /
    .json."""
    out.mkdir(parents=True, exist_ok=True)
    fitted = calibration.write_files(calibration.fitted, out / "fitted")
    (out / "calibrate.md").write_text(calibration.table() + "\n")
    summary = {
        "fitted": calibration.fitted,
        "start": calibration.start,
        "bounds": {u.name: [u.lower, u.upper] for u in calibration.unknowns},
        "evaluations": calibration.evaluations,
        "cost_before": calibration.cost_before,
        "cost_after": calibration.cost_after,
        "before": calibration.before.to_json()["cells"],
        "after": calibration.after.to_json()["cells"],
    }
    (out / "calibrate.json").write_bytes(msgspec.json.format(msgspec.json.encode(summary), indent=2))
    return fitted


@dataclass
class Sensitivity:
    """Each cell's mean at each parameter moved down and up by `step` (relative) from the shipped value."""

    step: float
    base: Comparison
    moved: dict[str, tuple[Comparison, Comparison]]

    def table(self, metric: str) -> str:
        base = {(c.task, c.law): c for c in self.base.checked()[0] if c.metric == metric}
        columns = list(base)
        head = " | ".join(f"{task} {law.upper()}" for task, law in columns)
        lines = [f"| {metric} | {head} |", "|---|" + "---:|" * len(columns)]
        lines.append(
            "| shipped | "
            + " | ".join(f"{base[k].mean:.3g} (paper {base[k].paper_mean:g})" for k in columns)
            + " |"
        )
        for name, pair in self.moved.items():
            for sign, comparison in zip("-+", pair, strict=True):
                cells = {(c.task, c.law): c for c in comparison.checked()[0] if c.metric == metric}
                row = " | ".join(
                    f"{cells[k].mean:.3g} ({cells[k].mean - base[k].mean:+.2g})" for k in columns
                )
                lines.append(f"| {name} {sign}{self.step:.0%} | {row} |")
        return "\n".join(lines)

    def write(self, out: Path, metrics: list[str]) -> None:
        """sensitivity.md (a table per metric) and sensitivity.json (every cell at each setting)."""
        out.mkdir(parents=True, exist_ok=True)
        (out / "sensitivity.md").write_text("\n\n".join(self.table(m) for m in metrics) + "\n")
        summary = {
            "step": self.step,
            "shipped": self.base.to_json()["cells"],
            "moved": {
                name: {sign: c.to_json()["cells"] for sign, c in zip("-+", pair, strict=True)}
                for name, pair in self.moved.items()
            },
        }
        (out / "sensitivity.json").write_bytes(msgspec.json.format(msgspec.json.encode(summary), indent=2))


def sensitivity(
    target: PaperTable,
    names: list[str],
    bench: Bench | None = None,
    step: float = 0.2,
    workers: int = 1,
    scenarios: list[Scenario] | None = None,
    laws: tuple[str, ...] = LAWS,
) -> Sensitivity:
    """How each cell moves with each named parameter, one at a time, by ±`step` of its shipped value, under
    each of `laws` (default both)."""
    with Evaluations(target, bench, scenarios, workers, laws) as evaluations:
        shipped = evaluations.shipped()
        base = evaluations({})
        moved = {
            name: (
                evaluations({name: shipped[name] * (1 - step)}),
                evaluations({name: shipped[name] * (1 + step)}),
            )
            for name in names
        }
    return Sensitivity(step, base, moved)
