"""The world as a Foxglove `foxglove.SceneUpdate`, for the 3-D panel.

One message holds the whole scene of one step; entity ids are stable across the
steps of an episode, so each message replaces the previous one entity by entity:

- `arena`: the boundary [0, W] x [0, H] as a line loop, with a status text;
- `pursuer/<i>`: a 2.0 x 1.0 m hull (cube) turned to the heading, plus a heading
  arrow; collided pursuers stay where they crashed, greyed out; a pursuer whose action
  the shield overrode in the step is amber, with metadata `shield_overrode` true;
- `evader/<j>`: a sphere of the robot radius, red while free, green once encircled;
- `obstacle/<k>`: a cylinder of the obstacle's radius;
- `vortex/<v>`: a flat disc at the core (r0) and an arrow along its rotation,
  orange clockwise, blue counter-clockwise.

Units are the world's (m, rad); the scene lies in the z = 0 plane of frame `world`.

Foxglove keeps every entity it was sent until it is deleted, so each update deletes
what is gone: the first scene of an episode starts with a deletion of type ALL (the
previous episode may have had more robots, obstacles or vortices), and a later one
deletes by id any entity of the previous scene it no longer holds (`previous_ids`).

`scene_update` builds the scene as a JSON object of Foxglove's JSON encoding (what the
renderer and the tests read); logs store it as Foxglove's own protobuf message
(`scene_protobuf`, through the `foxglove-schemas-protobuf` package, whose schema the log
embeds), and `scene_from_protobuf` turns it back into the same JSON object. Logs of
version 1 hold the JSON object itself.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping

import numpy as np
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.descriptor import Descriptor
from google.protobuf.message import Message
from mcap_protobuf.schema import build_file_descriptor_set

SCENE_UPDATE = "foxglove.SceneUpdate"
"""Schema name Foxglove recognises for scene updates."""
FRAME_ID = "world"
"""Frame of every entity: the arena's, x east, y north, metres."""

_GRID = 4096
"""The scene's lengths and quaternions lie on a 1/4096 grid (0.24 mm; the exact state goes
to /state): binary fractions leave the low bits of protobuf's doubles zero, so a step's
zstd chunk holds /world in about 25 % less than unrounded doubles."""
_HULL = (2.0, 1.0, 0.6)
"""m: pursuer hull drawn as a box (length, width, height); the disc radius stays the world's."""

COLORS: dict[str, tuple[float, float, float, float]] = {
    "pursuer": (0.16, 0.42, 0.85, 1.0),
    "pursuer_collided": (0.55, 0.55, 0.55, 0.6),
    "pursuer_shielded": (0.96, 0.62, 0.04, 1.0),
    "evader": (0.86, 0.18, 0.18, 1.0),
    "evader_encircled": (0.15, 0.68, 0.30, 1.0),
    "obstacle": (0.35, 0.30, 0.26, 1.0),
    "vortex_clockwise": (0.93, 0.55, 0.10, 0.8),
    "vortex_counter": (0.10, 0.60, 0.85, 0.8),
    "arena": (0.2, 0.2, 0.2, 1.0),
    "text": (0.1, 0.1, 0.1, 1.0),
}
"""RGBA in [0, 1] of each kind of entity (also used by the renderer)."""


# --- building a scene ------------------------------------------------------------


def _r(value: float) -> float:
    return round(float(value) * _GRID) / _GRID


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
    shielded: Iterable[int] = (),
) -> dict:
    """The scene of one step as a foxglove.SceneUpdate JSON object.

    state: a `Simulator.state()` dict (m, rad); arena (W, H) in m; time_ns the
    message's log time (ns); robot_radius and core_radius in m; status a line of
    text shown above the arena. previous_ids: the entity ids of the scene before in
    the same episode, whose missing ones are deleted by id; None for the first scene
    of an episode, which deletes every entity on the topic first (type ALL). shielded: the
    pursuers whose action the shield overrode in the step.
    """
    overrode = set(shielded)
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
        kind = "pursuer_shielded" if i in overrode else "pursuer" if active else "pursuer_collided"
        metadata = {"active": str(active).lower(), **({"shield_overrode": "true"} if i in overrode else {})}
        entities.append(_entity(
            f"pursuer/{i}", stamp, metadata,
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


# --- Foxglove's protobuf messages ---------------------------------------------------

_TIMES = ("google.protobuf.Timestamp", "google.protobuf.Duration")
_SCALAR, _SCALARS, _TIME, _MESSAGE, _MESSAGES = range(5)
"""How a field maps to JSON: a value, a list of values, {sec, nsec}, an object, a list of objects."""


@functools.cache
def _kinds(descriptor: Descriptor) -> dict[str, int]:
    """field name -> how it maps to JSON, for a message type (looked up once per type)."""
    kinds = {}
    for field in descriptor.fields:
        # protobuf >= 5 has is_repeated; older releases only the label.
        repeated = field.is_repeated if hasattr(field, "is_repeated") else field.label == field.LABEL_REPEATED
        if field.message_type is None:
            kinds[field.name] = _SCALARS if repeated else _SCALAR
        elif field.message_type.full_name in _TIMES:
            kinds[field.name] = _TIME
        else:
            kinds[field.name] = _MESSAGES if repeated else _MESSAGE
    return kinds


def _fill(message: Message, value: Mapping) -> Message:
    """Set `message`'s fields from a JSON object of Foxglove's JSON encoding ({sec, nsec}
    times, enums as numbers); a key the message does not define is a ValueError."""
    kinds = _kinds(message.DESCRIPTOR)
    for name, item in value.items():
        kind = kinds.get(name)
        if kind is None:
            raise ValueError(f"{message.DESCRIPTOR.full_name} has no field {name!r}")
        if kind == _SCALAR:
            setattr(message, name, item)
        elif kind == _SCALARS:
            getattr(message, name).extend(item)
        elif kind == _TIME:
            time = getattr(message, name)
            time.seconds, time.nanos = item["sec"], item["nsec"]
        elif kind == _MESSAGES:
            field = getattr(message, name)
            for element in item:
                _fill(field.add(), element)
        else:
            _fill(getattr(message, name), item)
    return message


def _unfill(message: Message) -> dict:
    """Every field of `message` (defaults included) as a JSON object: `_fill`'s inverse."""
    out: dict = {}
    for name, kind in _kinds(message.DESCRIPTOR).items():
        item = getattr(message, name)
        if kind == _SCALAR:
            out[name] = item
        elif kind == _SCALARS:
            out[name] = list(item)
        elif kind == _TIME:
            out[name] = {"sec": item.seconds, "nsec": item.nanos}
        elif kind == _MESSAGES:
            out[name] = [_unfill(element) for element in item]
        else:
            out[name] = _unfill(item)
    return out


def scene_protobuf(update: Mapping) -> bytes:
    """A scene built by `scene_update` serialised as Foxglove's foxglove.SceneUpdate protobuf."""
    return _fill(SceneUpdate(), update).SerializeToString()


def scene_from_protobuf(data: bytes) -> dict:
    """A serialised foxglove.SceneUpdate as the JSON object `scene_update` builds."""
    return _unfill(SceneUpdate.FromString(data))


def scene_update_schema() -> bytes:
    """The schema of /world in a log: Foxglove's foxglove.SceneUpdate as a serialised
    FileDescriptorSet (MCAP's "protobuf" schema encoding), with every file it imports."""
    return build_file_descriptor_set(SceneUpdate).SerializeToString()
