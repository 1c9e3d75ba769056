"""The simulated arm-hand system: servo layer, the two execution controllers (open loop, closed
loop), pushes, and the grasp trial (close, lift 10 cm, hold 2 s, two shakes) with its verdict.

Time advances in control periods of `CONTROL_DT` (5 physics steps). Everything here is
synchronous and deterministic for a given model, execution and seed; the bridge layer paces it.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import mujoco
import numpy as np

from .build import Built
from .law import TimedPoints
from .safety import STAGE_TOLERANCE

CONTROL_DT = 0.01  # s (100 Hz control, as the reference worker)


@dataclass
class RunOptions:
    # Arrival: arm joints within `goal_tolerance` of the goal, every joint slower than
    # `stop_velocity` (the hand's deviation is reported: the object may stop the fingers).
    goal_tolerance: float = 0.01
    stop_velocity: float = 0.05
    # Arrival against the object: when the settle time is over and the arm is at rest, touching
    # the object, within `contact_tolerance` of the goal, the motion has arrived (the hand's
    # contact forces hold the arm off its goal through the servo's finite stiffness, as on a
    # real arm); the deviation and the contact force are reported with the arrival.
    contact_tolerance: float = 0.03
    start_tolerance: float = 0.25
    settle_time: float = 2.0
    closed_loop_timeout: float = 30.0
    # Closed loop: the servo reference may run at most this far ahead of the measured state, so
    # a push that displaces the arm drags the reference with it and the law acts from there.
    reference_band: float = 0.05
    # Closed loop along a path (`law.PathFollower`): the feedback gain, 1/s, as the reference
    # worker's.
    tracking_gain: float = 8.0


@dataclass
class PushOptions:
    """Pushes during a closed-loop execution (the paper's perturbation experiment): `max_pushes`
    pushes of `force` N for `duration` s, `interval` s apart from `first` s after the start,
    while the motion is under way (`progress` < 0.8), each on a random body of the forearm,
    wrist or hand in a random horizontal direction (seeded). The servo gives way where the
    push exceeds the joints' effort limits; the law then acts from the displaced state."""

    target: str = "arm"  # arm | object (object: pushes on the held object during the hold)
    force: float = 150.0
    duration: float = 0.2
    first: float = 0.3
    interval: float = 0.6
    max_pushes: int = 3
    seed: int = 7


@dataclass
class TrialOptions:
    close_time: float = 0.6
    close_settle: float = 0.6
    lift: float = 0.10
    lift_time: float = 1.5
    hold_time: float = 2.0
    shakes: int = 2
    # One shake: x(s) = A sin(2 pi s) sin^2(pi s) over one period (s in [0, 1]), a Hann-windowed
    # sine that starts and ends at rest. A = 0.029 m at 2 Hz: peak acceleration 6.3 m/s^2 (peak
    # displacement 19 mm). The plain sine it replaces (4 cm, the same peak acceleration) began and
    # ended at 0.5 m/s, a velocity step through the servos at each of the four ends, which flung
    # held bottles out of pinches that carried the shakes themselves.
    shake_amplitude: float = 0.029  # m, A above
    shake_frequency: float = 2.0  # Hz
    settle_time: float = 0.5
    # Held: object above the support by at least this share of the lift and touching the hand.
    held_lift_share: float = 0.5
    # Slipped: the object moved more than this relative to the hand (m) while lifted.
    slip_threshold: float = 0.01
    # Push the held object during the hold (N, 0.1 s along -z then +y), 0 = none.
    object_push: float = 0.0
    # Grip: share of each closing drive's force limit (the URDF effort) the hand closes and holds
    # with, as a person grips: lightly, and harder once the object slips (Westling & Johansson
    # 1984; Johansson & Westling 1984). At the stall torque alone (1) the fingers pressed objects
    # of 30-520 g with 95-155 N in all and squeezed them out of fingertip grasps: 45 of 53
    # survey grasps held, 49 with this grip and reflex (README: the grip).
    grip: float = 0.25
    # Fingers the trial leaves as they are (the grasp's `idle_fingers`, kept off the object):
    # closing them would push the object out of the other fingers' pinch.
    idle_fingers: tuple = ()
    # The slip reflex: once the object has moved this far relative to the hand after closing (m),
    # the grip rises to `grip_on_slip` for the rest of the trial. 0 = no reflex.
    slip_reflex: float = 0.003
    grip_on_slip: float = 1.0


def rotation_error(target_R, R):
    """World-frame rotation vector (axis x angle) taking `R` to `target_R` (exact log map: the
    skew part alone vanishes at 180 degrees)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (target_R @ R.T).ravel())
    v = np.zeros(3)
    mujoco.mju_quat2Vel(v, quat, 1.0)
    return v


class Sim:
    def __init__(self, built: Built):
        self.b = built
        self.m = built.model
        self.d = mujoco.MjData(self.m)
        self.n = len(built.drives)
        self.steps_per_control = max(1, round(CONTROL_DT / self.m.opt.timestep))
        self.qadr = np.array([self.m.jnt_qposadr[dr.joint_id] for dr in built.drives])
        self.vadr = np.array([self.m.jnt_dofadr[dr.joint_id] for dr in built.drives])
        self.lower = np.array([dr.lower for dr in built.drives])
        self.upper = np.array([dr.upper for dr in built.drives])
        vel = np.array([dr.velocity for dr in built.drives])
        self.vlimit = np.where(vel > 0, vel, 1.5)
        self.arm = np.array([dr.arm for dr in built.drives])
        self.t = 0.0
        self.arrival_errors = None
        self._kin = mujoco.MjData(self.m)  # kinematic scratch for IK
        self.max_pen = {"hand_object": 0.0, "robot_support": 0.0, "object_support": 0.0, "robot_obstacle": 0.0}
        self._geom_class = np.zeros(self.m.ngeom, int)  # 0 other, 1 robot, 2 hand, 3 object, 4 support, 5 obstacle
        self._geom_class[built.robot_geoms] = 1
        self._geom_class[built.hand_geoms] = 2
        if built.object_geom >= 0:
            self._geom_class[built.object_geom] = 3
        if built.support_geom >= 0:
            self._geom_class[built.support_geom] = 4
        for g in built.obstacle_geoms:
            self._geom_class[g] = 5
        # Rigid joint equalities (mimic joints outside their leader's chain, e.g. the iHY's
        # geared spread pair): (qpos of j1, dof of j1, qpos of j2, dof of j2, offset, factor)
        # for j1 = offset + factor * j2.
        m = self.m
        self.equalities = [
            (
                int(m.jnt_qposadr[m.eq_obj1id[e]]),
                int(m.jnt_dofadr[m.eq_obj1id[e]]),
                int(m.jnt_qposadr[m.eq_obj2id[e]]),
                int(m.jnt_dofadr[m.eq_obj2id[e]]),
                float(m.eq_data[e][0]),
                float(m.eq_data[e][1]),
            )
            for e in range(m.neq)
            if m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT
        ]
        # Per independent joint, the dofs its value moves and by how much (its own, its tendon
        # followers', then the equalities led by any of those): d qvel / d q_k.
        self.coupled_dofs = []
        for k, dr in enumerate(built.drives):
            cols = {int(self.vadr[k]): 1.0}
            for jid, mult in dr.followers:
                cols[int(m.jnt_dofadr[jid])] = float(mult)
            for _, dof1, _, dof2, _, factor in self.equalities:
                if dof2 in cols:
                    cols[dof1] = factor * cols[dof2]
            self.coupled_dofs.append(list(cols.items()))

    # --- state -------------------------------------------------------------------------------
    def set_posture(self, q):
        """Places the robot at independent joint values `q` (followers from their couplings)."""
        q = np.clip(np.asarray(q, float), self.lower, self.upper)
        self.couple(self.d.qpos, q)
        self.d.qvel[:] = 0
        self.set_reference(q, np.zeros(self.n))
        mujoco.mj_forward(self.m, self.d)

    def couple(self, qpos, q):
        """Writes independent joint values `q` into the MuJoCo `qpos` vector in place, with every
        coupled joint (tendon followers, rigid equalities) where its coupling puts it."""
        for k, dr in enumerate(self.b.drives):
            qpos[self.qadr[k]] = q[k]
            for jid, mult in dr.followers:
                qpos[self.m.jnt_qposadr[jid]] = mult * q[k]
        for qadr1, _, qadr2, _, offset, factor in self.equalities:
            qpos[qadr1] = offset + factor * qpos[qadr2]

    def q(self):
        return self.d.qpos[self.qadr].copy()

    def qd(self):
        return self.d.qvel[self.vadr].copy()

    def set_reference(self, q_ref, qd_ref):
        """Servo targets: position `q_ref` with velocity feed-forward `qd_ref`."""
        q_ref = np.clip(q_ref, self.lower, self.upper)
        self.q_ref = q_ref
        m = self.m
        for k, dr in enumerate(self.b.drives):
            a = dr.actuator_id
            kp = m.actuator_gainprm[a, 0]
            kv = -m.actuator_biasprm[a, 2]
            ff = kv / kp * qd_ref[k] if kp > 0 else 0.0
            if dr.tendon_id >= 0:
                ratio = 1.0 + sum(mu for _, mu in dr.followers)
                self.d.ctrl[a] = dr.ctrl_gain * q_ref[k] + ff * ratio
            else:
                self.d.ctrl[a] = q_ref[k] + ff

    def step_control(self, pushes=None):
        for _ in range(self.steps_per_control):
            if pushes is not None:
                pushes.apply(self)
            mujoco.mj_step(self.m, self.d)
            self.t += self.m.opt.timestep
            self._watch_contacts()

    def _watch_contacts(self):
        d = self.d
        cls = self._geom_class
        for i in range(d.ncon):
            c = d.contact[i]
            if c.dist >= 0:
                continue
            a, b = sorted((cls[c.geom1], cls[c.geom2]))
            pen = -c.dist
            key = None
            if a in (1, 2) and b == 3:
                key = "hand_object" if a == 2 else "hand_object"
            elif a in (1, 2) and b == 4:
                key = "robot_support"
            elif a == 3 and b == 4:
                key = "object_support"
            elif a in (1, 2) and b == 5:
                key = "robot_obstacle"
            if key and pen > self.max_pen[key]:
                self.max_pen[key] = pen

    # --- contacts and poses ------------------------------------------------------------------
    def object_contacts(self):
        """[(robot geom, normal force N)] of the robot's contacts with the object, and whether
        the object touches the support."""
        out = []
        on_support = False
        f6 = np.zeros(6)
        og = self.b.object_geom
        for i in range(self.d.ncon):
            c = self.d.contact[i]
            if og not in (c.geom1, c.geom2):
                continue
            other = c.geom2 if c.geom1 == og else c.geom1
            if other == self.b.support_geom:
                on_support = True
                continue
            if self._geom_class[other] in (1, 2):
                mujoco.mj_contactForce(self.m, self.d, i, f6)
                out.append((int(other), float(f6[0])))
        return out, on_support

    def body_pose(self, body):
        return self.d.xpos[body].copy(), self.d.xmat[body].reshape(3, 3).copy()

    def object_in_hand(self):
        """Object position (hand frame) and rotation relative to the hand."""
        ph, Rh = self.body_pose(self.b.hand_body)
        po, Ro = self.body_pose(self.b.object_body)
        return Rh.T @ (po - ph), Rh.T @ Ro

    # --- kinematic IK for the trial's Cartesian hand motion -----------------------------------
    def hand_pointing_down(self, position):
        """Joint values with the hand root at `position`, its approach axis straight down (hand
        x along world x), from the elbow-bent WAM/PA10 branch (shoulder 0.8, elbow 1.6 rad);
        leaves the robot there. Raises if the IK does not reach the pose."""
        q0 = np.zeros(self.n)
        q0[1], q0[3] = 0.8, 1.6
        self.set_posture(q0)
        q, err = self.hand_pose_ik(q0, np.asarray(position, float), np.diag([1.0, -1.0, -1.0]))
        if err > 1e-6:
            raise RuntimeError(f"hand pose IK residual {err}")
        self.set_posture(q)
        return q

    def hand_pose_ik(self, q0, target_p, target_R, iters=200):
        """Arm joints (hand and the rest from `q0`) putting the hand root at `target_p`,
        `target_R` by damped least squares; returns (q, residual norm)."""
        m, kd = self.m, self._kin
        kd.qpos[:] = self.d.qpos
        arm = np.where(self.arm)[0]
        cols = self.vadr[arm]
        jp = np.zeros((3, m.nv))
        jr = np.zeros((3, m.nv))
        q = np.asarray(q0, float).copy()
        err = math.inf
        for _ in range(iters):
            kd.qpos[self.qadr] = q
            mujoco.mj_kinematics(m, kd)
            mujoco.mj_comPos(m, kd)
            p = kd.xpos[self.b.hand_body]
            R = kd.xmat[self.b.hand_body].reshape(3, 3)
            e = np.concatenate([target_p - p, rotation_error(target_R, R)])
            err = float(np.linalg.norm(e))
            if err < 1e-8:
                break
            mujoco.mj_jacBody(m, kd, jp, jr, self.b.hand_body)
            J = np.vstack([jp[:, cols], jr[:, cols]])
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(6), e)
            q[arm] = np.clip(q[arm] + dq, self.lower[arm], self.upper[arm])
        return q, err

    def arm_ik_path(self, q0, offsets, dt=CONTROL_DT):
        """Joint paths putting the hand root at its pose for `q0` shifted by each world offset
        (orientation kept), one every `dt` seconds: damped least squares on the arm joints,
        warm-started along the path, each joint within its limits and within its velocity limit
        of the previous point (where the pose needs faster joints the hand lags and catches up,
        as the servos would make it). Returns the path and the largest pose error on it."""
        m, kd = self.m, self._kin
        kd.qpos[:] = self.d.qpos
        kd.qpos[self.qadr] = q0
        mujoco.mj_kinematics(m, kd)
        p0 = kd.xpos[self.b.hand_body].copy()
        R0 = kd.xmat[self.b.hand_body].reshape(3, 3).copy()
        arm = np.where(self.arm)[0]
        cols = self.vadr[arm]
        step = self.vlimit[arm] * dt
        jp = np.zeros((3, m.nv))
        jr = np.zeros((3, m.nv))
        q = np.asarray(q0, float).copy()
        path = []
        worst = 0.0
        for off in offsets:
            target = p0 + off
            lo = np.maximum(self.lower[arm], q[arm] - step)
            hi = np.minimum(self.upper[arm], q[arm] + step)
            for _ in range(30):
                kd.qpos[self.qadr] = q
                mujoco.mj_kinematics(m, kd)
                p = kd.xpos[self.b.hand_body]
                R = kd.xmat[self.b.hand_body].reshape(3, 3)
                e = np.concatenate([target - p, rotation_error(R0, R)])
                if np.linalg.norm(e) < 1e-6:
                    break
                mujoco.mj_comPos(m, kd)
                mujoco.mj_jacBody(m, kd, jp, jr, self.b.hand_body)
                J = np.vstack([jp[:, cols], jr[:, cols]])
                # Active set: a joint on a bound whose step would push past it is locked and
                # the step re-solved with the others (a 7-joint arm keeps the 6-D pose with one
                # joint locked; clipping its share of every step instead left the hand rotating
                # off its pose, 0.15 rad and more at the WAM's wrist limits).
                qa = q[arm]
                free = np.ones(len(arm), bool)
                for _ in range(len(arm)):
                    Jf = J * free
                    dq = Jf.T @ np.linalg.solve(Jf @ Jf.T + 1e-6 * np.eye(6), e)
                    on = ((qa + dq < lo) & (qa <= lo + 1e-12)) | ((qa + dq > hi) & (qa >= hi - 1e-12))
                    if not (free & on).any():
                        break
                    free &= ~on
                q[arm] = np.clip(qa + dq, lo, hi)
            worst = max(worst, float(np.linalg.norm(e)))
            path.append(q.copy())
        return path, worst


# --- pushes ----------------------------------------------------------------------------------
class Pushes:
    def __init__(self, opts: PushOptions, sim: Sim, seed: int):
        self.o = opts
        self.rng = np.random.default_rng(seed)
        self.count = 0
        self.active_until = -1.0
        self.body = -1
        self.force = np.zeros(3)
        self.log = []
        m = sim.m
        if opts.target == "object":
            self.bodies = [sim.b.object_body]
        else:
            # The arm's moving bodies from the forearm out (pushes on the shoulder barely move it).
            bodies = sorted({int(m.jnt_bodyid[dr.joint_id]) for dr in sim.b.drives if dr.arm})
            self.bodies = bodies[len(bodies) // 2 :] + [sim.b.hand_body]

    def maybe_start(self, sim: Sim, progress: float, t: float):
        """`t`: seconds since the execution started."""
        o = self.o
        if self.log and sim.t < self.active_until:
            dev = float(np.max(np.abs(sim.q() - sim.q_ref)))
            self.log[-1]["deflection_rad"] = max(self.log[-1]["deflection_rad"], round(dev, 4))
        if o.force <= 0 or self.count >= o.max_pushes or progress >= 0.8 or sim.t < self.active_until:
            return
        if t >= o.first + self.count * o.interval:
            self.body = int(self.rng.choice(self.bodies))
            a = self.rng.uniform(0, 2 * math.pi)
            self.force = o.force * np.array([math.cos(a), math.sin(a), 0.0])
            self.active_until = sim.t + o.duration
            self.count += 1
            self.log.append(
                {"t": round(t, 3), "body": mujoco.mj_id2name(sim.m, mujoco.mjtObj.mjOBJ_BODY, self.body),
                 "force_n": [round(float(x), 2) for x in self.force], "deflection_rad": 0.0}
            )

    def apply(self, sim: Sim):
        sim.d.xfrc_applied[:] = 0
        if sim.t < self.active_until and self.body >= 0:
            sim.d.xfrc_applied[self.body, :3] = self.force


# --- controllers -----------------------------------------------------------------------------
class OpenLoop:
    """Follows timed points (servo reference = the trajectory, velocity feed-forward)."""

    def __init__(self, sim: Sim, points, opts: RunOptions):
        self.sim = sim
        self.o = opts
        self.path = TimedPoints(points)
        self.t0 = sim.t
        self.t_end = float(self.path.t[-1])
        self.goal = self.path.q[-1]
        self.tracking_error = 0.0
        self.progress = 0.0

    def reference(self, t):
        return self.path.at(t)

    def tick(self):
        sim = self.sim
        t = sim.t - self.t0
        q_ref, v_ref = self.reference(t)
        sim.set_reference(q_ref, v_ref)
        sim.step_control()
        t = sim.t - self.t0
        q = sim.q()
        self.tracking_error = float(np.max(np.abs(q - q_ref)))
        self.progress = min(t / self.t_end, 1.0) if self.t_end > 0 else 1.0
        if t < self.t_end:
            return None
        return arrival(sim, self.goal, self.o, t - self.t_end, self.o.settle_time)


def arrival(sim: Sim, goal, o: RunOptions, waited: float, allowed: float):
    """Arrived: the arm within `goal_tolerance` of the goal and every joint at rest. The hand's
    deviation is reported, not judged: at a grasp configuration the object stops the fingers
    (that is the point of a grasp), by how much depends on the contact."""
    q = sim.q()
    err = np.abs(q - goal)
    arm_err = float(np.max(err[sim.arm])) if sim.arm.any() else 0.0
    hand_err = float(np.max(err[~sim.arm])) if (~sim.arm).any() else 0.0
    speed = float(np.max(np.abs(sim.qd())))
    sim.arrival_errors = {"arm_rad": round(arm_err, 5), "hand_rad": round(hand_err, 5)}
    if arm_err <= o.goal_tolerance and speed <= o.stop_velocity:
        return ("succeeded", None)
    if waited >= allowed and arm_err <= o.contact_tolerance and speed <= o.stop_velocity:
        touching, _ = sim.object_contacts()
        if touching:
            sim.arrival_errors["in_contact"] = True
            sim.arrival_errors["contact_force_n"] = round(sum(f for _, f in touching), 2)
            return ("succeeded", None)
    if waited >= allowed:
        return (
            "failed",
            f"arm error {arm_err:.4f} rad (tolerance {o.goal_tolerance}), speed {speed:.3f} rad/s "
            f"after {waited:.1f} s (hand error {hand_err:.4f} rad)",
        )
    return None


class ClosedLoop:
    """Runs the model's law `u(q)` on the measured state (velocity command, servo reference
    integrated from it and kept within `reference_band` of the measured state)."""

    def __init__(self, sim: Sim, law, goal, opts: RunOptions, pushes: Pushes | None,
                 safety=None, stages=(), follower=None):
        self.sim = sim
        self.law = law
        self.goal = np.asarray(goal, float)
        self.o = opts
        self.pushes = pushes
        # `safety.SafetyFilter` of a payload with a scene, and the approach stages the law runs
        # to before the goal (`safety.approach_stages`).
        self.safety = safety
        self.stages = [np.asarray(s, float) for s in stages]
        self.stage = 0
        # `law.PathFollower` of a payload with a path: the law runs that motion instead.
        self.follower = follower
        self.t0 = sim.t
        self.q_ref = sim.q()
        self.initial = max(float(np.max(np.abs(self.q_ref - self.goal))), 1e-9)
        self.tracking_error = self.initial
        self.progress = 0.0

    def tick(self):
        sim = self.sim
        q = sim.q()
        while self.stage < len(self.stages) and np.max(np.abs(q - self.stages[self.stage])) <= STAGE_TOLERANCE:
            self.stage += 1
        reference = None
        if self.follower is not None:
            u, reference = self.follower.step(q, CONTROL_DT, self.q_ref)
        else:
            target = self.stages[self.stage] if self.stage < len(self.stages) else self.goal
            u = self.law.control(q, target)
        if self.safety is not None:
            u = self.safety.filter(sim.d.qpos, u, sim.t - self.t0, reference, CONTROL_DT)
        u = np.clip(u, -sim.vlimit, sim.vlimit)
        band = self.o.reference_band
        self.q_ref = q + np.clip(self.q_ref + u * CONTROL_DT - q, -band, band)
        sim.set_reference(self.q_ref, u)
        if self.pushes is not None:
            self.pushes.maybe_start(sim, self.progress, sim.t - self.t0)
        sim.step_control(self.pushes)
        q = sim.q()
        err = float(np.max(np.abs(q - self.goal)))
        self.tracking_error = err
        if self.follower is not None:
            self.progress = self.follower.progress()
        else:
            self.progress = min(max(1.0 - err / self.initial, 0.0), 1.0)
        t = sim.t - self.t0
        pushing = self.pushes is not None and sim.t < self.pushes.active_until
        if pushing or self.follower is not None and not self.follower.at_end():
            return None
        # (the time to converge counts from the end of the path: a long motion is not cut off)
        span = self.follower.span if self.follower is not None else 0.0
        return arrival(sim, self.goal, self.o, t, span + self.o.closed_loop_timeout)


class Follow:
    """A streaming execution (teleoperation): the servo reference follows the latest setpoint,
    moved on with its velocity until the next one is due (one setpoint interval) and then the
    setpoint itself, and never faster than the joints' velocity limits (a first setpoint far from
    the robot is approached, not jumped to). When no setpoint arrived for `hold_after` s the arm
    holds where it is. Ends only by the service's `end` or `cancel`."""

    def __init__(self, sim: Sim, hold_after: float):
        self.sim = sim
        self.hold_after = float(hold_after)
        # Setpoints arrive on the event loop while the simulation ticks on a worker thread.
        self.lock = threading.Lock()
        self.target = None
        self.velocity = None
        self.received_at = 0.0
        self.interval = 0.0
        self.stream_t = math.nan
        self.next_seq = 0
        self.stats = {"received": 0, "missing": 0, "refused": 0, "held_periods": 0}
        self.q_ref = sim.q()
        self.tracking_error = 0.0
        self.progress = 0.0

    def setpoint(self, m: dict) -> bool:
        with self.lock:
            return self._setpoint(m)

    def _setpoint(self, m: dict) -> bool:
        n = self.sim.n
        q, v, seq, t = m.get("positions"), m.get("velocities"), m.get("seq"), m.get("t")
        ok = (
            isinstance(q, list) and isinstance(v, list) and len(q) == n and len(v) == n
            and all(isinstance(x, (int, float)) and math.isfinite(x) for x in q + v)
            and isinstance(seq, int) and seq >= self.next_seq
            and isinstance(t, (int, float)) and math.isfinite(t)
        )
        if not ok:
            self.stats["refused"] += 1
            return False
        self.stats["missing"] += seq - self.next_seq
        self.stats["received"] += 1
        self.next_seq = seq + 1
        self.target = np.clip(np.asarray(q, float), self.sim.lower, self.sim.upper)
        self.velocity = np.asarray(v, float)
        self.received_at = self.sim.t
        gap = t - self.stream_t
        self.interval = min(gap, self.hold_after) if math.isfinite(gap) and gap > 0 else 0.0
        self.stream_t = t
        return True

    def tick(self):
        with self.lock:
            return self._tick()

    def _tick(self):
        sim = self.sim
        since = sim.t - self.received_at
        if self.target is not None and since <= self.hold_after:
            ff = since < self.interval
            goal = self.target + (self.velocity * since if ff else 0.0)
            step = np.clip(goal - self.q_ref, -sim.vlimit * CONTROL_DT, sim.vlimit * CONTROL_DT)
            self.q_ref = np.clip(self.q_ref + step, sim.lower, sim.upper)
            sim.set_reference(self.q_ref, self.velocity if ff else np.zeros(sim.n))
            sim.step_control()
            self.tracking_error = float(np.max(np.abs(sim.q() - np.clip(goal, sim.lower, sim.upper))))
        else:
            # No setpoint yet, or the stream went quiet: hold the measured posture.
            self.q_ref = sim.q()
            sim.set_reference(self.q_ref, np.zeros(sim.n))
            sim.step_control()
            self.stats["held_periods"] += 1
            self.tracking_error = 0.0 if self.target is None else float(np.max(np.abs(sim.q() - self.target)))
        return None


# --- the grasp trial -------------------------------------------------------------------------
def min_jerk(s):
    return s * s * s * (10 - 15 * s + 6 * s * s)


class Trial:
    """Close, lift, hold, shake; `tick()` advances one control period, `result()` is the verdict.

    Closing: each finger's tendon (or, without a tendon, its last independent joint that is not
    a spread joint) is commanded to the joint limit on the object's side, force limited to
    `grip` x the URDF effort until the object slips `slip_reflex` in the hand, then to
    `grip_on_slip` x; spread and opposition joints hold, and so do the idle fingers'. Lift/shake: the hand root moves along world
    offsets (orientation kept) through arm IK, tracked by the arm servos."""

    def __init__(self, sim: Sim, opts: TrialOptions):
        self.sim = sim
        self.o = opts
        b = sim.b
        self.q_grasp = sim.q()
        spread = {j for p in b.info.spread_pairs for j in p}
        names = [dr.name for dr in b.drives]
        close = set()
        for f in b.info.fingers:
            if f["name"] in opts.idle_fingers:
                continue
            idx = [names.index(j) for j in f["joints"] if j in names]
            tendon = [k for k in idx if b.drives[k].tendon_id >= 0]
            if tendon:
                close.update(tendon)
            else:
                free = [k for k in idx if names[k] not in spread and not b.drives[k].arm]
                if free:
                    close.add(free[-1])
        self.close = sorted(close)
        # The grip: the closing drives' force limits for the trial, restored by `result`.
        self._force_range = {}
        for k in self.close:
            a = b.drives[k].actuator_id
            self._force_range[a] = sim.m.actuator_forcerange[a].copy()
        self._set_grip(opts.grip)
        self.grip_raised = None  # the phase in which the slip reflex raised the grip
        self.close_target = self.q_grasp.copy()
        self.tips = {f["name"]: mujoco.mj_name2id(sim.m, mujoco.mjtObj.mjOBJ_BODY, f["tip_frame"]) for f in b.info.fingers}
        for k in self.close:
            self.close_target[k] = self._closing_limit(k)
        self.phase = "close"
        self.t0 = sim.t
        self.z0 = float(sim.d.xpos[b.object_body][2])
        self.events = []
        self.forces = []
        self.rel0 = None
        self.held_after = {}
        # Cartesian offsets, one per control period, after closing.
        o = opts
        offs = []
        n_lift = int(round(o.lift_time / CONTROL_DT))
        for i in range(1, n_lift + 1):
            offs.append(("lift", np.array([0, 0, o.lift * min_jerk(i / n_lift)])))
        for _ in range(int(round(o.hold_time / CONTROL_DT))):
            offs.append(("hold", np.array([0, 0, o.lift])))
        axes = [np.array([0, 1.0, 0]), np.array([0, 0, 1.0])]
        n_shake = int(round(1.0 / o.shake_frequency / CONTROL_DT))
        for s in range(o.shakes):
            ax = axes[s % 2]
            for i in range(1, n_shake + 1):
                u = i / n_shake
                a = o.shake_amplitude * math.sin(2 * math.pi * u) * math.sin(math.pi * u) ** 2
                offs.append((f"shake{s + 1}", np.array([0, 0, o.lift]) + a * ax))
        for _ in range(int(round(o.settle_time / CONTROL_DT))):
            offs.append(("settle", np.array([0, 0, o.lift])))
        self.plan = offs
        self.cursor = 0
        self.path = None
        self.ik_error = 0.0

    def _set_grip(self, share):
        for a, fr in self._force_range.items():
            self.sim.m.actuator_forcerange[a] = share * fr

    def _closing_limit(self, k):
        """The joint limit whose side brings the finger's tip nearer the object's centre."""
        sim = self.sim
        dr = sim.b.drives[k]
        kd = sim._kin
        kd.qpos[:] = sim.d.qpos
        mujoco.mj_kinematics(sim.m, kd)
        tipb = [bid for f, bid in self.tips.items() if dr.name in next(x["joints"] for x in sim.b.info.fingers if x["name"] == f)]
        po = sim.d.xpos[sim.b.object_body]
        if not tipb:
            # No fingertip frame moves with this joint: flex towards the upper limit, the
            # closing side of every bundled hand.
            return dr.upper

        def dist(delta):
            q = self.q_grasp.copy()
            q[k] += delta
            sim.couple(kd.qpos, q)
            mujoco.mj_kinematics(sim.m, kd)
            return sum(float(np.linalg.norm(kd.xpos[t] - po)) for t in tipb)

        up = dist(0.05) < dist(-0.05)
        return dr.upper if up else dr.lower

    def tick(self):
        sim, o = self.sim, self.o
        t = sim.t - self.t0
        if self.phase == "close":
            s = min(t / o.close_time, 1.0)
            q_ref = self.q_grasp + min_jerk(s) * (self.close_target - self.q_grasp)
            sim.set_reference(q_ref, np.zeros(sim.n))
            sim.step_control()
            if t >= o.close_time + o.close_settle:
                self.phase = "move"
                self.q_closed = sim.q()
                self.rel0 = sim.object_in_hand()
                self.contacts_closed = sim.object_contacts()
                self.path, self.ik_error = sim.arm_ik_path(self.q_grasp, [off for _, off in self.plan])
            return None
        if self.cursor >= len(self.plan):
            return self.result()
        phase, _ = self.plan[self.cursor]
        q_ref = self.close_target.copy()
        arm = sim.arm
        q_ref[arm] = self.path[self.cursor][arm]
        prev = self.path[self.cursor - 1][arm] if self.cursor > 0 else self.q_grasp[arm]
        v = np.zeros(sim.n)
        v[arm] = (q_ref[arm] - prev) / CONTROL_DT
        sim.set_reference(q_ref, v)
        if phase == "hold" and o.object_push > 0:
            k = self.cursor - int(round(o.lift_time / CONTROL_DT))
            sim.d.xfrc_applied[:] = 0
            if 50 <= k < 60:
                sim.d.xfrc_applied[sim.b.object_body, :3] = [0, 0, -o.object_push]
            elif 100 <= k < 110:
                sim.d.xfrc_applied[sim.b.object_body, :3] = [0, o.object_push, 0]
        sim.step_control()
        sim.d.xfrc_applied[:] = 0
        if self.grip_raised is None and o.slip_reflex > 0:
            if float(np.linalg.norm(sim.object_in_hand()[0] - self.rel0[0])) > o.slip_reflex:
                self._set_grip(o.grip_on_slip)
                self.grip_raised = phase
        if phase == "hold":
            cs, _ = sim.object_contacts()
            self.forces.append(cs)
        nxt = self.plan[self.cursor + 1][0] if self.cursor + 1 < len(self.plan) else "end"
        if nxt != phase:
            self.held_after[phase] = self.held()
        self.cursor += 1
        return None

    def held(self):
        sim = self.sim
        cs, on_support = sim.object_contacts()
        z = float(sim.d.xpos[sim.b.object_body][2])
        lifted = z - self.z0
        return bool(not on_support and lifted >= self.o.held_lift_share * self.o.lift and cs)

    def result(self):
        sim = self.sim
        m = sim.m
        for a, fr in self._force_range.items():
            m.actuator_forcerange[a] = fr
        held = self.held()
        p_rel, R_rel = sim.object_in_hand()
        p0, R0 = self.rel0
        slip = float(np.linalg.norm(p_rel - p0))
        dR = R0.T @ R_rel
        slip_rot = math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(dR) - 1) / 2))))
        z = float(sim.d.xpos[sim.b.object_body][2])
        # Mean normal force per robot body over the hold.
        per_body = {}
        totals = []
        for cs in self.forces:
            tot = 0.0
            for g, f in cs:
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g]))
                per_body[name] = per_body.get(name, 0.0) + f
                tot += f
            totals.append(tot)
        nh = max(len(self.forces), 1)
        cs_closed, _ = self.contacts_closed
        closed_links = sorted({mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) for g, _ in cs_closed})
        out = {
            "held": held,
            "slipped": bool(slip > self.o.slip_threshold),
            "held_after": self.held_after,
            "object_lift_m": round(z - self.z0, 4),
            "slip_m": round(slip, 4),
            "slip_rotation_deg": round(slip_rot, 2),
            "displacement_in_hand_m": [round(float(x), 4) for x in (p_rel - p0)],
            "contacts_after_close": closed_links,
            "contact_force_mean_n": {k: round(v / nh, 3) for k, v in sorted(per_body.items())},
            "contact_force_total_mean_n": round(float(np.mean(totals)) if totals else 0.0, 3),
            "contact_force_total_max_n": round(float(np.max(totals)) if totals else 0.0, 3),
            "max_penetration_m": {k: round(v, 5) for k, v in sim.max_pen.items()},
            "ik_error_m": round(self.ik_error, 6),
            "closing_joints": [sim.b.drives[k].name for k in self.close],
            "grip": self.o.grip,
            "grip_raised_in": self.grip_raised,
            "duration_s": round(sim.t - self.t0, 3),
        }
        return out
