"""Physics surveys against a running service (numbers for the README and the issue):

  survey.py grasps --http URL     grasp trial at each grasp's exact joint values:
                                   seeded objects x six systems x default tasks
  survey.py plans  --http URL --token T [--approach-standoff M] [--mode closed_loop]
                                   the same matrix as plans executed on MuJoCo workers
                                   (trajectory, then the trial), one worker per system
  survey.py fig5   --http URL     Q_DC-optimal grasp vs random feasible grasps (same object)
  survey.py pushes --http URL --token T [--runs 20]
                                   closed loop with pushes on the arm, then the trial
  survey.py rtf    --http URL --token T
                                   real-time factor of a 5 s plan with its grasp trial
  survey.py clearance --http URL  120 plans (six systems x seeded objects x default tasks x the
                                   zero and a bent-elbow start), not executed: feasibility, each
                                   trajectory replayed kinematically in MuJoCo as a second,
                                   independent clearance check (reachgrasp_mujoco/replay.py), and
                                   durations against the learned human duration

Default tasks: the README's two examples, force along z and velocity along y (maximised).
Mass and friction of the seeded objects: the worker's table (`--object-defaults`), since the
service stores none. Run it niced: `nice -n 10 .venv/bin/python survey.py ...`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from reachgrasp_mujoco.offline import grasp_trial, robot as robot_info  # noqa: E402
from reachgrasp_mujoco.replay import Replayer  # noqa: E402
from reachgrasp_mujoco.sim import TrialOptions  # noqa: E402
from reachgrasp_mujoco.service import Service, ServiceError  # noqa: E402

SYSTEMS = ["wam_t42", "wam_ihy", "wam_ob4f", "pa10_t42", "pa10_ihy", "pa10_ob4f"]
TASKS = {
    "force_z": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}],
    "velocity_y": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}],
}


def seeded(svc):
    """The service's seeded objects: name -> the object (id and spec)."""
    return {o["name"]: o for o in svc.get_json("/v1/objects") if o.get("seeded")}


def objects(svc):
    return {name: o["id"] for name, o in seeded(svc).items()}


def trial_options(a):
    """The trial as the command line sets it (grip, slip reflex)."""
    return TrialOptions(grip=a.grip, slip_reflex=a.slip_reflex)


def table(rows, key_a, key_b, ok):
    """Per `key_a` and per `key_b`: held / tried."""
    out = {}
    for k in (key_a, key_b):
        agg = {}
        for r in rows:
            a = agg.setdefault(r[k], [0, 0])
            a[1] += 1
            a[0] += 1 if ok(r) else 0
        out[k] = {n: f"{h}/{t}" for n, (h, t) in sorted(agg.items())}
    total = sum(1 for r in rows if ok(r))
    out["total"] = f"{total}/{len(rows)}"
    return out


def by_firmness(rows, ok):
    """The service's own prediction (a grasp's `exact.firm`) against the trial: held / tried of
    the firm rows per system and object, and of the rest in all."""
    firm = [r for r in rows if r.get("firm")]
    loose = [r for r in rows if not r.get("firm")]
    return {"held_of_firm": table(firm, "robot", "object", ok),
            "held_of_not_firm": f"{sum(1 for r in loose if ok(r))}/{len(loose)}"}


def zeros_start(svc, robot):
    return starts(svc.get_json(f"/v1/robots/{robot}")["joint_names"])["zero"]


def cmd_grasps(a):
    svc = Service(a.http)
    objs = seeded(svc)
    rows = []
    for robot in a.systems.split(","):
        for oname, obj in objs.items():
            for tname, task in TASKS.items():
                body = {"robot": robot, "object_id": obj["id"], "task_directions": task}
                if a.placement is not None:
                    # the seeded object elsewhere on the table (inline, same shape and height)
                    spec = dict(obj["spec"])
                    spec["position"] = [*a.placement, spec["position"][2]]
                    body = {"robot": robot, "object": spec, "task_directions": task}
                g = svc.post_json("/v1/grasps", body)
                row = {"robot": robot, "object": oname, "task": tname, "grasp": g["id"],
                       "feasible": g["result"]["feasible"],
                       "firm": g["result"]["exact"].get("firm", False)}
                if row["feasible"]:
                    t = grasp_trial(svc, g, True, trial_options(a))
                    row.update({k: t[k] for k in ("held", "slip_m", "object_lift_m", "initial_penetration_m",
                                                   "contacts_after_close", "contact_force_total_mean_n",
                                                   "real_time_factor")})
                rows.append(row)
                print(json.dumps(row), flush=True)
    feas = [r for r in rows if r["feasible"]]
    summary = {"feasible": f"{len(feas)}/{len(rows)}",
               "held_of_feasible": table(feas, "robot", "object", lambda r: r["held"]),
               **by_firmness(feas, lambda r: r["held"])}
    print(json.dumps({"summary": summary}, indent=1))


def start_worker(a, robot, report_dir, extra=()):
    log = open(Path(report_dir) / f"worker-{robot}.log", "w")
    cmd = [sys.executable, "-m", "reachgrasp_mujoco", "--robot", robot, "--url", a.ws, "--token", a.token,
           "--object-defaults", "--pace", "0", "--report-dir", report_dir, "--name", f"survey-{robot}",
           "--grip", str(a.grip), "--slip-reflex", str(a.slip_reflex), *extra]
    p = subprocess.Popen(cmd, cwd=HERE, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.time() + 60
    svc = Service(a.http)
    while time.time() < deadline:
        names = [b["name"] for b in svc.get_json("/v1/bridges")["items"] if b.get("connected")]
        if f"survey-{robot}" in names:
            return p
        if p.poll() is not None:
            raise RuntimeError(f"worker for {robot} exited: see {log.name}")
        time.sleep(0.3)
    raise RuntimeError(f"worker for {robot} did not connect")


def wait_execution(svc, eid, timeout=600):
    deadline = time.time() + timeout
    while time.time() < deadline:
        e = svc.get_json(f"/v1/executions/{eid}")
        if e["state"] not in ("queued", "running"):
            return e
        time.sleep(0.3)
    raise RuntimeError(f"execution {eid} did not finish")


def cmd_plans(a):
    svc = Service(a.http)
    objs = objects(svc)
    rows = []
    rep = tempfile.mkdtemp(prefix="rg-plans-")
    for robot in a.systems.split(","):
        w = start_worker(a, robot, rep)
        try:
            start = zeros_start(svc, robot)
            for oname, oid in objs.items():
                for tname, task in TASKS.items():
                    body = {"robot": robot, "object_id": oid, "task_directions": task, "start": start,
                            "execute": True, "worker": f"survey-{robot}"}
                    if a.approach_standoff is not None:
                        body["approach_standoff"] = a.approach_standoff
                    if a.mode is not None:
                        body["mode"] = a.mode
                    try:
                        p = svc.post_json("/v1/plans", body)
                    except ServiceError as e:
                        # refused, e.g. a closed-loop start outside the model's certified workspace
                        row = {"robot": robot, "object": oname, "task": tname, "plan": None, "feasible": False,
                               "reason": str(e)}
                        rows.append(row)
                        print(json.dumps(row), flush=True)
                        continue
                    row = {"robot": robot, "object": oname, "task": tname, "plan": p["id"], "feasible": p["feasible"],
                           "firm": p["grasp"]["result"]["exact"].get("firm", False)}
                    if p["feasible"] and p.get("execution_id"):
                        e = wait_execution(svc, p["execution_id"])
                        row["state"] = e["state"]
                        row["reason"] = e["reason"]
                        path = Path(rep) / f"{p['execution_id']}.json"
                        if path.exists():
                            r = json.loads(path.read_text())
                            t = r.get("trial") or {}
                            row["motion"] = r["motion"]["outcome"]
                            row["held"] = bool(t.get("held"))
                            row["slip_m"] = t.get("slip_m")
                            row["rtf"] = r.get("real_time_factor")
                            row["max_penetration_m"] = r.get("max_penetration_m")
                    else:
                        row["reason"] = p.get("reason")
                    rows.append(row)
                    print(json.dumps(row), flush=True)
        finally:
            w.terminate()
            w.wait(10)
    feas = [r for r in rows if r["feasible"]]
    summary = {"feasible_plans": f"{len(feas)}/{len(rows)}",
               "held_of_executed": table(feas, "robot", "object", lambda r: r.get("held", False)),
               "held_of_all": table(rows, "robot", "object", lambda r: r.get("held", False)),
               **by_firmness(feas, lambda r: r.get("held", False))}
    print(json.dumps({"summary": summary}, indent=1))


def cmd_fig5(a):
    """For each system and object: the Q_DC-optimal grasp (quality centroid_distance, default
    weights) and `--random` feasible grasps found with every cost weight zero (feasibility only,
    one start, seeds 1..), each tried in physics; reports held counts and Q_DC."""
    svc = Service(a.http)
    objs = objects(svc)
    rows = []
    for robot in a.systems.split(","):
        for oname in a.objects.split(","):
            oid = objs[oname]
            base = {"robot": robot, "object_id": oid, "quality": "centroid_distance"}
            g = svc.post_json("/v1/grasps", dict(base, starts=8))
            opt = None
            if g["result"]["feasible"]:
                t = grasp_trial(svc, g, True, trial_options(a))
                opt = {"held": t["held"], "q_dc": g["result"]["terms"]["q_dc"], "slip_m": t["slip_m"]}
            rnd = []
            seed = 1
            while len(rnd) < a.random and seed <= 4 * a.random:
                r = svc.post_json("/v1/grasps", dict(base, starts=1, seed=seed,
                                                     weights={"tc": 0, "gc": 0, "q": 0, "d": 0}))
                seed += 1
                if r["result"]["feasible"]:
                    t = grasp_trial(svc, r, True, trial_options(a))
                    rnd.append({"held": t["held"], "q_dc": r["result"]["terms"]["q_dc"], "slip_m": t["slip_m"]})
            row = {"robot": robot, "object": oname, "optimal": opt,
                   "random_held": f"{sum(x['held'] for x in rnd)}/{len(rnd)}",
                   "random_q_dc_median": sorted(x["q_dc"] for x in rnd)[len(rnd) // 2] if rnd else None}
            rows.append(row)
            print(json.dumps(row), flush=True)
    opt_h = sum(1 for r in rows if r["optimal"] and r["optimal"]["held"])
    opt_n = sum(1 for r in rows if r["optimal"])
    rh = sum(int(r["random_held"].split("/")[0]) for r in rows)
    rn = sum(int(r["random_held"].split("/")[1]) for r in rows)
    print(json.dumps({"summary": {"optimal_held": f"{opt_h}/{opt_n}", "random_held": f"{rh}/{rn}"}}, indent=1))


def cmd_pushes(a):
    """Closed-loop executions with pushes on the arm, then the grasp trial. `--case plan`: a plan
    (robot, object, force along z) from zero executed in closed loop, the law run along the
    plan's path through the worker's safety filter; `--case pinch`: to the T42 pinch of
    the reference block (reachgrasp_mujoco.cases) from `--height` above it, the law of the
    robot's default model."""
    from reachgrasp_mujoco.cases import BLOCK, pinch

    svc = Service(a.http)
    rep = tempfile.mkdtemp(prefix="rg-push-")
    extra = ["--push", "arm", "--push-force", str(a.force), "--seed", str(a.seed)]
    if a.case == "pinch":
        robot = "wam_t42"
        names, goal, pts = pinch(svc, robot, height=a.height)
        scene = Path(rep) / "block.json"
        scene.write_text(json.dumps(BLOCK))
        extra += ["--scene", str(scene), "--initial=" + ",".join(str(x) for x in pts[0]["positions"])]
        model = next(m["id"] for m in svc.get_json(f"/v1/models?robot={robot}")["items"] if m["status"] == "succeeded")
        goal = {"joint_names": names, "positions": list(goal)}
    else:
        robot = a.robot
    w = start_worker(a, robot, rep, extra)
    rows = []
    try:
        for i in range(a.runs):
            if a.case == "pinch":
                e = svc.post_json("/v1/executions", {"robot": robot, "mode": "closed_loop", "model_id": model,
                                                     "goal": goal, "worker": f"survey-{robot}"})
            else:
                # the plan executed in closed loop: the service sends the law with its scene and
                # the plan's path, which the worker runs through its safety filter
                p = svc.post_json("/v1/plans", {"robot": robot, "object_id": objects(svc)[a.object],
                                                "task_directions": TASKS["force_z"], "start": zeros_start(svc, robot),
                                                "execute": True, "mode": "closed_loop", "worker": f"survey-{robot}"})
                if not p["feasible"]:
                    raise RuntimeError(f"plan infeasible: {p['reason']}")
                e = {"id": p["execution_id"]}
            e = wait_execution(svc, e["id"])
            r = json.loads((Path(rep) / f"{e['id']}.json").read_text())
            t = r.get("trial") or {}
            pushes = r.get("pushes", [])
            row = {"run": i, "state": e["state"], "motion": r["motion"]["outcome"], "held": bool(t.get("held")),
                   "pushes": len(pushes), "max_deflection_rad": max([x["deflection_rad"] for x in pushes], default=0),
                   "sim_time_s": r["motion"]["sim_time_s"], "object_moved_m": r["motion"].get("object_moved_m"),
                   "reason": e["reason"]}
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        w.terminate()
        w.wait(10)
    conv = sum(1 for r in rows if r["motion"] == "succeeded")
    held = sum(1 for r in rows if r["motion"] == "succeeded" and r["held"])
    print(json.dumps({"summary": {"case": a.case, "converged": f"{conv}/{len(rows)}",
                                  "converged_and_held": f"{held}/{len(rows)}",
                                  "pushes": sum(r["pushes"] for r in rows),
                                  "median_max_deflection_rad": sorted(r["max_deflection_rad"] for r in rows)[len(rows) // 2]}},
                     indent=1))


def cmd_rtf(a):
    svc = Service(a.http)
    objs = objects(svc)
    rep = tempfile.mkdtemp(prefix="rg-rtf-")
    robot = a.robot
    w = start_worker(a, robot, rep)
    try:
        body = {"robot": robot, "object_id": objs[a.object], "task_directions": TASKS["force_z"],
                "start": zeros_start(svc, robot), "duration": 5.0, "execute": True, "worker": f"survey-{robot}"}
        out = []
        for _ in range(a.repeat):
            p = svc.post_json("/v1/plans", body)
            e = wait_execution(svc, p["execution_id"])
            r = json.loads((Path(rep) / f"{e['id']}.json").read_text())
            out.append({"plan_duration_s": p["trajectory"]["points"][-1]["t"], "sim_time_s": r["sim_time_s"],
                        "wall_time_s": r["wall_time_s"], "real_time_factor": r["real_time_factor"],
                        "held": (r.get("trial") or {}).get("held")})
            print(json.dumps(out[-1]), flush=True)
    finally:
        w.terminate()
        w.wait(10)
    print(json.dumps({"uptime": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()}))


# A bent-elbow ready pose (the arm's first seven joints; the hand open at zero), 0.2 m or more
# from every seeded object on all six systems (MuJoCo distances). The pose the service's push
# test starts the WAM from, [0, 0.5, 0, 2.0, 0, 0.3, 0], puts the PA10 hands 13-35 mm inside the
# bottle: a start the service refuses (422), not a ready pose.
BENT_ELBOW = [0.0, 0.4, 0.0, 1.6, 0.0, 0.5, 0.0]


def starts(names):
    """The survey's starts for a robot with joints `names`: the zero posture and the bent elbow."""
    bent = [0.0] * len(names)
    bent[:7] = BENT_ELBOW
    return {"zero": {"joint_names": names, "positions": [0.0] * len(names)},
            "bent_elbow": {"joint_names": names, "positions": bent}}


def cmd_clearance(a):
    """Plans the matrix without executing; replays every returned trajectory kinematically in
    MuJoCo (an independent collision check) and tabulates feasibility, the deepest forbidden
    overlap and durations."""
    svc = Service(a.http, timeout=120.0)
    objs = {n: o for n, o in seeded(svc).items() if n in a.objects.split(",")}
    rows = []
    for robot in a.systems.split(","):
        info, urdf_text = robot_info(svc, robot)
        meshes = svc.meshes(robot, urdf_text).get
        replayers = {}
        for sname, start in starts(info.joint_names).items():
            for oname, o in objs.items():
                for tname, task in TASKS.items():
                    body = {"robot": robot, "object_id": o["id"], "task_directions": task, "start": start}
                    row = {"robot": robot, "object": oname, "task": tname, "start": sname}
                    try:
                        p = svc.post_json("/v1/plans", body)
                    except ServiceError as e:
                        row.update(feasible=False, refused=True, reason=str(e)[:300])
                        rows.append(row)
                        print(json.dumps(row), flush=True)
                        continue
                    row.update(feasible=p["feasible"], reason=p.get("reason"))
                    tr = p.get("trajectory")
                    if tr is not None:
                        rep = tr["report"]
                        cl = rep.get("clearance") or {}
                        row["service_collision_free"] = cl.get("collision_free")
                        row["duration_s"] = rep["duration"]
                        row["learned_s"] = rep["learned_duration"]
                        row["time_optimal_s"] = rep.get("time_optimal_duration")
                        if oname not in replayers:
                            replayers[oname] = Replayer(info, urdf_text, p["grasp"]["object"], None, meshes)
                        r = replayers[oname].replay(tr["joint_names"], tr["points"], cl.get("closing_from_s"))
                        row["replay"] = r.json()
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    feas = [r for r in rows if r["feasible"]]
    traj = [r for r in feas if "replay" in r]
    over = [r for r in traj if r["replay"]["counted_max_m"] > 1e-3]
    ratio = [r["duration_s"] / r["learned_s"] for r in traj]
    opt = [r["time_optimal_s"] / r["learned_s"] for r in traj if r.get("time_optimal_s")]
    permit = [r for r in traj if r.get("time_optimal_s") and r["time_optimal_s"] <= 1.5 * r["learned_s"]]
    summary = {
        "feasible": table(rows, "robot", "object", lambda r: r["feasible"]),
        "feasible_by_start": table(rows, "start", "task", lambda r: r["feasible"]),
        "refused_at_request": [f"{r['robot']} {r['object']} {r['task']} {r['start']}: {r['reason']}"
                               for r in rows if r.get("refused")],
        "feasible_trajectories_over_1mm_in_replay": f"{len(over)}/{len(traj)}",
        "deepest_forbidden_overlap_m": max((r["replay"]["counted_max_m"] for r in traj), default=None),
        "over_1mm": [{k: r[k] for k in ("robot", "object", "task", "start")} | {"replay": r["replay"]} for r in over],
        "service_and_replay_disagree": [
            {k: r[k] for k in ("robot", "object", "task", "start")}
            for r in rows if "replay" in r
            and r.get("service_collision_free") is not None
            and r["service_collision_free"] != (r["replay"]["counted_max_m"] <= 1e-3)],
        "duration_over_learned_median": statistics.median(ratio) if ratio else None,
        "within_1_5x_learned": f"{sum(x <= 1.5 for x in ratio)}/{len(ratio)}",
        "velocity_acceleration_optimum_over_learned_median": statistics.median(opt) if opt else None,
        "optimum_within_1_5x": len(permit),
        "within_1_5x_where_the_optimum_is": f"{sum(r['duration_s'] <= 1.5 * r['learned_s'] for r in permit)}/{len(permit)}",
    }
    print(json.dumps({"summary": summary}, indent=1))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cmd", choices=["grasps", "plans", "fig5", "pushes", "rtf", "clearance"])
    ap.add_argument("--http", default="http://127.0.0.1:8080")
    ap.add_argument("--token", default=os.environ.get("REACHGRASP_BRIDGE_TOKEN"))
    ap.add_argument("--systems", default=",".join(SYSTEMS))
    ap.add_argument("--objects", default="ball,bottle,kitchen_timer,pencil,sunglasses")
    ap.add_argument("--random", type=int, default=4)
    ap.add_argument("--robot", default="wam_ihy")
    ap.add_argument("--object", default="ball")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--force", type=float, default=150.0)
    ap.add_argument("--case", choices=["plan", "pinch"], default="pinch")
    ap.add_argument("--height", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--grip", type=float, default=TrialOptions.grip,
                    help="share of the closing drives' force limit the trial grips with")
    ap.add_argument("--placement", type=lambda v: [float(x) for x in v.split(",")], default=None,
                    help="grasps: x,y of the seeded objects on the table (default: where they are seeded)")
    ap.add_argument("--slip-reflex", type=float, default=TrialOptions.slip_reflex,
                    help="object displacement in the hand (m) that raises the grip; 0 = none")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mode", choices=["open_loop", "closed_loop"], default=None,
                    help="plans: execution mode (default: the service's, open loop)")
    ap.add_argument("--approach-standoff", type=float, default=None,
                    help="plans: the pre-grasp standoff (m) to ask for (default: the service's)")
    a = ap.parse_args()
    a.ws = a.http.replace("http://", "ws://").replace("https://", "wss://") + "/v1/bridges/connect"
    {"grasps": cmd_grasps, "plans": cmd_plans, "fig5": cmd_fig5, "pushes": cmd_pushes, "rtf": cmd_rtf,
     "clearance": cmd_clearance}[a.cmd](a)


if __name__ == "__main__":
    main()
