"""Our riders against the iHACS paper's Table II (configs/paper/ihacs_table2.toml, docs/riders.md): the
shipped rider on both tasks under both laws. The paper's four riders and two riders outside its set are
benchmarks/paper_table.py (24 runs, the evidence docs/riders.md shows); here one rider's four runs still
fail when a law, the rider or the plant stops reproducing the table."""

from __future__ import annotations

import json

import pytest

from hil.pipeline import load_scenario
from hil.suites.compare import compare, write
from hil.suites.paper import KNOWN_GAPS, against, load_paper
from tests.zenoh_helpers import private_bench

TASKS = ("idle_keeping", "speed_limiting")
SHIPPED_RIDER = "s07_abi_73kg_176"
"""The scenarios' own rider, one of the paper's four."""


def test_the_shipped_rider_agrees_with_table_ii_and_keeps_its_orderings(tmp_path):
    # Two processes: the four runs are independent and deterministic.
    comparison = compare(
        [load_scenario(t) for t in TASKS], (SHIPPED_RIDER,), progress=None, bench=private_bench(), workers=2
    )
    cells, orderings = comparison.checked()
    assert len(cells) == 16
    within = [c for c in cells if c.within]
    # 15 of 16 (2026-11-28), as the paper's four riders' means: only the speed-limiting HACS tilt is out.
    assert len(within) >= 12, [(c.task, c.law, c.metric, round(c.distance, 1)) for c in cells if not c.within]
    assert len(orderings) == 8
    for o in orderings:
        # The known gaps are the four riders' means (the benchmark checks them); one rider's speed-limiting
        # tilt sits within 0.2 deg of either ordering, so it is not asserted here.
        if (o.metric, o.task) not in KNOWN_GAPS:
            assert o.holds, o
    write(comparison, tmp_path)
    data = json.loads((tmp_path / "compare.json").read_text())
    assert data["cells_within"] == len(within) and data["orderings_hold"] == sum(o.holds for o in orderings)
    assert (tmp_path / "compare.png").stat().st_size > 10_000
    assert "cells within 2 SD" in (tmp_path / "compare.md").read_text()


def test_a_cell_is_measured_in_the_papers_sds_and_a_printed_zero_sd_is_half_its_last_digit():
    paper = load_paper()
    runs = [
        {"scenario": "idle_keeping", "law": law, "pitch.max_speed": v}
        for law, v in (("hacs", 0.6), ("hacs", 0.6), ("ihacs", 0.32), ("ihacs", 0.32))
    ]
    cells, orderings = against(runs, paper)
    by_law = {c.law: c for c in cells}
    assert by_law["hacs"].distance == pytest.approx(0.0)
    # iHACS idle max|v| is printed 0.3 (0.0): an SD below 0.05, so 0.02 off is 0.4 of that.
    assert by_law["ihacs"].distance == pytest.approx(0.4) and by_law["ihacs"].within
    assert orderings[0].expected == "less" and orderings[0].holds
    runs[2]["pitch.max_speed"] = runs[3]["pitch.max_speed"] = 0.9  # positive control
    cells, orderings = against(runs, paper)
    assert not {c.law: c for c in cells}["ihacs"].within and not orderings[0].holds
    assert "reaction" in {c.law: c for c in cells}["ihacs"].note
