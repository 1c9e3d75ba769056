-- 0013 (objects + executions, issue 24 §3): physics verification of plans.
--
-- The seeded objects get the mass (kg) and friction coefficient a physics check needs, and their
-- table a friction coefficient: the values of `grasp::objects::seeded_properties` and
-- `TABLE_FRICTION` (a test compares them). Objects a user stored are left as they are: a
-- missing mass or friction is refused when a plan asks to verify a grasp of that object.
UPDATE objects SET spec = json_set(spec, '$.mass', 0.057, '$.friction', 0.8, '$.support.friction', 0.5)
 WHERE seeded = 1 AND name = 'ball';
UPDATE objects SET spec = json_set(spec, '$.mass', 0.52, '$.friction', 0.6, '$.support.friction', 0.5)
 WHERE seeded = 1 AND name = 'bottle';
UPDATE objects SET spec = json_set(spec, '$.mass', 0.1, '$.friction', 0.6, '$.support.friction', 0.5)
 WHERE seeded = 1 AND name = 'kitchen_timer';
UPDATE objects SET spec = json_set(spec, '$.mass', 0.006, '$.friction', 0.6, '$.support.friction', 0.5)
 WHERE seeded = 1 AND name = 'pencil';
UPDATE objects SET spec = json_set(spec, '$.mass', 0.03, '$.friction', 0.6, '$.support.friction', 0.5)
 WHERE seeded = 1 AND name = 'sunglasses';

-- An execution that ends in a grasp trial in physics carries the scene to simulate and the
-- trial (JSON `PhysicsTrial`: its own copy, so a later change of the object never changes it);
-- NULL for every other execution. Such an execution is dispatched only to a worker with the
-- `grasp_trial` capability.
ALTER TABLE executions ADD COLUMN trial TEXT;

-- A batch verification (POST /v1/verifications, a job): which plan answered which combination
-- of robot, object, placement and task set (`items`, JSON in request order). The verdicts are
-- read from the plans' executions when the verification is read, so they are never stale.
CREATE TABLE verifications (
    id         TEXT PRIMARY KEY NOT NULL,
    job_id     TEXT NOT NULL REFERENCES jobs(id),
    request    TEXT NOT NULL,
    items      TEXT NOT NULL,
    created_at TEXT NOT NULL
);
