"""The robot and its rider as bodies to draw in 3-D: each body the plant gives a pose for (`poses()`: ball,
chassis, torso, and on the 3-D plant thighs and shanks), with its shapes in its own frame, and the poses
taken from the plant as the run goes (`PoseLog`).

The shapes are MuJoCo's geoms of the robot's model (plant/model3d.py): the 3-D plant's own model, or for
the planar plant the same model compiled from the same robot and rider, its bodies placed by the planar
plant's poses. A body the plant gives no pose for (the planar plant's thighs and shanks) is drawn with the
posed body it is rigidly attached to; a body that moves on a joint of its own and has no pose is not drawn.

Poses are taken every `every(tick_hz)` ticks (POSES_HZ), at t = 0 before the first tick and at the run's
last tick: the views' frame rate, not the physics' (trace.npy keeps every tick's truth). A body's pose is
its frame in the world: position (m, z up from the floor) and orientation as a unit quaternion (w, x, y, z).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drivers.rotations import Quat, Vec3, multiply, rotate
from plant.core import PlantCore, Pose

POSES_HZ = 100.0
"""At most this many poses per simulated second: smooth to the eye, a quarter of a 400 Hz run's ticks."""
POSE_VALUES = 7
"""Numbers per body and pose: position x, y, z, then the quaternion w, x, y, z."""
BLOCK = 1024
"""Poses per write to the pose log's file."""
KINDS = ("sphere", "capsule", "cylinder", "box", "ellipsoid")
"""The shapes drawn: MuJoCo's geom types of those names (planes, height fields and meshes are not)."""


def every(tick_hz: float) -> int:
    """Ticks between poses: POSES_HZ or less."""
    return max(1, math.ceil(tick_hz / POSES_HZ - 1e-9))


class Shape(NamedTuple):
    """A geom in its body's frame."""

    kind: str
    """One of KINDS."""
    size: Vec3
    """MuJoCo's geom size: sphere (radius, -, -); capsule and cylinder (radius, half length, -) along the
    shape's z axis; box (half sizes x, y, z); ellipsoid (radii x, y, z). m."""
    position: Vec3
    orientation: Quat
    rgba: tuple[float, float, float, float]
    """Colour and opacity, 0..1."""

    def along_z(self, distance: float) -> Vec3:
        """The point `distance` along the shape's z axis from its centre, in the body's frame."""
        x, y, z = rotate((0.0, 0.0, distance), self.orientation)
        px, py, pz = self.position
        return px + x, py + y, pz + z


class Body(NamedTuple):
    name: str
    shapes: tuple[Shape, ...]


def model_bodies(model: object, posed: Iterable[str]) -> tuple[Body, ...]:
    """The `posed` bodies of a compiled MuJoCo model (`mujoco.MjModel`), in `posed`'s order, each with its
    own geoms and those of the unposed bodies welded to it (no joint between them)."""
    import mujoco

    m = model
    assert isinstance(m, mujoco.MjModel)
    names = list(posed)
    ids = {name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name) for name in names}
    missing = [name for name, b in ids.items() if b < 0]
    if missing:
        raise ValueError(f"the model has no body {', '.join(missing)}")
    owner = {b: name for name, b in ids.items()}
    kinds = {int(getattr(mujoco.mjtGeom, f"mjGEOM_{kind.upper()}")): kind for kind in KINDS}
    shapes: dict[str, list[Shape]] = {name: [] for name in names}
    for g in range(m.ngeom):
        kind = kinds.get(int(m.geom_type[g]))
        if kind is None:
            continue
        position = _vec3(m.geom_pos[g])
        orientation = _four(m.geom_quat[g])
        b = int(m.geom_bodyid[g])
        # Up the tree to the posed body this geom moves with, its pose carried into that body's frame.
        while b not in owner and b > 0 and int(m.body_jntnum[b]) == 0:
            lift, turn = _vec3(m.body_pos[b]), _four(m.body_quat[b])
            x, y, z = rotate(position, turn)
            position = (lift[0] + x, lift[1] + y, lift[2] + z)
            orientation = multiply(turn, orientation)
            b = int(m.body_parentid[b])
        if b in owner:
            shape = Shape(kind, _vec3(m.geom_size[g]), position, orientation, _four(m.geom_rgba[g]))
            shapes[owner[b]].append(shape)
    return tuple(Body(name, tuple(shapes[name])) for name in names)


def plant_bodies(plant: PlantCore) -> tuple[Body, ...]:
    """The bodies of `plant` in the order of its `poses()`."""
    return model_bodies(plant.body_model(), plant.poses())


def flatten(poses: dict[str, Pose], names: Sequence[str]) -> list[float]:
    """`poses` as one row: per body of `names`, its position then its quaternion (POSE_VALUES numbers)."""
    row: list[float] = []
    for name in names:
        position, orientation = poses[name]
        row += position
        row += orientation
    return row


@dataclass(frozen=True, slots=True)
class Poses:
    """The bodies' poses a run took: what its 3-D views draw."""

    bodies: tuple[Body, ...]
    t: np.ndarray
    """(n,) simulated time of each pose, s."""
    values: np.ndarray
    """(n, len(bodies), POSE_VALUES): each body's position (m) and quaternion (w, x, y, z), world frame."""


class PoseLog:
    """The poses as they are taken. With a folder they stream in blocks to an unnamed file there (gone when
    the last reader of its memory map is, and never left behind) and come back as a read-only memory map:
    memory stays flat in a run's length, as trace.npy's. Without one they stay in memory."""

    def __init__(self, bodies: tuple[Body, ...], folder: Path | None = None):
        self.bodies = bodies
        self.rows = 0
        self._width = 1 + POSE_VALUES * len(bodies)
        self._buffer = np.full((BLOCK, self._width), np.nan)
        self._kept: list[np.ndarray] = []
        self._file = None if folder is None else tempfile.TemporaryFile(dir=folder)  # noqa: SIM115
        self._closed: Poses | None = None

    def append(self, t: float, row: Sequence[float]) -> None:
        """One pose of every body at `t`: a row as `flatten` makes it."""
        i = self.rows % BLOCK
        buffer = self._buffer
        buffer[i, 0] = t
        buffer[i, 1:] = row
        self.rows += 1
        if i == BLOCK - 1:
            self._write(buffer)

    def close(self) -> Poses:
        """Every pose appended (the same on a second call)."""
        if self._closed is not None:
            return self._closed
        filled = self._buffer[: self.rows % BLOCK]
        if len(filled):
            self._write(filled)
        shape = (self.rows, self._width)
        if self._file is None:
            rows = np.concatenate(self._kept) if self._kept else np.zeros(shape)
        else:
            self._file.flush()
            rows = np.memmap(self._file, np.float64, "r", shape=shape) if self.rows else np.zeros(shape)
            self._file.close()  # the map keeps the file until it is dropped
        values = rows[:, 1:].reshape(self.rows, len(self.bodies), POSE_VALUES)
        self._closed = Poses(self.bodies, rows[:, 0], values)
        return self._closed

    def _write(self, rows: np.ndarray) -> None:
        if self._file is None:
            self._kept.append(rows.copy())
        else:
            self._file.write(rows.data)


def _vec3(values: np.ndarray) -> Vec3:
    x, y, z = values.tolist()
    return x, y, z


def _four(values: np.ndarray) -> tuple[float, float, float, float]:
    a, b, c, d = values.tolist()
    return a, b, c, d


class PoseTaker:
    """The tick loop's side: the plant's poses at t = 0, every `every` ticks after and at the last tick,
    kept for the recording (`keep`: in `folder`, None: in memory) and handed to `send` (run.mcap's writer)."""

    def __init__(
        self,
        plant: PlantCore,
        keep: bool,
        folder: Path | None,
        send: Callable[[float, list[float]], None] | None,
    ):
        self.bodies = plant_bodies(plant)
        self._names = [body.name for body in self.bodies]
        self.every = every(plant.sim.tick_hz)
        self._log = PoseLog(self.bodies, folder) if keep else None
        self._send = send
        self._taken = -1
        """The tick count of the last poses taken."""

    def take(self, plant: PlantCore, ticks: int) -> None:
        """The poses now, after `ticks` ticks of the run."""
        row = flatten(plant.poses(), self._names)
        if self._log is not None:
            self._log.append(plant.t, row)
        if self._send is not None:
            self._send(plant.t, row)
        self._taken = ticks

    def close(self, plant: PlantCore, ticks: int) -> Poses | None:
        """The last tick's poses (if not taken yet), and every pose kept (None: none were)."""
        if self._taken != ticks:
            self.take(plant, ticks)
        return None if self._log is None else self._log.close()
