"""A reference grasp whose outcome physics alone decides: the T42 pointing straight down over a
40 x 40 x 50 mm block on the table at (0.5, 0), its open distal phalanges straddling the block
(6 mm clear each side), so closing pinches it. Used by the end-to-end test and the push survey
while the service's own plans do not hold (README)."""

from __future__ import annotations

import numpy as np

from . import build as B
from .service import Service
from .sim import Sim

BLOCK = {"object": {"name": "block", "shape": {"type": "box", "size": [0.04, 0.04, 0.05]},
                    "position": [0.5, 0.0, 0.025], "orientation": [1, 0, 0, 0], "mass": 0.1, "friction": 0.8},
         "support": {"normal": [0, 0, 1], "offset": 0.0}}
HAND_P = np.array([0.5, 0.0, 0.2055])  # T42 base: fingertips 19 mm above the table


def pinch(svc: Service, robot: str = "wam_t42", height: float = 0.15, duration: float = 3.0, n: int = 150):
    """(joint names, goal, points): the pinch configuration and a trajectory descending onto it
    from `height` above (arm IK along the vertical line, computed from the goal upwards so the
    path ends exactly at the goal)."""
    detail, urdf = svc.robot(robot)
    sim = Sim(B.build(urdf, B.SystemInfo.from_detail(detail), None))
    goal = sim.hand_pointing_down(HAND_P)
    offs = [np.array([0, 0, height * (10 * u**3 - 15 * u**4 + 6 * u**5)]) for u in (k / n for k in range(n + 1))]
    path, err = sim.arm_ik_path(goal, offs, duration / n)
    if err > 1e-5:
        raise RuntimeError(f"descent IK residual {err}")
    path = np.array(path[::-1])
    dt = duration / n
    vel = np.gradient(path, dt, axis=0)
    vel[0] = vel[-1] = 0
    zero = [0.0] * sim.n
    pts = [{"t": k * dt, "positions": path[k].tolist(), "velocities": vel[k].tolist(), "accelerations": zero}
           for k in range(n + 1)]
    return detail["joint_names"], goal, pts
