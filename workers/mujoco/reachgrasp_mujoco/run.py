"""One execution on the physics worker: checks the `execute` message (as the reference worker's
`Run::new` does), builds the model with the execution's scene, runs the motion, then the grasp
trial, and assembles the report the `result` carries."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import build as B
from . import safety as S
from .law import Law, PathFollower
from .scene import Scene, SceneError, parse_scene, scene_from_object_spec
from .service import Service
from .sim import CONTROL_DT, ClosedLoop, Follow, OpenLoop, Pushes, PushOptions, RunOptions, Sim, Trial, TrialOptions


class ExecutionError(ValueError):
    pass


def resolve_scene(ex: dict, robot: str, service: Service | None, object_defaults: bool, fallback=None):
    """(scene or None, where it came from): the `execute` message's `scene`, else the stored plan
    the execution runs, else the worker's `--scene` file (`fallback`, parsed JSON), else none."""
    if ex.get("scene") is not None:
        return parse_scene(ex["scene"], object_defaults), "execute message"
    plan = service.plan_for_execution(robot, ex) if service is not None else None
    if plan is None:
        if fallback is not None:
            return parse_scene(fallback, object_defaults), "worker --scene file"
        return None, "none (no stored plan runs this execution)"
    spec = plan["grasp"]["object"]
    sc = scene_from_object_spec(spec, object_defaults)
    sc.plan_id = plan["id"]
    sc.idle_fingers = tuple((plan["grasp"].get("result") or {}).get("idle_fingers") or ())
    return sc, f"plan {plan['id']}"


def trial_moves(t) -> dict:
    """The `execute` message's `trial` (`{lift, hold_s, shakes}`, each optional) as
    `TrialOptions` fields; the service checked the ranges, checked again here (a worker is also
    driven by hand)."""
    if not isinstance(t, dict):
        raise ExecutionError("trial must be an object {lift, hold_s, shakes}")
    out = {}
    if "lift" in t:
        v = t["lift"]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not (0 < v <= 0.3):
            raise ExecutionError(f"trial.lift must be in (0, 0.3] m, got {v!r}")
        out["lift"] = float(v)
    if "hold_s" in t:
        v = t["hold_s"]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not (0 <= v <= 10):
            raise ExecutionError(f"trial.hold_s must be in [0, 10] s, got {v!r}")
        out["hold_time"] = float(v)
    if "shakes" in t:
        v = t["shakes"]
        if not isinstance(v, int) or isinstance(v, bool) or not (0 <= v <= 4):
            raise ExecutionError(f"trial.shakes must be an integer 0 to 4, got {v!r}")
        out["shakes"] = v
    return out


def idle_fingers(names, info: B.SystemInfo) -> tuple:
    """The `execute` message's `idle_fingers` (names of the system's fingers) as a tuple."""
    known = {f["name"] for f in info.fingers}
    if not isinstance(names, list) or not all(isinstance(n, str) and n in known for n in names):
        raise ExecutionError(f"idle_fingers must be a list of the system's fingers {sorted(known)}, got {names!r}")
    return tuple(names)


def _finite(xs):
    return all(isinstance(x, (int, float)) and math.isfinite(x) for x in xs)


class Execution:
    def __init__(self, ex: dict, urdf_text: str, info: B.SystemInfo, scene_and_note, q_start,
                 run: RunOptions, trial: TrialOptions | None, push: PushOptions | None, mesh_source=None):
        scene, note = scene_and_note if isinstance(scene_and_note, tuple) else (scene_and_note, "given")
        self.id = ex.get("execution_id")
        self.scene: Scene | None = scene
        self.scene_note = note
        self.opts = run
        mode = ex.get("mode")
        payload = ex.get("payload") or {}
        kind = payload.get("kind")
        names = info.joint_names
        n = len(names)
        if (mode, kind) not in (("open_loop", "trajectory"), ("closed_loop", "model"), ("streaming", "stream")):
            raise ExecutionError(f"mode {mode} does not fit a {kind} payload")
        pnames = payload.get("params", {}).get("joint_names") if kind == "model" else payload.get("joint_names")
        if pnames != names:
            raise ExecutionError(f"joint names {pnames} do not match this robot's {names}")
        self.built = B.build(urdf_text, info, scene, mesh_source)
        self.sim = Sim(self.built)
        self.q_start = np.asarray(q_start, float).copy()
        self.sim.set_posture(self.q_start)
        lo, hi = self.sim.lower, self.sim.upper

        def inside(q):
            return bool(np.all(q >= lo - 1e-6) and np.all(q <= hi + 1e-6))

        self.pushes = None
        self.safety = None
        self.streaming = kind == "stream"
        if self.streaming:
            hold = payload.get("hold_after_s")
            if not isinstance(hold, (int, float)) or not (math.isfinite(hold) and hold > 0):
                raise ExecutionError(f"hold_after_s must be positive, got {hold}")
            self.goal = None
            self.motion = Follow(self.sim, hold)
            # A teleoperated grasp is the operator's: no scripted trial after it.
            trial = None
        elif kind == "trajectory":
            pts = payload.get("points") or []
            self._check_points(pts, "trajectory", inside)
            self.goal = np.asarray(pts[-1]["positions"], float)
            self.motion = OpenLoop(self.sim, pts, run)
        else:
            try:
                law = Law(payload["params"])
            except (KeyError, ValueError, TypeError) as e:
                raise ExecutionError(f"the model's law is unreadable: {e}") from None
            goal = payload.get("goal") or []
            if law.n != n or len(goal) != n:
                raise ExecutionError(f"the model has {law.n} joints and the goal {len(goal)}, this robot {n}")
            if not _finite(goal) or not inside(np.asarray(goal, float)):
                raise ExecutionError("the goal is not finite or outside the joint limits")
            self.goal = np.asarray(goal, float)
            # The open-loop motion the law runs (`PathFollower`), which has the approach in it.
            path = payload.get("path")
            follower = None
            if path is not None:
                self._check_points(path, "law's path", inside)
                if float(np.max(np.abs(np.asarray(path[-1]["positions"], float) - self.goal))) > 1e-6:
                    raise ExecutionError("the law's path does not end at its goal")
                follower = PathFollower(path, run.tracking_gain)
            if push is not None and (push.target == "arm" or scene is not None and scene.object is not None):
                self.pushes = Pushes(push, self.sim, push.seed)
            stages = []
            spec = payload.get("safety")
            if spec is not None:
                self.safety, stages = self._safety(spec, inside, path)
            self.motion = ClosedLoop(self.sim, law, self.goal, run, self.pushes if push and push.target == "arm" else None,
                                     self.safety, stages, follower)
        if trial is not None and ex.get("trial") is not None:
            trial = dataclasses.replace(trial, **trial_moves(ex["trial"]))
        # The message's idle fingers, else those of the stored plan the scene came from.
        idle = ex.get("idle_fingers") or (list(scene.idle_fingers) if scene is not None else [])
        if trial is not None and idle:
            trial = dataclasses.replace(trial, idle_fingers=idle_fingers(idle, info))
        if trial is not None and push is not None and push.target == "object":
            trial = dataclasses.replace(trial, object_push=push.force)
        self.trial_opts = trial
        self.trial: Trial | None = None
        self.motion_outcome = None
        self.trial_result = None
        self.t_motion = None
        self.object_moved = None
        b = self.built
        self.object_p0 = self.sim.d.xpos[b.object_body].copy() if b.object_body >= 0 else None

    def _check_points(self, pts, what: str, inside):
        """A timed path the robot can follow from where it is (`ExecutionError` otherwise)."""
        n = self.sim.n
        if not isinstance(pts, list) or not pts:
            raise ExecutionError(f"the {what} has no points")
        prev = -math.inf
        for i, p in enumerate(pts):
            ok = (
                isinstance(p, dict)
                and len(p.get("positions", [])) == n
                and len(p.get("velocities", [])) == n
                and isinstance(p.get("t"), (int, float))
                and _finite(p["positions"]) and _finite(p["velocities"]) and math.isfinite(p["t"])
                and p["t"] > prev
            )
            if not ok:
                raise ExecutionError(f"{what} point {i} is invalid")
            if not inside(np.asarray(p["positions"])):
                raise ExecutionError(f"{what} point {i} is outside the joint limits")
            prev = p["t"]
        d = float(np.max(np.abs(np.asarray(pts[0]["positions"]) - self.q_start)))
        tol = self.opts.start_tolerance
        if d > tol:
            raise ExecutionError(f"the robot is {d:.3f} rad from the {what}'s start (tolerance {tol})")

    def _safety(self, spec, inside, path=None):
        """The safety filter and approach stages of a law with a scene (`safety.py`). A law that
        follows a path runs no stages, and its filter lets a pair come as close as it is
        anywhere on the path (the plan's, checked exactly; with the filter's 2 cm margin a path
        that passes closer would be held off for good), at every fifth point."""
        if not isinstance(spec, dict):
            raise ExecutionError("the payload's safety scene must be an object")
        if self.scene is None or self.scene.object is None:
            raise ExecutionError("a law with a safety scene needs the execution's object (no stored plan runs it)")
        n = self.sim.n
        stages = []
        pre = spec.get("pre_grasp")
        pairs = S.Pairs(self.sim)
        if pre is not None and path is None:
            if not isinstance(pre, list) or len(pre) != n or not _finite(pre) or not inside(np.asarray(pre, float)):
                raise ExecutionError(f"the pre-grasp needs {n} finite values inside the joint limits")
            stages = S.approach_stages(self.sim, pairs, self.q_start, pre, self.goal)
        try:
            along = [np.asarray(p["positions"], float) for p in (path or [])[::5]]
            f = S.SafetyFilter(self.sim, spec, [*stages, *along, self.goal], self.sim.vlimit)
        except (KeyError, TypeError, ValueError) as e:
            raise ExecutionError(f"the safety scene is unreadable: {e}") from None
        return f, stages

    def tick(self):
        """One control period; the (status, reason) of the motion once everything is done."""
        if self.motion_outcome is None:
            out = self.motion.tick()
            if out is None:
                return None
            self.motion_outcome = out
            self.t_motion = self.sim.t
            if self.object_p0 is not None:
                moved = self.sim.d.xpos[self.built.object_body] - self.object_p0
                self.object_moved = [round(float(x), 4) for x in moved]
            if out[0] != "succeeded" or self.trial_opts is None or self.scene is None or self.scene.object is None:
                return out
            self.trial = Trial(self.sim, self.trial_opts)
            return None
        out = self.trial.tick()
        if out is None:
            return None
        self.trial_result = out
        return self.motion_outcome

    def feedback(self):
        if self.trial is None:
            progress, err = self.motion.progress, self.motion.tracking_error
        else:
            progress = 1.0
            err = float(np.max(np.abs(self.sim.q() - self.sim.q_ref)))
        return {
            "type": "feedback",
            "execution_id": self.id,
            "t": round(self.sim.t, 6),
            "positions": [float(x) for x in self.sim.q()],
            "velocities": [float(x) for x in self.sim.qd()],
            "progress": float(progress),
            "tracking_error": float(err),
        }

    def report(self, status, reason, wall):
        sc = self.scene
        out = {
            "engine": "mujoco",
            "motion": {"outcome": status, "reason": reason, "sim_time_s": round(self.t_motion or self.sim.t, 3),
                       "final_error": self.sim.arrival_errors,
                       # where the motion left the object (m, world): the approach may push it
                       "object_moved_m": self.object_moved},
            "scene": None,
            "trial": self.trial_result,
            "sim_time_s": round(self.sim.t, 3),
            "wall_time_s": round(wall, 3),
            "real_time_factor": round(self.sim.t / wall, 3) if wall > 0 else None,
            "max_penetration_m": {k: round(v, 5) for k, v in self.sim.max_pen.items()},
            "model_notes": self.built.notes,
        }
        if sc is not None and sc.object is not None:
            out["scene"] = {
                "source": self.scene_note,
                "object": sc.object.name,
                "mass": sc.object.mass,
                "friction": sc.object.friction,
                "properties_from": sc.provenance,
                "obstacles": len(sc.obstacles),
            }
        if self.pushes is not None:
            out["pushes"] = self.pushes.log
        if self.safety is not None:
            out["safety"] = self.safety.report(self.sim)
        if self.streaming:
            out["stream"] = dict(self.motion.stats)
        return out

    def final_outcome(self, status, reason):
        """The execution's outcome: the motion's, and with a trial, failed when not held."""
        if status != "succeeded" or self.trial_result is None:
            return status, reason
        t = self.trial_result
        if t["held"]:
            return "succeeded", None
        return "failed", (
            f"grasp trial: object not held (lifted {t['object_lift_m']:.3f} m of {self.trial_opts.lift} m, "
            f"slip {t['slip_m']:.3f} m, held after {t['held_after']})"
        )
