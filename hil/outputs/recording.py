"""The run's rerun recording: states, commands and the rider on a simulated-time timeline, written to a
file in column batches (one chunk per signal group and block of ticks, never one call per tick), and the
robot and its rider in 3-D: each body's shapes once under `bodies/<body>`, its pose as a Transform3D on the
same timeline (hil/outputs/bodies.py).

File sink only: no viewer is spawned and nothing is served (network rule); CI=1 keeps rerun's analytics off.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import numpy as np

os.environ.setdefault("CI", "1")  # rerun's analytics are off in CI mode; the SDK alone never phones home

import rerun as rr
from rerun.chunk import Chunk, LazyChunkStream

from hil.outputs.bodies import Body, Poses, Shape

SIGNALS = {
    # entity path: (trace attribute, series names)
    "speed/actual": ("velocity", ["forward", "left"]),
    "speed/command": ("command_speed", ["pitch", "roll"]),
    "tilt/chassis": ("tilt", ["pitch", "roll"]),
    "tilt/command": ("tilt_command", ["pitch", "roll"]),
    "rider/lean": ("lean", ["pitch", "roll"]),
    "position": ("position", ["x", "y"]),
    "motor/torque": ("motor_torque", ["m1", "m2", "m3"]),
}
DEGREES = {"tilt/chassis", "tilt/command", "rider/lean"}


BLOCK = 4096
"""Ticks per chunk: the recording is written as it is produced, one block at a time (memory flat in a run's
length: rerun's LazyChunkStream writes each chunk as the generator yields it)."""
BODIES = "bodies"
"""The 3-D view's root: z up, a child entity per body."""


def write_rrd(path: Path, trace, name: str = "pure-hil") -> None:
    """The whole run as chunks (per signal group and block of ticks), written straight to `path`. No
    RecordingStream: a Python-created stream is never dropped and keeps its batcher threads for the life
    of the process (rerun-io/rerun#2116), which a service running for weeks cannot afford."""
    LazyChunkStream.from_iter(_chunks(trace)).write_rrd(
        path, application_id=f"pure_hil_{name}", recording_id=uuid.uuid4().hex
    )


def _chunks(trace):
    groups = [(entity, names, attr) for entity, (attr, names) in SIGNALS.items()]
    groups += [
        ("yaw_rate", ["yaw rate"], "yaw_rate"),
        ("safety/state", ["supervisor state (0 normal .. 3 e-stop)"], "safety_state"),
        ("safety/speed_estimate", ["supervisor's speed estimate"], "safety_speed"),
    ]
    for entity, names, _ in groups:
        labels = rr.SeriesLines.columns(names=names).partition([len(names)])
        yield Chunk.from_columns(entity, indexes=[], columns=labels)
    for start in range(0, len(trace.t), BLOCK):
        block = slice(start, start + BLOCK)
        times = [rr.TimeColumn("sim_time", duration=np.asarray(trace.t[block], float))]
        for entity, _, attr in groups:
            values = np.asarray(getattr(trace, attr)[block], float)
            values = np.degrees(values) if entity in DEGREES else values
            yield Chunk.from_columns(entity, indexes=times, columns=rr.Scalars.columns(scalars=values))

    def text_log(entity: str, rows: list[tuple[float, str, str]]):
        if rows:
            t, text, level = zip(*rows, strict=True)
            index = [rr.TimeColumn("sim_time", duration=np.asarray(t, float))]
            columns = rr.TextLog.columns(text=text, level=level)
            yield Chunk.from_columns(entity, indexes=index, columns=columns)

    events = []
    for e in trace.safety_events:
        level = "WARN" if e.to_state in ("STOPPING", "ESTOP") or e.kind != "transition" else "INFO"
        text = f"supervisor {e.kind}: {e.from_state} -> {e.to_state} ({e.cause}) {e.detail}".strip()
        events.append((float(e.t), text, level))
    if trace.fallen:
        events.append((float(trace.t[-1]), f"fell: {trace.fallen}", "ERROR"))
    yield from text_log("events", events)
    faults = getattr(trace, "fault_events", ())
    yield from text_log(
        "events/faults",
        [(float(f.t), f"fault {f.fault} {f.action}: {f.kind} {f.detail}".strip(), "WARN") for f in faults],
    )
    poses = getattr(trace, "poses", None)
    if poses is not None:
        yield from _body_chunks(poses)


def _body_chunks(poses: Poses):
    """The bodies: z up, each body's shapes (static), then its poses a block at a time."""
    up = rr.ViewCoordinates.columns(xyz=[rr.components.ViewCoordinates.RIGHT_HAND_Z_UP])
    yield Chunk.from_columns(BODIES, indexes=[], columns=up)
    for body in poses.bodies:
        yield from _shape_chunks(body)
    for start in range(0, len(poses.t), BLOCK):
        block = slice(start, start + BLOCK)
        times = [rr.TimeColumn("sim_time", duration=np.asarray(poses.t[block], float))]
        for i, body in enumerate(poses.bodies):
            values = np.asarray(poses.values[block, i], float)
            columns = rr.Transform3D.columns(translation=values[:, 0:3], quaternion=values[:, [4, 5, 6, 3]])
            yield Chunk.from_columns(f"{BODIES}/{body.name}", indexes=times, columns=columns)


ARCHETYPES = {
    "sphere": "ellipsoids",
    "ellipsoid": "ellipsoids",
    "capsule": "capsules",
    "cylinder": "cylinders",
}
"""The entity under a body that holds its shapes of a kind (boxes: `boxes`)."""


def _shape_chunks(body: Body):
    """A body's shapes in its frame, one static chunk per archetype (rerun's quaternions are x, y, z, w)."""
    groups: dict[str, list[Shape]] = {}
    for shape in body.shapes:
        groups.setdefault(ARCHETYPES.get(shape.kind, "boxes"), []).append(shape)
    for name, shapes in groups.items():
        turns = [(x, y, z, w) for w, x, y, z in (s.orientation for s in shapes)]
        colors = [s.rgba for s in shapes]
        lengths, radii = [2 * s.size[1] for s in shapes], [s.size[0] for s in shapes]
        centers = [s.position for s in shapes]
        archetype: type[rr.Ellipsoids3D | rr.Capsules3D | rr.Cylinders3D | rr.Boxes3D]
        if name == "ellipsoids":
            archetype = rr.Ellipsoids3D
            half = [s.size if s.kind == "ellipsoid" else (s.size[0],) * 3 for s in shapes]
            columns = rr.Ellipsoids3D.columns(
                half_sizes=half, centers=centers, quaternions=turns, colors=colors
            )
        elif name == "capsules":  # rerun's runs from its origin along +z; MuJoCo's is centred on it
            archetype = rr.Capsules3D
            ends = [s.along_z(-s.size[1]) for s in shapes]
            columns = rr.Capsules3D.columns(
                lengths=lengths, radii=radii, translations=ends, quaternions=turns, colors=colors
            )
        elif name == "cylinders":
            archetype = rr.Cylinders3D
            columns = rr.Cylinders3D.columns(
                lengths=lengths, radii=radii, centers=centers, quaternions=turns, colors=colors
            )
        else:
            archetype = rr.Boxes3D
            columns = rr.Boxes3D.columns(
                half_sizes=[s.size for s in shapes], centers=centers, quaternions=turns, colors=colors
            )
        solid = archetype.columns(fill_mode=[rr.components.FillMode.Solid])
        entity = f"{BODIES}/{body.name}/{name}"
        yield Chunk.from_columns(entity, indexes=[], columns=[*columns.partition([len(shapes)]), *solid])


LIVE = {
    # entity path: (series names, how to read them from a Truth)
    "speed/actual": (["forward", "left"], lambda tr: tr.velocity),
    "tilt/chassis": (["pitch", "roll"], lambda tr: np.degrees(tr.tilt)),
    "rider/lean": (["pitch", "roll"], lambda tr: np.degrees(tr.lean)),
    "motor/torque": (["m1", "m2", "m3"], lambda tr: tr.motor_torque),
}


class LiveView:
    """The running rig as it happens, for a bench operator's rerun viewer (`pure-hil serve --view URL`).

    Ticks are buffered and sent as one `send_columns` per signal group every `every` ticks (0.1 s at
    400 Hz), never one call per signal per tick. The viewer is the user's, started by them; the rig only
    connects to the address it is given (`sink`: an `rr.GrpcSink(url)`; tests use an `rr.FileSink`).
    """

    def __init__(self, sink, name: str = "pure-hil live", every: int = 40):
        self.rec = rr.RecordingStream(f"pure_hil_live_{name}")
        self.rec.set_sinks(sink)
        self.rec.set_log_time_enabled(False)
        for entity, (names, _) in LIVE.items():
            self.rec.log(entity, rr.SeriesLines(names=names), static=True)
        self.every = every
        self._t: list[float] = []
        self._rows: dict[str, list] = {entity: [] for entity in LIVE}

    def add(self, truth) -> None:
        self._t.append(truth.t)
        for entity, (_, read) in LIVE.items():
            self._rows[entity].append(read(truth))
        if len(self._t) >= self.every:
            self._send_rows()

    def mark(self, t: float, text: str, level: str = "INFO") -> None:
        self.rec.set_time("sim_time", duration=t)
        self.rec.log("events", rr.TextLog(text, level=level))

    def flush(self) -> None:
        """Everything so far to the sink (the end of a run; the stream stays open for the next)."""
        self._send_rows()
        self.rec.flush()

    def _send_rows(self) -> None:
        if not self._t:
            return
        times = rr.TimeColumn("sim_time", duration=np.asarray(self._t, float))
        for entity, rows in self._rows.items():
            self.rec.send_columns(
                entity, indexes=[times], columns=rr.Scalars.columns(scalars=np.asarray(rows, float))
            )
            rows.clear()
        self._t.clear()

    def close(self) -> None:
        self.flush()
        self.rec.disconnect()
