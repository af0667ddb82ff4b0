"""The bodies in run.mcap as Foxglove's 3-D panel reads them: a `foxglove.FrameTransform` per body and pose
(its frame from "world"), and one `foxglove.SceneUpdate` with every body's shapes, each drawn in its body's
frame and following it (docs.foxglove.dev, message schemas). JSON with JSON Schemas, as run.mcap's other
channels; the schemas hold the fields written here, inline (no `$ref`).

Foxglove has no capsule: a capsule is drawn as a cylinder with a sphere at each end.
"""

from __future__ import annotations

from collections.abc import Sequence

import msgspec

from drivers.rotations import Quat, Vec3
from hil.outputs.bodies import POSE_VALUES, Body, Shape

FRAME_TRANSFORM = "foxglove.FrameTransform"
SCENE_UPDATE = "foxglove.SceneUpdate"
"""The schema names Foxglove knows the messages by (it recognises them by name)."""
WORLD = "world"
"""The frame every body's transform is from."""

_encode = msgspec.json.Encoder().encode


def _number(description: str) -> dict:
    return {"type": "number", "description": description}


def _object(title: str, description: str, properties: dict) -> dict:
    return {"title": title, "description": description, "type": "object", "properties": properties}


def _time(description: str, title: str = "time") -> dict:
    """A time (or, titled "duration", a length of time) as seconds and nanoseconds."""
    second = {"type": "integer", "minimum": 0}
    nanosecond = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {"sec": second, "nsec": nanosecond},
    }


def _vector3(description: str) -> dict:
    return _object("foxglove.Vector3", description, {axis: _number(f"{axis}, m") for axis in "xyz"})


def _quaternion(description: str) -> dict:
    return _object("foxglove.Quaternion", description, {part: _number(part) for part in "xyzw"})


def _pose(description: str) -> dict:
    properties = {
        "position": _vector3("the centre, in the entity's frame"),
        "orientation": _quaternion("orientation in the entity's frame"),
    }
    return _object("foxglove.Pose", description, properties)


def _color(description: str) -> dict:
    return _object("foxglove.Color", description, {part: _number(f"{part}, 0..1") for part in "rgba"})


def frame_transform_schema() -> bytes:
    properties = {
        "timestamp": _time("simulated time of the pose"),
        "parent_frame_id": {"type": "string", "description": "the world"},
        "child_frame_id": {"type": "string", "description": "the body"},
        "translation": _vector3("the body's origin in the world, m (z up from the floor)"),
        "rotation": _quaternion("the body's orientation in the world"),
    }
    return _encode(_object(FRAME_TRANSFORM, "a body's frame in the world", properties))


def scene_update_schema() -> bytes:
    def primitives(title: str, description: str, **extra: dict) -> dict:
        item = _object(title, description, {"pose": _pose(description), **extra, "color": _color("colour")})
        return {"type": "array", "items": item, "description": description}

    size = _vector3("extent along each axis, m")
    unused = {"type": "array", "items": {"type": "object"}, "description": "none here"}
    entity = _object(
        "foxglove.SceneEntity",
        "a body's shapes, in its frame",
        {
            "timestamp": _time("when the entity was published"),
            "frame_id": {"type": "string", "description": "the body's frame"},
            "id": {"type": "string", "description": "the body"},
            "lifetime": _time("how long it is shown; 0: until replaced", "duration"),
            "frame_locked": {"type": "boolean", "description": "true: it moves with its frame"},
            "metadata": unused,
            "arrows": unused,
            "cubes": primitives("foxglove.CubePrimitive", "a box", size=size),
            "spheres": primitives("foxglove.SpherePrimitive", "a sphere or ellipsoid", size=size),
            "cylinders": primitives(
                "foxglove.CylinderPrimitive",
                "a cylinder along its z axis",
                size=size,
                bottom_scale=_number("the bottom face's share of the diameter"),
                top_scale=_number("the top face's share of the diameter"),
            ),
            "lines": unused,
            "triangles": unused,
            "texts": unused,
            "models": unused,
        },
    )
    properties = {
        "deletions": unused,
        "entities": {"type": "array", "items": entity, "description": "one entity per body"},
    }
    return _encode(_object(SCENE_UPDATE, "the bodies' shapes, each in its body's frame", properties))


def _xyz(v: Vec3) -> dict[str, float]:
    return {"x": v[0], "y": v[1], "z": v[2]}


def _xyzw(q: Quat) -> dict[str, float]:
    w, x, y, z = q
    return {"x": x, "y": y, "z": z, "w": w}


def _primitive(shape: Shape, position: Vec3, size: Vec3) -> dict:
    r, g, b, a = shape.rgba
    pose = {"position": _xyz(position), "orientation": _xyzw(shape.orientation)}
    return {"pose": pose, "size": _xyz(size), "color": {"r": r, "g": g, "b": b, "a": a}}


def _entity(body: Body) -> dict:
    cubes, spheres, cylinders = [], [], []
    for shape in body.shapes:
        a, b, c = shape.size
        if shape.kind == "box":
            cubes.append(_primitive(shape, shape.position, (2 * a, 2 * b, 2 * c)))
        elif shape.kind == "sphere":
            spheres.append(_primitive(shape, shape.position, (2 * a, 2 * a, 2 * a)))
        elif shape.kind == "ellipsoid":
            spheres.append(_primitive(shape, shape.position, (2 * a, 2 * b, 2 * c)))
        else:  # a cylinder, or a capsule's middle
            cylinder = _primitive(shape, shape.position, (2 * a, 2 * a, 2 * b))
            cylinders.append({**cylinder, "bottom_scale": 1.0, "top_scale": 1.0})
            if shape.kind == "capsule":
                for end in (-b, b):
                    spheres.append(_primitive(shape, shape.along_z(end), (2 * a, 2 * a, 2 * a)))
    zero = {"sec": 0, "nsec": 0}
    return {
        "timestamp": zero,
        "frame_id": body.name,
        "id": body.name,
        "lifetime": zero,
        "frame_locked": True,
        "metadata": [],
        "arrows": [],
        "cubes": cubes,
        "spheres": spheres,
        "cylinders": cylinders,
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }


def scene_update(bodies: Sequence[Body]) -> bytes:
    """Every body's shapes, at t = 0 and for the whole run (lifetime 0)."""
    return _encode({"deletions": [], "entities": [_entity(body) for body in bodies]})


class FrameTransforms:
    """A row of poses (hil/outputs/bodies.py `flatten`) as one FrameTransform message per body: a `%`
    template per body filled with msgspec's JSON numbers (the JSON a dict would give, at a fraction of its
    cost; NaN becomes null)."""

    def __init__(self, bodies: Sequence[Body]):
        self._templates = []
        for body in bodies:
            child = _encode(body.name).replace(b"%", b"%%")
            self._templates.append(
                b'{"timestamp":{"sec":%d,"nsec":%d},"parent_frame_id":"'
                + WORLD.encode()
                + b'","child_frame_id":'
                + child
                + b',"translation":{"x":%s,"y":%s,"z":%s},"rotation":{"x":%s,"y":%s,"z":%s,"w":%s}}'
            )

    def encode(self, at: int, row: Sequence[float]) -> list[bytes]:
        """The messages of a row of poses at `at` ns."""
        sec, nsec = divmod(at, 1_000_000_000)
        numbers = _encode(row)[1:-1].split(b",")
        messages = []
        for i, template in enumerate(self._templates):
            x, y, z, w, qx, qy, qz = numbers[POSE_VALUES * i : POSE_VALUES * (i + 1)]
            messages.append(template % (sec, nsec, x, y, z, qx, qy, qz, w))
        return messages
