"""The closed-loop law `u(q) = W(-K_p grad_y phi) + K_perp (I - W W^T)(q_d - q)` (paper eq. 8 in
PCA coordinates) of the service's `ControlParams`, as the `execute` message carries it, in NumPy.

A port of `src/motion/control.rs`, `nf.rs` and `bspline.rs` (`ControlParams::control`,
`NavigationFunction::value_gradient`, `TensorBSpline::value_gradient`); the tests compare it
with the service's own evaluation, `POST /v1/models/{id}/control`.
"""

from __future__ import annotations

import math

import numpy as np


def _basis(u: float):
    v = 1.0 - u
    u2 = u * u
    u3 = u2 * u
    b = np.array([v * v * v / 6.0, (3 * u3 - 6 * u2 + 4) / 6.0, (-3 * u3 + 3 * u2 + 3 * u + 1) / 6.0, u3 / 6.0])
    db = np.array([-0.5 * v * v, 0.5 * (3 * u2 - 4 * u), 0.5 * (-3 * u2 + 2 * u + 1), 0.5 * u2])
    return b, db


class Spline:
    """Uniform tensor-product cubic B-spline (axis 0 varies fastest in the coefficients)."""

    def __init__(self, d: dict):
        self.dim = int(d["dim"])
        self.intervals = int(d["intervals"])
        self.lower = np.asarray(d["lower"], float)
        self.spacing = np.asarray(d["spacing"], float)
        per = self.intervals + 3
        c = np.asarray(d["coefficients"], float)
        if c.size != per**self.dim:
            raise ValueError(f"spline has {c.size} coefficients, expected {per ** self.dim}")
        # C-order reshape with reversed axes: index = sum_i idx_i * per^i.
        self.coef = c.reshape([per] * self.dim).transpose(list(range(self.dim))[::-1])

    def value_gradient(self, y):
        d = self.dim
        last = self.intervals - 1
        bs, dbs, cells = [], [], []
        for i in range(d):
            x = (y[i] - self.lower[i]) / self.spacing[i]
            cell = min(max(math.floor(x), 0), last)
            u = min(max(x - cell, 0.0), 1.0)
            b, db = _basis(u)
            bs.append(b)
            dbs.append(db / self.spacing[i])
            cells.append(cell)
        block = self.coef[tuple(slice(c, c + 4) for c in cells)]
        val = block
        for i in range(d):
            val = np.tensordot(val, bs[i], axes=([0], [0]))
        grad = np.zeros(d)
        for k in range(d):
            g = block
            for i in range(d):
                g = np.tensordot(g, dbs[i] if i == k else bs[i], axes=([0], [0]))
            grad[k] = float(g)
        return float(val), grad


class NF:
    def __init__(self, d: dict):
        self.k = float(d["k"])
        self.length_scale = float(d["length_scale"])
        self.center = np.asarray(d["center"], float)
        self.radius = float(d["radius"])
        self.spline = Spline(d["spline"])

    def log_beta(self, y):
        r2 = float(np.sum((y - self.center) ** 2))
        beta0 = self.radius**2 - r2
        s, g = self.spline.value_gradient(y)
        if beta0 <= 0:
            return -math.inf, g
        g = g - 2.0 * (y - self.center) / beta0
        return math.log(beta0) + s, g

    def gradient(self, y, yd):
        l2 = self.length_scale**2
        lb, glb = self.log_beta(y)
        lb -= math.log(l2)
        gamma = float(np.sum((y - yd) ** 2)) / l2
        k = self.k
        lg = math.log(gamma) if gamma > 0 else -math.inf
        a = k * lg
        hi, lo = (a, lb) if a > lb else (lb, a)
        lse = hi + math.log1p(math.exp(lo - hi)) if math.isfinite(lo) else hi
        factor = math.exp(lb - (1.0 + 1.0 / k) * lse)
        return factor * (2.0 * (y - yd) / l2 - gamma / k * glb)


class Law:
    """`ControlParams` (the `params` of a `kind: model` payload)."""

    def __init__(self, params: dict):
        self.joint_names = list(params["joint_names"])
        self.k_perp = float(params["k_perp"])
        self.groups = []
        for g in params["groups"]:
            joints = np.asarray(g["joints"], int)
            mean = np.asarray(g["mean"], float)
            nf = NF(g["nf"])
            dim = len(nf.center)
            W = np.asarray(g["components"], float).reshape(len(joints), dim)
            self.groups.append((joints, mean, W, nf, float(g["kp"])))
        self.n = sum(len(g[0]) for g in self.groups)

    def control(self, q, qd_goal):
        q = np.asarray(q, float)
        qg = np.asarray(qd_goal, float)
        u = np.zeros(len(q))
        for joints, mean, W, nf, kp in self.groups:
            y = W.T @ (q[joints] - mean)
            yd = W.T @ (qg[joints] - mean)
            z = W.T @ (qg[joints] - q[joints])
            if float(np.sum((y - nf.center) ** 2)) < nf.radius**2:
                grad = nf.gradient(y, yd)
            else:
                grad = 2.0 * (y - yd) / nf.length_scale**2
            v = -kp * grad - self.k_perp * z
            u[joints] = self.k_perp * (qg[joints] - q[joints]) + W @ v
        return u


# `motion::CLOCK_TOLERANCE`: the error (rad) at which the clock runs at half speed.
CLOCK_TOLERANCE = 0.02


class TimedPoints:
    """A trajectory's timed points (`t`, `positions`, `velocities`) as the reference the
    open-loop servo and the path follower both run: linear between points, the last position at
    rest from the last point's time on."""

    def __init__(self, points):
        self.t = np.array([p["t"] for p in points], float)
        self.q = np.array([p["positions"] for p in points], float)
        self.v = np.array([p["velocities"] for p in points], float)

    def at(self, tau: float):
        """Position and velocity at time `tau`."""
        if tau >= self.t[-1] or len(self.t) == 1:
            return self.q[-1], np.zeros_like(self.q[-1])
        k = int(np.searchsorted(self.t, tau, side="right") - 1)
        k = max(0, min(k, len(self.t) - 2))
        s = min(max((tau - self.t[k]) / (self.t[k + 1] - self.t[k]), 0.0), 1.0)
        return (self.q[k] + s * (self.q[k + 1] - self.q[k]),
                self.v[k] + s * (self.v[k + 1] - self.v[k]))


class PathFollower:
    """`motion::PathFollower`: a closed-loop law that runs the payload's `path` (the open-loop
    humanlike motion) with a governed clock. Per period, with `p`, `v` the path at the clock
    `tau`, `e = max|p - q|` and `g = 1/(1 + (e/e0)^2)`: `u = g v + K (p - q)`, `tau += g dt`
    (the feedback `K (p - q_ref)` on the servo reference where the worker gives it: `step`).
    The clock waits while the robot is off the path (a push, a safety filter holding it), so
    the motion resumes where it left the path."""

    def __init__(self, points, gain: float, tolerance: float = CLOCK_TOLERANCE):
        self.path = TimedPoints(points)
        self.gain = float(gain)
        self.tolerance = float(tolerance)
        self.span = float(self.path.t[-1] - self.path.t[0])
        self.clock = 0.0

    def reference(self):
        return self.path.at(self.path.t[0] + self.clock)

    def step(self, q, dt: float, q_ref=None):
        """The command for the measured `q` and the reference; advances the clock. With `q_ref`,
        the servo reference a position-controlled arm tracks, the feedback acts on it instead of
        on `q` (the clock is still governed by the measured `q`, so it still waits after a
        push): the servo closes the loop on the measured state itself. With the feedback on `q`,
        a hand held off by a contact kept the feedback growing, and the reference integrated
        from it wound up past the path (to the 0.05 rad band) and pressed harder than open loop
        does: a link 3 mm into the table pressed it with 73 N against open loop's 17
        (`tests/test_follow.py`), and in the closed-loop physics survey objects were shoved
        10-24 cm before the grasp (38 of 60 held with the feedback on `q`, 41 on the reference;
        open loop 43). In free space it costs the servo's own lag (on a 1.4 rad, 1.5 s joint
        line at most 0.009 rad off the path against 0.005)."""
        p, v = self.reference()
        e = float(np.max(np.abs(p - q)))
        g = 1.0 / (1.0 + (e / self.tolerance) ** 2)
        self.clock = min(self.clock + g * dt, self.span)
        base = q if q_ref is None else q_ref
        return g * v + self.gain * (p - base), p

    def progress(self) -> float:
        return min(self.clock / self.span, 1.0) if self.span > 0 else 1.0

    def at_end(self) -> bool:
        return self.progress() >= 1.0
