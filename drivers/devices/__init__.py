"""Device profiles: how the drives and the IMU appear on the wire (docs/devices.md).

The controller's and the supervisor's logic reads and writes the contract's logical messages
(`DRIVEn_FEEDBACK`, `DRIVEn_TORQUE`, `DRIVEn_COMMAND`, `IMU_*`). A profile other than `pure` puts a
`Translator` between that logic and the bus: a `ProfileNode` sends a logical message as the device's own
frames and turns the device's frames back into logical ones, so only the node knows the wire format.
The contract's own frames (SYNC, CONTROLLER_HEARTBEAT, SUPERVISOR_*) are the same on every profile.

Translators come in two kinds per profile: the host's (what a controller or a supervisor speaks: this
package) and the device's (the rig's emulated drives: hil/devices/). `pure` has neither: a plain
`CanNode`, so the default profile costs nothing.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from typing import Any, Literal

import can
import msgspec

from drivers.can_bus import CanNode, Received
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MOTOR_OF, Catalog, MessageName
from drivers.devices.profile import PURE, Host, find_profile, profile_of

Role = Literal["controller", "supervisor"]


class OdriveOptions(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Three ODrive axes on CAN Simple (firmware 0.6, ODrive's own DBC)."""

    node_ids: tuple[int, int, int] = (1, 2, 3)
    """Each motor's axis node id (motor 1 first); frame id = node_id << 5 | command id, so a node owns the
    32 ids from node_id << 5 and must not own a contract frame that stays on the bus (node 0 holds the
    supervisor's frames 0x010-0x013, node 4 SYNC 0x080)."""
    encoder_ms: float = 2.5
    """Get_Encoder_Estimates period (0: only on RTR). Rounded to whole ticks."""
    heartbeat_ms: float = 10.0
    """Heartbeat period (the firmware's default is 100 ms; a balancing robot sets it shorter)."""
    torques: bool = True
    """Get_Torques cyclic at 100 Hz (the measured torque the supervisor checks); False: only on RTR."""
    control_mode: Literal["torque", "velocity", "position"] = "torque"
    """The axes' control mode at power-up (as configured before the run; Set_Controller_Mode changes it)."""
    bus_voltage: float = 48.0
    """V on the DC bus while the contactor is closed (Get_Bus_Voltage_Current, vbus_voltage)."""
    torque_constant: float = 0.0827
    """Nm/A at power-up (axis0.config.motor.torque_constant: 8.27 / KV, a 100 KV motor): Iq = torque / it."""
    phase_resistance: float = 0.05
    """Ohm: the motor's copper loss, 1.5 R Iq^2, in Get_Powers' Electrical_Power and the bus current."""
    endpoints: str = ""
    """A lab's own flat_endpoints.json for firmware 0.6.10 (ODrive publishes one per firmware and board):
    the endpoints the emulation serves take their ids and types from it. Empty: the emulation's own ids
    (hil/devices/odrive.py ENDPOINTS; docs/devices.md says why)."""

    def __post_init__(self) -> None:
        if len(set(self.node_ids)) != 3 or not all(0 <= n <= 62 for n in self.node_ids):
            raise ValueError("node_ids: three different node ids in 0..62 (63 is CAN Simple's broadcast id)")
        if min(self.encoder_ms, self.heartbeat_ms) < 0:
            raise ValueError("encoder_ms, heartbeat_ms: >= 0 (0: only on request)")
        if min(self.bus_voltage, self.torque_constant) <= 0 or self.phase_resistance < 0:
            raise ValueError("bus_voltage, torque_constant: > 0; phase_resistance: >= 0")


class Cia402Options(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Three CiA 402 drives on CANopen (configs/devices/cia402.eds) in cyclic synchronous torque."""

    node_ids: tuple[int, int, int] = (1, 2, 3)
    """Each motor's CANopen node id (motor 1 first), 1..127; a node owns EMCY 0x080+id, PDOs 0x180+id ..
    0x500+id, SDO 0x580/0x600+id and NMT error control 0x700+id, none of which may be a contract frame that
    stays on the bus (node 10's TPDO1-3 would be the IMU's 0x18A/0x28A/0x38A, node 32's heartbeat
    CONTROLLER_HEARTBEAT 0x720)."""
    heartbeat_ms: float = 10.0
    """Producer heartbeat time (0x1017) at power-up; rounded to whole ticks (0: none)."""
    vendor_id: int | None = None
    """0x1018 sub 1, the identity a lab's master checks at boot-up (its real drives'); None: the EDS's
    0xAFFF0000, in the range CiA reserves, which no real device carries. The serial number is the node id."""
    product_code: int | None = None
    """0x1018 sub 2; None: the EDS's (402)."""
    revision_number: int | None = None
    """0x1018 sub 3; None: the EDS's (0x00020000)."""

    def __post_init__(self) -> None:
        if len(set(self.node_ids)) != 3 or not all(1 <= n <= 127 for n in self.node_ids):
            raise ValueError("node_ids: three different node ids in 1..127")
        if not 0 <= self.heartbeat_ms <= 65535:
            raise ValueError("heartbeat_ms: 0..65535 (0: no heartbeat)")
        for name in ("vendor_id", "product_code", "revision_number"):
            value = getattr(self, name)
            if value is not None and not 0 <= value <= 0xFFFFFFFF:
                raise ValueError(f"{name}: 0..0xFFFFFFFF (a U32 of 0x1018)")


class XsensOptions(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """An Xsens MTi 600-series IMU on its CAN output (configs/devices/xsens_mti.dbc)."""

    base_id: int = 0x100
    """Added to each message's XCID to make its 11-bit frame id (the device's own default is 0: the XCIDs
    themselves, where StatusWord 0x011 would be the contract's OPERATOR_ESTOP and EulerAngles 0x022 an
    ODrive node 1 id). No id may be a contract frame that stays on the bus or a drive profile's frame."""
    rate_hz: float = 400.0
    """Output rate of the data group (every tick at 400 Hz); rounded to whole ticks."""

    def __post_init__(self) -> None:
        if not 0 <= self.base_id <= 0x7FF - max(XSENS_XCIDS.values()):
            raise ValueError(f"base_id: 0..0x{0x7FF - max(XSENS_XCIDS.values()):03X} (11-bit ids)")
        if self.rate_hz <= 0:
            raise ValueError("rate_hz: > 0")


XSENS_XCIDS = {
    "Error": 0x001,
    "SampleTime": 0x005,
    "GroupCounter": 0x006,
    "StatusWord": 0x011,
    "EulerAngles": 0x022,
    "RateOfTurn": 0x032,
    "Acceleration": 0x034,
}
"""The Xsens CAN messages the xsens profile puts on the wire, by XCID (configs/devices/xsens_mti.dbc)."""

CANOPEN_FUNCTIONS = (0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480, 0x500, 0x580, 0x600, 0x700)
"""CiA 301's predefined connection set: a node's COB-IDs are these + node id."""


class Devices(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Which device profile the drives and the IMU speak (a bench's `[devices]`): `pure` or a profile
    installed in the entry-point group `pure_hil.devices` (drivers/devices/profile.py)."""

    drives: str = PURE
    imu: str = PURE
    odrive: OdriveOptions = OdriveOptions()
    cia402: Cia402Options = Cia402Options()
    xsens: XsensOptions = XsensOptions()
    settings: dict[str, dict[str, Any]] = {}
    """`[devices.settings.<profile>]`: the settings of a profile that has no table of its own above (a lab's
    profile), checked against that profile's options type."""

    @property
    def stage_read_back(self) -> bool:
        """The drives' Enabled reads back their power stage itself (pure's drives). On ODrive and CiA 402 it
        is the firmware's state, which a power stage that failed on does not change: a supervisor must then
        open the main contactor on every e-stop, not only when a drive does not confirm it is off."""
        return self.drives == PURE

    def __post_init__(self) -> None:
        profiles = [p for p in (profile_of(self.drives, "drives"), profile_of(self.imu, "imu")) if p]
        for name in self.settings:
            if isinstance(getattr(self, name, None), msgspec.Struct):
                raise ValueError(f"settings.{name}: the {name} profile's settings are [devices.{name}]")
            if name not in self.profiles:
                raise ValueError(f"settings.{name}: not a profile this bench's drives or imu speak")
            self.options(name)
        for profile in profiles:
            profile.check(self)

    def options(self, profile: str) -> msgspec.Struct:
        """Profile `profile`'s settings on this bench (its `[devices.<profile>]` or
        `[devices.settings.<profile>]`, else its defaults); ValueError names the field and the bound."""
        own = getattr(self, profile, None)
        if isinstance(own, msgspec.Struct):
            return own
        try:
            return msgspec.convert(self.settings.get(profile, {}), find_profile(profile).options)
        except msgspec.ValidationError as exc:
            raise ValueError(f"settings.{profile}: {exc}") from exc

    @property
    def profiles(self) -> tuple[str, ...]:
        """The profiles other than `pure` on this bench, the drives' first: each has its translators."""
        return tuple(p for p in (self.drives, self.imu) if p != PURE)

    @property
    def pure(self) -> bool:
        """Every device speaks the contract's own frames: no translation anywhere."""
        return self.drives == PURE and self.imu == PURE


@functools.cache
def contract_ids(drives: bool, imu: bool) -> dict[str, int]:
    """The contract frames on the bus whatever the profile, plus the drives' and the IMU's where those are
    `pure`: message -> frame id."""
    devices = {*DRIVE_COMMAND, *DRIVE_FEEDBACK, *DRIVE_TORQUE} if not drives else set()
    if not imu:
        devices |= {MessageName.IMU_ATTITUDE, MessageName.IMU_RATE, MessageName.IMU_ACCEL}
    return {c.name: c.frame_id for c in Catalog() if c.name not in devices}


class Translator:
    """Between logical messages and one device family's frames. A `ProfileNode` calls it; a profile
    overrides `outgoing` and `incoming`, and keeps what the node tells everyone: the node it works for, the
    tick of the last SYNC, whether the supervisor's takeover holds the drives."""

    names: frozenset[str] = frozenset()
    """Logical messages it sends in its own frames."""
    frame_ids: frozenset[int] = frozenset()
    """Standard frame ids it reads (remote frames included)."""
    sends: frozenset[int] = frozenset()
    """Standard frame ids it sends (a replay tells a controller's answer from the rig's frames by them)."""
    profile: str = ""
    """The device profile (its name in a bench's `[devices]`)."""

    def __init__(self) -> None:
        self.node: ProfileNode | None = None
        self.tick = 0
        """SYNC's Tick, sent or read last (a command in a protocol without one is tagged with it)."""
        self.takeover = False
        """The last trusted SUPERVISOR_ESTOP says the recovery law holds the drives."""

    def bind(self, node: ProfileNode) -> None:
        """The node it works for (to send replies and contract frames with)."""
        self.node = node

    def outgoing(self, name: str, values: Mapping[str, float]) -> Iterable[can.Message]:
        """The frames that carry logical message `name` now (maybe none)."""
        return ()

    def incoming(self, msg: can.Message) -> Received | None:
        """A frame of its family -> the logical message it carries, or None (state only, or a reply sent)."""
        return None

    def observe(self, rx: Received) -> None:
        """Every contract frame the node read (SYNC, the supervisor's frames)."""
        if rx.name == MessageName.SYNC:
            self.tick = int(rx.signals["Tick"])
        elif rx.name == MessageName.SUPERVISOR_ESTOP and rx.ok:
            self.takeover = bool(rx.signals["Takeover"])

    def on_sync(self, tick: int) -> None:
        """The node sent SYNC(tick)."""
        self.tick = tick

    def frame_id_as(self, msg: can.Message, name: str) -> int:
        """The id under which `msg`, a frame of one of its messages, passes for the same frame of message
        `name` (a node impersonating another: can.masquerade). A profile that knows how overrides it."""
        raise ValueError(f"the {self.profile or 'device'} profile cannot send a frame as {name}")


class DriveHost(Translator):
    """The host side of three drives of one profile, for a controller or a supervisor: the contract's
    DRIVEn_COMMAND, the supervisor's e-stop and its recovery law's torques, each in the drives' own frames.
    A profile gives `_command` (one drive's torque and enable) and `_stop` (what an e-stop's rising edge
    sends one drive)."""

    def __init__(self, role: Role) -> None:
        super().__init__()
        self.role = role
        self.names = (
            frozenset({MessageName.SUPERVISOR_ESTOP, MessageName.SUPERVISOR_RECOVERY})
            if role == "supervisor"
            else frozenset(DRIVE_COMMAND)
        )
        self._estop = False

    def outgoing(self, name: str, values: Mapping[str, float]) -> list[can.Message]:
        if name == MessageName.SUPERVISOR_ESTOP:
            return self._estop_frames(values)
        if name == MessageName.SUPERVISOR_RECOVERY:
            torques = (values["Torque1"], values["Torque2"], values["Torque3"])
            return [m for i, torque in enumerate(torques) for m in self._recovery(i, torque)]
        if self.takeover:
            return []  # one master at a time (docs/contract.md): the recovery law's torques hold the drives
        return self._command(MOTOR_OF[name], float(values["Torque"]), bool(values["Enable"]))

    def _estop_frames(self, values: Mapping[str, float]) -> list[can.Message]:
        """The contract's SUPERVISOR_ESTOP (the drives' permission line) and, on an e-stop's rising edge, the
        profile's own stop to every drive."""
        assert self.node is not None
        frames = [self.node.contract_frame(MessageName.SUPERVISOR_ESTOP, values)]
        estop = bool(values["Estop"])
        if estop and not self._estop:
            frames += [m for i in range(3) for m in self._stop(i)]
        self._estop = estop
        return frames

    def _recovery(self, index: int, torque: float) -> list[can.Message]:
        """The recovery law's torque for drive `index`."""
        return self._command(index, torque, True)

    def _command(self, index: int, torque: float, enable: bool) -> list[can.Message]:
        raise NotImplementedError

    def _stop(self, index: int) -> list[can.Message]:
        raise NotImplementedError


class ProfileNode(CanNode):
    """A CanNode whose drive and IMU messages go through translators (python-can's BusABC shape: the public
    send/decode own the cross-cutting work, the translators are the small hooks)."""

    def __init__(
        self,
        bus: can.BusABC,
        translators: Iterable[Translator],
        catalog: Catalog | None = None,
        name: str = "node",
    ):
        super().__init__(bus, catalog, name)
        self.translators = tuple(translators)
        self._out = {n: t for t in self.translators for n in t.names}
        self._in = {i: t for t in self.translators for i in t.frame_ids}
        for t in self.translators:
            t.bind(self)

    def send(self, name: str, values: Mapping[str, float]) -> bool:
        translator = self._out.get(name)
        if name == MessageName.SYNC:
            for t in self.translators:
                t.on_sync(int(values["Tick"]))
        if translator is None:
            return super().send(name, values)
        sent = True
        for msg in translator.outgoing(name, values):
            for m in [msg] if self.tx_hook is None else self.tx_hook(name, msg):
                sent = self.transmit(name, m) and sent
        return sent

    def translator_of(self, name: str) -> Translator | None:
        """The translator that sends logical message `name` (None: a contract frame)."""
        return self._out.get(name)

    def contract_frame(self, name: str, values: Mapping[str, float]) -> can.Message:
        """A contract message as this node would send it (E2E sealed): for a translator that adds to it."""
        return self.message(name, values)

    def reply(self, name: str, msg: can.Message) -> None:
        """A frame a translator answers with at once (an RTR reply), under logical `name`."""
        for m in [msg] if self.tx_hook is None else self.tx_hook(name, msg):
            self.transmit(name, m)

    def decode(self, msg: can.Message) -> Received | None:
        translator = None if msg.is_extended_id or msg.is_error_frame else self._in.get(msg.arbitration_id)
        if translator is None:
            rx = super().decode(msg)
            if rx is not None:
                for t in self.translators:
                    t.observe(rx)
            return rx
        try:
            rx = translator.incoming(msg)
        except ValueError:  # a frame of the family that does not decode: counted and logged, never raised
            self._reject("malformed_device_frame", msg)
            return None
        if rx is not None:
            self.stats.received[rx.name] += 1
        return rx


def _host(profile: str) -> Host:
    """A profile's host-side translator (the drives' or the IMU's), imported only when a bench names it."""
    return find_profile(profile).host


def controller_frame_ids(devices: Devices, counts_per_rev: int = 8192) -> frozenset[int]:
    """The ids a controller sends its drive commands in on these devices (the contract's heartbeat aside)."""
    if devices.drives == PURE:
        return frozenset(Catalog()[name].frame_id for name in DRIVE_COMMAND)
    return _host(devices.drives)(devices, counts_per_rev, "controller").sends


def host_node(
    bus: can.BusABC, devices: Devices, counts_per_rev: int, role: Role, name: str | None = None
) -> CanNode:
    """The node a controller or a supervisor reads and writes the bus through on this bench's devices."""
    name = name or role
    if devices.pure:
        return CanNode(bus, name=name)
    translators = [_host(profile)(devices, counts_per_rev, role) for profile in devices.profiles]
    return ProfileNode(bus, translators, name=name)
