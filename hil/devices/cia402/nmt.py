"""NMT (CiA 301): a drive's boot-up, its NMT state, reset communication and the heartbeat producer.

python-canopen's NMT slave keeps the state and sends the boot-up message; the heartbeat it would send from
a python-can periodic task is sent here, counted in ticks (network.py)."""

from __future__ import annotations

from drivers.devices.cia402 import HEARTBEAT
from hil.devices.cia402.objects import DriveObjects

OPERATIONAL, STOPPED = "OPERATIONAL", "STOPPED"
STOP, RESET_NODE, RESET_COMMUNICATION = 0x02, 0x81, 0x82
"""NMT commands: stop remote node, reset node, reset communication."""


class NmtSlave(DriveObjects):
    """A drive's NMT slave: boot-up, state, reset communication, heartbeat."""

    booted: bool

    def _comm_defaults(self) -> None:
        """The communication objects a bench sets (the producer heartbeat, the identity) over the EDS's."""
        store = self.node.data_store
        store.setdefault(0x1017, {})[0] = round(self.options.heartbeat_ms).to_bytes(2, "little")
        o = self.options
        identity = {1: o.vendor_id, 2: o.product_code, 3: o.revision_number, 4: self.node_id}
        for sub, value in identity.items():
            if value is not None:
                store.setdefault(0x1018, {})[sub] = value.to_bytes(4, "little")

    def reset_communication(self) -> None:
        """NMT reset communication: the communication objects (0x1000-0x1FFF) back to power-on values."""
        for index in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
            del self.node.data_store[index]
        self._comm_defaults()
        self.compile_pdos()

    def boot(self) -> None:
        """Power-up: INITIALISING (the boot-up message) -> PRE-OPERATIONAL (the heartbeat producer starts)."""
        self.booted = True
        self.node.nmt.send_command(0x81)  # reset node: state 0, boot-up message
        self.node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL; starts the producer per 0x1017

    @property
    def nmt(self) -> str:
        return self.node.nmt.state

    def heartbeat(self) -> None:
        for task in self.network.tasks:
            if not task.stopped and task.can_id == HEARTBEAT + self.node_id:
                if task.count % task.every == 0:
                    self.network.send_message(task.can_id, task.data)
                task.count += 1
