"""Every number a user writes has a physical bound, declared once beside its field (drivers/bounds.py for the
robot and the rider, shared by the plant, the controller and the supervisor): a scenario whose files hold one
beyond it is refused before anything runs, exit 2, in one line naming the file, the field and the bound."""

from __future__ import annotations

import math
import typing
from operator import attrgetter
from pathlib import Path

import msgspec
import pytest

from drivers.bus_config import BusConfig
from drivers.config import ConfigError, decode_toml, load_toml
from drivers.resources import find
from drivers.robot import RobotModel
from hil.cli import main
from hil.config_bounds import FieldBound, bounds, segment_kinds
from plant.params import RiderParams, RobotParams, SimParams
from tests.helpers import ROOT

ROBOT, RIDER = find("configs/robot/pure.toml", "robot"), find("configs/riders/ref_60kg_180.toml", "riders")
"""A scenario's default robot and rider, as `pure-hil run` finds them (and names them)."""


def refused(argv: list[str], capsys) -> str:
    """`pure-hil ARGV`'s one line, which it must exit 2 with and without a traceback."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def a_scenario(folder: Path, text: str = "", duration: float = 1.0) -> Path:
    path = folder / "scenario.toml"
    path.write_text(f'name = "bounded"\nduration = {duration!r}\n{text}')
    return path


def run_refused(
    folder: Path, capsys, text: str = "", duration: float = 1.0, *options: str
) -> tuple[Path, str]:
    scenario = a_scenario(folder, text, duration)
    out = folder / "run"
    err = refused(["run", str(scenario), "--quiet", "--out", str(out), *options], capsys)
    assert not (out / "summary.json").exists(), "refused before anything ran"
    return scenario, err


# ------------------------------------------------------------------------------ one declaration for three
def hints(cls: type, prefix: str = "") -> dict[str, typing.Any]:
    """Each field's declared type by its path in the file, through the records in it."""
    found = {}
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        if name.startswith("_"):
            continue
        if isinstance(hint, type) and issubclass(hint, msgspec.Struct):
            found |= hints(hint, f"{prefix}{name}.")
        else:
            found[f"{prefix}{name}"] = hint
    return found


def differences(view: type, truth: type) -> list[str]:
    """Fields of a partial view of a file whose declared type is not the full record's."""
    full = hints(truth)
    return [
        f"{path}: {hint} is not {full.get(path)}"
        for path, hint in hints(view).items()
        if hint != full.get(path)
    ]


def test_the_controller_and_the_supervisor_read_the_robot_and_the_rider_with_the_plants_declarations():
    from controller.config import RiderInfo

    assert differences(RobotModel, RobotParams) == []
    assert differences(RiderInfo, RiderParams) == []
    # Positive control: a bound of their own, as each had before, is seen.
    Copied = msgspec.defstruct(
        "Copied", [("body", msgspec.defstruct("B", [("mass", typing.Annotated[float, msgspec.Meta(gt=0)])]))]
    )
    assert differences(Copied, RobotParams) == [
        f"body.mass: {typing.Annotated[float, msgspec.Meta(gt=0)]} is not {hints(RobotParams)['body.mass']}"
    ]


def test_the_plants_robot_sections_extend_the_shared_ones_and_redeclare_none_of_their_fields():
    for name in RobotModel.__struct_fields__:
        shared, own = type(getattr(RobotModel(), name)), type(getattr(RobotParams(), name))
        assert issubclass(own, shared), f"plant's {name} is not drivers.robot's {shared.__name__} extended"
        assert not set(own.__annotations__) & set(shared.__struct_fields__), f"{name} redeclares a field"
        with pytest.raises(msgspec.ValidationError, match="unknown field"):  # the plant's truth stays strict
            msgspec.convert({name: {"typo": 1}}, RobotParams)


def values(record: msgspec.Struct) -> dict[str, object]:
    """Each field's value by its path in the file."""
    return {path: attrgetter(path)(record) for path in hints(type(record))}


def disagreements(truth: RobotParams, model: RobotModel) -> list[str]:
    """The fields the controller's and the supervisor's model holds other than the plant's."""
    full = values(truth)
    return [
        f"{path}: {v!r} != {full.get(path)!r}" for path, v in values(model).items() if v != full.get(path)
    ]


@pytest.mark.parametrize("robot", [None, *sorted((ROOT / "configs/robot").glob("*.toml"))], ids=str)
def test_the_plant_and_the_model_decode_a_robot_file_alike(robot):
    # None: every default (a section or the whole file left out).
    truth, model = (
        (RobotParams(), RobotModel())
        if robot is None
        else (load_toml(robot, RobotParams), load_toml(robot, RobotModel))
    )
    assert disagreements(truth, model) == []
    assert len(values(model)) == 28  # every field the controller and the supervisor read
    # Positive control: a default or a decoded value drifting on one side is seen.
    drifted = msgspec.structs.replace(truth, body=msgspec.structs.replace(truth.body, mass=31.0))
    assert disagreements(drifted, model) == [f"body.mass: {model.body.mass!r} != 31.0"]


def test_every_number_of_the_robot_and_the_rider_file_has_a_bound_and_why():
    for cls in (RobotParams, RiderParams):
        for b in bounds(cls):
            assert b.bounded and b.why, f"{cls.__name__}.{b.path} declares no bound, or no reason for it"
            if not b.choices:
                assert b.low is not None and b.high is not None, f"{b.path}: a physical range has two ends"


# ------------------------------------------------------------------------------ issue 46's cases, one by one
@pytest.mark.parametrize(
    ("section", "line", "says"),
    [
        ("body", "mass = inf", "Expected `float` <= 200.0 - at `$.body.mass`"),  # was: ValueError, exit 1
        ("body", "com_height = inf", "Expected `float` <= 1.5 - at `$.body.com_height`"),
        ("ball", "inertia = inf", "Expected `float` <= 10.0 - at `$.ball.inertia`"),  # RuntimeWarnings
        ("body", "inertia_pitch = inf", "Expected `float` <= 50.0 - at `$.body.inertia_pitch`"),  # MuJoCo's
        ("body", "mass = 1e30", "Expected `float` <= 200.0 - at `$.body.mass`"),  # LinAlgError, exit 1
        ("ball", "mass = nan", "Expected `float` >= 0.2 - at `$.ball.mass`"),
    ],
)
def test_a_robot_beyond_a_ballbot_is_refused_naming_the_file_the_field_and_the_bound(
    tmp_path, capsys, section, line, says
):
    robot = tmp_path / "robot.toml"
    robot.write_text(f"[{section}]\n{line}\n")
    _, err = run_refused(tmp_path, capsys, f'robot = "{robot}"\n')
    assert f'robot = "{robot}": {says}' in err, err  # the scenario's field, the file it names, the bound
    # The controller's and the supervisor's own decoder (drivers.robot) refuses it in the same words.
    with pytest.raises(ConfigError) as raised:
        load_toml(robot, RobotModel)
    assert str(raised.value) == f"{robot}: {says}"


def test_a_rider_beyond_a_person_is_refused_naming_the_file_the_field_and_the_bound(tmp_path, capsys):
    rider = tmp_path / "rider.toml"
    rider.write_text('name = "x"\nmass = 70.0\nheight = 1.75\nmax_hip_torque = inf\n')  # was: it ran
    _, err = run_refused(tmp_path, capsys, f'rider = "{rider}"\n')
    assert f'rider = "{rider}": Expected `float` <= 500.0 - at `$.max_hip_torque`' in err


LEANS = [
    ("nan", "to = nan is not a finite number (expected |pitch| <= 30 deg (max_lean_deg of"),  # max_lean 98.8
    ("inf", "to = inf is not a finite number (expected |pitch| <= 30 deg"),  # clamped silently
    ("-1e308", "to = -1e+308 deg is past the rider's reach |pitch| <= 30 deg (max_lean_deg of"),
    ("30.5", "to = 30.5 deg is past the rider's reach |pitch| <= 30 deg"),
]


@pytest.mark.parametrize(("to", "says"), LEANS, ids=[to for to, _ in LEANS])
def test_a_lean_past_the_riders_own_limit_is_refused_naming_it(tmp_path, capsys, to, says):
    ramp = f'{{kind = "ramp", to = {to}, duration = 0.5}}'
    scenario, err = run_refused(
        tmp_path, capsys, f'[intent]\npitch = [{{kind = "hold", duration = 0.2}}, {ramp}]\n'
    )
    assert f"{scenario}: intent.pitch[1] (ramp): {says}" in err and str(RIDER) in err, err


def test_a_sine_and_a_twist_are_held_to_the_riders_reach_too(tmp_path, capsys):
    sine = '{kind = "sine", amplitude = 25.0, frequency_hz = 1.0, duration = 1.0}'
    _, err = run_refused(tmp_path, capsys, f'[intent]\nroll = [{{kind = "step", to = 10.0}}, {sine}]\n')
    said = "intent.roll[1] (sine): amplitude = 25 deg about 10: 35 deg is past the rider's reach |roll| <= 30"
    assert said in err, err
    _, err = run_refused(
        tmp_path, capsys, '[intent]\ntwist = [{kind = "ramp", to = -21.0, duration = 1.0}]\n'
    )
    said = (
        "intent.twist[0] (ramp): to = -21 Nm is past the rider's reach |twist| <= 20 Nm (max_twist_torque of"
    )
    assert said in err, err


def test_positive_control_a_lean_at_the_riders_limit_and_a_sine_within_it_are_taken():
    from hil.run.scenario import Intent

    rider = load_toml(RIDER, RiderParams)
    intent = msgspec.convert(
        {
            "pitch": [{"kind": "ramp", "to": -30.0, "duration": 1.0}, {"kind": "step", "to": 30.0}],
            "roll": [
                {"kind": "step", "to": 10.0},
                {"kind": "sine", "amplitude": -20.0, "frequency_hz": 1.0, "duration": 1.0},
            ],
            "twist": [{"kind": "sine", "amplitude": 20.0, "frequency_hz": 0.5, "duration": 1.0}],
        },
        Intent,
    )
    intent.check_reach(rider, str(RIDER))


@pytest.mark.parametrize("bitrate", ["0", "-5", "9999", "2000000"])
def test_a_bench_bitrate_no_can_bus_runs_at_is_refused(tmp_path, capsys, bitrate):
    bench = tmp_path / "bench.toml"
    bench.write_text(f'name = "odd"\n[can]\nbitrate = {bitrate}\n')  # was: it ran
    _, err = run_refused(tmp_path, capsys, "", 1.0, "--bench", str(bench))
    bound = "<= 1000000" if int(bitrate) > 1_000_000 else ">= 10000"
    assert f"{bench}: Expected `int` {bound} - at `$.can.bitrate`" in err, err


def test_a_fault_after_the_end_of_the_run_is_refused_naming_it_its_at_and_the_duration(tmp_path, capsys):
    from hil.run.scenario import Scenario

    fault = '[[faults]]\nkind = "sensor.off"\nchannel = "imu.pitch"\nat = 5.0\n'  # was: PASSED, silently
    scenario, err = run_refused(tmp_path, capsys, fault)
    said = "faults[0] (sensor.off): at = 5 s is not within the scenario's duration: 0 <= at < 1 s"
    assert f"{scenario}: {said}" in err, err
    # Positive control: within the run, it is taken.
    decode_toml(a_scenario(tmp_path, fault.replace("5.0", "0.99")).read_text(), Scenario)


def test_a_criterion_that_is_not_a_number_is_refused(tmp_path, capsys):
    criterion = '[[criteria]]\nmetric = "max_tilt_deg"\nmax = nan\n'  # was: it ran and FAILED, exit 1
    scenario, err = run_refused(tmp_path, capsys, criterion)
    said = "criterion on max_tilt_deg: max = nan is not a finite number - at `$.criteria[0]`"
    assert f"{scenario}: {said}" in err, err


@pytest.mark.parametrize("tilt", ["[20.0, 0.0]", "[15.0, 0.0]", "[29.9, 0.0]", "[25.0, 25.0]"])
def test_a_start_tilt_with_a_foot_on_the_floor_is_refused_naming_the_releasable_tilt(tmp_path, capsys, tilt):
    # Was: accepted (within the 30 deg fall bound), then "foot left touched the floor" at the first tick.
    scenario, err = run_refused(tmp_path, capsys, f"initial_tilt_deg = {tilt}\n")
    assert f"{scenario}: initial_tilt_deg = {tilt}: the foot " in err, err
    assert "mm into the floor; along this tilt the robot can be released from at most [" in err
    assert f"(the releasable tilt of robot {ROBOT} with rider {RIDER}" in err


# ------------------------------------------------------------------------- the releasable tilt is the plant's
def tilt_at(robot: RobotParams, rider: RiderParams, direction: tuple[float, float], height: float) -> tuple:
    """The tilt along `direction` (deg) at which the lowest fall geom is `height` above the floor (as
    plant/model3d.py computes it, the ball sunk MAX_SINK)."""
    from plant.model3d import lowest_fall_geom

    low, high = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (low + high)
        pitch, roll = (math.radians(mid * d) for d in direction)
        low, high = (mid, high) if lowest_fall_geom(robot, rider, pitch, roll)[1] > height else (low, mid)
    return tuple(low * d for d in direction)


def first_tick(robot: RobotParams, rider: RiderParams, tilt: tuple[float, float]) -> str | None:
    from plant.ballbot3d import Plant3D

    plant = Plant3D(robot, rider, SimParams(), None, (math.radians(tilt[0]), math.radians(tilt[1])))
    plant.step()
    return plant.fallen


LOW_RIM = msgspec.structs.replace(
    RobotParams(), body=msgspec.structs.replace(RobotParams().body, chassis_bottom=-0.06, chassis_radius=0.3)
)
"""A wide, low chassis whose rim reaches the floor well within the fall bound."""


@pytest.mark.parametrize(
    ("robot", "rider", "direction", "geom"),
    [
        (RobotParams(), "ref_60kg_180", (30.0, 0.0), "foot left"),
        (RobotParams(), "heavy_120kg_185", (25.0, 25.0), "foot right"),
        (RobotParams(), "light_45kg_150", (30.0, -10.0), "foot "),
        (LOW_RIM, "ref_60kg_180", (-30.0, 0.0), "chassis rim"),
        (LOW_RIM, "s16_mwcu_52kg_167", (0.0, 30.0), "chassis rim"),
    ],
)
def test_the_releasable_tilt_is_where_the_3d_plant_finds_nothing_on_the_floor(robot, rider, direction, geom):
    """The bound the start is checked against is the geometry the 3-D plant's fall check sees: released at it,
    no fall at the first tick; with its fall geom 2 mm further into the floor than the margin for the ball's
    sink, the first tick is that geom's fall."""
    from plant.model3d import MAX_SINK

    person = load_toml(ROOT / f"configs/riders/{rider}.toml", RiderParams)
    assert first_tick(robot, person, tilt_at(robot, person, direction, 0.0)) is None
    fallen = first_tick(robot, person, tilt_at(robot, person, direction, -(MAX_SINK + 0.002)))
    assert fallen is not None and fallen.startswith(geom) and "touched the floor" in fallen


def test_the_documented_releasable_tilt_is_the_computed_one():
    from plant.model3d import releasable_share

    share = releasable_share(RobotParams(), load_toml(RIDER, RiderParams), math.radians(30.0), 0.0)
    text = (ROOT / "docs/configuration.md").read_text()
    assert f"can be released from {math.trunc(300.0 * share) / 10.0:g} deg forward" in text


def test_positive_control_every_shipped_scenario_and_campaign_case_can_start(tmp_path):
    """Every shipped scenario, as shipped and as each shipped campaign runs it (its riders, laws, durations
    and faults), is within every bound: the robot, its rider, their reach, the faults' times, the start."""
    from hil.bench.bench import load_bench
    from hil.pipeline import check_start, load_scenario
    from hil.run.scenario import Scenario
    from hil.suites.campaign import expand, load_campaign

    bench = load_bench("embedded")
    scenarios = sorted((ROOT / "configs/scenarios").glob("*.toml"))
    for path in scenarios:
        check_start(load_scenario(path), bench, str(path))
    cases = [
        c for path in sorted((ROOT / "configs/campaigns").glob("*.toml")) for c in expand(load_campaign(path))
    ]
    assert len(cases) > 100
    for case in cases:
        check_start(msgspec.json.decode(case.scenario_text, type=Scenario), bench, case.id)


# --------------------------------------------------------------- every bounded field, beyond its bound
def beyond(b: FieldBound) -> list[tuple[str, str]]:
    """(a value, the bound msgspec names refusing it) for each way out of `b`: NaN and the infinities (a
    float's), just past each end."""

    def shown(x: float) -> str:
        return str(int(x)) if b.whole else repr(float(x))

    low = f"{'>' if b.low_open else '>='} {shown(b.low)}" if b.low is not None else None
    high = f"{'<' if b.high_open else '<='} {shown(b.high)}" if b.high is not None else None
    cases = []
    if not b.whole:
        cases += [("nan", low or high), ("inf", high or low), ("-inf", low or high)]
    if b.low is not None:
        under = b.low if b.low_open else (b.low - 1 if b.whole else b.low - max(abs(b.low), 1.0))
        cases.append((shown(under), low))
    if b.high is not None:
        over = b.high if b.high_open else (b.high + 1 if b.whole else b.high + max(abs(b.high), 1.0))
        cases.append((shown(over), high))
    return [(value, bound) for value, bound in cases if bound is not None]


def _files(folder: Path, kind: str, path: str, value: str) -> tuple[str, Path, list[str]]:
    """The scenario text, the file that holds the bad value and `pure-hil run`'s extra options."""
    if kind == "robot":
        *sections, key = path.split(".")
        robot = folder / "robot.toml"
        robot.write_text(f"[{'.'.join(sections)}]\n{key} = {value}\n")
        return f'robot = "{robot}"\n', robot, []
    if kind == "rider":
        rider = folder / "rider.toml"
        fields = {"name": '"x"', "mass": "70.0", "height": "1.75", path: value}
        rider.write_text("".join(f"{k} = {v}\n" for k, v in fields.items()))
        return f'rider = "{rider}"\n', rider, []
    if kind == "bench":
        bench = folder / "bench.toml"
        bench.write_text(f'name = "b"\n[can]\n{path.removeprefix("can.")} = {value}\n')
        return "", bench, ["--bench", str(bench)]
    tag, field = path.split(".")
    kind_cls = next(k for k in segment_kinds() if k.__struct_config__.tag == tag)
    given = {"to": "5.0", "duration": "0.5", "amplitude": "5.0", "frequency_hz": "0.5"}
    fields = {k: v for k, v in given.items() if k in kind_cls.__struct_fields__} | {field: value}
    segment = ", ".join([f'kind = "{tag}"', *(f"{k} = {v}" for k, v in fields.items())])
    return f"[intent]\npitch = [{{{segment}}}]\n", folder / "scenario.toml", []


def every_bound() -> list[tuple[str, str, str, str]]:
    """(the file, the field's path, a value beyond its bound, the bound the refusal names)."""
    cases = []
    for kind, cls in (("robot", RobotParams), ("rider", RiderParams), ("bench", BusConfig)):
        for b in bounds(cls):
            if b.choices or not (b.low is not None or b.high is not None):
                continue
            path = f"can.{b.path}" if kind == "bench" else b.path
            cases += [
                (kind, path, value, f"Expected `{'int' if b.whole else 'float'}` {bound} - at `$.{path}`")
                for value, bound in beyond(b)
            ]
    for seg in segment_kinds():
        tag = seg.__struct_config__.tag
        for b in bounds(seg):
            if b.low is None and b.high is None:  # within the rider's reach: 30 deg for the reference rider
                for value, says in (
                    ("nan", "is not a finite number"),
                    ("inf", "is not a finite number"),
                    ("31.0", "past the rider's reach"),
                ):
                    cases.append(("intent", f"{tag}.{b.path}", value, says))
                continue
            for value, bound in beyond(b):
                cases.append(
                    (
                        "intent",
                        f"{tag}.{b.path}",
                        value,
                        f"Expected `float` {bound} - at `$.intent.pitch[0].{b.path}`",
                    )
                )
    return cases


EVERY_BOUND = every_bound()


def test_the_generated_cases_cover_every_file_and_field():
    kinds = {kind for kind, *_ in EVERY_BOUND}
    assert kinds == {"robot", "rider", "bench", "intent"}
    paths = {path for _, path, *_ in EVERY_BOUND}
    assert {
        "body.mass",
        "ball.inertia",
        "max_hip_torque",
        "can.bitrate",
        "ramp.to",
        "sine.frequency_hz",
    } <= paths
    assert len(paths) > 75 and len(EVERY_BOUND) > 350


@pytest.mark.parametrize(
    ("kind", "path", "value", "says"), EVERY_BOUND, ids=[f"{k}-{p}={v}" for k, p, v, _ in EVERY_BOUND]
)
def test_each_bounded_field_beyond_its_bound_exits_2_naming_the_file_the_field_and_the_bound(
    tmp_path, capsys, kind, path, value, says
):
    text, holder, options = _files(tmp_path, kind, path, value)
    _, err = run_refused(tmp_path, capsys, text, 1.0, *options)
    assert str(holder) in err and says in err, err
    if kind == "intent":
        assert f"intent.pitch[0] ({path.split('.')[0]})" in err or "$.intent.pitch[0]." in err, err
