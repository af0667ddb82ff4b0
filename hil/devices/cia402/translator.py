"""The device side of three emulated CiA 402 drives (the rig's Translator): the plant's samples in, each
drive's boot-up, heartbeat, EMCY and TPDOs out; the host's NMT, SDO and RPDOs in, the contract's
DRIVEn_COMMAND out; the protocol faults' hooks (hil/faults/devices.py)."""

from __future__ import annotations

from collections.abc import Mapping

import can

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF
from drivers.devices import Devices, Translator
from drivers.devices.cia402 import EMCY, HEARTBEAT, NMT, RPDO1, SDO_RX, SDO_TX, TPDO1
from hil.devices.cia402.drive import Drive
from hil.devices.cia402.network import RigNetwork
from hil.devices.cia402.nmt import OPERATIONAL, RESET_NODE, STOP, STOPPED


class Cia402Drives(Translator):
    """The device side of three CiA 402 drives."""

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        options = devices.cia402
        self.network = RigNetwork(1.0 / tick_hz)
        self.drives = [Drive(i, n, self.network, options) for i, n in enumerate(options.node_ids)]
        self._drive_of = {d.node_id: d for d in self.drives}
        self.counts_per_rev = counts_per_rev
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        ids = {NMT}
        for n in options.node_ids:
            ids |= {RPDO1 + 0x100 * k + n for k in range(4)} | {SDO_RX + n}
        self.frame_ids = frozenset(ids)
        self.sends = frozenset(
            f + n
            for n in options.node_ids
            for f in (EMCY, *(TPDO1 + 0x100 * k for k in range(4)), SDO_TX, HEARTBEAT)
        )

    # ------------------------------------------------------------------------------ the drives' output
    def frame_id_as(self, msg: can.Message, name: str) -> int:
        """The same COB (its function code) from the drive that sends `name`."""
        function = msg.arbitration_id - (msg.arbitration_id & 0x7F)
        return function + self.drives[MOTOR_OF[name]].node_id

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        """The plant's sample of a drive: its state now (TPDOs go out at SYNC, `on_sync`); the boot-up,
        heartbeat and EMCY frames it causes."""
        self.network.take()  # nothing pending outside a call
        drive = self.drives[MOTOR_OF[name]]
        drive.fed.add(name)
        if name in DRIVE_TORQUE:
            drive.torque_actual = round(float(values["Torque"]) * 1e6 / drive.params[0x6076])
            return []
        if not drive.booted:
            drive.boot()
        if drive.stop_pending:
            drive.stop_pending = False
            drive.node.nmt.send_command(STOP)  # as a master's NMT stop: the heartbeat says STOPPED
        drive.follow_plant(values, self.counts_per_rev)
        drive.heartbeat()
        return self.network.take()

    def on_sync(self, tick: int) -> None:
        """The rig's SYNC: each drive's TPDOs of it go out just before it (a drive answering the previous
        SYNC with the state the rig sampled for this one: docs/devices.md)."""
        super().on_sync(tick)
        assert self.node is not None
        for drive in self.drives:
            for pdo, msg in drive.tpdos_at_sync():
                self.node.reply((DRIVE_TORQUE if pdo.torque_only else DRIVE_FEEDBACK)[drive.index], msg)
            drive.fed.clear()

    # ------------------------------------------------------------------------------- the host's input
    def incoming(self, msg: can.Message) -> Received | None:
        if msg.is_remote_frame:
            return None
        cob = msg.arbitration_id
        if cob == NMT:
            if len(msg.data) < 2:
                raise ValueError(f"NMT: {len(msg.data)} bytes, expected 2")
            for d in self.drives:
                before = d.nmt
                d.node.nmt.on_command(cob, bytes(msg.data), msg.timestamp)
                if d.nmt == "INITIALISING" and before != "INITIALISING":
                    d.booted = False  # reset node / communication: boots again at the next tick
                    if msg.data[0] == RESET_NODE:
                        d.power_on()
                    else:
                        d.reset_communication()
            self._flush(0)
            return None
        drive = self._drive_of[cob & 0x7F]
        function = cob - drive.node_id
        if function == SDO_RX:
            if drive.nmt != STOPPED and drive.sdo_abort:
                if (abort := drive.abort(bytes(msg.data))) is not None:
                    self.network.send_message(SDO_TX + drive.node_id, abort)
            elif drive.nmt != STOPPED:  # a stopped node answers NMT only
                self.network.notify(cob, bytearray(msg.data), msg.timestamp)
                drive.apply_written()
            self._flush(drive.index)
            return None
        pdo = drive.rpdos.get(cob)
        if drive.nmt != OPERATIONAL or pdo is None:
            return None  # PDOs only in OPERATIONAL, and only the RPDOs that exist
        drive.rpdo_result = None
        drive.receive(pdo, bytes(msg.data))
        self._flush(drive.index)
        result = drive.rpdo_result
        if result is None:
            return None
        torque, enable = result
        signals = {"Torque": torque, "Tick": self.tick, "Enable": int(enable)}
        return Received(DRIVE_COMMAND[drive.index], signals, msg.timestamp, None)

    # ------------------------------------------------------------------ protocol faults (hil/faults)
    profile = "cia402"

    def fault(self, motor: int, code: int) -> None:
        """Drive `motor` enters FAULT with EMCY `code` at its next tick and stays there, whatever fault reset
        says, until `code` is 0 (then a fault reset clears it)."""
        self.drives[motor].forced_error = code

    def nmt_stop(self, motor: int) -> None:
        """Drive `motor` goes to NMT STOPPED at its next tick, as if a master had stopped it (an NMT start
        takes it back to OPERATIONAL)."""
        self.drives[motor].stop_pending = True

    def sync_lost(self, motor: int, lost: bool) -> None:
        """Drive `motor` sees no SYNC: its SYNC-triggered TPDOs stop; its heartbeat (on its own timer), its
        event-driven TPDOs and its RPDOs (transmission type 255: acted on at reception, CiA 301) go on."""
        self.drives[motor].sync_lost = lost

    def sdo_abort(self, motor: int, code: int) -> None:
        """Drive `motor` answers every SDO request with abort `code` (0: its SDO server again)."""
        self.drives[motor].sdo_abort = code

    def _flush(self, index: int) -> None:
        """What the Network sent while handling a frame (SDO responses, EMCY) and the event-driven TPDOs the
        frame changed: out at once."""
        assert self.node is not None
        for m in self.network.take():
            self.node.reply(DRIVE_FEEDBACK[index], m)
        drive = self.drives[index]
        for pdo, m in drive.tpdos_on_change():
            self.node.reply((DRIVE_TORQUE if pdo.torque_only else DRIVE_FEEDBACK)[index], m)


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> Cia402Drives:
    return Cia402Drives(devices, counts_per_rev, tick_hz)
