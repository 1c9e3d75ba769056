"""The closed-loop law of the service's `ControlParams` (paper eq. 8 in PCA coordinates), as the
`execute` message carries it, in NumPy. Two laws (`params["law"]`):

- `phi_decay` (current models): per joint group, with `lam = params["lambda"]`,
  `ydot = -lam * phi * grad_y phi / |grad_y phi|^2` (the flow's direction at the speed that makes
  `phi` decay as `exp(-lam t)`), `u = W ydot + J_R(y) ydot - lam (z - delta_g)`, `z` the state's
  offset from the learned curved manifold `mu + W y + R(y)` and `delta_g` the goal's; the command
  is scaled as a whole into `velocity_limits`. This runs the open-loop humanlike path.
- `gradient` (parameters stored before): `u = W(-K_p grad_y phi) + K_perp (I - W W^T)(q_d - q)`.

A port of `src/motion/control.rs`, `nf.rs`, `curvature.rs` and `bspline.rs`; the tests compare it
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

    def phi_decay_velocity(self, y, yd):
        """-phi grad phi / |grad phi|^2 (phi decays at rate 1 along it), in log space."""
        l2 = self.length_scale**2
        lb, glb = self.log_beta(y)
        lb -= math.log(l2)
        gamma = float(np.sum((y - yd) ** 2)) / l2
        if gamma <= 0 or not math.isfinite(lb):
            return np.zeros(len(y))
        k = self.k
        lg = math.log(gamma)
        a = k * lg
        hi, lo = (a, lb) if a > lb else (lb, a)
        lse = hi + math.log1p(math.exp(lo - hi))
        f = 2.0 * (y - yd) / l2 - gamma / k * glb
        scale = math.exp(lg + lse - lb) / float(f @ f)
        return -scale * f if math.isfinite(scale) else np.zeros(len(y))

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


class Curvature:
    """`R(y) = C [1, y_i y_j (i <= j)]` (the learned off-manifold residual)."""

    def __init__(self, d: dict):
        self.dim = int(d["dim"])
        self.n = int(d["n"])
        self.C = np.asarray(d["coefficients"], float).reshape(self.n, -1)
        self.pairs = [(i, j) for i in range(self.dim) for j in range(i, self.dim)]

    def eval(self, y):
        f = np.array([1.0] + [y[i] * y[j] for i, j in self.pairs])
        return self.C @ f

    def directional(self, y, v):
        f = np.array([0.0] + [v[i] * y[j] + y[i] * v[j] for i, j in self.pairs])
        return self.C @ f


class Law:
    """`ControlParams` (the `params` of a `kind: model` payload)."""

    def __init__(self, params: dict):
        self.joint_names = list(params["joint_names"])
        self.k_perp = float(params["k_perp"])
        self.law = params.get("law", "gradient")
        self.lam = float(params.get("lambda", 0.0))
        self.vmax = np.asarray(params.get("velocity_limits", []), float)
        self.groups = []
        for g in params["groups"]:
            joints = np.asarray(g["joints"], int)
            mean = np.asarray(g["mean"], float)
            nf = NF(g["nf"])
            dim = len(nf.center)
            W = np.asarray(g["components"], float).reshape(len(joints), dim)
            curv = Curvature(g["curvature"]) if g.get("curvature") else None
            self.groups.append((joints, mean, W, nf, float(g["kp"]), curv))
        self.n = sum(len(g[0]) for g in self.groups)

    def control(self, q, qd_goal):
        if self.law == "phi_decay":
            return self._phi_decay(q, qd_goal)
        return self._gradient(q, qd_goal)

    def _phi_decay(self, q, qd_goal):
        q = np.asarray(q, float)
        qg = np.asarray(qd_goal, float)
        u = np.zeros(len(q))
        lam = self.lam
        for joints, mean, W, nf, _kp, curv in self.groups:
            y = W.T @ (q[joints] - mean)
            yd = W.T @ (qg[joints] - mean)
            if float(np.sum((y - nf.center) ** 2)) < nf.radius**2:
                v = lam * nf.phi_decay_velocity(y, yd)
            else:
                v = -0.5 * lam * (y - yd)
            off = q[joints] - mean - W @ y
            off_d = qg[joints] - mean - W @ yd
            jr = np.zeros(len(joints))
            if curv is not None:
                off = off - curv.eval(y)
                off_d = off_d - curv.eval(yd)
                jr = curv.directional(y, v)
            u[joints] = W @ v + jr - lam * (off - off_d)
        if self.vmax.size:
            m = len(self.vmax)
            lim = np.where(self.vmax > 0, self.vmax, np.inf)
            over = max(1.0, float(np.max(np.abs(u[:m]) / lim)))
            u[:m] /= over
        return u

    def _gradient(self, q, qd_goal):
        q = np.asarray(q, float)
        qg = np.asarray(qd_goal, float)
        u = np.zeros(len(q))
        for joints, mean, W, nf, kp, _curv in self.groups:
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
