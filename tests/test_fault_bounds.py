"""Every fault parameter within a physical or wire bound, declared once (hil/faults/base.py `Bound`), listed
in docs/faults.md from that declaration; a faulty sensor value saturates as it would on the wire."""

from __future__ import annotations

import math
from types import SimpleNamespace

import msgspec
import numpy as np
import pytest

from drivers.can_codec import Catalog
from drivers.config import ConfigError, decode_toml
from hil.faults import CATALOG, FaultSet, parse_fault
from hil.faults.sensors import CHANNELS, Readings
from hil.run.scenario import Scenario
from plant.params import RobotParams, SimParams
from tests.helpers import ROOT

RIG = SimpleNamespace(
    plant=SimpleNamespace(sim=SimParams(), robot=RobotParams(), torso=None),
    bitrate=1_000_000,
    can=SimpleNamespace(catalog=Catalog()),
    dut=None,
    supervisor=None,
)
"""What a fault's rig-dependent bounds read of a rig: 1 Mbit/s, 400 Hz, PURE's encoder."""


def taken(fault: dict) -> None:
    """Read as a scenario or a request is, then scheduled on RIG as a run's faults are."""
    FaultSet([parse_fault(fault)]).attach(RIG)


def test_every_parameter_of_every_kind_declares_its_bound_and_the_docs_list_them():
    from hil.faults.bounds import describe, render

    for cls in CATALOG.values():
        for field in msgspec.structs.fields(cls):
            if field.name != "expect":
                describe(cls, field.name)  # raises for a parameter without a declared bound
    page = ROOT / "docs/faults.md"
    assert render(page.read_text()) == page.read_text(), (
        "regenerate: python -m hil.faults.bounds docs/faults.md"
    )


# (fault, what the refusal says): the parameter, its value and its bound.
OUT_OF_BOUNDS = [
    (
        {"kind": "can.babble", "per_tick": 100_000_000},
        "per_tick = 100000000 is out of its bound 1 <= per_tick <= 22",
    ),
    ({"kind": "can.babble", "per_tick": 23}, "per_tick = 23 is out of its bound 1 <= per_tick <= 22"),
    ({"kind": "can.babble", "length": 0, "per_tick": 54}, "1 <= per_tick <= 53"),
    ({"kind": "can.repeat", "message": "IMU_RATE", "times": 22}, "times = 22 is out of its bound"),
    ({"kind": "can.drop", "message": "SYNC", "count": 10**12}, "count = 1000000000000 is out of its bound"),
    (
        {"kind": "can.delay", "message": "IMU_RATE", "delay": 3600.0},
        "delay = 3600 is out of its bound 0 < delay <= 10",
    ),
    ({"kind": "sensor.noise", "channel": "imu.pitch", "sigma": 1e308}, "0 < sigma <= 6.5535"),
    ({"kind": "sensor.noise", "channel": "tes.cell1", "sigma": 2.5e4}, "0 < sigma <= 20000"),
    ({"kind": "sensor.noise", "channel": "encoder1", "sigma": 1e308}, "sigma = 1e+308 is out of its bound"),
    ({"kind": "sensor.bias", "channel": "drive1.velocity", "offset": -700.0}, "|offset| <= 655.35"),
    ({"kind": "sensor.stuck", "channel": "imu.rate_z", "value": 40.0}, "|value| <= 32.7675"),
    ({"kind": "sensor.scale", "channel": "imu.pitch", "factor": 1e6}, "|factor| <= 1000"),
    ({"kind": "sensor.drift", "channel": "imu.pitch", "rate": 7.0}, "|rate| <= 6.5535"),
    ({"kind": "sensor.spikes", "channel": "imu.accel_x", "amplitude": 1e9}, "|amplitude| <= 65.535"),
    ({"kind": "sensor.delayed", "channel": "imu.pitch", "delay": 1e6}, "0 < delay <= 10"),
    ({"kind": "sensor.slow", "channel": "imu.pitch", "period": 1e9}, "0 < period <= 86400"),
    ({"kind": "zenoh.sc_flood", "per_tick": 10**6}, "per_tick = 1000000 is out of its bound"),
    ({"kind": "zenoh.sc_flood", "cap": 50.0}, "0 <= cap <= 5"),
    ({"kind": "zenoh.sc_flood", "source": "x" * 65}, "length <= 64"),
    ({"kind": "zenoh.malformed", "payload": "00" * 2000}, "length <= 2920"),
    ({"kind": "zenoh.sc_conflict", "period": 1e12}, "0 < period <= 86400"),
    ({"kind": "plant.drive_torque", "motor": 1, "scale": 1e300}, "0 <= scale <= 10"),
    ({"kind": "plant.push", "force": [1e6, 0.0]}, "|force| <= 2452"),
    ({"kind": "plant.push", "twist": -1e4}, "|twist| <= 980.8"),
    ({"kind": "plant.push", "height": 10.0}, "-1 <= height <= 1.5"),
    ({"kind": "plant.mass_shift", "pitch_deg": 1e308}, "|pitch_deg| <= 90"),
    ({"kind": "process.loop_delay", "delay": 1e5}, "0 < delay <= 10"),
    ({"kind": "process.jitter", "jitter": 1e5}, "0 < jitter <= 10"),
    ({"kind": "sensor.off", "channel": "imu.pitch", "at": 1e300}, "0 <= at <= 86400"),
    ({"kind": "sensor.off", "channel": "imu.pitch", "duration": 1e9}, "0 < duration <= 86400"),
    ({"kind": "cia402.fault", "code": 0x10000}, "1 <= code <= 65535"),
]


@pytest.mark.parametrize(("fault", "says"), OUT_OF_BOUNDS, ids=[f["kind"] for f, _ in OUT_OF_BOUNDS])
def test_a_parameter_out_of_its_bound_is_refused_naming_it_and_the_bound(fault, says):
    with pytest.raises(ValueError) as refused:
        taken(fault)
    assert says in str(refused.value) and fault["kind"] in str(refused.value)


def test_positive_control_the_same_kinds_at_their_bounds_are_taken():
    at_bounds = [
        {"kind": "can.babble", "per_tick": 22},
        {"kind": "can.babble"},  # none: as many as the bus carries
        {"kind": "can.repeat", "message": "IMU_RATE", "times": 21},
        {"kind": "sensor.noise", "channel": "imu.pitch", "sigma": 6.5535},
        {"kind": "sensor.noise", "channel": "encoder1", "sigma": 1000.0},
        {"kind": "sensor.bias", "channel": "drive1.velocity", "offset": -655.35},
        {"kind": "zenoh.sc_flood", "cap": 5.0},
        {"kind": "plant.push", "force": [2452.0, -2452.0], "height": 1.5},
    ]
    for fault in at_bounds:
        taken(fault)


@pytest.mark.parametrize("spelled", ["nan", "NaN", "inf", "-Infinity"])
def test_nan_and_infinities_are_refused_and_the_message_says_which(spelled):
    value = float(spelled)
    with pytest.raises(ValueError) as refused:
        parse_fault({"kind": "sensor.noise", "channel": "imu.pitch", "sigma": value})
    said = str(refused.value)
    assert (
        "sigma = " in said
        and ("nan is not a number" if math.isnan(value) else "is not a finite number") in said
    )
    assert "expected 0 < sigma <=" in said


def test_a_scenario_file_names_itself_the_fault_the_parameter_and_nan(tmp_path):
    text = (
        'name = "x"\nduration = 1.0\n[[faults]]\nkind = "sensor.noise"\nchannel = "imu.pitch"\nsigma = nan\n'
    )
    with pytest.raises(ConfigError) as refused:
        decode_toml(text, Scenario, tmp_path / "noisy.toml")
    said = str(refused.value)
    assert said.startswith(f"{tmp_path / 'noisy.toml'}: sensor.noise: sigma = nan is not a number")
    assert said.endswith("at `$.faults[0]`")


def test_a_live_injection_beyond_the_rigs_bound_is_refused_and_a_clear_of_an_unknown_fault_too():
    faults = FaultSet([parse_fault({"kind": "sensor.off", "channel": "imu.pitch", "at": 5.0})])
    faults.attach(RIG)
    with pytest.raises(ValueError, match=r"per_tick = 100000000 is out of its bound 1 <= per_tick <= 22"):
        faults.inject(parse_fault({"kind": "can.babble", "per_tick": 100_000_000}))
    assert faults.inject(parse_fault({"kind": "can.babble"})) == 1, "queued: numbered after the scenario's 0"
    faults.clear(1)  # a queued injection's number is known at once
    with pytest.raises(ValueError, match=r"no fault 7 in this run \(its faults: 0\.\.1"):
        faults.clear(7)
    with pytest.raises(ValueError, match="no fault -1"):
        faults.clear(-1)


def test_a_run_holds_at_most_max_faults():
    from hil.faults.runtime import MAX_FAULTS

    faults = FaultSet([parse_fault({"kind": "sensor.off", "channel": "imu.pitch"})] * (MAX_FAULTS - 1))
    faults.inject(parse_fault({"kind": "sensor.off", "channel": "imu.roll"}))
    with pytest.raises(ValueError, match=f"holds {MAX_FAULTS} faults already"):
        faults.inject(parse_fault({"kind": "sensor.off", "channel": "imu.roll"}))


SATURATES = {
    "imu.pitch": ("IMU_ATTITUDE", "Pitch"),
    "imu.rate_x": ("IMU_RATE", "RateX"),
    "imu.accel_z": ("IMU_ACCEL", "AccZ"),
    "drive2.velocity": ("DRIVE2_FEEDBACK", "Velocity"),
    "drive3.torque": ("DRIVE3_TORQUE", "Torque"),
    "tes.cell4": None,  # the seat's payload: drivers/schemas.py Force, +-1e4 N
}


@pytest.mark.parametrize("channel", sorted(SATURATES))
def test_a_faulty_value_saturates_where_its_signal_does_on_the_wire(channel):
    where = SATURATES[channel]
    if where is None:
        low, high = -1e4, 1e4
    else:
        signal = Catalog()[where[0]].message.get_signal_by_name(where[1])
        low, high = signal.minimum, signal.maximum
    index = list(CHANNELS).index(channel)
    for offset, expected in ((high - low, high), (low - high, low)):  # a full span from 0: past full scale
        bias = parse_fault({"kind": "sensor.bias", "channel": channel, "offset": offset})
        readings = Readings([0.0] * len(CHANNELS), set())
        bias.apply(readings, 0.0, None)
        assert readings.values[index] == expected


def test_an_encoders_range_is_its_words_on_the_rigs_robot():
    from hil.faults.sensors import SATURATION, channel_range

    assert SATURATION["encoder1"] is None, "an encoder's count wraps: it does not saturate"
    low, high = channel_range("encoder1", RIG.plant.robot.encoder)
    assert (high - low) * 8192 / (2 * math.pi) == pytest.approx(2**32 - 1)
    assert channel_range("encoder1", None) is None, "known on the rig only"


@pytest.mark.parametrize("kind", sorted(k for k in CATALOG if k.startswith("sensor.")))
def test_no_sensor_fault_at_its_bounds_makes_a_frame_or_a_seat_sample_fail(kind):
    """Every sensor kind on every channel with each parameter at its largest: the values stay finite over a
    day of drift, and the tick's frames and seat sample encode."""
    from drivers.schemas import TesWrench, encode
    from hil.faults.base import FaultState, bounds_of
    from plant.ballbot import Plant
    from tests.fault_bench import RIDER, ROBOT

    plant = Plant(ROBOT, RIDER, SimParams())
    catalog = Catalog()
    for channel in CHANNELS:
        base = parse_fault({"kind": kind, "channel": channel, **REQUIRED.get(kind, {})})
        largest = {}
        for name, bound in bounds_of(CATALOG[kind]).items():
            if name not in ("at", "duration"):
                largest[name] = bound.limit(base, RIG)[0] if bound.limit else bound.high
        spec = msgspec.structs.replace(base, **largest)
        FaultSet([spec]).attach(RIG)
        state = FaultState(np.random.default_rng(0))
        for t in (0.0, 0.0025, 86400.0):
            readings = Readings.of(plant, plant.sample_drives(), plant.sample_imu(), plant.sample_tes())
            spec.apply(readings, t, state)
            assert all(math.isfinite(v) for v in readings.values), (kind, channel, largest)
            for fb in readings.feedback(plant.robot.encoder):
                catalog["DRIVE1_FEEDBACK"].encode({"Position": fb.counts, "Velocity": fb.velocity})
                catalog["DRIVE1_TORQUE"].encode({"Torque": fb.torque})
            (roll, pitch, yaw), rate, accel = (
                readings.imu().attitude,
                readings.imu().rate,
                readings.imu().accel,
            )
            catalog["IMU_ATTITUDE"].encode({"Roll": roll, "Pitch": pitch, "Yaw": yaw})
            catalog["IMU_RATE"].encode(dict(zip(("RateX", "RateY", "RateZ"), rate, strict=True)))
            catalog["IMU_ACCEL"].encode(dict(zip(("AccX", "AccY", "AccZ"), accel, strict=True)))
            tes = readings.tes(plant, plant.sample_tes())
            encode(
                TesWrench(seq=1, stamp=t, force=tes.force, moment=tes.moment, cop=tes.cop, cells=tes.cells)
            )


REQUIRED = {
    "sensor.bias": {"offset": 0.0},
    "sensor.scale": {"factor": 1.0},
    "sensor.drift": {"rate": 0.0},
    "sensor.noise": {"sigma": 1e-3},
    "sensor.spikes": {"amplitude": 0.0},
    "sensor.delayed": {"delay": 0.01},
    "sensor.slow": {"period": 0.01},
}
"""The parameters a kind needs to be read at all, at a harmless value."""
