//! Bounded storage (issue 20): deleting a plan or a trajectory with what it owns, the retention
//! sweep that expires plans, trajectories and executions beyond a configured age or count, and
//! the WAL checkpoint.
//!
//! Ownership, from the schema (0006, 0007, 0009, 0010): a plan owns the grasp, the trajectory
//! and the execution it produced (the plan row links them; nothing else links a plan's grasp);
//! an execution owns its feedback history (`ON DELETE CASCADE`). A trajectory is used by the
//! plans that link it and by executions of it (`source_id`); a finished execution keeps its
//! own copy of the points, so only a queued or running one still needs the trajectory.
//!
//! Nothing that a queued or running execution needs is ever deleted: such a plan, trajectory
//! or execution is refused ([`Deletion::InUse`]) and skipped by the sweep. Every deletion is
//! one write transaction (`BEGIN IMMEDIATE`): all of a plan's rows go, or none.

use std::time::Duration;

use sqlx::{SqliteConnection, SqlitePool};

use super::{begin_write, format_timestamp};

/// The outcome of a delete.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Deletion {
    /// Deleted, with what it owned.
    Deleted,
    /// No such row.
    NotFound,
    /// Still used; nothing was deleted. Says by what.
    InUse(String),
}

/// The state of execution `id`, if it exists.
async fn execution_state(
    conn: &mut SqliteConnection,
    id: &str,
) -> Result<Option<String>, sqlx::Error> {
    sqlx::query_scalar("SELECT state FROM executions WHERE id = ?")
        .bind(id)
        .fetch_optional(&mut *conn)
        .await
}

fn unfinished(state: &str) -> bool {
    matches!(state, "queued" | "running")
}

/// Deletes plan `id` and what it owns inside the caller's write transaction.
pub async fn delete_plan_in(
    conn: &mut SqliteConnection,
    id: &str,
) -> Result<Deletion, sqlx::Error> {
    let plan: Option<(String, Option<String>, Option<String>)> =
        sqlx::query_as("SELECT grasp_id, trajectory_id, execution_id FROM plans WHERE id = ?")
            .bind(id)
            .fetch_optional(&mut *conn)
            .await?;
    let Some((grasp_id, trajectory_id, execution_id)) = plan else {
        return Ok(Deletion::NotFound);
    };
    if let Some(e) = &execution_id
        && let Some(state) = execution_state(conn, e).await?
        && unfinished(&state)
    {
        return Ok(Deletion::InUse(format!(
            "the plan's execution {e} is {state}; cancel it (POST /v1/executions/{e}/cancel) \
             or wait until it has finished"
        )));
    }
    let mut keep_trajectory = false;
    if let Some(t) = &trajectory_id {
        let users = super::trajectories::users(conn, t).await?;
        if let Some(e) = users
            .unfinished_executions
            .iter()
            .find(|e| Some(*e) != execution_id.as_ref())
        {
            return Ok(Deletion::InUse(format!(
                "the plan's trajectory {t} is used by execution {e}, which has not finished"
            )));
        }
        keep_trajectory = users.plans.iter().any(|p| p != id);
    }
    sqlx::query("DELETE FROM plans WHERE id = ?")
        .bind(id)
        .execute(&mut *conn)
        .await?;
    if let Some(e) = &execution_id {
        sqlx::query("DELETE FROM executions WHERE id = ?")
            .bind(e)
            .execute(&mut *conn)
            .await?;
    }
    if let Some(t) = &trajectory_id
        && !keep_trajectory
    {
        super::trajectories::delete_in(conn, t).await?;
    }
    let shared: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM plans WHERE grasp_id = ?")
        .bind(&grasp_id)
        .fetch_one(&mut *conn)
        .await?;
    if shared == 0 {
        sqlx::query("DELETE FROM grasps WHERE id = ?")
            .bind(&grasp_id)
            .execute(&mut *conn)
            .await?;
    }
    Ok(Deletion::Deleted)
}

/// Deletes plan `id` with what it owns (one write transaction).
pub async fn delete_plan(pool: &SqlitePool, id: &str) -> Result<Deletion, sqlx::Error> {
    let mut tx = begin_write(pool).await?;
    let done = delete_plan_in(&mut tx, id).await?;
    if done == Deletion::Deleted {
        tx.commit().await?;
    }
    Ok(done)
}

/// Deletes trajectory `id` inside the caller's write transaction, unless a plan links it (the
/// plan owns it: delete the plan) or an unfinished execution follows it.
pub async fn delete_trajectory_in(
    conn: &mut SqliteConnection,
    id: &str,
) -> Result<Deletion, sqlx::Error> {
    let exists: Option<i64> = sqlx::query_scalar("SELECT 1 FROM trajectories WHERE id = ?")
        .bind(id)
        .fetch_optional(&mut *conn)
        .await?;
    if exists.is_none() {
        return Ok(Deletion::NotFound);
    }
    let users = super::trajectories::users(conn, id).await?;
    if let Some(p) = users.plans.first() {
        return Ok(Deletion::InUse(format!(
            "trajectory {id} belongs to plan {p}; delete the plan (DELETE /v1/plans/{p})"
        )));
    }
    if let Some(e) = users.unfinished_executions.first() {
        return Ok(Deletion::InUse(format!(
            "trajectory {id} is used by execution {e}, which has not finished; cancel it \
             (POST /v1/executions/{e}/cancel) or wait until it has finished"
        )));
    }
    super::trajectories::delete_in(conn, id).await?;
    Ok(Deletion::Deleted)
}

/// Deletes trajectory `id` (one write transaction); see [`delete_trajectory_in`].
pub async fn delete_trajectory(pool: &SqlitePool, id: &str) -> Result<Deletion, sqlx::Error> {
    let mut tx = begin_write(pool).await?;
    let done = delete_trajectory_in(&mut tx, id).await?;
    if done == Deletion::Deleted {
        tx.commit().await?;
    }
    Ok(done)
}

/// How much to keep. `None` limits nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Policy {
    /// Expire rows older than this.
    pub max_age: Option<Duration>,
    /// Keep at most this many of each kind (plans; trajectories no plan owns; finished
    /// executions no plan owns), the newest.
    pub max_count: Option<u64>,
}

/// What one sweep deleted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Swept {
    pub plans: u64,
    pub trajectories: u64,
    pub executions: u64,
}

impl Swept {
    pub fn total(&self) -> u64 {
        self.plans + self.trajectories + self.executions
    }
}

/// Rows deleted per write transaction, so that a large backlog never holds the write lock long.
const BATCH: i64 = 100;

/// The ids of one kind beyond the policy, oldest first (at most [`BATCH`]). `own` selects the
/// rows of the kind (a SQL condition on the table aliased `r`).
async fn expired(
    pool: &SqlitePool,
    table: &str,
    own: &str,
    policy: &Policy,
    skip: &[String],
) -> Result<Vec<String>, sqlx::Error> {
    let cutoff = policy.max_age.map(|age| {
        let age = time::Duration::try_from(age).unwrap_or(time::Duration::MAX);
        format_timestamp(
            time::OffsetDateTime::now_utc()
                .checked_sub(age)
                .unwrap_or(time::OffsetDateTime::UNIX_EPOCH),
        )
    });
    // `LIMIT -1 OFFSET n`: every row after the newest n.
    let keep = policy
        .max_count
        .map(|n| i64::try_from(n).unwrap_or(i64::MAX));
    let sql = format!(
        "SELECT r.id FROM {table} r WHERE {own} AND (\
            (?1 IS NOT NULL AND r.created_at < ?1) OR \
            (?2 IS NOT NULL AND r.id IN (SELECT r.id FROM {table} r WHERE {own} \
                                         ORDER BY r.created_at DESC, r.id LIMIT -1 OFFSET ?2))) \
         ORDER BY r.created_at, r.id LIMIT ?3"
    );
    // `table` and `own` are the constants of `sweep`, never request data.
    let ids: Vec<String> = sqlx::query_scalar(sqlx::AssertSqlSafe(sql))
        .bind(cutoff)
        .bind(keep)
        .bind(BATCH + skip.len() as i64)
        .fetch_all(pool)
        .await?;
    Ok(ids.into_iter().filter(|id| !skip.contains(id)).collect())
}

/// Deletes what is beyond `policy`: plans (with what they own), trajectories no plan owns, and
/// finished executions no plan owns. Never anything a queued or running execution needs (those
/// are skipped, and counted among the kept). In batches of [`BATCH`] rows per transaction.
pub async fn sweep(pool: &SqlitePool, policy: &Policy) -> Result<Swept, sqlx::Error> {
    let mut swept = Swept::default();
    if policy.max_age.is_none() && policy.max_count.is_none() {
        return Ok(swept);
    }
    type DeleteIn = for<'c> fn(
        &'c mut SqliteConnection,
        &'c str,
    )
        -> futures::future::BoxFuture<'c, Result<Deletion, sqlx::Error>>;
    let kinds: [(&str, &str, DeleteIn); 3] = [
        ("plans", "1", |c, id| Box::pin(delete_plan_in(c, id))),
        (
            "trajectories",
            "NOT EXISTS (SELECT 1 FROM plans p WHERE p.trajectory_id = r.id)",
            |c, id| Box::pin(delete_trajectory_in(c, id)),
        ),
        (
            "executions",
            "r.state NOT IN ('queued', 'running') \
             AND NOT EXISTS (SELECT 1 FROM plans p WHERE p.execution_id = r.id)",
            |c, id| Box::pin(delete_execution_in(c, id)),
        ),
    ];
    for (table, own, delete) in kinds {
        let mut skip: Vec<String> = Vec::new();
        loop {
            let ids = expired(pool, table, own, policy, &skip).await?;
            if ids.is_empty() {
                break;
            }
            let mut tx = begin_write(pool).await?;
            let mut deleted = 0;
            for id in &ids {
                match delete(&mut tx, id).await? {
                    Deletion::Deleted => deleted += 1,
                    Deletion::NotFound => {}
                    Deletion::InUse(_) => skip.push(id.clone()),
                }
            }
            tx.commit().await?;
            match table {
                "plans" => swept.plans += deleted,
                "trajectories" => swept.trajectories += deleted,
                _ => swept.executions += deleted,
            }
            if deleted == 0 && ids.iter().all(|id| skip.contains(id)) {
                break;
            }
        }
    }
    Ok(swept)
}

/// Deletes execution `id` (with its feedback) unless it is queued or running.
pub async fn delete_execution_in(
    conn: &mut SqliteConnection,
    id: &str,
) -> Result<Deletion, sqlx::Error> {
    match execution_state(conn, id).await? {
        None => Ok(Deletion::NotFound),
        Some(state) if unfinished(&state) => {
            Ok(Deletion::InUse(format!("execution {id} is {state}")))
        }
        Some(_) => {
            sqlx::query("DELETE FROM executions WHERE id = ?")
                .bind(id)
                .execute(&mut *conn)
                .await?;
            Ok(Deletion::Deleted)
        }
    }
}

/// `PRAGMA wal_checkpoint(TRUNCATE)`: copies the WAL into the database and truncates it to
/// zero bytes when no reader holds it (otherwise it is truncated to `journal_size_limit` at a
/// later checkpoint). Returns (busy, WAL frames, frames checkpointed).
pub async fn checkpoint(pool: &SqlitePool) -> Result<(i64, i64, i64), sqlx::Error> {
    sqlx::query_as("PRAGMA wal_checkpoint(TRUNCATE)")
        .fetch_one(pool)
        .await
}

/// `PRAGMA integrity_check`: `ok` or the problems found.
pub async fn integrity_check(pool: &SqlitePool) -> Result<String, sqlx::Error> {
    let rows: Vec<String> = sqlx::query_scalar("PRAGMA integrity_check")
        .fetch_all(pool)
        .await?;
    Ok(rows.join("; "))
}
