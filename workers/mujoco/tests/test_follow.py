"""The path follower on the simulated arm (`law.PathFollower` in `sim.ClosedLoop`) against a
contact: a path that would take a link of the hand 2-4 mm into the table. With the follower's feedback on
the measured state, the hand held off by the table keeps the feedback growing, and the servo
reference it integrates winds up past the path (up to the reference band) and presses the table
harder; with the feedback on the servo reference, the reference stays on the path, as open loop
has it. Judged by the reference's excursion past the path and the normal force on the table,
against the follower with the feedback on the measured state and against open loop."""

import mujoco
import numpy as np
import pytest

from reachgrasp_mujoco import build as B
from reachgrasp_mujoco.law import PathFollower
from reachgrasp_mujoco.scene import parse_scene
from reachgrasp_mujoco.sim import ClosedLoop, OpenLoop, RunOptions, Sim

from test_model import load
from test_safety import lowered


@pytest.fixture(scope="module")
def ihy(service):
    detail, urdf = load(service, "wam_ihy")
    info = B.SystemInfo.from_detail(detail)
    scene = parse_scene({"support": {"normal": [0, 0, 1], "offset": 0.0}})
    return Sim(B.build(urdf, info, scene))


class OnMeasured(PathFollower):
    """The follower with its feedback on the measured state whatever the servo reference."""

    def step(self, q, dt, q_ref=None):
        return super().step(q, dt)


def joint_line(q0, q1, duration, rate=100.0):
    """`q0` to `q1` on the minimum-jerk clock, as timed points."""
    pts = []
    for k in range(int(duration * rate) + 1):
        s = k / (duration * rate)
        x = 10 * s**3 - 15 * s**4 + 6 * s**5
        dx = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
        pts.append({"t": k / rate, "positions": list(q0 + x * (q1 - q0)),
                    "velocities": list(dx * (q1 - q0))})
    return pts


def table_force(sim):
    """Total normal force (N) of the robot's contacts with the table."""
    f6 = np.zeros(6)
    total = 0.0
    for i in range(sim.d.ncon):
        c = sim.d.contact[i]
        if sim.b.support_geom in (c.geom1, c.geom2):
            mujoco.mj_contactForce(sim.m, sim.d, i, f6)
            total += abs(f6[0])
    return total


def pressed(sim, follower_cls, pts):
    """Runs the path 2 s past its end (`follower_cls` None: open loop): the servo reference's
    largest excursion from the path (rad, largest arm joint) and the mean table force over the
    last second."""
    sim.set_posture(np.asarray(pts[0]["positions"]))
    if follower_cls is None:
        run = OpenLoop(sim, pts, RunOptions())
    else:
        run = ClosedLoop(sim, None, np.asarray(pts[-1]["positions"]), RunOptions(), None,
                         follower=follower_cls(pts, 8.0))
    periods = int(round((pts[-1]["t"] + 2.0) / 0.01))
    excursion, forces = 0.0, []
    for k in range(periods):
        run.tick()
        if follower_cls is not None:
            p, _ = run.follower.reference()
            excursion = max(excursion, float(np.max(np.abs(sim.q_ref - p)[sim.arm])))
        if k >= periods - 100:
            forces.append(table_force(sim))
    return excursion, float(np.mean(forces))


def test_feedback_on_the_servo_reference_does_not_wind_up_against_a_contact(ihy):
    sim = ihy
    q0 = sim.hand_pointing_down([0.5, 0.2, 0.20])
    # the first palm height (1 mm steps down) that puts a link 2-4 mm into the table
    q1 = lowered(sim, q0, np.arange(0.20, -0.1, -0.001), -0.004, -0.002)
    assert q1 is not None
    pts = joint_line(q0, q1, 1.5)
    ref_excursion, ref_force = pressed(sim, PathFollower, pts)
    q_excursion, q_force = pressed(sim, OnMeasured, pts)
    _, open_force = pressed(sim, None, pts)
    # measured: 0.0001 rad and 17 N on the reference, 0.047 rad and 73 N on the measured state,
    # 17 N open loop
    assert q_excursion > 0.02 and ref_excursion < 0.1 * q_excursion, (ref_excursion, q_excursion)
    assert 0.0 < ref_force < 0.5 * q_force, (ref_force, q_force)
    assert 0.7 * open_force < ref_force < 1.3 * open_force, (ref_force, open_force)
