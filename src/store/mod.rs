//! SQLite repositories (sqlx, runtime-checked queries); numeric arrays stored as compact BLOBs.
//!
//! Queries use `sqlx::query` / `sqlx::query_as` with `#[derive(sqlx::FromRow)]` rows, never the
//! `query!` macros, so building never needs a live database. Every write that matters runs in a
//! transaction (`pool.begin()`); see [`crate::jobs`] for how a job stores its result rows and its
//! result reference in one transaction.

pub mod blob;
pub mod demonstrations;
pub mod executions;
pub mod feedback;
pub mod grasps;
pub mod jobs;
pub mod library;
pub mod mappings;
pub mod models;
pub mod payload;
pub mod plans;
pub mod robots;
pub mod trajectories;

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use sqlx::SqlitePool;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use time::OffsetDateTime;
use time::format_description::FormatItem;
use time::macros::format_description;

/// The embedded migrations of `migrations/` (applied by [`connect`]).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("./migrations");

/// Errors of the storage layer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    #[error("cannot create the database folder {path}: {source}")]
    CreateDir {
        path: String,
        source: std::io::Error,
    },
    #[error("cannot open the database {path}: {source}")]
    Open { path: String, source: sqlx::Error },
    #[error("cannot apply the database migrations: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("database error: {0}")]
    Sqlx(#[from] sqlx::Error),
}

/// Opens (creating the file and its folder if missing) the SQLite database at `path` with WAL
/// journalling, enforced foreign keys and a busy timeout, and applies the migrations.
pub async fn connect(path: &Path) -> Result<SqlitePool, StoreError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| StoreError::CreateDir {
            path: dir.display().to_string(),
            source,
        })?;
    }
    let options = SqliteConnectOptions::from_str("sqlite:")
        .map_err(|source| StoreError::Open {
            path: path.display().to_string(),
            source,
        })?
        .filename(path)
        .create_if_missing(true)
        .journal_mode(SqliteJournalMode::Wal)
        // NORMAL is durable across process crashes in WAL mode (only an OS crash can lose the
        // last commits), which is the failure the job recovery is about.
        .synchronous(SqliteSynchronous::Normal)
        .foreign_keys(true)
        .busy_timeout(Duration::from_secs(5));
    let pool = SqlitePoolOptions::new()
        .max_connections(8)
        .connect_with(options)
        .await
        .map_err(|source| StoreError::Open {
            path: path.display().to_string(),
            source,
        })?;
    MIGRATOR.run(&pool).await?;
    Ok(pool)
}

/// Answers whether the database is reachable (used by `/readyz`).
pub async fn ping(pool: &SqlitePool) -> Result<(), sqlx::Error> {
    sqlx::query("SELECT 1").execute(pool).await.map(|_| ())
}

const TIMESTAMP: &[FormatItem<'static>] =
    format_description!("[year]-[month]-[day]T[hour]:[minute]:[second].[subsecond digits:6]Z");

/// Formats a UTC instant as fixed-width RFC 3339 text (microseconds, `Z`): lexical order of the
/// stored text is time order, so `ORDER BY created_at` works without parsing.
pub fn format_timestamp(t: OffsetDateTime) -> String {
    t.to_offset(time::UtcOffset::UTC)
        .format(TIMESTAMP)
        .expect("a UTC date in the year range of `time` always formats")
}

/// The current instant as stored timestamp text (see [`format_timestamp`]).
pub fn now() -> String {
    format_timestamp(OffsetDateTime::now_utc())
}

/// True when `err` is a SQLite unique or primary-key violation (map it to 409 Conflict).
pub fn is_unique_violation(err: &sqlx::Error) -> bool {
    matches!(err, sqlx::Error::Database(db) if db.is_unique_violation())
}

/// True when `err` is a SQLite foreign-key violation (a referenced row is missing; map to 422/409).
pub fn is_foreign_key_violation(err: &sqlx::Error) -> bool {
    matches!(err, sqlx::Error::Database(db) if db.is_foreign_key_violation())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_are_fixed_width_and_sort_in_time_order() {
        let a = format_timestamp(OffsetDateTime::UNIX_EPOCH);
        let b = format_timestamp(OffsetDateTime::UNIX_EPOCH + time::Duration::microseconds(1));
        assert_eq!(a, "1970-01-01T00:00:00.000000Z");
        assert_eq!(a.len(), b.len());
        assert!(a < b);
    }

    #[tokio::test]
    async fn connect_creates_the_folder_and_enables_wal_and_foreign_keys() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nested/deeper/test.db");
        let pool = connect(&path).await.unwrap();
        assert!(path.exists());
        let mode: (String,) = sqlx::query_as("PRAGMA journal_mode")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(mode.0.to_lowercase(), "wal");
        let fk: (i64,) = sqlx::query_as("PRAGMA foreign_keys")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(fk.0, 1);
        ping(&pool).await.unwrap();
        // Applying the migrations a second time is a no-op, not an error.
        MIGRATOR.run(&pool).await.unwrap();
    }
}
