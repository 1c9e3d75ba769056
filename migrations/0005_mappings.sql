-- 0005 (mapapi): human-to-robot motion mappings (paper eq. 1-7, issue 5).
--
-- A mapping row is written when the job is submitted (so `GET /v1/mappings/{id}` answers while
-- it runs); its status is the job's. `summary` and every `mapping_demonstrations` row are
-- written in the one transaction that marks the job succeeded: a failed or cancelled mapping
-- has no summary and no per-demonstration rows, never a partial set.
CREATE TABLE mappings (
    id         TEXT PRIMARY KEY NOT NULL,
    job_id     TEXT NOT NULL REFERENCES jobs (id),
    robot      TEXT NOT NULL,
    -- The validated request (robot, resolved demonstration ids, weights, registration, rate).
    request    TEXT NOT NULL,
    -- Aggregate metrics (JSON), set on success.
    summary    TEXT,
    created_at TEXT NOT NULL
);

CREATE INDEX mappings_by_created ON mappings (created_at DESC);
CREATE INDEX mappings_by_job ON mappings (job_id);

-- One mapped demonstration. Numeric arrays are `reachgrasp::store::blob` BLOBs:
-- `frames`  f64 [frame_count, 1 + nq]: time, then the independent joint positions in the order
--           of `joint_names` (a JSON array);
-- `metrics` f64 [frame_count, 17]: the per-frame `mapping::FrameMetrics` in the column layout of
--           `reachgrasp::store::mappings::METRIC_COLUMNS`.
-- The labels are copied from the demonstration so a mapping stays readable (and trainable) on its
-- own; `demonstrations::delete` removes these rows before the demonstration.
CREATE TABLE mapping_demonstrations (
    mapping_id       TEXT NOT NULL REFERENCES mappings (id) ON DELETE CASCADE,
    position         INTEGER NOT NULL,
    demonstration_id TEXT NOT NULL REFERENCES demonstrations (id),
    subject_id       TEXT NOT NULL,
    object_name      TEXT NOT NULL,
    task             TEXT NOT NULL,
    position_index   INTEGER NOT NULL,
    trial            INTEGER NOT NULL,
    joint_names      TEXT NOT NULL,
    frame_count      INTEGER NOT NULL,
    frames           BLOB NOT NULL,
    metrics          BLOB NOT NULL,
    -- The resolved registration {rotation [w,x,y,z], translation [x,y,z], scale}.
    registration     TEXT NOT NULL,
    -- Per-demonstration aggregate metrics (JSON).
    summary          TEXT NOT NULL,
    PRIMARY KEY (mapping_id, position)
);

CREATE INDEX mapping_demonstrations_by_demonstration ON mapping_demonstrations (demonstration_id);
