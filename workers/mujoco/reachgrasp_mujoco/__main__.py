"""`python -m reachgrasp_mujoco` (or `workers/mujoco/run-worker`): the MuJoCo bridge worker.

Sub-commands: `worker` (default) connects to the service and executes what it forwards;
`trial` runs the grasp trial of stored grasps or plans offline (no bridge), printing JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import sys
import time

from . import build as B
from .bridge import Refused, Worker, WorkerConfig
from .service import Service, ServiceError, http_base
from .sim import PushOptions, RunOptions, TrialOptions


def worker_args(p: argparse.ArgumentParser):
    p.add_argument("--robot", required=True, help="robot system id (GET /v1/robots)")
    p.add_argument("--url", default="ws://127.0.0.1:8080/v1/bridges/connect")
    p.add_argument("--token", default=os.environ.get("REACHGRASP_BRIDGE_TOKEN"))
    p.add_argument("--name", help="worker name (default mujoco-<robot>)")
    p.add_argument("--http", help="service base URL for robot and plan look-ups (default: from --url)")
    p.add_argument("--pace", type=float, default=1.0,
                   help="simulated seconds per wall-clock second (1 = real time, 0 = as fast as possible)")
    p.add_argument("--feedback-hz", type=float, default=50.0)
    p.add_argument("--no-trial", action="store_true", help="run the motion only, no grasp trial")
    p.add_argument("--grip", type=float, default=TrialOptions.grip,
                   help="share of the closing drives' force limit (URDF effort) the trial grips with")
    p.add_argument("--slip-reflex", type=float, default=TrialOptions.slip_reflex,
                   help="object displacement in the hand (m) after which the grip rises to the full limit; 0 = none")
    p.add_argument("--object-defaults", action="store_true",
                   help="fill a missing mass/friction of the service's seeded objects from the worker's table")
    p.add_argument("--push", choices=["arm", "object"], help="push the arm (closed loop) or the held object")
    p.add_argument("--push-force", type=float, default=150.0, help="N")
    p.add_argument("--push-duration", type=float, default=0.2, help="s")
    p.add_argument("--max-pushes", type=int, default=3)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--reset", choices=["start", "keep"], default="start",
                   help="after an execution with an object put the robot back where it started (start, a scene reset) or keep it")
    p.add_argument("--initial", help="initial joint positions, comma-separated in the robot's joint order "
                   "(default: 0 where allowed, else the nearest limit)")
    p.add_argument("--scene", help="JSON file: the scene ({object, support, obstacles}) of executions that "
                   "bring none and come from no stored plan (e.g. an inline trajectory)")
    p.add_argument("--report-dir", help="also write each execution's physics report here as <id>.json")
    p.add_argument("--max-executions", type=int, default=0, help="exit after this many executions")
    p.add_argument("--log", default="info")


def main(argv=None):
    ap = argparse.ArgumentParser(prog="reachgrasp_mujoco", description=__doc__)
    sub = ap.add_subparsers(dest="cmd")
    w = sub.add_parser("worker", help="run the bridge worker (default)")
    worker_args(w)
    t = sub.add_parser("trial", help="grasp trial of stored grasps at their exact joint values (no bridge)")
    t.add_argument("--http", default="http://127.0.0.1:8080")
    t.add_argument("--grasp", action="append", default=[], help="grasp id (repeatable)")
    t.add_argument("--object-defaults", action="store_true")
    t.add_argument("--log", default="warning")
    args_list = list(sys.argv[1:] if argv is None else argv)
    if not args_list or args_list[0] not in ("worker", "trial", "-h", "--help"):
        args_list = ["worker"] + args_list
    args = ap.parse_args(args_list)
    logging.basicConfig(level=getattr(logging, args.log.upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.cmd == "trial":
        from .offline import grasp_trial

        svc = Service(args.http)
        for gid in args.grasp:
            g = svc.get_json(f"/v1/grasps/{gid}")
            print(json.dumps(grasp_trial(svc, g, args.object_defaults)))
        return 0
    if not args.token:
        print("error: --token or REACHGRASP_BRIDGE_TOKEN is required", file=sys.stderr)
        return 2
    svc = Service(args.http or http_base(args.url))
    try:
        detail, urdf_text = svc.robot(args.robot)
    except ServiceError as e:
        print(f"error: cannot load robot `{args.robot}` from the service: {e}", file=sys.stderr)
        return 2
    push = None
    if args.push:
        push = PushOptions(target=args.push, force=args.push_force, duration=args.push_duration,
                           max_pushes=args.max_pushes, seed=args.seed)
    scene = None
    if args.scene:
        from .scene import SceneError, parse_scene

        try:
            with open(args.scene) as f:
                scene = json.load(f)
            parse_scene(scene, args.object_defaults)
        except (OSError, ValueError, SceneError) as e:
            print(f"error: --scene {args.scene}: {e}", file=sys.stderr)
            return 2
    cfg = WorkerConfig(
        url=args.url, token=args.token, name=args.name or f"mujoco-{args.robot}", robot=args.robot,
        feedback_hz=args.feedback_hz, pace=args.pace, run=RunOptions(), trial=TrialOptions(grip=args.grip, slip_reflex=args.slip_reflex), push=push,
        object_defaults=args.object_defaults, trial_enabled=not args.no_trial, reset=args.reset,
        report_dir=args.report_dir, max_executions=args.max_executions, scene=scene,
    )
    try:
        worker = Worker(cfg, detail, urdf_text, svc)
    except B.BuildError as e:
        # Refused before any hello: the service never sees a worker it could not drive.
        print(f"error: robot `{args.robot}` cannot be simulated: {e}", file=sys.stderr)
        return 3
    if args.initial:
        try:
            q0 = [float(x) for x in args.initial.split(",")]
        except ValueError:
            q0 = []
        if len(q0) != len(worker.info.joint_names):
            print(f"error: --initial needs {len(worker.info.joint_names)} numbers", file=sys.stderr)
            return 2
        import numpy as np

        lo = np.array([d.lower for d in worker.robot_model.drives])
        hi = np.array([d.upper for d in worker.robot_model.drives])
        worker.q = np.clip(np.array(q0), lo, hi)
    stop = asyncio.Event()

    async def go():
        loop = asyncio.get_running_loop()
        for s in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(s, stop.set)
        await worker.run_forever(stop)

    try:
        asyncio.run(go())
    except Refused as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    return 0


if __name__ == "__main__":
    sys.exit(main())
