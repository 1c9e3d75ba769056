"""Grasp trials without the bridge: the robot placed at a stored grasp's exact joint values next
to its object, then close, lift, hold, shake (the same `Trial` the worker runs after a motion).
Used by the surveys (`workers/mujoco/survey.py`) and the `trial` sub-command."""

from __future__ import annotations

import dataclasses
import time

import mujoco
import numpy as np

from . import build as B
from .scene import scene_from_object_spec
from .sim import Sim, Trial, TrialOptions

_robots = {}


def robot(svc, robot_id):
    if robot_id not in _robots:
        detail, urdf_text = svc.robot(robot_id)
        _robots[robot_id] = (B.SystemInfo.from_detail(detail), urdf_text)
    return _robots[robot_id]


def grasp_posture(info: B.SystemInfo, result: dict):
    vals = {j["name"]: j["value"] for j in result["q_arm"] + result["q_hand"]}
    return np.array([vals[n] for n in info.joint_names], float)


def initial_penetration(sim: Sim):
    """Deepest overlap (m) at the placed posture, before any step: hand/robot vs object, robot vs
    support, object vs support."""
    mujoco.mj_forward(sim.m, sim.d)
    sim.max_pen = {k: 0.0 for k in sim.max_pen}
    sim._watch_contacts()
    return dict(sim.max_pen)


def grasp_trial(svc, grasp: dict, object_defaults: bool, opts: TrialOptions | None = None):
    info, urdf_text = robot(svc, grasp["robot"])
    scene = scene_from_object_spec(grasp["object"], object_defaults)
    built = B.build(urdf_text, info, scene, svc.meshes(grasp["robot"], urdf_text).get)
    sim = Sim(built)
    q = grasp_posture(info, grasp["result"])
    sim.set_posture(q)
    pen0 = initial_penetration(sim)
    sim.max_pen = {k: 0.0 for k in sim.max_pen}
    wall = time.monotonic()
    opts = opts or TrialOptions()
    idle = grasp["result"].get("idle_fingers") or ()
    trial = Trial(sim, dataclasses.replace(opts, idle_fingers=tuple(idle)))
    out = None
    while out is None:
        out = trial.tick()
    wall = time.monotonic() - wall
    out["initial_penetration_m"] = {k: round(v, 5) for k, v in pen0.items()}
    out["grasp_id"] = grasp["id"]
    out["robot"] = grasp["robot"]
    out["object"] = grasp["object"]["name"]
    out["real_time_factor"] = round(out["duration_s"] / wall, 2) if wall > 0 else None
    return out
