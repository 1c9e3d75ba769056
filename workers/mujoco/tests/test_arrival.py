"""When a motion has arrived (`sim.arrival`): within the goal tolerance and at rest; or, once the
settle time is over, at rest against the object it grasps and within the contact tolerance
(the hand's contact forces hold a servoed arm off its goal). The decision on measured states
given directly, so each case is known without the simulator."""

import numpy as np

from reachgrasp_mujoco.sim import RunOptions, arrival

GOAL = np.zeros(4)  # two arm joints, two hand joints


class Measured:
    """What `arrival` reads of a simulation: joint state, which joints are the arm's, and the
    robot's contacts with the object (geom, normal force N)."""

    def __init__(self, q, qd=(0.0, 0.0, 0.0, 0.0), touching=()):
        self._q, self._qd = np.asarray(q, float), np.asarray(qd, float)
        self.arm = np.array([True, True, False, False])
        self.touching = list(touching)
        self.arrival_errors = None

    def q(self):
        return self._q

    def qd(self):
        return self._qd

    def object_contacts(self):
        return self.touching, True


O = RunOptions()  # goal 0.01 rad, contact 0.03 rad, at rest below 0.05 rad/s, settle 2 s


def test_within_the_goal_tolerance_and_at_rest_has_arrived_at_once():
    s = Measured([0.009, 0.0, 0.2, 0.0])  # the hand's error is not judged
    assert arrival(s, GOAL, O, waited=0.0, allowed=2.0) == ("succeeded", None)
    assert "in_contact" not in s.arrival_errors


def test_held_off_by_the_object_it_arrives_when_the_settle_time_is_over():
    s = Measured([0.018, -0.004, 0.06, 0.0], qd=[0.02, 0.0, 0.0, 0.0], touching=[(7, 30.0), (9, 12.5)])
    # while the settle time runs, it may still reach the goal: wait
    assert arrival(s, GOAL, O, waited=1.0, allowed=2.0) is None
    assert arrival(s, GOAL, O, waited=2.0, allowed=2.0) == ("succeeded", None)
    assert s.arrival_errors == {"arm_rad": 0.018, "hand_rad": 0.06, "in_contact": True, "contact_force_n": 42.5}


def test_off_the_goal_without_touching_the_object_fails():
    # e.g. the fingers on the table, or a servo too weak for the arm
    s = Measured([0.018, 0.0, 0.0, 0.0])
    out = arrival(s, GOAL, O, waited=2.0, allowed=2.0)
    assert out[0] == "failed" and "arm error 0.0180 rad" in out[1], out


def test_touching_but_beyond_the_contact_tolerance_fails():
    # a collision with the object, not a grasp's contact
    s = Measured([0.031, 0.0, 0.0, 0.0], touching=[(7, 80.0)])
    assert arrival(s, GOAL, O, waited=2.0, allowed=2.0)[0] == "failed"


def test_touching_but_still_moving_fails():
    s = Measured([0.018, 0.0, 0.0, 0.0], qd=[0.0, 0.06, 0.0, 0.0], touching=[(7, 10.0)])
    assert arrival(s, GOAL, O, waited=2.0, allowed=2.0)[0] == "failed"
