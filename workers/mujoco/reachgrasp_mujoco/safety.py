"""The safety filter of a closed-loop law with a scene, and the approach stages it runs in.

The service sends a closed-loop payload with a `safety` scene (the grasped object, its support,
obstacles, margins, and the grasp's pre-grasp) only to a worker that announces the
`safety_filter` capability. This is the same filter as the service's reference worker
(`src/geometry/barrier.rs`), on MuJoCo's geometry: each control period the law's command `u0`
is replaced by the nearest command that keeps every monitored pair's barrier

    h_i(q) = d_i(q) - tau_i,  tau_i = margin, or g_i - 0.5 mm for a pair closer than the margin
                                      at one of the goals (the grasp's contacts)

from falling faster than the arm can stop:

    u = argmin 1/2 |u - u0|^2  s.t.  grad h_i . u >= -gamma(h_i)  (pairs within `influence`),
                                     |u_j| <= v_j,
    gamma(h) = min(alpha h, sqrt(2 A h)) for h > 0, alpha h otherwise.

`d_i` is MuJoCo's exact distance between a robot collision geom and a scene geom (object,
support, obstacles; `mj_geomDistance`) and its gradient comes from the witness points. Pairs of
two links are left to the simulator's own contacts here (the service's filter keeps 2 mm
between links; a plan's law was checked for that on the reference worker). The projection is
Hildreth's dual coordinate ascent with the bounds as dual variables, a fixed number of sweeps.

Stages (`approach_stages`): with a pre-grasp the law runs first to the pre-grasp (the palm
backed off along the approach direction, the hand open), then the arm to the grasp with the
hand still open (half or a quarter as open where fully open would put a finger into the scene),
then to the grasp itself, where the hand closes. The law's own flow otherwise closes the hand
while the arm is still on its way, through the object. A stage ends when every joint is within
`STAGE_TOLERANCE` of it.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

STAGE_TOLERANCE = 0.02  # rad
CONTACT_SLACK = 5e-4  # m: how far below its clearance at a goal a contact pair may come
INFLUENCE = 0.5  # m: a pair gets a constraint within its target plus this
SWEEPS = 64


class Pairs:
    """The monitored pairs (robot geom, scene geom) and their exact distances and gradients
    with respect to the independent joints."""

    def __init__(self, sim):
        b = sim.b
        self.sim = sim
        self.m = sim.m
        self.d = mujoco.MjData(sim.m)  # kinematic scratch
        scene = [g for g in [b.object_geom, b.support_geom, *b.obstacle_geoms] if g >= 0]
        # links welded to the world (the base on its table) never move apart: not monitored
        moving = [int(r) for r in b.robot_geoms if sim.m.body_weldid[sim.m.geom_bodyid[r]] != 0]
        self.pairs = [(r, int(s)) for r in moving for s in scene]
        self.scene = set(scene)
        self.fromto = np.zeros(6)
        self.jp = np.zeros((3, sim.m.nv))

    def pose(self, q_full):
        """Kinematics at full MuJoCo `qpos` values."""
        self.d.qpos[:] = q_full
        mujoco.mj_kinematics(self.m, self.d)
        mujoco.mj_comPos(self.m, self.d)

    def pose_joints(self, q):
        """Kinematics at independent joint values `q` (coupled joints as `Sim.set_posture` puts
        them)."""
        qpos = self.sim.d.qpos.copy()
        self.sim.couple(qpos, q)
        self.pose(qpos)

    def distance(self, i, reach):
        """Exact distance of pair `i` (capped at `reach`) and the witness points."""
        g1, g2 = self.pairs[i]
        d = mujoco.mj_geomDistance(self.m, self.d, g1, g2, reach, self.fromto)
        return d, self.fromto[:3].copy(), self.fromto[3:].copy()

    def within(self, i, reach):
        """Cheap cull: bounding spheres farther apart than `reach`."""
        g1, g2 = self.pairs[i]
        m, d = self.m, self.d
        if g2 == self.sim.b.support_geom:
            return True  # a plane has no bounding sphere
        c = float(np.linalg.norm(d.geom_xpos[g1] - d.geom_xpos[g2]))
        return c - m.geom_rbound[g1] - m.geom_rbound[g2] < reach

    def gradient(self, i, dist, p1, p2, out):
        """d(distance)/dq over the independent joints into `out`: the robot's witness point
        `p1` moves with its body; the distance grows along the separating direction."""
        g1, _ = self.pairs[i]
        n = p2 - p1
        norm = float(np.linalg.norm(n))
        out[:] = 0.0
        if norm < 1e-12:
            return False
        n /= norm
        # apart: p1 moving against n (towards away from p2) grows d; inside: along n
        s = -1.0 if dist >= 0 else 1.0
        body = int(self.m.geom_bodyid[g1])
        mujoco.mj_jac(self.m, self.d, self.jp, None, p1, body)
        g = s * (n @ self.jp)
        for k, cols in enumerate(self.sim.coupled_dofs):
            out[k] = sum(mult * g[c] for c, mult in cols)
        return True


class SafetyFilter:
    """The filter of one closed-loop execution (see the module docs)."""

    def __init__(self, sim, spec: dict, goals, velocity):
        self.p = Pairs(sim)
        self.margin = float(spec["margin_m"])
        self.rate = float(spec["rate"])
        self.braking = float(spec["braking_m_s2"])
        if not all(math.isfinite(x) and x > 0 for x in (self.margin, self.rate, self.braking)):
            raise ValueError("the safety filter's margin, rate and braking must be positive")
        self.velocity = np.asarray(velocity, float)
        n = len(self.p.pairs)
        # each pair may come as close as it is at any goal (less a contact's tolerance)
        self.target = np.full(n, self.margin)
        reach = self.margin + 1e-3
        for goal in goals:
            self.p.pose_joints(goal)
            for i in range(n):
                if self.p.within(i, reach):
                    d, _, _ = self.p.distance(i, reach)
                    if d < self.margin:
                        self.target[i] = min(self.target[i], d - CONTACT_SLACK)
        nq = sim.n
        self.rows = np.zeros((n, nq))
        self.rhs = np.zeros(n)
        self.row_pair = np.zeros(n, int)
        self.row_d = np.zeros(n)
        # along a path: per pair, the period of its last distance at the reference and that
        # distance (`filter`'s `reference`)
        self.ref_at = np.full(n, -2, int)
        self.ref_distance = np.zeros(n)
        self.periods = 0
        self.filtered = 0
        self.min_distance = math.inf
        self.min_barrier = math.inf
        self.closest = None
        self.time = None

    def filter(self, q_full, u, t, reference=None, dt=0.0):
        """The nearest safe command to `u` (independent joints) at the measured `qpos`. With
        the `reference` of a law that follows a path (the path at the follower's clock, `dt` s
        after the last period), each near pair may also approach as fast as it does on the path
        there (`barrier.rs`' `filter_along`): the path is checked exactly, and the static
        barrier alone braked a pair the path brings to its closest at the grasp, so that the
        follower fell behind its clock and came into the grasp another way."""
        p = self.p
        p.pose(q_full)
        u = np.asarray(u, float).copy()
        rows = 0
        reach = self.margin + INFLUENCE
        for i in range(len(p.pairs)):
            if not p.within(i, reach):
                continue
            d, p1, p2 = p.distance(i, reach)
            if d >= reach:
                continue
            h = d - self.target[i]
            self.min_barrier = min(self.min_barrier, h)
            if d < self.min_distance:
                self.min_distance, self.closest, self.time = d, i, t
            if h >= INFLUENCE:
                continue
            if not p.gradient(i, d, p1, p2, self.rows[rows]) or np.abs(self.rows[rows]).max() <= 1e-12:
                continue  # a pair no joint moves apart (a base link on the table)
            self.rhs[rows] = -approach_bound(self.rate, self.braking, h)
            self.row_pair[rows] = i
            self.row_d[rows] = d
            rows += 1
        self.periods += 1
        if reference is not None and rows:
            p.pose_joints(reference)
            for k in range(rows):
                i = self.row_pair[k]
                d_ref, _, _ = p.distance(i, 4.0 * reach)
                # (not for a pair already closer than the path has it: a deviation towards it)
                if self.ref_at[i] + 1 == self.periods and dt > 0 and self.row_d[k] >= d_ref - CONTACT_SLACK:
                    self.rhs[k] += min(0.0, (d_ref - self.ref_distance[i]) / dt)
                self.ref_at[i], self.ref_distance[i] = self.periods, d_ref
        # the nominal command inside the velocity bounds, its direction kept
        u /= max(1.0, float(np.max(np.abs(u) / self.velocity)))
        if rows and project(self.rows[:rows], self.rhs[:rows], self.velocity, u, SWEEPS):
            self.filtered += 1
        return u

    def report(self, sim):
        """The filter's account in the protocol's `SafetyReport` form (None before a period)."""
        if self.periods == 0:
            return None
        link = other = None
        if self.closest is not None:
            g1, g2 = self.p.pairs[self.closest]
            link = _body_name(sim, g1)
            other = "support" if g2 == sim.b.support_geom else _body_name(sim, g2)
        return {
            "min_barrier_m": _finite_or_none(self.min_barrier),
            "min_distance_m": _finite_or_none(self.min_distance),
            "link": link,
            "other": other,
            "time_s": self.time,
            "periods": self.periods,
            "filtered_periods": self.filtered,
        }


def _body_name(sim, geom):
    return mujoco.mj_id2name(sim.m, mujoco.mjtObj.mjOBJ_BODY, int(sim.m.geom_bodyid[geom]))


def _finite_or_none(x):
    return x if math.isfinite(x) else None


def approach_bound(rate, braking, h):
    """The fastest a barrier at `h` may fall."""
    if h > 0:
        return min(rate * h, math.sqrt(2.0 * braking * h))
    return rate * h


def project(a, b, bounds, u, sweeps):
    """Hildreth's method for min 1/2 |u - u0|^2 s.t. a_k . u >= b_k and |u_j| <= bounds_j, from
    u = u0 in place; the bounds are dual variables too (a plain clamp would not converge to the
    projection). Returns whether any row is active at the end."""
    rows = len(b)
    norms = np.einsum("ij,ij->i", a, a)
    duals = np.zeros(rows)
    mu = np.zeros(len(u))
    for _ in range(sweeps):
        change = 0.0
        for k in range(rows):
            r = b[k] - float(a[k] @ u)
            delta = max(r / norms[k], -duals[k])
            if delta != 0.0:
                duals[k] += delta
                u += delta * a[k]
                change = max(change, abs(delta) * math.sqrt(norms[k]))
        # bounds: mu_j <= 0 at the upper, >= 0 at the lower bound
        free = u - mu
        new_mu = np.clip(free, -bounds, bounds) - free
        change = max(change, float(np.max(np.abs(new_mu - mu))))
        u += new_mu - mu
        mu = new_mu
        if change < 1e-12:
            break
    return bool(np.any(duals > 0))


def opening_clear(pairs: Pairs, a, b, steps: int = 20) -> bool:
    """Whether the straight joint move from `a` to `b` keeps every robot-scene pair at least as
    far apart as the closest one is at `a` (sampled every 1/steps of the move)."""
    n = len(pairs.pairs)

    def closest(q):
        pairs.pose_joints(q)
        return min((pairs.distance(i, 0.05)[0] for i in range(n) if pairs.within(i, 0.05)), default=0.05)

    at_a = min(closest(a), 0.0)
    a, b = np.asarray(a, float), np.asarray(b, float)
    return all(closest(a + (k / steps) * (b - a)) >= at_a - 1e-4 for k in range(1, steps + 1))


def approach_stages(sim, pairs: Pairs, start, pre, goal):
    """The goals a law runs to in turn before `goal` (see the module docs)."""
    arm = sim.arm
    start, pre, goal = (np.asarray(x, float) for x in (start, pre, goal))
    stages = []
    opened = np.where(arm, start, pre)
    if np.max(np.abs(opened - start)) > STAGE_TOLERANCE and not opening_clear(pairs, start, opened):
        # a closed hand resting on the table cannot open there: carry it to the pre-grasp first
        stages.append(np.where(arm, pre, start))
    stages.append(pre)
    for f in (1.0, 0.5, 0.25):
        q = np.where(arm, goal, goal + f * (pre - goal))
        if opening_clear(pairs, pre, q):
            stages.append(q)
            break
    return stages
