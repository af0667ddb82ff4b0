"""A lab's own supervisor is a plug: tests/minimal_supervisor.py (nothing from safety/), registered through
an entry point of its own distribution, runs `speed_limiting` under `pure-hil run`, and the rig, its trace,
the judge and the run folder work with it; a campaign names it in its reports and its cases carry its report;
the console shows it on the bench and the run's supervisor state from its frames (issue 38)."""

from __future__ import annotations

import http.client
import json
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from hil.bench.bench import load_bench
from hil.cli import main
from hil.outputs.trace_log import LAYOUT
from tests.helpers import ROOT, TWO_CASES, wait_for
from tests.zenoh_helpers import hub_endpoint

DIST = "minimal_supervisor_plug-0.1.dist-info"


def install_minimal(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What `pip install` of a lab's package leaves: a dist-info with its entry points, on sys.path."""
    info = site / DIST
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: minimal-supervisor-plug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[pure_hil.supervisors]\nminimal = tests.minimal_supervisor:start\n"
    )
    monkeypatch.syspath_prepend(str(site))


@pytest.fixture
def minimal(tmp_path, monkeypatch) -> Path:
    """The minimal supervisor installed, and a bench whose supervisor plugin it is, writing of a run's folder
    only what the tests read (summary.json, trace.npy): that bench's file."""
    install_minimal(tmp_path / "site", monkeypatch)
    return minimal_bench(tmp_path, SUMMARY_ONLY)


SUMMARY_ONLY = "\n[outputs]\ncan_log = false\nrecording = false\nplots = false\nmcap = false\n"


def minimal_bench(folder: Path, more: str = "") -> Path:
    """The embedded bench with `plugin = "minimal"` for its supervisor (and `more` of the bench file)."""
    bench = folder / "minimal.toml"
    text = (ROOT / "configs/benches/embedded.toml").read_text()
    bench.write_text(
        text.replace(
            '[supervisor]\nwhere = "embedded"', '[supervisor]\nwhere = "embedded"\nplugin = "minimal"'
        )
        + more
    )
    assert 'plugin = "minimal"' in bench.read_text()
    return bench


def test_a_labs_own_supervisor_plugged_by_entry_point_runs_speed_limiting(tmp_path, monkeypatch, capsys):
    bench = minimal_bench(tmp_path)
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

    install_minimal(tmp_path / "site", monkeypatch)
    assert main(args) == 0
    summary = json.loads((tmp_path / "run/summary.json").read_text())
    assert summary["verdict"] == "PASSED", summary
    assert summary["bench"]["supervisor_plug"] == "minimal"  # the summary says which plug judged the run
    # It was this supervisor that ran, every tick: its own report, and its permission held the drives on.
    safety = summary["safety"]
    assert safety["sc_arbitration"] == {"supervisor": "minimal", "updates": summary["rig"]["ticks"] + 1}
    assert safety["events"] == [] and safety["final_state"] == "NORMAL"
    # The request's 0.5 m/s cap reached the controller through it: its command speed rose to it, no more.
    rows = np.load(tmp_path / "run/trace.npy")
    forward = rows[:, LAYOUT.span("command_speed")][:, 0]
    assert 0.45 < np.nanmax(np.abs(forward)) <= 0.5 + 1e-9


def test_a_campaign_on_a_labs_own_supervisor_names_it_and_its_cases_carry_its_report(minimal, tmp_path):
    campaign, out = tmp_path / "two_cases.toml", tmp_path / "campaign"
    campaign.write_text(TWO_CASES)
    # It completes; the fault-free case passes, and the silent seat, which this supervisor does not watch
    # (the reference stops for it), fails on the reaction it expects: the minimal supervisor judged both.
    assert main(["campaign", str(campaign), "--bench", str(minimal), "--out", str(out)]) == 1
    report = json.loads((out / "report.json").read_text())
    assert report["supervisor"] == "minimal"
    cases = {c["case"]: c for c in report["cases"]}
    assert {c["supervisor"] for c in cases.values()} == {"minimal"}
    assert cases["bench_smoke-none-seed0"]["passed"], cases["bench_smoke-none-seed0"]["why"]
    silent = cases["bench_smoke-seat_silent-seed0"]
    assert not silent["passed"] and "STOPPING/WRENCH_SILENT" in silent["why"], silent
    assert "Judged by the supervisor minimal." in (out / "report.md").read_text()
    assert "Judged by the supervisor minimal." in " ".join((out / "report.html").read_text().split())
    suite = ET.fromstring((out / "junit.xml").read_bytes())
    assert suite.find("properties/property[@name='supervisor']").get("value") == "minimal"
    # Each case's run folder carries the minimal supervisor's own report.
    for case in cases:
        summary = json.loads((out / case / "summary.json").read_text())
        assert summary["safety"]["sc_arbitration"]["supervisor"] == "minimal", case


def _events(port: int, seen: list[tuple[str, dict]], stop: threading.Event) -> None:
    """The console's event stream as a page reads it: (event, data) pairs, until `stop`."""
    page = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    page.request("GET", "/api/events")
    reply = page.getresponse()
    event = ""
    try:
        while not stop.is_set():
            line = reply.fp.readline().decode()
            if line.startswith("event: "):
                event = line[7:].strip()
            elif line.startswith("data: "):
                seen.append((event, json.loads(line[6:])))
    finally:
        page.close()


def test_the_console_shows_a_labs_own_supervisor_and_its_state_from_its_frames(minimal, tmp_path):
    from drivers.keys import Keys
    from drivers.zenoh_link import open_session
    from hil.console.events import Broadcast
    from hil.console.rig_link import RigLink
    from hil.console.server import Console
    from hil.service import RigService
    from tests.test_console import request

    endpoint = hub_endpoint()
    bench = load_bench(minimal).with_overrides(hub=endpoint)
    hub = open_session(role="hub", hub_endpoint=endpoint)
    service = RigService(hub, bench, out_root=tmp_path / "runs")
    session = open_session(role="member", hub_endpoint=endpoint)
    link = RigLink(session, Keys(), "operator", "test operator", Broadcast())
    server = Console(link, {"bench": bench.name, "faults": []}, ("127.0.0.1", 0)).start()
    seen: list[tuple[str, dict]] = []
    stop = threading.Event()
    reader = threading.Thread(target=_events, args=(server.server_address[1], seen, stop), daemon=True)
    try:
        assert wait_for(lambda: link.status is not None, 10), "the console hears the service"
        status, answer = request(server.url + "api/status")
        assert status == 200 and answer["bench"]["supervisor_plug"] == "minimal", answer["bench"]
        assert answer["bench"]["supervisor"] == "embedded"

        reader.start()
        status, reply = request(server.url + "api/start", {"scenario": "bench_smoke"})
        assert status == 200 and reply["run"] == 1, reply
        assert service.wait_idle(60) and wait_for(lambda: service.history.runs()[0]["verdict"] != "RUNNING")
        assert wait_for(lambda: any(e == "status" and d.get("state") == "idle" for e, d in seen[-5:]), 10)
        live = [d for e, d in seen if e == "live" and d["run"] == 1]
        assert live, "the page got the run's live samples"
        # Its state as its SUPERVISOR_ESTOP frames say it: this supervisor puts no pure/safety/state in a
        # quiet run (the reference does, with a cause), so the page has no other word from it.
        assert {d["supervisor"] for d in live} - {None} == {"NORMAL"}, live[-1]
        assert {d["cause"] for d in live} == {None} and not [e for e, _ in seen if e == "safety"]
        assert request(server.url + "api/status")[1]["last"]["verdict"] == "PASSED"
        # The run's summary, as the page links it, carries this supervisor's own report.
        status, summary = request(server.url + "runs/1/summary.json")
        assert status == 200 and summary["safety"]["sc_arbitration"]["supervisor"] == "minimal"
    finally:
        stop.set()
        server.close()
        link.close()
        session.close()
        service.close()
        hub.close()
        if reader.ident is not None:
            reader.join(15)
