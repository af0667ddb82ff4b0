"""The tick loop (DESIGN.md §3): the plant on one side, the controller under test on the wire on the other.

One tick k:
  1. the plant advances one tick under the torques the drives hold;
  2. sensors sample the truth;
  3. the rig sends drive feedback and IMU frames, publishes the seat wrench (and, until the supervisor
     exists, the SC command of the schedule), then SYNC(k);
  4. lockstep: it waits for the three drive commands tagged k (bounded by a wall-clock guard: a miss is
     counted, never a hang) and hands them to the drives;
  5. the recorder keeps the tick.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

from drivers.can_bus import CanNode
from drivers.schemas import ControllerTelemetry, ScCommand, TesWrench, encode
from drivers.zenoh_link import ZenohLink
from plant.ballbot import Plant
from plant.drives import DriveState

TICK_MODULO = 1 << 16
COMMANDS = {"DRIVE1_COMMAND": 0, "DRIVE2_COMMAND": 1, "DRIVE3_COMMAND": 2}
FEEDBACK = ("DRIVE1_FEEDBACK", "DRIVE2_FEEDBACK", "DRIVE3_FEEDBACK")
TORQUE = ("DRIVE1_TORQUE", "DRIVE2_TORQUE", "DRIVE3_TORQUE")
TORQUE_EVERY = 4  # DRIVEn_TORQUE at 100 Hz on a 400 Hz tick (the DBC's GenMsgCycleTime)
SC_REPEAT_EVERY = 20  # ticks between repeats of an unchanged SC command (keeps it fresh for the controller)


@dataclass(frozen=True, slots=True)
class ScStep:
    """From time `at` (s) on, the shared controller asks for `mode` (free, idle, limit) with `cap` (m/s)."""

    at: float
    mode: str
    cap: float = 0.0


@dataclass(slots=True)
class TickStats:
    ticks: int = 0
    missing_commands: int = 0
    """Commands tagged with the current tick that did not arrive within the guard."""
    late_commands: int = 0
    """Commands tagged with an older tick (arrived after their tick was given up)."""
    controller_states: Counter[int] = field(default_factory=Counter)


class ControllerSilent(RuntimeError):
    """Lockstep: the controller answered no SYNC for several ticks in a row."""


MAX_SILENT_TICKS = 3


class Rig:
    def __init__(
        self,
        plant: Plant,
        can: CanNode,
        link: ZenohLink,
        sc_schedule: list[ScStep] | tuple[ScStep, ...] = (ScStep(0.0, "free"),),
        command_guard: float = 1.0,
    ):
        self.plant, self.can, self.link = plant, can, link
        self.keys = link.keys
        self.sc_schedule = sorted(sc_schedule, key=lambda s: s.at)
        self.command_guard = command_guard
        self.stats = TickStats()
        self.telemetry = link.subscribe(self.keys.controller_telemetry, ControllerTelemetry, capacity=1 << 16)
        link.declare_publishers([self.keys.tes_wrench, self.keys.sc_command])
        self._sc_seq = 0
        self._sc_last: ScStep | None = None
        self._sc_sent_tick = -SC_REPEAT_EVERY
        self._silent_ticks = 0
        self.zenoh_inputs: list[tuple[int, str, bytes]] = []
        """Every (tick, key, payload) put for the controller, in order (what `pure-hil replay` replays)."""

    def wait_for_controller(self, timeout: float = 10.0) -> bool:
        """The controller's zenoh subscriptions are in place (the rig's publishers have a match)."""
        deadline = time.monotonic() + timeout
        pub = self.link.publisher(self.keys.tes_wrench)
        while not pub.matching_status.matching:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    def tick(self, deadline: float | None = None, lockstep: bool = True) -> None:
        """One tick; wait for the controller's answer until `deadline` (time.monotonic()).

        Lockstep also waits for the heartbeat that follows the commands, so every frame of tick k is on
        the bus before tick k + 1 starts (a deterministic CAN log).
        """
        plant = self.plant
        plant.step()
        k = plant.tick
        # zenoh first: its delivery to the controller overlaps with sending the CAN frames.
        self._publish_sc(k)
        self._publish_tes(k)
        self._send_sensors(k)
        self.can.send("SYNC", {"Tick": k % TICK_MODULO})
        if deadline is None:
            deadline = time.monotonic() + self.command_guard
        self._collect_commands(k, deadline, lockstep)
        self.stats.ticks += 1

    # ------------------------------------------------------------------------------------------ outputs
    def _send_sensors(self, k: int) -> None:
        plant, send = self.plant, self.can.send
        feedback = plant.sample_drives()
        for name, fb, motor in zip(FEEDBACK, feedback, plant.drives.motors, strict=True):
            send(
                name,
                {
                    "Position": fb.counts,
                    "Velocity": fb.velocity,
                    "Enabled": int(motor.state is DriveState.ENABLED),
                    "WatchdogTripped": int(motor.state is DriveState.WATCHDOG),
                },
            )
        if k % TORQUE_EVERY == 0:
            for name, fb in zip(TORQUE, feedback, strict=True):
                send(name, {"Torque": fb.torque})
        imu = plant.sample_imu()
        send(
            "IMU_ATTITUDE",
            {"Roll": imu.attitude[0], "Pitch": imu.attitude[1], "Yaw": imu.attitude[2], "Valid": 1},
        )
        send("IMU_RATE", {"RateX": imu.rate[0], "RateY": imu.rate[1], "RateZ": imu.rate[2], "Valid": 1})
        send("IMU_ACCEL", {"AccX": imu.accel[0], "AccY": imu.accel[1], "AccZ": imu.accel[2], "Valid": 1})

    def _put(self, k: int, key: str, payload) -> None:
        data = encode(payload)
        self.link.publisher(key).put(data)
        self.zenoh_inputs.append((k, key, data))

    def _publish_tes(self, k: int) -> None:
        s = self.plant.sample_tes()
        self._put(
            k,
            self.keys.tes_wrench,
            TesWrench(seq=k, stamp=self.plant.t, force=s.force, moment=s.moment, cop=s.cop),
        )

    def _publish_sc(self, k: int) -> None:
        current = None
        for step in self.sc_schedule:
            if step.at <= self.plant.t + 1e-12:
                current = step
        if current is None:
            return
        if current is self._sc_last and k - self._sc_sent_tick < SC_REPEAT_EVERY:
            return
        self._sc_seq += 1
        self._put(
            k,
            self.keys.sc_command,
            ScCommand(
                seq=self._sc_seq,
                stamp=self.plant.t,
                mode=current.mode,
                speed_cap=current.cap,
                source="scenario",
            ),
        )
        self._sc_last, self._sc_sent_tick = current, k

    # ------------------------------------------------------------------------------------------- inputs
    def _collect_commands(self, k: int, deadline: float, wait_heartbeat: bool) -> None:
        tag = k % TICK_MODULO
        pending = set(COMMANDS)
        heartbeat_due = wait_heartbeat
        drives = self.plant.drives.motors
        while pending or heartbeat_due:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self._missed(k, pending, wait_heartbeat)
                return
            rx = self.can.recv(timeout=remaining)
            if rx is None:
                continue
            if rx.name == "CONTROLLER_HEARTBEAT":
                self.stats.controller_states[int(rx.signals["State"])] += 1
                heartbeat_due = heartbeat_due and bool(pending)  # the heartbeat follows the commands
                continue
            if rx.name not in COMMANDS or not rx.ok:
                continue
            if int(rx.signals["Tick"]) != tag:
                self.stats.late_commands += 1
                continue
            drives[COMMANDS[rx.name]].set_command(
                rx.signals["Torque"], bool(rx.signals["Enable"]), self.plant.t
            )
            pending.discard(rx.name)
        self._silent_ticks = 0

    def _missed(self, k: int, pending: set[str], lockstep: bool) -> None:
        self.stats.missing_commands += len(pending)
        self._silent_ticks = self._silent_ticks + 1 if len(pending) == len(COMMANDS) else 0
        if lockstep and self._silent_ticks >= MAX_SILENT_TICKS:
            raise ControllerSilent(
                f"no drive command for {self._silent_ticks} ticks in a row (last tick {k}, "
                f"guard {self.command_guard} s each)"
            )
