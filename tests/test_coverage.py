"""The coverage judge itself (hil/suites/coverage.py): each class from synthetic outcomes, so a
campaign's 0 MISSED means what it says."""

import numpy as np

from hil.suites.coverage import Bounds, Outcome, classify, false_trip

BOUNDS = Bounds()
T = np.round(np.arange(0.0, 5.0, 0.01), 4).tolist()


def run(speed=0.0, tilt=1.0, yaw=0.0, transitions=(), fault_start=3.0, **kw) -> Outcome:
    """A run at constant values, with `(t0, value)` steps in speed, tilt or yaw rate after t0."""

    def series(x):
        if isinstance(x, tuple):
            t0, value = x
            return [value if t >= t0 else 0.0 for t in T]
        return [x] * len(T)

    return Outcome(
        T, series(speed), series(tilt), series(yaw), list(transitions), fault_start=fault_start, **kw
    )


TWIN = run()


def test_a_reaction_of_its_own_within_the_bound_is_detected_and_a_later_one_late():
    c = classify(run(speed=(3.05, 0.3), transitions=[(3.1, "STOPPING", "SENSOR_DISAGREE")]), TWIN, BOUNDS)
    assert (c.label, c.cause) == ("DETECTED", "SENSOR_DISAGREE") and abs(c.reaction - 0.1) < 1e-9
    c = classify(run(speed=(3.05, 0.3), transitions=[(3.5, "STOPPING", "SENSOR_DISAGREE")]), TWIN, BOUNDS)
    assert c.label == "LATE" and abs(c.departed - 0.05) < 1e-9


def test_seen_before_the_run_departs_from_its_twin_is_detected_however_long_after_the_start():
    c = classify(run(speed=(4.5, 0.3), transitions=[(4.0, "STOPPING", "SENSOR_DISAGREE")]), TWIN, BOUNDS)
    assert c.label == "DETECTED" and c.departed is None
    # The bound counts from the departure when the fault changed nothing at first.
    c = classify(run(speed=(4.0, 0.3), transitions=[(4.1, "STOPPING", "SENSOR_DISAGREE")]), TWIN, BOUNDS)
    assert c.label == "DETECTED"
    c = classify(run(speed=(4.0, 0.3), transitions=[(4.4, "STOPPING", "SENSOR_DISAGREE")]), TWIN, BOUNDS)
    assert c.label == "LATE"


def test_a_consequence_is_not_a_detection():
    fell = run(tilt=(3.5, 25.0), transitions=[(3.4, "ESTOP", "TILT")], fell_at=3.8)
    c = classify(fell, TWIN, BOUNDS)
    assert c.label == "MISSED" and "fell" in c.note
    assert classify(run(speed=(3.2, 2.3)), TWIN, BOUNDS).label == "MISSED", "over the cap, unseen"


def test_unseen_and_within_the_benign_bounds_is_benign_beyond_them_missed():
    assert classify(run(speed=(3.2, 0.2)), TWIN, BOUNDS).label == "BENIGN"
    assert classify(run(yaw=(3.2, 0.5)), TWIN, BOUNDS).label == "MISSED", "a drive lost: the robot yaws"
    assert classify(run(speed=(3.2, 0.7)), TWIN, BOUNDS).label == "MISSED"
    push = run(speed=(3.2, 0.7), disturbance=True)
    assert classify(push, TWIN, BOUNDS).label == "BENIGN", "a push ridden through"


def test_a_latent_fault_counts_from_its_demand_and_a_drive_left_powered_is_a_hazard():
    demand = [(3.0, "STOPPING", "OPERATOR_ESTOP"), (4.0, "ESTOP", "OPERATOR_ESTOP")]
    seen = run(transitions=[*demand, (4.02, "ESTOP", "DRIVE_NOT_DISABLED")], latent=True, detect_within=0.05)
    c = classify(seen, TWIN, BOUNDS)
    assert (c.label, c.cause) == ("DETECTED", "DRIVE_NOT_DISABLED") and abs(c.reaction - 0.02) < 1e-9
    unseen = run(transitions=demand, latent=True, powered_after_estop=0.9)
    assert classify(unseen, TWIN, BOUNDS).label == "MISSED"


def test_a_dead_supervisors_reaction_is_the_drives_own_watchdog():
    c = classify(run(transitions=[(3.045, "SUPERVISOR_LOST", "PERMISSION_TIMEOUT")]), TWIN, BOUNDS)
    assert (c.label, c.cause) == ("DETECTED", "PERMISSION_TIMEOUT")


def test_false_trips_are_the_supervisors_own_actions():
    assert false_trip(run(fault_start=None)) == ""
    operator = [(3.0, "STOPPING", "OPERATOR_ESTOP"), (3.3, "ESTOP", "OPERATOR_ESTOP")]
    assert false_trip(run(fault_start=None, transitions=operator)) == ""
    assert "OVER_CAP" in false_trip(run(fault_start=None, transitions=[(2.0, "LIMITING", "OVER_CAP")]))
    assert "fell" in false_trip(run(fault_start=None, fell_at=4.0))


def test_what_followed_a_detection_its_modes_and_who_held_the_drives():
    seen = [
        (2.0, "LIMITING", "OVER_CAP"),
        (3.02, "STOPPING", "SENSOR_DISAGREE"),
        (3.5, "ESTOP", "STOP_TIMEOUT"),
    ]
    # Power cut at 0.6 m/s with no takeover: nobody held the drives, and the robot fell.
    cut = classify(run(speed=(3.0, 0.6), transitions=seen, fell_at=3.9), TWIN, BOUNDS)
    assert cut.name == "DETECTED+FELL" and not cut.passed
    assert (cut.after.modes, cut.after.held_by, cut.after.to_rest) == (
        "LIMITING>STOPPING>ESTOP",
        "nobody",
        None,
    )
    excused = run(speed=(3.0, 0.6), transitions=seen, fell_at=3.9, unrecoverable="measured")
    assert classify(excused, TWIN, BOUNDS).passed, "a fall the campaign names unrecoverable does not fail"
    # The recovery law took over (an ESTOP again for another cause is one mode) and the robot stopped.
    taken = [(3.02, "RECOVERY", "HEARTBEAT_LOST"), (4.0, "ESTOP", "HEARTBEAT_LOST"), (4.1, "ESTOP", "TILT")]
    c = classify(run(speed=(3.0, 0.3), transitions=taken), TWIN, BOUNDS)
    assert c.name == "DETECTED+MOVING", "still moving at the end"
    stopped = [0.3 if 3.0 <= t < 3.8 else 0.0 for t in T]
    c = classify(Outcome(T, stopped, [1.0] * len(T), [0.0] * len(T), taken, fault_start=3.0), TWIN, BOUNDS)
    assert c.name == "DETECTED+AT_REST" and c.passed
    assert (c.after.modes, c.after.held_by) == ("NORMAL>RECOVERY>ESTOP", "recovery law")
    assert abs(c.after.to_rest - 0.8) < 1e-9 and abs(c.after.peak_speed - 0.3) < 1e-9


def test_the_docs_table_names_each_cases_reaction_modes_and_end():
    from hil.suites.coverage import cell, table

    fell = {
        "class": "DETECTED+FELL",
        "cause": "DRIVES_SILENT",
        "reaction": 0.0475,
        "note": "then fell",
        "after": {"ended": "FELL", "modes": "NORMAL>ESTOP", "excused": "no frame reaches the drives"},
    }
    assert cell(fell) == "DRIVES_SILENT 47.5 ms; NORMAL>ESTOP; fell (unrecoverable)"
    assert cell({**fell, "after": {**fell["after"], "excused": ""}}).endswith("; fell")
    assert cell({"class": "BENIGN", "after": None}) == "benign"
    report = {
        "cases": [
            {
                "case": "slalom-can.babble-seed0",
                "scenario": "configs/scenarios/slalom.toml",
                "role": "faulty",
                "coverage": fell,
            },
            {
                "case": "slalom-fault_free-seed0",
                "scenario": "configs/scenarios/slalom.toml",
                "role": "baseline",
                "coverage": None,
            },
        ]
    }
    rows = table(report).splitlines()
    assert rows[2] == "| `can.babble` |  | DRIVES_SILENT 47.5 ms; NORMAL>ESTOP; fell (unrecoverable) |  |"
    assert len(rows) == 3


def test_the_docs_dead_drive_table_names_each_cases_peak_yaw_rate_and_end():
    from hil.suites.coverage import dead_drives

    def case(scenario, fault_set, ended, yaw, fall_cause=None, excused=""):
        after = {"ended": ended, "peak_yaw_rate": yaw, "excused": excused}
        return {
            "case": f"{scenario}-{fault_set}-seed0",
            "scenario": f"configs/scenarios/{scenario}.toml",
            "role": "faulty",
            "fall_cause": fall_cause,
            "coverage": {"class": f"DETECTED+{ended}", "after": after},
        }

    report = {
        "cases": [
            case("balance", "plant.drive_torque", "AT_REST", 2.42),
            case(
                "slalom", "plant.drive_torque-drive2", "FELL", 11.6, "tilt beyond 30 deg at t=4.138 s", "why"
            ),
            case("slalom", "can.babble", "FELL", 0.1, "tilt beyond 30 deg at t=3.5 s"),  # not a dead drive
        ]
    }
    rows = dead_drives(report).splitlines()
    assert rows[0] == "| dead drive | speed_limiting | slalom | balance |"
    assert rows[2] == "| drive 1 |  |  | 2.4 rad/s; at rest |"
    assert rows[3] == "| drive 2 |  | 11.6 rad/s; fell: tilt beyond 30 deg at 4.1 s (unrecoverable) |  |"
    assert len(rows) == 4


def test_the_table_command_refuses_a_missing_or_foreign_report_by_name(tmp_path, capsys):
    from hil.suites.coverage import main

    assert main([str(tmp_path / "nope.json")]) == 2
    assert "nope.json: cannot read" in capsys.readouterr().err
    (tmp_path / "other.json").write_text('{"cases": 3}')
    assert main([str(tmp_path / "other.json")]) == 2
    assert "other.json: not a coverage campaign's report" in capsys.readouterr().err
