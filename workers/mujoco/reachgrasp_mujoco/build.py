"""The MuJoCo model of an arm-hand system and its scene, built with `mujoco.MjSpec`.

Robot (from the service's combined URDF):
- one body per URDF link (fixed links kept, so fingertip frames are bodies), one hinge or slide
  per movable joint with the URDF limits (hard stops); collision shapes as geoms; inertia from
  `<inertial>` where given, else from the collision geoms at `LINK_DENSITY` (the bundled URDFs
  carry none).
- Every robot body is gravity-compensated (`gravcomp = 1`), as the arm's controller does on the
  real robot; the object's weight still loads the arm through the contacts.
- Arm and hand joints not driven by a tendon are position servos (PD, force limited by the URDF
  `effort`, gains from the joint's largest inertia over sampled postures, as a real arm's servo
  is tuned for its worst case: every joint has at least the same bandwidth in every posture).
- Underactuated fingers: a `<mimic>` joint whose leader is one of its ancestors (a distal phalanx
  following the proximal) is driven by a fixed tendon through both joints with joint springs
  that give exactly the mimic ratio in free motion (`k_follower = k_leader / multiplier`), so
  when a phalanx is stopped by the object the others keep closing under the tendon force, as a
  tendon-driven compliant hand does; the tendon servo is force limited by the leader's `effort`.
  Any other mimic (e.g. the iHY's geared spread pair) is a rigid joint equality constraint.
- Robot geoms collide with the object, the support and the obstacles, not with each other (the
  planner checks self-collision; here it would only add unmodelled stiffness).

Scene: the support plane is a MuJoCo plane (a half-space, solid below) with its own friction;
the object is a free body (mass from the scene, inertia of a uniform solid; meshes collide as
their convex hull, MuJoCo's rule); obstacles are static geoms. Object contacts use the object's
friction (geom priority), elliptic cones, torsional friction (`condim 4`, soft-finger contacts).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import mujoco
import numpy as np

from . import urdf as U
from .scene import Scene

TIMESTEP = 0.002
LINK_DENSITY = 1000.0  # kg/m^3, where a URDF link has no <inertial>
ARM_BANDWIDTH = 40.0  # rad/s, natural frequency of the arm joint servos
GAIN_POSTURES = 64  # sampled postures whose largest inertia sets the servo gains
HAND_BANDWIDTH = 60.0  # rad/s
ARM_ARMATURE = 0.05  # kg m^2, reflected rotor inertia of a geared arm joint
HAND_ARMATURE = 2e-4
FINGER_DAMPING = 0.005  # N m s/rad, flexure damping
# Leader flexure stiffness: its spring torque at the joint's upper limit is this share of the
# tendon's force limit, so closing spends most of the effort on the object.
SPRING_SHARE = 0.15
TENDON_STIFFNESS = 20.0  # N m per rad of tendon error (saturates at the effort limit)
ROBOT_FRICTION = 1.0
# Object contacts stiffer than MuJoCo's default (time constant 0.02 s) so that the fingers'
# forces (tens of N) leave millimetres, not a centimetre, of overlap; 2 x the timestep is the
# stiffest the solver resolves. (Priority geoms' contact parameters decide the contact.)
CONTACT_SOLREF = (2 * TIMESTEP, 1.0)
# Joint limits as hard stops: MuJoCo's default (0.02 s) let the T42's proximal joints pass their
# 0 rad stop by 0.11-0.16 rad under the tendon's load, bending the fingers backwards until a
# shake flung the bottle out of them.
LIMIT_SOLREF = (2 * TIMESTEP, 1.0)
CONTACT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)  # robot geoms never decide a friction (object/support have priority)


class BuildError(ValueError):
    """The robot cannot be built in MuJoCo; names the link or joint."""


@dataclass
class SystemInfo:
    """What the worker needs of `GET /v1/robots/{id}`."""

    robot: str
    joint_names: list  # independent joints, model order
    arm_joints: list
    hand_joints: list
    fingers: list  # [{"name", "joints", "tip_frame"}]
    spread_pairs: list = field(default_factory=list)

    @staticmethod
    def from_detail(d: dict) -> "SystemInfo":
        return SystemInfo(
            d["id"],
            list(d["joint_names"]),
            list(d["arm_joints"]),
            list(d["hand_joints"]),
            [
                {"name": f["name"], "joints": list(f["joints"]), "tip_frame": f["tip_frame"]}
                for f in d["fingers"]
            ],
            [list(p) for p in d.get("spread_pairs", [])],
        )


@dataclass
class Drive:
    """How one independent joint is driven."""

    name: str
    joint_id: int  # MuJoCo joint of the independent coordinate
    actuator_id: int
    # ctrl = gain * q_target + ... (tendon: gain = sum of ratios + k_leader / kp)
    ctrl_gain: float
    tendon_id: int = -1
    followers: list = field(default_factory=list)  # [(joint_id, multiplier)]
    lower: float = -math.inf
    upper: float = math.inf
    velocity: float = 0.0
    effort: float = 0.0
    arm: bool = False


@dataclass
class Built:
    model: mujoco.MjModel
    spec: mujoco.MjSpec
    info: SystemInfo
    drives: list  # Drive per independent joint, joint_names order
    robot_geoms: np.ndarray  # geom ids of the robot
    hand_geoms: np.ndarray  # geom ids of the hand (bodies below the wrist)
    hand_body: int  # the hand's root body (the mount child)
    object_body: int = -1
    object_geom: int = -1
    support_geom: int = -1
    obstacle_geoms: list = field(default_factory=list)
    object_joint_qpos: int = -1
    notes: list = field(default_factory=list)


def rpy_quat(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r)) as a MuJoCo quaternion w x y z."""
    r, p, y = rpy
    cr, sr = math.cos(r / 2), math.sin(r / 2)
    cp, sp = math.cos(p / 2), math.sin(p / 2)
    cy, sy = math.cos(y / 2), math.sin(y / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def _z_to(normal) -> np.ndarray:
    """Quaternion rotating +z onto `normal`."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ n)
    if c > 1 - 1e-12:
        return np.array([1.0, 0, 0, 0])
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0, 0])
    ax = np.cross(z, n)
    ax /= np.linalg.norm(ax)
    a = math.acos(c)
    return np.concatenate([[math.cos(a / 2)], math.sin(a / 2) * ax])


def _add_shape(spec, parent, shape: dict, name: str, pos, quat):
    g = parent.add_geom(name=name, pos=list(pos), quat=list(quat))
    t = shape["type"]
    if t == "sphere":
        g.type = mujoco.mjtGeom.mjGEOM_SPHERE
        g.size = [shape["radius"], 0, 0]
    elif t == "cylinder":
        g.type = mujoco.mjtGeom.mjGEOM_CYLINDER
        g.size = [shape["radius"], 0.5 * shape["height"], 0]
    elif t == "capsule":
        g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        g.size = [shape["radius"], 0.5 * shape["length"], 0]
    elif t == "box":
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = [0.5 * s for s in shape["size"]]
    else:
        mesh = spec.add_mesh(name=f"{name}_mesh")
        mesh.uservert = np.asarray(shape["vertices"], float).ravel().tolist()
        mesh.userface = np.asarray(shape["triangles"], int).ravel().tolist()
        g.type = mujoco.mjtGeom.mjGEOM_MESH
        g.meshname = f"{name}_mesh"
    return g


def binary_stl(data: bytes, link: str, filename: str) -> bytes:
    """`data` as a binary STL: MuJoCo reads only binary STL, while URDF meshes (and the
    service's uploads) are often ASCII; an ASCII file is rewritten facet by facet."""
    head = data[:512].lstrip().lower()
    if not head.startswith(b"solid") or b"facet" not in head:
        return data  # binary (its 80-byte header may itself begin with "solid" but has no facets)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        return data
    vs = [tuple(float(x) for x in ln.split()[1:4]) for ln in text.splitlines() if ln.strip().startswith("vertex")]
    if not vs or len(vs) % 3:
        raise BuildError(f"link `{link}`: collision mesh `{filename}` is an ASCII STL whose vertices are not whole facets")
    out = bytearray(b"reachgrasp: from an ASCII STL".ljust(80, b" "))
    out += struct.pack("<I", len(vs) // 3)
    for k in range(0, len(vs), 3):
        out += struct.pack("<12fH", 0.0, 0.0, 0.0, *vs[k], *vs[k + 1], *vs[k + 2], 0)
    return bytes(out)


def build(
    urdf_text: str,
    info: SystemInfo,
    scene: Scene | None,
    mesh_source=None,
) -> Built:
    """The model of `info`'s system in `scene`. `mesh_source(filename) -> bytes | None` gives
    collision meshes (STL/OBJ); a mesh it cannot give is a BuildError naming the link."""
    try:
        robot = U.parse(urdf_text)
    except U.UrdfError as e:
        raise BuildError(str(e)) from None
    for n in info.joint_names:
        j = robot.joints.get(n)
        if j is None:
            raise BuildError(f"joint `{n}` of the robot's joint list is not in its URDF")
        if j.kind == "fixed" or j.mimic is not None:
            raise BuildError(f"joint `{n}` is listed as independent but is fixed or a mimic")
    movable = [j for j in robot.joints.values() if j.kind != "fixed"]
    listed = set(info.joint_names)
    for j in movable:
        if j.mimic is None and j.name not in listed:
            raise BuildError(f"joint `{j.name}` is movable, not a mimic, and not among the robot's joints")
    for f in info.fingers:
        if f["tip_frame"] not in robot.links:
            raise BuildError(f"finger `{f['name']}`: tip frame `{f['tip_frame']}` is not a URDF link")

    spec = mujoco.MjSpec()
    spec.modelname = info.robot
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.compiler.boundmass = 1e-4
    spec.compiler.boundinertia = 1e-8
    spec.compiler.autolimits = True
    spec.compiler.degree = False  # URDF angles are radians

    # Links at or below the wrist (the hand): the mount joint's child subtree.
    mount = robot.joints.get("hand_mount_joint")
    arm_set = set(info.arm_joints)
    hand_root = mount.child if mount is not None else None
    if hand_root is None:
        # A combined URDF without our mount joint: the hand starts below the last arm joint.
        last = [robot.joints[n] for n in info.arm_joints if n in robot.joints]
        if not last:
            raise BuildError("cannot tell the arm from the hand: no arm joints")
        hand_root = last[-1].child
    mesh_files = {}
    bodies = {}
    geom_names_hand = []
    geom_names_robot = []

    def in_hand(link):
        while True:
            if link == hand_root:
                return True
            pj = robot.parent_joint(link)
            if pj is None:
                return False
            link = pj.parent

    def add_link(parent_body, link_name, pos, quat):
        link = robot.links[link_name]
        b = parent_body.add_body(name=link_name, pos=list(pos), quat=list(quat))
        b.gravcomp = 1.0
        if link.inertial is not None:
            ii = link.inertial
            b.explicitinertial = True
            b.mass = ii.mass
            b.ipos = list(ii.xyz)
            b.iquat = list(rpy_quat(ii.rpy))
            ixx, ixy, ixz, iyy, iyz, izz = ii.inertia
            b.fullinertia = [ixx, iyy, izz, ixy, ixz, iyz]
        hand = in_hand(link_name)
        for k, g in enumerate(link.collisions):
            gname = f"{link_name}#{k}"
            if g.kind == "mesh":
                data = mesh_source(g.filename) if mesh_source else None
                if data is None:
                    raise BuildError(
                        f"link `{link_name}`: collision mesh `{g.filename}` is not available to the worker"
                    )
                mname = f"m{len(mesh_files)}"
                ext = ".obj" if g.filename.lower().endswith(".obj") else ".stl"
                mesh_files[mname + ext] = binary_stl(data, link_name, g.filename) if ext == ".stl" else data
                m = spec.add_mesh(name=mname, file=mname + ext)
                m.scale = list(g.scale)
                geom = b.add_geom(name=gname, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mname)
            elif g.kind == "box":
                geom = b.add_geom(name=gname, type=mujoco.mjtGeom.mjGEOM_BOX, size=[s / 2 for s in g.size])
            elif g.kind == "cylinder":
                geom = b.add_geom(
                    name=gname, type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[g.size[0], g.size[1] / 2, 0]
                )
            else:
                geom = b.add_geom(name=gname, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[g.size[0], 0, 0])
            geom.pos = list(g.xyz)
            geom.quat = list(rpy_quat(g.rpy))
            geom.density = LINK_DENSITY
            geom.contype = 1
            geom.conaffinity = 0
            geom.friction = [ROBOT_FRICTION, 0.005, 0.0001]
            geom.rgba = [0.3, 0.5, 0.8, 1] if hand else [0.6, 0.6, 0.6, 1]
            (geom_names_hand if hand else geom_names_robot).append(gname)
        bodies[link_name] = b
        for j in robot.children(link_name):
            cb = add_link(b, j.child, j.xyz, rpy_quat(j.rpy))
            if j.kind != "fixed":
                jt = cb.add_joint(name=j.name, axis=list(j.axis))
                jt.type = mujoco.mjtJoint.mjJNT_SLIDE if j.kind == "prismatic" else mujoco.mjtJoint.mjJNT_HINGE
                if j.kind != "continuous":
                    jt.range = [j.lower, j.upper]
                    jt.limited = mujoco.mjtLimited.mjLIMITED_TRUE
                    jt.solref_limit = list(LIMIT_SOLREF)
                hand_joint = in_hand(j.child)
                jt.armature = HAND_ARMATURE if hand_joint else ARM_ARMATURE
                if hand_joint:
                    jt.damping = [FINGER_DAMPING, 0, 0]
        return b

    add_link(spec.worldbody, robot.root, (0, 0, 0), (1, 0, 0, 0))

    # Couplings.
    notes = []
    tendon_of = {}  # leader -> [(follower, multiplier)]
    for j in robot.joints.values():
        if j.mimic is None:
            continue
        leader = j.mimic.joint
        in_chain = leader in robot.ancestors(j.name)
        if in_chain and j.mimic.multiplier > 0 and abs(j.mimic.offset) < 1e-12:
            tendon_of.setdefault(leader, []).append((j.name, j.mimic.multiplier))
        else:
            eq = spec.add_equality(name=f"mimic_{j.name}")
            eq.type = mujoco.mjtEq.mjEQ_JOINT
            eq.name1 = j.name
            eq.name2 = leader
            eq.data[0:5] = [j.mimic.offset, j.mimic.multiplier, 0, 0, 0]
            eq.solref = [0.005, 1.0]
            notes.append(f"{j.name} = {j.mimic.multiplier} x {leader} (rigid equality)")

    drives_spec = []
    for n in info.joint_names:
        j = robot.joints[n]
        hand = n not in arm_set
        if n in tendon_of:
            foll = tendon_of[n]
            upper = j.upper if math.isfinite(j.upper) else math.pi / 2
            effort = j.effort if j.effort > 0 else 1.0
            k_lead = SPRING_SHARE * effort / max(upper, 1e-3)
            jl = spec.joint(n)
            jl.stiffness = [k_lead, 0, 0]
            jl.springref = 0.0
            ten = spec.add_tendon(name=f"tendon_{n}")
            ten.wrap_joint(n, 1.0)
            for fname, mult in foll:
                spec.joint(fname).stiffness = [k_lead / mult, 0, 0]
                spec.joint(fname).springref = 0.0
                ten.wrap_joint(fname, 1.0)
            act = spec.add_actuator(name=f"act_{n}", target=f"tendon_{n}")
            act.trntype = mujoco.mjtTrn.mjTRN_TENDON
            act.set_to_position(kp=TENDON_STIFFNESS, kv=0.02)
            act.forcerange = [-effort, effort]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            ratio = 1.0 + sum(m for _, m in foll)
            drives_spec.append((n, f"act_{n}", ratio + k_lead / TENDON_STIFFNESS, f"tendon_{n}", foll, j, hand))
            notes.append(
                f"{n}: tendon-driven finger, followers "
                + ", ".join(f"{f} (ratio {m})" for f, m in foll)
                + f", leader spring {k_lead:.3f} N m/rad, force limit {effort} N m"
            )
        else:
            act = spec.add_actuator(name=f"act_{n}", target=n)
            act.trntype = mujoco.mjtTrn.mjTRN_JOINT
            act.set_to_position(kp=1.0, kv=0.0)  # gains set from the inertia after compiling
            if j.effort > 0:
                act.forcerange = [-j.effort, j.effort]
                act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            drives_spec.append((n, f"act_{n}", 1.0, None, [], j, hand))

    built = Built(None, spec, info, [], np.zeros(0, int), np.zeros(0, int), -1, notes=notes)
    # Scene.
    if scene is not None:
        if scene.support is not None:
            s = scene.support
            g = spec.worldbody.add_geom(
                name="support",
                type=mujoco.mjtGeom.mjGEOM_PLANE,
                size=[0, 0, 1],
                pos=list(np.asarray(s.normal) * s.offset),
                quat=list(_z_to(s.normal)),
            )
            g.friction = [s.friction, 0.005, 0.0001]
            g.priority = 2
            g.solref = list(CONTACT_SOLREF)
            g.solimp = list(CONTACT_SOLIMP)
            g.contype = 1
            g.conaffinity = 1
            g.rgba = [0.8, 0.75, 0.6, 1]
        for i, ob in enumerate(scene.obstacles):
            g = _add_shape(spec, spec.worldbody, ob.shape, f"obstacle{i}", ob.position, ob.orientation)
            g.contype = 1
            g.conaffinity = 1
            g.friction = [0.5, 0.005, 0.0001]
            g.rgba = [0.7, 0.3, 0.3, 1]
        if scene.object is not None:
            o = scene.object
            ob = spec.worldbody.add_body(name="object", pos=list(o.position), quat=list(o.orientation))
            ob.add_freejoint(name="object_free")
            g = _add_shape(spec, ob, o.shape, "object_geom", (0, 0, 0), (1, 0, 0, 0))
            g.mass = o.mass
            g.friction = [o.friction, 0.005, 0.0001]
            g.condim = 4
            g.priority = 1
            g.solref = list(CONTACT_SOLREF)
            g.solimp = list(CONTACT_SOLIMP)
            g.contype = 1
            g.conaffinity = 1
            g.rgba = [0.9, 0.6, 0.1, 1]
    if mesh_files:
        spec.assets = mesh_files
    try:
        m = spec.compile()
    except Exception as e:  # MuJoCo's compiler error names the element
        raise BuildError(f"MuJoCo could not compile the robot: {e}") from None

    # Servo gains from each joint's largest diagonal inertia over the zero posture and
    # `GAIN_POSTURES` postures drawn (seeded) within the limits: a position servo per joint with
    # at least `ARM_BANDWIDTH` / `HAND_BANDWIDTH` everywhere, critically damped where the inertia
    # is largest and overdamped elsewhere (the damping is integrated implicitly). Gains from the
    # zero posture alone left the PA10's first and third joints 10x too soft where the elbow is
    # bent: the arm lagged its trajectory, took another path into the object and stopped
    # 0.015-0.03 rad short against it (5 of 10 pa10_ihy plans in the survey).
    d = mujoco.MjData(m)
    M = np.zeros((m.nv, m.nv))
    diag = np.zeros(m.nv)
    rng = np.random.default_rng(0)
    for k in range(GAIN_POSTURES + 1):
        d.qpos[:] = m.qpos0
        if k > 0:
            for jid in range(m.njnt):
                if int(m.jnt_type[jid]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                    lo, hi = m.jnt_range[jid] if m.jnt_limited[jid] else (-math.pi, math.pi)
                    d.qpos[m.jnt_qposadr[jid]] = rng.uniform(lo, hi)
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        diag = np.maximum(diag, np.diag(M))
    drives = []
    for n, aname, gain, tname, foll, j, hand in drives_spec:
        aid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, aname)
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)
        if tname is None:
            dof = m.jnt_dofadr[jid]
            inertia = diag[dof]
            w = HAND_BANDWIDTH if hand else ARM_BANDWIDTH
            kp = inertia * w * w
            kv = 2.0 * inertia * w
            m.actuator_gainprm[aid, 0] = kp
            m.actuator_biasprm[aid, 1] = -kp
            m.actuator_biasprm[aid, 2] = -kv
        tid = -1 if tname is None else mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, tname)
        drives.append(
            Drive(
                n,
                jid,
                aid,
                gain,
                tid,
                [(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f), mult) for f, mult in foll],
                j.lower,
                j.upper,
                j.velocity,
                j.effort,
                not hand,
            )
        )
    built.model = m
    built.drives = drives
    gid = lambda nm: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, nm)
    built.hand_geoms = np.array([gid(n) for n in geom_names_hand], int)
    built.robot_geoms = np.array([gid(n) for n in geom_names_robot + geom_names_hand], int)
    built.hand_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, hand_root)
    if scene is not None and scene.object is not None:
        built.object_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        built.object_geom = gid("object_geom")
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "object_free")
        built.object_joint_qpos = m.jnt_qposadr[jid]
    if scene is not None and scene.support is not None:
        built.support_geom = gid("support")
    built.obstacle_geoms = [gid(f"obstacle{i}") for i in range(len(scene.obstacles))] if scene else []
    return built
