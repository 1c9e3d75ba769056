-- 0001 (shell): the job table shared by every long-running computation.
--
-- Timestamps are RFC 3339 UTC text with a fixed width (microseconds, `Z`), so lexical order is
-- time order. A job's result lives in its own resource's table; `result_resource`/`result_id`
-- point at it (e.g. 'mappings' + the mapping id) and are set in the same transaction that stores
-- the result rows and marks the job `succeeded`.
CREATE TABLE jobs (
    id              TEXT PRIMARY KEY NOT NULL,
    kind            TEXT NOT NULL,
    status          TEXT NOT NULL
                    CHECK (status IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    progress        REAL NOT NULL DEFAULT 0 CHECK (progress >= 0 AND progress <= 1),
    message         TEXT,
    -- Machine-readable failure reason ('interrupted', 'failed', 'internal') and a human message.
    error_reason    TEXT,
    error_message   TEXT,
    result_resource TEXT,
    result_id       TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0 CHECK (cancel_requested IN (0, 1)),
    created_at      TEXT NOT NULL,
    started_at      TEXT,
    finished_at     TEXT,
    CHECK ((result_resource IS NULL) = (result_id IS NULL))
);

CREATE INDEX jobs_by_status ON jobs (status);
CREATE INDEX jobs_by_created ON jobs (created_at DESC);
