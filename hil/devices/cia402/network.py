"""The canopen Network the emulated drives sit on: no bus and no Notifier thread (the rig feeds each frame
in, and sends what comes out through its ProfileNode, whose bus, fault hooks and log see every frame), and
periodic tasks (the heartbeat producer) counted in ticks instead of python-can's periodic thread."""

from __future__ import annotations

import can
import canopen


class _TickTask:
    """python-canopen's periodic task (the heartbeat producer), counted in ticks by the emulation."""

    def __init__(self, can_id: int, data: bytes, period: float, tick_s: float):
        self.can_id, self.data = can_id, bytes(data)
        self.every = max(1, round(period / tick_s))
        self.count = 1
        """The first heartbeat one period after the task starts (after the boot-up message, not with it: a
        master waiting for the boot-up would miss it behind a heartbeat in the same instant)."""
        self.stopped = False

    def update(self, data: bytes) -> None:
        self.data = bytes(data)

    def stop(self) -> None:
        self.stopped = True


class RigNetwork(canopen.Network):
    """A canopen Network without a bus or a Notifier: frames in by `notify`, frames out into `out`."""

    def __init__(self, tick_s: float):
        super().__init__(bus=None)
        self.tick_s = tick_s
        self.out: list[can.Message] = []
        self.tasks: list[_TickTask] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.out.append(
            can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False, is_remote_frame=remote)
        )

    def send_periodic(  # type: ignore[override]  # a task of the tick, not python-can's thread
        self, can_id: int, data: bytes, period: float, remote: bool = False
    ) -> _TickTask:
        task = _TickTask(can_id, data, period, self.tick_s)
        self.tasks = [t for t in self.tasks if not t.stopped] + [task]
        return task

    def take(self) -> list[can.Message]:
        out, self.out = self.out, []
        return out
