"""Plants and fault families are plugs (issue 48): a lab's own, registered by one entry-point line each in a
distribution of its own (tests/lab_plugs.py), is refused by name before it is installed, with the file, the
field and what is installed, and is built and run after."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.config import ConfigError
from drivers.registry import FAULT_FAMILIES, PLANTS, installed
from hil.bench.bench import load_bench
from hil.outputs.trace_log import LAYOUT
from hil.pipeline import load_scenario, run
from hil.run.build import RunOptions
from hil.run.plants import load_sim
from tests.helpers import ROOT
from tests.lab_plugs import ENTRY_POINTS
from tests.zenoh_helpers import hub_endpoint

OUTPUTS = "\n[outputs]\ncan_log = false\nrecording = false\nplots = false\nmcap = false\n"


def install_lab(site: Path) -> Path:
    """What `pip install` of the lab's package leaves: a dist-info with its entry points (put `site` on
    sys.path)."""
    info = site / "lab_plugs-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-plugs\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    return site


def bench_file(folder: Path, plant: str) -> Path:
    """The embedded bench with `plant` for its plant, writing only summary.json and trace.npy."""
    path = folder / f"{plant}.toml"
    path.write_text(f'plant = "{plant}"\n' + (ROOT / "configs/benches/embedded.toml").read_text() + OUTPUTS)
    return path


def test_the_built_in_plants_and_fault_families_are_entry_points_of_this_package():
    assert installed(PLANTS) == ["3d", "planar"]
    assert installed(FAULT_FAMILIES) == ["actuators", "devices", "frames", "processes", "sensors", "topics"]


def test_a_labs_plant_is_refused_by_name_before_its_entry_point_and_built_after(tmp_path, monkeypatch):
    bench = bench_file(tmp_path, "lab")
    with pytest.raises(ConfigError) as refused:
        load_bench(bench)
    said = str(refused.value)
    assert said.startswith(f"{bench}: ") and "plant: no plant 'lab' installed (have: sim, 3d, planar)" in said
    sim = tmp_path / "sim.toml"
    sim.write_text('plant = "lab"\n')
    with pytest.raises(ConfigError, match=r"no plant 'lab' installed \(have: 3d, planar\) - at `\$\.plant`"):
        load_sim(sim)

    monkeypatch.syspath_prepend(str(install_lab(tmp_path / "site")))
    assert load_sim(sim).plant == "lab"
    scenario = load_scenario("balance")
    built: dict[str, set[str]] = {}
    for plant in ("lab", "planar"):  # the planar plant: the control, another class by the same recording
        seen = built.setdefault(plant, set())
        options = RunOptions(on_tick=lambda p, seen=seen: seen.add(type(p).__name__))
        result = run(scenario, load_bench(bench_file(tmp_path, plant)), options=options)
        assert result.trace.failure is None and not result.trace.fallen
    assert built == {"lab": {"LabPlant"}, "planar": {"Plant"}}


def pure_hil(args: list[str], site: Path | None) -> subprocess.CompletedProcess[str]:
    """`pure-hil ARGS` in a fresh interpreter (the fault catalog is read once, when hil.faults is imported),
    with the lab's distribution on its path or not."""
    path = [str(ROOT)] if site is None else [str(site), str(ROOT)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path), "OPENBLAS_NUM_THREADS": "1"}
    main = "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", main, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )


def test_a_labs_fault_family_is_refused_by_name_before_its_entry_point_and_injected_after(tmp_path):
    scenario = tmp_path / "twisted.toml"
    scenario.write_text(
        (ROOT / "configs/scenarios/balance.toml").read_text().replace("duration = 5.0", "duration = 1.5")
        + '\n[[faults]]\nkind = "lab.twist"\nat = 0.5\nduration = 0.5\ntorque = 8.0\n'
    )
    args = ["run", str(scenario), "--bench", str(bench_file(tmp_path, "planar")), "--hub", hub_endpoint()]

    refused = pure_hil([*args, "--out", str(tmp_path / "refused")], site=None)
    assert refused.returncode == 2, refused.stderr
    said = refused.stderr.strip()
    assert said.startswith(f"pure-hil run: {scenario}: no fault kind 'lab.twist' in the fault families")
    assert "(actuators, devices, frames, processes, sensors, topics)" in said and "plant.push" in said
    assert said.endswith("- at `$.faults[0].kind`") and "\n" not in said

    out = tmp_path / "run"
    ran = pure_hil([*args, "--out", str(out)], site=install_lab(tmp_path / "site"))
    assert ran.returncode in (0, 1), ran.stderr  # judged: the balance criteria may not hold through a twist
    summary = json.loads((out / "summary.json").read_text())
    [fault] = summary["faults"]
    assert fault["fault"]["kind"] == "lab.twist" and fault["acted"] == [0.5, 1.0]
    # Its hooks acted on the plant: the chassis turns under the torque, and not before it.
    rows = np.load(out / "trace.npy")
    t, yaw_rate = rows[:, LAYOUT.span("t")].ravel(), np.abs(rows[:, LAYOUT.span("yaw_rate")].ravel())
    assert yaw_rate[t < 0.5].max() < 1e-9 < 0.05 < yaw_rate[(t > 0.5) & (t <= 1.0)].max()
