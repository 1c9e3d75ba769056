"""The grasp trial's verdict on cases whose outcome is known without the simulator's help:
a T42 pinch of a light block between its distal phalanges, whose hold Coulomb's law decides
(friction capacity 2 mu N against the weight m g), and objects the hand never grasps."""

import mujoco
import numpy as np
import pytest

from reachgrasp_mujoco import build as B
from reachgrasp_mujoco.scene import parse_scene
from reachgrasp_mujoco.sim import CONTROL_DT, Sim, Trial, TrialOptions

from test_model import load

# Hand pointing straight down above (0.5, 0), fingertips 19 mm above the table: the open T42's
# distal phalanges straddle a block 48 mm wide (their inner faces are 50 mm apart).
HAND_P = np.array([0.5, 0.0, 0.2055])


@pytest.fixture(scope="module")
def t42(service):
    detail, urdf = load(service, "wam_t42")
    info = B.SystemInfo.from_detail(detail)
    q = Sim(B.build(urdf, info, None)).hand_pointing_down(HAND_P)
    return urdf, info, q


def trial(t42, obj, support=True, opts=None, each=None):
    """The trial of the T42 pinch on `obj`; `each(sim, trial)` after every control period."""
    urdf, info, q = t42
    scene = parse_scene({"object": obj, "support": {"normal": [0, 0, 1], "offset": 0.0} if support else None})
    sim = Sim(B.build(urdf, info, scene))
    sim.set_posture(q)
    tr = Trial(sim, opts or TrialOptions())
    out = None
    while out is None:
        out = tr.tick()
        if each is not None:
            each(sim, tr)
    return out, sim


def tendon_force(sim):
    """The largest force of the T42's two tendon actuators now (N m)."""
    tendons = [dr.actuator_id for dr in sim.b.drives if dr.tendon_id >= 0]
    assert len(tendons) == 2
    return max(abs(sim.d.actuator_force[a]) for a in tendons)


def block(mu, mass=0.1, at=(0.5, 0.0, 0.025)):
    return {"name": "block", "shape": {"type": "box", "size": [0.048, 0.04, 0.05]},
            "position": list(at), "orientation": [1, 0, 0, 0], "mass": mass, "friction": mu}


def test_a_pinch_with_ample_friction_holds_through_lift_hold_and_shakes(t42):
    out, _ = trial(t42, block(0.8))
    assert out["held"], out
    assert all(out["held_after"].values()), out["held_after"]
    assert abs(out["object_lift_m"] - 0.10) < 0.01, out
    assert not out["slipped"] and out["slip_m"] < 0.01, out
    assert set(out["contacts_after_close"]) == {"t42_left_distal", "t42_right_distal"}
    # Coulomb: the pads' friction capacity (mu x total normal force) carries the weight
    weight = 0.1 * 9.81
    assert 0.8 * out["contact_force_total_mean_n"] > weight, out
    assert out["max_penetration_m"]["hand_object"] < 0.002, out


def test_a_pinch_without_friction_to_carry_the_weight_drops_the_object(t42):
    """mu = 0.005: even the largest normal force the tendon can make (1.5 N m at both joints,
    the contact at least 15 mm from the distal joint: N <= 100 N per pad) gives a friction
    capacity of 2 x 0.005 x 100 = 1 N < the block's weight 1.96 N (0.2 kg)."""
    out, _ = trial(t42, block(0.005, mass=0.2))
    assert not out["held"], out
    assert out["object_lift_m"] < 0.02, out
    assert out["slipped"]


def test_an_object_the_hand_never_reaches_stays_on_the_table(t42):
    out, _ = trial(t42, block(0.8, at=(0.8, 0.0, 0.025)))
    assert not out["held"]
    assert out["contacts_after_close"] == []
    assert abs(out["object_lift_m"]) < 1e-3


def test_an_object_with_no_grasp_falls(t42):
    """No support and the block below the fingertips, out of their reach: it falls."""
    out, sim = trial(t42, block(0.8, at=(0.5, 0.0, -0.05)), support=False)
    assert not out["held"]
    # fell freely for the whole trial (~6 s): far below where it started
    assert out["object_lift_m"] < -1.0, out


def test_the_trial_moves_the_hand_without_velocity_steps(t42):
    """The hand root's reference path (lift, hold, shakes, settle) has no velocity step: its
    second differences stay within the shakes' peak acceleration, 6.3 m/s^2 at 2 Hz (a shake
    that starts or stops at speed is a step of 0.5 m/s in one 10 ms control period, 50 m/s^2),
    and each shake reaches that peak."""
    urdf, info, q = t42
    sim = Sim(B.build(urdf, info, None))
    sim.set_posture(q)
    tr = Trial(sim, TrialOptions())
    path = np.array([np.zeros(3)] + [off for _, off in tr.plan])
    acc = np.linalg.norm(np.diff(path, 2, axis=0), axis=1) / CONTROL_DT**2
    assert acc.max() <= 6.4, acc.max()
    phases = np.array([p for p, _ in tr.plan])
    for s in ("shake1", "shake2"):
        k = np.flatnonzero(phases == s)
        assert acc[k[0] - 1 : k[-1]].max() >= 6.0, s


def test_the_lift_keeps_the_hand_pose_with_a_joint_at_its_limit(t42):
    """A 7-joint arm with one joint locked at its limit still has six for the hand's 6-D pose:
    the trial's lift IK reaches every pose of a 10 cm lift exactly (orientation kept) and never
    passes a limit. Here the WAM's wrist joint 6 sits on its upper limit and the lift pushes it
    outwards; clipping its share of each step instead left the hand 1.7 mm off."""
    urdf, info, _ = t42
    sim = Sim(B.build(urdf, info, None))
    q = np.array([-0.912, 1.7, 0.895, 2.712, -3.873, 1.6, -0.096, 0.04, 0.01])
    assert q[5] == sim.upper[5]
    sim.set_posture(q)
    lift = [np.array([0.0, 0.0, 0.1 * k / 50]) for k in range(1, 51)]
    path, worst = sim.arm_ik_path(q, lift)
    assert worst < 1e-6, worst
    P = np.array(path)
    assert (P >= sim.lower - 1e-12).all() and (P <= sim.upper + 1e-12).all()
    # one point per control period, no joint faster than its velocity limit
    steps = np.abs(np.diff(np.vstack([q, P]), axis=0))
    assert (steps <= sim.vlimit * CONTROL_DT + 1e-12).all()
    # the hand really rose 10 cm with its orientation kept (FK of the last posture)
    kd = mujoco.MjData(sim.m)

    def hand(qq):
        kd.qpos[:] = 0
        kd.qpos[sim.qadr] = qq
        mujoco.mj_kinematics(sim.m, kd)
        return kd.xpos[sim.b.hand_body].copy(), kd.xmat[sim.b.hand_body].reshape(3, 3).copy()

    (p0, R0), (p1, R1) = hand(q), hand(P[-1])
    assert np.allclose(p1 - p0, [0, 0, 0.1], atol=1e-6), p1 - p0
    assert np.allclose(R1, R0, atol=1e-6)


@pytest.mark.parametrize("grip", [0.25, 0.5])
def test_the_hand_grips_with_its_share_of_the_tendon_force_limit(t42, grip):
    """The T42's tendons (effort 1.5 N m in the bundled URDF) pull with at most `grip` x 1.5 N m
    while the trial runs and reach it on the block (the servo's reference is past the contact);
    afterwards the model's limits are the URDF's again."""
    peak = [0.0]

    def record(sim, _):
        peak[0] = max(peak[0], tendon_force(sim))

    out, sim = trial(t42, block(0.8), opts=TrialOptions(grip=grip, slip_reflex=0.0), each=record)
    assert out["held"], out
    assert 0.95 * grip * 1.5 <= peak[0] <= grip * 1.5 + 1e-9, peak[0]
    for dr in sim.b.drives:
        if dr.tendon_id >= 0:
            assert list(sim.m.actuator_forcerange[dr.actuator_id]) == [-1.5, 1.5]


def test_the_grip_rises_to_the_full_limit_only_once_the_object_slips(t42):
    """A held block (mu 0.8, 0.1 kg) is lifted and held with the tendons within a quarter of
    their 1.5 N m limit (the shakes may move it 3 mm in the hand). A slippery one (mu 0.02,
    0.2 kg: at that quarter, N <= 25 N per pad by the bound above, a friction capacity of at most
    1 N against a weight of 1.96 N) must slip as the lift starts; from then on the tendons pull
    with the full 1.5 N m."""

    def run(obj):
        peaks = {"before": 0.0, "after": 0.0}

        def record(sim, tr):
            k = "before" if tr.grip_raised is None else "after"
            peaks[k] = max(peaks[k], tendon_force(sim))

        out, _ = trial(t42, obj, opts=TrialOptions(grip=0.25, slip_reflex=0.003), each=record)
        return out, peaks["before"], peaks["after"]

    out, before, after = run(block(0.8))
    assert out["held"] and out["grip_raised_in"] in (None, "shake1", "shake2", "settle"), out
    assert before <= 0.25 * 1.5 + 1e-9, before
    out, before, after = run(block(0.02, mass=0.2))
    assert out["grip_raised_in"] == "lift", out
    assert before <= 0.25 * 1.5 + 1e-9, before
    assert after >= 0.95 * 1.5, after


def test_an_idle_finger_is_left_as_it_is(t42):
    """A grasp's idle fingers (kept off the object by the service) are not closed: the trial
    closes the others only and holds the idle ones where the grasp put them. With the T42's left
    finger idle, the right one closes onto the block (about 0.1 rad, until the block stops it)
    while the left one's joint stays within 5 mrad of its grasp value (the block pressing on it)."""
    moved = {"left": 0.0, "right": 0.0}

    def each(sim, tr):
        if tr.phase != "close":
            return
        q = sim.q()
        for k, dr in enumerate(sim.b.drives):
            for side in moved:
                if dr.name == f"t42_{side}_proximal":
                    moved[side] = max(moved[side], abs(q[k] - tr.q_grasp[k]))

    out, _ = trial(t42, block(0.8), opts=TrialOptions(idle_fingers=("left",)), each=each)
    assert out["closing_joints"] and all("left" not in j for j in out["closing_joints"]), out
    assert moved["right"] > 0.05, moved
    assert moved["left"] < 0.005, moved


def test_the_execute_messages_idle_fingers_name_the_systems_fingers(t42):
    """`idle_fingers` from an `execute` message: names of the system's fingers, else a refusal
    naming the field."""
    from reachgrasp_mujoco.run import ExecutionError, idle_fingers

    _, info, _ = t42
    assert idle_fingers(["left"], info) == ("left",)
    for bad in (["thumb"], "left", [1]):
        with pytest.raises(ExecutionError, match="idle_fingers"):
            idle_fingers(bad, info)


def test_a_stored_plans_idle_fingers_reach_the_trial(t42):
    """Without a `scene` in the `execute` message the worker takes the scene from the stored
    plan the execution runs, and with it the plan's grasp's idle fingers, which the trial then
    leaves open (the execution's trial options)."""
    from reachgrasp_mujoco.run import resolve_scene

    class Stored:
        def plan_for_execution(self, robot, ex):
            return {"id": "p", "grasp": {"object": block(0.8), "result": {"idle_fingers": ["left"]}}}

    sc, note = resolve_scene({"execution_id": "e"}, "wam_t42", Stored(), True)
    assert note == "plan p" and sc.idle_fingers == ("left",)
    sc, _ = resolve_scene({"execution_id": "e", "scene": {"object": block(0.8)}}, "wam_t42", Stored(), True)
    assert sc.idle_fingers == ()
