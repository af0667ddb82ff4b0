"""Protocol faults of a device profile (docs/devices.md): a drive misbehaves in its own protocol's terms.

They act on the rig's emulated devices of that profile, found among the rig node's translators by their
`profile` name (so this room imports nothing of hil/devices); on a bench of another profile they are
refused before the run.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Protocol, cast

from drivers.devices import ProfileNode
from drivers.devices.profile import find_profile
from hil.faults.base import Bound, FaultError, FaultSpec, FaultState, FaultTarget, Motor


class OdriveAxes(Protocol):
    """What the odrive faults ask of the emulated axes (hil/devices/odrive.py)."""

    def axis_error(self, motor: int, error: int) -> None: ...
    def heartbeat_loss(self, motor: int, lost: bool) -> None: ...
    def disarm(self, motor: int) -> None: ...


class Cia402Drives(Protocol):
    """What the cia402 faults ask of the emulated drives (hil/devices/cia402/translator.py)."""

    def fault(self, motor: int, code: int) -> None: ...
    def nmt_stop(self, motor: int) -> None: ...
    def sync_lost(self, motor: int, lost: bool) -> None: ...
    def sdo_abort(self, motor: int, code: int) -> None: ...


class XsensImu(Protocol):
    """What the xsens faults ask of the emulated IMU (hil/devices/xsens.py)."""

    def sample_counter_frozen(self, frozen: bool) -> None: ...


class DeviceFault(FaultSpec, frozen=True, kw_only=True):
    """A fault of a device in its device profile's protocol: the supervisor must see it within 100 ms of
    its effect on the wire."""

    profile: ClassVar[str] = ""
    detect_within: ClassVar[float] = 0.1

    def validate(self, rig: FaultTarget) -> None:
        self.emulation(rig)

    def emulation(self, rig: FaultTarget) -> object:
        translators = rig.can.translators if isinstance(rig.can, ProfileNode) else ()
        for translator in translators:
            if translator.profile == self.profile:
                return translator
        device = "IMU" if find_profile(self.profile).kind == "imu" else "drives"
        key = "imu" if device == "IMU" else "drives"
        raise FaultError(
            f"{self.kind}: needs a bench whose {device} speak {self.profile!r} ([devices] {key} = "
            f'"{self.profile}", docs/devices.md)'
        )


class OdriveFault(DeviceFault, frozen=True, kw_only=True):
    """A fault of drive `motor`'s ODrive axis."""

    profile: ClassVar[str] = "odrive"
    motor: Motor = 1

    def axes(self, rig: FaultTarget) -> OdriveAxes:
        return cast(OdriveAxes, self.emulation(rig))


class OdriveAxisError(OdriveFault, frozen=True, tag="odrive.axis_error"):
    """Drive `motor`'s ODrive axis raises `error` (default DRV_FAULT, 0x20: its gate driver failed) and
    disarms; the error stays active, whatever Clear_Errors says, until the fault ends."""

    error: Annotated[int, Bound(1, (1 << 32) - 1, why="ODrive's 32-bit axis error field (0: no error)")] = (
        0x20
    )

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.axes(rig).axis_error(self.motor - 1, self.error)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.axes(rig).axis_error(self.motor - 1, 0)


class OdriveHeartbeatLoss(OdriveFault, frozen=True, tag="odrive.heartbeat_loss"):
    """Drive `motor`'s ODrive axis stops sending its heartbeat (its encoder estimates go on)."""

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.axes(rig).heartbeat_loss(self.motor - 1, True)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.axes(rig).heartbeat_loss(self.motor - 1, False)


class OdriveDisarm(OdriveFault, frozen=True, tag="odrive.disarm"):
    """Drive `motor`'s ODrive axis drops to IDLE unasked, with no active error (a host re-arms it)."""

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.axes(rig).disarm(self.motor - 1)


class Cia402Fault(DeviceFault, frozen=True, kw_only=True):
    """A fault of drive `motor`, a CiA 402 drive on CANopen."""

    profile: ClassVar[str] = "cia402"
    motor: Motor = 1

    def drives(self, rig: FaultTarget) -> Cia402Drives:
        return cast(Cia402Drives, self.emulation(rig))


class Cia402DriveFault(Cia402Fault, frozen=True, tag="cia402.fault"):
    """Drive `motor` enters FAULT with EMCY `code` (0x603F; default 0xFF02, manufacturer specific: a
    drive-internal fault; 0x3220 is a DC-link under-voltage) and holds it while the fault lasts: a fault
    reset does not clear it until the fault ends."""

    code: Annotated[int, Bound(1, 0xFFFF, why="a 16-bit EMCY error code, object 0x603F (0: no error)")] = (
        0xFF02
    )

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).fault(self.motor - 1, self.code)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).fault(self.motor - 1, 0)


class Cia402NmtStop(Cia402Fault, frozen=True, tag="cia402.nmt_stop"):
    """Drive `motor` goes to NMT STOPPED unasked, as if a master had stopped it: no PDO, no SDO, its
    heartbeat says STOPPED (an NMT start brings it back)."""

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).nmt_stop(self.motor - 1)


class Cia402SyncLost(Cia402Fault, frozen=True, tag="cia402.sync_lost"):
    """Drive `motor` stops seeing SYNC: its SYNC-triggered TPDOs stop while its heartbeat goes on and its
    RPDOs (transmission type 255, acted on at reception per CiA 301) still act."""

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).sync_lost(self.motor - 1, True)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).sync_lost(self.motor - 1, False)


class Cia402SdoAbort(Cia402Fault, frozen=True, tag="cia402.sdo_abort"):
    """Drive `motor` answers every SDO request with abort `code` (default 0x08000022: not in the present
    device state) while the fault lasts; its PDOs go on."""

    code: Annotated[int, Bound(1, (1 << 32) - 1, why="a 32-bit SDO abort code (CiA 301)")] = 0x08000022

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).sdo_abort(self.motor - 1, self.code)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.drives(rig).sdo_abort(self.motor - 1, 0)


class XsensSampleCounterFrozen(DeviceFault, frozen=True, tag="xsens.sample_counter_frozen"):
    """The Xsens IMU's SampleTime and GroupCounter stop while its values go on (a stuck firmware pipeline
    repeating its group header); without E2E on the IMU, a host sees it as groups that do not advance."""

    profile: ClassVar[str] = "xsens"

    def imu(self, rig: FaultTarget) -> XsensImu:
        return cast(XsensImu, self.emulation(rig))

    def start(self, rig: FaultTarget, state: FaultState) -> None:
        self.imu(rig).sample_counter_frozen(True)

    def stop(self, rig: FaultTarget, state: FaultState) -> None:
        self.imu(rig).sample_counter_frozen(False)


FAULTS: tuple[type[FaultSpec], ...] = (
    OdriveAxisError,
    OdriveHeartbeatLoss,
    OdriveDisarm,
    Cia402DriveFault,
    Cia402NmtStop,
    Cia402SyncLost,
    Cia402SdoAbort,
    XsensSampleCounterFrozen,
)
