-- no-transaction
-- 0012 (bridge, issue 22): streaming executions (teleoperation: joint setpoints streamed live
-- from the retargeting WebSocket). `mode` gains 'streaming' and `kind` 'stream'; SQLite cannot
-- change a CHECK constraint in place, so the table is rebuilt as its documentation prescribes
-- (new table, copy, drop, rename), with foreign keys off so that dropping the old table does
-- not cascade into `execution_feedback` (whose rows keep referring to `executions` by name).
-- PRAGMA foreign_keys is a no-op inside a transaction, hence `no-transaction` above and the
-- explicit BEGIN/COMMIT here; every step is idempotent, so a crash between COMMIT and sqlx's
-- bookkeeping re-runs it harmlessly.
PRAGMA foreign_keys = OFF;
BEGIN;
DROP TABLE IF EXISTS executions_rebuild;
CREATE TABLE executions_rebuild (
    id               TEXT PRIMARY KEY NOT NULL,
    robot            TEXT NOT NULL,
    mode             TEXT NOT NULL CHECK (mode IN ('open_loop', 'closed_loop', 'streaming')),
    kind             TEXT NOT NULL CHECK (kind IN ('trajectory', 'model', 'stream')),
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
INSERT INTO executions_rebuild
    SELECT id, robot, mode, kind, source_id, payload, points, worker, state, assigned_worker,
           reason, cancel_requested, last_feedback, tracking, created_at, dispatched_at,
           finished_at
    FROM executions;
DROP TABLE executions;
ALTER TABLE executions_rebuild RENAME TO executions;
CREATE INDEX executions_state_created ON executions (state, created_at);
CREATE INDEX executions_created ON executions (created_at);
CREATE INDEX executions_by_source ON executions (source_id);
COMMIT;
PRAGMA foreign_keys = ON;
