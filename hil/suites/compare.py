"""`pure-hil compare`: HACS against iHACS on the same scenarios and riders, as the iHACS paper's Table II:
max |torso lean|, max |chassis tilt|, max |speed|, command-speed RMSE, mean (SD) over riders and trials."""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path

import msgspec

from hil.bench.bench import Bench, load_bench
from hil.run.pipeline import run
from hil.run.scenario import Scenario

PAPER_RIDERS = (
    "configs/riders/s04_abi_50kg_164.toml",
    "configs/riders/s07_abi_73kg_176.toml",
    "configs/riders/s12_mwcu_79kg_160.toml",
    "configs/riders/s16_mwcu_52kg_167.toml",
)
COLUMNS = (
    ("pitch.max_lean_deg", "max|lean| (deg)", "{:.1f}"),
    ("pitch.max_tilt_deg", "max|tilt| (deg)", "{:.1f}"),
    ("pitch.max_speed", "max|v| (m/s)", "{:.2f}"),
    ("pitch.rmse_paper", "RMSE (E-3)", "{:.1f}"),
    ("pitch.rmse", "RMSE (rad/s)", "{:.2f}"),
)
LAWS = ("hacs", "ihacs")


@dataclass(slots=True)
class Comparison:
    runs: list[dict]
    """One row per run: scenario, law, rider, seed, passed, fallen, and the metrics."""

    def cell(self, scenario: str, law: str, metric: str, fmt: str) -> str:
        values = [r[metric] for r in self.runs if r["scenario"] == scenario and r["law"] == law]
        if not values:
            return "-"
        sd = statistics.stdev(values) if len(values) > 1 else 0.0
        return f"{fmt.format(statistics.fmean(values))} ({fmt.format(sd)})"

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
        return "\n".join(lines)


def compare(
    scenarios: list[Scenario],
    riders: tuple[str, ...] = PAPER_RIDERS,
    trials: int = 1,
    progress=print,
    bench: Bench | None = None,
) -> Comparison:
    """Every scenario x rider x trial under both laws on `bench` (default embedded), in lockstep."""
    bench = (bench or load_bench()).with_overrides(clock="lockstep")
    runs = []
    for scenario in scenarios:
        for rider in riders:
            for trial in range(trials):
                for law in LAWS:
                    s = msgspec.structs.replace(scenario, rider=rider, law=law, seed=scenario.seed + trial)
                    result = run(s, bench.with_overrides(law="scenario"))
                    row = {
                        "scenario": scenario.name,
                        "law": law,
                        "rider": Path(rider).stem,
                        "seed": s.seed,
                        "passed": result.passed,
                        "fallen": result.trace.fallen,
                        **result.metrics,
                    }
                    runs.append(row)
                    if progress:
                        progress(
                            f"  {scenario.name:<16} {law:<6} {Path(rider).stem:<20} seed {s.seed}: "
                            f"max|v| {row['pitch.max_speed']:.2f} m/s, RMSE {row['pitch.rmse']:.2f} rad/s"
                            + (f", FELL: {row['fallen']}" if row["fallen"] else "")
                        )
    return Comparison(runs)


def write(comparison: Comparison, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.json").write_bytes(msgspec.json.format(msgspec.json.encode(comparison.runs), indent=2))
    (out / "compare.md").write_text(comparison.table() + "\n")
