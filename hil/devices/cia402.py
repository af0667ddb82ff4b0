"""Three emulated CiA 402 drives on CANopen, one per omniwheel motor, each a python-canopen `LocalNode` with
the project's EDS (configs/devices/cia402.eds; docs/devices.md).

python-canopen gives the object dictionary, the SDO server (so a master reads the PDO mapping over SDO), the
NMT slave's state and the PDO codecs. What it leaves to the application is done here: no Notifier thread (the
rig feeds each frame to the canopen Network from `incoming`), the Network sends through the rig's
ProfileNode (its bus, fault hooks and log see every frame), the heartbeat producer counts ticks instead of
running a python-can periodic task, TPDOs go out at SYNC (the rig's tick) only in OPERATIONAL, RPDOs apply
only in OPERATIONAL, and the CiA 402 state machine, the plant's feedback and EMCY are this module's.

An RPDO's target torque while OPERATION ENABLED in CST reaches the rig as the contract's DRIVEn_COMMAND
tagged with the current tick (a PDO carries no tick), Enable 1; any other RPDO as Enable 0.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable, Mapping

import can
import canopen
from canopen.pdo.base import PdoBase, PdoMaps

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF
from drivers.devices import Devices, Translator
from drivers.devices.cia402 import (
    CST,
    EMCY,
    ERROR_REGISTER,
    HEARTBEAT,
    NMT,
    RATED_MNM,
    REMOTE,
    RPDO1,
    RPDO2,
    SDO_RX,
    SDO_TX,
    STATUS_BITS,
    TPDO1,
    TPDO2,
    TPDO3,
    VOLTAGE_ENABLED,
    ErrorCode,
    State,
    eds_path,
)

log = logging.getLogger(__name__)

OPERATIONAL, STOPPED = "OPERATIONAL", "STOPPED"
SDO_ABORT = 0x80
"""An SDO abort's command specifier (CiA 301): 0x80, index, subindex, abort code (U32)."""
STOP = 0x02
"""NMT stop remote node."""


def error_register(code: int) -> int:
    """0x1001 for an error code: the emulation's own (ERROR_REGISTER), else CiA 301's bits of the code's class
    (generic, current 0x2xxx, voltage 0x3xxx, temperature 0x4xxx, communication 0x81xx, device profile
    0x6xxx-0x7xxx, manufacturer 0xFFxx)."""
    if code in ERROR_REGISTER:
        return ERROR_REGISTER[ErrorCode(code)]
    if not code:
        return 0x00
    bit = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x6: 0x20, 0x7: 0x20, 0xF: 0x80}.get(code >> 12, 0)
    if code >> 8 == 0x81:
        bit = 0x10
    return 0x01 | bit


class _TickTask:
    """python-canopen's periodic task (the heartbeat producer), counted in ticks by the emulation."""

    def __init__(self, can_id: int, data: bytes, period: float, tick_s: float):
        self.can_id, self.data = can_id, bytes(data)
        self.every = max(1, round(period / tick_s))
        self.count = 1
        """The first heartbeat one period after the task starts (after the boot-up message, not with it: a
        master waiting for the boot-up would miss it behind a heartbeat in the same instant)."""
        self.stopped = False

    def update(self, data: bytes) -> None:
        self.data = bytes(data)

    def stop(self) -> None:
        self.stopped = True


class RigNetwork(canopen.Network):
    """A canopen Network without a bus or a Notifier: frames in by `notify`, frames out into `out`."""

    def __init__(self, tick_s: float):
        super().__init__(bus=None)
        self.tick_s = tick_s
        self.out: list[can.Message] = []
        self.tasks: list[_TickTask] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.out.append(
            can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False, is_remote_frame=remote)
        )

    def send_periodic(  # type: ignore[override]  # a task of the tick, not python-can's thread
        self, can_id: int, data: bytes, period: float, remote: bool = False
    ) -> _TickTask:
        task = _TickTask(can_id, data, period, self.tick_s)
        self.tasks = [t for t in self.tasks if not t.stopped] + [task]
        return task

    def take(self) -> list[can.Message]:
        out, self.out = self.out, []
        return out


class Drive:
    """One CiA 402 drive: a LocalNode and its state machine."""

    def __init__(self, index: int, node_id: int, network: RigNetwork, heartbeat_ms: float):
        self.index, self.node_id = index, node_id
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds_path()), node_id))
        network.add_node(self.node)
        self.network = network
        self.heartbeat_ms = heartbeat_ms
        self.state = State.SWITCH_ON_DISABLED
        self.error: int = ErrorCode.NONE
        self.controlword = 0
        mode = self.node.object_dictionary[0x6060]
        assert isinstance(mode, canopen.objectdictionary.ODVariable)
        self.mode = int(mode.default or 0)
        """Modes of operation: the EDS's default (CST), as configured before the run."""
        self.target = 0
        self.position = self.velocity = self.torque_actual = 0
        self.powered = True
        self.booted = False
        self.forced_error = 0
        """An error a fault holds active (hil/faults/devices.py): FAULT with it, no fault reset, until 0."""
        self.stop_pending = False
        """A fault stops the node (NMT STOPPED) at its next tick."""
        self.sync_lost = False
        """A fault keeps SYNC from the drive: no SYNC-triggered TPDO (its RPDOs, type 255, still act)."""
        self.sdo_abort = 0
        """A fault's SDO abort code: every SDO request is answered with it (0: served)."""
        self.node.add_read_callback(self._read)
        self.node.add_write_callback(self._write)
        self.node.tpdo.read(from_od=True)
        self.node.rpdo.read(from_od=True)
        for pdo in _maps(self.node.rpdo).values():
            pdo.add_callback(self._on_rpdo)
        self.rpdo_result: tuple[float, bool] | None = None
        self._tpdo_codecs = [self._codec(pdo) for pdo in _maps(self.node.tpdo).values() if pdo.enabled]
        """Each enabled TPDO as (function, COB-ID, struct, getters), compiled once from python-canopen's map
        (the EDS's mapping): packing a tick's TPDOs through its PdoVariable setters costs about twice as
        much."""

    def _codec(self, pdo: canopen.pdo.PdoMap) -> tuple[int, int, struct.Struct, list[Callable[[], int]]]:
        getters = self._getters
        fmt = "<"
        if pdo.cob_id is None:  # python-canopen's type allows it; an enabled map of the EDS has one
            raise ValueError(f"{pdo.name}: no COB-ID")
        for var in pdo:
            if var.offset is None or var.offset % 8 or var.length % 8 or var.index not in getters:
                raise ValueError(f"{pdo.name}: 0x{var.index:04X} not a byte-aligned object it sends")
            fmt += var.od.STRUCT_TYPES[var.od.data_type].format.lstrip("<")
        return pdo.cob_id - self.node_id, pdo.cob_id, struct.Struct(fmt), [getters[var.index] for var in pdo]

    # -------------------------------------------------------------------------------- NMT and boot-up
    def boot(self) -> None:
        """Power-up: INITIALISING (the boot-up message) -> PRE-OPERATIONAL (the heartbeat producer starts)."""
        self.booted = True
        self.node.nmt.send_command(0x81)  # reset node: state 0, boot-up message
        self.node.data_store.setdefault(0x1017, {})[0] = round(self.heartbeat_ms).to_bytes(2, "little")
        self.node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL; starts the producer per 0x1017

    @property
    def nmt(self) -> str:
        return self.node.nmt.state

    # -------------------------------------------------------------------------------- object dictionary
    def statusword(self) -> int:
        word = STATUS_BITS[self.state] | REMOTE
        if self.powered and self.state in (
            State.READY_TO_SWITCH_ON,
            State.SWITCHED_ON,
            State.OPERATION_ENABLED,
            State.QUICK_STOP_ACTIVE,
        ):
            word |= VOLTAGE_ENABLED
        return word

    def _read(self, index: int, subindex: int, od: canopen.objectdictionary.Variable) -> int | None:
        getter = self._getters.get(index)
        return None if getter is None else getter()

    @property
    def _getters(self) -> dict[int, Callable[[], int]]:
        return {
            0x6041: self.statusword,
            0x603F: lambda: int(self.error),
            0x1001: lambda: error_register(self.error),
            0x6040: lambda: self.controlword,
            0x6060: lambda: self.mode,
            0x6061: lambda: self.mode,
            0x6064: lambda: self.position,
            0x606C: lambda: self.velocity,
            0x6071: lambda: self.target,
            0x6077: lambda: self.torque_actual,
        }

    def _write(self, index: int, subindex: int, od: canopen.objectdictionary.Variable, data: bytes) -> None:
        value = od.decode_raw(data)
        if index == 0x6040:
            self.apply_controlword(int(value))
        elif index == 0x6060:
            self.mode = int(value)
        elif index == 0x6071:
            self.target = int(value)

    # ------------------------------------------------------------------------------ the state machine
    def apply_controlword(self, cw: int) -> None:
        rising_reset = bool(cw & 0x80) and not self.controlword & 0x80
        self.controlword = cw
        s = self.state
        if s in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            if rising_reset and self.powered and not self.forced_error:
                self.state, self.error = State.SWITCH_ON_DISABLED, ErrorCode.NONE
                self.node.emcy.send(0x0000, 0x00)  # error reset
            return
        if not cw & 0x02:  # disable voltage (transitions 7, 9, 10, 12)
            self.state = State.SWITCH_ON_DISABLED
        elif not cw & 0x04:  # quick stop (7, 10, 11)
            if s is State.OPERATION_ENABLED:
                self.state = State.QUICK_STOP_ACTIVE
            elif s in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON):
                self.state = State.SWITCH_ON_DISABLED
        elif cw & 0x87 == 0x06:  # shutdown (2, 6, 8)
            if s in (State.SWITCH_ON_DISABLED, State.SWITCHED_ON, State.OPERATION_ENABLED):
                self.state = State.READY_TO_SWITCH_ON
        elif cw & 0x8F == 0x07:  # switch on (3) / disable operation (5)
            if s in (State.READY_TO_SWITCH_ON, State.OPERATION_ENABLED):
                self.state = State.SWITCHED_ON
        elif cw & 0x8F == 0x0F and s in (
            State.READY_TO_SWITCH_ON,
            State.SWITCHED_ON,
            State.QUICK_STOP_ACTIVE,
        ):
            self.state = (
                State.OPERATION_ENABLED
            )  # switch on + enable operation (3+4), enable operation (4, 16)

    def fault(self, code: int) -> None:
        if self.state is State.FAULT:
            return
        self.state, self.error = State.FAULT, code
        if self.nmt != STOPPED:  # a stopped node sends no EMCY (CiA 301): 0x603F still holds the code
            self.node.emcy.send(int(code), error_register(code))

    @property
    def makes_torque(self) -> bool:
        return self.state is State.OPERATION_ENABLED and self.mode == CST

    def _on_rpdo(self, pdo: canopen.pdo.PdoMap) -> None:
        values = {var.index: var.raw for var in pdo}
        if 0x6060 in values:
            self.mode = int(values[0x6060])
        if 0x6071 in values:
            self.target = int(values[0x6071])
        if 0x6040 in values:
            self.apply_controlword(int(values[0x6040]))
        if 0x6040 in values or 0x6071 in values:
            torque = self.target * RATED_MNM * 1e-6 if self.makes_torque else 0.0
            self.rpdo_result = (torque, self.state is State.OPERATION_ENABLED)

    # ------------------------------------------------------------------------------------ the plant
    def follow_plant(self, s: Mapping[str, float], counts_per_rev: int) -> None:
        self.position = int(s["Position"])
        self.velocity = round(s["Velocity"] * counts_per_rev / (2.0 * math.pi))
        self.powered = bool(s["BusPowered"])
        if self.forced_error:
            self.fault(self.forced_error)
        elif not self.powered:
            self.fault(ErrorCode.DC_LINK_UNDER_VOLTAGE)
        elif s["WatchdogTripped"]:
            self.fault(ErrorCode.COMMUNICATION)
        elif s.get("Fault", 0):
            self.fault(ErrorCode.POWER_SECTION)
        elif self.state is State.OPERATION_ENABLED and not s["Enabled"]:
            self.fault(ErrorCode.POWER_STAGE_OFF)  # off without a controlword: the permission line

    def tpdos(self, functions: tuple[int, ...]) -> None:
        """The TPDOs of this SYNC (only in OPERATIONAL), into the network's out."""
        if self.nmt != OPERATIONAL or self.sync_lost:
            return
        for function, cob_id, codec, getters in self._tpdo_codecs:
            if function in functions:
                self.network.send_message(cob_id, codec.pack(*(get() for get in getters)))

    def abort(self, request: bytes) -> bytes | None:
        """The SDO abort for a request: the request's multiplexer when it has one (an initiate), else the
        transfer's under way (a segment)."""
        ccs = request[0] >> 5 if request else 0
        if ccs == 4:  # the client's own abort: not answered
            return None
        if ccs in (1, 2, 5, 6) and len(request) >= 4:
            index, subindex = int.from_bytes(request[1:3], "little"), request[3]
        else:
            sdo = self.node.sdo
            index, subindex = int(getattr(sdo, "_index", 0) or 0), int(getattr(sdo, "_subindex", 0) or 0)
        return struct.pack("<BHBI", SDO_ABORT, index, subindex, self.sdo_abort)

    def heartbeat(self) -> None:
        for task in self.network.tasks:
            if not task.stopped and task.can_id == HEARTBEAT + self.node_id:
                if task.count % task.every == 0:
                    self.network.send_message(task.can_id, task.data)
                task.count += 1


class Cia402Drives(Translator):
    """The device side of three CiA 402 drives."""

    def __init__(self, devices: Devices, counts_per_rev: int, tick_hz: float):
        super().__init__()
        options = devices.cia402
        self.network = RigNetwork(1.0 / tick_hz)
        self.drives = [
            Drive(i, n, self.network, options.heartbeat_ms) for i, n in enumerate(options.node_ids)
        ]
        self._drive_of = {d.node_id: d for d in self.drives}
        self.counts_per_rev = counts_per_rev
        self.names = frozenset((*DRIVE_FEEDBACK, *DRIVE_TORQUE))
        ids = {NMT}
        for n in options.node_ids:
            ids |= {RPDO1 + n, RPDO2 + n, SDO_RX + n}
        self.frame_ids = frozenset(ids)
        self.sends = frozenset(
            f + n for n in options.node_ids for f in (EMCY, TPDO1, TPDO2, TPDO3, 0x580, HEARTBEAT)
        )

    # ------------------------------------------------------------------------------ the drives' output
    def frame_id_as(self, msg: can.Message, name: str) -> int:
        """The same COB (its function code) from the drive that sends `name`."""
        function = msg.arbitration_id - (msg.arbitration_id & 0x7F)
        return function + self.drives[MOTOR_OF[name]].node_id

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        self.network.take()  # nothing pending outside a call
        if name in DRIVE_TORQUE:
            drive = self.drives[MOTOR_OF[name]]
            drive.torque_actual = round(float(values["Torque"]) * 1e6 / RATED_MNM)
            drive.tpdos((TPDO3,))  # transmission type 4: the rig samples torque every 4th tick
            return self.network.take()
        drive = self.drives[MOTOR_OF[name]]
        if not drive.booted:
            drive.boot()
        if drive.stop_pending:
            drive.stop_pending = False
            drive.node.nmt.send_command(STOP)  # as a master's NMT stop: the heartbeat says STOPPED
        drive.follow_plant(values, self.counts_per_rev)
        drive.heartbeat()
        drive.tpdos((TPDO1, TPDO2))  # transmission type 1: each SYNC (the rig's tick)
        return self.network.take()

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
            self._flush(drive.index)
            return None
        if drive.nmt != OPERATIONAL:
            return None  # PDOs only in OPERATIONAL
        pdo = _maps(drive.node.rpdo)[1 if function == RPDO1 else 2]
        if len(msg.data) < len(pdo.data):
            raise ValueError(
                f"RPDO{1 if function == RPDO1 else 2}: {len(msg.data)} bytes, expected {len(pdo.data)}"
            )
        drive.rpdo_result = None
        self.network.notify(cob, bytearray(msg.data), msg.timestamp)
        self._flush(drive.index)
        if drive.rpdo_result is None:
            return None
        torque, enable = drive.rpdo_result
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
        """Drive `motor` sees no SYNC: its SYNC-triggered TPDOs (all three) stop; its heartbeat (on its own
        timer) and its RPDOs (transmission type 255: acted on at reception, CiA 301) go on."""
        self.drives[motor].sync_lost = lost

    def sdo_abort(self, motor: int, code: int) -> None:
        """Drive `motor` answers every SDO request with abort `code` (0: its SDO server again)."""
        self.drives[motor].sdo_abort = code

    def _flush(self, index: int) -> None:
        """What the Network sent while handling a frame (SDO responses, EMCY): out at once."""
        assert self.node is not None
        for m in self.network.take():
            self.node.reply(DRIVE_FEEDBACK[index], m)


def _maps(pdos: PdoBase) -> PdoMaps:
    assert pdos.map is not None  # a LocalNode's TPDO and RPDO always have their maps
    return pdos.map


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> Cia402Drives:
    return Cia402Drives(devices, counts_per_rev, tick_hz)
