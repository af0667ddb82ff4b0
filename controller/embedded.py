"""Start the reference controller on a thread, from a DutSpec (the rig's `pure_hil.controllers` plugin)."""

from __future__ import annotations

import threading

import msgspec

from controller.config import ControllerConfig, RiderInfo
from controller.core import Controller
from controller.node import ControllerNode
from drivers.can_bus import open_bus
from drivers.config import load_toml
from drivers.devices import host_node
from drivers.dut import DrivenDut, DutSpec, PausableDut
from drivers.keys import Keys
from drivers.plugs import NodeHandle, NodeThread
from drivers.robot import RobotModel
from drivers.zenoh_link import ZenohLink


def build_controller(spec: DutSpec) -> Controller:
    config = (
        load_toml(spec.controller_config, ControllerConfig) if spec.controller_config else ControllerConfig()
    )
    timing = msgspec.structs.replace(config.timing, tick_hz=spec.tick_hz)
    config = msgspec.structs.replace(config, mode=spec.mode, timing=timing)
    return Controller(config, load_toml(spec.robot, RobotModel), load_toml(spec.rider, RiderInfo))


class EmbeddedController(NodeHandle):
    """The reference controller in the rig's process: on a thread of its own, or (`spec.driven`) handled
    from the rig's thread through `poll()` after every SYNC."""

    def __init__(self, spec: DutSpec):
        controller = build_controller(spec)
        self.bus = open_bus(spec.can)
        try:
            self.session = spec.zenoh.open(spec.identity)
        except BaseException:
            self.close()
            raise
        self.link = link = ZenohLink(self.session, Keys(spec.zenoh.prefix))
        can = host_node(self.bus, spec.devices, controller.robot.encoder.counts_per_rev, "controller")
        self.node = ControllerNode(controller, can, link, lockstep=spec.lockstep)
        self.paused = threading.Event()
        if spec.driven:
            self.node.boot()  # the rig's start-up handshake waits for it before the first SYNC
        else:
            self.thread = NodeThread(self.node.run, "controller", 0.1, self.paused).start()

    def poll(self) -> None:
        """Driven: take in what is queued and answer any SYNC among it (nothing while hung or stopped)."""
        if self.thread is None and not self._stopped and not self.paused.is_set():
            self.node.poll()

    def pause(self) -> None:
        """Hang: stop handling frames (they queue up on the bus) until `resume` (a fault-injection hook)."""
        self.paused.set()

    def resume(self) -> None:
        self.paused.clear()


def start(spec: DutSpec) -> EmbeddedController:
    return EmbeddedController(spec)


PLUG_CONTRACT: tuple[type[DrivenDut], type[PausableDut]] = (EmbeddedController, EmbeddedController)
"""mypy checks the reference controller against what the rig drives and the hang fault pauses."""
