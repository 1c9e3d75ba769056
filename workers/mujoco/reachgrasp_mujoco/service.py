"""The few HTTP calls the worker makes to the service (stdlib `urllib`, loopback or lab network):
the robot (`GET /v1/robots/{id}`, `GET /v1/robots/{id}/urdf`) and, while the `execute` message
does not carry the scene, the plan an execution came from (`GET /v1/plans`)."""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.parse
import urllib.request


class ServiceError(RuntimeError):
    pass


def http_base(ws_url: str) -> str:
    u = urllib.parse.urlparse(ws_url)
    scheme = {"ws": "http", "wss": "https"}.get(u.scheme, u.scheme)
    return f"{scheme}://{u.netloc}"


class Service:
    def __init__(self, base: str, timeout: float = 30.0):
        self.base = base.rstrip("/")
        self.timeout = timeout

    def _req(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method)
        if data is not None:
            req.add_header("content-type", "application/json")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as e:
            return e.code, e.read()
        except (urllib.error.URLError, OSError) as e:
            raise ServiceError(f"{method} {path}: {e}") from None

    def get(self, path):
        status, body = self._req("GET", path)
        if status != 200:
            raise ServiceError(f"GET {path}: HTTP {status}: {body[:300].decode(errors='replace')}")
        return body

    def get_json(self, path):
        return json.loads(self.get(path))

    def post_json(self, path, body, ok=(200, 201, 202)):
        status, raw = self._req("POST", path, body)
        if status not in ok:
            raise ServiceError(f"POST {path}: HTTP {status}: {raw[:500].decode(errors='replace')}")
        return json.loads(raw)

    def robot(self, robot_id):
        q = urllib.parse.quote(robot_id, safe="")
        return self.get_json(f"/v1/robots/{q}"), self.get(f"/v1/robots/{q}/urdf").decode()

    def meshes(self, robot_id, urdf_text: str) -> dict:
        """The mesh files the robot's URDF names, as uploaded with the system
        (`GET /v1/robots/{id}/meshes/{filename}`), by filename; a file the service does not
        have is left out (the build then refuses the link that needs it, naming the file)."""
        q = urllib.parse.quote(robot_id, safe="")
        out = {}
        for name in sorted(set(re.findall(r'<mesh\b[^>]*\bfilename="([^"]+)"', urdf_text))):
            status, body = self._req("GET", f"/v1/robots/{q}/meshes/{urllib.parse.quote(name, safe='')}")
            if status == 200:
                out[name] = body
            elif status != 404:
                raise ServiceError(f"GET the mesh {name} of {robot_id}: HTTP {status}")
        return out

    def plan_for_execution(self, robot, execute: dict, newest: int = 200):
        """The stored plan whose trajectory (open loop) or grasp configuration (closed loop) this
        execution runs, newest first; None when there is none (e.g. an inline trajectory)."""
        payload = execute.get("payload", {})
        if payload.get("kind") == "stream":
            return None  # teleoperation: no plan behind it
        q = urllib.parse.quote(robot, safe="")
        items = self.get_json(f"/v1/plans?robot={q}&limit={newest}").get("items", [])
        if payload.get("kind") == "trajectory":
            tid = payload.get("trajectory_id")
            for it in items:
                if it.get("trajectory_id") == tid and tid not in (None, "inline"):
                    return self.get_json(f"/v1/plans/{it['id']}")
            return None
        goal = payload.get("goal")
        names = payload.get("params", {}).get("joint_names", [])
        # Closed loop names no trajectory: compare the goal with the newest plans' grasps.
        for it in items[:50]:
            if not it.get("feasible"):
                continue
            plan = self.get_json(f"/v1/plans/{it['id']}")
            r = plan.get("grasp", {}).get("result", {})
            vals = {j["name"]: j["value"] for j in r.get("q_arm", []) + r.get("q_hand", [])}
            if all(n in vals for n in names) and all(
                abs(vals[n] - g) < 1e-9 for n, g in zip(names, goal)
            ):
                return plan
        return None
