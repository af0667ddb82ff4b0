#!/usr/bin/env python3
"""The balance controller of balance_controller.py with its drives on CANopen CiA 402 (cyclic synchronous
torque), driven through python-canopen's master (`canopen.Network`, one `canopen.BaseNode402` per drive,
built from the drives' EDS), as a lab whose robot has EPOS- or Elmo-class drives would write it. It imports
nothing from pure-hil.

What changes against balance_controller.py:
  - start-up, at the first SYNC (the drives boot with the rig's first tick; the master answers that SYNC
    only once they are configured and started): each drive's boot-up, then SDO: the supported drive modes
    (0x6502) and modes of operation CST (0x6060 = 10, read back in 0x6061), the motor rated torque
    (0x6076) that scales the target torque, the PDO configuration (`setup_402_state_machine()`), then NMT
    start;
  - every SYNC: the drives' TPDOs of that SYNC (statusword, position, velocity) through BaseNode402's
    `tpdo_values`, the velocity from increments/s to rad/s at the motor (8192 increments a revolution);
    then RPDO1 (controlword, target torque in per mille of 0x6076) to each drive, then the contract's
    CONTROLLER_HEARTBEAT;
  - Enable: one thread per drive walks the 402 state machine through BaseNode402's `state` property to
    'OPERATION ENABLED' (fault reset on its way out of FAULT), and to 'SWITCH ON DISABLED' (disable
    voltage) when the law disables its drives. RPDO1 is this loop's cyclic PDO (its `period` says so),
    so the walk's controlwords go out in it, at the next SYNC. Its target torque stays zero until all
    three drives are OPERATION ENABLED (the walks end at different SYNCs).
The contract's own frames (SYNC, the IMU, the supervisor's, CONTROLLER_HEARTBEAT with its boot-up) still go
through the contract's DBC (balance_controller.py's Wire).

    python examples/cia402_controller.py --can socketcan:vcan0 --nodes 1 2 3
    pure-hil run balance --bench cia402 --controller external --can socketcan:vcan0
"""

from __future__ import annotations

import logging
import math
import sys
import threading
import time
from pathlib import Path

import can
import canopen
from canopen.sdo.exceptions import SdoError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from balance_controller import DBC, HEARTBEAT, TICK, BalanceController, Wire, drives_command_line, serve

EDS = Path(__file__).resolve().parents[1] / "configs" / "devices" / "cia402.eds"
COUNTS_PER_REV = 8192  # encoder increments per motor revolution
CST = 10  # modes of operation: cyclic synchronous torque
ENABLED, DISABLED = "OPERATION ENABLED", "SWITCH ON DISABLED"
IDLE = ("SWITCH ON DISABLED", "NOT READY TO SWITCH ON", "FAULT")  # no need to walk down from these
FRESH_WAIT = 0.01  # s a SYNC waits at most for the drives' TPDOs of that SYNC
STARTUP_TIMEOUT = 0.5  # s to wait for the drives' boot-up

log = logging.getLogger("cia402_controller")


class Cia402Drives:
    """Three CiA 402 drives through python-canopen's BaseNode402: start-up, velocities in, torques out, and
    the state-machine walk on a thread per drive."""

    def __init__(self, nodes: list[canopen.BaseNode402], stop: threading.Event):
        self.nodes, self.stop = nodes, stop
        self.started = False
        self.want = False
        """What the law wants: the drives OPERATION ENABLED (True) or SWITCH ON DISABLED."""
        self.rated_mnm = [1000] * len(nodes)
        self.position = [0.0] * len(nodes)  # rad at the motor
        self._heard = [threading.Event() for _ in nodes]
        self._used: list[float | None] = [None] * len(nodes)
        """Timestamp of each drive's TPDO2 the last SYNC used."""
        self._walkers: list[threading.Thread] = []
        self._run_over = threading.Event()
        """Set when a run ends: this run's walks end with it (the next run's drives boot afresh)."""
        for heard, node in zip(self._heard, nodes, strict=True):
            node.nmt.add_heartbeat_callback(lambda _state, heard=heard: heard.set())  # boot-up included

    # ------------------------------------------------------------------------------------ start-up
    def start_up(self) -> bool:
        """Boot-up (or a heartbeat) of every drive, SDO configuration, NMT start; False if a drive is not
        there yet or its SDO failed (tried again at the next SYNC)."""
        for heard, node in zip(self._heard, self.nodes, strict=True):
            if not heard.wait(STARTUP_TIMEOUT):
                log.warning("node %d: no boot-up or heartbeat yet", node.id)
                return False
        try:
            for i, node in enumerate(self.nodes):
                if not node.is_op_mode_supported("CYCLIC SYNCHRONOUS TORQUE"):  # 0x6502 over SDO
                    raise RuntimeError(f"node {node.id}: CST not among its supported drive modes")
                node.sdo[0x6060].raw = CST
                if node.sdo[0x6061].raw != CST:
                    raise RuntimeError(f"node {node.id}: modes of operation display is not CST")
                self.rated_mnm[i] = node.sdo[0x6076].raw
                node.setup_402_state_machine()  # the PDO configuration over SDO, TPDO callbacks
                node.rpdo[1].period = TICK  # sent by this loop every SYNC: BaseNode402 only updates it
        except SdoError as e:
            log.warning("SDO configuration: %s", e)
            return False
        for node in self.nodes:
            node.nmt.state = "OPERATIONAL"  # NMT start (0x000 01 id)
        self.started = True
        self._run_over = threading.Event()
        for node in self.nodes:
            args = (node, self._run_over)
            walker = threading.Thread(target=self._walk, args=args, name=f"walk-{node.id}", daemon=True)
            walker.start()
            self._walkers.append(walker)
        return True

    # ------------------------------------------------------------------------------------ each SYNC
    def velocities(self) -> list[float | None]:
        """rad/s at each motor from the drives' TPDO2 of this SYNC (None before a drive's first). The rig
        sends a SYNC's TPDOs before it, but they reach this thread through the Notifier's: wait for them a
        little (a drive that sent none keeps its last value)."""
        deadline = time.monotonic() + FRESH_WAIT
        scale = 2.0 * math.pi / COUNTS_PER_REV
        out: list[float | None] = []
        for i, node in enumerate(self.nodes):
            pdo = node.tpdo_pointers[0x606C].pdo_parent
            with pdo.receive_condition:
                pdo.receive_condition.wait_for(
                    lambda pdo=pdo, used=self._used[i]: pdo.timestamp not in (None, used),
                    timeout=max(deadline - time.monotonic(), 0.0),
                )
                self._used[i] = pdo.timestamp
            if not pdo.is_received:
                out.append(None)
                continue
            self.position[i] = node.tpdo_values[0x6064] * scale
            out.append(node.tpdo_values[0x606C] * scale)
        return out

    def command(self, torques: tuple[float, float, float], enable: bool) -> None:
        """RPDO1 to each drive: the controlword the walk last set, the target torque: zero until every drive
        is OPERATION ENABLED. Each walk ends at its own SYNC, and a wheel that pushes while another is not yet
        enabled turns the ball about the vertical, which a supervisor cannot tell from an encoder fault (the
        reference's yaw check took over at 0.03 s when one drive came up 3 SYNCs after another)."""
        self.want = enable
        together = enable and all(node.state == ENABLED for node in self.nodes)
        for node, torque, rated in zip(self.nodes, torques, self.rated_mnm, strict=True):
            per_mille = round(torque * 1e6 / rated) if together else 0  # Nm -> per mille of rated mNm
            node.rpdo[1][0x6071].raw = max(-32768, min(32767, per_mille))
            node.rpdo[1].transmit()

    # ------------------------------------------------------------------------------------ the walk
    def _walk(self, node: canopen.BaseNode402, run_over: threading.Event) -> None:
        """Keep the drive where the law wants it (also after a fault or a quick stop): BaseNode402's state
        setter sets the controlword in RPDO1 and waits for the statusword in TPDO1, step by step."""
        statusword = node.tpdo_pointers[0x6041].pdo_parent
        while not (self.stop.is_set() or run_over.is_set()):
            state = node.state
            if self.want and state != ENABLED:
                target = ENABLED
            elif not self.want and state not in IDLE:
                target = DISABLED
            else:
                statusword.wait_for_reception(timeout=0.05)
                continue
            try:
                node.state = target
            except (RuntimeError, ValueError) as e:  # a step not confirmed in time: look again
                log.info("node %d: %s -> %s: %s", node.id, state, target, e)
                statusword.wait_for_reception(timeout=0.05)

    def start_over(self) -> None:
        """The run is over (docs/contract.md "Between runs"): the next run's drives boot again, unconfigured
        and PRE-OPERATIONAL, so the next SYNC starts them up anew, from their boot-up on."""
        self._run_over.set()
        self.close()
        self._walkers.clear()
        self.started, self.want = False, False
        self._used = [None] * len(self.nodes)
        for heard in self._heard:
            heard.clear()

    def close(self) -> None:
        for walker in self._walkers:
            walker.join(timeout=2.0)


class Cia402BalanceController(BalanceController):
    """balance_controller.py's estimator and law; the drives are CiA 402 drives on CANopen."""

    drives: Cia402Drives

    def reset(self) -> None:
        super().reset()
        if hasattr(self, "drives"):  # not at construction: the drives are given after it
            self.drives.start_over()

    def tick(self, k: int) -> None:
        if not self.drives.started and not self.drives.start_up():
            self.wire.send("CONTROLLER_HEARTBEAT", {**HEARTBEAT, "State": self.state})
            return
        self.velocity = self.drives.velocities()
        super().tick(k)

    def command(self, k: int, torques: tuple[float, float, float], enable: bool) -> None:
        self.drives.command(torques, enable)


def run(channel: str, interface: str, nodes: list[int], stop: threading.Event) -> None:
    network = canopen.Network()
    drives = [canopen.BaseNode402(node, str(EDS)) for node in nodes]
    for node in drives:
        network.add_node(node)
    ids = [base + n for n in nodes for base in (0x080, 0x180, 0x280, 0x380, 0x480, 0x580, 0x700)]
    network.connect(
        interface=interface, channel=channel, can_filters=[{"can_id": i, "can_mask": 0x7FF} for i in ids]
    )  # its Notifier thread takes the drives' frames: TPDOs, SDO responses, heartbeats, EMCY
    wire = Wire(can.Bus(interface=interface, channel=channel), DBC)
    wire.bus.set_filters([{"can_id": m.frame_id, "can_mask": 0x7FF} for m in wire.db.messages])
    controller = Cia402BalanceController(wire)
    controller.drives = Cia402Drives(drives, stop)
    try:
        controller.run(stop)  # boot-up heartbeats at once: the rig waits for them before its first SYNC
    finally:
        stop.set()
        controller.drives.close()
        network.disconnect()
        wire.bus.shutdown()


def main(argv: list[str] | None = None) -> int:
    args = drives_command_line(__doc__).parse_args(argv)
    return serve(args.can, lambda channel, interface, stop: run(channel, interface, args.nodes, stop))


if __name__ == "__main__":
    raise SystemExit(main())
