"""The grasp trial's verdict on cases whose outcome is known without the simulator's help:
a T42 pinch of a light block between its distal phalanges, whose hold Coulomb's law decides
(friction capacity 2 mu N against the weight m g), and objects the hand never grasps."""

import mujoco
import numpy as np
import pytest

from reachgrasp_mujoco import build as B
from reachgrasp_mujoco.scene import parse_scene
from reachgrasp_mujoco.sim import Sim, Trial, TrialOptions

from test_model import load

# Hand pointing straight down above (0.5, 0), fingertips 19 mm above the table: the open T42's
# distal phalanges straddle a block 48 mm wide (their inner faces are 50 mm apart).
HAND_P = np.array([0.5, 0.0, 0.2055])
HAND_R = np.diag([1.0, -1.0, -1.0])


@pytest.fixture(scope="module")
def t42(service):
    detail, urdf = load(service, "wam_t42")
    info = B.SystemInfo.from_detail(detail)
    s0 = Sim(B.build(urdf, info, None))
    q0 = np.zeros(s0.n)
    q0[1], q0[3] = 0.8, 1.6
    s0.set_posture(q0)
    q, err = s0.hand_pose_ik(q0, HAND_P, HAND_R)
    assert err < 1e-6
    return urdf, info, q


def trial(t42, obj, support=True, opts=None):
    urdf, info, q = t42
    scene = parse_scene({"object": obj, "support": {"normal": [0, 0, 1], "offset": 0.0} if support else None})
    sim = Sim(B.build(urdf, info, scene))
    sim.set_posture(q)
    tr = Trial(sim, opts or TrialOptions())
    out = None
    while out is None:
        out = tr.tick()
    return out, sim


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
