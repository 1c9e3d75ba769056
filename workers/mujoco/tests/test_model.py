"""The MuJoCo model of each bundled system against independent references: the service's own
forward kinematics (`POST /v1/robots/{id}/fk`, the Rust kinematics) at random postures, and the
URDF's `<mimic>` numbers for the couplings; bad robots and scenes refused naming the element."""

import math

import mujoco
import numpy as np
import pytest

from reachgrasp_mujoco import build as B
from reachgrasp_mujoco import urdf as U
from reachgrasp_mujoco.scene import SceneError, parse_scene
from reachgrasp_mujoco.sim import Sim

SYSTEMS = ["wam_t42", "wam_ihy", "wam_ob4f", "pa10_t42", "pa10_ihy", "pa10_ob4f"]


def load(service, robot):
    detail = service.get(f"/v1/robots/{robot}")
    import urllib.request

    with urllib.request.urlopen(f"{service.http}/v1/robots/{robot}/urdf") as r:
        urdf = r.read().decode()
    return detail, urdf


def quat_angle(a, b):
    return 2 * math.acos(min(1.0, abs(float(np.dot(a, b)))))


@pytest.mark.parametrize("robot", SYSTEMS)
def test_kinematics_agree_with_the_service_fk_at_random_postures(service, robot):
    detail, urdf = load(service, robot)
    info = B.SystemInfo.from_detail(detail)
    built = B.build(urdf, info, None)
    sim = Sim(built)
    rng = np.random.default_rng(11)
    frames = detail["frames"]
    worst_p = worst_r = 0.0
    for _ in range(5):
        q = rng.uniform(sim.lower, sim.upper)
        sim.set_posture(q)
        status, fk = service.post(
            f"/v1/robots/{robot}/fk", {"joint_names": info.joint_names, "positions": q.tolist()}
        )
        assert status == 200, fk
        seen = 0
        for f in fk["frames"]:
            bid = mujoco.mj_name2id(built.model, mujoco.mjtObj.mjOBJ_BODY, f["name"])
            if bid < 0:
                continue
            seen += 1
            worst_p = max(worst_p, float(np.linalg.norm(sim.d.xpos[bid] - f["position"])))
            worst_r = max(worst_r, quat_angle(sim.d.xquat[bid], np.array(f["orientation"])))
        # every link of the URDF is a body: all fingertip frames and the wrist among them
        assert seen >= len(frames) - 1, (seen, len(frames))
        for fg in info.fingers:
            assert mujoco.mj_name2id(built.model, mujoco.mjtObj.mjOBJ_BODY, fg["tip_frame"]) >= 0
    assert worst_p < 1e-9 and worst_r < 1e-7, (worst_p, worst_r)


@pytest.mark.parametrize("robot", ["wam_t42", "wam_ihy", "wam_ob4f"])
def test_mimic_couplings_hold_in_free_motion(service, robot):
    """Commanding the independent joints in free space, every follower settles at
    multiplier x leader + offset as the URDF's <mimic> states."""
    detail, urdf = load(service, robot)
    info = B.SystemInfo.from_detail(detail)
    parsed = U.parse(urdf)
    built = B.build(urdf, info, None)
    sim = Sim(built)
    sim.set_posture(np.zeros(sim.n) + np.clip(0.0, sim.lower, sim.upper))
    target = sim.q()
    rng = np.random.default_rng(3)
    hand = ~sim.arm
    target[hand] = sim.lower[hand] + rng.uniform(0.25, 0.6, hand.sum()) * (sim.upper[hand] - sim.lower[hand])
    for _ in range(300):  # 3 s
        sim.set_reference(target, np.zeros(sim.n))
        sim.step_control()
    m = built.model
    qpos = lambda name: sim.d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)]]
    checked = 0
    for j in parsed.joints.values():
        if j.mimic is None:
            continue
        want = j.mimic.multiplier * qpos(j.mimic.joint) + j.mimic.offset
        assert abs(qpos(j.name) - want) < 2e-3, (j.name, qpos(j.name), want)
        checked += 1
    assert checked > 0
    # the independent hand joints reached their commands (the tendon servo's spring
    # compensation is exact in free motion)
    assert np.max(np.abs(sim.q()[hand] - target[hand])) < 2e-3, sim.q()[hand] - target[hand]


def test_a_robot_the_worker_cannot_build_is_refused_naming_the_element(service):
    detail, urdf = load(service, "wam_t42")
    info = B.SystemInfo.from_detail(detail)
    floating = urdf.replace('name="wam_joint3" type="revolute"', 'name="wam_joint3" type="floating"')
    with pytest.raises(B.BuildError, match="wam_joint3.*floating"):
        B.build(floating, info, None)
    meshed = urdf.replace(
        '<box size="0.0625 0.02 0.018"/>', '<mesh filename="package://t42/meshes/proximal.stl"/>', 1
    )
    assert meshed != urdf
    with pytest.raises(B.BuildError, match=r"link `t42_\w+`: collision mesh `package://t42/meshes/proximal.stl`"):
        B.build(meshed, info, None)
    with pytest.raises(B.BuildError, match="not well-formed"):
        B.build("<robot", info, None)


def test_a_scene_without_mass_or_friction_is_refused_naming_the_field():
    obj = {"name": "mug", "shape": {"type": "cylinder", "radius": 0.04, "height": 0.1},
           "position": [0.5, 0, 0.05], "orientation": [1, 0, 0, 0]}
    with pytest.raises(SceneError, match=r"scene.object.mass is missing"):
        parse_scene({"object": dict(obj, friction=0.5)})
    with pytest.raises(SceneError, match=r"scene.object.friction is missing"):
        parse_scene({"object": dict(obj, mass=0.2)})
    with pytest.raises(SceneError, match=r"scene.object.mass must be a positive number"):
        parse_scene({"object": dict(obj, mass=-1, friction=0.5)})
    # the worker's table fills seeded objects only, and says so
    with pytest.raises(SceneError, match="mass is missing"):
        parse_scene({"object": obj}, object_defaults=True)
    s = parse_scene({"object": dict(obj, name="bottle")}, object_defaults=True)
    assert s.provenance == "object-defaults" and s.object.mass == 0.52
