"""The world as a Foxglove `foxglove.SceneUpdate` (JSON encoding), for the 3-D panel.

One message holds the whole scene of one step; entity ids are stable across the
steps of an episode, so each message replaces the previous one entity by entity:

- `arena`: the boundary [0, W] x [0, H] as a line loop, with a status text;
- `pursuer/<i>`: a 2.0 x 1.0 m hull (cube) turned to the heading, plus a heading
  arrow; collided pursuers stay where they crashed, greyed out;
- `evader/<j>`: a sphere of the robot radius, red while free, green once encircled;
- `obstacle/<k>`: a cylinder of the obstacle's radius;
- `vortex/<v>`: a flat disc at the core (r0) and an arrow along its rotation,
  orange clockwise, blue counter-clockwise.

Units are the world's (m, rad); the scene lies in the z = 0 plane of frame `world`.

Foxglove keeps every entity it was sent until it is deleted, so each update deletes
what is gone: the first scene of an episode starts with a deletion of type ALL (the
previous episode may have had more robots, obstacles or vortices), and a later one
deletes by id any entity of the previous scene it no longer holds (`previous_ids`).

`SCENE_UPDATE_SCHEMA` is the JSON Schema of the message written into logs, written
out from Foxglove's published field list; `official_scene_update_schema()` derives the
schema from Foxglove's own published definition (the `foxglove-schemas-protobuf`
package, in the dev extra), against which the tests check every logged scene and this
hand-written copy.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

SCENE_UPDATE = "foxglove.SceneUpdate"
"""Schema name Foxglove recognises for scene updates."""
FRAME_ID = "world"
"""Frame of every entity: the arena's, x east, y north, metres."""

_PRECISION = 4
"""decimals kept in the scene's coordinates (the exact state goes to /state)."""
_HULL = (2.0, 1.0, 0.6)
"""m: pursuer hull drawn as a box (length, width, height); the disc radius stays the world's."""

COLORS: dict[str, tuple[float, float, float, float]] = {
    "pursuer": (0.16, 0.42, 0.85, 1.0),
    "pursuer_collided": (0.55, 0.55, 0.55, 0.6),
    "evader": (0.86, 0.18, 0.18, 1.0),
    "evader_encircled": (0.15, 0.68, 0.30, 1.0),
    "obstacle": (0.35, 0.30, 0.26, 1.0),
    "vortex_clockwise": (0.93, 0.55, 0.10, 0.8),
    "vortex_counter": (0.10, 0.60, 0.85, 0.8),
    "arena": (0.2, 0.2, 0.2, 1.0),
    "text": (0.1, 0.1, 0.1, 1.0),
}
"""RGBA in [0, 1] of each kind of entity (also used by the renderer)."""


# --- JSON Schema ---------------------------------------------------------------


def _number(description: str) -> dict:
    return {"type": "number", "description": description}


def _object(title: str, description: str, properties: Mapping[str, dict]) -> dict:
    return {"title": title, "description": description, "type": "object", "properties": dict(properties)}


def _array(items: dict, description: str) -> dict:
    return {"type": "array", "items": items, "description": description}


def _vector3(description: str) -> dict:
    return _object(
        "foxglove.Vector3", description,
        {axis: _number(f"{axis} coordinate length") for axis in "xyz"},
    )


def _color(description: str) -> dict:
    names = {"r": "Red", "g": "Green", "b": "Blue", "a": "Alpha"}
    return _object(
        "foxglove.Color", description,
        {key: _number(f"{name} value between 0 and 1") for key, name in names.items()},
    )


def _pose(description: str) -> dict:
    quaternion = _object(
        "foxglove.Quaternion", "Quaternion denoting orientation in 3D space",
        {axis: _number(f"{axis} value") for axis in "xyzw"},
    )
    return _object(
        "foxglove.Pose", description,
        {"position": _vector3("Point denoting position in 3D space"), "orientation": quaternion},
    )


def _time(title: str, description: str, signed: bool) -> dict:
    sec = {"type": "integer"} if signed else {"type": "integer", "minimum": 0}
    return {
        "type": "object", "title": title, "description": description,
        "properties": {"sec": sec, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
    }


def _point3() -> dict:
    return _object(
        "foxglove.Point3", "Point in 3D space",
        {axis: _number(f"{axis} coordinate position") for axis in "xyz"},
    )


def _scene_update_schema() -> dict:
    indices = {"type": "array", "items": {"type": "integer", "minimum": 0}}
    primitives = {
        "arrows": _object("foxglove.ArrowPrimitive", "A primitive representing an arrow", {
            "pose": _pose("Position of the arrow's tail and orientation; identity points along +x"),
            "shaft_length": _number("Length of the arrow shaft"),
            "shaft_diameter": _number("Diameter of the arrow shaft"),
            "head_length": _number("Length of the arrow head"),
            "head_diameter": _number("Diameter of the arrow head"),
            "color": _color("Color of the arrow"),
        }),
        "cubes": _object("foxglove.CubePrimitive", "A primitive representing a cube or rectangular prism", {
            "pose": _pose("Position of the center of the cube and orientation of the cube"),
            "size": _vector3("Size of the cube along each axis"),
            "color": _color("Color of the cube"),
        }),
        "spheres": _object("foxglove.SpherePrimitive", "A primitive representing a sphere or ellipsoid", {
            "pose": _pose("Position of the center of the sphere and orientation of the sphere"),
            "size": _vector3("Size (diameter) of the sphere along each axis"),
            "color": _color("Color of the sphere"),
        }),
        "cylinders": _object(
            "foxglove.CylinderPrimitive", "A primitive representing a cylinder, elliptic cylinder, or truncated cone", {
                "pose": _pose("Position of the center of the cylinder; flat faces perpendicular to z"),
                "size": _vector3("Size of the cylinder's bounding box"),
                "bottom_scale": _number("0-1, diameter of the bottom face relative to the bounding box"),
                "top_scale": _number("0-1, diameter of the top face relative to the bounding box"),
                "color": _color("Color of the cylinder"),
            }),
        "lines": _object("foxglove.LinePrimitive", "A primitive representing a series of points connected by lines", {
            "type": {
                "title": "foxglove.LineType", "description": "How the points are connected",
                "oneOf": [
                    {"title": "LINE_STRIP", "const": 0, "description": "0-1, 1-2, ..., (n-1)-n"},
                    {"title": "LINE_LOOP", "const": 1, "description": "0-1, 1-2, ..., (n-1)-n, n-0"},
                    {"title": "LINE_LIST", "const": 2, "description": "0-1, 2-3, 4-5, ..."},
                ],
            },
            "pose": _pose("Origin of lines relative to reference frame"),
            "thickness": _number("Width of the line"),
            "scale_invariant": {"type": "boolean", "description": "Thickness in screen pixels (true) or world units (false)"},
            "points": _array(_point3(), "Points along the line"),
            "color": _color("Solid color to use for the whole line"),
            "colors": _array(_color("Color"), "Per-point colors (overrides color)"),
            "indices": {**indices, "description": "Indices into the points and colors attribute arrays"},
        }),
        "triangles": _object("foxglove.TriangleListPrimitive", "A primitive representing a set of triangles", {
            "pose": _pose("Origin of triangles relative to reference frame"),
            "points": _array(_point3(), "Vertices to use for triangles, interpreted as a list of triples"),
            "color": _color("Solid color to use for the whole shape"),
            "colors": _array(_color("Color"), "Per-vertex colors (overrides color)"),
            "indices": {**indices, "description": "Indices into the points and colors attribute arrays"},
        }),
        "texts": _object("foxglove.TextPrimitive", "A primitive representing a text label", {
            "pose": _pose("Position of the center of the text box and orientation of the text"),
            "billboard": {"type": "boolean", "description": "Always face the camera (true) or respect the pose (false)"},
            "font_size": _number("Font size (height of one line of text)"),
            "scale_invariant": {"type": "boolean", "description": "font_size in screen pixels (true) or world units (false)"},
            "color": _color("Color of the text"),
            "text": {"type": "string", "description": "Text"},
        }),
        "models": _object("foxglove.ModelPrimitive", "A primitive representing a 3D model file", {
            "pose": _pose("Origin of model relative to reference frame"),
            "scale": _vector3("Scale factor to apply to the model along each axis"),
            "color": _color("Solid color to use for the whole model if override_color is true"),
            "override_color": {"type": "boolean", "description": "Whether to use the color instead of the model's own"},
            "url": {"type": "string", "description": "URL pointing to model file"},
            "media_type": {"type": "string", "description": "Media type of embedded model"},
            "data": {"type": "string", "contentEncoding": "base64", "description": "Embedded model"},
        }),
    }
    deletion = _object("foxglove.SceneEntityDeletion", "Command to remove previously published entities", {
        "timestamp": _time("time", "Only matching entities earlier than this timestamp are deleted", signed=False),
        "type": {
            "title": "foxglove.SceneEntityDeletionType", "description": "Type of deletion action to perform",
            "oneOf": [
                {"title": "MATCHING_ID", "const": 0, "description": "Delete the entity on the same topic with this id"},
                {"title": "ALL", "const": 1, "description": "Delete all entities on the same topic"},
            ],
        },
        "id": {"type": "string", "description": "Identifier which must match if type is MATCHING_ID"},
    })
    key_value = _object("foxglove.KeyValuePair", "A key with its associated value", {
        "key": {"type": "string", "description": "Key"},
        "value": {"type": "string", "description": "Value"},
    })
    entity = _object(
        "foxglove.SceneEntity",
        "A visual element in a 3D scene; its primitives share one frame of reference",
        {
            "timestamp": _time("time", "Timestamp of the entity", signed=False),
            "frame_id": {"type": "string", "description": "Frame of reference"},
            "id": {"type": "string", "description": "Identifier; replaces any prior entity on the topic with this id"},
            "lifetime": _time("duration", "Time after timestamp the entity is removed; zero keeps it", signed=True),
            "frame_locked": {"type": "boolean", "description": "Follow frame_id as it moves (true) or stay in the fixed frame"},
            "metadata": _array(key_value, "Additional user-provided metadata; keys must be unique"),
            **{name: _array(item, f"{item['title'].split('.')[1]}s") for name, item in primitives.items()},
        },
    )
    schema = _object(SCENE_UPDATE, "An update to the entities displayed in a 3D scene", {
        "deletions": _array(deletion, "Scene entities to delete"),
        "entities": _array(entity, "Scene entities to add or replace"),
    })
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


SCENE_UPDATE_SCHEMA: dict = _scene_update_schema()
"""JSON Schema of foxglove.SceneUpdate (JSON encoding)."""


# --- building a scene ------------------------------------------------------------


def _r(value: float) -> float:
    return round(float(value), _PRECISION)


def _vec(x: float, y: float, z: float = 0.0) -> dict:
    return {"x": _r(x), "y": _r(y), "z": _r(z)}


def _yaw(theta: float) -> dict:
    """Quaternion of a rotation by theta (rad) about z."""
    return {"x": 0.0, "y": 0.0, "z": _r(math.sin(theta / 2)), "w": _r(math.cos(theta / 2))}


def _pose_at(x: float, y: float, z: float = 0.0, theta: float = 0.0) -> dict:
    return {"position": _vec(x, y, z), "orientation": _yaw(theta)}


def _rgba(kind: str) -> dict:
    r, g, b, a = COLORS[kind]
    return {"r": r, "g": g, "b": b, "a": a}


def _entity(entity_id: str, stamp: dict, metadata: Mapping[str, str] | None = None, **primitives: list) -> dict:
    return {
        "timestamp": stamp,
        "frame_id": FRAME_ID,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": k, "value": v} for k, v in (metadata or {}).items()],
        "arrows": primitives.get("arrows", []),
        "cubes": primitives.get("cubes", []),
        "spheres": primitives.get("spheres", []),
        "cylinders": primitives.get("cylinders", []),
        "lines": primitives.get("lines", []),
        "triangles": [],
        "texts": primitives.get("texts", []),
        "models": [],
    }


def _arrow(x: float, y: float, theta: float, length: float, kind: str, z: float = 0.0) -> dict:
    return {
        "pose": _pose_at(x, y, z, theta),
        "shaft_length": _r(0.65 * length),
        "shaft_diameter": _r(0.12 * length),
        "head_length": _r(0.35 * length),
        "head_diameter": _r(0.3 * length),
        "color": _rgba(kind),
    }


def scene_update(
    state: Mapping[str, np.ndarray],
    arena: tuple[float, float],
    time_ns: int,
    robot_radius: float,
    core_radius: float,
    status: str = "",
    previous_ids: Iterable[str] | None = None,
) -> dict:
    """The scene of one step as a foxglove.SceneUpdate JSON object.

    state: a `Simulator.state()` dict (m, rad); arena (W, H) in m; time_ns the
    message's log time (ns); robot_radius and core_radius in m; status a line of
    text shown above the arena. previous_ids: the entity ids of the scene before in
    the same episode, whose missing ones are deleted by id; None for the first scene
    of an episode, which deletes every entity on the topic first (type ALL).
    """
    stamp = {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}
    width, height = arena
    corners = [(0.0, 0.0), (width, 0.0), (width, height), (0.0, height)]
    entities = [
        _entity(
            "arena", stamp,
            lines=[{
                "type": 1, "pose": _pose_at(0.0, 0.0), "thickness": 0.4, "scale_invariant": False,
                "points": [_vec(x, y) for x, y in corners], "color": _rgba("arena"), "colors": [], "indices": [],
            }],
            texts=[{
                "pose": _pose_at(width / 2, height + 4.0), "billboard": True, "font_size": 14.0,
                "scale_invariant": True, "color": _rgba("text"), "text": status,
            }],
        )
    ]

    for i, ((x, y), theta, active) in enumerate(
        zip(state["pursuer_xy"].tolist(), state["pursuer_theta"].tolist(), state["pursuer_active"].tolist())
    ):
        kind = "pursuer" if active else "pursuer_collided"
        entities.append(_entity(
            f"pursuer/{i}", stamp, {"active": str(active).lower()},
            cubes=[{"pose": _pose_at(x, y, _HULL[2] / 2, theta), "size": _vec(*_HULL), "color": _rgba(kind)}],
            arrows=[_arrow(x, y, theta, 2.5, kind, z=_HULL[2])] if active else [],
        ))

    for j, ((x, y), active) in enumerate(zip(state["evader_xy"].tolist(), state["evader_active"].tolist())):
        kind = "evader" if active else "evader_encircled"
        entities.append(_entity(
            f"evader/{j}", stamp, {"encircled": str(not active).lower()},
            spheres=[{
                "pose": _pose_at(x, y, robot_radius), "size": _vec(*(3 * [2 * robot_radius])), "color": _rgba(kind),
            }],
        ))

    for k, ((x, y), radius) in enumerate(zip(state["obstacle_xy"].tolist(), state["obstacle_r"].tolist())):
        entities.append(_entity(
            f"obstacle/{k}", stamp,
            cylinders=[{
                "pose": _pose_at(x, y, 0.5), "size": _vec(2 * radius, 2 * radius, 1.0),
                "bottom_scale": 1.0, "top_scale": 1.0, "color": _rgba("obstacle"),
            }],
        ))

    for v, ((x, y), gamma, clockwise) in enumerate(
        zip(state["vortex_xy"].tolist(), state["vortex_gamma"].tolist(), state["vortex_clockwise"].tolist())
    ):
        kind = "vortex_clockwise" if clockwise else "vortex_counter"
        # An arrow tangent to a 2 m circle round the core, pointing the way the water turns.
        ring = 2.0
        tangent = -math.pi / 2 if clockwise else math.pi / 2
        entities.append(_entity(
            f"vortex/{v}", stamp,
            {"clockwise": str(bool(clockwise)).lower(), "circulation_m2_per_s": repr(float(gamma))},
            cylinders=[{
                "pose": _pose_at(x, y, 0.05), "size": _vec(2 * core_radius, 2 * core_radius, 0.1),
                "bottom_scale": 1.0, "top_scale": 1.0, "color": _rgba(kind),
            }],
            arrows=[_arrow(x + ring, y, tangent, 1.6, kind, z=0.1)],
        ))
    return {"deletions": _deletions(stamp, previous_ids, entities), "entities": entities}


DELETE_MATCHING_ID = 0
DELETE_ALL = 1
"""foxglove.SceneEntityDeletion types."""


def _deletions(stamp: dict, previous_ids: Iterable[str] | None, entities: list[dict]) -> list[dict]:
    """Deletions that go before `entities`: everything (type ALL) at an episode's first
    scene, else the ids of the previous scene that `entities` no longer holds. Foxglove
    applies a message's deletions before its entities, to entities stamped earlier."""
    if previous_ids is None:
        return [{"timestamp": stamp, "type": DELETE_ALL, "id": ""}]
    present = {entity["id"] for entity in entities}
    return [
        {"timestamp": stamp, "type": DELETE_MATCHING_ID, "id": entity_id}
        for entity_id in previous_ids if entity_id not in present
    ]


def entity_ids(update: Mapping) -> list[str]:
    """The ids of the entities a SceneUpdate JSON object adds or replaces."""
    return [entity["id"] for entity in update["entities"]]


# --- Foxglove's own definition ------------------------------------------------------

_PROTO_SCALARS = {
    "TYPE_DOUBLE": {"type": "number"}, "TYPE_FLOAT": {"type": "number"},
    "TYPE_INT32": {"type": "integer"}, "TYPE_INT64": {"type": "integer"},
    "TYPE_SINT32": {"type": "integer"}, "TYPE_SINT64": {"type": "integer"},
    "TYPE_SFIXED32": {"type": "integer"}, "TYPE_SFIXED64": {"type": "integer"},
    "TYPE_UINT32": {"type": "integer", "minimum": 0}, "TYPE_UINT64": {"type": "integer", "minimum": 0},
    "TYPE_FIXED32": {"type": "integer", "minimum": 0}, "TYPE_FIXED64": {"type": "integer", "minimum": 0},
    "TYPE_BOOL": {"type": "boolean"}, "TYPE_STRING": {"type": "string"},
    "TYPE_BYTES": {"type": "string", "contentEncoding": "base64"},
}


def official_scene_update_schema(strict: bool = True) -> dict:
    """JSON Schema of foxglove.SceneUpdate derived from Foxglove's published definition
    (`foxglove_schemas_protobuf`; raises ImportError without it), mapped to JSON the way
    Foxglove's JSON encoding does: times and durations as {sec, nsec}, enums as their
    numbers, bytes as base64 strings. strict: no property beyond the definition's."""
    from google.protobuf.descriptor import FieldDescriptor
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    type_names = {value: name for name, value in vars(FieldDescriptor).items() if name.startswith("TYPE_")}

    def time(signed: bool) -> dict:
        sec = {"type": "integer"} if signed else {"type": "integer", "minimum": 0}
        return {
            "type": "object", "required": ["sec", "nsec"], "additionalProperties": not strict,
            "properties": {"sec": sec, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
        }

    def message(descriptor) -> dict:
        if descriptor.full_name == "google.protobuf.Timestamp":
            return time(signed=False)
        if descriptor.full_name == "google.protobuf.Duration":
            return time(signed=True)
        properties = {}
        for field in descriptor.fields:
            if field.message_type is not None:
                item = message(field.message_type)
            elif field.enum_type is not None:
                item = {"enum": [value.number for value in field.enum_type.values]}
            else:
                item = dict(_PROTO_SCALARS[type_names[field.type]])
            repeated = field.is_repeated if hasattr(field, "is_repeated") else field.label == FieldDescriptor.LABEL_REPEATED
            properties[field.name] = {"type": "array", "items": item} if repeated else item
        return {
            "title": descriptor.full_name, "type": "object", "properties": properties,
            "additionalProperties": not strict,
        }

    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **message(SceneUpdate.DESCRIPTOR)}
