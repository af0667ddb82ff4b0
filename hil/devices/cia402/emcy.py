"""EMCY (CiA 301) of an emulated drive: the error register of an error code, the error history's length
(0x1003) and the EMCY producer (python-canopen's, sending unless the node is stopped or 0x1014 invalid)."""

from __future__ import annotations

from drivers.devices.cia402 import ERROR_REGISTER, ErrorCode
from hil.devices.cia402.nmt import STOPPED
from hil.devices.cia402.objects import VALID, DriveObjects

HISTORY = 8
"""0x1003's standard error fields."""


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


class EmcyProducer(DriveObjects):
    """A drive's EMCY producer."""

    def _emcy(self, code: int, register: int) -> None:
        """EMCY, unless the node is stopped (CiA 301) or a master made 0x1014 invalid."""
        if self.nmt != STOPPED and not self.value(0x1014) & VALID:
            self.node.emcy.send(code, register)
