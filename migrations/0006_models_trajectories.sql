-- 0006 (models): trained motion models (PCA + navigation functions, paper eq. 8-9) and the
-- trajectories generated from them.
--
-- A model row is written when its training job is submitted (`model` and `report` NULL) and
-- completed in the transaction that marks the job `succeeded`; its status is the job's. The
-- trained `motion::MotionModel` is stored as JSON text: a few kB of parameters read whole (PCA
-- bases, spline coefficients), not a large array. `joint_names` (JSON array) is the model's joint
-- order; `control_rate`/`k_perp` are the closed-loop gains handed to bridge workers.
--
-- Default model of a robot: the one with `is_default = 1` if any (at most one per robot, enforced
-- by the partial unique index), otherwise the most recently created succeeded model.
CREATE TABLE models (
    id           TEXT PRIMARY KEY NOT NULL,
    job_id       TEXT NOT NULL REFERENCES jobs(id),
    robot        TEXT NOT NULL,
    request      TEXT NOT NULL,
    joint_names  TEXT NOT NULL,
    control_rate REAL NOT NULL,
    k_perp       REAL NOT NULL,
    report       TEXT,
    model        TEXT,
    is_default   INTEGER NOT NULL DEFAULT 0 CHECK (is_default IN (0, 1)),
    created_at   TEXT NOT NULL,
    CHECK ((report IS NULL) = (model IS NULL))
);

CREATE INDEX models_by_robot ON models (robot, created_at DESC);
CREATE UNIQUE INDEX models_one_default ON models (robot) WHERE is_default = 1;

-- A stored trajectory: joint order, exact start and goal, timed points as one BLOB of shape
-- [points, 1 + 3n] (t, positions, velocities, accelerations; store::blob), the request as given
-- and a JSON summary (convergence, final errors, certificates, timing, Cartesian paths).
-- `model_id` is NULL for trajectories that did not come from a model.
CREATE TABLE trajectories (
    id          TEXT PRIMARY KEY NOT NULL,
    model_id    TEXT REFERENCES models(id),
    robot       TEXT NOT NULL,
    joint_names TEXT NOT NULL,
    start       BLOB NOT NULL,
    goal        BLOB NOT NULL,
    points      BLOB NOT NULL,
    duration    REAL NOT NULL,
    request     TEXT NOT NULL,
    summary     TEXT NOT NULL,
    created_at  TEXT NOT NULL
);

CREATE INDEX trajectories_by_created ON trajectories (created_at DESC);
CREATE INDEX trajectories_by_model ON trajectories (model_id, created_at DESC);
