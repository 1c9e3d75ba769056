//! Plans (migration 0009): the links from one `POST /v1/plans` to the grasp, trajectory and
//! execution it produced.

use sqlx::SqlitePool;
use uuid::Uuid;

use super::now;

#[derive(Debug, Clone, sqlx::FromRow)]
pub struct PlanRow {
    pub id: String,
    pub robot: String,
    pub model_id: Option<String>,
    pub grasp_id: String,
    pub trajectory_id: Option<String>,
    pub execution_id: Option<String>,
    pub feasible: bool,
    pub reason: Option<String>,
    pub request: String,
    pub timings: String,
    pub created_at: String,
}

/// The columns of [`PlanRow`] (a macro so queries stay `&'static str` literals).
macro_rules! columns {
    () => {
        "id, robot, model_id, grasp_id, trajectory_id, execution_id, feasible, reason, request, \
         timings, created_at"
    };
}

/// A plan to insert (id and timestamp are set here).
#[derive(Debug, Clone)]
pub struct NewPlan {
    pub robot: String,
    pub model_id: Option<String>,
    pub grasp_id: String,
    pub trajectory_id: Option<String>,
    pub execution_id: Option<String>,
    pub feasible: bool,
    pub reason: Option<String>,
    pub request: String,
    pub timings: String,
}

pub async fn insert(pool: &SqlitePool, p: NewPlan) -> Result<PlanRow, sqlx::Error> {
    let mut conn = pool.acquire().await?;
    insert_in(&mut conn, p).await
}

/// [`insert`] inside the caller's transaction (`&mut *tx`).
pub async fn insert_in(
    conn: &mut sqlx::SqliteConnection,
    p: NewPlan,
) -> Result<PlanRow, sqlx::Error> {
    let row = PlanRow {
        id: Uuid::new_v4().to_string(),
        robot: p.robot,
        model_id: p.model_id,
        grasp_id: p.grasp_id,
        trajectory_id: p.trajectory_id,
        execution_id: p.execution_id,
        feasible: p.feasible,
        reason: p.reason,
        request: p.request,
        timings: p.timings,
        created_at: now(),
    };
    sqlx::query(
        "INSERT INTO plans (id, robot, model_id, grasp_id, trajectory_id, execution_id, feasible, \
         reason, request, timings, created_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(&row.id)
    .bind(&row.robot)
    .bind(&row.model_id)
    .bind(&row.grasp_id)
    .bind(&row.trajectory_id)
    .bind(&row.execution_id)
    .bind(row.feasible)
    .bind(&row.reason)
    .bind(&row.request)
    .bind(&row.timings)
    .bind(&row.created_at)
    .execute(conn)
    .await?;
    Ok(row)
}

pub async fn get(pool: &SqlitePool, id: &str) -> Result<Option<PlanRow>, sqlx::Error> {
    sqlx::query_as(concat!("SELECT ", columns!(), " FROM plans WHERE id = ?"))
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// The plans of `ids` that exist, in no particular order (one query however many).
pub async fn get_many(pool: &SqlitePool, ids: &[&str]) -> Result<Vec<PlanRow>, sqlx::Error> {
    let ids = serde_json::to_string(ids).map_err(|e| sqlx::Error::Encode(Box::new(e)))?;
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM plans WHERE id IN (SELECT value FROM json_each(?))"
    ))
    .bind(ids)
    .fetch_all(pool)
    .await
}

/// The plan whose motion is trajectory `trajectory_id`, if a plan made it.
pub async fn of_trajectory(
    pool: &SqlitePool,
    trajectory_id: &str,
) -> Result<Option<PlanRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM plans WHERE trajectory_id = ? LIMIT 1"
    ))
    .bind(trajectory_id)
    .fetch_optional(pool)
    .await
}

/// The plan that queued execution `execution_id`, if a plan did (a plan queues at most one
/// execution, and an execution belongs to at most one plan).
pub async fn of_execution(
    pool: &SqlitePool,
    execution_id: &str,
) -> Result<Option<PlanRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM plans WHERE execution_id = ? LIMIT 1"
    ))
    .bind(execution_id)
    .fetch_optional(pool)
    .await
}

/// A page of plans, newest first, optionally of one robot; with the total count.
pub async fn list(
    pool: &SqlitePool,
    robot: Option<&str>,
    limit: i64,
    offset: i64,
) -> Result<(Vec<PlanRow>, i64), sqlx::Error> {
    let rows = sqlx::query_as(concat!(
        "SELECT ",
        columns!(),
        " FROM plans WHERE (?1 IS NULL OR robot = ?1) \
         ORDER BY created_at DESC, id LIMIT ?2 OFFSET ?3"
    ))
    .bind(robot)
    .bind(limit)
    .bind(offset)
    .fetch_all(pool)
    .await?;
    let total = sqlx::query_scalar("SELECT COUNT(*) FROM plans WHERE (?1 IS NULL OR robot = ?1)")
        .bind(robot)
        .fetch_one(pool)
        .await?;
    Ok((rows, total))
}

/// A plan as the dashboard lists it: the plan's links with its object's name, its grasp's task
/// directions (JSON), its trajectory's duration and its execution's state, read in one query
/// instead of three more per listed plan.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct PlanOverview {
    pub id: String,
    pub robot: String,
    pub grasp_id: String,
    pub trajectory_id: Option<String>,
    pub execution_id: Option<String>,
    pub feasible: bool,
    pub reason: Option<String>,
    pub created_at: String,
    pub object_name: Option<String>,
    pub task_directions: Option<String>,
    pub duration: Option<f64>,
    pub execution_state: Option<String>,
}

/// A page of [`PlanOverview`]s, newest first (the order of [`list`]); with the total count.
pub async fn list_overview(
    pool: &SqlitePool,
    limit: i64,
    offset: i64,
) -> Result<(Vec<PlanOverview>, i64), sqlx::Error> {
    let rows = sqlx::query_as(
        "SELECT p.id, p.robot, p.grasp_id, p.trajectory_id, p.execution_id, p.feasible, \
         p.reason, p.created_at, json_extract(g.object, '$.name') AS object_name, \
         json_extract(g.request, '$.task_directions') AS task_directions, \
         t.duration AS duration, e.state AS execution_state \
         FROM plans p LEFT JOIN grasps g ON g.id = p.grasp_id \
         LEFT JOIN trajectories t ON t.id = p.trajectory_id \
         LEFT JOIN executions e ON e.id = p.execution_id \
         ORDER BY p.created_at DESC, p.id LIMIT ?1 OFFSET ?2",
    )
    .bind(limit)
    .bind(offset)
    .fetch_all(pool)
    .await?;
    let total = sqlx::query_scalar("SELECT COUNT(*) FROM plans")
        .fetch_one(pool)
        .await?;
    Ok((rows, total))
}
