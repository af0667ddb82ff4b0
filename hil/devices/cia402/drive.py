"""One emulated CiA 402 drive: a python-canopen LocalNode with the project's EDS, its CiA 301 layers (NMT,
SDO, PDOs, EMCY: their modules here) and what CiA 402 and the plant give it: the state machine in cyclic
synchronous torque, the statusword, the torque it makes and the faults the plant's drive state raises."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import canopen

from drivers.devices import Cia402Options
from drivers.devices.cia402 import ErrorCode, State, eds_path
from hil.devices.cia402.emcy import HISTORY, EmcyProducer, error_register
from hil.devices.cia402.network import RigNetwork
from hil.devices.cia402.nmt import NmtSlave
from hil.devices.cia402.p402 import FAULTS, makes_torque, next_state, status_word
from hil.devices.cia402.pdo import Pdos
from hil.devices.cia402.sdo import SdoServer
from hil.devices.plant_drive import PlantFault, plant_faults

ERROR_CODE = {
    PlantFault.UNPOWERED: ErrorCode.DC_LINK_UNDER_VOLTAGE,
    PlantFault.WATCHDOG: ErrorCode.COMMUNICATION,
    PlantFault.POWER_STAGE: ErrorCode.POWER_SECTION,
}
"""The error code (0x603F, EMCY) each fault of the plant's drive state raises."""


class Drive(NmtSlave, SdoServer, Pdos, EmcyProducer):
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

    # ---------------------------------------------------------------- live objects of the 402 profile
    def statusword(self) -> int:
        return status_word(
            self.state, self.powered, self.makes_torque and abs(self.target) > self.torque_limit()
        )

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

    def torque_nm(self) -> float:
        """The torque the power stage is told to make, Nm."""
        return self.torque_demand() * self.params[0x6076] * 1e-6

    # ------------------------------------------------------- the state machine (p402.py), faults
    def apply_controlword(self, cw: int) -> None:
        rising_reset = bool(cw & 0x80) and not self.controlword & 0x80
        self.controlword = cw
        s = self.state
        self.state = next_state(
            s,
            cw,
            fault_reset=rising_reset and self.powered and not self.forced_error,
            quick_stop_stays=self.params[0x605A] < 0,
        )
        if s in FAULTS and self.state is not s:
            self.error = ErrorCode.NONE
            self._emcy(0x0000, 0x00)  # error reset

    def fault(self, code: int) -> None:
        if self.state is State.FAULT:
            return
        self.state, self.error = State.FAULT, code
        self.history = [code & 0xFFFF, *self.history][:HISTORY]
        self._emcy(int(code), error_register(code))

    @property
    def makes_torque(self) -> bool:
        return makes_torque(self.state, self.mode, self.controlword)

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
