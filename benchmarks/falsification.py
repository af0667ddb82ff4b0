"""Which searcher finds the worst rider in fewer runs: `pure-hil adversary`'s optuna samplers (uniform
random, Sobol, CMA-ES) against the two optimisers of PSY-TaLiRo (the Python S-TaLiRo), uniform random and
dual annealing, on the same objective (the requirement's STL robustness of a lockstep run,
hil/suites/adversary.py) over the same space of lean profiles, with the same budget and seeds. (That the
robustness is what rtamt, the STL monitor PSY-TaLiRo uses, computes: tests/test_adversary.py.)

    python benchmarks/falsification.py [SCENARIO (speed_limiting)] [--law hacs] [--objective overspeed]
                                       [--budget 50] [--seeds 3] [--workers 2] [--methods a,b,...] [--json]

PSY-TaLiRo: `pip install '.[staliro]'`; without it only optuna's samplers run. Every search is sequential
(one run at a time: the figure is runs needed, not wall time); searches run side by side on `--workers`
processes. The table is in docs/riders.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from concurrent.futures import as_completed

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import msgspec

from drivers.config import load_toml
from drivers.resources import find
from hil.bench.bench import load_bench
from hil.pipeline import load_scenario
from hil.suites.adversary import SPACE, candidate, evaluate, requirement, search
from hil.suites.campaign import run_pool
from plant.params import RiderParams

METHODS = {
    "cmaes": "optuna CMA-ES",
    "random": "optuna random",
    "qmc": "optuna Sobol (QMC)",
    "taliro-random": "PSY-TaLiRo uniform random",
    "taliro-annealing": "PSY-TaLiRo dual annealing",
}
"""Searchers by name; the first three are `pure-hil adversary --sampler`'s."""
SEEDS = range(1, 1000)  # PSY-TaLiRo refuses a seed of 0


def has_staliro() -> bool:
    try:
        import staliro  # noqa: F401
    except ImportError:
        return False
    return True


def _setup(name: str, law: str, objective: str):
    scenario = msgspec.structs.replace(load_scenario(name), law=law)
    bench = load_bench().with_overrides(clock="lockstep", law="scenario")
    return scenario, bench, requirement(objective, scenario, bench)


def one_search(method: str, name: str, law: str, objective: str, budget: int, seed: int) -> list[float]:
    """The robustness of each run of one search, in order (in a worker process)."""
    scenario, bench, req = _setup(name, law, objective)
    if not method.startswith("taliro-"):
        return search(scenario, objective, budget=budget, seed=seed, bench=bench, sampler=method).history
    import staliro
    from staliro.optimizers import DualAnnealing, UniformRandom

    rider = load_toml(find(scenario.rider, "riders"), RiderParams)
    history: list[float] = []

    @staliro.costfunc
    def robustness(inputs: staliro.Inputs) -> float:
        x = {name: float(inputs.static[name]) for name in SPACE}
        history.append(req.robustness(evaluate(candidate(scenario, x, rider), bench)))
        return history[-1]

    optimizer = UniformRandom() if method == "taliro-random" else DualAnnealing()
    options = staliro.TestOptions(runs=1, iterations=budget, static_inputs=dict(SPACE), seed=seed)
    staliro.staliro(robustness, optimizer, options)
    return history[:budget]


def runs_to(history: list[float], level: float) -> int | None:
    """Runs until the best robustness so far is at or below `level` (None: never within the budget)."""
    best = float("inf")
    for i, rho in enumerate(history, 1):
        best = min(best, rho)
        if best <= level:
            return i
    return None


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="speed_limiting")
    parser.add_argument("--law", default="hacs", choices=["hacs", "ihacs"])
    parser.add_argument("--objective", default="overspeed", choices=["overspeed", "tilt", "rmse"])
    parser.add_argument("--budget", type=int, default=50)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--methods", default=",".join(METHODS), help="comma-separated, of: " + ", ".join(METHODS)
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    methods = [m for m in args.methods.split(",") if has_staliro() or not m.startswith("taliro-")]
    if unknown := [m for m in methods if m not in METHODS]:
        parser.error(f"unknown searcher {', '.join(unknown)}: one of {', '.join(METHODS)}")
    scenario, bench, req = _setup(args.scenario, args.law, args.objective)
    shipped = req.robustness(evaluate(scenario, bench))
    t0 = time.perf_counter()
    histories: dict[tuple[str, int], list[float]] = {}
    with run_pool(args.workers) as pool:
        jobs = {
            pool.submit(one_search, m, args.scenario, args.law, args.objective, args.budget, seed): (m, seed)
            for m in methods
            for seed in SEEDS[: args.seeds]
        }
        for future in as_completed(jobs):
            histories[jobs[future]] = future.result()
    wall = time.perf_counter() - t0
    best = min(min(h) for h in histories.values())
    near = best + 0.01 * abs(best)  # within 1 % of the worst any search found
    figures = {
        "scenario": args.scenario,
        "law": args.law,
        "requirement": req.formula,
        "budget": args.budget,
        "seeds": args.seeds,
        "shipped_robustness": shipped,
        "best_robustness": best,
        "wall_s": wall,
        "methods": {},
    }
    for m in methods:
        runs = [histories[(m, s)] for s in SEEDS[: args.seeds]]
        figures["methods"][METHODS[m]] = {
            "best_per_seed": [min(h) for h in runs],
            "runs_past_shipped": [runs_to(h, shipped - 1e-9) for h in runs],
            "runs_to_1pct_of_best": [runs_to(h, near) for h in runs],
        }
    if args.json:
        print(json.dumps(figures))
        return
    print(
        f"{args.scenario} under {args.law}, {req.formula}: budget {args.budget} runs, {args.seeds} seeds, "
        f"{wall:.0f} s on {args.workers} workers"
    )
    print(f"  shipped rider's robustness {shipped:+.3f} {req.unit}; worst found by any {best:+.3f}")
    print(f"  {'searcher':<28}{'best (median)':>14}{'runs past shipped':>20}{'runs to 1 % of worst':>22}")
    for m, f in figures["methods"].items():
        med = statistics.median(f["best_per_seed"])
        print(
            f"  {m:<28}{med:>+14.3f}{_fmt(f['runs_past_shipped']):>20}{_fmt(f['runs_to_1pct_of_best']):>22}"
        )
    print("  (per seed; '-' = not within the budget)")
    if not has_staliro():
        print("  PSY-TaLiRo not installed (pip install '.[staliro]'): optuna's samplers only")


def _fmt(values: list[int | None]) -> str:
    return " ".join("-" if v is None else str(v) for v in values)


if __name__ == "__main__":
    main()
