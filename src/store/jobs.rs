//! The `jobs` table (migration 0001).

use std::fmt;

use serde::{Deserialize, Serialize};
use sqlx::{SqliteConnection, SqlitePool};
use utoipa::ToSchema;
use uuid::Uuid;

/// Lifecycle state of a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobStatus {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

impl JobStatus {
    pub const ALL: [JobStatus; 5] = [
        JobStatus::Queued,
        JobStatus::Running,
        JobStatus::Succeeded,
        JobStatus::Failed,
        JobStatus::Cancelled,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Queued => "queued",
            JobStatus::Running => "running",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Cancelled => "cancelled",
        }
    }

    pub fn parse(s: &str) -> Option<JobStatus> {
        JobStatus::ALL.into_iter().find(|x| x.as_str() == s)
    }

    /// True for `succeeded`, `failed` and `cancelled`: the job will not change again.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Cancelled
        )
    }
}

impl fmt::Display for JobStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Progress of a job: a fraction in [0, 1] and an optional message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobProgress {
    /// Completed fraction, 0 to 1.
    pub fraction: f64,
    pub message: Option<String>,
}

/// Why a job failed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct JobFailure {
    /// Stable reason: `interrupted` (the process stopped while the job was queued or running),
    /// `failed` (the computation reported an error) or `internal` (a bug; see the server logs).
    pub reason: String,
    pub message: String,
}

/// Where a job's result lives: a resource collection and an id.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ResultRef {
    /// Resource collection under `/v1`, e.g. `mappings`.
    pub resource: String,
    pub id: String,
    /// `/v1/{resource}/{id}`.
    pub href: String,
}

impl ResultRef {
    pub fn new(resource: impl Into<String>, id: impl fmt::Display) -> Self {
        let resource = resource.into();
        let id = id.to_string();
        let href = format!("/v1/{resource}/{id}");
        ResultRef { resource, id, href }
    }
}

/// A job as stored and as served by the API.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct JobRecord {
    pub id: Uuid,
    /// What the job computes, e.g. `mapping`.
    pub kind: String,
    pub status: JobStatus,
    pub progress: JobProgress,
    /// Set when `status` is `failed`.
    pub error: Option<JobFailure>,
    /// Set when `status` is `succeeded` and the job stored a result.
    pub result: Option<ResultRef>,
    /// A cancellation was requested (the job stops at its next check).
    pub cancel_requested: bool,
    /// RFC 3339 UTC.
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
}

/// The final state a driver writes.
pub(crate) struct Finish {
    pub status: JobStatus,
    pub reason: Option<&'static str>,
    pub message: Option<String>,
}

impl Finish {
    pub(crate) fn cancelled() -> Self {
        Finish {
            status: JobStatus::Cancelled,
            reason: None,
            message: None,
        }
    }
    pub(crate) fn failed(reason: &'static str, message: impl Into<String>) -> Self {
        Finish {
            status: JobStatus::Failed,
            reason: Some(reason),
            message: Some(message.into()),
        }
    }
    pub(crate) fn interrupted() -> Self {
        Finish::failed(
            "interrupted",
            "the service shut down while the job was running",
        )
    }
}

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

/// How many jobs are in each state (states with none are left out).
pub async fn count_by_status(pool: &SqlitePool) -> Result<Vec<(JobStatus, i64)>, sqlx::Error> {
    let rows: Vec<(String, i64)> =
        sqlx::query_as("SELECT status, COUNT(*) FROM jobs GROUP BY status ORDER BY status")
            .fetch_all(pool)
            .await?;
    rows.into_iter()
        .map(|(status, n)| {
            let status = JobStatus::ALL
                .into_iter()
                .find(|s| s.as_str() == status)
                .ok_or_else(|| {
                    sqlx::Error::Decode(format!("unknown job status {status}").into())
                })?;
            Ok((status, n))
        })
        .collect()
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
