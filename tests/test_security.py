"""The secured bench: a router with mutual TLS and a default-deny ACL on 127.0.0.1 (started by the test),
clients by role. Counts of what reached a subscriber are asserted against a positive control with the ACL
off, so the test proves it can see a leak."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest
import zenoh

from drivers.keys import Keys
from drivers.robot import RobotModel
from drivers.schemas import EstopCommand, ScRequest
from drivers.zenoh_link import CONFIG_DIR, ZenohConfigError, load_config
from hil.bench.certs import ROLES, init
from hil.cli import main
from safety.config import Identity, SupervisorConfig
from safety.monitors import Monitors
from tests.zenoh_helpers import free_port, own_sockets

ROUTER = CONFIG_DIR / "bench-router.json5"
CLIENT = CONFIG_DIR / "bench-client.json5"
KEYS = Keys()
SAFETY_KEYS = (KEYS.safety_estop, KEYS.sc_request)


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench") / "certs"
    init(folder)
    return folder


@pytest.fixture(scope="module")
def impostor_certs(tmp_path_factory):
    """Certificates from another CA, with the operator's CN."""
    folder = tmp_path_factory.mktemp("impostor") / "certs"
    init(folder)
    return folder


class Bench:
    def __init__(self, certs: Path, acl: bool = True):
        self.endpoint = f"tls/127.0.0.1:{free_port()}"
        config = load_config(ROUTER, hub_endpoint=self.endpoint, certs=certs)
        if not acl:
            config.insert_json5("access_control/enabled", "false")
        self.router = zenoh.open(config)
        self.certs = certs
        # The supervisor's view: what reaches a legitimate subscriber on the safety keys.
        self.supervisor = self.client("supervisor")
        self.received: list[tuple[str, bytes]] = []
        self.sub = self.supervisor.declare_subscriber(
            "pure/**", lambda s: self.received.append((str(s.key_expr), s.payload.to_bytes()))
        )

    def client(self, role: str, certs: Path | None = None, **overrides) -> zenoh.Session:
        config = load_config(CLIENT, hub_endpoint=self.endpoint, certs=certs or self.certs, identity=role)
        for key, value in overrides.items():
            config.insert_json5(key, json.dumps(value))
        return zenoh.open(config)

    def put_all(self, session: zenoh.Session, who: str, keys=(*SAFETY_KEYS, KEYS.tes_wrench), n: int = 5):
        for key in keys:
            pub = session.declare_publisher(key)
            time.sleep(0.2)  # let the subscriber's declaration reach it (or not)
            for i in range(n):
                pub.put(f"{who}:{i}".encode())
            session.put(key, f"{who}:session".encode())
        time.sleep(0.5)

    def delivered(self, who: str, key: str) -> int:
        return sum(1 for k, data in self.received if k == key and data.startswith(f"{who}:".encode()))

    def close(self):
        self.sub.undeclare()
        self.supervisor.close()
        self.router.close()


@pytest.fixture
def bench(certs):
    b = Bench(certs)
    yield b
    b.close()


def test_operator_reaches_the_supervisor_others_do_not(bench):
    operator, tes = bench.client("operator"), bench.client("tes")
    try:
        bench.put_all(operator, "operator")
        bench.put_all(tes, "tes")
    finally:
        operator.close()
        tes.close()
    for key in SAFETY_KEYS:
        assert bench.delivered("operator", key) == 6, key
        assert bench.delivered("tes", key) == 0, f"TES client put on {key}: must be denied"
    assert bench.delivered("tes", KEYS.tes_wrench) == 6, "the TES may still put its own key"
    assert bench.delivered("operator", KEYS.tes_wrench) == 0, "each role puts exactly its own keys"


def test_wildcard_puts_cannot_reach_the_safety_keys(bench):
    tes = bench.client("tes")
    try:
        bench.put_all(tes, "tes", keys=("pure/**", "pure/safety/*"))
    finally:
        tes.close()
    assert not any(data.startswith(b"tes:") for _, data in bench.received)


def test_without_credentials_or_with_another_ca_no_connection(bench, impostor_certs, tmp_path):
    refused_fast = {"connect/timeout_ms": 1000}  # a refused handshake is final: no need to retry for 5 s
    with pytest.raises(zenoh.ZError):
        bench.client("operator", certs=impostor_certs, **refused_fast)  # CN=operator, signed by another CA
    no_cert = {"transport/link/tls/connect_certificate": None, "transport/link/tls/connect_private_key": None}
    with pytest.raises(zenoh.ZError):
        bench.client("operator", **no_cert, **refused_fast)
    anonymous = {"mode": "client", "connect": {"endpoints": [bench.endpoint.replace("tls/", "tcp/")]}}
    with pytest.raises(zenoh.ZError):
        config = zenoh.Config.from_json5(
            json.dumps(
                {**anonymous, "listen": {"endpoints": []}, "scouting": {"multicast": {"enabled": False}}}
            )
        )
        config.insert_json5("connect/timeout_ms", "1000")
        config.insert_json5("connect/exit_on_failure", "true")
        zenoh.open(config)
    assert bench.received == []


def test_spoofing_the_operators_zid_gives_no_rights(bench):
    operator = bench.client("operator")
    operator_zid = str(operator.info.zid())
    operator.close()
    spoof = bench.client("tes", id=operator_zid)  # the ACL identifies by certificate, never by zid
    try:
        assert str(spoof.info.zid()) == operator_zid
        bench.put_all(spoof, "spoof", keys=SAFETY_KEYS)
    finally:
        spoof.close()
    assert not any(data.startswith(b"spoof:") for _, data in bench.received)


def test_positive_control_without_the_acl_the_leak_is_seen(certs):
    b = Bench(certs, acl=False)
    tes = b.client("tes")
    try:
        b.put_all(tes, "tes", keys=SAFETY_KEYS)
    finally:
        tes.close()
        b.close()
    for key in SAFETY_KEYS:
        assert b.delivered("tes", key) == 6, "this test can see a leak"


RIG_QUERIES = ("status", "history", "file", "start", "stop", "intent", "fault/inject", "fault/clear")
READ = {"status", "history", "file"}


def asked_through(bench: Bench, roles: tuple[str, ...]) -> dict[str, set[str]]:
    """Which of the rig service's queryables each role's query reaches (and gets a reply from), all asked
    at once: a denied query just times out."""
    rig = bench.client("rig")
    reached: list[str] = []
    queryables = [
        rig.declare_queryable(
            KEYS.rig(name), lambda q: (reached.append(str(q.key_expr)), q.reply(q.key_expr, b"ok"))
        )
        for name in RIG_QUERIES
    ]
    clients = {role: bench.client(role) for role in roles}
    try:
        time.sleep(0.3)  # the queryables' declarations reach the router
        pending = {
            (role, name): session.get(KEYS.rig(name), timeout=1.0)
            for role, session in clients.items()
            for name in RIG_QUERIES
        }
        answered = {role: set() for role in roles}
        for (role, name), replies in pending.items():
            if any(r.ok is not None for r in replies):
                answered[role].add(name)
    finally:
        for q in queryables:
            q.undeclare()
        for session in (*clients.values(), rig):
            session.close()
    assert sum(map(len, answered.values())) == len(reached), "every reply came from a query that reached"
    return answered


def test_least_privilege_monitor_reads_operator_runs_fault_injector_injects(bench):
    answered = asked_through(bench, ("monitor", "operator", "fault-injector", "tes"))
    assert answered == {
        "monitor": READ,
        "operator": READ | {"start", "stop", "intent"},
        "fault-injector": READ | {"fault/inject", "fault/clear"},
        "tes": set(),
    }


def test_positive_control_without_the_acl_the_monitor_could_start_and_inject(certs):
    b = Bench(certs, acl=False)
    try:
        answered = asked_through(b, ("monitor",))
    finally:
        b.close()
    assert answered == {"monitor": set(RIG_QUERIES)}, "this test can see a query get through"


def test_router_and_clients_stay_on_loopback(bench):
    operator = bench.client("operator")
    try:
        sockets = own_sockets()
        assert sockets["tcp"] and all(ip == "127.0.0.1" for ip, _, _ in sockets["tcp"])
        assert sockets["udp"] == []
    finally:
        operator.close()


def test_certs_init_output(certs, capsys, tmp_path):
    for name in ("ca", "router", *ROLES):
        assert (certs / f"{name}.pem").exists()
        assert (certs / f"{name}.key").stat().st_mode & 0o777 == 0o600
    assert certs.stat().st_mode & 0o777 == 0o700
    assert main(["certs", "init", str(certs)]) == 2, "never overwrites silently"
    assert "not empty" in capsys.readouterr().err
    assert main(["certs", "init", str(tmp_path / "fresh")]) == 0


def test_a_world_readable_key_is_refused(tmp_path):
    folder = tmp_path / "certs"
    init(folder, roles=("operator",))
    os.chmod(folder / "operator.key", 0o644)
    with pytest.raises(ZenohConfigError, match=r"operator.key is readable by group or others \(mode 0644\)"):
        load_config(CLIENT, certs=folder, identity="operator")
    assert main(["estop", "--bench", "secured", "--certs", str(folder)]) == 2


def test_placeholders_must_be_filled():
    with pytest.raises(ZenohConfigError, match="needs certs"):
        load_config(CLIENT)


def test_supervisor_ignores_resets_and_requests_without_an_operators_identity():
    config = SupervisorConfig(identity=Identity(operators=["operator"]))
    m = Monitors(config, RobotModel())
    m.sc_request(ScRequest(seq=1, stamp=0.0, mode="free", source="intruder"), 1.0)
    m.operator_command(EstopCommand(seq=1, stamp=0.0, action="reset", source="intruder"))
    obs = m.observe(1.0)
    assert obs.request is None and obs.operator is None
    m.operator_command(EstopCommand(seq=2, stamp=0.0, action="estop", source="anyone"))
    assert m.observe(1.1).operator == "estop", "an e-stop is accepted from anyone"
    m.operator_command(EstopCommand(seq=3, stamp=0.0, action="reset", source="operator"))
    assert m.observe(1.2).operator == "reset"
    assert dict(m.rejected_identity) == {"sc_request": 1, "reset": 1}
