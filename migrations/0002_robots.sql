-- 0002 (kin): arm-hand systems. Bundled systems (robots/systems/*.toml) are synchronised at
-- start (id = file stem, bundled = 1, read-only); registered ones get a UUID id. The URDF texts
-- and the descriptor are stored verbatim, so the kinematic model can be rebuilt exactly.
-- Other resources reference robots(id); deleting a referenced system fails the foreign key and
-- the API answers 409.
CREATE TABLE robots (
    id          TEXT PRIMARY KEY NOT NULL,
    name        TEXT NOT NULL,
    bundled     INTEGER NOT NULL CHECK (bundled IN (0, 1)),
    -- The descriptor as JSON (SystemDescriptor).
    descriptor  TEXT NOT NULL,
    -- The arm URDF, or the one combined URDF when hand_urdf is NULL.
    arm_urdf    TEXT NOT NULL,
    hand_urdf   TEXT,
    created_at  TEXT NOT NULL,
    updated_at  TEXT NOT NULL
);

CREATE INDEX robots_by_created ON robots (created_at);
