"""The rider's intent: lean/twist profiles and the adversarial policy (their torso control: plant/torso.py).

A profile is a sequence of segments (ramp, hold, step, sine, adversarial) played from t = 0; after the last
segment the final value holds. Lean values are degrees of torso lean relative to the chassis (positive:
forward in the pitch plane, toward −y in the roll plane); twist values are the twisting moment on the
seat in Nm (positive: about +z). The rider cannot exceed their capability (RiderParams): lean targets are
clipped to ±max_lean, the lean they intend changes no faster than max_lean_rate and its rate no faster
than max_lean_accel (a trunk has inertia and muscles take time: the hip torque never steps); hip torque
saturates at max_hip_torque.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Literal

import msgspec

from drivers.bounds import LeanDeg, LeanRateDeg, ReactionTime, RobotSpeed, SegmentDuration, SwayHz
from plant.params import RiderParams


class _Segment(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True, tag_field="kind"):
    pass


class Ramp(_Segment, frozen=True, tag="ramp"):
    to: float
    """Within the rider's reach (`beyond_reach`)."""
    duration: SegmentDuration


class Hold(_Segment, frozen=True, tag="hold"):
    duration: SegmentDuration


class Step(_Segment, frozen=True, tag="step"):
    to: float
    """Within the rider's reach (`beyond_reach`)."""


class Sine(_Segment, frozen=True, tag="sine"):
    """Oscillation about the value reached so far."""

    amplitude: float
    """About the value reached so far, within the rider's reach (`beyond_reach`)."""
    frequency_hz: SwayHz
    duration: SegmentDuration


class Adversarial(_Segment, frozen=True, tag="adversarial"):
    """Lean as far as the rider can in the direction the robot is moving (defeating a speed cap or idle);
    at first toward `direction`. The rider commits: they switch sides only when the robot has moved the
    other way faster than `speed_threshold` for `reaction_time` (a person does not flip every wobble).
    Lean profiles only."""

    duration: SegmentDuration
    direction: Literal[-1, 1] = 1
    speed_threshold: RobotSpeed = 0.1
    """|speed| in m/s beyond which motion against the lean counts."""
    reaction_time: ReactionTime = 0.5
    """How long the robot must move against the lean before the rider switches sides, s."""


class Until(_Segment, frozen=True, tag="until"):
    """The paper's protocol (docs/riders.md): lean toward `direction` x `amplitude` at `rate` until the
    robot's |speed| rises above `speed` ("lean until it moves", "brake past 1.4 m/s") or, with
    `when = "slower"`, falls below it ("lean back until it stops"); the rider acts `reaction_time` after
    noticing, and the next segment starts then. `duration` bounds the segment (the trial's end, the
    finishing line). Lean profiles only; `amplitude` and `rate` default to the rider's own
    (RiderParams.lean_amplitude_deg, lean_rate_deg)."""

    duration: SegmentDuration
    direction: Literal[-1, 1] = 1
    speed: RobotSpeed = 0.2
    """|speed|, m/s, whose crossing ends the segment."""
    when: Literal["faster", "slower"] = "faster"
    amplitude: LeanDeg | None = None
    """deg, within the rider's reach (`beyond_reach`); None: the rider's lean_amplitude_deg."""
    rate: LeanRateDeg | None = None
    """deg/s; None: the rider's lean_rate_deg."""
    reaction_time: ReactionTime = 0.3
    """s from the speed's crossing to the rider's next move (a person's reaction to what they see)."""


Segment = Ramp | Hold | Step | Sine | Adversarial | Until


class LeanStyle(msgspec.Struct, frozen=True):
    """How a rider follows a protocol segment that does not say: lean amplitude (deg) and rate (deg/s)."""

    amplitude: float
    rate: float


_RIDER_DEFAULTS = {f.name: f.default for f in msgspec.structs.fields(RiderParams)}
DEFAULT_STYLE = LeanStyle(_RIDER_DEFAULTS["lean_amplitude_deg"], _RIDER_DEFAULTS["lean_rate_deg"])
"""A rider's style when a profile is made without one: RiderParams' defaults."""


_Span = tuple[float, float, "Segment", float]
"""(start, end, segment, value at the start)."""


def _compile(
    segments: Iterable[Segment], t: float, value: float, style: LeanStyle
) -> tuple[list[_Span], float, float]:
    """Spans (start, end, segment, start value) from time t and value; the end time and final value."""
    spans: list[_Span] = []
    for seg in segments:
        if isinstance(seg, Step):
            spans.append((t, t, seg, value))
            value = seg.to
            continue
        end = t + seg.duration
        spans.append((t, end, seg, value))
        if isinstance(seg, Ramp):
            value = seg.to
        elif isinstance(seg, Until):  # never reacted: where the lean got to by the end
            value = _leaning(seg, seg.duration, value, style, math.inf)
        t = end
    return spans, t, value


def beyond_reach(
    segments: Iterable[Segment], limit: float, style: LeanStyle = DEFAULT_STYLE
) -> tuple[int, str, float, float] | None:
    """The first segment that asks for more than ±limit (a rider's largest lean, deg, or twist, Nm), or a
    value that is not a number: its index, its field, the field's value and the value it reaches (a sine's
    amplitude about the value reached before it; the profile starts at 0). An adversarial segment and an
    until without an amplitude lean as far as the rider can; None: all within reach."""
    spans, _, _ = _compile(segments, 0.0, 0.0, style)
    for i, (_, _, seg, v0) in enumerate(spans):
        if isinstance(seg, (Ramp, Step)):
            field, value, reached = "to", seg.to, seg.to
        elif isinstance(seg, Sine):
            field, value, reached = "amplitude", seg.amplitude, abs(v0) + abs(seg.amplitude)
        elif isinstance(seg, Until) and seg.amplitude is not None:
            field, value, reached = "amplitude", seg.amplitude, seg.amplitude
        else:
            continue
        if not abs(reached) <= limit:  # NaN too
            return i, field, value, reached
    return None


def _leaning(seg: Until, elapsed: float, v0: float, style: LeanStyle, limit: float) -> float:
    """An Until's lean after `elapsed` s: from v0 toward its goal at its rate."""
    goal = seg.direction * min(seg.amplitude or style.amplitude, limit)
    step = (seg.rate or style.rate) * elapsed
    return goal if abs(goal - v0) <= step else v0 + math.copysign(step, goal - v0)


class Profile:
    """A compiled segment sequence: target(t, speed, limit) -> the value the rider aims at."""

    def __init__(
        self,
        segments: list[Segment] | tuple[Segment, ...] = (),
        start: float = 0.0,
        value: float = 0.0,
        style: LeanStyle = DEFAULT_STYLE,
    ):
        """Segments play from time `start`, beginning at `value` (a live change starts where the rider is)."""
        self._segments = tuple(segments)
        self.style = style
        self._spans, self.end_time, self.final_value = _compile(self._segments, start, value, style)
        self._side: dict[int, float] = {}  # adversarial span -> the side the rider leans to
        self._against_since: float | None = None
        self._noticed: dict[int, float] = {}  # Until span -> when its speed condition was first seen

    def target(self, t: float, speed: float, limit: float) -> float:
        """The value the rider aims at, at time t; `limit` is the largest they can reach."""
        for i, (start, end, seg, v0) in enumerate(self._spans):
            if t >= end:
                continue
            if t < start:
                return v0
            # A step has start == end, so reaching here means it has not happened yet: v0 holds.
            if isinstance(seg, Ramp):
                return v0 + (seg.to - v0) * (t - start) / (end - start)
            if isinstance(seg, Sine):
                return v0 + seg.amplitude * math.sin(2.0 * math.pi * seg.frequency_hz * (t - start))
            if isinstance(seg, Adversarial):
                return self._adversarial_side(i, seg, t, speed) * limit
            if isinstance(seg, Until):
                value = _leaning(seg, t - start, v0, self.style, limit)
                if self._reacted(i, seg, t, speed):
                    self._end_early(i, t, value)
                    return self.target(t, speed, limit)
                return value
            return v0
        return self.final_value

    def _reacted(self, span: int, seg: Until, t: float, speed: float) -> bool:
        crossed = abs(speed) > seg.speed if seg.when == "faster" else abs(speed) < seg.speed
        if crossed:
            self._noticed.setdefault(span, t)
        return span in self._noticed and t - self._noticed[span] >= seg.reaction_time

    def _end_early(self, i: int, t: float, value: float) -> None:
        """Span i ends at t with `value`: the segments after it start from there."""
        start, _, seg, v0 = self._spans[i]
        later, self.end_time, self.final_value = _compile(self._segments[i + 1 :], t, value, self.style)
        self._spans[i:] = [(start, t, seg, v0), *later]

    def _adversarial_side(self, span: int, seg: Adversarial, t: float, speed: float) -> float:
        side = self._side.setdefault(span, float(seg.direction))
        if speed * side < -seg.speed_threshold:
            if self._against_since is None:
                self._against_since = t
            if t - self._against_since >= seg.reaction_time:
                side = self._side[span] = -side
                self._against_since = None
        else:
            self._against_since = None
        return side
