-- 0007 (bridge): bridge workers seen by the service, and executions forwarded to them (DESIGN §7).
--
-- An execution keeps its own resolved copy of what it runs (`payload`: the JSON of
-- `bridge::ExecutionPayload` without the points; `points`: the trajectory's timed points as a
-- numeric BLOB of shape [n_points, 1 + 3 n_joints] = t, positions, velocities, accelerations),
-- so deleting or retraining a model never changes an execution. `trajectory_id` / `model_id`
-- are not foreign keys for the same reason. `state` is one of
-- queued | running | succeeded | failed | aborted | cancelled | interrupted.
-- `worker` is the requested worker (NULL: any compatible one), `assigned_worker` the one that
-- ran it. `last_feedback` and `tracking` are JSON, flushed at a bounded rate while it runs and
-- at its end, so an interrupted execution keeps its last feedback.
CREATE TABLE executions (
    id               TEXT PRIMARY KEY NOT NULL,
    robot            TEXT NOT NULL,
    mode             TEXT NOT NULL CHECK (mode IN ('open_loop', 'closed_loop')),
    kind             TEXT NOT NULL CHECK (kind IN ('trajectory', 'model')),
    source_id        TEXT NOT NULL,
    payload          TEXT NOT NULL,
    points           BLOB,
    worker           TEXT,
    state            TEXT NOT NULL,
    assigned_worker  TEXT,
    reason           TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0 CHECK (cancel_requested IN (0, 1)),
    last_feedback    TEXT,
    tracking         TEXT,
    created_at       TEXT NOT NULL,
    dispatched_at    TEXT,
    finished_at      TEXT
);

CREATE INDEX executions_state_created ON executions (state, created_at);
CREATE INDEX executions_created ON executions (created_at);

-- Every worker that ever said a valid hello (the live connection state is in memory).
CREATE TABLE bridges (
    name              TEXT PRIMARY KEY NOT NULL,
    robot             TEXT NOT NULL,
    joint_names       TEXT NOT NULL,
    capabilities      TEXT NOT NULL,
    first_seen_at     TEXT NOT NULL,
    last_connected_at TEXT NOT NULL,
    last_seen_at      TEXT NOT NULL
);
