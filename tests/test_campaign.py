"""Campaigns: expansion, the report and JUnit, the CLI with worker processes, the pytest plugin, and the
test of the tests: a fault the supervisor does not catch makes the verdict fail, saying why."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from importlib.metadata import version

import msgspec
import numpy as np
import pytest

from hil.run.measurements import measure, release_end
from hil.suites.campaign import Campaign, CaseResult, expand, junit_xml, load_campaign, report
from tests.helpers import ROOT, TWO_CASES
from tests.zenoh_helpers import private_bench

SMOKE = ROOT / "configs/campaigns/smoke.toml"

# bench_smoke whose supervisor is told a silent seat is no fault: the wrench dropout goes uncaught.
BLIND = """
name = "blind_to_the_seat"
rider = "configs/riders/ref_60kg_180.toml"
duration = 1.6
initial_tilt_deg = [3.0, 0.0]
[safety.watchdogs]
require_wrench = false
[[criteria]]
metric = "fallen"
equals = false
"""
MISSED = """
name = "missed"
scenarios = ["{scenario}"]
[[fault]]
name = "seat_silent"
[[fault.inject]]
kind = "zenoh.wrench_dropout"
at = 1.0
expect = {{ state = "STOPPING", cause = "WRENCH_SILENT", within = 0.15 }}
"""
WHY = "expected the supervisor to enter STOPPING/WRENCH_SILENT within 0.15 s of zenoh.wrench_dropout"


def test_smoke_campaign_expands_to_a_baseline_and_one_case_per_fault_set():
    campaign = load_campaign(SMOKE)
    cases = expand(campaign)
    assert [c.id for c in cases] == [
        f"bench_smoke-{f}-seed0" for f in ["none", *(s.name for s in campaign.fault)]
    ]
    baseline, faulty = cases[0].build(), cases[1].build()
    assert baseline.criteria and not baseline.faults and baseline.duration == 2.5
    assert faulty.faults and not faulty.criteria, "a faulty case is judged by what its faults expect"


def test_expansion_crosses_scenarios_riders_fault_sets_and_seeds():
    campaign = msgspec.convert(
        {
            "name": "x",
            "scenarios": ["configs/scenarios/balance.toml", "configs/scenarios/bench_smoke.toml"],
            "riders": ["configs/riders/s04_abi_50kg_164.toml", "configs/riders/s07_abi_73kg_176.toml"],
            "fault": [
                {
                    "name": "a",
                    "inject": [{"kind": "sensor.off", "channel": "imu.roll", "expect": {"fall": False}}],
                }
            ],
            "seeds": [1, 2, 3],
        },
        Campaign,
    )
    cases = expand(campaign)
    assert len(cases) == 2 * 2 * 2 * 3
    assert len({c.id for c in cases}) == len(cases)
    built = cases[-1].build()
    assert built.rider.endswith("s07_abi_73kg_176.toml") and built.seed == 3
    assert built.faults[0].kind == "sensor.off"


def test_a_fault_set_that_expects_nothing_is_refused():
    with pytest.raises(msgspec.ValidationError, match="no fault says what it expects"):
        msgspec.convert(
            {
                "name": "x",
                "scenarios": ["a.toml"],
                "fault": [{"name": "f", "inject": [{"kind": "sensor.off", "channel": "imu.roll"}]}],
            },
            Campaign,
        )


def test_report_is_worst_first_and_junit_carries_failures_and_errors():
    ok = CaseResult(
        "a-none-seed0",
        "a.toml",
        True,
        1.0,
        [{"criterion": "fallen", "value": 0.0, "limit": "== False", "units": "", "passed": True, "note": ""}],
        peak_tilt_after_release_deg=2.0,
    )
    tilted = CaseResult("a-push-seed0", "a.toml", True, 1.0, peak_tilt_after_release_deg=9.0)
    failed = CaseResult(
        "a-x-seed0",
        "a.toml",
        False,
        2.0,
        [
            {
                "criterion": "fault 0 x: ESTOP",
                "value": float("nan"),
                "limit": "<= 0.1 s",
                "units": "s",
                "passed": False,
                "note": "expected ESTOP",
            }
        ],
    )
    broken = CaseResult("a-y-seed0", "a.toml", False, 0.5, error="ControllerUnavailable: no controller")
    text = report("c", [ok, tilted, failed, broken])
    order = [line.split("|")[2].strip() for line in text.splitlines()[6:]]
    assert order == ["a-y-seed0", "a-x-seed0", "a-push-seed0", "a-none-seed0"]
    assert "2/4 passed" in text and "expected ESTOP" in text
    suite = ET.fromstring(junit_xml("c", [ok, tilted, failed, broken]))
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("4", "1", "1")
    cases = {c.get("name"): c for c in suite.iter("testcase")}
    assert "expected ESTOP" in cases["a-x-seed0"].find("failure").text
    assert cases["a-y-seed0"].find("error").get("message").startswith("ControllerUnavailable")
    assert cases["a-none-seed0"].find("properties/property").get("name") == "fallen"


def test_a_missing_rider_is_named_by_the_campaigns_file_and_field_or_the_cases_error(tmp_path):
    """A rider the campaign lists is checked as it loads (each case ended FAIL, its verdicts NaN 'the run
    never ticked', the rider named nowhere); a scenario's own, as its case's error."""
    from drivers.config import ConfigError
    from hil.suites.campaign import run_case

    listed = tmp_path / "listed.toml"
    listed.write_text('name = "x"\nscenarios = ["balance"]\nriders = ["nobody"]\n')
    with pytest.raises(ConfigError) as refused:
        load_campaign(listed)
    assert str(refused.value).startswith(f'{listed}: riders: "nobody": no such file here')
    own = tmp_path / "own.toml"
    own.write_text((ROOT / "configs/scenarios/balance.toml").read_text().replace("ref_60kg_180", "nobody"))
    campaign = tmp_path / "own_rider.toml"
    campaign.write_text(f'name = "y"\nscenarios = ["{own}"]\n')
    (case,) = expand(load_campaign(campaign))
    result = run_case(case, bench=private_bench())
    assert result.verdict == "ERROR" and 'rider = "configs/riders/nobody.toml": no such file' in result.error


def test_a_verdict_without_a_unit_reads_without_a_stray_space_in_every_report(tmp_path):
    """The junit and md reports read "measured 2 , limit" for a unitless measurement (a count)."""
    from hil.run.scenario import Criterion
    from hil.suites.html_report import html_report

    limit = Criterion(metric="missing_commands", min=0.0, max=1.0).describe()
    assert limit == ">= 0 and <= 1", "no unit, no space after the number"
    assert Criterion(metric="max_speed", max=0.5).describe() == "<= 0.5 m/s", "the control: a unit kept"
    verdicts = [
        {
            "criterion": "missing_commands",
            "value": 2.0,
            "limit": limit,
            "units": "",
            "passed": False,
            "note": "",
        },
        {
            "criterion": "max_speed",
            "value": 0.75,
            "limit": "<= 0.5 m/s",
            "units": "m/s",
            "passed": False,
            "note": "",
        },
    ]
    failed = CaseResult("a-none-seed0", "a.toml", False, 1.0, verdicts)
    assert failed.message().splitlines() == [
        "missing_commands: measured 2, limit >= 0 and <= 1",
        "max_speed: measured 0.75 m/s, limit <= 0.5 m/s",
    ]
    junit = ET.fromstring(junit_xml("c", [failed])).find("testcase/failure")
    texts = {
        "junit message": junit.get("message"),
        "junit text": junit.text,
        "md": report("c", [failed]),
        "html": html_report("c", [failed], tmp_path),
    }
    for where, text in texts.items():
        assert "measured 2, limit" in text or "2 (limit" in text, (where, text)
        assert " ," not in text and "2  (limit" not in text, (where, text)


def test_the_peak_tilt_is_the_runs_own_after_the_release(shipped):
    """balance is released at 3 deg: the release ends when the robot first comes back through upright, and
    the peak after it is the run's own (3 deg, the release's, for every case of the scenario before)."""
    result = shipped[0]["balance"]
    tr, released = result.trace, result.scenario.initial_tilt_deg
    assert released == (3.0, 0.0) and np.degrees(np.abs(tr.tilt).max()) > 3.0
    end = release_end(tr, released)
    i = int(np.searchsorted(tr.t, end))
    assert 0 < end < 1.0 and (tr.tilt[:i, 0] > 0).all() and tr.tilt[i, 0] <= 0, "first back through upright"
    assert 0 < measure(tr, "max_tilt_deg", "both", end) < 1.0
    # Either side, either plane: released the other way in roll, the same end.
    mirrored = dataclasses.replace(tr, tilt=-tr.tilt[:, ::-1])
    assert release_end(mirrored, (0.0, -3.0)) == end
    assert release_end(tr, (0.0, 0.0)) == 0.0, "released upright: nothing to wait for"
    leaning = dataclasses.replace(tr, tilt=np.full_like(tr.tilt, 0.05))
    assert release_end(leaning, released) is None, "never came back: the release never ended"


@pytest.fixture
def missed_campaign(tmp_path):
    scenario = tmp_path / "blind.toml"
    scenario.write_text(BLIND)
    folder = tmp_path / "campaigns"
    folder.mkdir()
    path = folder / "missed.toml"
    path.write_text(MISSED.format(scenario=scenario))
    return path


def campaign_cli(path, out, *options: str) -> subprocess.CompletedProcess:
    """`pure-hil campaign` on two workers, as a user runs it."""
    command = [sys.executable, "-m", "hil.cli", "campaign", str(path), "--workers", "2", "--out", str(out)]
    return subprocess.run([*command, *options], capture_output=True, text=True, timeout=600, cwd=ROOT)


def test_cli_runs_a_campaign_on_workers_and_fails_on_a_missed_reaction(missed_campaign, tmp_path):
    """A supervisor blind to a silent seat: the case fails, the report and JUnit say what was missed."""
    out = tmp_path / "out"
    # The scenario's own law is hacs: the option must reach the workers.
    proc = campaign_cli(missed_campaign, out, "--law", "ihacs")
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "[2/2]" in proc.stdout and WHY in proc.stdout
    text = (out / "report.md").read_text()
    assert text.splitlines()[6].startswith("| FAIL | blind-seat_silent-seed0")
    assert "| PASS | blind-none-seed0" in text
    suite = ET.parse(out / "junit.xml").getroot()
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("2", "1", "0")
    for case in ("blind-none-seed0", "blind-seat_silent-seed0"):
        assert json.loads((out / case / "summary.json").read_text())["as_run"]["law"] == "ihacs"
    # Every report says what wrote it: the version, and the commit of this checkout.
    data = json.loads((out / "report.json").read_text())
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    commit = head.stdout.strip() if head.returncode == 0 else None
    assert data["version"] == version("pure-hil") and (data["commit"] or "").startswith(commit or "")
    for report_text in (text, (out / "report.html").read_text()):
        assert f"pure-hil {version('pure-hil')}" in report_text and (commit or "") in report_text
    # Both cases are released at 3 deg: the peak is their own, after the release, and not 3 deg for both.
    for case in data["cases"]:
        assert 0 < case["release_end"] < 1.0 and case["peak_tilt_after_release_deg"] < 3.0, case
    # The HTML page: worst first, each case's verdicts and plot, every link to a file that is there.
    page = _Links()
    page.feed((out / "report.html").read_text())
    assert page.rows[0].startswith("FAIL") and page.rows[1].startswith("PASS")
    assert WHY in page.text
    assert page.images == ["blind-seat_silent-seed0/plots.png", "blind-none-seed0/plots.png"]
    assert {"blind-none-seed0/recording.rrd", "blind-none-seed0/summary.json"} <= set(page.links)
    for link in page.links + page.images:
        assert (out / link).exists(), link


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.images: list[str] = []
        self.rows: list[str] = []
        self.text = ""
        self._cell = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "a":
            self.links.append(a["href"])
        elif tag == "img":
            self.images.append(a["src"])
        elif tag == "tr" and "class" in a:
            self.rows.append(a["class"])

    def handle_data(self, data):
        self.text += data


# pytest in a subprocess: in-process runs would drop and re-import native (PyO3) modules, which fails.
def test_pytest_plugin_collects_cases_and_a_missed_reaction_fails_the_item(missed_campaign, pytester):
    result = pytester.runpytest_subprocess(
        str(missed_campaign), "-p", "no:cacheprovider", "-m", "hil", f"--junitxml={pytester.path / 'j.xml'}"
    )
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*blind-seat_silent-seed0 failed:*", f"*{WHY}*"])
    suite = ET.parse(pytester.path / "j.xml").getroot().find("testsuite")
    failure = next(c for c in suite.iter("testcase") if c.find("failure") is not None)
    assert failure.get("name") == "blind-seat_silent-seed0"
    assert any(p.get("name").startswith("fault 0 zenoh.wrench_dropout") for p in failure.iter("property"))


def test_plugin_fixtures_run_a_scenario_with_faults_and_assert_on_events(pytester):
    pytester.makepyfile(
        f"""
        import pytest
        from hil.suites.testing import assert_no_reaction, assert_passed, assert_supervisor, assert_metric

        @pytest.mark.hil
        def test_imu_loss(hil_rig, hil_scenario):
            scenario = hil_scenario(
                r"{ROOT / "configs/scenarios/bench_smoke.toml"}",
                duration=2.0,
                criteria=[],
                faults=[{{"kind": "can.drop", "message": "IMU_RATE", "at": 1.0,
                          "expect": {{"state": "RECOVERY", "within": 0.05}}}}],
            )
            result = hil_rig.run(scenario)
            assert_passed(result)
            # The controller loses its rate channel; the supervisor's recovery law balances on the attitude's
            # derivative and turns the drives off once the robot stands still: latched from there.
            event = assert_supervisor(result, state="RECOVERY", after=1.0, within=0.05)
            assert 1.0 < event.t < 1.05
            rest = assert_supervisor(result, state="ESTOP", after=event.t)
            assert_no_reaction(result, after=rest.t + 0.01)
            assert_metric(result, "max_tilt_deg", plane="both", after=1.2, max=3.0)
            with pytest.raises(AssertionError, match="expected the supervisor to enter STOPPING/TILT"):
                assert_supervisor(result, state="STOPPING", cause="TILT")
        """
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-m", "hil")
    result.assert_outcomes(passed=1)


@pytest.mark.parametrize("workers", ["2", "1"])
def test_on_a_terminal_a_campaign_shows_a_progress_bar_with_counts_and_elsewhere_lines(tmp_path, workers):
    """The bar (tqdm, on stderr) only when stderr is a terminal; the lines of the test above otherwise. The
    bar stays one line: the cases' own (fault starts, supervisor transitions) broke it up, one worker's
    cases run in this process."""
    import fcntl
    import os
    import pty
    import struct
    import termios
    import threading

    campaign = tmp_path / "two_passing.toml"
    campaign.write_text(TWO_CASES)
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))  # a terminal has a size
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hil.cli",
            "campaign",
            str(campaign),
            "--workers",
            workers,
            "--out",
            str(tmp_path / "out"),
        ],
        stdout=subprocess.PIPE,
        stderr=slave,
        text=True,
        cwd=ROOT,
    )
    os.close(slave)
    seen = bytearray()

    def drain():
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the child closed the terminal
                return
            if not chunk:
                return
            seen.extend(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    stdout, _ = proc.communicate(timeout=300)
    reader.join(10)
    os.close(master)
    terminal = seen.decode(errors="replace")
    assert proc.returncode == 0, stdout[-2000:] + terminal[-2000:]
    assert "2/2" in terminal and "passed=2" in terminal and ("case/s" in terminal or "s/case" in terminal)
    assert "[1/2]" not in stdout and "2/2 passed" in stdout  # no per-case lines under a bar; the report
    assert "WRENCH_SILENT" in stdout, "the control: the faulty case's supervisor did react"
    case_lines = [
        line for line in terminal.splitlines() if "fault 0" in line or "supervisor transition" in line
    ]
    assert case_lines == [] and terminal.count("\n") <= 1, terminal[-2000:]


AFTERMATH = """
name = "aftermath"
scenarios = ["{root}/configs/scenarios/balance.toml", "{root}/configs/scenarios/speed_limiting.toml"]
duration = 5.0
[coverage]
wall_ratio = 100.0  # what it judges is the classes; a loaded machine must not fail a case on wall time
[[fault]]
name = "kill"
inject = [{{ kind = "process.kill", target = "controller", at = 3.0 }}]
[[fault]]
name = "bus_off"
inject = [{{ kind = "can.bus_off", at = 3.0, duration = 0.1 }}]
[[fault]]
name = "bus_off_named"
inject = [{{ kind = "can.bus_off", at = 3.0, duration = 0.1 }}]
unrecoverable = {{ speed_limiting = "no frame reaches the drives while the bus is down" }}
"""


def test_coverage_classes_what_followed_a_detection_and_a_fall_after_it_fails_the_case(tmp_path):
    """Real runs: a killed controller at standstill is taken over by the recovery law and ends at rest; the
    bus down in motion (~0.5 m/s, the rider leaning) is seen in 25 ms but nothing reaches the drives and the
    robot falls: DETECTED+FELL fails the case, unless the campaign names the fault unrecoverable there."""
    from plant.params import SimParams

    path = tmp_path / "aftermath.toml"
    path.write_text(AFTERMATH.format(root=ROOT))
    out = tmp_path / "out"
    proc = campaign_cli(path, out, "--select", "balance-kill", "--select", "speed_limiting-bus_off")
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    data = json.loads((out / "report.json").read_text())
    cases = {c["case"]: c for c in data["cases"]}
    selected = ["balance-none", "balance-kill", "speed_limiting-none", "speed_limiting-bus_off"]
    assert set(cases) == {f"{s}-seed0" for s in [*selected, "speed_limiting-bus_off_named"]}
    assert (data["passed"], data["total"]) == (4, 5)

    fell = cases["speed_limiting-bus_off-seed0"]
    assert not fell["passed"] and fell["fallen"] and "DETECTED+FELL" in fell["why"]
    c = fell["coverage"]
    assert (c["class"], c["cause"], c["passed"]) == ("DETECTED+FELL", "DRIVES_SILENT", False)
    assert c["reaction"] <= c["bound"]
    after = c["after"]
    # Fallen after power was cut in motion with nobody holding: on the 3-D plant a foot or the chassis' rim
    # touches the floor (~15 deg) before the tilt bound, far past the tilt a robot at rest may have.
    assert after["peak_tilt_deg"] >= 2 * SimParams().rest_tilt_deg and after["to_rest"] is None
    assert after["held_by"] == "nobody" and after["modes"].startswith("NORMAL>ESTOP")
    assert after["peak_speed"] > 0.3, "in motion when the bus went down"

    named = cases["speed_limiting-bus_off_named-seed0"]
    assert named["passed"] and named["coverage"]["class"] == "DETECTED+FELL"
    assert named["coverage"]["after"]["excused"] == "no frame reaches the drives while the bus is down"

    rest = cases["balance-kill-seed0"]["coverage"]
    assert (rest["class"], rest["cause"], rest["passed"]) == ("DETECTED+AT_REST", "HEARTBEAT_LOST", True)
    after = rest["after"]
    assert after["held_by"] == "recovery law" and after["modes"] == "NORMAL>RECOVERY>ESTOP"
    assert after["to_rest"] is not None and after["peak_tilt_deg"] < 5.0 and after["peak_speed"] < 0.1

    # The Markdown report carries the same: the failing class first, with what followed the detection.
    table = (out / "report.md").read_text().split("## Diagnostic coverage")[1]
    rows = [line for line in table.splitlines() if line.startswith("| DETECTED")]
    assert rows[0].startswith("| DETECTED+FELL | speed_limiting-bus_off-seed0 | DRIVES_SILENT |")
    assert "| NORMAL>ESTOP" in rows[0] and "| nobody |" in rows[0]
    assert any(
        r.startswith("| DETECTED+AT_REST | balance-kill-seed0") and "| recovery law |" in r for r in rows
    )
    assert "FELL 2 (1 of the falls unrecoverable, named in the campaign)" in table
    suite = ET.parse(out / "junit.xml").getroot()
    assert (suite.get("tests"), suite.get("failures")) == ("5", "1")
    # Each faulty case was timed against its twin run again just before it, on the same worker.
    timed = {k: c["twin_wall"] for k, c in cases.items() if c["role"] == "faulty"}
    assert len(timed) == 3 and all(wall > 0 for wall in timed.values()), timed
    assert all(c["twin_wall"] == 0 for c in cases.values() if c["role"] != "faulty")


def test_a_campaign_in_the_benchs_folder_is_in_its_history_beside_the_services_runs(tmp_path):
    from hil.cli import main
    from hil.history import History

    smoke = ROOT / "configs/campaigns/smoke.toml"
    bench = tmp_path / "lab.toml"
    bench.write_text(f'name = "lab"\n[outputs]\nfolder = "{tmp_path / "runs"}"\n')
    assert main(["campaign", str(smoke), "--bench", str(bench), "--select", "bench_smoke-none"]) == 0
    (row,) = History(tmp_path / "runs").runs()
    assert row["scenario"] == "campaign smoke" and row["verdict"] == "PASSED" and row["bench"] == "lab"
    assert {"report.html", "report.md", "report.json", "junit.xml"} <= set(row["files"])
    # Positive control: one written elsewhere with --out stays out of the bench's history.
    assert (
        main(
            [
                "campaign",
                str(smoke),
                "--bench",
                str(bench),
                "--select",
                "bench_smoke-none",
                "--out",
                str(tmp_path / "apart"),
            ]
        )
        == 0
    )
    assert History(tmp_path / "runs").count() == 1


def test_a_faulty_cases_wall_time_is_judged_against_its_twin_run_back_to_back_on_the_same_worker():
    """Issue 36: a twin that ran on a quiet machine made a healthy faulty case on a loaded one fail the
    2x wall-time criterion. The reference is now the twin run again right before the case on its worker
    (`twin_wall`), whatever the twin's own run took."""
    from hil.suites.campaign import CaseResult, judge
    from hil.suites.coverage import Bounds, Outcome

    def still(n: int = 50) -> Outcome:
        return Outcome(t=[i / 100 for i in range(n)], speed=[0.0] * n, tilt_deg=[0.0] * n, yaw_rate=[0.0] * n)

    def judged(twin_wall: float) -> CaseResult:
        twin = CaseResult("b-none-seed0", "b", True, wall=1.0, role="twin", outcome=still())
        case = CaseResult(
            "b-x-seed0",
            "b",
            True,
            wall=3.0,
            role="faulty",
            twin=twin.case_id,
            outcome=still(),
            twin_wall=twin_wall,
        )
        judge(case, twin, Bounds(wall_ratio=2.0))
        return case

    loaded = judged(twin_wall=2.5)  # the twin's own run met a quiet machine (1.0 s): 3x, but 1.2x beside it
    assert not [v for v in loaded.verdicts if v["criterion"] == "wall time vs twin"]
    slow = judged(twin_wall=1.2)  # the positive control: 2.5x its twin on the same worker
    [verdict] = [v for v in slow.verdicts if v["criterion"] == "wall time vs twin"]
    assert not slow.passed and verdict["value"] == pytest.approx(2.5)
    assert "run just before it on the same worker" in verdict["note"]


def test_expansion_gives_each_faulty_case_its_twins_scenario_to_time_it_with():
    from hil.suites.campaign import expand, load_campaign

    cases = expand(load_campaign("odrive"))
    by_id = {c.id: c for c in cases}
    faulty = [c for c in cases if c.role == "faulty"]
    assert faulty and all(c.twin_text == by_id[c.twin_id].scenario_text for c in faulty)
    assert not any(c.twin_text for c in cases if c.role != "faulty")
