"""The scene an execution runs in: the object (shape, pose, mass, friction), the support plane
and obstacles, all in the robot base frame, in the service's JSON form (`ObjectSpec` of
`POST /v1/grasps`, plus `mass` in kg and `friction`, the Coulomb coefficient against the hand).

Validation refuses, naming the field, anything the simulation cannot honour: a scene without a
mass or friction for the object is refused rather than guessed, unless the worker was started
with `--object-defaults`, which fills them for the service's seeded objects only (see
`SEEDED_PROPERTIES`) and says so in the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


class SceneError(ValueError):
    """A scene the worker cannot simulate; the message names the field."""


# Mass (kg) and friction against a rubber-padded finger for the service's seeded objects, which
# the service does not (yet) store: common items of the stated size. Ball: a tennis ball (57 g,
# felt); bottle: a full 0.5 l PET bottle (0.52 kg); kitchen timer: a plastic timer (0.1 kg);
# pencil: a wooden pencil (6 g); sunglasses: folded, plastic frame (30 g). Friction 0.8 felt /
# rubber, 0.6 for smooth plastic and painted wood against rubber pads (handbook ranges 0.5-1.0).
SEEDED_PROPERTIES = {
    "ball": {"mass": 0.057, "friction": 0.8},
    "bottle": {"mass": 0.52, "friction": 0.6},
    "kitchen_timer": {"mass": 0.10, "friction": 0.6},
    "pencil": {"mass": 0.006, "friction": 0.6},
    "sunglasses": {"mass": 0.030, "friction": 0.6},
}
# Table (laminate) against objects and links.
DEFAULT_SUPPORT_FRICTION = 0.5

SHAPES = ("sphere", "cylinder", "box", "capsule", "mesh")


@dataclass
class Body:
    name: str
    shape: dict
    position: tuple
    orientation: tuple  # w x y z, normalised


@dataclass
class SceneObject(Body):
    mass: float = 0.0
    friction: float = 0.0


@dataclass
class Support:
    normal: tuple
    offset: float
    friction: float


@dataclass
class Scene:
    object: SceneObject | None
    support: Support | None
    obstacles: list = field(default_factory=list)
    # Where mass/friction came from (`scene`, `object-defaults`), reported in the result.
    provenance: str = "scene"
    # The grasp's fingers kept off the object, when the scene comes from a stored plan (the
    # `execute` message of a verified plan carries them itself): the trial does not close them.
    idle_fingers: tuple = ()


def _vec(v, n, path):
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise SceneError(f"{path} must be an array of {n} numbers")
    out = []
    for i, x in enumerate(v):
        if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x):
            raise SceneError(f"{path}[{i}] must be a finite number")
        out.append(float(x))
    return tuple(out)


def _positive(d, key, path):
    v = d.get(key)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v <= 0:
        raise SceneError(f"{path}.{key} must be a positive number")
    return float(v)


def _shape(s, path):
    if not isinstance(s, dict):
        raise SceneError(f"{path} must be an object")
    t = s.get("type")
    if t not in SHAPES:
        raise SceneError(f"{path}.type must be one of {', '.join(SHAPES)}")
    if t == "sphere":
        return {"type": t, "radius": _positive(s, "radius", path)}
    if t == "cylinder":
        return {"type": t, "radius": _positive(s, "radius", path), "height": _positive(s, "height", path)}
    if t == "capsule":
        return {"type": t, "radius": _positive(s, "radius", path), "length": _positive(s, "length", path)}
    if t == "box":
        size = _vec(s.get("size"), 3, f"{path}.size")
        if min(size) <= 0:
            raise SceneError(f"{path}.size must be positive")
        return {"type": t, "size": size}
    verts = s.get("vertices")
    tris = s.get("triangles")
    if not isinstance(verts, list) or len(verts) < 4:
        raise SceneError(f"{path}.vertices must hold at least 4 vertices")
    if not isinstance(tris, list) or len(tris) < 4:
        raise SceneError(f"{path}.triangles must hold at least 4 triangles")
    vs = [_vec(v, 3, f"{path}.vertices[{i}]") for i, v in enumerate(verts)]
    ts = []
    for i, t3 in enumerate(tris):
        if (
            not isinstance(t3, list)
            or len(t3) != 3
            or not all(isinstance(k, int) and 0 <= k < len(vs) for k in t3)
        ):
            raise SceneError(f"{path}.triangles[{i}] must be 3 vertex indices")
        ts.append(tuple(t3))
    return {"type": "mesh", "vertices": vs, "triangles": ts}


def _body(d, path, cls=Body, **extra):
    if not isinstance(d, dict):
        raise SceneError(f"{path} must be an object")
    name = d.get("name") or "object"
    shape = _shape(d.get("shape"), f"{path}.shape")
    pos = _vec(d.get("position"), 3, f"{path}.position")
    q = _vec(d.get("orientation", [1, 0, 0, 0]), 4, f"{path}.orientation")
    n = math.sqrt(sum(x * x for x in q))
    if n < 1e-9:
        raise SceneError(f"{path}.orientation must be a non-zero quaternion")
    return cls(str(name), shape, pos, tuple(x / n for x in q), **extra)


def parse_scene(d, object_defaults: bool = False) -> Scene:
    """A scene from its JSON form (`{"object", "support", "obstacles"}`)."""
    if not isinstance(d, dict):
        raise SceneError("scene must be an object")
    obj = d.get("object")
    provenance = "scene"
    scene_object = None
    if obj is not None:
        if not isinstance(obj, dict):
            raise SceneError("scene.object must be an object")
        obj = dict(obj)
        missing = [k for k in ("mass", "friction") if obj.get(k) is None]
        if missing and object_defaults and obj.get("name") in SEEDED_PROPERTIES:
            for k in missing:
                obj[k] = SEEDED_PROPERTIES[obj["name"]][k]
            provenance = "object-defaults"
        for k in ("mass", "friction"):
            if obj.get(k) is None:
                raise SceneError(
                    f"scene.object.{k} is missing: the object `{obj.get('name')}` has no {k}, "
                    "so it cannot be simulated"
                )
        mass = _positive(obj, "mass", "scene.object")
        friction = _positive(obj, "friction", "scene.object")
        scene_object = _body(obj, "scene.object", SceneObject, mass=mass, friction=friction)
    support = None
    sp = d.get("support", obj.get("support") if isinstance(obj, dict) else None)
    if sp is not None:
        if not isinstance(sp, dict):
            raise SceneError("scene.support must be an object")
        nrm = _vec(sp.get("normal"), 3, "scene.support.normal")
        nn = math.sqrt(sum(x * x for x in nrm))
        if nn < 1e-9:
            raise SceneError("scene.support.normal must be non-zero")
        off = sp.get("offset")
        if not isinstance(off, (int, float)) or not math.isfinite(off):
            raise SceneError("scene.support.offset must be a finite number")
        fr = sp.get("friction", DEFAULT_SUPPORT_FRICTION)
        if not isinstance(fr, (int, float)) or not math.isfinite(fr) or fr <= 0:
            raise SceneError("scene.support.friction must be a positive number")
        support = Support(tuple(x / nn for x in nrm), float(off) / nn, float(fr))
    obstacles = []
    obs = d.get("obstacles") or []
    if not isinstance(obs, list):
        raise SceneError("scene.obstacles must be an array")
    for i, o in enumerate(obs):
        obstacles.append(_body(o, f"scene.obstacles[{i}]"))
    return Scene(scene_object, support, obstacles, provenance)


def scene_from_object_spec(spec: dict, object_defaults: bool) -> Scene:
    """Today's service stores an `ObjectSpec` (shape, pose, support) with every grasp; it has
    no mass or friction, which `object_defaults` may fill for seeded objects."""
    return parse_scene({"object": spec, "support": spec.get("support")}, object_defaults)
