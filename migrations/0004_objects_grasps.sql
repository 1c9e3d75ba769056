-- 0004 (grasp): graspable objects and computed grasps (paper eq. 10-29).
--
-- An object row keeps the validated object description (shape, pose, support plane) as the JSON
-- of `grasp::ObjectSpec`; meshes are small (limit 100k triangles) and only read whole, so JSON is
-- adequate. `seeded` marks the everyday objects of the paper's study, present from the start.
CREATE TABLE objects (
    id         TEXT PRIMARY KEY NOT NULL,
    name       TEXT NOT NULL,
    spec       TEXT NOT NULL,
    seeded     INTEGER NOT NULL DEFAULT 0 CHECK (seeded IN (0, 1)),
    created_at TEXT NOT NULL
);

-- A grasp keeps the request it answered (robot, object as used, task, weights, seed) and the full
-- result (joint values with names, contacts, every term and residual, ellipsoids). `object_id`
-- is NULL for inline objects and is not a foreign key: deleting an object must not erase the
-- grasps computed for it (they carry their own copy of the object). `batch_id` groups the grasps
-- of one batch job.
CREATE TABLE grasp_batches (
    id         TEXT PRIMARY KEY NOT NULL,
    job_id     TEXT NOT NULL REFERENCES jobs(id),
    robot      TEXT NOT NULL,
    count      INTEGER NOT NULL,
    feasible   INTEGER NOT NULL,
    created_at TEXT NOT NULL
);

CREATE TABLE grasps (
    id         TEXT PRIMARY KEY NOT NULL,
    robot      TEXT NOT NULL,
    object_id  TEXT,
    object     TEXT NOT NULL,
    request    TEXT NOT NULL,
    result     TEXT NOT NULL,
    feasible   INTEGER NOT NULL CHECK (feasible IN (0, 1)),
    batch_id   TEXT REFERENCES grasp_batches(id),
    position   INTEGER,
    created_at TEXT NOT NULL
);

CREATE INDEX grasps_by_batch ON grasps (batch_id, position);

-- The seeded everyday objects (paper Fig. 3-7) on a table at z = 0, 0.5 m in front of the robot.
-- Same shapes and dimensions as `grasp::objects::seeded_shapes`.
INSERT INTO objects (id, name, spec, seeded, created_at) VALUES
 ('00000000-0000-4000-8000-000000000001', 'ball',
  '{"name":"ball","shape":{"type":"sphere","radius":0.033},"position":[0.5,0.0,0.033],"orientation":[1.0,0.0,0.0,0.0],"support":{"normal":[0.0,0.0,1.0],"offset":0.0}}',
  1, '2026-01-01T00:00:00.000000Z'),
 ('00000000-0000-4000-8000-000000000002', 'bottle',
  '{"name":"bottle","shape":{"type":"cylinder","radius":0.0325,"height":0.2},"position":[0.5,0.0,0.1],"orientation":[1.0,0.0,0.0,0.0],"support":{"normal":[0.0,0.0,1.0],"offset":0.0}}',
  1, '2026-01-01T00:00:00.000000Z'),
 ('00000000-0000-4000-8000-000000000003', 'kitchen_timer',
  '{"name":"kitchen_timer","shape":{"type":"cylinder","radius":0.0325,"height":0.05},"position":[0.5,0.0,0.025],"orientation":[1.0,0.0,0.0,0.0],"support":{"normal":[0.0,0.0,1.0],"offset":0.0}}',
  1, '2026-01-01T00:00:00.000000Z'),
 ('00000000-0000-4000-8000-000000000004', 'pencil',
  '{"name":"pencil","shape":{"type":"capsule","radius":0.004,"length":0.17},"position":[0.5,0.0,0.004],"orientation":[0.7071067811865476,-0.7071067811865476,0.0,0.0],"support":{"normal":[0.0,0.0,1.0],"offset":0.0}}',
  1, '2026-01-01T00:00:00.000000Z'),
 ('00000000-0000-4000-8000-000000000005', 'sunglasses',
  '{"name":"sunglasses","shape":{"type":"box","size":[0.045,0.14,0.035]},"position":[0.5,0.0,0.0175],"orientation":[1.0,0.0,0.0,0.0],"support":{"normal":[0.0,0.0,1.0],"offset":0.0}}',
  1, '2026-01-01T00:00:00.000000Z');
