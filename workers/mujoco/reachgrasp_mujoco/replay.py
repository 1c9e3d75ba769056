"""A second, independent clearance check of a trajectory the service returned: its points (and
three linear sub-steps between neighbours) set kinematically on the MuJoCo model of the robot and
its scene, and MuJoCo's own collision detection (its primitive pair functions and convex
collider, not the service's parry queries, EPA or FK) reports every overlap. The issue's claim it
measures: no link more than 1 mm inside the object before the closing phase, the support, an
obstacle or another link, anywhere along the motion.

The rules follow the service's stated contract, applied independently:
- the object: every robot geom before `closing_from_s` (the trajectory's `report.clearance`);
  from then on the geoms of each finger's tip link (its pad) may press into it, the rest may not;
- the support: every robot geom a joint moves (the base stands on it), all along;
- obstacles: every robot geom, all along;
- the robot itself: every pair of geoms on bodies that are not parent and child (MuJoCo's own
  filter), except pairs already overlapping at the zero posture (clipped into the limits): parts
  the robot's design keeps in contact, as a MoveIt allowed-collision matrix samples them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from . import build as B
from .scene import parse_scene
from .sim import Sim

SUB_STEPS = 4


@dataclass
class Overlap:
    depth_m: float = 0.0
    a: str | None = None
    b: str | None = None
    t_s: float | None = None

    def take(self, depth, a, b, t):
        if depth > self.depth_m:
            self.depth_m, self.a, self.b, self.t_s = float(depth), a, b, float(t)

    def json(self):
        return {"depth_m": round(self.depth_m, 6), "pair": [self.a, self.b] if self.a else None,
                "t_s": None if self.t_s is None else round(self.t_s, 3)}


@dataclass
class Replay:
    """Deepest overlap per kind over a trajectory (0 where none)."""
    object_before_closing: Overlap = field(default_factory=Overlap)
    object_closing_not_pad: Overlap = field(default_factory=Overlap)
    pad_press_closing: Overlap = field(default_factory=Overlap)
    support: Overlap = field(default_factory=Overlap)
    obstacle: Overlap = field(default_factory=Overlap)
    self_collision: Overlap = field(default_factory=Overlap)
    samples: int = 0

    def counted(self):
        """The deepest overlap the contract forbids (the pads' press excluded)."""
        return max(self.object_before_closing.depth_m, self.object_closing_not_pad.depth_m,
                   self.support.depth_m, self.obstacle.depth_m, self.self_collision.depth_m)

    def json(self):
        return {"counted_max_m": round(self.counted(), 6), "samples": self.samples,
                **{k: getattr(self, k).json() for k in (
                    "object_before_closing", "object_closing_not_pad", "pad_press_closing",
                    "support", "obstacle", "self_collision")}}


class Replayer:
    """The robot in one scene, ready to replay trajectories on it."""

    def __init__(self, info: B.SystemInfo, urdf_text: str, object_spec: dict | None,
                 obstacles: list | None = None, mesh_source=None):
        d = {"object": object_spec, "support": (object_spec or {}).get("support"),
             "obstacles": obstacles or []}
        if object_spec is not None:
            # Mass and friction play no part in a kinematic check; the scene parser wants them.
            d["object"] = {"mass": 1.0, "friction": 1.0, **object_spec}
        scene = parse_scene(d)
        built = B.build(urdf_text, info, scene, mesh_source)
        self.sim = Sim(built)
        m = self.sim.m
        # Robot geoms collide with each other here (the physics model leaves that out).
        m.geom_conaffinity[built.robot_geoms] = 1
        m.geom_conaffinity[built.hand_geoms] = 1
        m.geom_margin[:] = 0.0
        m.geom_gap[:] = 0.0
        self.built = built
        self.names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}" for g in range(m.ngeom)]
        robot = set(int(g) for g in built.robot_geoms) | set(int(g) for g in built.hand_geoms)
        self.robot = robot
        self.pads = set()
        for f in info.fingers:
            b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f["tip_frame"])
            while b > 0 and m.body_geomnum[b] == 0:
                b = m.body_parentid[b]
            self.pads.update(g for g in range(m.ngeom) if m.geom_bodyid[g] == b)
        self.obstacles = set(int(g) for g in built.obstacle_geoms)
        # Geoms on bodies welded to the world (no joint moves them): the base on its support.
        self.static = set(g for g in robot if m.body_weldid[m.geom_bodyid[g]] == 0)
        self.allowed = set()
        zero = np.clip(np.zeros(self.sim.n), self.sim.lower, self.sim.upper)
        for a, b, depth in self._overlaps(zero):
            if a in robot and b in robot and depth > 0:
                self.allowed.add((a, b))

    def _overlaps(self, q):
        m, d = self.sim.m, self.sim.d
        d.qpos[:] = m.qpos0
        self.sim.couple(d.qpos, q)
        mujoco.mj_fwdPosition(m, d)
        for i in range(d.ncon):
            c = d.contact[i]
            if c.dist < 0:
                a, b = sorted((int(c.geom1), int(c.geom2)))
                yield a, b, -float(c.dist)

    def replay(self, names, points, closing_from_s=None) -> Replay:
        """`points`: the trajectory's `[{t, positions}]` in `names` order."""
        order = [names.index(n) for n in self.built.info.joint_names]
        qs = np.array([[p["positions"][k] for k in order] for p in points], float)
        ts = np.array([p["t"] for p in points], float)
        closing = np.inf if closing_from_s is None else closing_from_s
        r = Replay()
        og, sg = self.built.object_geom, self.built.support_geom
        for i in range(len(qs)):
            subs = [0.0] if i == 0 else [s / SUB_STEPS for s in range(1, SUB_STEPS + 1)]
            for s in subs:
                q = qs[i] if s == 0.0 else qs[i - 1] + s * (qs[i] - qs[i - 1])
                t = ts[i] if s == 0.0 else ts[i - 1] + s * (ts[i] - ts[i - 1])
                r.samples += 1
                for a, b, depth in self._overlaps(q):
                    ra, rb = a in self.robot, b in self.robot
                    if ra and rb:
                        if (a, b) not in self.allowed:
                            r.self_collision.take(depth, self.names[a], self.names[b], t)
                        continue
                    if not (ra or rb):
                        continue  # the object on the support
                    g, other = (a, b) if ra else (b, a)
                    if other == og:
                        if t < closing:
                            r.object_before_closing.take(depth, self.names[g], "object", t)
                        elif g in self.pads:
                            r.pad_press_closing.take(depth, self.names[g], "object", t)
                        else:
                            r.object_closing_not_pad.take(depth, self.names[g], "object", t)
                    elif other == sg and g not in self.static:
                        r.support.take(depth, self.names[g], "support", t)
                    elif other in self.obstacles:
                        r.obstacle.take(depth, self.names[g], self.names[other], t)
        return r


__all__ = ["Replay", "Replayer"]
