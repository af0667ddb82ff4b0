"""A CAN bus as a bench names it: python-can's interface, channel, bitrate and extra kwargs (`BusConfig`),
and the CLI's short form of one (`parse_can_spec`). drivers/can_bus.py opens it.

A module of its own because `BusConfig` is a msgspec Struct: the compiled build (setup.py) compiles
drivers/can_bus.py, and msgspec does not see the class keywords (`frozen=True`, `kw_only=True`, ...) of a
Struct that mypyc compiled, so the Structs stay in modules that stay Python.
"""

from __future__ import annotations

import socket
from typing import Annotated, Any

import msgspec

LOOPBACK_ONLY_INTERFACES = frozenset({"udp_multicast"})
"""Buses over IP multicast: allowed only in a network namespace whose only interface is lo, where nothing
can leave the machine (docs/bench.md, "Processes at host speed"), never in the host's namespace."""
IN_PROCESS_INTERFACES = frozenset({"pure_shared", "virtual"})
"""Buses that exist only inside one Python process (drivers/shared_bus.py; python-can's `virtual`)."""


class BusConfigError(ValueError):
    pass


class BusConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A bus in python-can's terms (`can.Bus(interface=..., channel=..., bitrate=..., **kwargs)`)."""

    interface: str = "pure_shared"
    channel: str = "pure"
    bitrate: Annotated[
        int,
        msgspec.Meta(
            ge=10_000,
            le=1_000_000,
            description="bit/s; ISO 11898's classical CAN runs at 10 kbit/s to 1 Mbit/s, and every frame "
            "of the rig is classical (no bit-rate switch): the bus load and a babbling node's frames per "
            "tick are counted at this rate (a CAN FD data phase, up to 8 Mbit/s, would be python-can's "
            "data_bitrate in kwargs)",
        ),
    ] = 1_000_000
    kwargs: dict[str, Any] = {}
    max_load: Annotated[
        float, msgspec.Meta(gt=0.0, le=1.0, description="a fraction of the bitrate: 1 is a full bus")
    ] = 0.70
    """Refuse a tick rate whose worst-case bus load exceeds this fraction of the bitrate."""

    @property
    def in_process(self) -> bool:
        """Only nodes in this Python process can join the bus."""
        return self.interface in IN_PROCESS_INTERFACES

    def __post_init__(self) -> None:
        if self.interface in LOOPBACK_ONLY_INTERFACES and (here := network_interfaces()) != ["lo"]:
            raise ValueError(
                f"interface {self.interface!r} is not allowed here: it sends multicast UDP, allowed only "
                f"inside a network namespace whose only interface is lo (this one has {', '.join(here)}); "
                "use 'pure_shared' or 'socketcan', or run the bench inside such a namespace (docs/bench.md)"
            )


def network_interfaces() -> list[str]:
    """The network interfaces of this process's namespace."""
    return sorted(name for _, name in socket.if_nameindex())


def parse_can_spec(spec: str, base: BusConfig | None = None) -> BusConfig:
    """`pure_shared`, `pure_shared:NAME`, `socketcan:vcan0`, `pcan:PCAN_USBBUS1`, ... -> BusConfig."""
    interface, _, channel = spec.partition(":")
    if not interface:
        raise BusConfigError(f"bad CAN spec {spec!r}: expected INTERFACE[:CHANNEL], e.g. socketcan:vcan0")
    base = base or BusConfig()
    try:
        return msgspec.structs.replace(base, interface=interface, channel=channel or base.channel)
    except ValueError as exc:
        raise BusConfigError(f"bad CAN spec {spec!r}: {exc}") from exc
