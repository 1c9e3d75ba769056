"""The bridge worker: connects out to `/v1/bridges/connect`, says hello, runs each `execute` in
MuJoCo (the motion, then the grasp trial when the execution has an object), streams feedback,
sends heartbeats, and reconnects with exponential backoff (0.2 s doubling to 5 s, jittered), as
the reference worker (`src/bridge/worker.rs`) does. Protocol version 1.

Scene of an execution, first found wins: the `scene` field of the `execute` message (not sent by
today's service, see the README); the stored plan the execution came from (`GET /v1/plans`);
else none (the motion runs without an object and no trial).
"""

from __future__ import annotations

import asyncio
import json
import logging
import random
import time
from dataclasses import dataclass, field

import numpy as np
import websockets
from websockets.asyncio.client import connect

from . import build as B
from .law import Law
from .run import Execution, ExecutionError, resolve_scene
from .scene import SceneError
from .service import Service, ServiceError, http_base
from .sim import PushOptions, RunOptions, TrialOptions

PROTOCOL_VERSION = 1
log = logging.getLogger("reachgrasp_mujoco")


def advance(run: Execution, periods: int):
    """Up to `periods` control periods of `run` (fewer when it ends): (outcome, periods run)."""
    out, n = None, 0
    while n < periods and out is None:
        out = run.tick()
        n += 1
    return out, n


class Refused(RuntimeError):
    """The service refused the token or the hello: stop for good."""


@dataclass
class WorkerConfig:
    url: str
    token: str
    name: str
    robot: str
    feedback_hz: float = 50.0
    pace: float = 1.0  # simulated seconds per wall second; 0 = as fast as possible
    run: RunOptions = field(default_factory=RunOptions)
    trial: TrialOptions = field(default_factory=TrialOptions)
    push: PushOptions | None = None
    object_defaults: bool = False
    trial_enabled: bool = True
    reset: str = "start"  # start | keep: robot posture after an execution with a trial
    report_dir: str | None = None
    max_executions: int = 0  # stop after this many (0 = never); for tests and surveys
    scene: dict | None = None  # `--scene` file: the scene of executions that bring none


class Worker:
    def __init__(self, cfg: WorkerConfig, detail: dict, urdf_text: str, service: Service | None):
        self.cfg = cfg
        self.info = B.SystemInfo.from_detail(detail)
        self.urdf = urdf_text
        self.service = service
        # The meshes uploaded with a registered system (none for the bundled ones).
        self.meshes = service.meshes(cfg.robot, urdf_text) if service is not None else {}
        # Build once without a scene: refuses (before any hello) a robot MuJoCo cannot build.
        self.robot_model = B.build(urdf_text, self.info, None, self.meshes.get)
        self.q = np.zeros(len(self.info.joint_names))
        lo = np.array([d.lower for d in self.robot_model.drives])
        hi = np.array([d.upper for d in self.robot_model.drives])
        self.q = np.where((lo <= 0) & (hi >= 0), 0.0, np.where(np.isfinite(lo), lo, 0.0))
        self.executed = 0
        self.current: Execution | None = None
        self.cancel_id = None
        self.end_id = None
        self.push_seed = cfg.push.seed if cfg.push else 0

    def hello(self):
        import mujoco

        return {
            "type": "hello",
            "protocol_version": PROTOCOL_VERSION,
            "worker": self.cfg.name,
            "robot": self.cfg.robot,
            "joint_names": self.info.joint_names,
            # `grasp_trial`: the service sends executions that end in a grasp trial (a plan's
            # `verify`) only to a worker that announces it; `--no-trial` does not.
            "capabilities": ["open_loop", "closed_loop", "safety_filter", "path_following", "streaming"]
            + (["grasp_trial"] if self.cfg.trial_enabled else []),
            # The service refuses a plan to execute that starts farther than this from our state.
            "start_tolerance": self.cfg.run.start_tolerance,
            # Ignored by the service (serde skips unknown fields): for logs and humans.
            "simulator": {"engine": "mujoco", "version": mujoco.__version__},
        }

    async def run_forever(self, stop: asyncio.Event):
        delay = 0.2
        headers = {"Authorization": f"Bearer {self.cfg.token}"}
        while not stop.is_set():
            try:
                async with connect(self.cfg.url, additional_headers=headers, max_size=2**26, open_timeout=10) as ws:
                    delay = 0.2
                    done = await self.session(ws, stop)
                    if done:
                        return
            except websockets.exceptions.InvalidStatus as e:
                code = e.response.status_code
                if code in (401, 403):
                    raise Refused(f"the service refused the token (HTTP {code})") from None
                log.warning("connection refused: HTTP %s", code)
            except Refused:
                raise
            except (OSError, websockets.exceptions.WebSocketException, asyncio.TimeoutError) as e:
                log.warning("bridge connection lost: %s", e)
            wait = delay * random.uniform(0.8, 1.2)
            try:
                await asyncio.wait_for(stop.wait(), wait)
            except asyncio.TimeoutError:
                pass
            delay = min(delay * 2, 5.0)

    async def session(self, ws, stop) -> bool:
        await ws.send(json.dumps(self.hello()))
        raw = await asyncio.wait_for(ws.recv(), 10)
        msg = json.loads(raw)
        if msg.get("type") == "error":
            if msg.get("code") in ("name_in_use", "shutting_down"):
                raise OSError(msg.get("message"))
            raise Refused(f"the service refused the hello: {msg.get('message')}")
        if msg.get("type") != "welcome":
            raise OSError(f"unexpected {msg.get('type')} before welcome")
        hb = max(msg.get("heartbeat_interval_ms", 1000), 10) / 1000.0
        log.info("connected to %s as %s", self.cfg.url, self.cfg.name)
        queue: asyncio.Queue = asyncio.Queue()
        send_lock = asyncio.Lock()

        async def send(m):
            async with send_lock:
                await ws.send(json.dumps(m))

        async def heartbeat():
            seq = 0
            while True:
                seq += 1
                q = self.current.sim.q() if self.current is not None else self.q
                await send({"type": "heartbeat", "seq": seq, "positions": [float(x) for x in q]})
                await asyncio.sleep(hb)

        async def receive():
            async for raw in ws:
                try:
                    m = json.loads(raw)
                except ValueError:
                    continue
                t = m.get("type")
                if t == "execute":
                    await queue.put(m)
                elif t == "setpoint":
                    cur = self.current
                    if cur is not None and cur.id == m.get("execution_id") and cur.streaming:
                        cur.motion.setpoint(m)
                elif t == "end":
                    if self.current is not None and self.current.id == m.get("execution_id"):
                        self.end_id = m.get("execution_id")
                elif t == "cancel":
                    if self.current is not None and self.current.id == m.get("execution_id"):
                        self.cancel_id = m.get("execution_id")
                elif t == "error":
                    log.warning("service error %s: %s", m.get("code"), m.get("message"))

        hb_task = asyncio.create_task(heartbeat())
        rx_task = asyncio.create_task(receive())
        stop_task = asyncio.create_task(stop.wait())
        try:
            while True:
                get = asyncio.create_task(queue.get())
                done, _ = await asyncio.wait({get, rx_task, stop_task}, return_when=asyncio.FIRST_COMPLETED)
                if get not in done:
                    get.cancel()
                    if stop_task in done:
                        await ws.close()
                        return True
                    raise OSError("connection closed")
                ex = get.result()
                await self.execute(ex, send, rx_task)
                self.executed += 1
                if self.cfg.max_executions and self.executed >= self.cfg.max_executions:
                    await ws.close()
                    return True
        finally:
            for t in (hb_task, rx_task, stop_task):
                t.cancel()

    async def execute(self, ex: dict, send, rx_task):
        eid = ex.get("execution_id")
        loop = asyncio.get_running_loop()
        try:
            scene = await loop.run_in_executor(None, resolve_scene, ex, self.cfg.robot, self.service, self.cfg.object_defaults, self.cfg.scene)
            push = None
            if self.cfg.push is not None:
                self.push_seed += 1
                push = PushOptions(**{**self.cfg.push.__dict__, "seed": self.push_seed})
            run = await loop.run_in_executor(
                None,
                lambda: Execution(
                    ex, self.urdf, self.info, scene, self.q, self.cfg.run,
                    self.cfg.trial if self.cfg.trial_enabled else None, push, self.meshes.get,
                ),
            )
        except (ExecutionError, SceneError, B.BuildError, ServiceError) as e:
            log.warning("execution %s refused: %s", eid, e)
            await send({"type": "result", "execution_id": eid, "outcome": "failed", "reason": str(e),
                        "positions": [float(x) for x in self.q]})
            return
        self.current = run
        log.info("executing %s (%s, scene: %s)", eid, ex.get("mode"), run.scene_note)
        every = max(1, round(100.0 / self.cfg.feedback_hz))
        ticks = 0
        wall0 = time.monotonic()
        sim0 = run.sim.t
        # A stream's setpoints arrive in real time: simulated faster, the arm would see every
        # pause between two setpoints as a lost link.
        pace = self.cfg.pace if self.cfg.pace > 0 or not run.streaming else 1.0
        outcome = None
        try:
            while outcome is None:
                if rx_task.done():
                    raise OSError("connection closed during an execution")
                if self.cancel_id == eid:
                    outcome = ("aborted", "cancelled")
                    break
                if self.end_id == eid:
                    outcome = ("succeeded", None)
                    await send(run.feedback())
                    break
                # The simulation runs on a thread, never on the event loop: one control period
                # can take seconds (the grasp trial's lift path is hundreds of IK solves), and a
                # loop blocked that long sends no heartbeat, so a loaded machine used to lose the
                # connection and the execution mid-trial (`interrupted`). Paced runs step one
                # period at a time, unpaced ones up to the next feedback.
                batch = 1 if pace > 0 else every - ticks % every
                outcome, n = await loop.run_in_executor(None, advance, run, batch)
                ticks += n
                if ticks % every == 0 or outcome is not None:
                    await send(run.feedback())
                if pace > 0:
                    ahead = (run.sim.t - sim0) / pace - (time.monotonic() - wall0)
                    if ahead > 0:
                        await asyncio.sleep(ahead)
        finally:
            self.current = None
            self.cancel_id = None
            self.end_id = None
            # A simulated lab resets the scene: with an object, the robot is put back where the
            # execution started (the next plan starts there); without one it stays put.
            if self.cfg.reset == "start" and run.scene is not None and run.scene.object is not None:
                self.q = run.q_start.copy()
            else:
                self.q = run.sim.q()
        status, reason = outcome
        report = run.report(status, reason, wall=time.monotonic() - wall0)
        if self.cfg.report_dir:
            import os

            os.makedirs(self.cfg.report_dir, exist_ok=True)
            with open(os.path.join(self.cfg.report_dir, f"{eid}.json"), "w") as f:
                json.dump(report, f, indent=1)
        final, final_reason = run.final_outcome(status, reason)
        log.info("execution %s %s: %s", eid, final, final_reason or "")
        await send({
            "type": "result",
            "execution_id": eid,
            "outcome": final,
            "reason": final_reason,
            # Where the robot is now (after a reset, back at the start): the service takes these
            # as the measured state a next plan is checked against; where the motion ended is
            # in the report.
            "positions": [float(x) for x in self.q],
            # The safety filter's account (a law with a scene), as the reference worker sends it.
            **({"safety": report["safety"]} if report.get("safety") else {}),
            # The whole report; the service keeps the trial's verdict with the execution
            # (`tracking.physics`; README: protocol).
            "physics": report,
        })
