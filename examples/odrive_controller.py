#!/usr/bin/env python3
"""The balance controller of balance_controller.py with its drives on ODrive's CAN Simple, driven through
odrive-can's own client (`odrive_can.ODriveCAN`, one per axis), as a lab whose robot has ODrive drives would
write it. It imports nothing from pure-hil.

What changes against balance_controller.py: the motor velocities come from each axis's cyclic
Get_Encoder_Estimates (the client's `feedback_callback`, rev/s at the motor); a drive is armed with
`set_axis_state_no_wait("CLOSED_LOOP_CONTROL")` (after `clear_errors()` if its heartbeat shows an error) and
commanded with `set_input_torque`; it is disarmed with IDLE. The contract's own frames (SYNC, the IMU, the
supervisor's, CONTROLLER_HEARTBEAT) still go through the contract's DBC.

    python examples/odrive_controller.py --can socketcan:vcan0 --nodes 1 2 3
    pure-hil run balance --bench odrive --controller external --can socketcan:vcan0
"""

from __future__ import annotations

import asyncio
import math
import sys
import threading
from pathlib import Path

import can
from odrive_can import ODriveCAN
from odrive_can.odrive import DriveError, HeartbeatError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from balance_controller import DBC, BalanceController, Wire, drives_command_line, serve


class OdriveDrives:
    """Three axes through odrive-can's client: velocities in, arm/disarm and torques out."""

    def __init__(self, axes: list[ODriveCAN], controller: BalanceController):
        self.axes, self.controller = axes, controller
        self.armed = [False, False, False]
        for i, axis in enumerate(axes):
            axis.feedback_callback = lambda msg, _, i=i: self._velocity(i, msg.data["Vel_Estimate"])

    def _velocity(self, i: int, rev_per_s: float) -> None:
        self.controller.velocity[i] = rev_per_s * 2.0 * math.pi

    def command(self, torques: tuple[float, float, float], enable: bool) -> None:
        for i, (axis, torque) in enumerate(zip(self.axes, torques, strict=True)):
            if enable and (not self.armed[i] or self._disarmed(axis)):
                try:
                    axis.check_errors()
                except (DriveError, HeartbeatError):
                    axis.clear_errors()  # an error latched (the watchdog, an e-stop): clear, then arm
                axis.set_axis_state_no_wait("CLOSED_LOOP_CONTROL")
            elif not enable and self.armed[i]:
                axis.set_axis_state_no_wait("IDLE")
            self.armed[i] = enable
            axis.set_input_torque(torque if enable else 0.0)

    @staticmethod
    def _disarmed(axis: ODriveCAN) -> bool:
        """Its last heartbeat says it is not in closed loop (it disarmed itself, or has not armed yet)."""
        try:
            return axis.axis_state != "CLOSED_LOOP_CONTROL"
        except HeartbeatError:
            return True


class OdriveBalanceController(BalanceController):
    """balance_controller.py's estimator and law; the drive commands go to the ODrive axes."""

    drives: OdriveDrives

    def command(self, k: int, torques: tuple[float, float, float], enable: bool) -> None:
        self.drives.command(torques, enable)


async def run(channel: str, interface: str, nodes: list[int], stop: threading.Event) -> None:
    buses = [can.Bus(interface=interface, channel=channel) for _ in nodes]  # one reader thread each
    axes = [ODriveCAN(axis_id=node, can_bus=bus) for node, bus in zip(nodes, buses, strict=True)]
    wire = Wire(can.Bus(interface=interface, channel=channel), DBC)
    controller = OdriveBalanceController(wire)
    controller.drives = OdriveDrives(axes, controller)
    contract = threading.Thread(target=controller.run, args=(stop,), daemon=True)
    contract.start()  # boot-up heartbeats at once: the rig waits for them before its first SYNC
    for axis in axes:
        await axis.start()  # its first heartbeat (the rig's emulated axes send them from the first tick)
    while not stop.is_set():
        await asyncio.sleep(0.05)
    contract.join()
    for axis in axes:
        axis.stop()
    wire.bus.shutdown()


def main(argv: list[str] | None = None) -> int:
    args = drives_command_line(__doc__).parse_args(argv)
    return serve(
        args.can, lambda channel, interface, stop: asyncio.run(run(channel, interface, args.nodes, stop))
    )


if __name__ == "__main__":
    raise SystemExit(main())
