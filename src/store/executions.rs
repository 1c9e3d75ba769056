//! Executions and known bridge workers (migration 0007).
//!
//! The payload's trajectory points are stored as one numeric BLOB (`[n, 1 + 3 n_joints]`:
//! `t`, positions, velocities, accelerations per row); the rest of the payload as JSON. The
//! measured state history is in [`super::feedback`] (migration 0010), written in the same
//! transactions as the progress flushes and the final state change here.

use sqlx::SqlitePool;
use uuid::Uuid;

use super::feedback::{self, Chunk};
use super::{blob, now};
use crate::motion::TrajectoryPoint;
use crate::store::payload::{ExecutionPayload, Mode, PhysicsTrial};

/// An execution's state: `queued` and `running` are live, the others final. Stored and sent as
/// its snake_case name.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, sqlx::Type,
)]
#[serde(rename_all = "snake_case")]
#[sqlx(rename_all = "snake_case")]
pub enum ExecutionState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Aborted,
    Cancelled,
    Interrupted,
}

impl ExecutionState {
    pub const ALL: [ExecutionState; 7] = [
        ExecutionState::Queued,
        ExecutionState::Running,
        ExecutionState::Succeeded,
        ExecutionState::Failed,
        ExecutionState::Aborted,
        ExecutionState::Cancelled,
        ExecutionState::Interrupted,
    ];

    pub const fn as_str(self) -> &'static str {
        match self {
            ExecutionState::Queued => "queued",
            ExecutionState::Running => "running",
            ExecutionState::Succeeded => "succeeded",
            ExecutionState::Failed => "failed",
            ExecutionState::Aborted => "aborted",
            ExecutionState::Cancelled => "cancelled",
            ExecutionState::Interrupted => "interrupted",
        }
    }

    pub fn parse(s: &str) -> Option<ExecutionState> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// Whether the execution has ended (it never changes state again).
    pub fn is_final(self) -> bool {
        !matches!(self, ExecutionState::Queued | ExecutionState::Running)
    }
}

impl std::fmt::Display for ExecutionState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An execution row without its payload.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct ExecutionRow {
    pub id: String,
    pub robot: String,
    pub mode: Mode,
    pub kind: String,
    pub source_id: String,
    pub worker: Option<String>,
    pub state: ExecutionState,
    pub assigned_worker: Option<String>,
    pub reason: Option<String>,
    pub cancel_requested: bool,
    pub last_feedback: Option<String>,
    pub tracking: Option<String>,
    pub created_at: String,
    pub dispatched_at: Option<String>,
    pub finished_at: Option<String>,
    /// Samples in the stored feedback history.
    pub feedback_samples: i64,
    /// The execution ends in a grasp trial in physics (its scene and trial: [`trial`]).
    pub grasp_trial: bool,
}

/// The columns of [`ExecutionRow`] (a macro so queries stay `&'static str` literals).
macro_rules! columns {
    () => {
        "id, robot, mode, kind, source_id, worker, state, assigned_worker, reason, \
         cancel_requested, last_feedback, tracking, created_at, dispatched_at, finished_at, \
         trial IS NOT NULL AS grasp_trial, (SELECT COALESCE(SUM(f.samples), 0) FROM execution_feedback f \
          WHERE f.execution_id = executions.id) AS feedback_samples"
    };
}

/// The JSON part of a payload (points travel in the BLOB).
fn split_payload(p: &ExecutionPayload) -> Result<(String, Option<Vec<u8>>), sqlx::Error> {
    let enc = |e: blob::BlobError| sqlx::Error::Encode(Box::new(e));
    match p {
        ExecutionPayload::Trajectory {
            trajectory_id,
            joint_names,
            points,
        } => {
            let n = joint_names.len();
            let width = 1 + 3 * n;
            let mut data = Vec::with_capacity(points.len() * width);
            for pt in points {
                data.push(pt.t);
                data.extend_from_slice(&pt.positions);
                data.extend_from_slice(&pt.velocities);
                data.extend_from_slice(&pt.accelerations);
            }
            let bytes = blob::encode(&[points.len(), width], &data).map_err(enc)?;
            let meta = ExecutionPayload::Trajectory {
                trajectory_id: trajectory_id.clone(),
                joint_names: joint_names.clone(),
                points: Vec::new(),
            };
            Ok((
                serde_json::to_string(&meta).map_err(|e| sqlx::Error::Encode(Box::new(e)))?,
                Some(bytes),
            ))
        }
        ExecutionPayload::Model { .. } | ExecutionPayload::Stream { .. } => Ok((
            serde_json::to_string(p).map_err(|e| sqlx::Error::Encode(Box::new(e)))?,
            None,
        )),
    }
}

fn join_payload(json: &str, points: Option<&[u8]>) -> Result<ExecutionPayload, sqlx::Error> {
    let dec = |e: Box<dyn std::error::Error + Send + Sync>| sqlx::Error::Decode(e);
    let mut p: ExecutionPayload = serde_json::from_str(json).map_err(|e| dec(Box::new(e)))?;
    if let (
        ExecutionPayload::Trajectory {
            joint_names,
            points: out,
            ..
        },
        Some(bytes),
    ) = (&mut p, points)
    {
        let a = blob::decode::<f64>(bytes).map_err(|e| dec(Box::new(e)))?;
        let n = joint_names.len();
        let width = 1 + 3 * n;
        if a.shape.len() != 2 || a.shape[1] != width {
            return Err(dec(format!(
                "points blob has shape {:?}, expected [_, {width}]",
                a.shape
            )
            .into()));
        }
        *out = a
            .data
            .chunks_exact(width)
            .map(|r| TrajectoryPoint {
                t: r[0],
                positions: r[1..1 + n].to_vec(),
                velocities: r[1 + n..1 + 2 * n].to_vec(),
                accelerations: r[1 + 2 * n..].to_vec(),
            })
            .collect();
    }
    Ok(p)
}

/// Inserts a queued execution; returns its row.
pub async fn insert(
    pool: &SqlitePool,
    robot: &str,
    mode: Mode,
    payload: &ExecutionPayload,
    worker: Option<&str>,
) -> Result<ExecutionRow, sqlx::Error> {
    let mut conn = pool.acquire().await?;
    insert_in(&mut conn, robot, mode, payload, worker, None).await
}

/// [`insert`] on a connection or inside a transaction (`&mut *tx`).
pub async fn insert_in(
    conn: &mut sqlx::SqliteConnection,
    robot: &str,
    mode: Mode,
    payload: &ExecutionPayload,
    worker: Option<&str>,
    trial: Option<&PhysicsTrial>,
) -> Result<ExecutionRow, sqlx::Error> {
    let row = ExecutionRow {
        id: Uuid::new_v4().to_string(),
        robot: robot.to_owned(),
        mode,
        kind: payload.kind().to_owned(),
        source_id: payload.source_id().to_owned(),
        worker: worker.map(str::to_owned),
        state: ExecutionState::Queued,
        assigned_worker: None,
        reason: None,
        cancel_requested: false,
        last_feedback: None,
        tracking: None,
        created_at: now(),
        dispatched_at: None,
        finished_at: None,
        feedback_samples: 0,
        grasp_trial: trial.is_some(),
    };
    write_row(conn, &row, payload, trial).await?;
    Ok(row)
}

/// Inserts execution `id` already `running` on `worker` (a stream: it starts on the worker the
/// caller claimed, never through the queue).
pub async fn insert_running(
    pool: &SqlitePool,
    id: &str,
    robot: &str,
    payload: &ExecutionPayload,
    worker: &str,
) -> Result<(), sqlx::Error> {
    let now = now();
    let row = ExecutionRow {
        id: id.to_owned(),
        robot: robot.to_owned(),
        mode: payload.mode(),
        kind: payload.kind().to_owned(),
        source_id: payload.source_id().to_owned(),
        worker: Some(worker.to_owned()),
        state: ExecutionState::Running,
        assigned_worker: Some(worker.to_owned()),
        reason: None,
        cancel_requested: false,
        last_feedback: None,
        tracking: None,
        created_at: now.clone(),
        dispatched_at: Some(now),
        finished_at: None,
        feedback_samples: 0,
        grasp_trial: false,
    };
    let mut conn = pool.acquire().await?;
    write_row(&mut conn, &row, payload, None).await
}

/// Writes a new execution row with its payload (the columns a new execution has).
async fn write_row(
    conn: &mut sqlx::SqliteConnection,
    row: &ExecutionRow,
    payload: &ExecutionPayload,
    trial: Option<&PhysicsTrial>,
) -> Result<(), sqlx::Error> {
    let (json, points) = split_payload(payload)?;
    let trial = trial
        .map(serde_json::to_string)
        .transpose()
        .map_err(|e| sqlx::Error::Encode(Box::new(e)))?;
    sqlx::query(
        "INSERT INTO executions (id, robot, mode, kind, source_id, payload, points, worker, \
         state, assigned_worker, created_at, dispatched_at, trial) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(&row.id)
    .bind(&row.robot)
    .bind(row.mode)
    .bind(&row.kind)
    .bind(&row.source_id)
    .bind(&json)
    .bind(&points)
    .bind(&row.worker)
    .bind(row.state)
    .bind(&row.assigned_worker)
    .bind(&row.created_at)
    .bind(&row.dispatched_at)
    .bind(&trial)
    .execute(conn)
    .await
    .map(|_| ())
}

pub async fn get(pool: &SqlitePool, id: &str) -> Result<Option<ExecutionRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM executions WHERE id = ?"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// The grasp trial an execution ends in, with its scene (`None`: none, or no such execution).
pub async fn trial(pool: &SqlitePool, id: &str) -> Result<Option<PhysicsTrial>, sqlx::Error> {
    let row: Option<(Option<String>,)> =
        sqlx::query_as("SELECT trial FROM executions WHERE id = ?")
            .bind(id)
            .fetch_optional(pool)
            .await?;
    row.and_then(|(t,)| t)
        .map(|t| serde_json::from_str(&t).map_err(|e| sqlx::Error::Decode(Box::new(e))))
        .transpose()
}

/// The executions of `ids` that exist, each with its grasp trial (if it ends in one), in no
/// particular order (one query however many).
pub async fn get_many_with_trial(
    pool: &SqlitePool,
    ids: &[&str],
) -> Result<Vec<(ExecutionRow, Option<PhysicsTrial>)>, sqlx::Error> {
    use sqlx::{FromRow, Row};
    let ids = serde_json::to_string(ids).map_err(|e| sqlx::Error::Encode(Box::new(e)))?;
    let rows = sqlx::query(concat!(
        "SELECT ",
        columns!(),
        ", trial FROM executions WHERE id IN (SELECT value FROM json_each(?))"
    ))
    .bind(ids)
    .fetch_all(pool)
    .await?;
    rows.iter()
        .map(|row| {
            let trial = row
                .try_get::<Option<String>, _>("trial")?
                .map(|t| serde_json::from_str(&t).map_err(|e| sqlx::Error::Decode(Box::new(e))))
                .transpose()?;
            Ok((ExecutionRow::from_row(row)?, trial))
        })
        .collect()
}

/// The stored payload of an execution.
pub async fn payload(pool: &SqlitePool, id: &str) -> Result<Option<ExecutionPayload>, sqlx::Error> {
    let row: Option<(String, Option<Vec<u8>>)> =
        sqlx::query_as("SELECT payload, points FROM executions WHERE id = ?")
            .bind(id)
            .fetch_optional(pool)
            .await?;
    row.map(|(json, points)| join_payload(&json, points.as_deref()))
        .transpose()
}

/// The joint names of an execution's payload (without decoding its points).
pub async fn joint_names(pool: &SqlitePool, id: &str) -> Result<Option<Vec<String>>, sqlx::Error> {
    let row: Option<(String,)> = sqlx::query_as("SELECT payload FROM executions WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?;
    row.map(|(json,)| join_payload(&json, None).map(|p| p.joint_names().to_vec()))
        .transpose()
}

/// A page of executions, newest first, optionally of one state and/or robot.
pub async fn list(
    pool: &SqlitePool,
    state: Option<ExecutionState>,
    robot: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<Vec<ExecutionRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM executions WHERE (?1 IS NULL OR state = ?1) AND (?2 IS NULL OR robot = ?2) \
         ORDER BY created_at DESC, id LIMIT ?3 OFFSET ?4"
    ))
    .bind(state)
    .bind(robot)
    .bind(limit as i64)
    .bind(offset as i64)
    .fetch_all(pool)
    .await
}

/// Queued executions, oldest first (the dispatch order).
pub async fn queued(pool: &SqlitePool) -> Result<Vec<ExecutionRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM executions WHERE state = 'queued' ORDER BY created_at, id"
    ))
    .fetch_all(pool)
    .await
}

/// The newest execution that will run on worker `worker` of `robot` before anything queued
/// now: the one it runs, or a queued one pinned to it or to no worker; its id and payload.
pub async fn last_pending(
    pool: &SqlitePool,
    robot: &str,
    worker: &str,
) -> Result<Option<(String, ExecutionPayload)>, sqlx::Error> {
    let row: Option<(String, String, Option<Vec<u8>>)> = sqlx::query_as(
        "SELECT id, payload, points FROM executions WHERE robot = ?1 AND \
         ((state = 'running' AND assigned_worker = ?2) OR \
          (state = 'queued' AND (worker IS NULL OR worker = ?2))) \
         ORDER BY created_at DESC, id DESC LIMIT 1",
    )
    .bind(robot)
    .bind(worker)
    .fetch_optional(pool)
    .await?;
    row.map(|(id, json, points)| Ok((id, join_payload(&json, points.as_deref())?)))
        .transpose()
}

/// `queued` → `running` on `worker`; false if it was no longer queued (cancelled meanwhile).
pub async fn mark_running(pool: &SqlitePool, id: &str, worker: &str) -> Result<bool, sqlx::Error> {
    let r = sqlx::query(
        "UPDATE executions SET state = 'running', assigned_worker = ?, dispatched_at = ? \
         WHERE id = ? AND state = 'queued'",
    )
    .bind(worker)
    .bind(now())
    .bind(id)
    .execute(pool)
    .await?;
    Ok(r.rows_affected() == 1)
}

/// Back to `queued` (the dispatch could not be delivered).
pub async fn requeue(pool: &SqlitePool, id: &str) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE executions SET state = 'queued', assigned_worker = NULL, dispatched_at = NULL \
         WHERE id = ? AND state = 'running'",
    )
    .bind(id)
    .execute(pool)
    .await
    .map(|_| ())
}

/// Stores the latest feedback, the tracking summary and the new part of the feedback history
/// of a running execution, in one transaction; false (nothing written) if it is no longer
/// running.
pub async fn save_progress(
    pool: &SqlitePool,
    id: &str,
    last_feedback: &str,
    tracking: &str,
    history: Option<&Chunk>,
) -> Result<bool, sqlx::Error> {
    let mut tx = super::begin_write(pool).await?;
    let r = sqlx::query(
        "UPDATE executions SET last_feedback = ?, tracking = ? WHERE id = ? AND state = 'running'",
    )
    .bind(last_feedback)
    .bind(tracking)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    append_history_and_commit(tx, r.rows_affected(), id, history).await
}

/// The common end of [`save_progress`] and [`finish`]: when their state update touched the
/// execution's row, append the history chunk and commit; otherwise drop the transaction (nothing
/// written) and answer false.
async fn append_history_and_commit(
    mut tx: sqlx::Transaction<'_, sqlx::Sqlite>,
    rows_affected: u64,
    id: &str,
    history: Option<&Chunk>,
) -> Result<bool, sqlx::Error> {
    if rows_affected != 1 {
        return Ok(false);
    }
    if let Some(c) = history {
        feedback::write_chunk(&mut tx, id, c).await?;
    }
    tx.commit().await?;
    Ok(true)
}

/// Moves a live execution to a final state (with the last feedback and the rest of the
/// feedback history, when known) in one transaction; false if it was already final.
pub async fn finish(
    pool: &SqlitePool,
    id: &str,
    state: ExecutionState,
    reason: Option<&str>,
    last_feedback: Option<&str>,
    tracking: Option<&str>,
    history: Option<&Chunk>,
) -> Result<bool, sqlx::Error> {
    debug_assert!(state.is_final());
    let mut tx = super::begin_write(pool).await?;
    let r = sqlx::query(
        "UPDATE executions SET state = ?, reason = ?, finished_at = ?, \
         last_feedback = COALESCE(?, last_feedback), tracking = COALESCE(?, tracking) \
         WHERE id = ? AND state IN ('queued', 'running')",
    )
    .bind(state)
    .bind(reason)
    .bind(now())
    .bind(last_feedback)
    .bind(tracking)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    append_history_and_commit(tx, r.rows_affected(), id, history).await
}

pub async fn set_cancel_requested(pool: &SqlitePool, id: &str) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE executions SET cancel_requested = 1 WHERE id = ?")
        .bind(id)
        .execute(pool)
        .await
        .map(|_| ())
}

/// At start: executions left `running` by a previous process lost their worker connection with
/// it; they become `interrupted` (their last flushed feedback is kept). Returns how many.
pub async fn recover_interrupted(pool: &SqlitePool) -> Result<u64, sqlx::Error> {
    let r = sqlx::query(
        "UPDATE executions SET state = 'interrupted', finished_at = ?, \
         reason = 'the service stopped while the execution was running' WHERE state = 'running'",
    )
    .bind(now())
    .execute(pool)
    .await?;
    Ok(r.rows_affected())
}

/// A known worker.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct BridgeRow {
    pub name: String,
    pub robot: String,
    pub joint_names: String,
    pub capabilities: String,
    pub first_seen_at: String,
    pub last_connected_at: String,
    pub last_seen_at: String,
}

/// Records a worker's hello.
pub async fn upsert_bridge(
    pool: &SqlitePool,
    name: &str,
    robot: &str,
    joint_names: &str,
    capabilities: &str,
) -> Result<(), sqlx::Error> {
    let t = now();
    sqlx::query(
        "INSERT INTO bridges (name, robot, joint_names, capabilities, first_seen_at, last_connected_at, last_seen_at) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?5, ?5) \
         ON CONFLICT (name) DO UPDATE SET robot = ?2, joint_names = ?3, capabilities = ?4, \
         last_connected_at = ?5, last_seen_at = ?5",
    )
    .bind(name)
    .bind(robot)
    .bind(joint_names)
    .bind(capabilities)
    .bind(&t)
    .execute(pool)
    .await
    .map(|_| ())
}

pub async fn touch_bridge(pool: &SqlitePool, name: &str) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE bridges SET last_seen_at = ? WHERE name = ?")
        .bind(now())
        .bind(name)
        .execute(pool)
        .await
        .map(|_| ())
}

pub async fn list_bridges(pool: &SqlitePool) -> Result<Vec<BridgeRow>, sqlx::Error> {
    sqlx::query_as(
        "SELECT name, robot, joint_names, capabilities, first_seen_at, last_connected_at, last_seen_at \
         FROM bridges ORDER BY name",
    )
    .fetch_all(pool)
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn payload_points_round_trip_through_the_blob_and_states_move_once() {
        let dir = tempfile::tempdir().unwrap();
        let pool = super::super::connect(&dir.path().join("t.db"))
            .await
            .unwrap();
        let p = ExecutionPayload::Trajectory {
            trajectory_id: "inline".into(),
            joint_names: vec!["a".into(), "b".into()],
            points: (0..5)
                .map(|i| TrajectoryPoint {
                    t: i as f64 * 0.1,
                    positions: vec![i as f64, -(i as f64)],
                    velocities: vec![1.0, -1.0],
                    accelerations: vec![0.0, 0.5],
                })
                .collect(),
        };
        let row = insert(&pool, "wam_ihy", Mode::OpenLoop, &p, None)
            .await
            .unwrap();
        assert_eq!(payload(&pool, &row.id).await.unwrap().unwrap(), p);
        assert_eq!(queued(&pool).await.unwrap().len(), 1);
        assert!(mark_running(&pool, &row.id, "w").await.unwrap());
        assert!(!mark_running(&pool, &row.id, "w").await.unwrap());
        assert_eq!(recover_interrupted(&pool).await.unwrap(), 1);
        let after = get(&pool, &row.id).await.unwrap().unwrap();
        assert_eq!(after.state, ExecutionState::Interrupted);
        assert!(
            !finish(
                &pool,
                &row.id,
                ExecutionState::Failed,
                None,
                None,
                None,
                None
            )
            .await
            .unwrap()
        );
    }

    /// Migration 0012 rebuilds `executions` on a database that already holds executions with
    /// stored feedback: every row and its feedback survive (dropping the old table did not
    /// cascade), the indexes are back, foreign keys still cascade, and a streaming execution
    /// can be stored.
    #[tokio::test]
    async fn the_streaming_migration_keeps_executions_and_their_feedback() {
        use sqlx::sqlite::SqlitePoolOptions;
        use std::borrow::Cow;
        let dir = tempfile::tempdir().unwrap();
        let options = sqlx::sqlite::SqliteConnectOptions::new()
            .filename(dir.path().join("old.db"))
            .create_if_missing(true)
            .foreign_keys(true);
        let pool = SqlitePoolOptions::new()
            .max_connections(2)
            .connect_with(options)
            .await
            .unwrap();
        let mut before = sqlx::migrate!("./migrations");
        before.migrations = Cow::Owned(
            before
                .migrations
                .iter()
                .filter(|m| m.version < 12)
                .cloned()
                .collect(),
        );
        before.run(&pool).await.unwrap();
        let p = ExecutionPayload::Trajectory {
            trajectory_id: "inline".into(),
            joint_names: vec!["a".into()],
            points: vec![TrajectoryPoint {
                t: 0.0,
                positions: vec![0.5],
                velocities: vec![0.0],
                accelerations: vec![0.0],
            }],
        };
        // (rows written as the store of that time wrote them: its columns only)
        let old_row = |id: &str, mode: &str, kind: &str, p: &ExecutionPayload| {
            let (json, points) = split_payload(p).unwrap();
            sqlx::query(
                "INSERT INTO executions (id, robot, mode, kind, source_id, payload, points, \
                 worker, state, created_at) VALUES (?, 'wam_ihy', ?, ?, 'inline', ?, ?, 'w', \
                 'queued', ?)",
            )
            .bind(id.to_owned())
            .bind(mode.to_owned())
            .bind(kind.to_owned())
            .bind(json)
            .bind(points)
            .bind(now())
        };
        old_row("old", "open_loop", "trajectory", &p)
            .execute(&pool)
            .await
            .unwrap();
        sqlx::query("INSERT INTO execution_feedback (execution_id, chunk, samples, data) VALUES ('old', 0, 3, x'00')")
            .execute(&pool)
            .await
            .unwrap();
        // Before 0012 the store refuses a streaming execution.
        let stream = ExecutionPayload::Stream {
            source: "retarget".into(),
            joint_names: vec!["a".into()],
            hold_after_s: 0.2,
        };
        assert!(
            old_row("s0", "streaming", "stream", &stream)
                .execute(&pool)
                .await
                .is_err()
        );

        super::super::MIGRATOR.run(&pool).await.unwrap();
        let kept = get(&pool, "old").await.unwrap().unwrap();
        assert_eq!(kept.worker.as_deref(), Some("w"));
        assert_eq!(
            kept.feedback_samples, 3,
            "the feedback survived the rebuild"
        );
        assert_eq!(payload(&pool, "old").await.unwrap().unwrap(), p);
        let indexes: Vec<String> = sqlx::query_scalar(
            "SELECT name FROM sqlite_master WHERE type = 'index' AND tbl_name = 'executions' \
             AND name NOT LIKE 'sqlite_%' ORDER BY name",
        )
        .fetch_all(&pool)
        .await
        .unwrap();
        assert_eq!(
            indexes,
            [
                "executions_by_source",
                "executions_created",
                "executions_state_created"
            ]
        );
        insert_running(&pool, "s1", "wam_ihy", &stream, "w")
            .await
            .unwrap();
        let s = get(&pool, "s1").await.unwrap().unwrap();
        assert_eq!((s.mode, s.kind.as_str()), (Mode::Streaming, "stream"));
        assert_eq!(s.state, ExecutionState::Running);
        assert_eq!(payload(&pool, "s1").await.unwrap().unwrap(), stream);
        let fk: i64 = sqlx::query_scalar("PRAGMA foreign_keys")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(fk, 1, "foreign keys are on again after the migration");
        sqlx::query("DELETE FROM executions WHERE id = 'old'")
            .execute(&pool)
            .await
            .unwrap();
        let left: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM execution_feedback")
            .fetch_one(&pool)
            .await
            .unwrap();
        assert_eq!(
            left, 0,
            "deleting an execution still cascades to its feedback"
        );
    }
}
