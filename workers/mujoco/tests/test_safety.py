"""The worker's safety filter against independent references: its distance gradients against
central finite differences of MuJoCo's exact distances, its projection against closed forms,
the barrier it keeps when the plain law would drive a finger into the table, and a path it
admits left alone when the path's reference is given."""

import math

import mujoco
import numpy as np
import pytest

from reachgrasp_mujoco import build as B
from reachgrasp_mujoco import safety as S
from reachgrasp_mujoco.scene import parse_scene
from reachgrasp_mujoco.sim import Sim

from test_model import load

BALL = {"name": "ball", "shape": {"type": "sphere", "radius": 0.033}, "position": [0.5, 0.0, 0.033],
        "orientation": [1, 0, 0, 0], "mass": 0.06, "friction": 0.8}


@pytest.fixture(scope="module")
def ihy(service):
    detail, urdf = load(service, "wam_ihy")
    info = B.SystemInfo.from_detail(detail)
    scene = parse_scene({"object": BALL, "support": {"normal": [0, 0, 1], "offset": 0.0}})
    return Sim(B.build(urdf, info, scene))


def hand_above_ball(sim):
    """The hand pointing down, its palm 17 cm above the table over the ball."""
    return sim.hand_pointing_down([0.5, 0.0, 0.17])


def hand_beside_ball(sim):
    """The hand pointing down, its palm 30 cm above the table and 20 cm beside the ball (so the
    table is what a downward motion meets)."""
    q = hand_above_ball(sim)
    sim.set_posture(q)
    q, err = sim.hand_pose_ik(q, np.array([0.5, 0.2, 0.30]), np.diag([1.0, -1.0, -1.0]))
    assert err < 1e-6
    return q


SPEC = {"margin_m": 0.02, "self_margin_m": 0.002, "rate": 4.0, "braking_m_s2": 1.0}


def lowered(sim, q0, zs, near, far):
    """From `q0` (the hand pointing down), the first palm height of `zs` (metres, going down,
    over (0.5, 0.2)) at which the robot's closest link to the table is between `near` and `far`
    from it (negative: inside); None where none is."""
    probe = S.Pairs(sim)
    support = [i for i, (_, g) in enumerate(probe.pairs) if g == sim.b.support_geom]
    for z in zs:
        q, err = sim.hand_pose_ik(q0, np.array([0.5, 0.2, z]), np.diag([1.0, -1.0, -1.0]))
        if err >= 1e-6:
            continue
        probe.pose_joints(q)
        lowest = min(probe.distance(i, 0.5)[0] for i in support)
        if near < lowest < far:
            return q
    return None


def test_distance_gradients_match_finite_differences(ihy):
    sim = ihy
    pairs = S.Pairs(sim)
    rng = np.random.default_rng(5)
    base = hand_above_ball(sim)
    checked = 0
    # the iHY's finger2 spread follows finger1's through a rigid equality, not a tendon: pairs on
    # finger2's links must see finger1's spread move them
    spread = next(k for k, dr in enumerate(sim.b.drives) if dr.name == "ihy_finger1_spread")
    finger2 = {b for b in range(sim.m.nbody) if "finger2" in (mujoco.mj_id2name(sim.m, mujoco.mjtObj.mjOBJ_BODY, b) or "")}
    through_equality = 0
    for trial in range(4):
        q = np.clip(base + rng.normal(0, 0.05, sim.n), sim.lower + 0.05, sim.upper - 0.05)
        pairs.pose_joints(q)
        near = [i for i in range(len(pairs.pairs)) if pairs.within(i, 0.3)]
        for i in near:
            d, p1, p2 = pairs.distance(i, 0.3)
            if not 1e-3 < d < 0.3:
                continue  # FD across the contact switch or beyond the cap is not a derivative
            g = np.zeros(sim.n)
            assert pairs.gradient(i, d, p1, p2, g)
            fd = np.zeros(sim.n)
            h = 1e-6
            for k in range(sim.n):
                e = np.zeros(sim.n)
                e[k] = h
                pairs.pose_joints(q + e)
                dp = pairs.distance(i, 0.5)[0]
                pairs.pose_joints(q - e)
                dm = pairs.distance(i, 0.5)[0]
                fd[k] = (dp - dm) / (2 * h)
            pairs.pose_joints(q)
            # curved surfaces (sphere, capsules) make the witness-point gradient exact to first order
            assert np.allclose(g, fd, atol=2e-4 + 1e-3 * np.abs(fd).max()), (pairs.pairs[i], g, fd)
            checked += 1
            if sim.m.geom_bodyid[pairs.pairs[i][0]] in finger2 and abs(fd[spread]) > 1e-3:
                through_equality += 1
    assert checked >= 20, checked
    assert through_equality >= 2, through_equality


def test_posed_couplings_satisfy_the_models_own_equality_constraints(ihy):
    # MuJoCo's constraint residuals (efc_pos of the equality rows) are the independent reference
    # for where `Sim.couple` puts the coupled joints
    sim = ihy
    rng = np.random.default_rng(11)
    assert sim.equalities, "the iHY's spread pair is a rigid equality"
    for _ in range(5):
        sim.set_posture(rng.uniform(sim.lower, sim.upper))
        rows = [r for r in range(sim.d.nefc) if sim.d.efc_type[r] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)]
        assert len(rows) == len(sim.equalities)
        assert max(abs(sim.d.efc_pos[r]) for r in rows) < 1e-12


def test_the_projection_is_the_nearest_admissible_command():
    # one half-space u1 + u2 >= 1 from u0 = 0: the foot of the perpendicular, (0.5, 0.5)
    a = np.array([[1.0, 1.0]])
    u = np.zeros(2)
    assert S.project(a, np.array([1.0]), np.array([10.0, 10.0]), u, 64)
    assert np.allclose(u, [0.5, 0.5], atol=1e-12)
    # with |u1| <= 0.2 the nearest admissible point is (0.2, 0.8)
    u = np.zeros(2)
    S.project(a, np.array([1.0]), np.array([0.2, 10.0]), u, 200)
    assert np.allclose(u, [0.2, 0.8], atol=1e-9), u
    # two half-spaces meeting at a corner: u1 >= 1, u2 >= 2 from (0, 0) -> (1, 2)
    u = np.zeros(2)
    S.project(np.eye(2), np.array([1.0, 2.0]), np.array([10.0, 10.0]), u, 64)
    assert np.allclose(u, [1.0, 2.0], atol=1e-12)
    # an admissible command is left alone and no row is active
    u = np.array([3.0, 0.0])
    assert not S.project(a, np.array([1.0]), np.array([10.0, 10.0]), u, 64)
    assert np.allclose(u, [3.0, 0.0])


def test_the_filter_stops_a_command_into_the_table_at_its_margin(ihy):
    """A command driving the hand straight down: integrated through the filter, the closest
    pair never comes closer than the margin less the braking overshoot of one control period,
    and the unfiltered command would have gone through the table."""
    sim = ihy
    q = hand_beside_ball(sim)
    f = S.SafetyFilter(sim, SPEC, [q], sim.vlimit)
    # the joint velocity that moves the palm down at 0.3 m/s (arm Jacobian, least squares),
    # integrated for 3 s with and without the filter
    kd = mujoco.MjData(sim.m)
    jp = np.zeros((3, sim.m.nv))
    jr = np.zeros((3, sim.m.nv))
    support = [i for i, (_, s) in enumerate(f.p.pairs) if s == sim.b.support_geom]

    def run(filtered):
        q_cur = q.copy()
        lowest = math.inf
        for _ in range(300):
            kd.qpos[:] = sim.d.qpos
            kd.qpos[sim.qadr] = q_cur
            mujoco.mj_kinematics(sim.m, kd)
            mujoco.mj_comPos(sim.m, kd)
            mujoco.mj_jacBody(sim.m, kd, jp, jr, sim.b.hand_body)
            J = np.vstack([jp[:, sim.vadr], jr[:, sim.vadr]])
            u = np.linalg.lstsq(J, np.array([0, 0, -0.3, 0, 0, 0]), rcond=None)[0]
            if filtered:
                u = f.filter(kd.qpos, u, 0.0)
            q_cur = np.clip(q_cur + u * 0.01, sim.lower, sim.upper)
            f.p.pose_joints(q_cur)
            lowest = min(lowest, min(f.p.distance(i, 0.5)[0] for i in support))
        return lowest

    assert run(False) < 0.0  # the plain command goes into the table
    lowest = run(True)
    # kept at the 2 cm margin, less the discretisation of a 10 ms control period
    assert 0.019 < lowest < 0.025, lowest
    assert f.filtered > 0


def test_a_path_the_filter_admits_is_left_alone_when_its_reference_is_given(ihy):
    """The hand brought down to within the margin of the table along a path (joint line,
    minimum-jerk clock over 1 s), its goal admitted (the pair may come as close as it is
    there): run exactly on the path, the plain barrier still brakes the command as the path
    nears its goal (`dh/dt >= -alpha h` while the path's approach rate over h grows without
    bound), while with the path's reference the command is the path's own velocity (the
    pair may approach as fast as it does on the path)."""
    sim = ihy
    q0 = hand_beside_ball(sim)
    # the first palm height whose closest link is 3-15 mm above the table
    q1 = lowered(sim, q0, np.arange(0.29, 0.0, -0.005), 0.003, 0.015)
    assert q1 is not None

    dt, steps = 0.01, 100

    def at(k):
        s = k / steps
        x = 10 * s**3 - 15 * s**4 + 6 * s**5
        dx = (30 * s**2 - 60 * s**3 + 30 * s**4) / (steps * dt)
        return q0 + x * (q1 - q0), dx * (q1 - q0)

    def worst_change(with_reference):
        f = S.SafetyFilter(sim, SPEC, [q1], sim.vlimit)
        qpos = sim.d.qpos.copy()
        worst = 0.0
        for k in range(steps):
            qk, vk = at(k)
            sim.couple(qpos, qk)
            u = f.filter(qpos, vk, k * dt, qk if with_reference else None, dt)
            worst = max(worst, float(np.max(np.abs(u - vk))))
        return worst, f.filtered

    plain, plain_filtered = worst_change(False)
    along, _ = worst_change(True)
    assert plain_filtered > 0 and plain > 0.05, (plain, plain_filtered)
    assert along < 1e-6, along
