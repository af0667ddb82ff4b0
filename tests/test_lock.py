"""The installed set is the tested one: every package the rig and its dev extra need is installed at the
version requirements.lock pins (README's first command and .ci/run install from it), and the rig's own
metadata keeps pyproject.toml's lower bounds, not the lock's pins (a wheel is a library others install beside
their own). docs/dependencies.md says how the lock is refreshed and checked."""

from __future__ import annotations

import importlib.metadata as md
import os

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from tests.helpers import ROOT

UNLOCKED = "PURE_HIL_UNLOCKED"  # tools/deps.py sets it where it installs another set on purpose
only_locked = pytest.mark.skipif(
    bool(os.environ.get(UNLOCKED)),
    reason=f"{UNLOCKED} is set: tools/deps.py installed another set on purpose",
)


def locked() -> dict[str, str]:
    """name -> pinned version, for the lock's lines whose marker holds on this interpreter."""
    pinned = {}
    for line in (ROOT / "requirements.lock").read_text().splitlines():
        if not line or line[0] in "# ":
            continue
        req = Requirement(line)
        if req.marker is None or req.marker.evaluate():
            (spec,) = req.specifier
            assert spec.operator == "==", line
            pinned[canonicalize_name(req.name)] = spec.version
    return pinned


def needed(root: str = "pure-hil", extras: tuple[str, ...] = ("dev",)) -> set[str]:
    """The installed closure of `root[extras]`'s requirements, by their own metadata."""
    seen: set[str] = set()
    todo = [(root, set(extras))]
    while todo:
        name, wanted = todo.pop()
        for text in md.requires(name) or []:
            req = Requirement(text)
            env = [{"extra": e} for e in wanted] or [{"extra": ""}]
            if req.marker is not None and not any(req.marker.evaluate(e) for e in env):
                continue
            key = canonicalize_name(req.name)
            if key not in seen:
                seen.add(key)
                todo.append((key, set(req.extras)))
    return seen


def disagreements(pinned: dict[str, str]) -> tuple[list[str], dict[str, tuple[str, str]]]:
    """What is needed but not pinned, and what is installed at another version than pinned."""
    missing = sorted(needed() - pinned.keys())
    wrong = {n: (md.version(n), pinned[n]) for n in needed() & pinned.keys() if md.version(n) != pinned[n]}
    return missing, wrong


@only_locked
def test_the_installed_versions_are_the_locks():
    missing, wrong = disagreements(locked())
    assert not missing, f"needed but not in requirements.lock (python3 tools/deps.py lock): {missing}"
    assert not wrong, f"installed vs locked: {wrong}; install with README's first command"


@only_locked
def test_the_lock_covers_exactly_what_the_rig_needs():
    """Nothing stale in the lock either: each of its packages is needed here, or only on another Python or
    platform (its marker false here)."""
    assert set(locked()) <= needed() | {"pure-hil"}, sorted(set(locked()) - needed())


def test_the_rigs_metadata_keeps_lower_bounds():
    """The installed metadata (the wheel's, in .ci/run's compiled section) asks for pyproject.toml's `>=`
    bounds, never an exact version: the lock is the application's, not the library's."""
    requires = md.requires("pure-hil") or []
    assert requires
    for text in requires:
        req = Requirement(text)
        ops = {s.operator for s in req.specifier}
        assert ops == {">="}, f"{text}: a dependency of the rig takes a lower bound only"


def test_a_positive_control_sees_a_missing_and_a_wrong_version():
    pinned = {name: md.version(name) for name in needed()}  # what is installed: agrees, whatever it is
    assert disagreements(pinned) == ([], {})
    del pinned["numpy"]
    pinned["msgspec"] = "0.0.1"
    missing, wrong = disagreements(pinned)
    assert missing == ["numpy"]
    assert wrong == {"msgspec": (md.version("msgspec"), "0.0.1")}
