"""Protocol faults of a device profile (docs/devices.md): a drive misbehaves in its own protocol's terms.

They act on the rig's emulated devices of that profile, found among the rig node's translators by their
`profile` name (so this room imports nothing of hil/devices); on a bench of another profile they are
refused before the run.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Protocol, cast

import msgspec

from drivers.devices import IMU_PROFILES
from hil.faults.base import FaultError, FaultSpec, FaultState, FaultTarget

Motor = Annotated[int, msgspec.Meta(ge=1, le=3)]


class OdriveAxes(Protocol):
    """What the odrive faults ask of the emulated axes (hil/devices/odrive.py)."""

    def axis_error(self, motor: int, error: int) -> None: ...
    def heartbeat_loss(self, motor: int, lost: bool) -> None: ...
    def disarm(self, motor: int) -> None: ...


class XsensImu(Protocol):
    """What the xsens faults ask of the emulated IMU (hil/devices/xsens.py)."""

    def sample_counter_frozen(self, frozen: bool) -> None: ...


class DeviceFault(FaultSpec, frozen=True, kw_only=True):
    """A fault of a device in its device profile's protocol: the supervisor must see it within 100 ms of
    its effect on the wire."""

    family: ClassVar[str] = "devices"
    profile: ClassVar[str] = ""
    detect_within: ClassVar[float] = 0.1

    def validate(self, rig: FaultTarget) -> None:
        self.emulation(rig)

    def emulation(self, rig: FaultTarget) -> object:
        for translator in getattr(rig.can, "translators", ()):
            if getattr(translator, "profile", "") == self.profile:
                return translator
        device = "IMU" if self.profile in IMU_PROFILES else "drives"
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

    error: Annotated[int, msgspec.Meta(gt=0, lt=1 << 32)] = 0x20

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
    XsensSampleCounterFrozen,
)
