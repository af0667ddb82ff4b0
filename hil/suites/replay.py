"""`pure-hil replay RUN_DIR`: feed a recorded run back into a controller and check it answers the same.

The run's CAN log holds every frame; zenoh_inputs.msgpack holds what the rig told the controller over
zenoh (seat wrench, SC commands) tick by tick. Replay starts the controller under test afresh (lockstep),
plays the rig's frames through python-can's MessageSync, puts each tick's zenoh inputs and the lockstep
fence before that tick's SYNC, and compares the controller's drive commands and heartbeat with the
recorded ones, byte for byte.
A deterministic controller reproduces them exactly; any difference is reported with its tick.
"""

from __future__ import annotations

import json
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import can
import msgspec

from drivers.bus_config import BusConfig
from drivers.can_bus import open_bus, private_channel
from drivers.can_codec import Catalog, MessageName
from drivers.config import ConfigError
from drivers.devices import Devices, controller_frame_ids
from drivers.dut import DutSpec, start_dut
from drivers.resources import find
from drivers.zenoh_access import ZenohAccess
from drivers.zenoh_link import ZenohLink
from hil.bench.bench import Bench, load_bench


@dataclass(slots=True)
class ReplayResult:
    ticks: int = 0
    frames_compared: int = 0
    mismatches: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return self.ticks > 0 and not self.mismatches


@dataclass(slots=True)
class _Tick:
    rig_frames: list[can.Message] = field(default_factory=list)
    expected: list[tuple[int, bytes]] = field(default_factory=list)


def _ticks(log: Path, catalog: Catalog, controller_ids: frozenset[int]) -> list[_Tick]:
    """Split the log at each SYNC: the rig's frames up to and including SYNC, then the controller's answer
    (its heartbeat and the frames of `controller_ids`). The controller's frames before the first SYNC are
    its boot-up (the start-up handshake), not answers."""
    ticks: list[_Tick] = []
    current = _Tick()
    answering = synced = False
    controller_ids = controller_ids | {catalog[MessageName.CONTROLLER_HEARTBEAT].frame_id}
    for msg in can.MessageSync(can.LogReader(str(log)), timestamps=False):
        codec = catalog.by_id(msg.arbitration_id)
        name = codec.name if codec else ""
        if msg.arbitration_id in controller_ids and not msg.is_remote_frame:
            if synced:
                current.expected.append((msg.arbitration_id, bytes(msg.data)))
            continue
        synced = synced or name == MessageName.SYNC
        if answering:  # the first rig frame after the controller's answer starts the next tick
            ticks.append(current)
            current, answering = _Tick(), False
        current.rig_frames.append(msg)
        answering = name == MessageName.SYNC
    if answering:
        ticks.append(current)
    return ticks


def replay(run_dir: Path, bench: Bench | None = None, limit: int | None = None) -> ReplayResult:
    """Feed a run folder's frames and zenoh inputs to a fresh controller (the bench's plugin and config) on
    a private bus and hub, and compare its answers with the recorded ones."""
    bench = bench or load_bench()
    summary = json.loads((run_dir / "summary.json").read_text())
    if "as_run" not in summary:
        # A folder of an older pure-hil, whose summary had the law at its top level.
        raise ConfigError(run_dir / "summary.json", "no `as_run.law` (written by an older pure-hil?)")
    scenario = summary["scenario"]
    catalog = Catalog()
    try:  # the devices the run spoke (a summary of an older pure-hil has none: the contract's own)
        devices = msgspec.convert(summary.get("bench", {}).get("devices", {}), Devices)
    except msgspec.ValidationError as exc:
        raise ConfigError(run_dir / "summary.json", f"bench.devices: {exc}") from exc
    ticks = _ticks(run_dir / "can.log", catalog, controller_frame_ids(devices))[:limit]
    inputs: dict[int, list[tuple[str, bytes]]] = defaultdict(list)
    for tick, key, data in msgspec.msgpack.decode((run_dir / "zenoh_inputs.msgpack").read_bytes()):
        inputs[tick].append((key, data))
    first_tick = min(inputs) if inputs else 1
    bus_config = BusConfig(channel=private_channel("replay"))
    bus = open_bus(bus_config)
    access = ZenohAccess(endpoint=bench.zenoh.endpoint if bench.zenoh.mode == "loopback" else None)
    session, access = access.open_rig(fallback=True)  # nobody else joins a replay
    link = ZenohLink(session, lossless=True)  # a lockstep replay must not lose an input
    dut = None
    result = ReplayResult()
    try:
        dut = start_dut(
            bench.controller.plugin,
            DutSpec(
                can=bus_config,
                zenoh=access,
                mode=summary["as_run"]["law"],
                robot=str(find(bench.controller.robot or scenario["robot"], "robot")),
                rider=str(find(scenario["rider"], "riders")),
                devices=devices,
                controller_config=str(find(bench.controller.config, "controller")),
                lockstep=True,
                tick_hz=scenario["tick_hz"],
            ),
        )
        link.wait_for_subscriber(link.keys.tes_wrench, 10.0)
        heartbeat = catalog[MessageName.CONTROLLER_HEARTBEAT]
        booting = True
        """Until its first answer the fresh controller may still send boot-up heartbeats: not compared."""
        for i, tick in enumerate(ticks):
            for key, data in inputs.get(first_tick + i, ()):
                link.put(key, data)
            link.put_fence(first_tick + i, 0.0)
            for msg in tick.rig_frames:
                bus.send(can.Message(arbitration_id=msg.arbitration_id, is_extended_id=False, data=msg.data))
            actual: list[tuple[int, bytes]] = []
            answer_deadline = time.monotonic() + 2.0
            while len(actual) < len(tick.expected) and time.monotonic() < answer_deadline:
                answer = bus.recv(max(answer_deadline - time.monotonic(), 0.0))
                if answer is None:
                    continue
                if booting and answer.arbitration_id == heartbeat.frame_id:
                    continue  # a boot-up (before the first command)
                booting = False
                actual.append((answer.arbitration_id, bytes(answer.data)))
            result.ticks += 1
            result.frames_compared += len(tick.expected)
            if actual != tick.expected:
                result.mismatches.append(
                    f"tick {first_tick + i}: expected {_fmt(tick.expected)}, got {_fmt(actual)}"
                )
    finally:
        if dut is not None:
            dut.stop()
        link.close()
        session.close()
        bus.shutdown()
    return result


def _fmt(frames: list[tuple[int, bytes]]) -> str:
    return " ".join(f"{fid:03X}#{data.hex().upper()}" for fid, data in frames) or "(nothing)"
