#!/usr/bin/env python3
"""The balance controller of balance_controller.py with its IMU an Xsens MTi 600-series on CAN, read as a lab
would write it from Xsens' published CAN layout (Movella's CAN message page, formerly the MT CAN Protocol
Documentation; the MT Low Level Communication Protocol for byte order and the StatusWord's bits). It
imports nothing from pure-hil and uses no DBC for the IMU.

What changes against balance_controller.py: the attitude and the rates come from the MTi's output group
(XCID_SampleTime, XCID_GroupCounter, XCID_StatusWord, then XCID_EulerAngles in 2^-7 deg and XCID_RateOfTurn
in 2^-9 rad/s; every field big-endian); a data frame counts only if its group's SampleTime advanced since
the last frame of its kind (the group is the IMU's only freshness: the frames carry no CRC or counter),
the attitude only while the StatusWord says the filter is valid, the rates only without gyroscope
clipping. Each message's id is what the device's CAN output configuration gives it: its XCID plus one base
here (`--xsens-base`, the xsens bench's 0x100). The drives and the contract's other frames still go through
the contract's DBC.

    python examples/xsens_controller.py --can socketcan:vcan0 --xsens-base 0x100
    pure-hil run balance --bench xsens --controller external --can socketcan:vcan0
"""

from __future__ import annotations

import math
import struct
import sys
import threading
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent))
import balance_controller
from balance_controller import DBC, Wire, command_line, serve

SAMPLE_TIME, GROUP_COUNTER, STATUS_WORD, EULER_ANGLES, RATE_OF_TURN = 0x005, 0x006, 0x011, 0x022, 0x032
FILTER_VALID = 1 << 1
GYRO_CLIPPING = 0b111 << 11
EULER_SCALE = 2.0**-7  # deg per count
RATE_SCALE = 2.0**-9  # rad/s per count


class XsensWire(Wire):
    """The contract's frames through the DBC, the MTi's through its published layout."""

    def __init__(self, bus: can.BusABC, dbc: Path, base: int):
        super().__init__(bus, dbc)
        self.xcid = {
            base + x: x for x in (SAMPLE_TIME, GROUP_COUNTER, STATUS_WORD, EULER_ANGLES, RATE_OF_TURN)
        }
        self.sample_time: int | None = None
        self.status = 0
        self.used: dict[int, int | None] = {EULER_ANGLES: None, RATE_OF_TURN: None}
        """The SampleTime of the group each data message was last taken from."""

    def receive(self, msg: can.Message) -> tuple[str, dict] | None:
        xcid = self.xcid.get(msg.arbitration_id)
        if xcid is None or msg.is_extended_id:
            return super().receive(msg)
        data = bytes(msg.data)
        expected = 4 if xcid in (SAMPLE_TIME, STATUS_WORD) else 2 if xcid == GROUP_COUNTER else 6
        if len(data) != expected:
            self.rejected += 1
            return None
        if xcid == SAMPLE_TIME:
            (self.sample_time,) = struct.unpack(">I", data)
            return None
        if xcid == STATUS_WORD:
            (self.status,) = struct.unpack(">I", data)
            return None
        if xcid == GROUP_COUNTER:
            return None
        fresh = self.sample_time is not None and self.used[xcid] != self.sample_time
        self.used[xcid] = self.sample_time
        x, y, z = struct.unpack(">hhh", data)
        if xcid == EULER_ANGLES:
            valid = fresh and bool(self.status & FILTER_VALID)
            roll, pitch, yaw = (math.radians(v * EULER_SCALE) for v in (x, y, z))
            return "IMU_ATTITUDE", {"Roll": roll, "Pitch": pitch, "Yaw": yaw, "Valid": int(valid)}
        valid = fresh and not self.status & GYRO_CLIPPING
        return "IMU_RATE", {"RateX": x * RATE_SCALE, "RateY": y * RATE_SCALE, "RateZ": z * RATE_SCALE,
                            "Valid": int(valid)}  # fmt: skip


def run(channel: str, interface: str, base: int, stop: threading.Event) -> None:
    balance_controller.run(channel, interface, stop, lambda bus: XsensWire(bus, DBC, base))


def main(argv: list[str] | None = None) -> int:
    parser = command_line(__doc__)
    parser.add_argument(
        "--xsens-base", type=lambda text: int(text, 0), default=0x100, help="the MTi's ids: base + XCID"
    )
    args = parser.parse_args(argv)
    return serve(args.can, lambda channel, interface, stop: run(channel, interface, args.xsens_base, stop))


if __name__ == "__main__":
    raise SystemExit(main())
