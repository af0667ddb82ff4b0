"""The machine's rig folder (hil/bench/rigs.py): a dead rig's card is removed as clients look and as rigs
announce themselves, and a client never takes one for a live rig, also when its pid went to another
process."""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import asdict

import pytest

from drivers.zenoh_link import open_session
from hil.bench.rigs import (
    FOLDER_VARIABLE,
    HUB_VARIABLE,
    RigCard,
    announce,
    choose_hub,
    running,
    started_ticks,
)
from tests.zenoh_helpers import hub_endpoint


@pytest.fixture
def rigs(tmp_path, monkeypatch):
    monkeypatch.setenv(FOLDER_VARIABLE, str(tmp_path))
    monkeypatch.delenv(HUB_VARIABLE, raising=False)
    return tmp_path


def leave(folder, card: RigCard, name: str):
    path = folder / f"{name}.json"
    path.write_text(json.dumps(asdict(card)))
    return path


def dead_pid() -> int:
    child = subprocess.Popen(["true"])
    child.wait()  # reaped: the pid names no process now
    return child.pid


def test_a_dead_rigs_card_is_removed_and_never_picked(rigs):
    mine = started_ticks(os.getpid())
    live = leave(
        rigs, RigCard("embedded", "tcp/127.0.0.1:1111", os.getpid(), "serve", 0.0, process=mine), "a"
    )
    dead = leave(rigs, RigCard("embedded", "tcp/127.0.0.1:2222", dead_pid(), "serve", 0.0), "b")
    # The pid went to another process (here: this one, started at another time than the card says).
    reused = leave(
        rigs, RigCard("embedded", "tcp/127.0.0.1:3333", os.getpid(), "run x", 0.0, process="1"), "c"
    )
    assert mine and mine != "1", "the control: this process's start is known, and not the reused card's"
    assert [card.endpoint for card in running()] == ["tcp/127.0.0.1:1111"]
    assert live.exists() and not dead.exists() and not reused.exists()
    # One live rig of the bench: the client takes it (three cards would have been 'name one with --hub').
    assert choose_hub("embedded", None, None) == "tcp/127.0.0.1:1111"


def test_a_rig_announcing_itself_clears_the_dead_rigs_cards(rigs):
    dead = leave(rigs, RigCard("embedded", "tcp/127.0.0.1:2222", dead_pid(), "serve", 0.0), "b")
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    try:
        with announce(hub, "pure", "embedded", endpoint, "serve") as card:
            assert not dead.exists()
            assert card.process == started_ticks(os.getpid())
            assert [c.id for c in running()] == [card.id], "its own card is a live one"
        assert not list(rigs.glob("*.json")), "and it takes its own away"
    finally:
        hub.close()
