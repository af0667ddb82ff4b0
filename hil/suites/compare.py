"""`pure-hil compare`: HACS against iHACS on the same scenarios and riders, as the iHACS paper's Table II:
max |torso angle|, max |chassis tilt|, max |speed|, command-speed RMSE, mean (SD) over riders and trials,
each paper task's cell beside the paper's value and its distance in the paper's SDs (hil/suites/paper.py),
and a figure of the same."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import msgspec

from drivers.resources import find
from hil.bench.bench import Bench, load_bench
from hil.pipeline import run
from hil.run.scenario import Scenario
from hil.suites.campaign import distributable, run_pool
from hil.suites.paper import LAWS, WITHIN, Cell, Ordering, PaperTable, against, load_paper, mean_sd

COLUMNS = (
    ("pitch.max_torso_deg", "max|torso| (deg)", "{:.1f}"),
    ("pitch.max_lean_deg", "max|lean| (deg)", "{:.1f}"),
    ("pitch.max_tilt_deg", "max|tilt| (deg)", "{:.1f}"),
    ("pitch.max_speed", "max|v| (m/s)", "{:.2f}"),
    ("pitch.rmse_paper", "RMSE (E-3)", "{:.1f}"),
    ("pitch.rmse", "RMSE (rad/s)", "{:.2f}"),
)


@dataclass(slots=True)
class Comparison:
    runs: list[dict]
    """One row per run: scenario, law, rider, seed, passed, fallen, and the metrics."""

    paper: PaperTable | None = None
    """The paper's Table II; its tasks' cells are shown beside it."""

    def cell(self, scenario: str, law: str, metric: str, fmt: str) -> str:
        values = [r[metric] for r in self.runs if r["scenario"] == scenario and r["law"] == law]
        if not values:
            return "-"
        mean, sd = mean_sd(values)
        text = f"{fmt.format(mean)} ({fmt.format(sd)})"
        for c in self.checked()[0]:
            if (c.metric, c.task, c.law) == (metric, scenario, law):
                mark = "" if c.within else " ✗"
                paper = f"{fmt.format(c.paper_mean)} ({fmt.format(c.paper_sd)})"
                text += f" · paper {paper}, {c.distance:.1f} SD{mark}"
        return text

    def checked(self) -> tuple[list[Cell], list[Ordering]]:
        """(cells, orderings) against the paper, or nothing without it."""
        return against(self.runs, self.paper) if self.paper is not None else ([], [])

    def table(self) -> str:
        scenarios = list(dict.fromkeys(r["scenario"] for r in self.runs))
        head = ["metric", *[f"{s} {c.upper()}" for s in scenarios for c in LAWS]]
        rows = [
            [label, *[self.cell(s, c, key, fmt) for s in scenarios for c in LAWS]]
            for key, label, fmt in COLUMNS
        ]
        n = {(r["scenario"], r["law"]) for r in self.runs}
        falls = sum(bool(r["fallen"]) for r in self.runs)
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(row) + " |" for row in rows]
        lines.append(
            f"\nmean (SD) over {len(self.runs) // max(len(n), 1)} runs per column (riders × trials); "
            f"falls: {falls}"
        )
        cells, orderings = self.checked()
        if cells and self.paper is not None:  # (cells come only from the paper)
            within = sum(c.within for c in cells)
            holding = sum(o.holds for o in orderings)
            lines.append(
                f"against {self.paper.source}: {within} of {len(cells)} cells within {WITHIN:g} SD; "
                f"{holding} of {len(orderings)} orderings hold (iHACS vs HACS)"
            )
            lines += [
                f"- {c.task} {c.law.upper()} {c.metric}: {c.distance:.1f} SD off; hangs on {c.note}"
                for c in cells
                if not c.within
            ]
            lines += [
                f"- ordering {o.task} {o.metric}: the paper has iHACS {o.expected} than HACS; here "
                f"{o.ihacs:.3g} vs {o.hacs:.3g}"
                for o in orderings
                if not o.holds
            ]
        return "\n".join(lines)

    def to_json(self) -> dict:
        cells, orderings = self.checked()
        return {
            "source": self.paper.source if self.paper else None,
            "cells": [{**{k: getattr(c, k) for k in c.__slots__}, "within": c.within} for c in cells],
            "cells_within": sum(c.within for c in cells),
            "orderings": [{**{k: getattr(o, k) for k in o.__slots__}, "holds": o.holds} for o in orderings],
            "orderings_hold": sum(o.holds for o in orderings),
            "runs": self.runs,
        }


def compare(
    scenarios: list[Scenario],
    riders: tuple[str, ...] | None = None,
    trials: int = 1,
    progress=print,
    bench: Bench | None = None,
    workers: int = 1,
    paper: PaperTable | None = None,
    pool: ProcessPoolExecutor | None = None,
    laws: tuple[str, ...] = LAWS,
) -> Comparison:
    """Every scenario x rider x trial (default: the paper's four riders) under each of `laws` (default
    both) on `bench` (default embedded), in lockstep, `workers` runs at a time in fresh processes when the
    bench allows (or on `pool`, a caller's run_pool kept across comparisons)."""
    paper = paper or load_paper()
    riders = riders or tuple(str(find(r)) for r in paper.riders)
    bench = (bench or load_bench()).with_overrides(clock="lockstep", law="scenario")
    jobs = [
        (scenario.name, msgspec.structs.replace(scenario, rider=rider, law=law, seed=scenario.seed + trial))
        for scenario in scenarios
        for rider in riders
        for trial in range(trials)
        for law in laws
    ]
    rows: list[dict | None] = [None] * len(jobs)

    def done(i: int, row: dict) -> None:
        rows[i] = row
        if progress:
            progress(
                f"  {row['scenario']:<16} {row['law']:<6} {row['rider']:<20} seed {row['seed']}: "
                f"max|v| {row['pitch.max_speed']:.2f} m/s, RMSE {row['pitch.rmse']:.2f} rad/s"
                + (f", FELL: {row['fallen']}" if row["fallen"] else "")
            )

    with ExitStack() as stack:
        if pool is None and workers > 1 and distributable(bench):
            pool = stack.enter_context(run_pool(workers))
        if pool is None:
            for i, (name, s) in enumerate(jobs):
                done(i, _row(name, s, bench))
        else:
            futures = {pool.submit(_row, name, s, bench): i for i, (name, s) in enumerate(jobs)}
            for future in as_completed(futures):
                done(futures[future], future.result())
    return Comparison([r for r in rows if r is not None], paper)


def _row(name: str, scenario: Scenario, bench: Bench) -> dict:
    """One run's line of the comparison: what it was, and its metrics."""
    result = run(scenario, bench)
    return {
        "scenario": name,
        "law": scenario.law,
        "rider": Path(scenario.rider).stem,
        "seed": scenario.seed,
        "passed": result.passed,
        "fallen": result.trace.fallen,
        **result.metrics,
    }


def write(comparison: Comparison, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    data = msgspec.json.encode(comparison.to_json())
    (out / "compare.json").write_bytes(msgspec.json.format(data, indent=2))
    (out / "compare.md").write_text(comparison.table() + "\n")
    cells, _ = comparison.checked()
    if cells:
        figure(cells, out / "compare.png")


def figure(cells, path: Path) -> None:
    """One panel per metric: our mean (SD) per task and law beside the paper's mean and its 2-SD band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = list(dict.fromkeys(c.metric for c in cells))
    columns = list(dict.fromkeys((c.task, c.law) for c in cells))
    fig, axes = plt.subplots(1, len(metrics), figsize=(3.4 * len(metrics), 3.6), squeeze=False)
    for ax, metric in zip(axes[0], metrics, strict=True):
        for c in (c for c in cells if c.metric == metric):
            x = columns.index((c.task, c.law))
            band = 2 * c.paper_sd
            ax.add_patch(plt.Rectangle((x - 0.3, c.paper_mean - band), 0.6, 2 * band, color="0.85", zorder=0))
            ax.hlines(c.paper_mean, x - 0.3, x + 0.3, color="0.4", zorder=1)
            ax.errorbar(
                x,
                c.mean,
                yerr=c.sd,
                fmt="o",
                color="tab:blue" if c.within else "tab:red",
                capsize=3,
                zorder=2,
            )
        ax.set_xticks(range(len(columns)), [f"{t.split('_')[0]}\n{law.upper()}" for t, law in columns])
        ax.set_title(metric.removeprefix("pitch."), fontsize=9)
        ax.margins(y=0.15)
    fig.suptitle("ours: mean ± SD (red: beyond 2 SD); paper: mean (line) and ± 2 SD (grey)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
