"""PDOs (CiA 301) of an emulated drive: compiled from the communication and mapping parameters a master
writes (checked as CiA 301 asks), TPDOs sent at SYNC or on change, RPDOs taken on reception; only in
OPERATIONAL."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

import can
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from drivers.can_codec import DRIVE_FEEDBACK, DRIVE_TORQUE
from drivers.devices.cia402 import State
from hil.devices.cia402.nmt import OPERATIONAL
from hil.devices.cia402.objects import EXTENDED, NO_RTR, VALID, DriveObjects
from hil.devices.cia402.sdo import Abort

SUPPORTED_TPDO_TYPES = frozenset((0, *range(1, 241), 254, 255))
"""0 acyclic synchronous, 1-240 every n-th SYNC, 254/255 event-driven. 252/253 (on RTR only) are not
emulated: the rig's node drops remote frames."""
SUPPORTED_RPDO_TYPES = frozenset((254, 255))
"""Acted on at reception. 0-240 (taken at the next SYNC) are not emulated: the rig hands a drive's command
to the plant when its frame arrives."""
TORQUE_OBJECTS = frozenset((0x6077, 0x6078))
"""Objects the plant samples with DRIVEn_TORQUE (every 4th tick): a TPDO of only these passes for it."""


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


class Pdos(DriveObjects):
    """A drive's PDOs: their parameters checked and compiled, the TPDOs due, the RPDOs taken."""

    tpdos: list[Pdo]
    active: list[Pdo]
    rpdos: dict[int, Pdo]

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


def _format(od: ODVariable) -> str:
    """An object's struct format character(s), little-endian as CANopen sends them."""
    assert od.data_type is not None  # every mappable object of the EDS has one
    return od.STRUCT_TYPES[od.data_type].format.lstrip("<")
