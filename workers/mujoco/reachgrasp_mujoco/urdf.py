"""A small URDF reader: the subset the service's systems use (links with collision geometry and
optional inertials, revolute/continuous/prismatic/fixed joints with limits and `<mimic>`).

We read the XML ourselves instead of using MuJoCo's URDF importer because the importer fuses
fixed links (the fingertip frames we must keep as sites), knows nothing of `<mimic>`, and fails
on links without inertials with a compiler message; here every refusal names the joint or link
(the worker's hello is refused with it).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field


class UrdfError(ValueError):
    """The robot cannot be built; the message names the element."""


SUPPORTED_JOINTS = ("revolute", "continuous", "prismatic", "fixed")


@dataclass
class Geometry:
    kind: str  # box | cylinder | sphere | mesh
    size: tuple  # box: full edges; cylinder: (radius, length); sphere: (radius,); mesh: ()
    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)
    filename: str | None = None
    scale: tuple = (1.0, 1.0, 1.0)


@dataclass
class Inertial:
    mass: float
    xyz: tuple
    rpy: tuple
    inertia: tuple  # ixx ixy ixz iyy iyz izz


@dataclass
class Link:
    name: str
    collisions: list = field(default_factory=list)
    inertial: Inertial | None = None


@dataclass
class Mimic:
    joint: str
    multiplier: float
    offset: float


@dataclass
class Joint:
    name: str
    kind: str
    parent: str
    child: str
    xyz: tuple
    rpy: tuple
    axis: tuple
    lower: float
    upper: float
    velocity: float
    effort: float
    mimic: Mimic | None = None


@dataclass
class Robot:
    name: str
    links: dict
    joints: dict  # by name, in document order
    root: str

    def children(self, link: str):
        return [j for j in self.joints.values() if j.parent == link]

    def parent_joint(self, link: str):
        for j in self.joints.values():
            if j.child == link:
                return j
        return None

    def ancestors(self, joint: str):
        """Joint names from `joint`'s parent joint up to the root."""
        out = []
        j = self.joint_parent(joint)
        while j is not None:
            out.append(j.name)
            j = self.joint_parent(j.name)
        return out

    def joint_parent(self, joint: str):
        return self.parent_joint(self.joints[joint].parent)


def _floats(text: str | None, n: int, what: str, default=None) -> tuple:
    if text is None:
        if default is None:
            raise UrdfError(f"{what} is missing")
        return default
    parts = text.split()
    if len(parts) != n:
        raise UrdfError(f"{what} must have {n} numbers, got {text!r}")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise UrdfError(f"{what} is not numeric: {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise UrdfError(f"{what} is not finite: {text!r}")
    return vals


def _origin(el, what):
    o = el.find("origin")
    if o is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    return (
        _floats(o.get("xyz"), 3, f"{what} origin xyz", (0.0, 0.0, 0.0)),
        _floats(o.get("rpy"), 3, f"{what} origin rpy", (0.0, 0.0, 0.0)),
    )


def _number(el, attr, what, default=None):
    v = el.get(attr) if el is not None else None
    if v is None:
        if default is None:
            raise UrdfError(f"{what} has no {attr}")
        return default
    try:
        x = float(v)
    except ValueError:
        raise UrdfError(f"{what} {attr} is not a number: {v!r}") from None
    if not math.isfinite(x):
        raise UrdfError(f"{what} {attr} is not finite")
    return x


def _geometry(col, link_name) -> Geometry:
    what = f"link `{link_name}` collision"
    xyz, rpy = _origin(col, what)
    g = col.find("geometry")
    if g is None or len(g) == 0:
        raise UrdfError(f"{what} has no geometry")
    shape = g[0]
    if shape.tag == "box":
        size = _floats(shape.get("size"), 3, f"{what} box size")
        if min(size) <= 0:
            raise UrdfError(f"{what} box size must be positive")
        return Geometry("box", size, xyz, rpy)
    if shape.tag == "cylinder":
        r = _number(shape, "radius", f"{what} cylinder")
        length = _number(shape, "length", f"{what} cylinder")
        if r <= 0 or length <= 0:
            raise UrdfError(f"{what} cylinder radius and length must be positive")
        return Geometry("cylinder", (r, length), xyz, rpy)
    if shape.tag == "sphere":
        r = _number(shape, "radius", f"{what} sphere")
        if r <= 0:
            raise UrdfError(f"{what} sphere radius must be positive")
        return Geometry("sphere", (r,), xyz, rpy)
    if shape.tag == "mesh":
        fn = shape.get("filename")
        if not fn:
            raise UrdfError(f"{what} mesh has no filename")
        scale = _floats(shape.get("scale"), 3, f"{what} mesh scale", (1.0, 1.0, 1.0))
        return Geometry("mesh", (), xyz, rpy, filename=fn, scale=scale)
    raise UrdfError(f"{what}: unsupported geometry <{shape.tag}>")


def parse(text: str) -> Robot:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise UrdfError(f"URDF is not well-formed XML: {e}") from None
    if root.tag != "robot":
        raise UrdfError(f"URDF root element is <{root.tag}>, not <robot>")
    links = {}
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            raise UrdfError("a <link> has no name")
        if name in links:
            raise UrdfError(f"link `{name}` is defined twice")
        link = Link(name)
        for col in el.findall("collision"):
            link.collisions.append(_geometry(col, name))
        inert = el.find("inertial")
        if inert is not None:
            what = f"link `{name}` inertial"
            mass = _number(inert.find("mass"), "value", f"{what} mass")
            xyz, rpy = _origin(inert, what)
            i = inert.find("inertia")
            if i is None:
                raise UrdfError(f"{what} has no <inertia>")
            vals = tuple(
                _number(i, k, f"{what} inertia") for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
            )
            if mass < 0:
                raise UrdfError(f"{what} mass must not be negative")
            # A zero-mass inertial (what urdf-rs writes for a link without one, as the
            # service's combined URDF does) means "none": the inertia comes from the geoms.
            if mass > 0:
                link.inertial = Inertial(mass, xyz, rpy, vals)
        links[name] = link
    joints = {}
    for el in root.findall("joint"):
        name = el.get("name")
        kind = el.get("type")
        if not name:
            raise UrdfError("a <joint> has no name")
        if kind not in SUPPORTED_JOINTS:
            raise UrdfError(
                f"joint `{name}`: type `{kind}` is not supported (supported: {', '.join(SUPPORTED_JOINTS)})"
            )
        parent = el.find("parent")
        child = el.find("child")
        if parent is None or child is None:
            raise UrdfError(f"joint `{name}` needs <parent> and <child>")
        p, c = parent.get("link"), child.get("link")
        for ln in (p, c):
            if ln not in links:
                raise UrdfError(f"joint `{name}` refers to unknown link `{ln}`")
        xyz, rpy = _origin(el, f"joint `{name}`")
        axis = (1.0, 0.0, 0.0)
        ax = el.find("axis")
        if ax is not None:
            axis = _floats(ax.get("xyz"), 3, f"joint `{name}` axis", (1.0, 0.0, 0.0))
        n = math.sqrt(sum(a * a for a in axis))
        if kind != "fixed" and n < 1e-9:
            raise UrdfError(f"joint `{name}` has a zero axis")
        if n > 0:
            axis = tuple(a / n for a in axis)
        lim = el.find("limit")
        lower, upper = -math.inf, math.inf
        velocity, effort = 0.0, 0.0
        if kind in ("revolute", "prismatic"):
            if lim is None:
                raise UrdfError(f"joint `{name}` ({kind}) has no <limit>")
            lower = _number(lim, "lower", f"joint `{name}` limit", 0.0)
            upper = _number(lim, "upper", f"joint `{name}` limit", 0.0)
            if lower > upper:
                raise UrdfError(f"joint `{name}` limit lower {lower} > upper {upper}")
        if lim is not None:
            velocity = _number(lim, "velocity", f"joint `{name}` limit", 0.0)
            effort = _number(lim, "effort", f"joint `{name}` limit", 0.0)
        mimic = None
        mi = el.find("mimic")
        if mi is not None:
            leader = mi.get("joint")
            if not leader:
                raise UrdfError(f"joint `{name}` mimic has no joint")
            mimic = Mimic(
                leader,
                _number(mi, "multiplier", f"joint `{name}` mimic", 1.0),
                _number(mi, "offset", f"joint `{name}` mimic", 0.0),
            )
        if name in joints:
            raise UrdfError(f"joint `{name}` is defined twice")
        joints[name] = Joint(name, kind, p, c, xyz, rpy, axis, lower, upper, velocity, effort, mimic)
    for j in joints.values():
        if j.mimic is not None:
            leader = joints.get(j.mimic.joint)
            if leader is None:
                raise UrdfError(f"joint `{j.name}` mimics unknown joint `{j.mimic.joint}`")
            if leader.kind == "fixed" or leader.mimic is not None:
                raise UrdfError(
                    f"joint `{j.name}` mimics `{leader.name}`, which is fixed or itself a mimic (unsupported)"
                )
    children = {j.child for j in joints.values()}
    roots = [n for n in links if n not in children]
    if len(roots) != 1:
        raise UrdfError(f"the URDF must have exactly one root link, found {roots}")
    seen = set()
    for j in joints.values():
        if j.child in seen:
            raise UrdfError(f"link `{j.child}` has two parent joints")
        seen.add(j.child)
    return Robot(root.get("name") or "robot", links, joints, roots[0])
