"""Every fault of the catalog, injected into a rig with no controller: its effect on the wire (CAN frames,
zenoh puts) or on the plant, against a healthy twin with the same seed where a comparison says more."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from drivers.e2e import E2EStatus
from drivers.zenoh_link import LOOPBACK, open_session
from hil.faults import CATALOG, FAMILIES, parse_fault
from hil.faults.frames import RX_MESSAGES
from hil.run.drives_port import DrivesPort
from hil.run.rig import Rig
from tests.fault_bench import DT, Bench
from tests.zenoh_helpers import hub_endpoint

AT = 0.05
START = round(AT / DT)  # tick 20
TICKS = 60
Q = 1e-4  # IMU attitude resolution, rad


@pytest.fixture(scope="module")
def session():
    s = open_session(LOOPBACK, "hub", hub_endpoint())
    yield s
    s.close()


@pytest.fixture
def pair(session):
    """run(fault) -> (faulty bench, healthy twin) after TICKS ticks."""
    benches = []

    def run(*faults, ticks=TICKS):
        faulty, healthy = Bench(session, faults), Bench(session)
        benches.extend([faulty, healthy])
        faulty.run(ticks)
        healthy.run(ticks)
        return faulty, healthy

    yield run
    for b in benches:
        b.close()


def pitch(bench):
    return bench.series("IMU_ATTITUDE", "Pitch")


def imu_fault(kind, **params):
    return {"kind": kind, "channel": "imu.pitch", "at": AT, **params}


def test_every_fault_of_the_catalog_has_a_family_and_a_doc():
    assert len(CATALOG) == sum(len(f) for f in FAMILIES.values()) == 44
    for kind, cls in CATALOG.items():
        families = ("sensor", "can", "zenoh", "plant", "process", "odrive", "cia402", "xsens")
        assert kind.split(".")[0] in families
        assert cls.__doc__ and len(cls.__doc__.split()) >= 5, kind


# ------------------------------------------------------------------------------------------- sensors
def test_sensor_off_silences_the_frame_that_carries_the_channel(pair):
    faulty, healthy = pair(imu_fault("sensor.off"))
    assert set(pitch(healthy)) == set(range(1, TICKS + 1))
    assert set(pitch(faulty)) == set(range(1, START))
    assert set(faulty.series("IMU_RATE", "RateX")) == set(range(1, TICKS + 1)), "other frames go on"


def test_sensor_stuck_holds_the_value_it_had_at_the_start(pair):
    faulty, healthy = pair(imu_fault("sensor.stuck"))
    f, h = pitch(faulty), pitch(healthy)
    assert all(f[k] == h[k] for k in range(1, START))
    assert {f[k] for k in range(START, TICKS + 1)} == {h[START]}
    assert len({h[k] for k in range(START, TICKS + 1)}) > 5, "the healthy channel moves (noise)"


def test_sensor_stuck_at_a_given_value(pair):
    faulty, _ = pair(imu_fault("sensor.stuck", value=0.2))
    held = [v for k, v in pitch(faulty).items() if k >= START]
    assert len(held) == TICKS - START + 1 and all(v == pytest.approx(0.2, abs=Q) for v in held)


@pytest.mark.parametrize(
    "kind, params, expected",
    [
        ("sensor.bias", {"offset": 0.05}, lambda h, t: h + 0.05),
        ("sensor.scale", {"factor": -3.0}, lambda h, t: -3.0 * h),
        ("sensor.sign_flip", {}, lambda h, t: -h),
        ("sensor.drift", {"rate": 2.0}, lambda h, t: h + 2.0 * (t - AT)),
    ],
)
def test_deterministic_sensor_faults_follow_their_law(pair, kind, params, expected):
    faulty, healthy = pair(imu_fault(kind, **params))
    f, h = pitch(faulty), pitch(healthy)
    for k in range(1, TICKS + 1):
        want = expected(h[k], k * DT) if k >= START else h[k]
        assert f[k] == pytest.approx(want, abs=1.5 * Q + 1e-3 * abs(want)), (kind, k)


def test_sensor_noise_adds_noise_of_the_given_sigma(pair):
    faulty, healthy = pair(imu_fault("sensor.noise", sigma=0.05), ticks=200)
    f, h = pitch(faulty), pitch(healthy)
    diff = np.array([f[k] - h[k] for k in range(START, 201)])
    assert 0.04 < diff.std() < 0.06 and abs(diff.mean()) < 0.015
    assert all(f[k] == h[k] for k in range(1, START))


def test_sensor_spikes_are_single_samples_of_the_given_amplitude(pair):
    faulty, healthy = pair(imu_fault("sensor.spikes", amplitude=0.5, rate=0.3), ticks=200)
    f, h = pitch(faulty), pitch(healthy)
    diff = np.array([f[k] - h[k] for k in range(START, 201)])
    spikes = np.abs(diff) > 0.25
    assert 0.15 < spikes.mean() < 0.45
    assert np.allclose(np.abs(diff[spikes]), 0.5, atol=2 * Q)
    assert np.allclose(diff[~spikes], 0.0, atol=Q)
    assert (diff > 0.25).any() and (diff < -0.25).any(), "both signs"


def test_sensor_delayed_reports_the_past(pair):
    faulty, healthy = pair(imu_fault("sensor.delayed", delay=0.01))  # 4 ticks
    f, h = pitch(faulty), pitch(healthy)
    for k in range(START + 4, TICKS + 1):
        assert f[k] == h[k - 4]
    assert all(f[k] == h[START] for k in range(START, START + 4)), "held at its first value until then"


def test_sensor_slow_updates_at_the_lower_rate(pair):
    faulty, healthy = pair(imu_fault("sensor.slow", period=0.025))  # every 10 ticks
    f, h = pitch(faulty), pitch(healthy)
    for k in range(START, TICKS + 1):
        assert f[k] == h[START + 10 * ((k - START) // 10)]


def test_sensor_intermittent_drops_frames_at_the_given_rate(pair):
    faulty, healthy = pair(imu_fault("sensor.intermittent", rate=0.5), ticks=200)
    f, h = pitch(faulty), pitch(healthy)
    missing = [k for k in range(START, 201) if k not in f]
    assert 0.3 < len(missing) / (201 - START) < 0.7
    assert all(f[k] == h[k] for k in f)


def test_encoder_bias_is_in_radians_at_the_motor(pair):
    faulty, healthy = pair({"kind": "sensor.bias", "channel": "encoder2", "offset": 1.0, "at": AT})
    f, h = faulty.series("DRIVE2_FEEDBACK", "Position"), healthy.series("DRIVE2_FEEDBACK", "Position")
    per_rad = 8192 / (2 * math.pi)
    assert all(f[k] - h[k] == round(per_rad) or f[k] - h[k] == round(per_rad) + 1 for k in range(START, 61))
    assert faulty.series("DRIVE1_FEEDBACK", "Position") == healthy.series("DRIVE1_FEEDBACK", "Position")


def test_a_dead_load_cell_skews_the_wrench_along_its_calibration_column(pair):
    faulty, healthy = pair({"kind": "sensor.off", "channel": "tes.cell1", "at": AT})
    f = {w.seq: w for w in faulty.tes.drain()}
    h = {w.seq: w for w in healthy.tes.drain()}
    assert f[START - 1] == h[START - 1]
    column = faulty.plant.tes_model.calibration[:, 0]
    for k in range(START, TICKS + 1):
        delta = np.array([*h[k].force, *h[k].moment]) - np.array([*f[k].force, *f[k].moment])
        assert np.linalg.norm(delta) > 1.0, "a seated rider loads every cell"
        cos = abs(delta @ column) / (np.linalg.norm(delta) * np.linalg.norm(column))
        assert cos > 0.999, "the missing reading enters through its own column of −E"


# -------------------------------------------------------------------------------------------- frames
def can_fault(kind, message="IMU_RATE", **params):
    return {"kind": kind, "message": message, "at": AT, **params}


def test_can_drop_burst_loses_exactly_count_frames(pair):
    faulty, _ = pair(can_fault("can.drop", count=5))
    ticks = [k for k, _ in faulty.decoded("IMU_RATE")]
    assert [k for k in range(1, TICKS + 1) if k not in ticks] == list(range(START, START + 5))
    assert faulty.statuses("IMU_RATE").count("LOST") == 1
    assert faulty.rig.faults.events[-1].action == "end", "the burst ends the fault"


def test_can_drop_rate_loses_about_that_share(pair):
    faulty, _ = pair(can_fault("can.drop", rate=0.5), ticks=200)
    lost = 200 - len(faulty.decoded("IMU_RATE"))
    assert 50 < lost < 130


def test_can_delay_holds_frames_for_the_delay_in_simulated_time(pair):
    faulty, healthy = pair(can_fault("can.delay", delay=0.01))
    f = faulty.series("IMU_RATE", "RateX")
    h = healthy.series("IMU_RATE", "RateX")
    # The frame of tick k goes out with tick k + 4, before that tick's SYNC.
    assert all(f[k] == h[k - 4] for k in range(START + 4, TICKS + 1))
    assert all(k not in f for k in range(START, START + 4))
    assert set(faulty.statuses("IMU_RATE")) == {"OK"}


def test_can_repeat_sends_copies_the_receiver_sees_as_repeated(pair):
    faulty, _ = pair(can_fault("can.repeat", times=2))
    statuses = faulty.statuses("IMU_RATE")
    assert statuses.count("REPEATED") == 2 * (TICKS - START + 1)


def test_can_reorder_swaps_neighbours(pair):
    faulty, _ = pair(can_fault("can.reorder"))
    statuses = faulty.statuses("IMU_RATE")
    assert statuses.count("OUT_OF_ORDER") >= (TICKS - START) // 2 - 1


def test_can_corrupt_fails_the_crc(pair):
    faulty, healthy = pair(can_fault("can.corrupt", bit=13))
    statuses = faulty.statuses("IMU_RATE")
    assert statuses[: START - 1] == ["OK"] * (START - 1)
    assert set(statuses[START - 1 :]) == {"CRC_ERROR"}
    f = [m for _, m, _ in faulty.frames if m.arbitration_id == 650]
    h = [m for _, m, _ in healthy.frames if m.arbitration_id == 650]
    assert int.from_bytes(f[-1].data, "little") ^ int.from_bytes(h[-1].data, "little") == 1 << 13


@pytest.mark.parametrize("mode, status", [("frozen", "REPEATED"), ("skip", "LOST")])
def test_can_wrong_counter_keeps_a_valid_crc(pair, mode, status):
    faulty, _ = pair(can_fault("can.wrong_counter", mode=mode))
    statuses = faulty.statuses("IMU_RATE")
    assert set(statuses[START:]) == {status}, "every frame after the first faulty one"
    assert "CRC_ERROR" not in statuses


def test_can_wrong_dlc_is_malformed_for_the_receiver(pair):
    faulty, _ = pair(can_fault("can.wrong_dlc", length=5))
    assert faulty.listener.stats.malformed["wrong_length"] == TICKS - START + 1
    assert all(len(m.data) == 5 for k, m, _ in faulty.frames if m.arbitration_id == 650 and k >= START)


def test_can_masquerade_under_another_id_fails_its_crc(pair):
    faulty, _ = pair(can_fault("can.masquerade", as_message="IMU_ACCEL"))
    statuses = faulty.statuses("IMU_ACCEL")
    assert statuses.count("CRC_ERROR") == TICKS - START + 1
    assert set(faulty.statuses("IMU_RATE")) == {"OK"}


def test_can_replay_from_one_counter_period_back_passes_e2e(pair):
    # A replayed loop of exactly 16 frames: the alive counter comes round, the CRC is the original's, so
    # every frame is OK to E2E while its data is 16 frames (40 ms) stale and repeats (the supervisor's
    # freshness check is in tests/test_safety_diagnostics.py and the coverage campaign).
    faulty, healthy = pair(can_fault("can.replay", frames=16), ticks=TICKS + 40)
    assert set(faulty.statuses("IMU_RATE")) == {"OK"}
    f = [m.data for k, m, _ in faulty.frames if m.arbitration_id == 650 and k >= START]
    h = [m.data for k, m, _ in healthy.frames if m.arbitration_id == 650 and k >= START]
    assert f[:16] == h[:16], "recorded while passed on"
    assert f[16:] == [f[i % 16] for i in range(16, len(f))] and f[16:] != h[16:], "then looped"


def test_can_babble_floods_and_starves_lower_priority_frames_when_it_saturates(pair):
    # By default as many frames as the bus carries: 22 of 8 bytes (111 bits unstuffed) in 2500 bit times.
    faulty, _ = pair({"kind": "can.babble", "at": AT, "duration": 0.025})  # 10 ticks
    babble = [k for k, m, _ in faulty.frames if m.arbitration_id == 0x001]
    assert len(babble) == 22 * 10 and faulty.listener.stats.malformed["unknown_id"] == 220
    sync = {k for k, rx in faulty.decoded("SYNC")}
    assert not sync & set(range(START, START + 10)), "SYNC (0x080) loses every arbitration"
    assert set(range(START + 10, TICKS + 1)) <= sync


def test_can_babble_below_saturation_starves_nothing(pair):
    faulty, _ = pair({"kind": "can.babble", "at": AT, "per_tick": 5})
    assert len({k for k, _ in faulty.decoded("SYNC")}) == TICKS


def test_can_bus_off_silences_the_node_then_it_recovers(pair):
    faulty, _ = pair({"kind": "can.bus_off", "at": AT, "duration": 0.02})  # 8 ticks
    ticks = {k for k, m, _ in faulty.frames}
    assert not ticks & set(range(START, START + 8))
    assert set(range(START + 8, TICKS + 1)) <= ticks


def test_receive_side_frame_faults_act_on_what_the_drives_get(session):
    bench = Bench(
        session, [can_fault("can.drop", "DRIVE1_COMMAND"), can_fault("can.corrupt", "DRIVE2_COMMAND")]
    )
    try:
        bench.run(START + 1)
        node = bench.rig.can
        commands = {
            n: node.message(n, {"Torque": 1.0, "Tick": 1, "Enable": 1}) for n in RX_MESSAGES if "COMMAND" in n
        }
        assert node.rx_hook(commands["DRIVE1_COMMAND"]) is None
        corrupted = node.rx_hook(commands["DRIVE2_COMMAND"])
        assert node.decode(corrupted).e2e.status is E2EStatus.CRC_ERROR
        assert node.rx_hook(commands["DRIVE3_COMMAND"]) is commands["DRIVE3_COMMAND"]
    finally:
        bench.close()


def test_a_frame_fault_on_an_unknown_message_or_the_wrong_direction_is_refused(session):
    with pytest.raises(ValueError, match="no message 'IMU_RATES'"):
        Bench(session, [can_fault("can.drop", "IMU_RATES")])
    with pytest.raises(ValueError, match="receives"):
        Bench(session, [can_fault("can.delay", "DRIVE1_COMMAND", delay=0.01)])


# -------------------------------------------------------------------------------------------- topics
def seqs(bench):
    return [w.seq for w in bench.tes.drain()]


def test_wrench_dropout_publishes_nothing_in_its_window(pair):
    faulty, _ = pair({"kind": "zenoh.wrench_dropout", "at": AT, "duration": 0.025})
    got = seqs(faulty)
    assert got == [k for k in range(1, TICKS + 1) if not START <= k < START + 10]


def test_wrench_stale_repeats_the_last_sample_unchanged(pair):
    faulty, _ = pair({"kind": "zenoh.wrench_stale", "at": AT})
    got = seqs(faulty)
    assert got == [*range(1, START + 1), *[START] * (TICKS - START)]


def test_wrench_frozen_keeps_the_values_while_seq_goes_on(pair):
    faulty, healthy = pair({"kind": "zenoh.wrench_frozen", "at": AT})
    f = faulty.tes.drain()
    h = {w.seq: w for w in healthy.tes.drain()}
    assert [w.seq for w in f] == list(range(1, TICKS + 1))
    assert {w.force for w in f if w.seq >= START} == {h[START].force}
    assert len({h[k].force for k in range(START, TICKS + 1)}) > 5


@pytest.mark.parametrize("key", ["tes/wrench", "sc/request"])
def test_malformed_payloads_are_put_and_rejected_by_typed_subscribers(pair, key):
    faulty, _ = pair({"kind": "zenoh.malformed", "key": key, "at": AT, "payload": "c1c1"})
    garbage = [k for k, data in faulty.raw if data == b"\xc1\xc1"]
    assert len(garbage) == TICKS - START + 1
    sub = faulty.tes if key == "tes/wrench" else faulty.sc
    sub.drain()
    assert sub.rejected["garbage"] == TICKS - START + 1
    if key == "tes/wrench":
        assert faulty.tes.accepted == START - 1, "the sample itself was replaced"


def test_sc_flood_puts_that_many_requests_per_tick(pair):
    faulty, _ = pair({"kind": "zenoh.sc_flood", "at": AT, "per_tick": 7, "mode": "idle"})
    flood = [r for r in faulty.sc.drain() if r.source == "flood"]
    assert len(flood) == 7 * (TICKS - START + 1) and {r.mode for r in flood} == {"idle"}


def test_sc_conflict_adds_a_second_source_at_its_period(pair):
    faulty, _ = pair({"kind": "zenoh.sc_conflict", "at": AT, "mode": "limit", "cap": 0.3, "period": 0.01})
    requests = faulty.sc.drain()
    rogue = [r for r in requests if r.source == "rogue-agent"]
    assert len(rogue) == math.ceil((TICKS - START + 1) / 4)
    assert {(r.mode, r.speed_cap) for r in rogue} == {("limit", 0.3)}
    assert any(r.source == "scenario" for r in requests)


# ----------------------------------------------------------------------------------------- actuators
def enable_all(bench, torque=0.5):
    """What the supervisor's frame does for the drives: permission, and the main contactor closed."""
    bench.plant.drives.set_permission(True)
    bench.plant.drives.set_contactor(True)
    bench.plant.drives.set_commands((torque,) * 3, True, bench.plant.t)


def test_drive_torque_scale_is_what_the_motor_produces(session):
    bench = Bench(session, [{"kind": "plant.drive_torque", "motor": 2, "scale": 0.5, "at": AT}])
    try:
        bench.run(START)
        enable_all(bench)
        for _ in range(40):
            bench.plant.drives.motors[0].last_command_time = bench.plant.drives.motors[
                1
            ].last_command_time = bench.plant.t
            bench.plant.drives.motors[2].last_command_time = bench.plant.t
            bench.plant.step()
        m = bench.plant.drives.motors
        assert m[0].torque == pytest.approx(0.5, rel=1e-3) and m[1].torque == pytest.approx(0.25, rel=1e-3)
    finally:
        bench.close()


def test_drive_stuck_enabled_ignores_the_supervisors_permission(session):
    bench = Bench(session, [{"kind": "plant.drive_stuck_enabled", "motor": 3, "at": AT}])
    try:
        bench.run(START)
        enable_all(bench)
        bench.plant.drives.set_permission(False)
        bench.plant.step()
        states = [m.state.name for m in bench.plant.drives.motors]
        assert states == ["DISABLED", "DISABLED", "ENABLED"] and bench.plant.drives.torques[2] != 0.0
        assert bench.plant.drives.powered
        # The second path: the main contactor cuts the DC bus of all three, the stuck one included.
        bench.plant.drives.set_contactor(False)
        bench.plant.step()
        assert bench.plant.drives.torques == (0.0, 0.0, 0.0) and not bench.plant.drives.powered
        assert bench.plant.drives.motors[2].state.name == "ENABLED", "it still thinks itself on"
    finally:
        bench.close()


def test_push_accelerates_the_robot_by_its_impulse(session):
    """Held upright by nothing, the robot gains forward momentum from a forward push: its speed rises
    faster than its unpushed twin's, and the pushing stops with the fault."""
    push = {"kind": "plant.push", "force": [100.0, 0.0], "at": AT, "duration": 0.05}
    faulty, healthy = Bench(session, [push]), Bench(session)
    try:
        faulty.run(START + 20)
        healthy.run(START + 20)
        assert faulty.plant.external == [None, None], "ended with the fault"
        dv = faulty.plant.velocity[0] - healthy.plant.velocity[0]
        # 5 N s into robot + rider (105 kg; part of it goes into rotation, not speed).
        assert 0.01 < dv < 5.0 / 105.0
        assert abs(faulty.plant.velocity[1] - healthy.plant.velocity[1]) < 1e-6, "no sideways push"
    finally:
        faulty.close()
        healthy.close()


HARD_PUSH = """
name = "hard_push"
rider = "configs/riders/ref_60kg_180.toml"
law = "hacs"
duration = 1.5
[[sc]]
mode = "free"
[[faults]]
kind = "plant.push"
force = [2000.0, 0.0]
height = 0.4
at = 1.0
duration = 0.3
"""


def test_a_hard_push_leaves_the_seat_publishing_what_its_schema_takes(caplog, tmp_path):
    """A push at the rider's chest loads the seat with a moment no seated body makes: the seat's COP
    stays on its footprint, so neither the controller nor the supervisor rejects a seat payload (it was
    `cop[0]` >= -1 m, 11 payloads)."""
    from drivers.config import decode_toml
    from hil.pipeline import run
    from hil.run.scenario import Scenario
    from tests.zenoh_helpers import private_bench

    scenario = decode_toml(HARD_PUSH, Scenario, tmp_path / "hard_push.toml")
    caplog.set_level(logging.DEBUG, logger="drivers.zenoh_link")
    result = run(scenario, private_bench())
    assert result.trace.stats.ticks > 400, "the run reached the push"
    seen = [e for e in result.trace.safety_events if e.t >= 1.0]
    assert seen, "the push did load the seat: the supervisor saw it"
    rejected = [r.getMessage() for r in caplog.records if "rejected payload" in r.getMessage()]
    assert rejected == []


def test_mass_shift_moves_the_torso_at_once(session):
    faulty, healthy = (
        Bench(session, [{"kind": "plant.mass_shift", "pitch_deg": 10.0, "at": AT}]),
        Bench(session),
    )
    try:
        faulty.run(START + 60)
        healthy.run(START + 60)
        lean = math.degrees(faulty.plant.truth().lean[0] - healthy.plant.truth().lean[0])
        assert 5.0 < lean < 15.0
    finally:
        faulty.close()
        healthy.close()


# ----------------------------------------------------------------------------------------- processes
def test_process_faults_refuse_a_target_that_is_not_in_process(session):
    with pytest.raises(ValueError, match="external"):
        Bench(session, [{"kind": "process.kill", "target": "controller", "at": AT}])
    with pytest.raises(ValueError, match="pause"):
        Bench(session, [{"kind": "process.hang", "at": AT}])


def test_fault_parameters_are_checked_with_clear_errors():
    with pytest.raises(ValueError, match=r"unknown kind 'sensor.stuk'"):
        parse_fault({"kind": "sensor.stuk", "channel": "imu.pitch"})
    with pytest.raises(ValueError, match=r"sensor.bias.*Object missing required field `offset`"):
        parse_fault({"kind": "sensor.bias", "channel": "imu.pitch"})
    with pytest.raises(ValueError, match=r"scale = -1 is out of its bound 0 <= scale <= 10"):
        parse_fault({"kind": "plant.drive_torque", "motor": 1, "scale": -1})
    with pytest.raises(ValueError, match="not hex"):
        parse_fault({"kind": "zenoh.malformed", "payload": "xyz"})
    with pytest.raises(ValueError, match="unknown cause 'TILTED'"):
        parse_fault({"kind": "sensor.off", "channel": "imu.pitch", "expect": {"cause": "TILTED"}})


class Responder:
    """A stand-in controller: answers SYNC(k) with torque k/1000 on every drive, at once."""

    def __init__(self, bench):
        import threading

        from drivers.can_bus import CanNode, open_bus

        self.node = CanNode(open_bus(bench.bus_config), name="responder")
        self.stop = threading.Event()
        self.answered = threading.Condition()
        self.last = -1
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            rx = self.node.recv(0.05)
            if rx is not None and rx.name == "SYNC":
                k = int(rx.signals["Tick"])
                for n in (1, 2, 3):
                    self.node.send(f"DRIVE{n}_COMMAND", {"Torque": k / 1000, "Tick": k, "Enable": 1})
                with self.answered:
                    self.last = k
                    self.answered.notify_all()

    def wait_answer(self, k: int) -> None:
        """Until SYNC(k) is answered: what the real-time clock's sleep gives a controller on a thread."""
        with self.answered:
            assert self.answered.wait_for(lambda: self.last == k, timeout=10.0), f"SYNC({k}) not answered"

    def close(self):
        self.stop.set()
        self.thread.join(1.0)
        self.node.bus.shutdown()


class PermittedPort(DrivesPort):
    """No supervisor here: permission is not the subject."""

    def apply_permission(self):
        pass


class PermittedRig(Rig):
    """Keeps what drive 1 held under each tick's step."""

    def _sample(self):
        # Right after the step: the command it ran under (the answer to the previous SYNC may come in at the
        # end of a tick or as the next one starts; either way it holds for the next step).
        self.held_in_step.append((self.plant.tick - 1, self.plant.drives.motors[0].command))
        return super()._sample()


def applied_commands(session, fault, ticks=80):
    """(tick, the torque drive 1 holds after it) with a responder that answers every tick."""
    import time

    bench = Bench(session, [fault] if fault else [], rig=PermittedRig, port=PermittedPort)
    bench.rig.held_in_step = []
    responder = Responder(bench)
    bench.plant.drives.set_permission(True)
    try:
        for _ in range(ticks + 1):
            # Real time: the commands of tick k are taken in by the time tick k + 1 steps.
            bench.rig.tick(deadline=time.monotonic() + 1.0, lockstep=False)
            responder.wait_answer(bench.plant.tick)
    finally:
        responder.close()
        bench.close()
    return [(k, c) for k, c in bench.rig.held_in_step if k >= 1]


def test_loop_delay_hands_each_command_to_the_drives_that_much_later(session):
    healthy = applied_commands(session, None)
    assert all(c == pytest.approx(k / 1000) for k, c in healthy)
    late = applied_commands(session, {"kind": "process.loop_delay", "delay": 0.01, "at": AT})
    for k, c in late:
        want = k if k < START else k - 4
        if START <= k < START + 4:
            want = START - 1  # nothing new arrives for 4 ticks: the drive holds the last command
        assert c == pytest.approx(want / 1000), k


def test_jitter_delays_vary_within_the_bound_and_never_reorder(session):
    got = applied_commands(session, {"kind": "process.jitter", "jitter": 0.01, "at": AT}, ticks=200)
    source = [round(c * 1000) for _, c in got]
    lags = [k - s for (k, _), s in zip(got, source, strict=True) if k >= START]
    assert source == sorted(source), "a command never overtakes an earlier one"
    assert max(lags) <= 4 and min(lags) == 0 and len(set(lags)) >= 3


def test_the_docs_list_every_fault_of_the_catalog():
    from tests.helpers import ROOT

    text = (ROOT / "docs/faults.md").read_text()
    missing = [kind for kind in CATALOG if f"`{kind}`" not in text]
    assert not missing, f"docs/faults.md does not list {missing}"


@pytest.mark.parametrize(("at", "duration", "first", "end"), [(0.3, 0.1, 120, 160), (0.7, 0.0025, 280, 281)])
def test_fault_times_become_ticks_once_and_act_on_exactly_those_ticks(session, at, duration, first, end):
    # 0.7 * 400 = 280.00000000000006 and 0.3 + 0.1 = 0.4000000000000001: times compared as floats tick by
    # tick would need a tolerance; as ticks they need none.
    fault = {"kind": "sensor.off", "channel": "imu.rate_z", "at": at, "duration": duration}
    bench = Bench(session, [fault])
    try:
        assert bench.rig.faults.specs[0].ticks(400.0) == (first, end)
        bench.run(end + 5)
        events = [(e.action, round(e.t / DT)) for e in bench.rig.faults.events]
    finally:
        bench.close()
    assert events == [("start", first), ("end", end)]


def test_a_live_fault_starts_exactly_at_after_the_tick_that_takes_it_in():
    # A fault injected into a running rig (pure-hil fault inject) counts `at` once, from the tick that
    # takes the request in: it once started at twice its time (and past a short run's end, never).
    from hil.faults import FaultSet, parse_fault

    faults = FaultSet()
    taken_at = 589  # t = 1.4725 s at 400 Hz
    for k in range(1, taken_at):
        faults.update(k, k / faults.tick_hz)
    faults.inject(parse_fault({"kind": "zenoh.wrench_dropout", "at": 0.5}))
    starts = []
    faults.on_event = lambda event: starts.append(event) if event.action == "start" else None
    for k in range(taken_at, 2 * taken_at + 400):
        faults.update(k, k / faults.tick_hz)
    (start,) = starts
    assert start.t == pytest.approx(taken_at / faults.tick_hz + 0.5)


@pytest.mark.parametrize(("bench", "own", "other"), [("odrive", 0x029, 0x049), ("cia402", 0x181, 0x182)])
def test_can_masquerade_on_a_device_profile_sends_under_the_other_devices_id(tmp_path, bench, own, other):
    """On a profile the impersonated drive's frames are the profile's (axis 2's Get_Encoder_Estimates, drive
    2's TPDO1), not the contract's DRIVE2_FEEDBACK (0x182 on an odrive bus belongs to nobody)."""
    import msgspec

    from hil.pipeline import load_scenario, run
    from tests.zenoh_helpers import private_bench

    at = 0.5
    fault = parse_fault(
        {"kind": "can.masquerade", "message": "DRIVE1_FEEDBACK", "as_message": "DRIVE2_FEEDBACK", "at": at}
    )
    scenario = msgspec.structs.replace(load_scenario("balance"), duration=1.0, faults=[fault], criteria=[])
    run(scenario, private_bench(bench), out=tmp_path)
    ticks: list[list[tuple[int, str]]] = [[]]  # the frames between two SYNCs (the rig's tick, 2.5 ms)
    for line in (tmp_path / "can.log").read_text().splitlines():
        frame_id, _, data = line.split()[2].partition("#")
        if int(frame_id, 16) == 0x080:
            ticks.append([])
        ticks[-1].append((int(frame_id, 16), data))
    start = round(at / 0.0025) + 2

    def copies(tick: list[tuple[int, str]]) -> bool:
        """Drive 1's frame went out again under drive 2's id this tick."""
        return {d for i, d in tick if i == own} <= {d for i, d in tick if i == other} and (
            sum(i == other for i, _ in tick) == 2 * sum(i == own for i, _ in tick) > 0
        )

    assert all(copies(tick) for tick in ticks[start:-1])
    assert not any(copies(tick) for tick in ticks[10 : start - 4]), "test the test: none before the fault"
    if bench == "odrive":
        assert all(i != 0x182 for tick in ticks for i, _ in tick), "no contract frame on an odrive bus"


@pytest.mark.parametrize(
    ("bench", "fault", "error"),
    [
        ("xsens", {"message": "IMU_RATE", "as_message": "IMU_ACCEL"}, "xsens profile cannot send a frame"),
        ("odrive", {"message": "DRIVE1_FEEDBACK", "as_message": "IMU_RATE"}, "not frames of one family"),
    ],
)
def test_can_masquerade_a_profile_cannot_carry_is_refused_before_the_run(bench, fault, error):
    import msgspec

    from hil.pipeline import load_scenario, run
    from tests.zenoh_helpers import private_bench

    spec = parse_fault({"kind": "can.masquerade", "at": 0.5, **fault})
    scenario = msgspec.structs.replace(load_scenario("balance"), duration=1.0, faults=[spec])
    trace = run(scenario, private_bench(bench)).trace
    assert trace.failure is not None and error in trace.failure.error
