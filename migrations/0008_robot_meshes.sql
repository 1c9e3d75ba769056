-- 0008 (robots, perf session): collision meshes uploaded with a registered system
-- (`POST /v1/robots` field `meshes`), keyed by the filename exactly as the URDF references it,
-- so the model can be rebuilt exactly from the database like the URDF texts. The meshes go with
-- their robot: deleting the robot deletes them.
CREATE TABLE robot_meshes (
    robot_id TEXT NOT NULL REFERENCES robots(id) ON DELETE CASCADE,
    filename TEXT NOT NULL,
    data     BLOB NOT NULL,
    PRIMARY KEY (robot_id, filename)
);
