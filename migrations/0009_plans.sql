-- 0009 (plans): one request from object to humanlike motion (issue 10).
--
-- A plan links what it produced: the grasp (always), the trajectory to it (when the grasp is
-- feasible and inside the model's certified goal region) and the execution it queued (when
-- asked). Each of those is a complete resource of its own, stored before the plan row. The
-- links are not foreign keys: a plan keeps naming its pieces even if one is removed later.
CREATE TABLE plans (
    id            TEXT PRIMARY KEY NOT NULL,
    robot         TEXT NOT NULL,
    model_id      TEXT,
    grasp_id      TEXT NOT NULL,
    trajectory_id TEXT,
    execution_id  TEXT,
    -- Grasp feasible and a trajectory generated; `reason` says why not otherwise.
    feasible      INTEGER NOT NULL CHECK (feasible IN (0, 1)),
    reason        TEXT,
    -- The request as received (JSON).
    request       TEXT NOT NULL,
    -- Timings of the steps (JSON: grasp_s, trajectory_s, total_s).
    timings       TEXT NOT NULL,
    created_at    TEXT NOT NULL
);

CREATE INDEX plans_by_created ON plans (created_at DESC);
