-- 0010 (bridge): the measured state history of an execution (issue 9: planned vs measured).
--
-- 0007 keeps only the latest feedback; a figure of measured joint positions over time needs the
-- history. The hub decimates the worker's feedback (at most 20 samples per second) and bounds it
-- (at most 4000 samples: when the bound is reached it drops every other sample and halves the
-- rate, so a long closed-loop run keeps its whole span at a coarser resolution instead of
-- growing). It is written with the periodic progress flush and the final state change, in the
-- same transaction, as append-only chunks: each flush adds one row holding the samples since the
-- previous one, so a flush costs the new samples, not the whole history. After a halving the
-- chunks are replaced by one. An execution that is interrupted keeps the chunks flushed so far.
--
-- `data` is a numeric BLOB (`store::blob`, f64) of shape [samples, 3 + 2 n_joints]: per row
-- t (s since the execution started on the worker), progress, tracking_error, the n measured
-- positions and the n measured velocities, in the joint order of the execution's payload.
-- The history is part of its execution: deleting the execution deletes it.
CREATE TABLE execution_feedback (
    execution_id TEXT NOT NULL REFERENCES executions (id) ON DELETE CASCADE,
    -- 0, 1, 2, ... in write order; the history is the chunks concatenated in this order.
    chunk        INTEGER NOT NULL CHECK (chunk >= 0),
    -- Rows in `data` (so counting samples needs no BLOB decoding).
    samples      INTEGER NOT NULL CHECK (samples > 0),
    data         BLOB NOT NULL,
    PRIMARY KEY (execution_id, chunk)
);
