"""The scenario's SC agent and operator (hil/run/agents.py): what they put, and at which tick."""

from __future__ import annotations

import pytest

from drivers.keys import Keys
from drivers.schemas import ControllerCommand, EstopCommand, ScRequest
from drivers.zenoh_link import LOOPBACK, ZenohLink, open_session
from hil.run.agents import (
    FREE_SCHEDULE,
    SC_REPEAT_EVERY,
    SCENARIO_SOURCE,
    OperatorStep,
    ScenarioAgents,
    ScStep,
)
from tests.zenoh_helpers import hub_endpoint


@pytest.fixture(scope="module")
def link():
    session = open_session(LOOPBACK, "hub", hub_endpoint())
    link = ZenohLink(session, Keys("agentstest"))
    yield link
    link.close()
    session.close()


def agents_over(link, ticks, sc=FREE_SCHEDULE, operator=()):
    """(tick, key, payload) of every put over `ticks` ticks."""
    puts: list = []
    agents = ScenarioAgents(
        link, sc, operator, None, lambda k, key, payload, via: puts.append((k, key, payload))
    )
    for k in range(ticks):
        agents.publish(k, k / 400)
    return puts


def test_an_sc_request_goes_out_when_it_changes_and_again_every_repeat(link):
    limit = ScRequest(seq=0, stamp=0.0, mode="limit", speed_cap=0.5, source=SCENARIO_SOURCE)
    puts = agents_over(link, 200, sc=(*FREE_SCHEDULE, ScStep(100, limit)))
    ticks = [k for k, _, _ in puts]
    assert ticks == [
        0,
        SC_REPEAT_EVERY,
        2 * SC_REPEAT_EVERY,
        100,
        100 + SC_REPEAT_EVERY,
        100 + 2 * SC_REPEAT_EVERY,
    ]
    assert [p.mode for _, _, p in puts] == ["free"] * 3 + ["limit"] * 3
    assert [p.seq for _, _, p in puts] == [1, 2, 3, 4, 5, 6], "one sequence per key"
    assert all(key == link.keys.sc_request for _, key, _ in puts)
    assert puts[3][2].stamp == pytest.approx(100 / 400), "stamped when it goes out, not when planned"


def test_operator_actions_go_out_once_at_their_tick_on_their_keys(link):
    operator = (OperatorStep(30, "disable"), OperatorStep(10, "estop"), OperatorStep(10, "reset"))
    puts = [p for p in agents_over(link, 50, sc=(), operator=operator)]
    assert [(k, type(p), p.action) for k, _, p in puts] == [
        (10, EstopCommand, "estop"),
        (10, EstopCommand, "reset"),
        (30, ControllerCommand, "disable"),
    ]
    keys = link.keys
    assert [key for _, key, _ in puts] == [keys.safety_estop, keys.safety_estop, keys.controller_command]
    assert [p.seq for _, _, p in puts] == [1, 2, 1] and {p.source for _, _, p in puts} == {SCENARIO_SOURCE}
