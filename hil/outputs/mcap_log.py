"""run.mcap: the run in one MCAP file for Foxglove/Lichtblick, PlotJuggler and rerun, written as it goes.

Every channel is JSON with a JSON Schema (MCAP schema encoding `jsonschema`, message encoding `json`), which
Foxglove shows and plots without set-up. Times are simulated time in ns from the run's start (log and
publish time alike):

    /can/frames      every frame of can.log, handed over by the same recorder poll that writes can.log
                     (drivers/can_bus.py BusRecorder): one message per tick with the frames the recorder
                     took in it (the start-up's at 0), in can.log's order, each stamped with that
                     simulated time and with can.log's own (wall-clock) stamp beside it
    /can/<MESSAGE>   a DBC message's signals, decoded by drivers/can_codec.py: one message per frame
    /zenoh/<key>     what the controller was told over zenoh (zenoh_inputs.msgpack), decoded; a payload
                     that does not decode (a fault's garbage) goes to /zenoh/rejected with its bytes
    /trace           one message per tick: trace.npy's row as the tick ends (the plant's truth, the
                     supervisor's state and speed estimate; hil/outputs/trace_log.py COLUMNS)
    /events/...      what happened, at its time: each fault's window, the fault log, the supervisor's
                     transitions with their causes, the operator's actions, the rig's own late windows in
                     real time (EVENTS; handed over as the run ends, `event`)
    /pose/<body>     a body's pose as Foxglove's FrameTransform from "world": at 0, at 100 Hz and at the
                     last tick (hil/outputs/bodies.py, foxglove.py)
    /scene           every body's shapes as Foxglove's SceneUpdate, once at 0, each in its body's frame

It streams, a chunk at a time (hil/outputs/mcap_file.py: memory flat in a run's length). Writing never
fails a run: an error stops the messages there, stop() still completes the file and records the error as
metadata `failed`, and `check` (run with the other outputs, hil/report/folder.py) raises it, so the
summary lists run.mcap in `outputs_failed`.
"""

from __future__ import annotations

import logging
import operator
from collections.abc import Callable, Sequence
from pathlib import Path

import can
import msgspec
from mcap.reader import make_reader

from drivers.can_codec import Catalog, MessageCodec
from drivers.keys import PAYLOADS, Keys
from drivers.schemas import Payload, PayloadError, decode, json_schema
from hil.outputs.bodies import Body
from hil.outputs.foxglove import (
    FRAME_TRANSFORM,
    SCENE_UPDATE,
    FrameTransforms,
    frame_transform_schema,
    scene_update,
    scene_update_schema,
)
from hil.outputs.mcap_file import McapFile
from hil.outputs.trace_log import COLUMNS, TELEMETRY

log = logging.getLogger(__name__)

FRAMES = "/can/frames"
SIGNALS = "/can/{message}"
ZENOH = "/zenoh/{key}"
REJECTED = "/zenoh/rejected"
TRACE = "/trace"
FAULT_WINDOWS = "/events/fault_windows"
FAULT_LOG = "/events/faults"
SUPERVISOR = "/events/supervisor"
OPERATOR = "/events/operator"
RIG_LATE = "/events/rig_late"
POSE = "/pose/{body}"
SCENE = "/scene"
FAILED = "failed"
"""The metadata record that says why the file's messages stop early."""
ROW = COLUMNS[:TELEMETRY]
"""A tick's row as the tick ends; the controller's telemetry lands in trace.npy later, not here."""
STAMP = [column.name for column in ROW].index("t")
"""The row's simulated time: its message's log time."""


class Frame(msgspec.Struct, omit_defaults=True):
    """One CAN frame as can.log has it (the flags only when set)."""

    stamp: float
    """Simulated time, s: when the recorder took it (the message's log time)."""
    wall: float
    """can.log's stamp: the bus's wall-clock time, s."""
    id: int
    data: bytes | bytearray
    """python-can's Message.data is a bytearray, kept as is (msgspec writes either as base64)."""
    extended: bool = False
    remote: bool = False
    error: bool = False


def _plain(m: can.Message) -> bool:
    """A data frame with a standard id: the only kind the DBC describes."""
    return not (m.is_extended_id or m.is_remote_frame or m.is_error_frame)


class Frames(msgspec.Struct):
    frames: list[Frame]


class Rejected(msgspec.Struct):
    key: str
    reason: str
    data: bytes


BYTES = {"type": "string", "contentEncoding": "base64"}
"""Foxglove's JSON Schema for bytes (msgspec writes bytes as base64)."""


def _schema(title: str, properties: dict, description: str) -> bytes:
    return msgspec.json.encode(
        {"title": title, "description": description, "type": "object", "properties": properties}
    )


def _frames_schema() -> bytes:
    flag = {"type": "boolean", "default": False}
    frame = {
        "type": "object",
        "properties": {
            "stamp": {"type": "number", "description": "simulated time, s: when the CAN log took it"},
            "wall": {"type": "number", "description": "the bus's wall-clock stamp, s (can.log's)"},
            "id": {"type": "integer", "description": "arbitration id"},
            "data": BYTES,
            "extended": flag,
            "remote": flag,
            "error": flag,
        },
    }
    properties = {"frames": {"type": "array", "items": frame}}
    return _schema("CanFrames", properties, "the frames the CAN log took in one tick, in can.log's order")


def _signals_schema(codec: MessageCodec) -> bytes:
    properties = {}
    for signal in codec.message.signals:
        values = [f"{raw} {name}" for raw, name in sorted((signal.choices or {}).items())]
        notes = [n for n in (signal.unit, signal.comment, ", ".join(values)) if n]
        entry = {"type": "integer" if signal.scale == 1 and signal.offset == 0 else "number"}
        if notes:
            entry["description"] = "; ".join(notes)
        properties[signal.name] = entry
    return _schema(codec.name, properties, f"CAN 0x{codec.frame_id:03X} decoded through the DBC")


def _payload_schema(payload: type[Payload]) -> bytes:
    """msgspec's JSON Schema of a payload, the payload's own at the top (no `$ref` for a viewer to follow:
    the payloads of drivers/schemas.py refer to no other type)."""
    schema = json_schema(payload)
    defs = schema.get("$defs", {})
    return msgspec.json.encode(defs[payload.__name__] if len(defs) == 1 else schema)


def _rejected_schema() -> bytes:
    properties = {"key": {"type": "string"}, "reason": {"type": "string"}, "data": BYTES}
    return _schema("Rejected", properties, "a zenoh input that does not decode as its key's payload")


_TEXT, _NUMBER, _INTEGER = {"type": "string"}, {"type": "number"}, {"type": "integer"}
_STATE = {"type": "string", "description": "NORMAL, LIMITING, STOPPING, ESTOP or RECOVERY"}
EVENTS: dict[str, tuple[str, dict, str]] = {
    FAULT_WINDOWS: (
        "FaultWindow",
        {
            "fault": {**_INTEGER, "description": "its number in the run (the scenario's, then live ones)"},
            "kind": _TEXT,
            "description": {**_TEXT, "description": "the kind and its parameters"},
            "start": {**_NUMBER, "description": "s, when it began to act (the message's time)"},
            "end": {**_NUMBER, "description": "s, when it stopped acting (the run's end if it never did)"},
            "live": {"type": "boolean", "description": "injected into the running run (not scheduled)"},
            "expect": {"type": ["object", "null"], "description": "the reaction it expects (docs/faults.md)"},
        },
        "the window one fault acted in, at its start",
    ),
    FAULT_LOG: (
        "FaultEvent",
        {
            "fault": _INTEGER,
            "kind": _TEXT,
            "action": {**_TEXT, "description": "inject, start, end or clear"},
            "detail": _TEXT,
        },
        "a line of the fault log (summary.json fault_events)",
    ),
    SUPERVISOR: (
        "SupervisorEvent",
        {
            "kind": {**_TEXT, "description": "transition, reset_refused or contactor_opened"},
            "from_state": _STATE,
            "to_state": _STATE,
            "cause": {**_TEXT, "description": "drivers/vocabulary.py Cause"},
            "detail": _TEXT,
        },
        "the supervisor's transition (or refused reset) with its cause (summary.json safety.events)",
    ),
    OPERATOR: (
        "OperatorAction",
        {
            "action": {**_TEXT, "description": "estop, cut_power or reset"},
            "source": {**_TEXT, "description": "who sent it (button: a wired e-stop)"},
            "supervisor_state": {**_STATE, "description": "the supervisor's state when it came"},
            "scheduled": {"type": "boolean", "description": "one of the scenario's own [[operator]] steps"},
        },
        "an operator's e-stop, category-0 cut or reset as the supervisor took it in",
    ),
    RIG_LATE: (
        "RigLateWindow",
        {
            "start": {**_NUMBER, "description": "s, the first tick whose SYNC the rig sent late"},
            "end": {**_NUMBER, "description": "s, the window's end (its last late tick's tail included)"},
        },
        "real time: a window in which the rig itself sent SYNC late (docs/rig.md, When the rig is late)",
    ),
}
"""The event topics: (schema title, properties, description)."""


def _trace_layout() -> tuple[list[tuple[str, int]], dict[str, list[tuple[str, int]]]]:
    """ROW's columns as fields: "t" -> t, "velocity.forward" -> velocity.forward (a Foxglove message path)."""
    scalars: list[tuple[str, int]] = []
    groups: dict[str, list[tuple[str, int]]] = {}
    for i, column in enumerate(ROW):
        group, _, field = column.name.partition(".")
        if field:
            groups.setdefault(group, []).append((field, i))
        else:
            scalars.append((column.name, i))
    return scalars, groups


def _trace_schema() -> bytes:
    scalars, groups = _trace_layout()

    def number(i: int) -> dict:  # the column's unit and meaning, as Foxglove shows a field's description
        unit = f" ({ROW[i].unit})" if ROW[i].unit else ""
        return {"type": ["number", "null"], "description": ROW[i].meaning + unit}

    properties = {name: number(i) for name, i in scalars}
    for group, fields in groups.items():
        properties[group] = {"type": "object", "properties": {field: number(i) for field, i in fields}}
    return _schema(
        "Trace", properties, "a tick's row of trace.npy (hil/outputs/trace_log.py COLUMNS), SI units"
    )


def _trace_template() -> tuple[bytes, Callable[[tuple[float, ...]], tuple[float, ...]]]:
    """A /trace message as a `%` template of the row's JSON numbers, and what picks the row's values in the
    template's order: the same JSON as the message's dict through msgspec, a third of its cost."""
    scalars, groups = _trace_layout()
    fields = [f'"{name}":%s' for name, _ in scalars]
    fields += [
        f'"{group}":{{' + ",".join(f'"{field}":%s' for field, _ in members) + "}"
        for group, members in groups.items()
    ]
    order = [i for _, i in scalars] + [i for members in groups.values() for _, i in members]
    return ("{" + ",".join(fields) + "}").encode(), operator.itemgetter(*order)


class McapLog(can.Listener):
    """run.mcap as the run goes: a python-can listener (BusRecorder hands it every frame it writes to
    can.log), `zenoh(tick, key, data)` from the zenoh inputs log, and `trace(row)` at the end of every
    tick, which also writes the frames taken in it; `stop()` completes the file."""

    def __init__(self, path: Path, tick_hz: float, keys: Keys, metadata: dict[str, str] | None = None):
        self.path = path
        self.dt = 1.0 / tick_hz
        self.clock: Callable[[], float] = lambda: 0.0
        """Simulated time now, s (build sets the plant's): when the recorder took a frame."""
        self.error: str | None = None
        self._codecs = {codec.frame_id: codec for codec in Catalog()}
        self._payloads = {getattr(keys, name): payload for name, payload in PAYLOADS.items()}
        self._channels: dict[object, int] = {}
        """A frame id, a zenoh key or a topic -> its channel."""
        self._decoders: dict[int, tuple[Callable[[int], dict[str, float | int]], int, int]] = {}
        """A DBC message's frame id -> (its codec's decode_int, its length, its channel), from its first
        frame on."""
        self._json = msgspec.json.Encoder().encode
        self._frames: list[can.Message] = []
        self._frames_t = 0.0
        """When the recorder took the frames in `_frames`, s."""
        self._trace_json, self._trace_values = _trace_template()
        self._transforms: FrameTransforms | None = None
        self._pose_channels: list[int] = []
        self._file = McapFile(path, library="pure-hil")
        self._on = False
        """Messages are written (until the first error)."""
        try:
            self._file.metadata(
                "pure-hil", {"time": "simulated, ns from the run's start", **(metadata or {})}
            )
            self._on = True
        except Exception as exc:
            self._fail(exc)

    def on_message_received(self, msg: can.Message) -> None:
        """A frame of the CAN log (python-can's Listener), kept (read-only) until the recorder's next poll
        or the tick's end."""
        if not self._on:
            return
        t = self.clock()
        if t != self._frames_t:
            if self._frames:
                try:
                    self._write_frames()
                except Exception as exc:
                    self._fail(exc)
                    return
            self._frames_t = t
        self._frames.append(msg)

    def zenoh(self, tick: int, key: str, data: bytes) -> None:
        """A zenoh input for tick `tick` (hil/outputs/inputs_log.py)."""
        if not self._on:
            return
        try:
            at = round(tick * self.dt * 1e9)
            payload = self._payloads.get(key)
            try:
                if payload is None:
                    raise PayloadError("schema", f"no payload is known for key {key}")
                message = self._json(decode(data, payload))
            except PayloadError as exc:
                channel = self._channel(REJECTED, "Rejected", _rejected_schema)
                self._file.message(channel, at, self._json(Rejected(key, str(exc), data)))
                return
            channel = self._channels.get(key) or self._channel(
                key, payload.__name__, lambda: _payload_schema(payload), ZENOH.format(key=key)
            )
            self._file.message(channel, at, message)
        except Exception as exc:
            self._fail(exc)

    def trace(self, row) -> None:
        """The end of a tick: the frames taken in it, then its row of trace.npy (ROW's columns)."""
        if not self._on:
            return
        try:
            if self._frames:
                self._write_frames()
            # As trace.npy keeps them (f8; NaN becomes JSON's null), in the template's order: msgspec
            # writes them as a JSON array, whose numbers go into the template (none holds a comma).
            numbers = self._json(list(map(float, self._trace_values(row))))[1:-1].split(b",")
            channel = self._channels.get(TRACE) or self._channel(TRACE, "Trace", _trace_schema)
            self._file.message(channel, round(float(row[STAMP]) * 1e9), self._trace_json % tuple(numbers))
        except Exception as exc:
            self._fail(exc)

    def event(self, topic: str, t: float, message: dict) -> None:
        """Something that happened at `t` (s) on one of the EVENTS topics, as its schema describes it."""
        if not self._on:
            return
        try:
            title, properties, description = EVENTS[topic]
            channel = self._channels.get(topic) or self._channel(
                topic, title, lambda: _schema(title, properties, description)
            )
            self._file.message(channel, round(t * 1e9), self._json(message))
        except Exception as exc:
            self._fail(exc)

    def bodies(self, bodies: Sequence[Body]) -> None:
        """The bodies the poses will name: their shapes on /scene at 0, and a /pose/<body> channel each."""
        if not self._on:
            return
        try:
            scene = self._channel(SCENE, SCENE_UPDATE, scene_update_schema)
            self._file.message(scene, 0, scene_update(bodies))
            schema = self._file.schema(FRAME_TRANSFORM, "jsonschema", frame_transform_schema())
            self._pose_channels = [
                self._file.channel(POSE.format(body=b.name), "json", schema) for b in bodies
            ]
            self._transforms = FrameTransforms(bodies)
        except Exception as exc:
            self._fail(exc)

    def poses(self, t: float, row: Sequence[float]) -> None:
        """Every body's pose at `t` (a row as hil/outputs/bodies.py `flatten` makes it): a FrameTransform
        on each body's channel."""
        if not self._on or self._transforms is None:
            return
        try:
            at = round(t * 1e9)
            self._file.messages(at, self._pose_channels, self._transforms.encode(at, row))
        except Exception as exc:
            self._fail(exc)

    def stop(self) -> None:
        """The frames still held (those after the last tick), then the file's summary: it is complete,
        also after an error (up to it, with the error as metadata)."""
        try:
            if self._on and self._frames:
                self._write_frames()
        except Exception as exc:
            self._fail(exc)
        try:
            if self.error is not None:
                self._file.metadata(FAILED, {"error": self.error})
            self._file.close()
        except Exception as exc:  # the file stays without its summary: check() says so
            log.warning("run.mcap: cannot finish %s: %s", self.path, exc)
        self._on = False

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _write_frames(self) -> None:
        """The frames taken at one time: raw on /can/frames, then each decoded on its message's channel."""
        frames, self._frames = self._frames, []
        encode, decoders = self._json, self._decoders
        t = self._frames_t
        raw = [
            Frame(
                t,
                m.timestamp,
                m.arbitration_id,
                m.data,
                m.is_extended_id,
                m.is_remote_frame,
                m.is_error_frame,
            )
            for m in frames
        ]
        at = round(self._frames_t * 1e9)
        channels = [self._channels.get(FRAMES) or self._channel(FRAMES, "CanFrames", _frames_schema)]
        messages = [encode(Frames(raw))]
        channel_of, message_of = channels.append, messages.append
        for m in frames:
            data = m.data
            decoder = decoders.get(m.arbitration_id)
            if decoder is None:  # the messages so far go first, before a new channel's records
                self._file.messages(at, channels, messages)
                channels, messages = [], []
                channel_of, message_of = channels.append, messages.append
                decoder = self._decoder(m)
            if decoder is None or len(data) != decoder[1] or not _plain(m):
                continue  # not a DBC message: /can/frames keeps it
            decode, _, channel = decoder
            channel_of(channel)
            message_of(encode(decode(int.from_bytes(data, "little"))))
        self._file.messages(at, channels, messages)

    def _decoder(self, m: can.Message) -> tuple[Callable[[int], dict[str, float | int]], int, int] | None:
        """A DBC message's decoder, from its first frame on (its channel opens then): None before."""
        codec = self._codecs.get(m.arbitration_id)
        if codec is None or len(m.data) != codec.length or not _plain(m):
            return None
        name = SIGNALS.format(message=codec.name)
        channel = self._channel(codec.frame_id, codec.name, lambda: _signals_schema(codec), name)
        decoder = self._decoders[codec.frame_id] = (codec.decode_int, codec.length, channel)
        return decoder

    def _channel(self, what, schema_name: str, schema: Callable[[], bytes], topic: str | None = None) -> int:
        """Register `what`'s channel (once; the first of its messages calls)."""
        if what in self._channels:
            return self._channels[what]
        channel = self._file.channel(
            topic or what, "json", self._file.schema(schema_name, "jsonschema", schema())
        )
        self._channels[what] = channel
        return channel

    def _fail(self, exc: Exception) -> None:
        """Keep the first error and stop the messages; stop() still completes the file up to here."""
        if self.error is None:
            self.error = f"{type(exc).__name__}: {exc}"
            log.warning("run.mcap stopped: %s", self.error)
        self._on = False


def check(path: Path) -> None:
    """Raise unless `path` is a complete MCAP file (its summary reads back) that does not say it failed."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        if reader.get_summary() is None:
            raise ValueError(f"{path.name} has no summary: it was not finished")
        for metadata in reader.iter_metadata():
            if metadata.name == FAILED:
                raise RuntimeError(metadata.metadata.get("error", "failed"))
