"""`pure-hil serve`: the rig as a service, driven over zenoh queryables on loopback."""

import json
import os
import time

import msgspec
import pytest

from drivers.keys import Keys
from drivers.zenoh_link import open_session
from hil.service import RigService
from tests.helpers import ROOT
from tests.zenoh_helpers import hub_endpoint, private_bench

# Long enough that a lockstep run (several times real time) is still going when a test asks it to stop.
SHORT = """
name = "served"
rider = "configs/riders/ref_60kg_180.toml"
duration = 60.0
[[sc]]
mode = "limit"
cap = 1.0
[[criteria]]
metric = "fallen"
equals = false
"""


@pytest.fixture
def service(tmp_path):
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    svc = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    yield svc, client
    svc.close()
    client.close()
    hub.close()


def ask(client, action, payload=""):
    replies = list(client.get(Keys().rig(action), payload=payload, timeout=10.0))
    assert replies and replies[0].ok is not None
    return json.loads(replies[0].ok.payload.to_string())


def test_status_start_intent_stop(service, tmp_path):
    svc, client = service
    assert ask(client, "status")["state"] == "idle"
    started = ask(client, "start", SHORT)
    assert started["ok"] and started["scenario"] == "served"
    assert ask(client, "start", SHORT)["error"] == "already running served"
    deadline = time.monotonic() + 60
    while ask(client, "status")["sim_time"] < 1.0 and time.monotonic() < deadline:
        time.sleep(0.1)
    # The rider leans forward from now on: the robot drives off.
    intent = ask(client, "intent", json.dumps({"pitch": [{"kind": "ramp", "to": 15.0, "duration": 0.5}]}))
    assert intent == {"ok": True, "applies_to": "served"}
    while ask(client, "status")["sim_time"] < 4.0 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert ask(client, "stop")["stopping"] is True
    assert svc.wait_idle(30)
    last = ask(client, "status")["last"]
    # Stopped by the operator: not PASSED, whatever it measured until then.
    assert (last["verdict"], last["passed"], last["stopped_early"]) == ("STOPPED", False, True)
    assert last["metrics"]["pitch.max_speed"] > 0.3
    assert (tmp_path / last["out"].split("/")[-1] / "summary.json").exists()


def test_a_live_intent_past_the_riders_reach_is_refused_naming_it(service):
    """`pure-hil rig intent` holds the rider to their own limits, as a scenario's [intent] is (before, a lean
    of 1e308 deg was taken and clipped silently). JSON has no NaN or infinity: msgspec refuses those."""
    svc, client = service
    lean = '{"pitch": [{"kind": "ramp", "to": %s, "duration": 0.5}]}'
    idle = ask(client, "intent", lean % "10.0")
    assert idle == {"ok": False, "error": "no run in progress: start one first"}, "no rider to hold it to"
    assert ask(client, "start", SHORT)["ok"]
    rider = "configs/riders/ref_60kg_180.toml"
    for to, says in [
        ("1e308", "to = 1e+308 deg is past the rider's reach |pitch| <= 30 deg (max_lean_deg of "),
        ("31", "to = 31 deg is past the rider's reach |pitch| <= 30 deg"),
    ]:
        reply = ask(client, "intent", lean % to)
        assert reply["refused"] and not reply["ok"], reply
        assert (
            reply["error"].startswith(f"pure/rig/intent.pitch[0] (ramp): {says}") and rider in reply["error"]
        )
    twist = ask(client, "intent", '{"twist": [{"kind": "step", "to": -20.5}]}')
    assert (
        "pure/rig/intent.twist[0] (step): to = -20.5 Nm is past the rider's reach |twist| <= 20 Nm"
        in (twist["error"])
    )
    assert ask(client, "intent", lean % "30.0") == {"ok": True, "applies_to": "served"}  # at the limit
    assert ask(client, "stop")["stopping"] is True
    assert svc.wait_idle(30)


def test_bad_requests_get_clear_errors(service):
    _, client = service
    assert "unknown field `durration`" in ask(client, "start", 'name = "x"\ndurration = 1.0\n')["error"]
    assert "no such file here or among the shipped configs" in ask(client, "start", "nope")["error"]
    bad = ask(client, "intent", '{"pitch": [{"kind": "wobble"}]}')
    assert not bad["ok"] and "pure/rig/intent payload" in bad["error"]
    assert ask(client, "status")["state"] == "idle"


def test_start_by_file(service):
    svc, client = service
    reply = ask(client, "start", str(ROOT / "configs/scenarios/balance.toml"))
    assert reply["ok"] and reply["scenario"] == "balance"
    assert svc.wait_idle(60)
    assert ask(client, "status")["last"]["passed"] is True


def test_live_view_streams_each_run_in_batches(tmp_path):
    """`serve --view` sends to the operator's viewer; here the same stream goes to a file sink (tests never
    connect to a viewer) and is read back with rerun's own reader."""
    import rerun as rr
    from rerun.chunk import RrdReader

    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    live = tmp_path / "live.rrd"
    svc = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path, view=rr.FileSink(str(live)))
    client = open_session(role="member", hub_endpoint=endpoint)
    try:
        assert ask(client, "start", str(ROOT / "configs/scenarios/bench_smoke.toml"))["ok"]
        assert svc.wait_idle(60)
    finally:
        svc.close()
        client.close()
        hub.close()
    reader = RrdReader(str(live))
    assert [r.application_id for r in reader.recordings()] == ["pure_hil_live_bench_smoke"]
    rows = {}
    for chunk in reader.stream():
        if not chunk.is_static and "sim_time" in chunk.timeline_names:
            rows.setdefault(chunk.entity_path, []).append(chunk.num_rows)
    # Every tick of the 2 s run (800 at 400 Hz) arrived, in batches of 0.1 s, for every signal group.
    for entity in ("/speed/actual", "/tilt/chassis", "/rider/lean", "/motor/torque"):
        assert sum(rows[entity]) == 800, (entity, rows[entity])
        assert max(rows[entity]) >= 40
    assert "/events" in rows


def test_live_fault_injection_lands_in_the_event_log_and_the_recording(service, tmp_path):
    svc, client = service
    assert not ask(client, "fault/inject", '{"kind": "zenoh.wrench_dropout"}')["ok"], "no run yet"
    assert ask(client, "start", SHORT)["ok"]
    deadline = time.monotonic() + 60
    while ask(client, "status")["sim_time"] < 1.0 and time.monotonic() < deadline:
        time.sleep(0.1)
    bad = ask(client, "fault/inject", '{"kind": "can.drop", "message": "NOPE"}')
    assert not bad["ok"] and "no message 'NOPE'" in bad["error"]
    bad = ask(client, "fault/inject", '{"kind": "sensor.bias", "channel": "imu.pitch"}')
    assert not bad["ok"] and "offset" in bad["error"]
    reply = ask(client, "fault/inject", '{"kind": "sensor.bias", "channel": "imu.rate_z", "offset": 0.01}')
    assert reply == {"ok": True, "fault": "sensor.bias offset=0.01 channel=imu.rate_z", "scenario": "served"}
    while not any(f["active"] for f in ask(client, "status")["faults"]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ask(client, "fault/clear", "0") == {"ok": True, "cleared": 0}
    assert ask(client, "stop")["stopping"] is True
    assert svc.wait_idle(30)
    last = ask(client, "status")["last"]
    actions = [(e["fault"], e["action"]) for e in last["fault_events"]]
    assert actions == [(0, "inject"), (0, "start"), (0, "clear"), (0, "end")]
    inject = last["fault_events"][0]
    assert inject["t"] >= 1.0 and inject["detail"] == "sensor.bias offset=0.01 channel=imu.rate_z"

    from rerun.chunk import RrdReader  # the recording has the same log

    summary = json.loads((tmp_path / last["out"].split("/")[-1] / "summary.json").read_text())
    assert [e["action"] for e in summary["fault_events"]] == ["inject", "start", "clear", "end"]
    rrd = tmp_path / last["out"].split("/")[-1] / "recording.rrd"
    rows = sum(c.num_rows for c in RrdReader(str(rrd)).stream() if c.entity_path == "/events/faults")
    assert rows == 4, "every fault event in the rerun recording"


def test_a_console_is_offered_the_shipped_scenarios_and_the_benchs_own(tmp_path):
    own = tmp_path / "lab_demo.toml"
    own.write_text(SHORT)
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    bench = msgspec.structs.replace(private_bench(hub=endpoint), scenarios=(str(own),))
    svc = RigService(hub, bench, out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    try:
        offered = ask(client, "status")["scenarios"]
        assert str(own) in offered and "speed_limiting" in offered
        # Positive control: a bench that lists nothing offers the shipped scenarios only.
        plain = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path / "plain")
        plain.close()
        assert str(own) not in plain.scenarios
    finally:
        svc.close()
        client.close()
        hub.close()


def test_a_bench_with_a_rider_on_board_refuses_every_fault(tmp_path):
    # The same requests the test above has accepted on the default bench (the positive control).
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    bench = msgspec.structs.replace(private_bench(hub=endpoint), rider_on_board=True)
    svc = RigService(hub, bench, out_root=tmp_path)
    client = open_session(role="member", hub_endpoint=endpoint)
    try:
        faulted = SHORT + '[[faults]]\nkind = "zenoh.wrench_dropout"\nat = 1.0\n'
        refused = ask(client, "start", faulted)
        assert not refused["ok"] and "rider_on_board" in refused["error"]
        assert ask(client, "status")["state"] == "idle"
        assert ask(client, "start", SHORT)["ok"]
        live = ask(client, "fault/inject", '{"kind": "sensor.bias", "channel": "imu.rate_z", "offset": 0.01}')
        assert not live["ok"] and "a person is on the robot" in live["error"]
        assert ask(client, "stop")["stopping"] is True
        assert svc.wait_idle(30)
        assert ask(client, "status")["last"]["fault_events"] == []
    finally:
        svc.close()
        client.close()
        hub.close()


def test_fault_cli_lists_injects_and_clears_through_the_service(tmp_path, capsys):
    from hil.cli import main
    from hil.faults import CATALOG

    assert main(["fault", "list"]) == 0
    listing = capsys.readouterr().out
    assert all(kind in listing for kind in CATALOG)
    assert main(["fault", "inject", "sensor.bias", "--param", "channel=imu.pitch"]) == 2
    assert "Object missing required field `offset`" in capsys.readouterr().err
    assert main(["fault", "inject", "sensor.bias", "--param", "offset"]) == 2
    assert "expected NAME=VALUE" in capsys.readouterr().err

    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    svc = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path)
    try:
        args = ["--hub", endpoint]
        assert main(["fault", "clear", *args]) == 1, "no run to clear faults in"
        assert "no run in progress" in capsys.readouterr().out
        client = open_session(role="member", hub_endpoint=endpoint)
        assert ask(client, "start", SHORT)["ok"]
        client.close()
        cmd = [
            "fault",
            "inject",
            "can.drop",
            "--param",
            "message=IMU_RATE",
            "--param",
            "rate=0.2",
            "--at",
            "0.5",
        ]
        assert main([*cmd, "--duration", "1", *args]) == 0
        reply = json.loads(capsys.readouterr().out)
        assert reply["ok"] and reply["fault"] == "can.drop rate=0.2 message=IMU_RATE"
        assert main(["fault", "clear", *args]) == 0
        assert json.loads(capsys.readouterr().out) == {"ok": True, "cleared": "all"}
        svc._stop.set()
        assert svc.wait_idle(30)
    finally:
        svc.close()
        hub.close()
    events = [(e["kind"], e["action"]) for e in svc.last["fault_events"]]
    assert events[0] == ("can.drop", "inject") and events[-1][1] in ("clear", "end")


def os_threads() -> int:
    """Every thread of this process, native ones (zenoh's, rerun's) included."""
    return len(os.listdir("/proc/self/task"))


def test_many_runs_in_a_row_keep_the_thread_count_flat(service):
    svc, client = service
    short = SHORT.replace("duration = 60.0", "duration = 0.25")
    counts = []
    # Ten runs: a leak of one thread a run (rerun's leaked two) ended 6 over the second run's count.
    for _ in range(10):
        assert ask(client, "start", short)["ok"]
        assert svc.wait_idle(30)
        assert ask(client, "status")["last"]["passed"]
        counts.append(os_threads())
    assert counts[-1] - counts[1] <= 2, f"threads after each run: {counts}"


def test_positive_control_a_recording_stream_per_run_leaks_threads_this_count_sees(tmp_path):
    import rerun as rr

    before = set(os.listdir("/proc/self/task"))  # thread ids: another test's threads may end meanwhile
    for i in range(3):
        rec = rr.RecordingStream(f"pure_hil_leak_{i}")
        rec.set_sinks(rr.FileSink(str(tmp_path / f"{i}.rrd")))
        rec.flush()
        rec.disconnect()
        del rec
    born = set(os.listdir("/proc/self/task")) - before
    assert len(born) >= 3, "rerun-io/rerun#2116: the threads of a dropped stream live on"


def test_serve_prints_its_hub_and_a_client_finds_it_without_a_hub(tmp_path):
    """`serve` on a hub of its own says where; `rig status` typed without --hub finds that rig (the one of
    its bench on this machine), not whatever holds the bench file's port."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from tests.helpers import serving

    pure_hil = str(Path(sys.executable).with_name("pure-hil"))
    endpoint = hub_endpoint()
    env = {**os.environ, "PURE_HIL_RIGS": str(tmp_path / "rigs")}
    env.pop("PURE_HIL_HUB", None)
    with serving(tmp_path, endpoint, env) as serve:
        status = subprocess.run(
            [pure_hil, "rig", "status"], capture_output=True, text=True, env=env, timeout=60
        )
        assert status.returncode == 0, status.stderr
        assert json.loads(status.stdout)["state"] == "idle"
        serve.send_signal(signal.SIGINT)
        serve.communicate(timeout=60)
    assert not list((tmp_path / "rigs").glob("*.json")), "a stopped rig leaves no card behind"
    # Positive control: with the rig gone, the client finds nobody rather than any other hub.
    gone = subprocess.run(
        [pure_hil, "rig", "status", "--hub", endpoint], capture_output=True, text=True, env=env, timeout=60
    )
    assert gone.returncode == 1 and gone.stderr
