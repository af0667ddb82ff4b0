"""The reference supervisor as a plug (`pure_hil.supervisors`: reference), started from a SupervisorSpec:
in the rig's process, driven by the rig's tick (`spec.driven`), or on a thread of its own, in the process
`pure-hil part supervisor reference SPEC.json` runs."""

from __future__ import annotations

import msgspec

from drivers.can_bus import open_bus
from drivers.config import load_toml
from drivers.devices import host_node
from drivers.keys import Keys
from drivers.plugs import NodeHandle, NodeThread, Supervisor, SupervisorHandle, SupervisorSpec, Watched
from drivers.robot import RobotModel
from drivers.zenoh_link import ZenohLink
from safety.config import SupervisorConfig
from safety.node import SupervisorNode


class EmbeddedSupervisor(NodeHandle):
    """A SupervisorNode with its bus and zenoh; `node` is what the rig updates when it drives it."""

    def __init__(self, spec: SupervisorSpec, link: ZenohLink | None = None):
        """link: the rig's, for a driven supervisor (its puts are counted in the lockstep fence); None: a
        session and link of its own, as the bench's supervisor role."""
        self.bus = open_bus(spec.can)
        try:
            if link is None:
                self.session = spec.zenoh.open("supervisor")
                link = ZenohLink(self.session, Keys(spec.zenoh.prefix), lossless=spec.lockstep)
            self.link = link
            robot = load_toml(spec.robot, RobotModel)
            rules = msgspec.convert(spec.rules, SupervisorConfig)
            can = host_node(self.bus, spec.devices, robot.encoder.counts_per_rev, "supervisor")
            self.node = SupervisorNode(
                can, link, rules, robot, tick_hz=spec.tick_hz, stage_read_back=spec.devices.stage_read_back
            )
        except BaseException:
            self.close()
            raise
        if not spec.driven:
            run = self.node.run_on_sync if spec.lockstep else self.node.run  # lockstep: on SYNC's time base
            self.thread = NodeThread(run, "supervisor").start()


PLUG_CONTRACT: type[Supervisor] = SupervisorNode
"""The reference supervisor is what the rig may drive (mypy checks it against drivers.plugs.Supervisor)."""
HANDLE_CONTRACT: tuple[type[SupervisorHandle], type[Watched]] = (EmbeddedSupervisor, EmbeddedSupervisor)
"""Its handle, and one that says whether its thread still runs (mypy checks both)."""


def start(spec: SupervisorSpec, link: ZenohLink | None = None) -> EmbeddedSupervisor:
    return EmbeddedSupervisor(spec, link)
