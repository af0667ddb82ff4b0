"""The supervisor's decisions: a pure state machine (no I/O, no clock; time comes with each observation).

    NORMAL ──over cap──▶ LIMITING ──overpowered──▶ STOPPING ──standstill──▶ ESTOP ──reset──▶ NORMAL
       │                    │                         │ stop fails             ▲
       ├────────────────────┴──controlled cause───────┘                        │
       ├──immediate cause, a lying sensor, a drive fault──▶ RECOVERY ──at rest─┤
       └──balance lost, drives at fault, operator's cut_power (any state)──────┘

Stop category by cause (IEC 60204-1 §9.2.2; docs/safety.md): a *controlled* cause (operator, speed, rider
absent, bus integrity, the seat) brakes to standstill through the controller (SC idle) and then removes
power, as long as the controller is healthy and its inputs trusted. When the controller cannot be trusted to
stop the robot (it is silent or faulted, commands nonsense, balances on a sensor that lies, drives a drive
that does not do its job, or its stop fails) the supervisor's recovery law takes the drives (RECOVERY,
SUPERVISOR_ESTOP.Takeover; safety/recovery.py) and power goes off once the robot is at rest: a ballbot falls
when power is cut in motion. Power goes off at once only for CUT_POWER causes (balance already lost, the
drives themselves at fault, the operator's category-0 request) or when the recovery law has nothing to
balance on. ESTOP latches; only an operator reset at standstill with every monitor healthy leaves it (the
takeover latches with it), and a reset permits motion, it never causes it.

Power is removed on two paths (IEC 60204-1, ISO 13849): the drives' permission (SUPERVISOR_ESTOP), and
the main contactor in their power feed. In ESTOP the drives must confirm that they are off (their feedback
reports Enabled = 0) within `drives.confirm`; if one does not (a power stage stuck on, a drive that cannot
be heard) the contactor opens (DRIVE_NOT_DISABLED), and it does not close again until a valid reset. Drives
whose Enabled is only their firmware's state (`stage_read_back` False: ODrive, CiA 402) cannot confirm a
power stage off, so there both paths act on every e-stop: the contactor opens `drives.confirm` after ESTOP
is entered. An open contactor that a drive still reports powered after `drives.confirm` is CONTACTOR_FAULT.

Root cause: causes are checked from source to consequence (the order of `_immediate` and `_controlled`),
so when several hold in one update the most upstream one names the transition; a stop already under way
keeps its cause unless an immediate cause escalates it. A drive's command watchdog trips before the
controller's heartbeat watchdog when the controller dies (20 ms < 50 ms): a tripped watchdog while the
heartbeat has been silent at least that long is HEARTBEAT_LOST, not DRIVE_FAULT.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from drivers.schemas import ScCommand, ScRequest
from drivers.vocabulary import Cause, ControllerState, Event, EventKind, State
from safety.config import SupervisorConfig
from safety.observation import Observation
from safety.reactions import CUT_POWER, FINDINGS, TAKEOVER_CAUSES


class Decision:
    """What the machine decides at one update (a plain class: safety/observation.py says why)."""

    def __init__(
        self,
        state: State,
        cause: Cause,
        drives_permitted: bool,
        cap: float,
        command: ScCommand,
        since: float,
        contactor_closed: bool = True,
        takeover: bool = False,
        alert: int = 0,
        estop_by: str = "",
    ):
        self.state = state
        self.cause = cause
        self.drives_permitted = drives_permitted
        self.cap = cap
        """The cap in force, m/s."""
        self.command = command
        self.since = since
        self.contactor_closed = contactor_closed
        """The main contactor may stay closed (SUPERVISOR_ESTOP.Contactor)."""
        self.takeover = takeover
        """The recovery law holds the drives (SUPERVISOR_ESTOP.Takeover): they follow SUPERVISOR_RECOVERY
        only."""
        self.alert = alert
        """What the rider is told: 0 nothing, 1 slow down, 2 stop, sit up and hold still."""
        self.estop_by = estop_by
        """Whose operator e-stop (or category-0 cut) is latched ('' none): the robot ends in ESTOP and waits
        for a reset, whatever stop was already under way when it came."""


def silent(ages: Mapping[str, float], stream: str, timeout: float, armed: bool) -> bool:
    """The stream's last input is older than `timeout` (one never heard counts only once `armed`)."""
    age = ages.get(stream, math.inf)
    return age > timeout and (armed or age != math.inf)


class SafetyMachine:
    def __init__(
        self,
        config: SupervisorConfig | None = None,
        torque_limit: float = 3.75,
        drive_watchdog: float = 0.02,
        stage_read_back: bool = True,
    ):
        self.config = c = config or SupervisorConfig()
        self.tilt_limit = math.radians(c.motion.tilt_limit_deg)
        self._standstill_tilt = math.radians(c.stop.standstill_tilt_deg)
        self.torque_limit = torque_limit
        self.drive_watchdog = drive_watchdog
        """The drives' own command watchdog (robot file), s: for the root-cause rule."""
        self.stage_read_back = stage_read_back
        """The drives' Enabled reads back their power stage (else the contactor opens on every e-stop)."""
        self.state, self.cause, self.since = State.NORMAL, Cause.NONE, 0.0
        self.started: float | None = None
        self.permitted_since = 0.0
        """When the drives last got their permission (start-up or a reset)."""
        self.contactor_closed = True
        self.takeover = False
        """Latched from the entry to RECOVERY until a valid reset."""
        self.estop_by = ""
        """The source of the operator e-stop latched now ('' none): taken in whatever the state (a stop
        already under way keeps its cause, and ends in ESTOP all the same), cleared by a valid reset."""
        self._contactor_opened = -math.inf
        self._contactor_fault = False
        self.events: list[Event] = []
        self.reset_by: list[tuple[float, str]] = []
        self._clear_timers()
        self._saturated_since: float | None = None
        self._absent_since: float | None = None
        self._over_since: float | None = None
        self._sc_seen = False
        self._last_cap = math.inf
        self._ramp = (-math.inf, 0.0)
        """(time, speed) when the cap last dropped below the speed."""

    def _clear_timers(self) -> None:
        self._entry_speed = 0.0
        self._under_since: float | None = None
        self._still_since: float | None = None
        self._failing_since: float | None = None
        self._reached_standstill = False

    # ----------------------------------------------------------------------------------------- decide
    def update(self, obs: Observation) -> Decision:
        started = self.started
        if started is None:
            started = self.started = self.since = self.permitted_since = obs.t
        armed = obs.t - started >= self.config.watchdogs.startup_grace
        """The stream watchdogs judge a stream never heard from only after the start-up grace."""
        if obs.ages.get("sc", math.inf) != math.inf:
            self._sc_seen = True
        if obs.operator in ("estop", "cut_power"):
            self.estop_by = obs.operator_source or "?"
        immediate = self._immediate(obs, armed)
        controlled = self._controlled(obs, armed)
        if self.state is State.ESTOP:
            if obs.operator == "reset":
                self._try_reset(obs)
            else:
                self._second_path(obs)
        elif self.state is State.RECOVERY:
            self._recovering(obs, immediate)
        elif immediate is not None:
            self._take_over_or_cut(immediate[0], obs, immediate[1])
        elif self.state is State.STOPPING:
            self._stopping(obs)
        elif controlled is not None:
            self._stop(controlled[0], controlled[1], obs)
        else:
            self._limit(obs)
        # The Decision: what the state this update leaves the machine in allows.
        cap = self.active_cap()
        return Decision(
            self.state,
            self.cause,
            self.state is not State.ESTOP,
            cap,
            self.forward(obs.request, cap),
            self.since,
            self.contactor_closed,
            self.takeover,
            self.alert(),
            self.estop_by,
        )

    def _immediate(self, obs: Observation, armed: bool) -> tuple[Cause, str] | None:
        """The first immediate cause that holds, from source to consequence, and what it saw."""
        c, w = self.config, self.config.watchdogs
        ages = obs.ages
        if obs.operator == "cut_power":
            return Cause.OPERATOR_CUT, f"by {obs.operator_source or '?'}"
        if silent(ages, "heartbeat", w.heartbeat, armed):
            return Cause.HEARTBEAT_LOST, ""
        tripped = next((i for i, d in enumerate(obs.drives, 1) if d.watchdog), None)
        heartbeat_age = ages.get("heartbeat", math.inf)
        if tripped and self.state is not State.ESTOP and heartbeat_age >= self.drive_watchdog - 1e-9:
            return Cause.HEARTBEAT_LOST, (
                f"drive {tripped}'s command watchdog tripped and the heartbeat is "
                f"{heartbeat_age * 1e3:.1f} ms old: the controller is silent"
            )
        if obs.controller_state == ControllerState.FAULT:
            return Cause.CONTROLLER_FAULT, ""
        if silent(ages, "drives", w.drives, armed):
            return Cause.DRIVES_SILENT, ""
        if silent(ages, "imu", w.imu, armed):
            return Cause.IMU_SILENT, ""
        if obs.tilt is not None and obs.tilt > self.tilt_limit:
            return Cause.TILT, ""
        if obs.torque_peak > c.motion.torque_range * self.torque_limit:
            return Cause.TORQUE_RANGE, f"{obs.torque_peak:.3f} Nm commanded"
        if obs.torque_peak >= c.motion.saturation_fraction * self.torque_limit:
            if self._saturated_since is None:
                self._saturated_since = obs.t
            if obs.t - self._saturated_since >= c.motion.saturation_time:
                return Cause.TORQUE_SATURATED, ""
        else:
            self._saturated_since = None
        return None

    def _controlled(self, obs: Observation, armed: bool) -> tuple[Cause, str] | None:
        """The first controlled cause that holds, from source to consequence, and what it saw."""
        c, w = self.config, self.config.watchdogs
        if obs.operator == "estop":
            return Cause.OPERATOR_ESTOP, f"by {obs.operator_source or '?'}"
        if obs.button:
            return Cause.BUTTON_ESTOP, ""
        if obs.e2e_invalid:
            return (
                Cause.E2E_ERRORS,
                f"{', '.join(obs.e2e_invalid)}: more E2E errors than the window tolerates",
            )
        wrench_age = obs.ages.get("wrench", math.inf)
        if w.require_wrench and wrench_age > w.wrench and (armed or wrench_age != math.inf):
            return Cause.WRENCH_SILENT, ""
        if obs.findings:
            first = min(obs.findings, key=lambda f: FINDINGS.index(f.cause))
            return first.cause, first.detail
        drive = self._drive_fault(obs)
        if drive:
            return Cause.DRIVE_FAULT, drive
        if obs.speed is not None and obs.speed > c.speed.hard_limit:
            return Cause.HARD_SPEED, ""
        moving = obs.speed is not None and obs.speed > c.stop.standstill_speed
        if obs.seat_load is not None and obs.seat_load < c.motion.rider_min_load and moving:
            if self._absent_since is None:
                self._absent_since = obs.t
            if obs.t - self._absent_since >= c.motion.rider_absent_time:
                return Cause.RIDER_ABSENT, ""
        else:
            self._absent_since = None
        return None

    def _drive_fault(self, obs: Observation) -> str:
        """Why a permitted drive is not doing its job ('' if each is): it reports its watchdog tripped
        (its commands are lost) or a fault, or stays off although permitted and told to enable."""
        if self.state is State.ESTOP:
            return ""
        confirm = self.config.drives.confirm
        permitted_for = obs.t - self.permitted_since
        for i, d in enumerate(obs.drives, 1):
            if d.watchdog:
                return f"drive {i}: command watchdog tripped (its commands are lost)"
            if d.fault:
                return f"drive {i} reports a fault"
            if d.enabled is False and min(d.commanded_for, permitted_for) >= confirm - 1e-9:
                return f"drive {i} is off although permitted and told to enable"
        return ""

    def _stop(self, cause: Cause, detail: str, obs: Observation) -> None:
        """A controlled stop if the controller is balancing on inputs it can trust; else the recovery law."""
        healthy = obs.controller_state == ControllerState.BALANCING and obs.speed is not None
        if healthy and cause not in TAKEOVER_CAUSES:
            self._enter(State.STOPPING, cause, obs, detail)
        else:
            self._take_over_or_cut(cause, obs, detail)

    def _take_over_or_cut(self, cause: Cause, obs: Observation, detail: str = "") -> None:
        """The controller cannot stop the robot: the recovery law takes the drives; power goes off at once
        only for a CUT_POWER cause or when the recovery law lacks the inputs to balance."""
        if cause in CUT_POWER or not obs.recoverable:
            self._enter(State.ESTOP, cause, obs, detail)
        else:
            self._enter(State.RECOVERY, cause, obs, detail)

    def _recovering(self, obs: Observation, immediate: tuple[Cause, str] | None) -> None:
        """The recovery law holds the drives: power off once at rest and upright, or at once when balance
        is lost, the drives are the fault, the operator asks for category 0, or its inputs are gone. The
        controller's own faults (heartbeat, torque) no longer matter: its commands are not followed."""
        if immediate is not None and immediate[0] in CUT_POWER:
            self._enter(State.ESTOP, immediate[0], obs, immediate[1])
        elif not obs.recoverable:
            self._enter(State.ESTOP, self.cause, obs, "the recovery law lost the inputs it needs")
        elif self._at_rest(obs):
            self._enter(State.ESTOP, self.cause, obs, detail="at rest under the recovery law: drives off")

    def _at_rest(self, obs: Observation) -> bool:
        """At standstill and upright for `standstill_time` (a robot tilted at rest would tip when its power
        goes off: it keeps balancing until the rider sits up)."""
        st = self.config.stop
        still = obs.speed is not None and obs.speed <= st.standstill_speed
        if still and obs.tilt is not None and obs.tilt <= self._standstill_tilt:
            if self._still_since is None:
                self._still_since = obs.t
            return obs.t - self._still_since >= st.standstill_time
        self._still_since = None
        return False

    def _limit(self, obs: Observation) -> None:
        s = self.config.speed
        allowed = self._allowed_speed(obs)
        speed = obs.speed
        if self.state is State.LIMITING and self.cause is Cause.OVER_CAP:
            over_too_long = self._under_since is None and obs.t - self.since > s.limit_timeout
            if speed is not None and (speed > self._entry_speed + s.rise_margin or over_too_long):
                self._stop(Cause.OVERPOWERED, "", obs)
                return
            if speed is not None and speed <= allowed + s.margin:
                if self._under_since is None:
                    self._under_since = obs.t
                if obs.t - self._under_since >= s.release_window:
                    self._enter_limit_or_normal(obs)
            else:
                self._under_since = None
            return
        if speed is not None and speed > allowed + s.margin:
            if self._over_since is None:
                self._over_since = obs.t
            if obs.t - self._over_since >= s.window:
                self._enter(State.LIMITING, Cause.OVER_CAP, obs)
                return
        else:
            self._over_since = None
        self._enter_limit_or_normal(obs)

    def _allowed_speed(self, obs: Observation) -> float:
        """The enforced cap, or the braking ramp down to it after it dropped below the speed."""
        cap = self._enforced_cap(obs)
        if cap < self._last_cap and obs.speed is not None and obs.speed > cap:
            self._ramp = (obs.t, obs.speed)
        self._last_cap = cap
        t0, v0 = self._ramp
        s, elapsed = self.config.speed, obs.t - t0
        if elapsed < s.brake_delay:
            return max(cap, v0 + s.rise_margin)
        return max(cap, v0 - s.decel * (elapsed - s.brake_delay))

    def _enter_limit_or_normal(self, obs: Observation) -> None:
        if self._sc_silent(obs):
            if (self.state, self.cause) != (State.LIMITING, Cause.SC_SILENT):
                self._enter(State.LIMITING, Cause.SC_SILENT, obs)
        elif self.state is not State.NORMAL:
            self._enter(State.NORMAL, Cause.NONE, obs)

    def _stopping(self, obs: Observation) -> None:
        st, speed = self.config.stop, obs.speed
        if speed is None:
            return  # a speed stream is silent: the immediate causes have already acted
        rising = speed > self._entry_speed + self.config.speed.rise_margin
        moving_again = self._reached_standstill and speed > st.motion_after_standstill
        if rising or moving_again:
            # The stop fails; only when it keeps failing is cutting power (a tip) the lesser hazard.
            self._still_since = None
            if self._failing_since is None:
                self._failing_since = obs.t
            if obs.t - self._failing_since >= st.escalation_time - 1e-9:
                cause = Cause.STOP_INEFFECTIVE if rising else Cause.MOTION_AFTER_STANDSTILL
                self._take_over_or_cut(cause, obs)
            return
        self._failing_since = None
        if speed <= st.standstill_speed:
            self._reached_standstill = True
            if obs.tilt is None or obs.tilt > self._standstill_tilt:
                self._still_since = None  # stopped but tilted: cutting power now would tip it
                return
            if self._still_since is None:
                self._still_since = obs.t
            if obs.t - self._still_since >= st.standstill_time:
                self._enter(State.ESTOP, self.cause, obs, detail="standstill reached: drives off")
        else:
            self._still_since = None
            if not self._reached_standstill and obs.t - self.since > st.timeout:
                self._take_over_or_cut(Cause.STOP_TIMEOUT, obs)

    def _second_path(self, obs: Observation) -> None:
        """In ESTOP: open the main contactor when a drive does not confirm it is off within the bound, and
        check that the contactor really cut their power (external device monitoring)."""
        confirm = self.config.drives.confirm
        if self.contactor_closed:
            if obs.t - self.since < confirm - 1e-9:
                return
            if not obs.drives:
                unconfirmed = "no drive feedback"
            else:
                on = [str(i) for i, d in enumerate(obs.drives, 1) if d.enabled is not False]
                unconfirmed = f"drive {', '.join(on)} not confirmed off" if on else ""
            if unconfirmed:
                self.contactor_closed, self._contactor_opened = False, obs.t
                self._enter(
                    State.ESTOP,
                    Cause.DRIVE_NOT_DISABLED,
                    obs,
                    f"{unconfirmed} {(obs.t - self.since) * 1e3:.1f} ms after the e-stop: "
                    "main contactor opened",
                    keep_since=True,
                )
            elif not self.stage_read_back:
                self.contactor_closed, self._contactor_opened = False, obs.t
                self._log(
                    obs,
                    "contactor_opened",
                    self.state,
                    self.cause,
                    "the drives' state cannot show a power stage stuck on: main contactor opened "
                    f"{(obs.t - self.since) * 1e3:.1f} ms after the e-stop",
                )
        elif not self._contactor_fault and obs.t - self._contactor_opened >= confirm - 1e-9:
            live = [str(i) for i, d in enumerate(obs.drives, 1) if d.bus_powered]
            if live:
                self._contactor_fault = True
                self._enter(
                    State.ESTOP,
                    Cause.CONTACTOR_FAULT,
                    obs,
                    f"drive {', '.join(live)} still reports its DC bus live "
                    f"{(obs.t - self._contactor_opened) * 1e3:.1f} ms after the contactor was told to open",
                    keep_since=True,
                )

    def _try_reset(self, obs: Observation) -> None:
        why = self.reset_refusal(obs)
        if why:
            self._log(obs, "reset_refused", self.state, self.cause, why)
            return
        self.reset_by.append((obs.t, obs.operator_source))
        self._saturated_since = self._absent_since = self._over_since = None
        self.contactor_closed, self.permitted_since, self.takeover = True, obs.t, False
        self.estop_by = ""
        self._enter(State.NORMAL, Cause.RESET, obs, detail=f"reset by {obs.operator_source or '?'}")

    def reset_refusal(self, obs: Observation) -> str:
        """Why a reset is refused now ('' if it would be accepted)."""
        c, w = self.config, self.config.watchdogs
        if obs.speed is None or obs.speed > c.stop.standstill_speed:
            return "not at standstill"
        if obs.tilt is None or obs.tilt > self.tilt_limit:
            return "tilt unknown or beyond the limit"
        if obs.button:
            return "e-stop button still pressed"
        timeouts = {"drives": w.drives, "imu": w.imu, "heartbeat": w.heartbeat}
        if w.require_wrench:
            timeouts["wrench"] = w.wrench
        for stream, timeout in timeouts.items():
            if obs.ages.get(stream, math.inf) > timeout:
                return f"{stream} silent"
        if obs.controller_state == ControllerState.FAULT:
            return "controller reports a fault"
        if obs.e2e_invalid:
            return f"E2E errors persist on {', '.join(obs.e2e_invalid)}"
        if self._contactor_fault:
            return "the main contactor did not open when told to (welded?)"
        on = [str(i) for i, d in enumerate(obs.drives, 1) if d.enabled]
        if on:
            return (
                f"drive {', '.join(on)} still enabled without permission: its power stage does not turn off"
            )
        if obs.findings:
            return f"{obs.findings[0].cause.name}: {obs.findings[0].detail}"
        return ""

    # ---------------------------------------------------------------------------------------- outputs
    def _enter(
        self, state: State, cause: Cause, obs: Observation, detail: str = "", keep_since: bool = False
    ) -> None:
        """Enter `state` with `cause`; keep_since: a new cause within the same state (the second path)."""
        previous, previous_cause = self.state, self.cause
        self.state, self.cause = state, cause
        if keep_since:
            self._log(obs, "transition", previous, previous_cause, detail)
            return
        self.since = obs.t
        self.takeover = self.takeover or state is State.RECOVERY
        self._clear_timers()
        self._entry_speed = obs.speed or 0.0
        if state is State.NORMAL:
            self._over_since = None
        self._log(obs, "transition", previous, previous_cause, detail)

    def _log(
        self, obs: Observation, kind: EventKind, previous: State, previous_cause: Cause, detail: str
    ) -> None:
        self.events.append(
            Event(
                obs.t,
                kind,
                previous.name,
                self.state.name,
                (self.cause if kind == "transition" else previous_cause).name,
                detail,
                {
                    "speed": obs.speed,
                    "tilt_deg": None if obs.tilt is None else math.degrees(obs.tilt),
                    "torque_peak": obs.torque_peak,
                    "seat_load": obs.seat_load,
                    "e2e_errors": obs.e2e_errors,
                    **{f"age_{k}": v for k, v in obs.ages.items() if math.isfinite(v)},
                },
            )
        )

    def _sc_silent(self, obs: Observation) -> bool:
        return self._sc_seen and obs.ages.get("sc", math.inf) > self.config.watchdogs.sc

    def active_cap(self) -> float:
        """The cap the supervisor grants in its current state, m/s."""
        if self.state in (State.STOPPING, State.ESTOP, State.RECOVERY) or self.cause is Cause.OVER_CAP:
            return 0.0
        if self.cause is Cause.SC_SILENT:
            return self.config.speed.reduced_cap
        return self.config.speed.absolute_cap

    def _enforced_cap(self, obs: Observation) -> float:
        """The cap the speed is held to: the active cap, and the request's if it is enforced."""
        speed = self.config.speed
        if self._sc_silent(obs):
            return speed.reduced_cap
        r = obs.request
        if r is None or not speed.enforce_requested_cap:
            return speed.absolute_cap
        return min(speed.absolute_cap, r.speed_limit())

    def alert(self) -> int:
        """What the rider is told: slow down while limited, stop (sit up, hold still) from a stop on."""
        if self.state is State.NORMAL:
            return 0
        return 1 if self.state is State.LIMITING else 2

    def forward(self, request: ScRequest | None, cap: float) -> ScCommand:
        """The request clamped to `cap`: never above it, `free` becomes `limit` at the cap, 0 is idle (never
        `free`). Its seq and stamp are the node's to set."""
        reason = "" if self.cause is Cause.NONE else self.cause.name
        if request is None or self.cause is Cause.SC_SILENT:  # a silent agent's last request is stale
            want, source = math.inf, "supervisor"
        else:
            want, source = request.speed_limit(), request.source
        granted = min(want, cap)
        if granted != want:
            source = "supervisor" if request is None else source
            reason = reason or f"capped at {cap:g} m/s"
        if granted <= 0.0:
            return ScCommand(seq=0, stamp=0.0, mode="idle", speed_cap=0.0, source=source, reason=reason)
        return ScCommand(seq=0, stamp=0.0, mode="limit", speed_cap=granted, source=source, reason=reason)
