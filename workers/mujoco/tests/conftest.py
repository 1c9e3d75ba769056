"""Fixtures: a reachgrasp service on a free loopback port with a temporary database.

The binary is `$REACHGRASP_BIN`, else the newer of `target/release/reachgrasp` and
`target/debug/reachgrasp` (the one `cargo test` builds); without one the service tests fail,
never skip, when CI=true.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
WORKER = HERE.parent
REPO = WORKER.parent.parent
sys.path.insert(0, str(WORKER))

TOKEN = "physics-test-token"


def binary():
    env = os.environ.get("REACHGRASP_BIN")
    if env:
        return env
    built = [p for p in (REPO / "target/release/reachgrasp", REPO / "target/debug/reachgrasp") if p.exists()]
    return str(max(built, key=lambda p: p.stat().st_mtime)) if built else None


class Service:
    def __init__(self, seed: bool):
        exe = binary()
        if exe is None:
            msg = "no reachgrasp binary (build it with cargo build, or set REACHGRASP_BIN)"
            if os.environ.get("CI") == "true":
                pytest.fail(msg)
            pytest.skip(msg)
        self.dir = tempfile.TemporaryDirectory(prefix="rg-phys-")
        env = dict(os.environ)
        env.update(
            REACHGRASP_BIND="127.0.0.1:0",
            REACHGRASP_DB=str(Path(self.dir.name) / "t.db"),
            REACHGRASP_ROBOTS=str(REPO / "robots"),
            REACHGRASP_BRIDGE_TOKEN=TOKEN,
            REACHGRASP_LOG="info",
            REACHGRASP_LOG_JSON="1",
        )
        if not seed:
            env["REACHGRASP_NO_SEED"] = "1"
        self.log = open(Path(self.dir.name) / "service.log", "w+")
        self.proc = subprocess.Popen([exe], env=env, stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 60
        self.addr = None
        while time.monotonic() < deadline and self.addr is None:
            time.sleep(0.1)
            self.log.seek(0)
            for line in self.log:
                m = re.search(r'"addr":"([0-9.:]+)"', line)
                if m and "listening" in line:
                    self.addr = m.group(1)
            if self.proc.poll() is not None:
                break
        if self.addr is None:
            self.log.seek(0)
            raise RuntimeError("the service did not start:\n" + self.log.read()[-3000:])
        self.http = f"http://{self.addr}"
        self.ws = f"ws://{self.addr}/v1/bridges/connect"

    def get(self, path):
        with urllib.request.urlopen(self.http + path, timeout=60) as r:
            return json.loads(r.read())

    def post(self, path, body):
        req = urllib.request.Request(
            self.http + path, data=json.dumps(body).encode(), method="POST",
            headers={"content-type": "application/json"},
        )
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read() or b"null")

    def close(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()
        self.dir.cleanup()


@pytest.fixture(scope="session")
def service():
    s = Service(seed=False)
    yield s
    s.close()


@pytest.fixture(scope="session")
def seeded_service():
    """A service whose first-start seeding has trained every bundled system's default model."""
    s = Service(seed=True)
    deadline = time.monotonic() + float(os.environ.get("PHYSICS_SEED_TIMEOUT", "1500"))
    while True:
        jobs = s.get("/v1/jobs?limit=200")
        items = jobs.get("items", jobs) if isinstance(jobs, dict) else jobs
        models = s.get("/v1/models?limit=100")
        mitems = models.get("items", models) if isinstance(models, dict) else models
        done = [m for m in mitems if m.get("status") == "succeeded"]
        failed = [j for j in items if j.get("status") == "failed"]
        if failed:
            raise RuntimeError(f"seeding failed: {failed[0]}")
        if len(done) >= 6:
            break
        if time.monotonic() > deadline:
            raise RuntimeError(f"seeding did not finish in time ({len(done)} models)")
        time.sleep(2)
    yield s
    s.close()
