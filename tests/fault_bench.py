"""A rig with no controller, and a listener on its bus and its zenoh keys: what faults put on the wire."""

from __future__ import annotations

import time

import can

from drivers.bus_config import BusConfig
from drivers.can_bus import CanNode, Received, open_bus, private_channel
from drivers.config import load_toml
from drivers.keys import Keys
from drivers.schemas import ScRequest, TesWrench
from drivers.zenoh_link import ZenohLink
from hil.faults import FaultSet, parse_fault
from hil.run.drives_port import DrivesPort
from hil.run.rig import Rig, RigParts
from plant.ballbot import Plant
from plant.params import RiderParams, RobotParams, SimParams
from tests.helpers import ROOT, wait_for

ROBOT = load_toml(ROOT / "configs/robot/pure.toml", RobotParams)
RIDER = load_toml(ROOT / "configs/riders/ref_60kg_180.toml", RiderParams)
DT = 1.0 / 400


class Bench:
    def __init__(
        self,
        session,
        faults=(),
        seed: int = 0,
        prefix: str | None = None,
        rig: type[Rig] = Rig,
        port: type[DrivesPort] = DrivesPort,
    ):
        """rig, port: the Rig and its DrivesPort or a test's subclasses (the compiled build's cannot be
        patched)."""
        self.plant = Plant(ROBOT, RIDER, SimParams(seed=seed))
        self.bus_config = config = BusConfig(channel=private_channel())
        self.bus, self.listen_bus = open_bus(config), open_bus(config)
        self.listener = CanNode(self.listen_bus, name="listener")
        self.link = ZenohLink(session, Keys(prefix or private_channel("bench").replace("-", "")))
        specs = [parse_fault(f) if isinstance(f, dict) else f for f in faults]
        drives = port(self.plant, CanNode(self.bus, name="rig"))
        self.rig = rig(RigParts(drives, self.link, faults=FaultSet(specs, seed)))
        self.rig.faults.attach(self.rig)
        keys = self.link.keys
        self.tes = self.link.subscribe(keys.tes_wrench, TesWrench, capacity=1 << 14)
        self.sc = self.link.subscribe(keys.sc_request, ScRequest, capacity=1 << 14)
        self.raw: list[tuple[int, bytes]] = []
        self._raw_sub = session.declare_subscriber(
            f"{keys.prefix}/**", lambda s: self.raw.append((self.plant.tick, bytes(s.payload.to_bytes())))
        )
        assert wait_for(lambda: self.rig.link.publisher(keys.tes_wrench).matching_status.matching, 5.0)
        self.frames: list[tuple[int, can.Message, Received | None]] = []
        """(tick, frame, what the listener made of it: None if malformed) in arrival order."""

    def run(self, ticks: int) -> None:
        """`ticks` ticks of the rig (no controller answers: each tick gives up at once)."""
        for _ in range(ticks):
            self.rig.tick(deadline=time.monotonic(), lockstep=False)
            self._listen()
        time.sleep(0.05)
        self._listen()

    def _listen(self) -> None:
        while (m := self.listen_bus.recv(0.0)) is not None:
            self.frames.append((self.plant.tick, m, self.listener.decode(m)))

    def decoded(self, name: str) -> list[tuple[int, Received]]:
        return [(tick, rx) for tick, _, rx in self.frames if rx is not None and rx.name == name]

    def statuses(self, name: str) -> list[str]:
        return [rx.e2e.status.name for _, rx in self.decoded(name)]

    def series(self, name: str, signal: str) -> dict[int, float]:
        return {tick: rx.signals[signal] for tick, rx in self.decoded(name)}

    def close(self) -> None:
        self._raw_sub.undeclare()
        self.link.close()
        self.bus.shutdown()
        self.listen_bus.shutdown()
