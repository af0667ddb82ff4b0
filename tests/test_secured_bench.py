"""The secured bench end to end, as docs/security.md tells an operator to run it: `pure-hil certs init`,
`pure-hil router`, `pure-hil run --bench secured` and `pure-hil estop` as separate processes, each a router
client with its own certificate. CAN stays in the rig's process (python-can `virtual`: this kernel has no
SocketCAN); every zenoh message between rig, controller, supervisor and operator crosses the router's ACL.

During the run two intruders try to steer the supervisor: a process without a certificate (refused at the
TLS handshake) and one with the TES's certificate putting SC requests (dropped by the ACL). A monitor
subscribed to pure/sc/request is the witness; the rig's own SC agent reaching it is the positive control.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from drivers.keys import Keys
from drivers.schemas import SafetyState, ScRequest, decode, encode
from drivers.zenoh_link import CONFIG_DIR, load_config
from hil.bench.certs import init
from tests.zenoh_helpers import free_port

BIN = Path(sys.executable).parent
KEYS = Keys()
SCENARIO = """
name = "secured_estop"
rider = "ref_60kg_180"
duration = 120.0  # lockstep: ended by the test (SIGINT) once the e-stop has brought the robot to rest
[[sc]]
at = 0.0
mode = "limit"
cap = 1.0
[[criteria]]
metric = "fallen"
equals = false
"""


def _client(endpoint: str, certs: Path, role: str, **overrides) -> zenoh.Session:
    config = load_config(CONFIG_DIR / "bench-client.json5", hub_endpoint=endpoint, certs=certs, identity=role)
    for key, value in overrides.items():
        config.insert_json5(key, json.dumps(value))
    return zenoh.open(config)


def _wait_for_port(port: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    pytest.fail(f"the router did not listen on 127.0.0.1:{port} within {timeout} s")


@pytest.fixture
def router(tmp_path):
    certs = tmp_path / "certs"
    init(certs)
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [str(BIN / "pure-hil"), "router", "--certs", str(certs), "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env,
    )
    try:
        _wait_for_port(port, 10)
        yield endpoint, certs, env
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_scenario_runs_through_the_router_and_only_certified_roles_reach_the_supervisor(router, tmp_path):
    endpoint, certs, env = router
    bench = ["--bench", "secured", "--certs", str(certs), "--hub", endpoint]
    scenario = tmp_path / "secured_estop.toml"
    scenario.write_text(SCENARIO)
    witness = _client(endpoint, certs, "monitor")
    requests: list[ScRequest] = []
    states: list[SafetyState] = []
    subs = [
        witness.declare_subscriber(
            KEYS.sc_request, lambda s: requests.append(decode(s.payload.to_bytes(), ScRequest))
        ),
        witness.declare_subscriber(
            KEYS.safety_state, lambda s: states.append(decode(s.payload.to_bytes(), SafetyState))
        ),
    ]
    out = tmp_path / "run"
    rig = subprocess.Popen(
        [str(BIN / "pure-hil"), "run", str(scenario), *bench, "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + 60
        while not states and rig.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert states, "the supervisor's state reached the monitor through the router"

        # Intruder 1: no certificate. The router's mutual TLS refuses the handshake.
        no_cert = {
            "transport/link/tls/connect_certificate": None,
            "transport/link/tls/connect_private_key": None,
            "connect/timeout_ms": 1000,
        }
        with pytest.raises(zenoh.ZError):
            _client(endpoint, certs, "operator", **no_cert)
        # Intruder 2: a valid certificate of another role (the seat's) claiming to be the operator.
        tes = _client(endpoint, certs, "tes")
        try:
            publisher = tes.declare_publisher(KEYS.sc_request)
            time.sleep(0.2)
            for seq in range(20):
                publisher.put(encode(ScRequest(seq=seq, stamp=0.0, mode="idle", source="operator")))
        finally:
            tes.close()

        # The operator's e-stop, from its own process and certificate.
        estop = subprocess.run(
            [str(BIN / "pure-hil"), "estop", *bench, "--timeout", "20"],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
        )
        assert estop.returncode == 0, estop.stdout + estop.stderr
        # The operator ends the run (Ctrl-C) once the supervisor has the robot stopped and unpowered.
        deadline = time.monotonic() + 60
        while not any(s.state == "ESTOP" for s in states) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
        rig.send_signal(signal.SIGINT)
        output, _ = rig.communicate(timeout=120)
    finally:
        if rig.poll() is None:
            rig.kill()
        for sub in subs:
            sub.undeclare()
        witness.close()

    assert rig.returncode == 130, output  # stopped by the operator; the run's folder is written all the same
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bench"]["zenoh"] == "router", output
    assert (summary["verdict"], summary["passed"]) == ("STOPPED", False), "ended early: not passed"
    assert summary["stopped_early"] and summary["simulated"] < 120.0
    steps = [(e["to_state"], e["cause"]) for e in summary["safety"]["events"]]
    assert ("STOPPING", "OPERATOR_ESTOP") in steps, steps
    assert summary["safety"]["ended_resting"] and summary["fallen"] is False
    # The rig's SC agent reached the supervisor's key (positive control); the intruder's requests did not.
    assert any(r.mode == "limit" for r in requests), "the rig's SC requests crossed the router"
    assert not any(r.mode == "idle" for r in requests), "the TES certificate cannot put pure/sc/request"
