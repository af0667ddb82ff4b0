"""The SDO server (CiA 301) of an emulated drive: python-canopen's serves the transfers (expedited and
segmented); here, the objects answered live from the drive's state, the checks of a write (an abort, with
CiA 301's code, leaves everything as it was) and what it changes, and a fault's aborts."""

from __future__ import annotations

import struct

from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from drivers.devices.cia402 import EMCY
from hil.devices.cia402.objects import EXTENDED, DriveObjects

SDO_ABORT = 0x80
"""An SDO abort's command specifier (CiA 301): 0x80, index, subindex, abort code (U32)."""


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


class SdoServer(DriveObjects):
    """What a drive's SDO server reads and writes beyond python-canopen's object dictionary."""

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
