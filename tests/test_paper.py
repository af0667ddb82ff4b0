"""Our riders against the iHACS paper's Table II (configs/paper/ihacs_table2.toml, docs/riders.md): the
paper's four riders on both tasks under both laws, and two riders outside its set."""

from __future__ import annotations

import json

import pytest

from hil.pipeline import load_scenario
from hil.suites.compare import compare, write
from hil.suites.paper import against, load_paper
from tests.zenoh_helpers import private_bench

TASKS = ("idle_keeping", "speed_limiting")
KNOWN_GAPS = {("pitch.max_torso_deg", "speed_limiting"), ("pitch.max_tilt_deg", "speed_limiting")}
"""Orderings the model does not reproduce (docs/riders.md): under HACS the riders here need as much lean to
reach 1.4 m/s as iHACS riders use in 7 s, where the paper's HACS riders needed 9.5 deg."""


def _compare(riders=None):
    # Two processes: the 16 runs are independent and deterministic, on two cores in half the time.
    return compare([load_scenario(t) for t in TASKS], riders, progress=None, bench=private_bench(), workers=2)


def _orderings(comparison):
    return {(o.metric, o.task): o for o in comparison.checked()[1]}


def test_the_papers_riders_agree_with_table_ii_and_keep_its_orderings(tmp_path):
    comparison = _compare()
    cells, _ = comparison.checked()
    assert len(cells) == 16
    within = [c for c in cells if c.within]
    assert len(within) >= 12, [(c.task, c.law, c.metric, round(c.distance, 1)) for c in cells if not c.within]
    orderings = _orderings(comparison)
    assert len(orderings) == 8
    for key, o in orderings.items():
        # A known gap that closes is news too: the docs and this list must then change.
        assert o.holds == (key not in KNOWN_GAPS), (key, o)
    write(comparison, tmp_path)
    data = json.loads((tmp_path / "compare.json").read_text())
    assert data["cells_within"] == len(within) and data["orderings_hold"] == 6
    assert (tmp_path / "compare.png").stat().st_size > 10_000
    assert "cells within 2 SD" in (tmp_path / "compare.md").read_text()


def test_riders_outside_the_papers_set_keep_its_orderings():
    comparison = _compare(("light_45kg_150", "heavy_120kg_185"))
    for key, o in _orderings(comparison).items():
        assert o.holds == (key not in KNOWN_GAPS), (key, o)


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
