"""A lab's own supervisor is a plug: tests/minimal_supervisor.py (nothing from safety/), registered through
an entry point of its own distribution, runs `speed_limiting` under `pure-hil run`, and the rig, its trace,
the judge and the run folder work with it (issue 38)."""

from __future__ import annotations

import json

import numpy as np

from hil.cli import main
from hil.outputs.trace_log import LAYOUT
from tests.helpers import ROOT
from tests.zenoh_helpers import hub_endpoint

DIST = "minimal_supervisor_plug-0.1.dist-info"


def _install_entry_point(site, monkeypatch) -> None:
    """What `pip install` of a lab's package leaves: a dist-info with its entry points, on sys.path."""
    info = site / DIST
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: minimal-supervisor-plug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[pure_hil.supervisors]\nminimal = tests.minimal_supervisor:start\n"
    )
    monkeypatch.syspath_prepend(str(site))


def test_a_labs_own_supervisor_plugged_by_entry_point_runs_speed_limiting(tmp_path, monkeypatch, capsys):
    bench = tmp_path / "minimal.toml"
    text = (ROOT / "configs/benches/embedded.toml").read_text()
    bench.write_text(
        text.replace(
            '[supervisor]\nwhere = "embedded"', '[supervisor]\nwhere = "embedded"\nplugin = "minimal"'
        )
    )
    assert 'plugin = "minimal"' in bench.read_text()
    args = [
        "run",
        "speed_limiting",
        "--bench",
        str(bench),
        "--hub",
        hub_endpoint(),
        "--out",
        str(tmp_path / "run"),
    ]

    # Control: before its distribution is installed, the bench is refused by name, before any run.
    assert main(args) == 2
    assert "minimal" in capsys.readouterr().err

    _install_entry_point(tmp_path / "site", monkeypatch)
    assert main(args) == 0
    summary = json.loads((tmp_path / "run/summary.json").read_text())
    assert summary["verdict"] == "PASSED", summary
    # It was this supervisor that ran, every tick: its own report, and its permission held the drives on.
    safety = summary["safety"]
    assert safety["sc_arbitration"] == {"supervisor": "minimal", "updates": summary["rig"]["ticks"] + 1}
    assert safety["events"] == [] and safety["final_state"] == "NORMAL"
    # The request's 0.5 m/s cap reached the controller through it: its command speed rose to it, no more.
    rows = np.load(tmp_path / "run/trace.npy")
    forward = rows[:, LAYOUT.span("command_speed")][:, 0]
    assert 0.45 < np.nanmax(np.abs(forward)) <= 0.5 + 1e-9
