//! SQLite repositories (sqlx, runtime-checked queries); numeric arrays stored as compact BLOBs.
//!
//! Queries use `sqlx::query` / `sqlx::query_as` with `#[derive(sqlx::FromRow)]` rows, never the
//! `query!` macros, so building never needs a live database. Every write that matters runs in a
//! transaction started with [`begin_write`] (`BEGIN IMMEDIATE`); see [`crate::jobs`] for how a job stores its result rows and its
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
pub mod retention;
pub mod robots;
pub mod trajectories;

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::{Sqlite, SqlitePool, Transaction};
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
    connect_capped(path, None).await
}

/// SQLite's page size for new databases (the default); the unit of [`connect_capped`]'s cap.
pub const PAGE_SIZE: u64 = 4096;

/// [`connect`], with the database file limited to about `max_bytes` (`PRAGMA max_page_count`
/// on every connection): a write that would grow it further fails with SQLITE_FULL, as on a
/// full disk ([`is_disk_full`]), and changes nothing. Deleting rows frees pages for reuse.
pub async fn connect_capped(path: &Path, max_bytes: Option<u64>) -> Result<SqlitePool, StoreError> {
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
        // Writers queue for SQLite's one write lock (`begin_write`); a long job result commit
        // under load can hold it for seconds, so a waiting writer gets well over that.
        .busy_timeout(Duration::from_secs(30))
        // A checkpoint truncates the WAL back to this size instead of leaving it at its
        // high-water mark after a large write (64 MiB).
        .pragma("journal_size_limit", "67108864");
    let options = match max_bytes {
        Some(bytes) => options.pragma("max_page_count", bytes.div_ceil(PAGE_SIZE).to_string()),
        None => options,
    };
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

/// Begins a write transaction with `BEGIN IMMEDIATE`: it takes SQLite's single write lock at
/// once, waiting (up to the busy timeout) while another writer holds it.
///
/// A deferred `BEGIN` (sqlx's `pool.begin()`) reads from a snapshot and upgrades to a writer at
/// its first write; when another connection committed in between, the upgrade fails at once with
/// SQLITE_BUSY_SNAPSHOT in WAL mode — the busy timeout cannot help, because the conflict is with
/// data already read. Every transaction that writes starts here.
///
/// The writers of this process first queue for their turn on an async lock of the database
/// file ([`WriteTx`] holds it until it ends), so SQLite's lock is free when they ask for it.
/// Why: a writer SQLite refuses waits in its busy handler, which polls with sleeps growing to
/// 100 ms and serves no one in order. Measured with `cargo bench --bench plans` (8 + 8 runs,
/// 32 clients), when a plan's four rows became one transaction (aac632b): p99 489-612 ms
/// before, 629-967 ms after, the median a little faster.
pub async fn begin_write(pool: &SqlitePool) -> Result<WriteTx, sqlx::Error> {
    let gate = write_gate(pool.connect_options().get_filename());
    let turn = tokio::time::timeout(WRITE_TURN_TIMEOUT, gate.lock_owned())
        .await
        .map_err(|_| sqlx::Error::PoolTimedOut)?;
    let tx = pool.begin_with("BEGIN IMMEDIATE").await?;
    Ok(WriteTx { tx, _turn: turn })
}

/// How long a writer waits for its turn, as SQLite's busy timeout (a safety net: a turn is
/// normally a few milliseconds).
const WRITE_TURN_TIMEOUT: Duration = Duration::from_secs(30);

/// The async lock that orders this process's writers of the database file `path`.
fn write_gate(path: &Path) -> std::sync::Arc<tokio::sync::Mutex<()>> {
    static GATES: std::sync::LazyLock<
        std::sync::Mutex<
            std::collections::HashMap<std::path::PathBuf, std::sync::Arc<tokio::sync::Mutex<()>>>,
        >,
    > = std::sync::LazyLock::new(Default::default);
    let mut gates = GATES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    gates.entry(path.to_path_buf()).or_default().clone()
}

/// A write transaction ([`begin_write`]) and this process's turn at the database's write lock,
/// held until it commits or is dropped (rolled back). Dereferences to the transaction.
pub struct WriteTx {
    tx: Transaction<'static, Sqlite>,
    _turn: tokio::sync::OwnedMutexGuard<()>,
}

impl WriteTx {
    pub async fn commit(self) -> Result<(), sqlx::Error> {
        self.tx.commit().await
    }

    pub async fn rollback(self) -> Result<(), sqlx::Error> {
        self.tx.rollback().await
    }
}

impl std::ops::Deref for WriteTx {
    type Target = Transaction<'static, Sqlite>;
    fn deref(&self) -> &Self::Target {
        &self.tx
    }
}

impl std::ops::DerefMut for WriteTx {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.tx
    }
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

/// True when `err` is SQLITE_FULL: the disk (or the database's configured size cap) is full.
/// The statement changed nothing; the transaction it was part of is rolled back.
pub fn is_disk_full(err: &sqlx::Error) -> bool {
    match err {
        sqlx::Error::Database(db) => {
            db.code().as_deref() == Some("13") || db.message().contains("database or disk is full")
        }
        sqlx::Error::Io(io) => io.raw_os_error() == Some(libc::ENOSPC),
        _ => false,
    }
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
        let limit: (i64,) = sqlx::query_as("PRAGMA journal_size_limit")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(limit.0, 64 << 20);
    }

    /// Reads, lets another connection commit, then writes: the pattern of a job that checks
    /// what exists before storing, or a delete that checks what uses a row.
    async fn read_commit_write(immediate: bool) -> Result<(), sqlx::Error> {
        let dir = tempfile::tempdir().unwrap();
        let pool = connect(&dir.path().join("t.db")).await.unwrap();
        sqlx::query("CREATE TABLE t (x INTEGER)")
            .execute(&pool)
            .await
            .unwrap();
        let (mut write, mut deferred): (Option<WriteTx>, Option<Transaction<'static, Sqlite>>) =
            (None, None);
        let tx: &mut sqlx::SqliteConnection = if immediate {
            write.insert(begin_write(&pool).await?)
        } else {
            deferred.insert(pool.begin().await?)
        };
        let _: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM t")
            .fetch_one(&mut *tx)
            .await?;
        // Another writer; it waits for the lock when `tx` holds it.
        let other = tokio::spawn({
            let pool = pool.clone();
            async move { sqlx::query("INSERT INTO t VALUES (2)").execute(&pool).await }
        });
        tokio::time::sleep(Duration::from_millis(200)).await;
        sqlx::query("INSERT INTO t VALUES (1)")
            .execute(&mut *tx)
            .await?;
        match (write, deferred) {
            (Some(w), _) => w.commit().await?,
            (_, Some(d)) => d.commit().await?,
            _ => unreachable!("one of the two began"),
        }
        other.await.unwrap()?;
        let rows: Vec<i64> = sqlx::query_scalar("SELECT x FROM t ORDER BY rowid")
            .fetch_all(&pool)
            .await?;
        assert_eq!(
            rows,
            [1, 2],
            "the immediate writer goes first, the other waits"
        );
        Ok(())
    }

    #[tokio::test]
    async fn a_write_transaction_survives_a_commit_between_its_read_and_its_write() {
        read_commit_write(true).await.unwrap();
        // The reference: a deferred transaction fails exactly there (SQLITE_BUSY_SNAPSHOT,
        // extended code 517), which is what made concurrent jobs end `failed: internal`.
        let err = read_commit_write(false).await.unwrap_err();
        let code = err.as_database_error().and_then(|e| e.code()).unwrap();
        assert_eq!(code, "517", "{err}");
    }

    /// Every write transaction in the service starts IMMEDIATE (tests may use `begin()`).
    #[test]
    fn no_deferred_transaction_outside_tests() {
        fn visit(dir: &Path, found: &mut Vec<String>) {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    visit(&path, found);
                    continue;
                }
                let name = path.file_name().unwrap().to_string_lossy();
                if name == "tests.rs" || name.ends_with("_tests.rs") || name == "testing.rs" {
                    continue;
                }
                let text = std::fs::read_to_string(&path).unwrap();
                // An inline unit-test module sits at the end of its file.
                let body = text.split("mod tests {").next().unwrap_or("");
                for (i, line) in body.lines().enumerate() {
                    let code = line.split("//").next().unwrap_or("");
                    if code.contains(".begin()") {
                        found.push(format!("{}:{}", path.display(), i + 1));
                    }
                }
            }
        }
        let mut found = Vec::new();
        visit(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("src"),
            &mut found,
        );
        assert!(found.is_empty(), "use store::begin_write: {found:?}");
    }
}
