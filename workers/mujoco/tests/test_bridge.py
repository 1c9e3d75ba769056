"""The physics worker headless against a live, seeded service: a plan executed to a held
object; the closed-loop law against the service's own `u(q)`; bad executions refused with the
reason while the worker keeps serving."""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import TOKEN, WORKER
from reachgrasp_mujoco.law import Law

# Today's plans do not hold in physics (README: 0 of 60 through the bridge, the grasps overlap
# the table and the motions have no approach phase; issues #18/#23). So the held execution is
# one the service forwards like any other: a trajectory descending straight onto a block until
# the T42's open distal phalanges straddle it (the pinch of test_trial.py), the block given to
# the worker with --scene; the trial then decides the execution's state in the service.
BLOCK = {"object": {"name": "block", "shape": {"type": "box", "size": [0.04, 0.04, 0.05]},
                    "position": [0.5, 0.0, 0.025], "orientation": [1, 0, 0, 0], "mass": 0.1, "friction": 0.8},
         "support": {"normal": [0, 0, 1], "offset": 0.0}}
BALL = "00000000-0000-4000-8000-000000000001"
FORCE_Z = [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]


class WorkerProc:
    def __init__(self, svc, robot, *extra, tag=""):
        self.name = f"pytest-{robot}{tag}-{os.getpid()}"
        self.reports = tempfile.mkdtemp(prefix="rg-phys-reports-")
        self.log = open(Path(self.reports) / "worker.log", "w+")
        cmd = [sys.executable, "-m", "reachgrasp_mujoco", "--robot", robot, "--url", svc.ws, "--token", TOKEN,
               "--name", self.name, "--pace", "0", "--object-defaults", "--report-dir", self.reports, *extra]
        self.proc = subprocess.Popen(cmd, cwd=WORKER, stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            bridges = svc.get("/v1/bridges")["items"]
            if any(b["name"] == self.name and b.get("connected") for b in bridges):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.2)
        self.log.seek(0)
        raise RuntimeError("the worker did not connect:\n" + self.log.read())

    def report(self, eid):
        return json.loads((Path(self.reports) / f"{eid}.json").read_text())

    def close(self):
        self.proc.terminate()
        self.proc.wait(10)


def wait(svc, eid, timeout=300):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        e = svc.get(f"/v1/executions/{eid}")
        if e["state"] not in ("queued", "running"):
            return e
        time.sleep(0.25)
    raise AssertionError(f"execution {eid} still {e['state']}")


def start(svc, robot):
    names = svc.get(f"/v1/robots/{robot}")["joint_names"]
    return {"joint_names": names, "positions": [0.0] * len(names)}


def descent(svc, robot="wam_t42", height=0.15, duration=3.0, n=150):
    """(start, points): the hand pointing down, from `height` above the pinch pose straight down
    onto it (arm IK along the vertical line, from the goal up so the path ends exactly there)."""
    import urllib.request

    from reachgrasp_mujoco import build as B
    from reachgrasp_mujoco.sim import Sim

    detail = svc.get(f"/v1/robots/{robot}")
    with urllib.request.urlopen(f"{svc.http}/v1/robots/{robot}/urdf") as r:
        urdf = r.read().decode()
    sim = Sim(B.build(urdf, B.SystemInfo.from_detail(detail), None))
    q0 = np.zeros(sim.n)
    q0[1], q0[3] = 0.8, 1.6
    sim.set_posture(q0)
    goal, err = sim.hand_pose_ik(q0, np.array([0.5, 0.0, 0.2055]), np.diag([1.0, -1.0, -1.0]))
    assert err < 1e-6
    sim.set_posture(goal)
    s = [k / n for k in range(n + 1)]
    offs = [np.array([0, 0, height * (10 * u**3 - 15 * u**4 + 6 * u**5)]) for u in s]
    path, err = sim.arm_ik_path(goal, offs)
    assert err < 1e-5
    path = np.array(path[::-1])
    dt = duration / n
    vel = np.gradient(path, dt, axis=0)
    vel[0] = vel[-1] = 0
    zero = [0.0] * sim.n
    pts = [{"t": k * dt, "positions": path[k].tolist(), "velocities": vel[k].tolist(), "accelerations": zero}
           for k in range(n + 1)]
    return detail["joint_names"], pts


@pytest.fixture(scope="module")
def pinch(seeded_service):
    names, pts = descent(seeded_service)
    scene = Path(tempfile.mkdtemp(prefix="rg-phys-scene-")) / "block.json"
    scene.write_text(json.dumps(BLOCK))
    w = WorkerProc(seeded_service, "wam_t42", "--scene", str(scene),
                   "--initial", ",".join(str(x) for x in pts[0]["positions"]), tag="-pinch")
    yield w, names, pts
    w.close()


@pytest.fixture(scope="module")
def t42_worker(seeded_service):
    w = WorkerProc(seeded_service, "wam_t42")
    yield w
    w.close()


def test_an_execution_in_physics_ends_with_the_object_held(seeded_service, pinch):
    w, names, pts = pinch
    status, ex = seeded_service.post("/v1/executions", {
        "robot": "wam_t42", "mode": "open_loop", "worker": w.name,
        "trajectory": {"joint_names": names, "points": pts}})
    assert status == 202, ex
    e = wait(seeded_service, ex["id"])
    rep = w.report(e["id"])
    assert e["state"] == "succeeded", (e["reason"], rep)
    assert rep["scene"]["source"] == "worker --scene file"
    assert rep["motion"]["outcome"] == "succeeded"
    assert max(abs(x) for x in rep["motion"]["object_moved_m"]) < 0.005, rep["motion"]
    t = rep["trial"]
    assert t["held"] and all(t["held_after"].values()), t
    assert abs(t["object_lift_m"] - 0.10) < 0.01 and not t["slipped"], t
    assert t["max_penetration_m"]["hand_object"] < 0.003, t
    # the service recorded the measured motion and the trial's stream
    assert e["feedback_samples"] > 10 and e["tracking"]["samples"] > 10


def test_a_plan_gets_its_scene_from_the_service_and_a_physics_verdict(seeded_service, t42_worker):
    """A real plan (wam_t42, ball, force along z): the worker finds the plan's object, runs the
    motion and the trial, and the execution's state is the verdict (succeeded only if held)."""
    svc = seeded_service
    status, plan = svc.post("/v1/plans", {
        "robot": "wam_t42", "object_id": BALL, "task_directions": FORCE_Z, "start": start(svc, "wam_t42"),
        "execute": True, "worker": t42_worker.name})
    assert status == 201 and plan["feasible"], plan
    e = wait(svc, plan["execution_id"])
    rep = t42_worker.report(e["id"])
    assert rep["scene"]["source"] == f"plan {plan['id']}"
    assert rep["scene"]["object"] == "ball" and rep["scene"]["properties_from"] == "object-defaults"
    held = bool(rep["trial"] and rep["trial"]["held"])
    assert (e["state"] == "succeeded") == held, (e["state"], e["reason"], rep["trial"])
    if rep["motion"]["outcome"] == "succeeded":
        assert rep["trial"] is not None and "held_after" in rep["trial"]
        if not held:
            assert e["reason"].startswith("grasp trial: object not held"), e["reason"]


def test_bad_executions_fail_with_the_reason_and_the_worker_keeps_serving(seeded_service, t42_worker):
    svc = seeded_service
    robot = "wam_t42"
    names = svc.get(f"/v1/robots/{robot}")["joint_names"]
    far = [0.0] * len(names)
    far[0] = 1.0  # the robot stands at zero: 1 rad from this trajectory's start
    traj = {"joint_names": names, "points": [
        {"t": 0.0, "positions": far, "velocities": [0.0] * len(names), "accelerations": [0.0] * len(names)},
        {"t": 1.0, "positions": far, "velocities": [0.0] * len(names), "accelerations": [0.0] * len(names)}]}
    status, ex = svc.post("/v1/executions", {"robot": robot, "mode": "open_loop", "trajectory": traj,
                                             "worker": t42_worker.name})
    assert status == 202, ex
    e = wait(svc, ex["id"])
    assert e["state"] == "failed" and "from the trajectory's start" in e["reason"], e
    # an inline trajectory has no scene: the motion runs in physics, no trial, succeeded
    zero = [0.0] * len(names)
    traj["points"] = [dict(p, positions=zero) for p in traj["points"]]
    traj["points"][1]["positions"] = [0.0, 0.3] + [0.0] * (len(names) - 2)
    status, ex = svc.post("/v1/executions", {"robot": robot, "mode": "open_loop", "trajectory": traj,
                                             "worker": t42_worker.name})
    e = wait(svc, ex["id"])
    assert e["state"] == "succeeded", e
    rep = t42_worker.report(e["id"])
    assert rep["trial"] is None and rep["scene"] is None


def test_the_closed_loop_law_matches_the_service(seeded_service):
    svc = seeded_service
    models = svc.get("/v1/models?robot=wam_ihy&limit=10")["items"]
    mid = next(m["id"] for m in models if m["status"] == "succeeded")
    params = svc.get(f"/v1/models/{mid}/params")
    law = Law(params)
    names = params["joint_names"]
    # states along a trajectory the model generates (inside its workspace), goal = its end
    status, plan = svc.post("/v1/plans", {"robot": "wam_ihy", "object_id": "00000000-0000-4000-8000-000000000001",
                                          "task_directions": FORCE_Z, "start": start(svc, "wam_ihy")})
    assert status == 201 and plan["feasible"], plan
    pts = plan["trajectory"]["points"]
    goal = plan["trajectory"]["goal"]
    assert plan["trajectory"]["joint_names"] == names
    worst = 0.0
    for p in pts[:: max(1, len(pts) // 8)]:
        q = np.asarray(p["positions"]) + 0.01  # off the path too
        status, r = svc.post(f"/v1/models/{mid}/control", {
            "q": {"joint_names": names, "positions": q.tolist()},
            "goal": {"joint_names": names, "positions": goal}})
        assert status == 200, r
        mine = law.control(q, goal)
        worst = max(worst, float(np.max(np.abs(mine - np.asarray(r["u"])))))
        scale = float(np.max(np.abs(r["u"])))
    assert worst < 1e-9 * max(1.0, scale), worst
