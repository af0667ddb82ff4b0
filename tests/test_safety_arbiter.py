"""Several SC agents: the most restrictive request wins, conflicts and floods never lift a cap, each source
is rate-limited, and the number of sources is bounded."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.schemas import ScRequest
from safety.arbiter import ScArbiter
from safety.config import ScRules

RULES = ScRules()


def sc_request(mode, cap, source):
    return ScRequest(seq=0, stamp=0.0, mode=mode, speed_cap=cap, source=source)


def test_the_most_restrictive_request_wins_whatever_the_order():
    for order in (("a", "b"), ("b", "a")):
        arbiter = ScArbiter(RULES)
        asks = {"a": sc_request("free", 0.0, "a"), "b": sc_request("limit", 0.5, "b")}
        for t, source in enumerate(order):
            arbiter.offer(asks[source], float(t))
        assert arbiter.request == asks["b"]
        assert arbiter.conflicts == 1


def test_a_source_lifts_only_its_own_cap():
    arbiter = ScArbiter(RULES)
    arbiter.offer(sc_request("limit", 0.5, "a"), 0.0)
    arbiter.offer(sc_request("idle", 0.0, "b"), 0.1)
    assert arbiter.request.mode == "idle"
    arbiter.offer(sc_request("free", 0.0, "b"), 0.2)  # b lets go; a's cap stays
    assert (arbiter.request.mode, arbiter.request.speed_cap) == ("limit", 0.5)
    arbiter.offer(sc_request("free", 0.0, "a"), 0.3)
    assert arbiter.request.mode == "free"


def test_each_source_is_rate_limited_and_the_sources_are_bounded():
    arbiter = ScArbiter(RULES)
    accepted = sum(arbiter.offer(sc_request("free", 0.0, "flood"), 1.0) for _ in range(100))
    assert accepted == RULES.burst and arbiter.sources["flood"].refused == 100 - RULES.burst
    # One second later the bucket has refilled at the rate (capped at the burst).
    assert sum(arbiter.offer(sc_request("free", 0.0, "flood"), 2.0) for _ in range(100)) == RULES.burst
    for i in range(RULES.max_sources + 3):
        arbiter.offer(sc_request("limit", 1.0, f"agent{i}"), 3.0)
    assert len(arbiter.sources) == RULES.max_sources and arbiter.refused_sources == 4
    assert arbiter.age(4.0) == 2.0, "the stalest source"


requests = st.tuples(
    st.sampled_from(["a", "b"]),
    st.sampled_from(["free", "idle", "limit"]),
    st.floats(0.0, 5.0),
    st.sampled_from([0.0, 0.001, 0.02, 0.5]),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(requests, min_size=1, max_size=200))
def test_no_interleaving_of_two_sources_lifts_either_ones_cap(sequence):
    arbiter = ScArbiter(RULES)
    last: dict[str, ScRequest] = {}
    t = 0.0
    for source, mode, cap, dt in sequence:
        t += dt
        request = sc_request(mode, cap, source)
        if arbiter.offer(request, t):
            last[source] = request
        merged = arbiter.request
        if merged is not None:
            assert merged.speed_limit() == min(r.speed_limit() for r in last.values())
            assert all(merged.speed_limit() <= r.speed_limit() for r in last.values())
        assert math.isinf(sc_request("free", 0.0, "x").speed_limit())
