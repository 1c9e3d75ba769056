//! SQLite repositories (sqlx, runtime-checked queries); numeric arrays stored as compact BLOBs.
