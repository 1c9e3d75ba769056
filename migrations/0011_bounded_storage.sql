-- 0011 (storage, issue 20): compact trajectories, and the lookups that deletes and retention need.
--
-- A trajectory written from now on keeps `points` as f64 [points, 1 + n] (t and positions,
-- exact) and its velocities and accelerations in `derivatives`, f32 [points, 2n] rounded towards
-- zero (so a magnitude never grows past a limit the exact value respected). Rows written before
-- have `derivatives` NULL and the old f64 [points, 1 + 3n] layout in `points`; both read.
ALTER TABLE trajectories ADD COLUMN derivatives BLOB;

-- Deleting or expiring a trajectory asks whether a plan or an unfinished execution uses it.
CREATE INDEX plans_by_trajectory ON plans (trajectory_id);
CREATE INDEX executions_by_source ON executions (source_id);
