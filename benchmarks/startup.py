"""Start-up of `pure-hil run`: from process start to the first tick (summary.json `timing.first_tick_at`),
against, measured in the same run, a bare interpreter start and `pure-hil --help`; plus the dearest
imports of the run's modules (python -X importtime).

    python benchmarks/startup.py [SCENARIO (default balance)] [--repeat N] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PURE_HIL = Path(sys.executable).with_name("pure-hil")


def timed(command: list[str]) -> float:
    t0 = time.time()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.time() - t0


def first_tick(scenario: str, out: Path) -> tuple[float, float]:
    """(process start -> first tick, whole command) in seconds."""
    t0 = time.time()
    subprocess.run(
        [str(PURE_HIL), "run", scenario, "--out", str(out), "--quiet"],
        check=False,
        stdout=subprocess.DEVNULL,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
    )
    total = time.time() - t0
    started = json.loads((out / "summary.json").read_text())["timing"]["first_tick_at"]
    return started - t0, total


def dearest_imports(n: int = 10) -> list[tuple[str, float]]:
    code = "import hil.pipeline, controller.embedded"
    err = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True, check=True
    ).stderr
    rows = []
    for line in err.splitlines():
        if line.startswith("import time:") and "|" in line and "cumulative" not in line:
            _, cumulative, name = line[len("import time:") :].split("|")
            depth = (len(name) - len(name.lstrip()) - 1) // 2
            if depth == 1:  # imported directly by the run's own modules
                rows.append((name.strip(), int(cumulative) / 1e6))
    return sorted(rows, key=lambda r: -r[1])[:n]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("scenario", nargs="?", default="balance")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    interpreter = statistics.median(timed([sys.executable, "-c", "pass"]) for _ in range(args.repeat))
    help_ = statistics.median(timed([str(PURE_HIL), "--help"]) for _ in range(args.repeat))
    runs = []
    with tempfile.TemporaryDirectory(prefix="startup-bench-") as tmp:
        for i in range(args.repeat):
            runs.append(first_tick(args.scenario, Path(tmp) / str(i)))
    to_first = statistics.median(r[0] for r in runs)
    total = statistics.median(r[1] for r in runs)
    imports = dearest_imports()
    figures = {
        "scenario": args.scenario,
        "interpreter_s": interpreter,
        "help_s": help_,
        "first_tick_s": to_first,
        "first_tick_min_s": min(r[0] for r in runs),
        "run_total_s": total,
        "imports_s": dict(imports),
    }
    if args.json:
        print(json.dumps(figures))
        return
    print(f"pure-hil run {args.scenario}: medians of {args.repeat}")
    print(f"  bare interpreter start:          {interpreter * 1e3:7.0f} ms")
    print(f"  pure-hil --help:                 {help_ * 1e3:7.0f} ms")
    print(
        f"  process start -> first tick:     {to_first * 1e3:7.0f} ms "
        f"(min {figures['first_tick_min_s'] * 1e3:.0f}) = {to_first / interpreter:.0f}x the bare "
        "interpreter; target 1500 ms"
    )
    print(f"  whole command (run + outputs):   {total * 1e3:7.0f} ms")
    print("  dearest imports of the run's modules (cumulative, one process):")
    for name, seconds in imports:
        print(f"    {name:<28} {seconds * 1e3:7.0f} ms")


if __name__ == "__main__":
    main()
