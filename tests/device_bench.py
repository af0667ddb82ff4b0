"""A profile's emulated drives in front of three plant drives, ticking on a thread at about 400 Hz (wall
clock, as real drives would): feedback and SYNC out, the hosts' frames in and onto the power stages. What
a field's own client (odrive-can, python-canopen) is tested against, without the rig."""

from __future__ import annotations

import threading
import time

from drivers.bus_config import BusConfig
from drivers.can_bus import open_bus
from drivers.can_codec import DRIVE_COMMAND, DRIVE_FEEDBACK, DRIVE_TORQUE, MessageName
from drivers.devices import ProfileNode, Translator
from plant.drives import DriveArray, DriveState
from plant.params import Drive

TICK = 0.0025
WATCHDOG = 0.5
"""s: the bench's drives' watchdog, long beside a client's 5 ms feeds (a loaded machine may starve a thread
for tens of ms; the rig's drives keep the plant's 20 ms in simulated time)."""


class DevicesOnABench:
    def __init__(self, channel: str, emulation: Translator):
        self.bus = open_bus(BusConfig(channel=channel))
        self.emulation = emulation
        self.node = ProfileNode(self.bus, [emulation], name="rig")
        self.drives = DriveArray(Drive(watchdog_timeout=WATCHDOG))
        self.t, self.k = 0.0, 0
        self.lock = threading.Lock()
        """Held for each tick: a test changes the emulation between ticks."""
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            with self.lock:
                self._tick()
            time.sleep(TICK)

    def _tick(self) -> None:
        self.k += 1
        self.t += TICK
        self.drives.advance(TICK, self.t, (0.0, 0.0, 0.0))  # a bench with the wheels held
        for name, m in zip(DRIVE_FEEDBACK, self.drives.motors, strict=True):
            self.node.send(
                name,
                {
                    "Position": 1000 * self.k,
                    "Velocity": 2.0,
                    "Enabled": int(m.state is DriveState.ENABLED),
                    "WatchdogTripped": int(m.state is DriveState.WATCHDOG),
                    "BusPowered": int(m.bus_powered),
                },
            )
        if self.k % 4 == 0:
            for name, m in zip(DRIVE_TORQUE, self.drives.motors, strict=True):
                self.node.send(name, {"Torque": m.torque})
        self.node.send(MessageName.SYNC, {"Tick": self.k % 65536})
        while (rx := self.node.recv(timeout=0.0)) is not None:
            if rx.name in DRIVE_COMMAND:
                motor = self.drives.motors[DRIVE_COMMAND.index(rx.name)]
                motor.set_command(float(rx.signals["Torque"]), bool(rx.signals["Enable"]), self.t)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.bus.shutdown()
