"""Three emulated CiA 402 drives on CANopen, one per omniwheel motor, each a python-canopen `LocalNode` with
the project's EDS (configs/devices/cia402.eds; docs/devices.md).

python-canopen gives the object dictionary, the SDO server (expedited and segmented: a master reads the
device name, the PDO configuration, the identity) and the NMT slave's state. What it leaves to the
application is done here: no Notifier thread (the rig feeds each frame to the canopen Network from
`incoming`), the Network sends through the rig's ProfileNode (its bus, fault hooks and log see every frame),
the heartbeat producer counts ticks instead of running a python-can periodic task, the PDOs follow the
communication and mapping parameters a master writes (checked as CiA 301 asks, compiled, applied: TPDOs at
SYNC or on change, RPDOs on reception, only in OPERATIONAL), the live objects answer SDO from the drive's
state, and the CiA 402 state machine, the plant's feedback, EMCY and the error history are this module's.

An RPDO's target torque while OPERATION ENABLED in CST reaches the rig as the contract's DRIVEn_COMMAND
tagged with the current tick (a PDO carries no tick), Enable 1; any other RPDO that carries the controlword
or the target torque as Enable 0.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from drivers.can_bus import Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF
from drivers.devices import Cia402Options, Devices, Translator
from drivers.devices.cia402 import (
    CST,
    EMCY,
    ERROR_REGISTER,
    HEARTBEAT,
    NMT,
    REMOTE,
    RPDO1,
    SDO_RX,
    SDO_TX,
    STATUS_BITS,
    TPDO1,
    VOLTAGE_ENABLED,
    ErrorCode,
    State,
    eds_path,
)
from hil.devices.plant_drive import PlantFault, plant_faults

OPERATIONAL, STOPPED = "OPERATIONAL", "STOPPED"
SDO_ABORT = 0x80
"""An SDO abort's command specifier (CiA 301): 0x80, index, subindex, abort code (U32)."""
STOP, RESET_NODE, RESET_COMMUNICATION = 0x02, 0x81, 0x82
"""NMT commands: stop remote node, reset node, reset communication."""
INTERNAL_LIMIT = 0x0800
"""Statusword bit 11: internal limit active (the target torque is clipped to 0x6072 / 0x6073)."""
HALT = 0x0100
"""Controlword bit 8."""
HISTORY = 8
"""0x1003's standard error fields."""
ERROR_CODE = {
    PlantFault.UNPOWERED: ErrorCode.DC_LINK_UNDER_VOLTAGE,
    PlantFault.WATCHDOG: ErrorCode.COMMUNICATION,
    PlantFault.POWER_STAGE: ErrorCode.POWER_SECTION,
}
"""The error code (0x603F, EMCY) each fault of the plant's drive state raises."""
VALID, NO_RTR, EXTENDED = 0x80000000, 0x40000000, 0x20000000
"""A COB-ID entry's bits 31 (0: the PDO or EMCY exists), 30 (TPDO: 1 = no RTR), 29 (1: a 29-bit id)."""


class Abort:
    """The SDO abort codes (CiA 301) this drive answers with."""

    UNSUPPORTED_ACCESS = 0x06010000
    NOT_MAPPABLE = 0x06040041
    PDO_TOO_LONG = 0x06040042
    NO_OBJECT = 0x06020000
    INVALID_VALUE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    CANNOT_STORE = 0x08000020
    NO_DATA = 0x08000024


SAVE, LOAD = 0x65766173, 0x64616F6C
"""The signatures 'save' (0x1010) and 'load' (0x1011) as U32 (CiA 301)."""
SUPPORTED_TPDO_TYPES = frozenset((0, *range(1, 241), 254, 255))
"""0 acyclic synchronous, 1-240 every n-th SYNC, 254/255 event-driven. 252/253 (on RTR only) are not
emulated: the rig's node drops remote frames."""
SUPPORTED_RPDO_TYPES = frozenset((254, 255))
"""Acted on at reception. 0-240 (taken at the next SYNC) are not emulated: the rig hands a drive's command
to the plant when its frame arrives."""
TORQUE_OBJECTS = frozenset((0x6077, 0x6078))
"""Objects the plant samples with DRIVEn_TORQUE (every 4th tick): a TPDO of only these passes for it."""


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


@dataclass(slots=True)
class Pdo:
    """One PDO as its communication and mapping parameters say, compiled: what goes in or out, how packed."""

    number: int
    """1-4."""
    transmit: bool
    cob_id: int
    enabled: bool
    trans_type: int
    objects: tuple[int, ...]
    """Mapped indices (each at sub-index 0), in order."""
    codec: struct.Struct
    getters: tuple[Callable[[], int], ...] = ()
    """TPDO: each mapped object's present value, in order."""
    torque_only: bool = False
    """TPDO: it carries only objects the plant samples with DRIVEn_TORQUE: it passes for that message."""
    inhibit_ticks: int = 0
    event_ticks: int = 0
    last: bytes | None = None
    """TPDO: the data last sent (types 0, 254, 255 send on change)."""
    sent_at: int = -(1 << 30)
    """TPDO: the tick of the last transmission."""


class Drive:
    """One CiA 402 drive: a LocalNode, its state machine and its PDOs."""

    def __init__(self, index: int, node_id: int, network: RigNetwork, options: Cia402Options):
        self.index, self.node_id = index, node_id
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds_path()), node_id))
        network.add_node(self.node)
        self.network = network
        self.options = options
        self.tick_s = network.tick_s
        self.forced_error = 0
        """An error a fault holds active (hil/faults/devices.py): FAULT with it, no fault reset, until 0."""
        self.stop_pending = False
        """A fault stops the node (NMT STOPPED) at its next tick."""
        self.sync_lost = False
        """A fault keeps SYNC from the drive: no SYNC-triggered TPDO (its RPDOs, type 255, still act)."""
        self.sdo_abort = 0
        """A fault's SDO abort code: every SDO request is answered with it (0: served)."""
        self.position = self.velocity = self.torque_actual = 0
        self.powered = True
        self.booted = False
        self.ticks = 0
        """Ticks (SYNCs) this drive has seen: its SYNC counter and its clock."""
        self.fed: set[str] = set()
        """The logical messages the rig sampled this tick (a silenced sample silences its TPDOs)."""
        self.rpdo_result: tuple[float, bool] | None = None
        self.pdos_written = False
        """An SDO write changed a PDO parameter: the PDOs are compiled again once it is stored."""
        self._live: dict[int, Callable[[], int]] = {
            0x6041: self.statusword,
            0x603F: lambda: int(self.error),
            0x1001: lambda: error_register(self.error),
            0x6040: lambda: self.controlword,
            0x6060: lambda: self.mode,
            0x6061: lambda: self.mode,
            0x6064: lambda: self.position,
            0x606C: lambda: self.velocity,
            0x6071: lambda: self.target,
            0x6074: self.torque_demand,
            0x6077: lambda: self.torque_actual,
            0x6078: self.current_actual,
        }
        """Objects whose value is the drive's state, answered live (SDO and TPDOs)."""
        self.node.add_read_callback(self._read)
        self.node.add_write_callback(self._write)
        self.power_on()

    # -------------------------------------------------------------------------------- power-on values
    def power_on(self) -> None:
        """The drive as it powers up (and as reset node leaves it): nothing a master wrote survives (nothing
        is ever stored, 0x1010), the application at its EDS defaults."""
        self.node.data_store.clear()
        self._comm_defaults()
        self.state = State.SWITCH_ON_DISABLED
        self.error: int = ErrorCode.NONE
        self.history: list[int] = []
        self.controlword = 0
        self.target = 0
        self.params = {
            i: int(self._od(i).default or 0)
            for i in (0x605A, 0x605B, 0x605C, 0x605D, 0x605E, 0x6072, 0x6073, 0x6075, 0x6076, 0x6087)
        }
        """The drive's parameters as a master last set them (SDO or RPDO)."""
        self.mode = int(self._od(0x6060).default or 0)
        """Modes of operation: the EDS's default (CST), as configured before the run."""
        self.compile_pdos()

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

    def _od(self, index: int, subindex: int = 0) -> ODVariable:
        obj = self.node.object_dictionary[index]
        var = obj if isinstance(obj, ODVariable) else obj[subindex]
        assert isinstance(var, ODVariable)
        return var

    def value(self, index: int, subindex: int = 0) -> int:
        """An object's present value (live, stored or default) as an integer."""
        value = self._od(index, subindex).decode_raw(self.node.get_data(index, subindex))
        assert isinstance(value, int)
        return value

    # -------------------------------------------------------------------------------- NMT and boot-up
    def boot(self) -> None:
        """Power-up: INITIALISING (the boot-up message) -> PRE-OPERATIONAL (the heartbeat producer starts)."""
        self.booted = True
        self.node.nmt.send_command(0x81)  # reset node: state 0, boot-up message
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
        if self.makes_torque and abs(self.target) > self.torque_limit():
            word |= INTERNAL_LIMIT
        return word

    def torque_limit(self) -> int:
        """Per mille of the rated torque: 0x6072, and 0x6073 (per mille of the rated current, the same per
        mille of torque through the motor's torque constant)."""
        return min(self.params[0x6072], self.params[0x6073])

    def torque_demand(self) -> int:
        """0x6074, per mille of the rated torque: the target the torque loop follows (clipped to the limit;
        0 while the drive makes no torque)."""
        if not self.makes_torque:
            return 0
        limit = self.torque_limit()
        return max(-limit, min(limit, self.target))

    def current_actual(self) -> int:
        """0x6078, per mille of the rated current: the plant's torque through the motor's torque constant
        (rated torque / rated current), so the same per mille as 0x6077."""
        return self.torque_actual

    def _read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        if index == 0x1003:
            if subindex == 0:
                return len(self.history)
            if subindex > len(self.history):
                raise SdoAbortedError(Abort.NO_DATA)
            return self.history[subindex - 1]
        getter = self._live.get(index)
        return None if getter is None else getter()

    def _write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        """Check an SDO write (an abort leaves everything as it was) and apply it. python-canopen stores the
        data after this returns; what needs the stored value (the PDOs, the heartbeat) applies then."""
        value = od.decode_raw(data)
        if not isinstance(value, int):
            return  # no writable string objects: python-canopen refuses const ones before this
        if od.min is not None and value < od.min:
            raise SdoAbortedError(Abort.VALUE_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(Abort.VALUE_TOO_HIGH)
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(index, subindex, value)
            self.pdos_written = True
        elif index == 0x1003:
            if value != 0:
                raise SdoAbortedError(Abort.INVALID_VALUE)  # only 0 (clear the history) may be written
            self.history.clear()
        elif index == 0x1005:
            if value & 0x7FF != 0x080 or value & (0x40000000 | EXTENDED):
                raise SdoAbortedError(Abort.INVALID_VALUE)  # SYNC stays the rig's 0x080; no SYNC producer
        elif index == 0x1014:
            if value & 0x7FF != EMCY + self.node_id or value & EXTENDED:
                raise SdoAbortedError(Abort.INVALID_VALUE)  # only its validity (bit 31) may change
        elif index == 0x1016 and subindex > 0:
            if value:
                raise SdoAbortedError(Abort.INVALID_VALUE)  # consumer heartbeat: not emulated
        elif index == 0x1010 and subindex > 0:
            raise SdoAbortedError(Abort.CANNOT_STORE)  # nothing is stored: the drives power up per run
        elif index == 0x1011 and subindex > 0:
            if value != LOAD:
                raise SdoAbortedError(Abort.CANNOT_STORE)
        elif index == 0x6040:
            self.apply_controlword(value)
        elif index == 0x6060:
            if not self._supported_mode(value):
                raise SdoAbortedError(Abort.INVALID_VALUE)
            self.mode = value
        elif index == 0x6071:
            self.target = value
        elif index in self.params:
            self.params[index] = value

    def _supported_mode(self, mode: int) -> bool:
        """A mode 0x6502 lists (bit n-1 for the standard modes 1-10)."""
        return 1 <= mode <= 10 and bool(self.value(0x6502) >> (mode - 1) & 1)

    def apply_written(self) -> None:
        """What an SDO write changed, once python-canopen has stored it."""
        if self.pdos_written:
            self.pdos_written = False
            self.compile_pdos()

    # ------------------------------------------------------------------------------------------ PDOs
    def _pdo_of(self, index: int) -> tuple[bool, int, bool]:
        """(transmit, number 1-4, mapping) of a PDO parameter object."""
        base = index & 0xFF00
        return base in (0x1800, 0x1A00), (index & 0xFF) + 1, base in (0x1600, 0x1A00)

    def _check_pdo_write(self, index: int, subindex: int, value: int) -> None:
        """CiA 301's rules for changing a PDO: an abort where the new value is not allowed or not possible."""
        transmit, number, mapping = self._pdo_of(index)
        if number > 4:
            raise SdoAbortedError(Abort.NO_OBJECT)
        comm = (0x1800 if transmit else 0x1400) + number - 1
        cob = self.value(comm, 1)
        valid = not cob & VALID
        if not mapping:
            if subindex == 1:
                own = (0x180 if transmit else 0x200) + 0x100 * (number - 1) + self.node_id
                if value & 0x7FF != own or value & EXTENDED or value & 0x1FFFF800:
                    # Its own COB-ID, 11 bits: the bench checks a node's ids against the contract's frames.
                    raise SdoAbortedError(Abort.INVALID_VALUE)
                if transmit and not value & NO_RTR:
                    raise SdoAbortedError(Abort.INVALID_VALUE)  # RTR is not emulated
                if not value & VALID:
                    self._check_mapping(
                        transmit,
                        [self.value(index + 0x200, s) for s in range(1, 5)][: self.value(index + 0x200, 0)],
                    )
            elif subindex == 2:
                if value not in (SUPPORTED_TPDO_TYPES if transmit else SUPPORTED_RPDO_TYPES):
                    raise SdoAbortedError(Abort.INVALID_VALUE)
            elif subindex in (3, 6) and valid:
                raise SdoAbortedError(Abort.INVALID_VALUE)  # not while the PDO exists (CiA 301)
            return
        if valid:
            raise SdoAbortedError(Abort.UNSUPPORTED_ACCESS)  # destroy the PDO first (bit 31 of its COB-ID)
        if subindex == 0:
            if value > 4:
                raise SdoAbortedError(Abort.PDO_TOO_LONG)
            self._check_mapping(transmit, [self.value(index, s) for s in range(1, value + 1)])
        else:
            if self.value(index, 0):
                raise SdoAbortedError(Abort.UNSUPPORTED_ACCESS)  # disable the mapping first (sub-index 0)
            if value:
                self._check_mapping(transmit, [value])

    def _check_mapping(self, transmit: bool, entries: list[int]) -> None:
        bits = 0
        for entry in entries:
            index, subindex, length = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            if index not in self.node.object_dictionary:
                raise SdoAbortedError(Abort.NO_OBJECT)
            try:
                od = self._od(index, subindex)
            except KeyError:
                raise SdoAbortedError(Abort.NO_OBJECT) from None
            if (
                subindex
                or not od.pdo_mappable
                or not (od.readable if transmit else od.writable)
                or length != len(od)
            ):
                raise SdoAbortedError(Abort.NOT_MAPPABLE)
            bits += length
        if bits > 64:
            raise SdoAbortedError(Abort.PDO_TOO_LONG)

    def compile_pdos(self) -> None:
        """The PDOs as their parameters now say (the EDS's, or what a master wrote)."""
        self.tpdos = [self._compile(True, n) for n in range(1, 5)]
        self.active = [p for p in self.tpdos if p.enabled and p.objects]
        """The TPDOs that exist and carry something."""
        self.rpdos = {p.cob_id: p for n in range(1, 5) if (p := self._compile(False, n)).enabled}

    def _compile(self, transmit: bool, number: int) -> Pdo:
        comm = (0x1800 if transmit else 0x1400) + number - 1
        cob = self.value(comm, 1)
        count = self.value(comm + 0x200, 0)
        objects = tuple(self.value(comm + 0x200, s) >> 16 for s in range(1, count + 1))
        codec = struct.Struct("<" + "".join(_format(self._od(i)) for i in objects))
        pdo = Pdo(number, transmit, cob & 0x7FF, not cob & VALID, self.value(comm, 2), objects, codec)
        if transmit:
            pdo.inhibit_ticks = math.ceil(self.value(comm, 3) * 1e-4 / self.tick_s - 1e-9)
            pdo.event_ticks = math.ceil(self.value(comm, 5) * 1e-3 / self.tick_s - 1e-9)
            pdo.getters = tuple(self._getter(i) for i in objects)
            pdo.torque_only = bool(objects) and set(objects) <= TORQUE_OBJECTS
        return pdo

    def _getter(self, index: int) -> Callable[[], int]:
        """An object's present value: live, a parameter, or what is stored (read again each time)."""
        if index in self._live:
            return self._live[index]
        if index in self.params:
            return lambda: self.params[index]
        return lambda: self.value(index)

    @staticmethod
    def _pack(pdo: Pdo) -> bytes:
        return pdo.codec.pack(*[get() for get in pdo.getters])

    def tpdos_at_sync(self) -> list[tuple[Pdo, can.Message]]:
        """This SYNC's TPDOs (only in OPERATIONAL): the synchronous ones due (types 1-240 every n-th SYNC, 0
        when changed), the event-driven ones changed or due by their event timer."""
        self.ticks += 1
        if self.nmt != OPERATIONAL:
            return []
        out = []
        fed = self.fed
        feedback, torque = DRIVE_FEEDBACK[self.index] in fed, DRIVE_TORQUE[self.index] in fed
        for pdo in self.active:
            if not (torque if pdo.torque_only else feedback):
                continue  # the rig did not sample what it carries this tick
            kind = pdo.trans_type
            if 0 < kind <= 240 and (self.sync_lost or self.ticks % kind):
                continue  # cyclic synchronous: every n-th SYNC it sees
            data = self._pack(pdo)
            if kind == 0 and (self.sync_lost or data == pdo.last):
                continue  # acyclic synchronous: at a SYNC, when its data changed
            if kind > 240 and not self._event_due(pdo, data):
                continue
            out.append((pdo, self._send(pdo, data)))
        return out

    def tpdos_on_change(self) -> list[tuple[Pdo, can.Message]]:
        """Event-driven TPDOs whose data a frame just changed (a statusword after a controlword, say)."""
        if self.nmt != OPERATIONAL:
            return []
        out = []
        for pdo in self.active:
            if pdo.trans_type >= 254:
                data = self._pack(pdo)
                if data != pdo.last and self.ticks - pdo.sent_at >= pdo.inhibit_ticks:
                    out.append((pdo, self._send(pdo, data)))
        return out

    def _event_due(self, pdo: Pdo, data: bytes) -> bool:
        if self.ticks - pdo.sent_at < pdo.inhibit_ticks:
            return False
        return data != pdo.last or (pdo.event_ticks > 0 and self.ticks - pdo.sent_at >= pdo.event_ticks)

    def _send(self, pdo: Pdo, data: bytes) -> can.Message:
        pdo.last, pdo.sent_at = data, self.ticks
        return can.Message(arbitration_id=pdo.cob_id, data=data, is_extended_id=False)

    def receive(self, pdo: Pdo, data: bytes) -> None:
        """An RPDO in OPERATIONAL: its values, the controlword last (it acts on the new target and mode)."""
        if len(data) < pdo.codec.size:
            raise ValueError(f"RPDO{pdo.number}: {len(data)} bytes, expected {pdo.codec.size}")
        values = dict(zip(pdo.objects, pdo.codec.unpack_from(data), strict=True))
        for index, value in values.items():
            if index == 0x6060:
                self.mode = value
            elif index == 0x6071:
                self.target = value
            elif index in self.params:
                self.params[index] = value
            if index != 0x6040 and index not in self._live:
                od = self._od(index)
                self.node.data_store.setdefault(index, {})[0] = od.encode_raw(value)
        if 0x6040 in values:
            self.apply_controlword(values[0x6040])
        if 0x6040 in values or 0x6071 in values:
            self.rpdo_result = (self.torque_nm(), self.state is State.OPERATION_ENABLED)

    def torque_nm(self) -> float:
        """The torque the power stage is told to make, Nm."""
        return self.torque_demand() * self.params[0x6076] * 1e-6

    # ------------------------------------------------------------------------------ the state machine
    def apply_controlword(self, cw: int) -> None:
        rising_reset = bool(cw & 0x80) and not self.controlword & 0x80
        self.controlword = cw
        s = self.state
        if s in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            if rising_reset and self.powered and not self.forced_error:
                self.state, self.error = State.SWITCH_ON_DISABLED, ErrorCode.NONE
                self._emcy(0x0000, 0x00)  # error reset
            return
        if not cw & 0x02:  # disable voltage (transitions 7, 9, 10, 12)
            self.state = State.SWITCH_ON_DISABLED
        elif not cw & 0x04:  # quick stop (7, 10, 11)
            if s is State.OPERATION_ENABLED:
                # 0x605A -1 (manufacturer's): torque off at once, stay in QUICK STOP ACTIVE; 0: disable the
                # drive function, the motor free, and on to SWITCH ON DISABLED (transition 12) at once.
                quick_stop_stays = self.params[0x605A] < 0
                self.state = State.QUICK_STOP_ACTIVE if quick_stop_stays else State.SWITCH_ON_DISABLED
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
        self.history = [code & 0xFFFF, *self.history][:HISTORY]
        self._emcy(int(code), error_register(code))

    def _emcy(self, code: int, register: int) -> None:
        """EMCY, unless the node is stopped (CiA 301) or a master made 0x1014 invalid."""
        if self.nmt != STOPPED and not self.value(0x1014) & VALID:
            self.node.emcy.send(code, register)

    @property
    def makes_torque(self) -> bool:
        return self.state is State.OPERATION_ENABLED and self.mode == CST and not self.controlword & HALT

    # ------------------------------------------------------------------------------------ the plant
    def follow_plant(self, s: Mapping[str, float], counts_per_rev: int) -> None:
        self.position = int(s["Position"])
        self.velocity = round(s["Velocity"] * counts_per_rev / (2.0 * math.pi))
        self.powered = bool(s["BusPowered"])
        faults = plant_faults(s)
        if self.forced_error:
            self.fault(self.forced_error)
        elif faults:
            self.fault(ERROR_CODE[faults[0]])  # one error register: the most fundamental fault
        elif self.state is State.OPERATION_ENABLED and not s["Enabled"]:
            self.fault(ErrorCode.POWER_STAGE_OFF)  # off without a controlword: the permission line

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


def _format(od: ODVariable) -> str:
    """An object's struct format character(s), little-endian as CANopen sends them."""
    assert od.data_type is not None  # every mappable object of the EDS has one
    return od.STRUCT_TYPES[od.data_type].format.lstrip("<")


def emulate(devices: Devices, counts_per_rev: int, tick_hz: float) -> Cia402Drives:
    return Cia402Drives(devices, counts_per_rev, tick_hz)
