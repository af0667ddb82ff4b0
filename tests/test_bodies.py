"""The robot and its rider in 3-D (hil/outputs/bodies.py): each body's shapes placed by its pose land where
MuJoCo puts the model's geoms (the 3-D plant in random configurations, its welded bodies folded onto the
chassis, the planar plant upright), and the pose log streams."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from hil.outputs.bodies import (
    POSE_VALUES,
    PoseLog,
    every,
    flatten,
    model_bodies,
    multiply,
    plant_bodies,
    rotate,
)
from plant.ballbot import Plant
from plant.ballbot3d import Plant3D
from plant.model3d import build_model
from tests.helpers import RIDER_75, robot, sim

BODY_NAMES = ["ball", "chassis", "thigh_left", "shank_left", "thigh_right", "shank_right", "torso"]


def world_shapes(bodies, poses) -> list[tuple]:
    """Each shape of `bodies` placed by its body's pose: (kind, size, world position, world rotation
    matrix, rgba)."""
    placed = []
    for body in bodies:
        p, q = poses[body.name]
        for s in body.shapes:
            x, y, z = rotate(q, s.position)
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
    assert np.array_equal(poses.t, np.arange(2500) * 0.01)
    assert np.array_equal(poses.values, rows.reshape(2500, len(bodies), POSE_VALUES))
    assert list(tmp_path.iterdir()) == []  # streamed to a file with no name: nothing left behind
    assert PoseLog(bodies, tmp_path).close().values.shape == (0, len(bodies), POSE_VALUES)


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
