"""The robot and its rider in 3-D (hil/outputs/bodies.py, foxglove.py, recording.py): each body's shapes
placed by its pose land where MuJoCo puts the model's geoms (the 3-D plant in random configurations, its
welded bodies folded onto the chassis, the planar plant upright); the pose log streams; and a run's run.mcap
(read back with the `mcap` package's reader) and recording.rrd (rerun's own reader) hold every body's pose
at 100 Hz equal to the plant's and to trace.npy's truth, with the shapes once, while trace.npy and the CAN
frames stay as they are without them."""

from __future__ import annotations

import json
import math
import mmap
from pathlib import Path

import can
import msgspec
import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

from drivers.rotations import euler_zyx, multiply, rotate
from hil.outputs.bodies import (
    POSE_VALUES,
    PoseLog,
    PoseTaker,
    every,
    flatten,
    model_bodies,
    plant_bodies,
)
from hil.outputs.foxglove import FrameTransforms
from hil.outputs.trace_log import LAYOUT
from hil.pipeline import run
from hil.run.build import RunOptions
from hil.run.scenario import Intent, Scenario
from plant.ballbot import Plant
from plant.ballbot3d import Plant3D
from plant.model3d import build_model
from plant.rider import Ramp
from tests.helpers import RIDER_75, robot, sim
from tests.test_mcap import bench

BODY_NAMES = ["ball", "chassis", "thigh_left", "shank_left", "thigh_right", "shank_right", "torso"]


def world_shapes(bodies, poses) -> list[tuple]:
    """Each shape of `bodies` placed by its body's pose: (kind, size, world position, world rotation
    matrix, rgba)."""
    placed = []
    for body in bodies:
        p, q = poses[body.name]
        for s in body.shapes:
            x, y, z = rotate(s.position, q)
            matrix = np.zeros(9)
            mujoco.mju_quat2Mat(matrix, np.array(multiply(q, s.orientation)))
            placed.append((s.kind, s.size, (p[0] + x, p[1] + y, p[2] + z), matrix, s.rgba))
    return placed


def engine_geoms(model, data) -> list[tuple]:
    """MuJoCo's own world poses of the model's geoms but the floor, as world_shapes has them."""
    kinds = {
        int(getattr(mujoco.mjtGeom, f"mjGEOM_{k.upper()}")): k for k in ("sphere", "capsule", "cylinder")
    }
    return [
        (
            kinds[int(model.geom_type[g])],
            tuple(model.geom_size[g]),
            tuple(data.geom_xpos[g]),
            data.geom_xmat[g],
            tuple(model.geom_rgba[g]),
        )
        for g in range(model.ngeom)
        if int(model.geom_type[g]) in kinds
    ]


def unmatched(placed: list[tuple], geoms: list[tuple], tol: float = 1e-9) -> list[tuple]:
    """The geoms no placed shape coincides with (kind, size, colour, position and orientation), each shape
    used once; plus any shape left over."""
    left = list(placed)
    missing = []
    for kind, size, pos, mat, rgba in geoms:
        for i, (k, s, p, m, c) in enumerate(left):
            if (
                (k, c) == (kind, rgba)
                and np.allclose(s, size, atol=tol)
                and np.allclose(p, pos, atol=tol)
                and np.allclose(m, mat, atol=tol)
            ):
                del left[i]
                break
        else:
            missing.append((kind, size, pos))
    return missing + left


def random_configuration(plant: Plant3D, rng) -> None:
    """Any pose of the ball, the chassis on it and the torso on its hinges (not a state of the dynamics: the
    drawing is checked, not the physics)."""
    d = plant.data
    d.qpos[0:3] = rng.uniform(-1.0, 1.0, 3) + np.array([0.0, 0.0, 1.0])
    for start in (3, 7):  # the ball's free joint, then the chassis' ball joint
        q = rng.normal(size=4)
        d.qpos[start : start + 4] = q / np.linalg.norm(q)
    d.qpos[11:13] = rng.uniform(-0.5, 0.5, 2)  # the torso's lean hinges
    mujoco.mj_kinematics(plant.model, d)


def test_every_shape_lands_on_its_geom_in_any_configuration():
    plant = Plant3D(robot(), RIDER_75, sim(plant="3d"))
    bodies = plant_bodies(plant)
    assert [b.name for b in bodies] == BODY_NAMES == list(plant.poses())
    assert [len(b.shapes) for b in bodies] == [1, 2, 1, 2, 1, 2, 1]
    assert plant.model.nq == 13  # free joint 7, ball joint 4, two hinges: random_configuration's layout
    rng = np.random.default_rng(5)
    for _ in range(5):
        random_configuration(plant, rng)
        geoms = engine_geoms(plant.model, plant.data)
        assert len(geoms) == 10 and unmatched(world_shapes(bodies, plant.poses()), geoms) == []
    # Positive control: a shape half a millimetre off, or one turned by a degree, is seen.
    body = bodies[-1]
    shape = body.shapes[0]
    moved = shape._replace(position=(shape.position[0] + 5e-4, *shape.position[1:]))
    turned = shape._replace(
        orientation=multiply(shape.orientation, (math.cos(0.0087), math.sin(0.0087), 0, 0))
    )
    for wrong in (moved, turned):
        broken = (*bodies[:-1], body._replace(shapes=(wrong,)))
        assert len(unmatched(world_shapes(broken, plant.poses()), geoms)) == 2


def test_bodies_without_a_pose_are_drawn_with_the_body_they_are_welded_to():
    """Thighs and shanks have no joint: with only ball, chassis and torso posed (as the planar plant poses
    them) their shapes ride on the chassis, still where MuJoCo puts them."""
    plant = Plant3D(robot(), RIDER_75, sim(plant="3d"))
    random_configuration(plant, np.random.default_rng(11))
    three = {name: pose for name, pose in plant.poses().items() if name in ("ball", "chassis", "torso")}
    bodies = model_bodies(plant.model, three)
    assert [(b.name, len(b.shapes)) for b in bodies] == [("ball", 1), ("chassis", 8), ("torso", 1)]
    assert unmatched(world_shapes(bodies, three), engine_geoms(plant.model, plant.data)) == []


def test_the_planar_plant_is_drawn_with_the_same_model_upright():
    planar = Plant(robot(), RIDER_75, sim(plant="planar"))
    bodies = plant_bodies(planar)
    assert [(b.name, len(b.shapes)) for b in bodies] == [("ball", 1), ("chassis", 8), ("torso", 1)]
    s = planar.sim
    model = mujoco.MjModel.from_xml_string(build_model(planar.robot, planar.rider, s.mujoco, s.dt).xml)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # the model's reference pose: upright, ball on the floor, no lean
    assert unmatched(world_shapes(bodies, planar.poses()), engine_geoms(model, data)) == []


def test_a_plant_without_a_rider_has_ball_and_chassis():
    plant = Plant3D(robot(), None, sim(plant="3d"))
    assert [(b.name, len(b.shapes)) for b in plant_bodies(plant)] == [("ball", 1), ("chassis", 2)]


def test_the_pose_rate():
    assert [every(hz) for hz in (400.0, 1000.0, 100.0, 250.0, 50.0)] == [4, 10, 1, 3, 1]


def in_a_map(a: np.ndarray) -> bool:
    """`a` is a view of a memory-mapped file (its memory the file's pages, not the process's)."""
    while isinstance(a, np.ndarray):
        a = a.base
    return isinstance(a, mmap.mmap)


@pytest.mark.parametrize("streamed", [True, False])
def test_the_pose_log_gives_back_every_row_and_leaves_no_file(tmp_path, streamed):
    plant = Plant3D(robot(), RIDER_75, sim(plant="3d"))
    bodies = plant_bodies(plant)
    log = PoseLog(bodies, tmp_path if streamed else None)
    rows = np.random.default_rng(1).normal(size=(2500, len(bodies) * POSE_VALUES))  # blocks of 1024
    for i, row in enumerate(rows):
        log.append(i * 0.01, row.tolist())
    poses = log.close()
    assert isinstance(poses.values, np.memmap) is streamed
    assert all(in_a_map(a) is streamed for a in (poses.values, poses.t))  # streamed: views, no copy
    assert np.array_equal(poses.t, np.arange(2500) * 0.01)
    assert np.array_equal(poses.values, rows.reshape(2500, len(bodies), POSE_VALUES))
    assert list(tmp_path.iterdir()) == []  # streamed to a file with no name: nothing left behind
    assert PoseLog(bodies, tmp_path).close().values.shape == (0, len(bodies), POSE_VALUES)


def test_a_frame_transform_is_the_pose_in_foxgloves_fields():
    plant = Plant3D(robot(), None, sim(plant="3d"))
    bodies = plant_bodies(plant)
    row = [0.1, -0.2, 0.3, 0.5, 0.5, -0.5, 0.5, 1e-17, 2.0, float("nan"), 1.0, 0.0, 0.0, 0.0]
    messages = [json.loads(m) for m in FrameTransforms(bodies).encode(12_345_678_901, row)]
    assert messages[0] == {
        "timestamp": {"sec": 12, "nsec": 345_678_901},
        "parent_frame_id": "world",
        "child_frame_id": "ball",
        "translation": {"x": 0.1, "y": -0.2, "z": 0.3},
        "rotation": {"x": 0.5, "y": -0.5, "z": 0.5, "w": 0.5},
    }
    assert messages[1]["translation"] == {"x": 1e-17, "y": 2.0, "z": None}  # NaN: JSON's null
    assert messages[1]["child_frame_id"] == "chassis" and messages[1]["rotation"]["w"] == 1.0


def test_flatten_orders_each_pose_position_first():
    poses = {"b": ((4.0, 5.0, 6.0), (0.0, 1.0, 0.0, 0.0)), "a": ((1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0))}
    assert flatten(poses, ["a", "b"]) == [
        1.0,
        2.0,
        3.0,
        1.0,
        0.0,
        0.0,
        0.0,
        4.0,
        5.0,
        6.0,
        0.0,
        1.0,
        0.0,
        0.0,
    ]


def test_the_pose_taker_keeps_and_sends_the_same_poses_at_its_rate_and_the_last_tick(tmp_path):
    planar = Plant(robot(), RIDER_75, sim(plant="planar"))
    sent: list[tuple[float, list[float]]] = []
    taker = PoseTaker(planar, True, tmp_path, lambda t, row: sent.append((t, row)))
    assert taker.every == 4
    expected = {}
    taker.take(planar, 0)
    expected[0] = planar.poses()
    for n in range(1, 11):
        planar.step()
        if n % taker.every == 0:
            taker.take(planar, n)
            expected[n] = planar.poses()
    expected[10] = planar.poses()
    kept = taker.close(planar, 10)
    assert [b.name for b in kept.bodies] == ["ball", "chassis", "torso"]
    assert np.array_equal(kept.t, [n / 400 for n in expected]) and [t for t, _ in sent] == list(kept.t)
    rows = [flatten(poses, ["ball", "chassis", "torso"]) for poses in expected.values()]
    assert np.array_equal(kept.values.reshape(len(rows), -1), rows) and [row for _, row in sent] == rows
    assert taker.close(planar, 10) is not None and len(sent) == len(rows), "the last tick is taken once"


# ------------------------------------------------------------------------------------ a run, end to end
TICKS = 241  # not a multiple of the pose interval: the last tick's poses are taken as well
SCENARIO = Scenario(
    name="bodies",
    rider="configs/riders/s16_mwcu_52kg_167.toml",
    law="ihacs",
    duration=TICKS / 400,
    seed=4,
    intent=Intent(pitch=[Ramp(to=12.0, duration=0.4)], roll=[Ramp(to=-6.0, duration=0.4)]),
)


@pytest.fixture(scope="module")
def ride(tmp_path_factory) -> tuple[Path, dict[int, dict]]:
    """A run with every output, and the plant's own poses after every tick."""
    out = tmp_path_factory.mktemp("ride")
    seen: dict[int, dict] = {}
    options = RunOptions(on_tick=lambda plant: seen.update({plant.tick: plant.poses()}))
    result = run(SCENARIO, bench(recording=True), out=out, options=options)
    assert result.trace.failure is None and result.trace.stats.ticks == TICKS
    assert json.loads((out / "summary.json").read_text())["outputs_failed"] == {}
    return out, seen


def read(path: Path, topic: str) -> list[tuple[int, dict]]:
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        return [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=[topic])]


def pose_ticks() -> list[int]:
    return [*range(4, TICKS, 4), TICKS]


def as_pose(message: dict) -> tuple[tuple, tuple]:
    p, r = message["translation"], message["rotation"]
    return (p["x"], p["y"], p["z"]), (r["w"], r["x"], r["y"], r["z"])


def test_run_mcap_has_each_bodys_pose_at_100_hz_equal_to_the_plants(ride):
    out, seen = ride
    with open(out / "run.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    channels = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    for name in BODY_NAMES:
        assert (channels[f"/pose/{name}"].name, channels[f"/pose/{name}"].encoding) == (
            "foxglove.FrameTransform",
            "jsonschema",
        )
        got = read(out / "run.mcap", f"/pose/{name}")
        # At t = 0 (before the first tick), every 4th tick (100 Hz), and the last tick.
        assert [t for t, _ in got] == [0] + [k * 2_500_000 for k in pose_ticks()]
        for t, m in got:
            assert m["parent_frame_id"] == "world" and m["child_frame_id"] == name
            assert m["timestamp"]["sec"] * 1_000_000_000 + m["timestamp"]["nsec"] == t
        assert [as_pose(m) for _, m in got[1:]] == [seen[k][name] for k in pose_ticks()]
        assert [as_pose(m) for _, m in got[1:]] != [seen[k - 1][name] for k in pose_ticks()]  # control
    # Against the truth trace.npy keeps: the ball's centre is the position, the chassis' orientation the tilt.
    rows = np.load(out / "trace.npy")
    t, position, tilt, lean = (LAYOUT.span(group) for group in ("t", "position", "tilt", "lean"))
    ball, chassis = read(out / "run.mcap", "/pose/ball")[1:], read(out / "run.mcap", "/pose/chassis")[1:]
    for k, (_, b), (_, c) in zip(pose_ticks(), ball, chassis, strict=True):
        row = rows[k - 1]
        assert abs(row[t] - k / 400) < 1e-12
        assert (b["translation"]["x"], b["translation"]["y"]) == tuple(row[position])
        roll, pitch, _ = euler_zyx(as_pose(c)[1])
        assert abs(pitch - row[tilt][0]) < 1e-9 and abs(roll - row[tilt][1]) < 1e-9
    moved = rows[-1, tilt][0] > 0.005 and abs(rows[-1, lean][0]) > 0.01
    assert moved, "the robot tilted and the rider leaned"


def schema_mismatch(value, schema: dict, where: str = "") -> str | None:
    """Where a message differs from its JSON Schema: an object with a field the schema has not, or without
    one it has; a value of another type (None: nowhere)."""
    kind = schema.get("type")
    if kind == "object":
        if not isinstance(value, dict) or set(value) != set(schema["properties"]):
            return f"{where}: {sorted(value) if isinstance(value, dict) else value}"
        for key, sub in schema["properties"].items():
            if (wrong := schema_mismatch(value[key], sub, f"{where}.{key}")) is not None:
                return wrong
        return None
    if kind == "array":
        for i, item in enumerate(value):
            if schema["items"].get("properties") and (
                wrong := schema_mismatch(item, schema["items"], f"{where}[{i}]")
            ):
                return wrong
        return None if isinstance(value, list) else where
    types = {"number": (int, float), "integer": int, "string": str, "boolean": bool}[kind]
    return None if isinstance(value, types) and (kind == "boolean" or not isinstance(value, bool)) else where


def test_the_scene_draws_each_body_in_its_frame_once(ride):
    out, _ = ride
    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    scene = read(out / "run.mcap", "/scene")
    assert [t for t, _ in scene] == [0] and schemas["/scene"].name == "foxglove.SceneUpdate"
    update = scene[0][1]
    assert schema_mismatch(update, json.loads(schemas["/scene"].data)) is None
    pose = read(out / "run.mcap", "/pose/torso")[0][1]
    assert schema_mismatch(pose, json.loads(schemas["/pose/torso"].data)) is None
    assert schema_mismatch({**pose, "extra": 1}, json.loads(schemas["/pose/torso"].data)) is not None
    entities = {e["id"]: e for e in update["entities"]}
    assert list(entities) == BODY_NAMES
    counts = {n: (len(e["spheres"]), len(e["cylinders"]), len(e["cubes"])) for n, e in entities.items()}
    # A capsule is a cylinder with a sphere at each end; the shank has its foot too.
    assert counts == {
        "ball": (1, 0, 0),
        "chassis": (0, 2, 0),
        "thigh_left": (2, 1, 0),
        "shank_left": (4, 2, 0),
        "thigh_right": (2, 1, 0),
        "shank_right": (4, 2, 0),
        "torso": (2, 1, 0),
    }
    for name, e in entities.items():
        assert (e["frame_id"], e["frame_locked"], e["lifetime"]) == (name, True, {"sec": 0, "nsec": 0})
    ball = entities["ball"]["spheres"][0]
    plant = Plant3D(robot(), None, sim(plant="3d"))
    radius = plant.robot.ball.radius
    assert ball["size"] == {"x": 2 * radius, "y": 2 * radius, "z": 2 * radius}


def test_the_recording_has_the_bodies_moving_on_the_simulated_timeline(ride):
    import rerun.chunk

    out, seen = ride
    reader = rerun.chunk.RrdReader(str(out / "recording.rrd"))
    chunks = list(reader.stream())
    for name in BODY_NAMES:
        moving = [c for c in chunks if c.entity_path == f"/bodies/{name}" and not c.is_static]
        assert len(moving) == 1
        batch = moving[0].to_record_batch()
        times = batch.column("sim_time").cast("int64").to_pylist()
        assert times == [0] + [k * 2_500_000 for k in pose_ticks()]
        translation = np.array(batch.column("Transform3D:translation").to_pylist())[:, 0]
        quaternion = np.array(batch.column("Transform3D:quaternion").to_pylist())[:, 0]
        expected = [seen[k][name] for k in pose_ticks()]
        assert np.allclose(translation[1:], [p for p, _ in expected], atol=1e-6)  # rerun keeps float32
        assert np.allclose(quaternion[1:], [(x, y, z, w) for _, (w, x, y, z) in expected], atol=1e-6)
    shapes = {c.entity_path: c for c in chunks if c.is_static and c.entity_path.startswith("/bodies/")}
    assert set(shapes) == {
        "/bodies/ball/ellipsoids",
        "/bodies/chassis/cylinders",
        *(f"/bodies/{limb}/capsules" for limb in BODY_NAMES[2:]),
    }
    ball = shapes["/bodies/ball/ellipsoids"].to_record_batch()
    radius = Plant3D(robot(), None, sim(plant="3d")).robot.ball.radius
    assert np.allclose(ball.column("Ellipsoids3D:half_sizes").to_pylist()[0], [[radius] * 3])
    assert "/bodies:ViewCoordinates:xyz" in str(reader.store().schema())


def test_the_trace_and_the_frames_are_the_same_without_the_bodies(ride, tmp_path):
    """The poses are an addition: a run that takes none (no recording, no run.mcap) writes the same
    trace.npy byte for byte and the same frames in the same order (can.log's wall-clock stamps aside)."""
    out, _ = ride
    run(SCENARIO, bench(recording=False, mcap=False), out=tmp_path)
    assert not (tmp_path / "run.mcap").exists()
    assert (tmp_path / "trace.npy").read_bytes() == (out / "trace.npy").read_bytes()

    def frames(path: Path) -> list[tuple[int, bytes]]:
        return [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(path))]

    assert frames(tmp_path / "can.log") == frames(out / "can.log")
    other = msgspec.structs.replace(SCENARIO, seed=5)  # positive control: what changes the trace is seen
    run(other, bench(recording=False, mcap=False), out=tmp_path / "other")
    assert (tmp_path / "other" / "trace.npy").read_bytes() != (out / "trace.npy").read_bytes()
