//! The `jobs` table (migration 0001).

use sqlx::{SqliteConnection, SqlitePool};
use uuid::Uuid;

use crate::jobs::{Finish, JobFailure, JobProgress, JobRecord, JobStatus, ResultRef};

#[derive(Debug, sqlx::FromRow)]
struct JobRow {
    id: String,
    kind: String,
    status: String,
    progress: f64,
    message: Option<String>,
    error_reason: Option<String>,
    error_message: Option<String>,
    result_resource: Option<String>,
    result_id: Option<String>,
    cancel_requested: bool,
    created_at: String,
    started_at: Option<String>,
    finished_at: Option<String>,
}

impl TryFrom<JobRow> for JobRecord {
    type Error = sqlx::Error;

    fn try_from(row: JobRow) -> Result<Self, Self::Error> {
        let decode = |what: &str, value: &str| {
            sqlx::Error::Decode(format!("jobs.{what} holds an unexpected value {value:?}").into())
        };
        Ok(JobRecord {
            id: Uuid::parse_str(&row.id).map_err(|_| decode("id", &row.id))?,
            status: JobStatus::parse(&row.status).ok_or_else(|| decode("status", &row.status))?,
            kind: row.kind,
            progress: JobProgress {
                fraction: row.progress,
                message: row.message,
            },
            error: match (row.error_reason, row.error_message) {
                (Some(reason), message) => Some(JobFailure {
                    reason,
                    message: message.unwrap_or_default(),
                }),
                (None, _) => None,
            },
            result: match (row.result_resource, row.result_id) {
                (Some(resource), Some(id)) => Some(ResultRef::new(resource, id)),
                _ => None,
            },
            cancel_requested: row.cancel_requested,
            created_at: row.created_at,
            started_at: row.started_at,
            finished_at: row.finished_at,
        })
    }
}

// A macro rather than a const so the queries stay `&'static str` literals via `concat!`.
macro_rules! job_columns {
    () => {
        "id, kind, status, progress, message, error_reason, error_message, result_resource, \
         result_id, cancel_requested, created_at, started_at, finished_at"
    };
}

/// Filter and page for [`list`].
#[derive(Debug, Clone, Default)]
pub struct JobFilter {
    pub status: Option<JobStatus>,
    pub kind: Option<String>,
    pub limit: u32,
    pub offset: u32,
}

pub(crate) async fn insert(pool: &SqlitePool, r: &JobRecord) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO jobs (id, kind, status, progress, message, created_at) VALUES (?, ?, ?, ?, ?, ?)",
    )
    .bind(r.id.to_string())
    .bind(&r.kind)
    .bind(r.status.as_str())
    .bind(r.progress.fraction)
    .bind(&r.progress.message)
    .bind(&r.created_at)
    .execute(pool)
    .await?;
    Ok(())
}

/// One job by id.
pub async fn get(pool: &SqlitePool, id: Uuid) -> Result<Option<JobRecord>, sqlx::Error> {
    sqlx::query_as::<_, JobRow>(concat!(
        "SELECT ",
        job_columns!(),
        " FROM jobs WHERE id = ?"
    ))
    .bind(id.to_string())
    .fetch_optional(pool)
    .await?
    .map(JobRecord::try_from)
    .transpose()
}

/// Jobs matching `filter`, newest first.
pub async fn list(pool: &SqlitePool, filter: &JobFilter) -> Result<Vec<JobRecord>, sqlx::Error> {
    sqlx::query_as::<_, JobRow>(concat!(
        "SELECT ",
        job_columns!(),
        " FROM jobs WHERE (?1 IS NULL OR status = ?1) AND (?2 IS NULL OR kind = ?2) \
         ORDER BY created_at DESC, id LIMIT ?3 OFFSET ?4"
    ))
    .bind(filter.status.map(JobStatus::as_str))
    .bind(filter.kind.as_deref())
    .bind(i64::from(filter.limit))
    .bind(i64::from(filter.offset))
    .fetch_all(pool)
    .await?
    .into_iter()
    .map(JobRecord::try_from)
    .collect()
}

pub(crate) async fn mark_running(
    pool: &SqlitePool,
    id: Uuid,
    now: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET status = 'running', started_at = ? WHERE id = ? AND status = 'queued'",
    )
    .bind(now)
    .bind(id.to_string())
    .execute(pool)
    .await?;
    Ok(())
}

pub(crate) async fn set_progress(
    pool: &SqlitePool,
    id: Uuid,
    p: &JobProgress,
) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE jobs SET progress = ?, message = ? WHERE id = ? AND status = 'running'")
        .bind(p.fraction.clamp(0.0, 1.0))
        .bind(&p.message)
        .bind(id.to_string())
        .execute(pool)
        .await?;
    Ok(())
}

pub(crate) async fn set_cancel_requested(pool: &SqlitePool, id: Uuid) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND status IN ('queued', 'running')",
    )
    .bind(id.to_string())
    .execute(pool)
    .await?;
    Ok(())
}

/// Marks a job succeeded with its result reference (inside the result's transaction).
pub(crate) async fn succeed(
    conn: &mut SqliteConnection,
    id: Uuid,
    result: Option<&ResultRef>,
    message: &str,
    now: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET status = 'succeeded', progress = 1, message = ?, result_resource = ?, \
         result_id = ?, finished_at = ? WHERE id = ? AND status IN ('queued', 'running')",
    )
    .bind(message)
    .bind(result.map(|r| r.resource.as_str()))
    .bind(result.map(|r| r.id.as_str()))
    .bind(now)
    .bind(id.to_string())
    .execute(conn)
    .await?;
    Ok(())
}

/// Records the end of an unfinished job (a finished job is left as it is).
pub(crate) async fn finish(
    pool: &SqlitePool,
    id: Uuid,
    f: &Finish,
    now: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE jobs SET status = ?, error_reason = ?, error_message = ?, finished_at = ? \
         WHERE id = ? AND status IN ('queued', 'running')",
    )
    .bind(f.status.as_str())
    .bind(f.reason)
    .bind(&f.message)
    .bind(now)
    .bind(id.to_string())
    .execute(pool)
    .await?;
    Ok(())
}

/// Crash recovery: every job a previous process left `queued` or `running` can no longer make
/// progress (its closure lived in that process), so it becomes `failed: interrupted`.
pub(crate) async fn mark_interrupted(pool: &SqlitePool, now: &str) -> Result<u64, sqlx::Error> {
    let done = sqlx::query(
        "UPDATE jobs SET status = 'failed', error_reason = 'interrupted', \
         error_message = 'the service stopped while the job was ' || status, finished_at = ? \
         WHERE status IN ('queued', 'running')",
    )
    .bind(now)
    .execute(pool)
    .await?;
    Ok(done.rows_affected())
}
