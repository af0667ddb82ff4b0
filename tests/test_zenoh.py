"""zenoh: loopback-only sessions, key expressions, payload schemas over real sessions, malformed payloads."""

import contextlib
import math
import pickle
import re

import msgspec
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.keys import Keys
from drivers.schemas import (
    TICK_MODULO,
    ControllerTelemetry,
    EstopCommand,
    PayloadError,
    RigTick,
    SafetyState,
    ScCommand,
    ScRequest,
    TesWrench,
    decode,
    encode,
)
from drivers.zenoh_access import ZenohAccess
from drivers.zenoh_link import (
    CONFIG_DIR,
    LOOPBACK,
    LentSession,
    ZenohConfigError,
    ZenohLink,
    check_config,
    lend,
    load_config,
    open_session,
)
from tests.helpers import wait_for
from tests.zenoh_helpers import hub_endpoint, own_sockets, wait_matching

SAMPLES = [
    TesWrench(seq=1, stamp=2.5, force=(12.0, -3.0, -640.0), moment=(1.5, 27.3, -4.0), cop=(0.04, -0.01)),
    ScRequest(seq=2, stamp=3.0, mode="limit", speed_cap=0.5, source="sc-agent"),
    ScCommand(seq=3, stamp=3.0, mode="idle", speed_cap=0.0, source="supervisor", reason="speed above cap"),
    SafetyState(seq=4, stamp=3.1, state="LIMITING", reason="SPEED_OVER_CAP", cap=0.5, since=3.05),
    EstopCommand(seq=5, stamp=1.7e9, action="reset", source="operator"),
    ControllerTelemetry(
        seq=6,
        stamp=4.0,
        state=3,
        mode="ihacs",
        command_speed=(0.4, -0.1),
        tilt_command=(0.02, 0.0),
        yaw_rate_command=0.1,
        ball_torque=(1.0, -2.0, 0.5),
    ),
]


# ---------------------------------------------------------------------------------- network rule
@pytest.mark.parametrize("role", ["hub", "member"])
def test_loopback_config_has_no_multicast_and_only_loopback_endpoints(role):
    raw = zenoh.Config.from_file(str(LOOPBACK))
    assert raw.get_json("scouting/multicast/enabled") == "false"
    config = load_config(LOOPBACK, role)
    assert config.get_json("mode") == '"peer"'
    assert config.get_json("scouting/multicast/enabled") == "false"
    listen = msgspec.json.decode(config.get_json("listen/endpoints"))
    connect = msgspec.json.decode(config.get_json("connect/endpoints"))
    assert all(e.startswith("tcp/127.0.0.1:") for e in listen + connect)
    assert (listen, connect) == (
        (["tcp/127.0.0.1:7447"], []) if role == "hub" else (["tcp/127.0.0.1:0"], ["tcp/127.0.0.1:7447"])
    )


def test_configs_that_leave_the_machine_are_refused():
    multicast = zenoh.Config.from_json5('{mode: "peer", listen: {endpoints: ["tcp/127.0.0.1:7447"]}}')
    with pytest.raises(ZenohConfigError, match="multicast/enabled must be false"):
        check_config(multicast)
    lan = zenoh.Config.from_json5(
        '{mode: "peer", scouting: {multicast: {enabled: false}}, listen: {endpoints: ["tcp/0.0.0.0:7447"]}}'
    )
    with pytest.raises(ZenohConfigError, match="not on loopback"):
        check_config(lan)
    with pytest.raises(ZenohConfigError, match="not on loopback"):
        load_config(CONFIG_DIR / "router.json5", "hub")  # the bench router config is never opened here
    # Without explicit endpoints zenoh listens on every interface (tcp/[::]): refused.
    bare = zenoh.Config.from_json5('{mode: "peer", scouting: {multicast: {enabled: false}}}')
    with pytest.raises(ZenohConfigError, match=r"tcp/\[::\]"):
        check_config(bare)


def test_sessions_bind_only_to_loopback_and_open_no_udp():
    before = own_sockets()
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    member = open_session(role="member", hub_endpoint=endpoint)
    try:
        assert wait_for(lambda: list(member.info.peers_zid()))
        sockets = own_sockets()
        new_tcp = set(sockets["tcp"]) - set(before["tcp"])
        listening = [port for _, port, state in new_tcp if state == "LISTEN"]
        assert int(endpoint.rsplit(":", 1)[1]) in listening and len(listening) == 2  # hub + member
        assert all(ip == "127.0.0.1" for ip, _, _ in new_tcp)
        assert set(sockets["udp"]) == set(before["udp"])  # no scouting sockets
    finally:
        member.close()
        hub.close()


# ------------------------------------------------------------------------------------------- keys
def test_key_expressions_follow_the_prefix():
    k = Keys("bench2/pure")
    assert (k.tes_wrench, k.sc_request, k.sc_command, k.safety_state, k.safety_estop) == (
        "bench2/pure/tes/wrench",
        "bench2/pure/sc/request",
        "bench2/pure/sc/command",
        "bench2/pure/safety/state",
        "bench2/pure/safety/estop",
    )
    assert Keys().rig_status == "pure/rig/status" and Keys().rig("start") == "pure/rig/start"
    for bad in ("", "/pure", "pure/", "pure/*"):
        with pytest.raises(ValueError):
            Keys(bad)


def test_keys_are_the_same_strings_for_any_prefix():
    # Formatted once when made: the same strings the keys were formatted to at every read.
    k = Keys(prefix="bench2/pure")
    assert vars(k) == {
        "prefix": "bench2/pure",
        "tes_wrench": "bench2/pure/tes/wrench",
        "sc_request": "bench2/pure/sc/request",
        "sc_command": "bench2/pure/sc/command",
        "safety_state": "bench2/pure/safety/state",
        "safety_alert": "bench2/pure/safety/alert",
        "safety_estop": "bench2/pure/safety/estop",
        "controller_command": "bench2/pure/controller/command",
        "controller_telemetry": "bench2/pure/controller/telemetry",
        "rig_tick": "bench2/pure/rig/tick",
        "rig_status": "bench2/pure/rig/status",
        "rig_live": "bench2/pure/rig/live",
        "rig_history": "bench2/pure/rig/history",
        "rig_file": "bench2/pure/rig/file",
        "everything": "bench2/pure/**",
    }
    assert k.rig("start") == "bench2/pure/rig/start"
    assert k == Keys("bench2/pure") and hash(k) == hash(Keys("bench2/pure")) and k != Keys()
    assert repr(k) == "Keys(prefix='bench2/pure')" and pickle.loads(pickle.dumps(k)) == k
    assert Keys() == Keys("pure") and Keys().tes_wrench == "pure/tes/wrench"
    message = "zenoh key prefix 'bench2/*': expected a plain path like 'pure' or 'bench2/pure'"
    with pytest.raises(ValueError, match=re.escape(message)):
        Keys("bench2/*")


# ----------------------------------------------------------------------------- over real sessions
@pytest.fixture
def hub_and_member():
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    member = open_session(role="member", hub_endpoint=endpoint)
    yield ZenohLink(hub), ZenohLink(member), endpoint
    member.close()
    hub.close()


def test_every_payload_round_trips_between_two_sessions(hub_and_member):
    tx, rx, _ = hub_and_member
    keys = Keys()
    for key, sample in zip(
        [
            keys.tes_wrench,
            keys.sc_request,
            keys.sc_command,
            keys.safety_state,
            keys.safety_estop,
            keys.controller_telemetry,
        ],
        SAMPLES,
        strict=True,
    ):
        sub = rx.subscribe(key, type(sample))
        assert wait_matching(tx.publisher(key))
        tx.put(key, sample)
        got = wait_for(sub.drain)
        assert got == [sample]
    assert tx.publisher(keys.tes_wrench) is tx.publisher(keys.tes_wrench)  # declared once


def test_members_reach_each_other_through_the_hub(hub_and_member):
    # Controller and supervisor are both members: gossip over loopback introduces them.
    _, _, endpoint = hub_and_member
    a = ZenohLink(open_session(role="member", hub_endpoint=endpoint))
    b = ZenohLink(open_session(role="member", hub_endpoint=endpoint))
    try:
        sub = b.subscribe(Keys().sc_command, ScCommand)
        assert wait_matching(a.publisher(Keys().sc_command))
        a.put(Keys().sc_command, SAMPLES[2])
        assert wait_for(sub.drain) == [SAMPLES[2]]
    finally:
        a.session.close()
        b.session.close()


def test_a_lent_hub_is_shared_in_process_and_never_closed_by_the_borrower():
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    access = ZenohAccess(endpoint=endpoint)
    key = Keys().tes_wrench
    try:
        with lend(hub, endpoint):
            borrowed = access.open("controller")
            assert isinstance(borrowed, LentSession)
            sub = ZenohLink(borrowed).subscribe(key, TesWrench)
            ZenohLink(hub).put(key, SAMPLES[0])
            assert sub.received == 1  # inside one session: delivered by the put itself, no wait
            assert sub.drain() == [SAMPLES[0]]
            borrowed.close()  # the borrower's close leaves the owner's session open
            ZenohLink(hub).put(key, SAMPLES[0])
            assert wait_for(lambda: sub.received == 2)
            sub.close()
        outside = access.open("controller")  # control: once the loan ends, a session of its own
        try:
            assert not isinstance(outside, LentSession)
            assert wait_for(lambda: list(outside.info.routers_zid()) or list(outside.info.peers_zid()))
        finally:
            outside.close()
    finally:
        hub.close()


def test_latest_and_all_new(hub_and_member):
    tx, rx, _ = hub_and_member
    key = Keys().tes_wrench
    sub = rx.subscribe(key, TesWrench)
    assert wait_matching(tx.publisher(key))
    for i in range(5):
        tx.put(key, msgspec.structs.replace(SAMPLES[0], seq=i))
    assert wait_for(lambda: sub.latest() is not None and sub.accepted == 5)
    assert sub.latest().seq == 4
    assert sub.drain() == [] and sub.latest().seq == 4


def test_a_reader_behind_the_rig_leaves_later_ticks_queued(hub_and_member):
    """Puts tagged with a tick (the lockstep rig's) wait for a reader at that tick, across the 2^16 wrap;
    untagged ones (a person's e-stop) never wait for a tick; drain() without a tick takes all."""
    tx, rx, _ = hub_and_member
    key = Keys().tes_wrench
    sub = rx.subscribe(key, TesWrench)
    assert wait_matching(tx.publisher(key))
    data = {i: encode(msgspec.structs.replace(SAMPLES[0], seq=i)) for i in range(5)}
    tx.put(key, data[0])  # untagged
    tx.put(key, data[1], tick=TICK_MODULO - 1)
    tx.put(key, data[2], tick=TICK_MODULO)  # wraps to 0: one tick later
    tx.put(key, data[3], tick=TICK_MODULO + 2)
    assert wait_for(lambda: sub.received == 4)
    seqs = lambda payloads: [p.seq for p in payloads]  # noqa: E731
    assert seqs(sub.drain(tick=TICK_MODULO - 1)) == [0, 1]
    assert seqs(sub.drain(tick=TICK_MODULO - 1)) == []
    assert seqs(sub.drain(tick=TICK_MODULO + 1)) == [2]  # the reader counts on past the wrap, unwrapped
    tx.put(key, data[4])
    assert wait_for(lambda: sub.received == 5)
    assert seqs(sub.drain(tick=1)) == [], "in order: the untagged one waits behind tick 2's"
    assert seqs(sub.drain()) == [3, 4]


MALFORMED = {
    "garbage": b"\xc1\xff\x00garbage",
    "not a map": msgspec.msgpack.encode([1, 2, 3]),
    "wrong type": msgspec.msgpack.encode(
        {"seq": "one", "stamp": 0.0, "force": [0, 0, 0], "moment": [0, 0, 0], "cop": [0, 0]}
    ),
    "missing field": msgspec.msgpack.encode(
        {"seq": 1, "stamp": 0.0, "force": [0, 0, 0], "moment": [0, 0, 0]}
    ),
    "nan": msgspec.msgpack.encode(
        {"seq": 1, "stamp": 0.0, "force": [math.nan, 0, 0], "moment": [0, 0, 0], "cop": [0, 0]}
    ),
    "inf": msgspec.msgpack.encode(
        {"seq": 1, "stamp": 0.0, "force": [0, 0, 0], "moment": [math.inf, 0, 0], "cop": [0, 0]}
    ),
    "out of range": msgspec.msgpack.encode(
        {"seq": 1, "stamp": 0.0, "force": [0, 0, -5e4], "moment": [0, 0, 0], "cop": [0, 0]}
    ),
    "wrong version": msgspec.msgpack.encode(
        {"version": 2, "seq": 1, "stamp": 0.0, "force": [0, 0, 0], "moment": [0, 0, 0], "cop": [0, 0]}
    ),
    "unknown field": msgspec.msgpack.encode(
        {"seq": 1, "stamp": 0.0, "force": [0, 0, 0], "moment": [0, 0, 0], "cop": [0, 0], "extra": 1}
    ),
}
EXPECTED_KIND = {"garbage": "garbage", "not a map": "garbage", "wrong version": "version"}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_payloads_raise_payload_error_with_a_kind(case):
    with pytest.raises(PayloadError) as err:
        decode(MALFORMED[case], TesWrench)
    assert err.value.kind == EXPECTED_KIND.get(case, "schema")


def test_malformed_payloads_are_counted_and_dropped_by_the_subscriber(hub_and_member):
    tx, rx, _ = hub_and_member
    key = Keys().tes_wrench
    sub = rx.subscribe(key, TesWrench)
    pub = tx.publisher(key)
    assert wait_matching(pub)
    for raw in MALFORMED.values():
        pub.put(raw)
    tx.put(key, SAMPLES[0])  # positive control: the valid one still gets through
    wait_for(lambda: sub.drain() or sum(sub.rejected.values()) + sub.accepted == len(MALFORMED) + 1)
    assert sub.accepted == 1 and sub.latest() == SAMPLES[0]
    assert sub.rejected == {"garbage": 2, "version": 1, "schema": len(MALFORMED) - 3}
    assert sub.last_rejection


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=200))
def test_fuzzed_bytes_never_escape_as_anything_but_payload_error(data):
    for t in (TesWrench, ScRequest, ScCommand, SafetyState, EstopCommand, ControllerTelemetry, RigTick):
        with contextlib.suppress(PayloadError):  # anything else escaping fails the test
            decode(data, t)


finite = st.floats(allow_nan=True, allow_infinity=True)


@settings(max_examples=300, deadline=None)
@given(
    force=st.tuples(finite, finite, finite),
    moment=st.tuples(finite, finite, finite),
    cop=st.tuples(finite, finite),
    seq=st.integers(-(2**40), 2**40),
    stamp=finite,
)
def test_extreme_values_are_accepted_exactly_when_in_range(force, moment, cop, seq, stamp):
    raw = msgspec.msgpack.encode({"seq": seq, "stamp": stamp, "force": force, "moment": moment, "cop": cop})

    def ok(x, lim):
        return not math.isnan(x) and -lim <= x <= lim

    valid = (
        all(ok(f, 1e4) for f in force)
        and all(ok(m, 2e3) for m in moment)
        and all(ok(c, 1.0) for c in cop)
        and 0 <= seq <= 2**32 - 1
        and ok(stamp, 1e10)
        and stamp >= 0
    )
    try:
        got = decode(raw, TesWrench)
    except PayloadError as exc:
        assert not valid and exc.kind == "schema"
    else:
        assert valid and got.force == tuple(force)
