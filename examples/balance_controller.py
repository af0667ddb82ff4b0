#!/usr/bin/env python3
"""A balancing controller for PURE written from docs/contract.md alone: the template a controller team starts
from. It imports nothing from pure-hil: python-can for the bus, cantools for the DBC, numpy for the maths.

It keeps the robot upright and still (no rider input: it reads nothing from zenoh, as a controller board on
CAN alone would). Per tick it follows the contract:
  - boot-up: CONTROLLER_HEARTBEAT with State INIT and Contract 2 every 100 ms until the first SYNC (the rig
    starts on it);
  - every frame it receives is checked (E2E CRC-8) and decoded through the DBC;
  - on SYNC(k): estimate (tilt and tilt rate from the IMU, ball rates from the three motor velocities through
    the omniwheel map), one state feedback per plane, ball torques -> motor torques, then DRIVE1..3_COMMAND
    tagged k, then CONTROLLER_HEARTBEAT (always after the commands);
  - Enable = 1 only while balancing and the supervisor's last SUPERVISOR_ESTOP says Estop 0 and Takeover 0;
    after an e-stop or a takeover it stays disabled (an operator's enable comes over zenoh, which this
    example does not read);
  - SUPERVISOR_DIAGNOSIS: an encoder it names is left out (the other two and the gyro's yaw rate give the
    ball's rates), a rate channel it names is replaced by the attitude's derivative;
  - the supervisor lost (SUPERVISOR_ESTOP silent for 50 ms, 20 ticks): it stops on its own and, standing
    still and upright for 0.3 s, disables its drives (the drives follow it meanwhile).

    python examples/balance_controller.py --can socketcan:vcan0
    pure-hil run configs/scenarios/balance.toml --controller external --can socketcan:vcan0
"""

from __future__ import annotations

import argparse
import math
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import cantools
import numpy as np

DBC = Path(__file__).resolve().parents[1] / "configs" / "can" / "pure.dbc"

# Robot geometry (docs/contract.md "Geometry").
BALL_RADIUS = 0.1145  # m
WHEEL_RADIUS = 0.0625  # m
ZENITH = math.radians(45.0)  # wheel contact angle from the vertical
AZIMUTH0 = 0.0  # wheel 1 on body +x; wheels 2 and 3 at +120 and +240 deg
MOTOR_SIGN = (1, 1, 1)
GEAR_RATIO = 8.0
TORQUE_LIMIT = 3.75  # Nm at the motor shaft

# Ball torque (Nm) per rad of tilt, rad/s of tilt rate and rad/s of ball rate, per plane: LQR with
# Q = diag(100, 1, 10), R = 0.1 on the planar model of docs/contract.md with a 60 kg rider sitting still
# (50-80 kg riders give gains within 8 %). Yaw: a rate damper.
GAINS = (540.0, 140.0, 10.5)
YAW_GAIN = 20.0  # Nm of ball yaw torque per rad/s of yaw rate

INIT, DISABLED, BALANCING = 0, 1, 3  # CONTROLLER_HEARTBEAT.State
CONTRACT = 2  # the contract version this controller speaks (docs/contract.md, Versions)
HEARTBEAT = {"Mode": 0, "FaultCode": 0, "Contract": CONTRACT}
BOOT_PERIOD = 0.1  # s between boot-up heartbeats until the first SYNC
RUN_OVER = 2.0  # s without SYNC: the run is over, back to INIT (docs/contract.md "Between runs")
TICK = 1.0 / 400  # s between SYNCs
SUPERVISOR_LOST = 20  # ticks of silence of SUPERVISOR_ESTOP: the drives' permission timeout, 50 ms
REST_SPEED, REST_TILT, REST_TICKS = 0.05, math.radians(3.0), 120  # m/s, rad, 0.3 s: at rest, drives off
NAMED = ("Encoder1", "Encoder2", "Encoder3", "RateX", "RateY")  # the diagnosis' flags this controller acts on


def motor_jacobian() -> np.ndarray:
    """Motor-shaft rates = G @ [ball rate x - body rate x, ball rate y - body rate y, -yaw rate]."""
    rho = BALL_RADIUS / WHEEL_RADIUS
    rows = []
    for i, sign in enumerate(MOTOR_SIGN):
        azimuth = AZIMUTH0 + 2.0 * math.pi * i / 3.0
        direction = (
            -math.cos(ZENITH) * math.cos(azimuth),
            -math.cos(ZENITH) * math.sin(azimuth),
            math.sin(ZENITH),
        )
        rows.append([sign * GEAR_RATIO * rho * x for x in direction])
    return np.array(rows)


G = motor_jacobian()
TO_RELATIVE = np.linalg.inv(G)  # motor rates -> ball-to-body rates
TO_MOTORS = np.linalg.inv(G.T)  # ball torques (x, y, z) -> motor torques


def crc8(data: bytes) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, no reflection, xorout 0xFF; check("123456789") = 0x4B."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


class Wire:
    """The DBC, E2E-sealed sending (alive counter + CRC over the frame id and the payload with a zero
    CRC field) and checked receiving."""

    def __init__(self, bus: can.BusABC, dbc: Path):
        self.bus = bus
        self.db = cantools.database.load_file(str(dbc))
        self.counters: dict[int, int] = {}
        self.rejected = 0

    def send(self, name: str, values: dict[str, float]) -> None:
        message = self.db.get_message_by_name(name)
        counter = self.counters.get(message.frame_id, 0)
        self.counters[message.frame_id] = (counter + 1) % 16
        values = {**values, "Counter": counter, "Crc": 0}
        data = message.encode(values)
        values["Crc"] = crc8(message.frame_id.to_bytes(2, "little") + data)
        data = message.encode(values)
        self.bus.send(can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False))

    def receive(self, msg: can.Message) -> tuple[str, dict] | None:
        """(message name, signals) of a frame that decodes and passes its CRC; None otherwise."""
        try:
            message = self.db.get_message_by_frame_id(msg.arbitration_id)
            signals = message.decode(msg.data, decode_choices=False)
        except (KeyError, ValueError, cantools.database.errors.DecodeError):
            self.rejected += 1
            return None
        if "Crc" in signals:
            cleared = bytearray(msg.data)
            crc_signal = message.get_signal_by_name("Crc")
            cleared[crc_signal.start // 8] = 0
            if crc8(msg.arbitration_id.to_bytes(2, "little") + bytes(cleared)) != signals["Crc"]:
                self.rejected += 1
                return None
        return message.name, signals


class BalanceController:
    def __init__(self, wire: Wire):
        self.wire = wire
        self.reset()

    def reset(self) -> None:
        """Everything a run leaves behind, as at power-on: INIT, nothing measured, nothing named."""
        self.state = INIT
        self.permitted = False
        self.attitude: tuple[float, float] | None = None  # roll, pitch
        self.rate: tuple[float, float, float] | None = None
        self.velocity: list[float | None] = [None, None, None]
        self.synced = False
        self.synced_at = 0.0  # time.monotonic() of the last SYNC
        self.last_tick = 0
        self.named: set[str] = set()  # what SUPERVISOR_DIAGNOSIS names faulty
        self.derivative = [0.0, 0.0]  # the attitude's derivative (roll, pitch), low-passed
        self.supervisor_tick: int | None = None
        self.still = 0  # ticks at rest while the supervisor is lost

    def frame(self, name: str, s: dict) -> None:
        if name == "IMU_ATTITUDE" and s["Valid"]:
            if self.attitude is not None:  # low-passed over ~20 ms: stands in for a faulty rate channel
                for i, now in enumerate((s["Roll"], s["Pitch"])):
                    self.derivative[i] += ((now - self.attitude[i]) / TICK - self.derivative[i]) * 0.125
            self.attitude = (s["Roll"], s["Pitch"])
        elif name == "IMU_RATE" and s["Valid"]:
            self.rate = (s["RateX"], s["RateY"], s["RateZ"])
        elif name.startswith("DRIVE") and name.endswith("_FEEDBACK"):
            self.velocity[int(name[5]) - 1] = s["Velocity"]
        elif name == "SUPERVISOR_DIAGNOSIS":
            self.named = {part for part in NAMED if s[part]}
        elif name == "SUPERVISOR_ESTOP":
            self.supervisor_tick = self.last_tick
            # Takeover: the supervisor's recovery law holds the drives; stop commanding, as after an e-stop.
            self.permitted = not (s["Estop"] or s["Takeover"])
            if not self.permitted and self.state == BALANCING:
                self.state = DISABLED  # stays disabled: a reset permits motion, it never causes it
        elif name == "SYNC":
            self.synced, self.synced_at = True, time.monotonic()
            self.last_tick = int(s["Tick"])
            self.tick(self.last_tick)

    def relative(self, rate_z: float) -> np.ndarray:
        """Ball-to-body rates (x, y, z) from the encoders, without one the supervisor named faulty."""
        bad = [i for i in range(3) if f"Encoder{i + 1}" in self.named]
        if not bad:
            return TO_RELATIVE @ np.array(self.velocity)
        others = [i for i in range(3) if i != bad[0]]
        # Each remaining motor rate less its yaw part (the third relative rate is minus the yaw rate).
        known = np.array([self.velocity[i] for i in others]) + G[others, 2] * rate_z
        x, y = np.linalg.solve(G[np.ix_(others, [0, 1])], known)
        return np.array([x, y, -rate_z])

    def torques(self) -> tuple[float, float, float]:
        roll, pitch = self.attitude
        rate_x, rate_y, rate_z = self.rate
        if "RateX" in self.named:
            rate_x = self.derivative[0]
        if "RateY" in self.named:
            rate_y = self.derivative[1]
        relative = self.relative(rate_z)
        k_tilt, k_rate, k_ball = GAINS
        # Ball rate per plane = ball-to-body rate + body rate; the roll plane turns about +x, pitch about +y.
        tau_x = k_tilt * roll + k_rate * rate_x + k_ball * (relative[0] + rate_x)
        tau_y = k_tilt * pitch + k_rate * rate_y + k_ball * (relative[1] + rate_y)
        tau_z = YAW_GAIN * rate_z  # the body yaws under -tau_z: a positive tau_z slows a positive yaw rate
        motors = TO_MOTORS @ np.array([tau_x, tau_y, tau_z])
        return tuple(float(np.clip(m, -TORQUE_LIMIT, TORQUE_LIMIT)) for m in motors)

    def tick(self, k: int) -> None:
        ready = self.attitude is not None and self.rate is not None and None not in self.velocity
        if self.state == INIT and ready:
            self.state = BALANCING
        if self.state == BALANCING and self.supervisor_lost(k):
            self.state = DISABLED  # stopped on its own: at rest, drives off
        balancing = self.state == BALANCING
        torques = self.torques() if balancing else (0.0, 0.0, 0.0)
        self.command(k, torques, balancing and self.permitted)
        self.wire.send("CONTROLLER_HEARTBEAT", {**HEARTBEAT, "State": self.state})

    def command(self, k: int, torques: tuple[float, float, float], enable: bool) -> None:
        """Tick k's motor torques to the drives: the contract's DRIVE1..3_COMMAND."""
        for i, torque in enumerate(torques, 1):
            command = {"Torque": torque if enable else 0.0, "Tick": k, "Enable": int(enable)}
            self.wire.send(f"DRIVE{i}_COMMAND", command)

    def supervisor_lost(self, k: int) -> bool:
        """True once the supervisor has been silent and the robot has stood still and upright for 0.3 s."""
        if self.supervisor_tick is None or (k - self.supervisor_tick) % 65536 <= SUPERVISOR_LOST:
            self.still = 0
            return False
        relative = self.relative(self.rate[2])
        speed = BALL_RADIUS * math.hypot(relative[0] + self.rate[0], relative[1] + self.rate[1])
        still = speed <= REST_SPEED and max(abs(a) for a in self.attitude) <= REST_TILT
        self.still = self.still + 1 if still else 0
        return self.still >= REST_TICKS

    def run(self, stop: threading.Event) -> None:
        """Serve runs until `stop`: boot-up heartbeats until a run's first SYNC; a SYNC silent for RUN_OVER
        ends the run, and the controller starts over for the next one (the rig waits for a boot-up)."""
        next_boot = time.monotonic()
        while not stop.is_set():
            if self.synced and time.monotonic() - self.synced_at > RUN_OVER:
                self.reset()
            if not self.synced and time.monotonic() >= next_boot:
                self.wire.send("CONTROLLER_HEARTBEAT", {**HEARTBEAT, "State": INIT})
                next_boot = time.monotonic() + BOOT_PERIOD
            msg = self.wire.bus.recv(timeout=0.05)
            if msg is not None and not msg.is_error_frame:
                frame = self.wire.receive(msg)
                if frame is not None:
                    self.frame(*frame)


def run(channel: str, interface: str, stop: threading.Event, wire: Callable[[can.BusABC], Wire]) -> None:
    """Balance through `wire(bus)`, the bus `interface:channel`, until `stop`."""
    bus = can.Bus(interface=interface, channel=channel or None)
    try:
        BalanceController(wire(bus)).run(stop)
    finally:
        bus.shutdown()


def command_line(doc: str) -> argparse.ArgumentParser:
    """An example's command line: `--can INTERFACE:CHANNEL`, then its own options."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--can", default="socketcan:vcan0", help="INTERFACE:CHANNEL for python-can")
    return parser


def drives_command_line(doc: str) -> argparse.ArgumentParser:
    """A drive profile's example's command line: `--can`, and `--nodes`, its three drives' CAN node ids."""
    parser = command_line(doc)
    parser.add_argument(
        "--nodes", type=int, nargs=3, default=[1, 2, 3], help="the drives' node ids, motor 1 first"
    )
    return parser


def serve(can_option: str, example: Callable[[str, str, threading.Event], object]) -> int:
    """Run `example(channel, interface, stop)` on the bus `--can` names until SIGTERM or Ctrl-C stops it."""
    interface, _, channel = can_option.partition(":")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        example(channel, interface, stop)
    except KeyboardInterrupt:
        stop.set()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = command_line(__doc__)
    parser.add_argument("--dbc", type=Path, default=DBC)
    args = parser.parse_args(argv)
    return serve(
        args.can,
        lambda channel, interface, stop: run(channel, interface, stop, lambda bus: Wire(bus, args.dbc)),
    )


if __name__ == "__main__":
    raise SystemExit(main())
