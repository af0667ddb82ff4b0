"""Several SC agents: the most restrictive request wins, conflicts and floods never lift a cap, each source
is rate-limited, and the number of sources is bounded."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from safety.arbiter import ScArbiter, cap_of
from safety.config import ScRules
from safety.machine import Request

RULES = ScRules()


def test_the_most_restrictive_request_wins_whatever_the_order():
    for order in (("a", "b"), ("b", "a")):
        arbiter = ScArbiter(RULES)
        asks = {"a": Request("free", 0.0, "a"), "b": Request("limit", 0.5, "b")}
        for t, source in enumerate(order):
            arbiter.offer(asks[source], float(t))
        assert arbiter.request == asks["b"]
        assert arbiter.conflicts == 1


def test_a_source_lifts_only_its_own_cap():
    arbiter = ScArbiter(RULES)
    arbiter.offer(Request("limit", 0.5, "a"), 0.0)
    arbiter.offer(Request("idle", 0.0, "b"), 0.1)
    assert arbiter.request.mode == "idle"
    arbiter.offer(Request("free", 0.0, "b"), 0.2)  # b lets go; a's cap stays
    assert (arbiter.request.mode, arbiter.request.cap) == ("limit", 0.5)
    arbiter.offer(Request("free", 0.0, "a"), 0.3)
    assert arbiter.request.mode == "free"


def test_each_source_is_rate_limited_and_the_sources_are_bounded():
    arbiter = ScArbiter(RULES)
    accepted = sum(arbiter.offer(Request("free", 0.0, "flood"), 1.0) for _ in range(100))
    assert accepted == RULES.burst and arbiter.sources["flood"].refused == 100 - RULES.burst
    # One second later the bucket has refilled at the rate (capped at the burst).
    assert sum(arbiter.offer(Request("free", 0.0, "flood"), 2.0) for _ in range(100)) == RULES.burst
    for i in range(RULES.max_sources + 3):
        arbiter.offer(Request("limit", 1.0, f"agent{i}"), 3.0)
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
    last: dict[str, Request] = {}
    t = 0.0
    for source, mode, cap, dt in sequence:
        t += dt
        request = Request(mode, cap, source)
        if arbiter.offer(request, t):
            last[source] = request
        merged = arbiter.request
        if merged is not None:
            assert cap_of(merged) == min(cap_of(r) for r in last.values())
            assert all(cap_of(merged) <= cap_of(r) for r in last.values())
        assert math.isinf(cap_of(Request("free", 0.0, "x")))
