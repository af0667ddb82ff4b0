"""Typed configuration: every shipped file loads; a bad file names the file, the field and the expectation."""

import math
from pathlib import Path

import pytest

from drivers.config import ConfigError, decode_toml, load_toml
from plant.anthropometry import seat_rider
from plant.params import RiderParams, RobotParams, SimParams

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
RIDERS = sorted((CONFIGS / "riders").glob("*.toml"))


def test_robot_file_is_the_nominal_set():
    robot = load_toml(CONFIGS / "robot" / "pure.toml", RobotParams)
    # docs/physics.md §6.1 nominal values, and the file agrees with the code defaults.
    assert robot.ball.radius == 0.1145 and robot.ball.mass == 3.6 and robot.ball.inertia == 0.047
    assert robot.drivetrain.wheel_radius == 0.0625 and robot.drivetrain.zenith_deg == 45.0
    assert robot.body.top_height == 0.386
    assert robot == RobotParams()


def test_sim_file_loads():
    sim = load_toml(CONFIGS / "sim" / "default.toml", SimParams)
    assert sim.tick_hz == 400.0 and sim.fixture == "free"


def test_paper_riders_and_reference_are_shipped():
    riders = {(r.mass, r.height) for r in (load_toml(p, RiderParams) for p in RIDERS)}
    assert {(50.0, 1.64), (73.0, 1.76), (79.0, 1.60), (52.0, 1.67), (60.0, 1.80)} <= riders


@pytest.mark.parametrize("path", RIDERS, ids=lambda p: p.stem)
def test_each_rider_can_hold_their_max_lean(path):
    # Capability must be physically consistent: the hip torque limit holds the torso at the max lean.
    rider = load_toml(path, RiderParams)
    hat = seat_rider(RobotParams(), rider).hat
    holding = hat.mass * 9.80665 * hat.com_distance * math.sin(math.radians(rider.max_lean_deg))
    assert holding < rider.max_hip_torque
    assert rider.name == path.stem


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[ball]\nmass = "heavy"\n', "Expected `float`, got `str` - at `$.ball.mass`"),
        ("[ball]\nmass = -1.0\n", "Expected `float` >= 0.2 - at `$.ball.mass`"),
        ("[drivetrain]\nzenith_deg = 95.0\n", "Expected `float` <= 80.0 - at `$.drivetrain.zenith_deg`"),
        ("[drivetrain]\nmotor_sign = [1, 2, 1]\n", "at `$.drivetrain.motor_sign[1]`"),
        ("[bal]\nmass = 3.0\n", "Object contains unknown field `bal`"),
        (
            "[friction]\ndrivetrain_stiction = 0.5\n",
            "drivetrain_stiction must be >= drivetrain_coulomb (breakaway exceeds kinetic) - at `$.friction`",
        ),
        ("[ball\n", "not valid TOML"),
    ],
)
def test_bad_robot_config_names_file_field_and_expectation(tmp_path, text, expected):
    path = tmp_path / "robot.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_toml(path, RobotParams)
    assert str(err.value).startswith(f"{path}: ")
    assert expected in str(err.value)


def test_missing_rider_field_is_named():
    with pytest.raises(ConfigError, match=r"Object missing required field `height`"):
        decode_toml('name = "x"\nmass = 70.0\n', RiderParams, "riders/x.toml")


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_toml(tmp_path / "nope.toml", SimParams)


def test_bench_files_name_the_file_and_the_field(tmp_path):
    from drivers.bus_config import network_interfaces
    from hil.bench.bench import load_bench

    for path in sorted((CONFIGS / "benches").glob("*.toml")):
        if path.stem == "processes" and network_interfaces() != ["lo"]:
            with pytest.raises(ConfigError, match=r"processes.toml.*only inside a network namespace"):
                load_bench(path)
        else:
            assert load_bench(path).name == path.stem
    bad = tmp_path / "bench.toml"
    bad.write_text('name = "fast"\n[realtime]\npriority = 120\n')
    with pytest.raises(ConfigError, match=r"bench.toml.*Expected `int` <= 99 - at `\$\.realtime\.priority`"):
        load_bench(bad)
    bad.write_text('name = "fast"\n[realtime]\nlock_memroy = true\n')
    with pytest.raises(ConfigError, match=r"unknown field `lock_memroy`"):
        load_bench(bad)
