-- 0003 (human): recorded or synthetic human reach-to-grasp demonstrations (issue 4).
--
-- The raw sensor streams are not kept: what the pipeline consumes is the derived kinematics on
-- the common clock, stored as one BLOB (`reachgrasp::store::blob`, f64, shape [frames, 71]; the
-- row layout is `reachgrasp::human::storage`). Filterable labels are columns; the subject and
-- object descriptions and the ingest summary are small JSON documents.
CREATE TABLE demonstrations (
    id             TEXT PRIMARY KEY NOT NULL,
    -- Client-chosen id: a re-upload with the same value returns the existing row (idempotency).
    external_id    TEXT UNIQUE,
    -- The synthetic-study job that produced the row (NULL for uploads).
    job_id         TEXT REFERENCES jobs (id) ON DELETE SET NULL,
    subject_id     TEXT NOT NULL,
    object_name    TEXT NOT NULL,
    task           TEXT NOT NULL,
    position_index INTEGER NOT NULL,
    trial          INTEGER NOT NULL,
    synthetic      INTEGER NOT NULL CHECK (synthetic IN (0, 1)),
    subject        TEXT NOT NULL,
    object         TEXT NOT NULL,
    summary        TEXT NOT NULL,
    frame_count    INTEGER NOT NULL,
    frames         BLOB NOT NULL,
    created_at     TEXT NOT NULL
);

CREATE INDEX demonstrations_by_subject ON demonstrations (subject_id);
CREATE INDEX demonstrations_by_object ON demonstrations (object_name);
CREATE INDEX demonstrations_by_created ON demonstrations (created_at DESC);
CREATE INDEX demonstrations_by_job ON demonstrations (job_id);
