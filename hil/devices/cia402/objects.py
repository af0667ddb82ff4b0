"""What every CANopen layer of an emulated drive shares: its LocalNode's object dictionary and the drive's
state, declared once for the layers (nmt.py, sdo.py, pdo.py, emcy.py) that drive.py's Drive combines.

The layers are mixins of one object rather than parts holding a reference to it: they all read and write
the same object dictionary and drive state (an SDO write changes a PDO, an RPDO the controlword, a fault
the error history), so their methods stay as they were in one class, and so does the behaviour.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import canopen
from canopen.objectdictionary import ODVariable

from drivers.devices import Cia402Options
from drivers.devices.cia402 import State

if TYPE_CHECKING:
    from hil.devices.cia402.network import RigNetwork

VALID, NO_RTR, EXTENDED = 0x80000000, 0x40000000, 0x20000000
"""A COB-ID entry's bits 31 (0: the PDO or EMCY exists), 30 (TPDO: 1 = no RTR), 29 (1: a 29-bit id)."""


class DriveObjects:
    """One drive's object dictionary (`_od`, `value`) and the state its layers share."""

    index: int
    node_id: int
    node: canopen.LocalNode
    network: RigNetwork
    options: Cia402Options
    tick_s: float
    ticks: int
    """Ticks (SYNCs) this drive has seen: its SYNC counter and its clock."""
    fed: set[str]
    sync_lost: bool
    sdo_abort: int
    pdos_written: bool
    rpdo_result: tuple[float, bool] | None
    _live: dict[int, Callable[[], int]]
    state: State
    error: int
    history: list[int]
    controlword: int
    target: int
    mode: int
    params: dict[int, int]

    if TYPE_CHECKING:
        # What one layer calls of another (each defined once, in its own layer's module).
        @property
        def nmt(self) -> str: ...  # nmt.py

        def compile_pdos(self) -> None: ...  # pdo.py

        def _check_pdo_write(self, index: int, subindex: int, value: int) -> None: ...  # pdo.py

        def apply_controlword(self, cw: int) -> None: ...  # drive.py

        def torque_nm(self) -> float: ...  # drive.py

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
