"""`pure-hil adversary SCENARIO --objective overspeed|tilt|rmse`: the worst rider a controller and its
supervisor face. A requirement written as a Signal Temporal Logic formula, always (|v| <= cap) or always
(|tilt| <= limit), has a robustness (for "always": the smallest margin over the run; negative: violated;
tests/test_adversary.py checks it against rtamt's); an optuna sampler searches lean profiles within the
rider's physical limits (amplitude, rate, timing, both planes) for the lowest robustness, each evaluation a
lockstep run. The worst profile is written as a scenario file that reproduces it, with its run folder
(docs/riders.md; which sampler, and why: benchmarks/falsification.py).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from drivers.config import dump_toml, load_toml
from drivers.resources import find
from hil.bench.bench import Bench, load_bench
from hil.run.build import judged_rules
from hil.run.scenario import Intent, Scenario
from hil.suites.campaign import distributable, run_pool
from plant.params import RiderParams
from plant.rider import Hold, Ramp

Objective = Literal["overspeed", "tilt", "rmse"]
SAMPLERS = ("random", "qmc", "cmaes")
"""optuna samplers a search may use: uniform random (the default: it found the worst riders in the fewest
runs, benchmarks/falsification.py), scrambled Sobol (quasi-random), CMA-ES."""

SPACE = {
    "start": (0.5, 2.0),  # s before the rider begins
    "pitch1": (-1.0, 1.0),  # first lean, fraction of max_lean_deg
    "rate1": (0.1, 1.0),  # its rate, fraction of max_lean_rate_deg
    "hold1": (0.2, 4.0),  # s held
    "pitch2": (-1.0, 1.0),  # second lean
    "rate2": (0.1, 1.0),
    "roll": (-1.0, 1.0),  # sideways lean, from the start
    "roll_rate": (0.1, 1.0),
}
"""A lean profile, every value within what the rider's body allows (RiderParams)."""


def profile(x: dict[str, float], rider: RiderParams) -> Intent:
    """The intent a point of SPACE describes for this rider."""
    lean, rate = rider.max_lean_deg, rider.max_lean_rate_deg

    def ramp(to: float, frm: float, fraction: float) -> Ramp:
        return Ramp(to=to, duration=max(abs(to - frm) / (fraction * rate), 0.05))

    p1, p2, roll = x["pitch1"] * lean, x["pitch2"] * lean, x["roll"] * lean
    return Intent(
        pitch=[
            Hold(duration=x["start"]),
            ramp(p1, 0.0, x["rate1"]),
            Hold(duration=x["hold1"]),
            ramp(p2, p1, x["rate2"]),
        ],
        roll=[Hold(duration=x["start"]), ramp(roll, 0.0, x["roll_rate"])],
    )


@dataclass(frozen=True, slots=True)
class Requirement:
    """What must hold, as STL over the run's trace; robustness > 0: held with that margin."""

    objective: Objective
    formula: str
    bound: float
    unit: str

    def robustness(self, metrics: dict[str, float]) -> float:
        # For always(|s| <= b) the robustness is min_t (b - |s(t)|) = b - max|s|, the larger of the planes.
        metric = METRIC[self.objective]
        return self.bound - max(metrics[f"pitch.{metric}"], metrics[f"roll.{metric}"])


METRIC = {"overspeed": "max_speed", "tilt": "max_tilt_deg", "rmse": "rmse"}


def requirement(objective: Objective, scenario: Scenario, bench: Bench) -> Requirement:
    if objective == "overspeed":
        caps = [e.cap for e in scenario.sc if e.mode == "limit"]
        if not caps:
            raise ValueError(f'scenario {scenario.name} has no speed cap ([[sc]] mode = "limit") to exceed')
        return Requirement(objective, f"always (|v| <= {min(caps):g} m/s)", min(caps), "m/s")
    if objective == "tilt":
        limit = judged_rules(bench, scenario).motion.tilt_limit_deg
        return Requirement(objective, f"always (|tilt| <= {limit:g} deg)", limit, "deg")
    return Requirement(objective, "rmse <= 0 rad/s (smaller is better)", 0.0, "rad/s")


def evaluate(scenario: Scenario, bench: Bench) -> dict[str, float]:
    """One lockstep run's metrics (in a worker process)."""
    from hil.pipeline import run

    return run(scenario, bench).metrics


@dataclass
class Search:
    requirement: Requirement
    worst: Scenario
    shipped_robustness: float
    history: list[float]
    """Robustness of each evaluation, in order."""

    @property
    def worst_robustness(self) -> float:
        return min(self.history)

    @property
    def evaluations(self) -> int:
        return len(self.history)

    def evaluations_to_worst(self) -> int:
        return int(np.argmin(self.history)) + 1


def search(
    scenario: Scenario,
    objective: Objective,
    budget: int = 50,
    workers: int = 1,
    seed: int = 0,
    bench: Bench | None = None,
    progress: Callable[[str], None] | None = None,
    sampler: str = "random",
) -> Search:
    """`sampler` (one of SAMPLERS) over SPACE for the lowest robustness of the objective's requirement,
    `budget` runs."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    bench = (bench or load_bench()).with_overrides(clock="lockstep", law="scenario")
    rider = load_toml(find(scenario.rider, "riders"), RiderParams)
    req = requirement(objective, scenario, bench)
    study = optuna.create_study(sampler=_sampler(sampler, seed), direction="minimize")
    candidates: dict[int, Scenario] = {}
    history: list[float] = []
    pool = run_pool(workers) if workers > 1 and distributable(bench) else None
    try:
        shipped = req.robustness(_run_all(pool, [scenario], bench)[0])
        while len(history) < budget:
            trials = [study.ask() for _ in range(min(workers, budget - len(history)))]
            batch = []
            for trial in trials:
                x = {name: trial.suggest_float(name, lo, hi) for name, (lo, hi) in SPACE.items()}
                candidates[trial.number] = candidate(scenario, x, rider)
                batch.append(candidates[trial.number])
            # Told in the order asked: the same seed gives the same search, however the runs finish.
            for trial, metrics in zip(trials, _run_all(pool, batch, bench), strict=True):
                rho = req.robustness(metrics)
                study.tell(trial, rho)
                history.append(rho)
                if progress:
                    progress(f"  evaluation {len(history)}: robustness {rho:+.3f} {req.unit}")
    finally:
        if pool is not None:
            pool.shutdown()
    return Search(req, candidates[study.best_trial.number], shipped, history)


def candidate(scenario: Scenario, x: dict[str, float], rider: RiderParams) -> Scenario:
    """The scenario with the rider's intent the point `x` of SPACE describes (its pass criteria dropped:
    the requirement judges it)."""
    return msgspec.structs.replace(
        scenario, intent=profile(x, rider), name=f"{scenario.name}_adversary", criteria=[]
    )


def _sampler(name: str, seed: int):
    import optuna

    if name == "cmaes":
        return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    if name == "qmc":
        with warnings.catch_warnings():  # "experimental" in optuna since 3.0: its interface may change
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.QMCSampler(
                qmc_type="sobol", scramble=True, seed=seed, warn_independent_sampling=False
            )
    raise ValueError(f"sampler {name!r}: one of {', '.join(SAMPLERS)}")


def _run_all(pool, scenarios: list[Scenario], bench: Bench) -> list[dict[str, float]]:
    if pool is None:
        return [evaluate(s, bench) for s in scenarios]
    return list(pool.map(evaluate, scenarios, [bench] * len(scenarios)))


def write_worst(found: Search, out: Path, bench: Bench | None = None) -> Path:
    """The worst profile as a scenario file (its rider, law, seed, SC schedule and intent) and its run
    folder next to it; returns the scenario file."""
    from hil.pipeline import run

    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{found.worst.name}.toml"
    path.write_bytes(dump_toml(_absolute(found.worst)))
    run(
        found.worst, (bench or load_bench()).with_overrides(clock="lockstep", law="scenario"), out=out / "run"
    )
    return path


def _absolute(scenario: Scenario) -> Scenario:
    """The scenario with its robot and rider as absolute paths: the file reproduces from any folder."""
    return msgspec.structs.replace(
        scenario, robot=str(find(scenario.robot, "robot")), rider=str(find(scenario.rider, "riders"))
    )


def summary(found: Search) -> str:
    req = found.requirement
    worse = "exceeds" if found.worst_robustness < found.shipped_robustness else "does not exceed"
    return (
        f"requirement: {req.formula}\n"
        f"shipped rider: robustness {found.shipped_robustness:+.3f} {req.unit}\n"
        f"worst found:   robustness {found.worst_robustness:+.3f} {req.unit} (evaluation "
        f"{found.evaluations_to_worst()} of {found.evaluations}); it {worse} the shipped rider's"
    )
