"""A device profile as one object: what a bench, the rig and a host need of it, behind one entry point.

A profile is one line in the entry-point group `pure_hil.devices` (drivers/registry.py) naming a
`DeviceProfile`: its name, whether the drives or the IMU speak it, its settings type, its host (what a
controller or a supervisor speaks: a translator made here, in drivers/) and its emulation (the rig's
devices). The object lives in drivers/ and names its emulation by a "module:attr" string, imported only by
the rig: drivers/ sits below hil/ (tests/test_boundaries.py), and the bench's `[devices]` (drivers/) must
check a profile's settings, and a controller or a supervisor (which may not import hil/) must find its
host, through the same one object. Nothing of a profile is imported before a bench names it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, Protocol

import msgspec

from drivers.registry import DEVICE_PROFILES, BrokenPlug, PlugNotFound, find_plug, installed

if TYPE_CHECKING:
    from drivers.devices import Devices, Role, Translator

Kind = Literal["drives", "imu"]
"""What speaks a profile: the three drives or the IMU (the bench's `[devices]` key that names it)."""
PURE = "pure"
"""The contract's own frames: no profile, no translator (drivers/devices/__init__.py)."""


class Emulate(Protocol):
    """The rig's side: (the bench's devices, the plant encoders' counts per revolution, the tick rate in Hz)
    -> the translator of the emulated devices."""

    def __call__(self, devices: Devices, counts_per_rev: int, tick_hz: float) -> Translator: ...


class Host(Protocol):
    """A controller's or a supervisor's side: (the bench's devices, counts per revolution, role) -> the
    translator it reads and writes the devices through."""

    def __call__(self, devices: Devices, counts_per_rev: int, role: Role) -> Translator: ...


class DeviceProfile(Protocol):
    """Everything the rig needs of a device profile (one entry point in `pure_hil.devices`)."""

    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> Kind: ...
    @property
    def options(self) -> type[msgspec.Struct]:
        """The profile's settings, a msgspec Struct whose defaults make a working bench; its
        `__post_init__` raises ValueError naming the field and the bound."""
        ...

    @property
    def host(self) -> Host: ...
    def emulation(self) -> Emulate:
        """The rig's side, imported now (not before a rig needs it)."""
        ...

    def claims(self, devices: Devices) -> Mapping[int, str]:
        """A drive profile: the standard frame ids its drives own on this bench -> whose they are (the IMU
        profile's check refuses them). An IMU profile's are not read (it checks against the drives')."""
        ...

    def check(self, devices: Devices) -> None:
        """ValueError naming the setting if its devices' ids take a frame another part keeps on the bus."""
        ...


def _none(devices: Devices) -> dict[int, str]:
    return {}


def _fine(devices: Devices) -> None:
    return None


@dataclass(frozen=True)
class Profile:
    """A `DeviceProfile` made of plain parts: what a profile module puts behind its entry point."""

    name: str
    kind: Kind
    options: type[msgspec.Struct]
    host: Host
    emulation_at: str
    """"module:attr" of its `Emulate` (hil/devices/ for the built-in ones)."""
    claims: Callable[[Devices], Mapping[int, str]] = field(default=_none)
    check: Callable[[Devices], None] = field(default=_fine)

    def emulation(self) -> Emulate:
        module, _, attr = self.emulation_at.partition(":")
        found: Emulate = getattr(importlib.import_module(module), attr)
        return found


PROFILE_PARTS = ("name", "kind", "options", "host", "emulation", "claims", "check")
"""What a DeviceProfile has (`Profile` gives `claims` and `check` that claim and refuse nothing)."""


_found: dict[str, DeviceProfile] = {}
"""Profiles loaded so far (only found ones: one installed later is found then)."""


def find_profile(name: str) -> DeviceProfile:
    """The installed profile `name`; PlugNotFound lists the installed ones."""
    if name not in _found:
        profile: Any = find_plug(DEVICE_PROFILES, name, "device profile")
        missing = [a for a in PROFILE_PARTS if not hasattr(profile, a)]
        if missing:
            raise BrokenPlug(
                f"device profile {name!r}: its entry point is not a DeviceProfile ({profile!r} has no "
                f"{', '.join(missing)}; drivers.devices.profile.Profile makes one from plain parts)"
            )
        _found[name] = profile
    return _found[name]


def profile_of(name: str, kind: Kind) -> DeviceProfile | None:
    """The profile a bench's `[devices] <kind> = name` names (None: `pure`); ValueError names the key and
    lists the installed profiles of that kind."""
    if name == PURE:
        return None
    try:
        profile = find_profile(name)
    except BrokenPlug as exc:
        raise ValueError(f"{kind}: {exc}") from None
    except PlugNotFound:
        profile = None
    if profile is None or profile.kind != kind:
        have = [PURE, *(p for p in installed(DEVICE_PROFILES) if p != name and _kind_of(p) == kind)]
        raise ValueError(f"{kind}: no {kind} device profile {name!r} installed (have: {', '.join(have)})")
    return profile


def _kind_of(name: str) -> Kind | None:
    try:
        return find_profile(name).kind
    except PlugNotFound:
        return None
