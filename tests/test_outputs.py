"""A run folder explains itself: summary.json names trace.npy's columns, their units and the supervisor's
state codes, says what ran beside what the scenario asked, and has one `fallen`; plots.png is titled with
the verdict and the faults, has a legend for the supervisor's states, marks each fault's window, and draws
the criteria's bounds beside the SC's command cap; the git commit of what wrote them."""

from __future__ import annotations

import dataclasses
import json
import subprocess

import matplotlib.pyplot as plt
import msgspec
import numpy as np
from matplotlib.collections import LineCollection

from drivers.vocabulary import State
from hil.faults import Fault
from hil.report.folder import commit, summary
from hil.report.plots import FAULT_COLOR, SHADES, figure
from hil.run.scenario import Verdict

UNITS = {
    "t": "s",
    "velocity.forward": "m/s",
    "velocity.left": "m/s",
    "tilt.pitch": "rad",
    "tilt.roll": "rad",
    "lean.pitch": "rad",
    "lean.roll": "rad",
    "position.x": "m",
    "position.y": "m",
    "yaw_rate": "rad/s",
    "ball_rate.pitch": "rad/s",
    "ball_rate.roll": "rad/s",
    "motor_torque.1": "Nm",
    "motor_torque.2": "Nm",
    "motor_torque.3": "Nm",
    "safety_state": "",
    "safety_speed": "m/s",
    "powered": "",
    "resting": "",
    "command_speed.pitch": "m/s",
    "command_speed.roll": "m/s",
    "tilt_command.pitch": "rad",
    "tilt_command.roll": "rad",
}


def test_the_run_folder_names_the_trace_columns_their_units_and_the_state_codes(shipped):
    folder = shipped[1] / "speed_limiting"
    described = json.loads((folder / "summary.json").read_text())["trace"]
    rows = np.load(folder / "trace.npy")
    assert rows.dtype == np.float64 and rows.shape == (described["rows"], len(described["columns"]))
    assert {c["name"]: c["unit"] for c in described["columns"]} == UNITS
    # Each column holds what its name says: the run's trace, by name.
    tr = shipped[0]["speed_limiting"].trace
    column = {c["name"]: rows[:, i] for i, c in enumerate(described["columns"])}
    expected = {
        "t": tr.t,
        "yaw_rate": tr.yaw_rate,
        "safety_state": tr.safety_state,
        "safety_speed": tr.safety_speed,
        "powered": tr.powered,
        "resting": tr.resting,
    }
    for name, values, parts in (
        ("velocity", tr.velocity, ("forward", "left")),
        ("tilt", tr.tilt, ("pitch", "roll")),
        ("lean", tr.lean, ("pitch", "roll")),
        ("position", tr.position, ("x", "y")),
        ("ball_rate", tr.ball_rate, ("pitch", "roll")),
        ("motor_torque", tr.motor_torque, ("1", "2", "3")),
        ("command_speed", tr.command_speed, ("pitch", "roll")),
        ("tilt_command", tr.tilt_command, ("pitch", "roll")),
    ):
        expected |= {f"{name}.{part}": values[:, i] for i, part in enumerate(parts)}
    assert expected.keys() == column.keys()
    for name, values in expected.items():
        assert np.array_equal(column[name], np.asarray(values, float), equal_nan=True), name
    # Every code in the state column has its name: the supervisor's states, and none yet.
    assert described["safety_states"] == {"-1": "no frame yet", **{str(s.value): s.name for s in State}}
    assert {str(int(code)) for code in np.unique(column["safety_state"])} <= described["safety_states"].keys()


def test_the_summary_says_what_ran_beside_what_the_scenario_asked_and_has_one_fallen(shipped):
    result = shipped[0]["speed_limiting"]
    # The bench and the command line override the scenario's wishes (a realtime bench, --law, --seed).
    ran = summary(dataclasses.replace(result, clock="realtime", law="hacs", seed=7))
    asked = ran["scenario"]
    assert (asked["clock"], asked["law"], asked["seed"]) == ("lockstep", "ihacs", 0)
    assert ran["as_run"] == {"law": "hacs", "clock": "realtime", "seed": 7}
    assert not {"law", "clock", "seed"} & ran.keys(), "what ran is said in one place"
    # `fallen` means what the `fallen` criterion measures; how and when it fell is `fall_cause`.
    criterion = next(v for v in result.verdicts if v.criterion == "fallen")
    upright = summary(result)
    assert upright["fallen"] is bool(criterion.value) is False and upright["fall_cause"] is None
    fell = "tilt beyond 30 deg at t=1.000 s"
    fallen = summary(dataclasses.replace(result, trace=dataclasses.replace(result.trace, fallen=fell)))
    assert fallen["fallen"] is True and fallen["fall_cause"] == fell


def _legend(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_the_plots_title_has_the_verdict_and_a_legend_names_the_supervisors_states(shipped):
    result = shipped[0]["overpower_cap"]
    fig = figure(result)
    try:
        head, faults = fig.get_suptitle().split("\n")
        assert head.endswith(": PASSED") and faults == "faults: none"
        entered = {e.to_state for e in result.trace.safety_events if e.kind == "transition"}
        assert {"LIMITING", "STOPPING", "ESTOP"} <= entered
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        assert legend == [f"supervisor {s.name}" for s in SHADES if s.name in entered]
    finally:
        plt.close(fig)
    failed = Verdict("max_speed [pitch]", 1.5, "<= 1.3 m/s", "m/s", False)
    fig = figure(dataclasses.replace(result, verdicts=[*result.verdicts, failed]))
    try:
        assert fig.get_suptitle().split("\n")[0].endswith(": FAILED — failed: max_speed [pitch]")
    finally:
        plt.close(fig)


def test_the_plots_mark_each_faults_window_and_name_it_in_the_title(shipped):
    result = shipped[0]["overpower_cap"]
    faults = [
        {"kind": "can.drop", "message": "IMU_RATE", "at": 2.0, "duration": 1.5},
        {"kind": "sensor.off", "channel": "imu.roll", "at": 6.0},
        {"kind": "sensor.off", "channel": "imu.pitch", "at": 30.0},
    ]
    end = float(result.trace.t[-1])
    trace = dataclasses.replace(
        result.trace,
        faults=[msgspec.convert(f, Fault) for f in faults],
        fault_windows=[(2.0, 3.5), (6.0, end), None],  # ended; acting to the end; never started
    )
    fig = figure(dataclasses.replace(result, trace=trace))
    try:
        title = fig.get_suptitle()
        assert "F0 can.drop message=IMU_RATE 2.00–3.50 s" in title
        assert "F1 sensor.off channel=imu.roll from 6.00 s to the end" in title
        assert "F2 sensor.off channel=imu.pitch (never started)" in title
        for ax in fig.axes:
            lines = [line for line in ax.get_lines() if line.get_color() == FAULT_COLOR]
            marks = [(line.get_xdata()[0], line.get_linestyle()) for line in lines]
            assert marks == [(2.0, "-"), (3.5, "--"), (6.0, "-")]
        assert {"fault start", "fault end"} <= set(_legend(fig.axes[0]))
    finally:
        plt.close(fig)


def test_speed_limitings_plot_says_why_the_speed_may_pass_the_cap(shipped):
    """The drawn 0.5 m/s cap is the SC's command to the controller (not enforced in this scenario); the
    verdict's limit is the max_speed criterion's 1.3 m/s, drawn too."""
    result = shipped[0]["speed_limiting"]
    speed = np.abs(result.trace.velocity[:, 0])
    assert 0.5 < speed.max() < 1.3 and result.passed
    fig = figure(result)
    try:
        drawn = [c for c in fig.axes[0].collections if isinstance(c, LineCollection)]
        level = {c.get_label(): {seg[0][1] for seg in c.get_segments()} for c in drawn}
        legend = _legend(fig.axes[0])
        cap = next(label for label in legend if label.startswith("SC command cap 0.5 m/s"))
        assert "not enforced by the supervisor" in cap and level[cap] == {0.5}
        criterion = next(label for label in legend if label.startswith("criterion max_speed [pitch]"))
        assert "<= 1.3 m/s" in criterion and level[criterion] == {1.3}
        assert {-1.3} in level.values(), "|speed| is measured: the bound is drawn on both sides"
    finally:
        plt.close(fig)


def test_the_commit_is_the_checkouts_and_none_elsewhere(tmp_path, monkeypatch):
    def git(*args):
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True)

    repo = tmp_path / "checkout"
    repo.mkdir()
    git("init", "-q")
    (repo / "f").write_text("1")
    git("add", "f")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "x")
    head = git("rev-parse", "HEAD").stdout.strip()
    try:
        assert commit(repo) == head
        (repo / "f").write_text("2")
        commit.cache_clear()
        assert commit(repo) == head + "+dirty"
        (repo / "site-packages").mkdir()
        assert commit(repo / "site-packages") is None, "a wheel installed inside a checkout is not it"
        assert commit(tmp_path) is None, "not a checkout"
        monkeypatch.setenv("PATH", "")
        commit.cache_clear()
        assert commit(repo) is None, "no git"
    finally:
        commit.cache_clear()


def test_a_real_time_run_says_its_overruns_beside_its_verdict(shipped):
    from hil.report.folder import format_table

    result = shipped[0]["speed_limiting"]
    timing = dataclasses.replace(result.trace.timing, overruns=113)
    trace = dataclasses.replace(result.trace, timing=timing)
    late = dataclasses.replace(result, clock="realtime", trace=trace)
    last = format_table(late).splitlines()[-1]
    assert f"113 overruns of {timing.ticks} ticks, 0 SYNCs late; " in last and last.endswith(result.verdict)
    assert "commands missing 0 and late 0 (the controller's), 0 and 0 (the rig's)" in last
    assert "overruns" not in format_table(result), "a lockstep run has no deadlines to overrun"
