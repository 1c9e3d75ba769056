//! Objects and grasps (migration 0004). Descriptions and results are stored as JSON text of the
//! `grasp` module's serde types (small, read whole).

use sqlx::{Sqlite, SqlitePool, Transaction};
use uuid::Uuid;

use super::now;

/// An object row.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct ObjectRow {
    pub id: String,
    pub name: String,
    pub spec: String,
    pub seeded: bool,
    pub created_at: String,
}

/// A grasp row.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct GraspRow {
    pub id: String,
    pub robot: String,
    pub object_id: Option<String>,
    pub object: String,
    pub request: String,
    pub result: String,
    pub feasible: bool,
    pub batch_id: Option<String>,
    pub created_at: String,
}

/// A batch row.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct BatchRow {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub count: i64,
    pub feasible: i64,
    pub created_at: String,
}

/// A grasp to insert.
#[derive(Debug, Clone)]
pub struct NewGrasp {
    pub robot: String,
    pub object_id: Option<String>,
    pub object: String,
    pub request: String,
    pub result: String,
    pub feasible: bool,
}

pub async fn insert_object(
    pool: &SqlitePool,
    name: &str,
    spec: &str,
) -> Result<ObjectRow, sqlx::Error> {
    let row = ObjectRow {
        id: Uuid::new_v4().to_string(),
        name: name.to_owned(),
        spec: spec.to_owned(),
        seeded: false,
        created_at: now(),
    };
    sqlx::query("INSERT INTO objects (id, name, spec, seeded, created_at) VALUES (?, ?, ?, 0, ?)")
        .bind(&row.id)
        .bind(&row.name)
        .bind(&row.spec)
        .bind(&row.created_at)
        .execute(pool)
        .await?;
    Ok(row)
}

pub async fn list_objects(pool: &SqlitePool) -> Result<Vec<ObjectRow>, sqlx::Error> {
    sqlx::query_as(
        "SELECT id, name, spec, seeded, created_at FROM objects ORDER BY created_at, name",
    )
    .fetch_all(pool)
    .await
}

pub async fn get_object(pool: &SqlitePool, id: &str) -> Result<Option<ObjectRow>, sqlx::Error> {
    sqlx::query_as("SELECT id, name, spec, seeded, created_at FROM objects WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// A seeded object by its name (`ball`, `bottle`, ...), so requests may name one instead of
/// giving its id.
pub async fn get_seeded_object(
    pool: &SqlitePool,
    name: &str,
) -> Result<Option<ObjectRow>, sqlx::Error> {
    sqlx::query_as(
        "SELECT id, name, spec, seeded, created_at FROM objects WHERE seeded = 1 AND name = ? \
         ORDER BY created_at, id LIMIT 1",
    )
    .bind(name)
    .fetch_optional(pool)
    .await
}

/// Names of the seeded objects, for error messages.
pub async fn seeded_object_names(pool: &SqlitePool) -> Result<Vec<String>, sqlx::Error> {
    sqlx::query_scalar("SELECT name FROM objects WHERE seeded = 1 ORDER BY name")
        .fetch_all(pool)
        .await
}

/// Deletes an object; returns whether it existed.
pub async fn delete_object(pool: &SqlitePool, id: &str) -> Result<bool, sqlx::Error> {
    let r = sqlx::query("DELETE FROM objects WHERE id = ?")
        .bind(id)
        .execute(pool)
        .await?;
    Ok(r.rows_affected() > 0)
}

/// Stores one grasp inside the caller's transaction (a plan stores its grasp with its other
/// rows); `batch` places it in a batch.
pub async fn insert_grasp_in(
    tx: &mut Transaction<'_, Sqlite>,
    g: &NewGrasp,
    batch: Option<(&str, i64)>,
) -> Result<GraspRow, sqlx::Error> {
    let row = GraspRow {
        id: Uuid::new_v4().to_string(),
        robot: g.robot.clone(),
        object_id: g.object_id.clone(),
        object: g.object.clone(),
        request: g.request.clone(),
        result: g.result.clone(),
        feasible: g.feasible,
        batch_id: batch.map(|b| b.0.to_owned()),
        created_at: now(),
    };
    sqlx::query(
        "INSERT INTO grasps (id, robot, object_id, object, request, result, feasible, batch_id, position, created_at) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(&row.id)
    .bind(&row.robot)
    .bind(&row.object_id)
    .bind(&row.object)
    .bind(&row.request)
    .bind(&row.result)
    .bind(row.feasible)
    .bind(&row.batch_id)
    .bind(batch.map(|b| b.1))
    .bind(&row.created_at)
    .execute(&mut **tx)
    .await?;
    Ok(row)
}

pub async fn insert_grasp(pool: &SqlitePool, g: &NewGrasp) -> Result<GraspRow, sqlx::Error> {
    let mut tx = super::begin_write(pool).await?;
    let row = insert_grasp_in(&mut tx, g, None).await?;
    tx.commit().await?;
    Ok(row)
}

/// Stores a batch and its grasps inside the job's result transaction; returns the batch id.
pub async fn insert_batch(
    tx: &mut Transaction<'_, Sqlite>,
    job_id: &str,
    robot: &str,
    grasps: &[NewGrasp],
) -> Result<String, sqlx::Error> {
    let id = Uuid::new_v4().to_string();
    let feasible = grasps.iter().filter(|g| g.feasible).count() as i64;
    sqlx::query("INSERT INTO grasp_batches (id, job_id, robot, count, feasible, created_at) VALUES (?, ?, ?, ?, ?, ?)")
        .bind(&id)
        .bind(job_id)
        .bind(robot)
        .bind(grasps.len() as i64)
        .bind(feasible)
        .bind(now())
        .execute(&mut **tx)
        .await?;
    for (k, g) in grasps.iter().enumerate() {
        insert_grasp_in(tx, g, Some((&id, k as i64))).await?;
    }
    Ok(id)
}

pub async fn get_grasp(pool: &SqlitePool, id: &str) -> Result<Option<GraspRow>, sqlx::Error> {
    sqlx::query_as(
        "SELECT id, robot, object_id, object, request, result, feasible, batch_id, created_at FROM grasps WHERE id = ?",
    )
    .bind(id)
    .fetch_optional(pool)
    .await
}

pub async fn get_batch(
    pool: &SqlitePool,
    id: &str,
) -> Result<Option<(BatchRow, Vec<String>)>, sqlx::Error> {
    let Some(b): Option<BatchRow> = sqlx::query_as(
        "SELECT id, job_id, robot, count, feasible, created_at FROM grasp_batches WHERE id = ?",
    )
    .bind(id)
    .fetch_optional(pool)
    .await?
    else {
        return Ok(None);
    };
    let ids: Vec<(String,)> =
        sqlx::query_as("SELECT id FROM grasps WHERE batch_id = ? ORDER BY position")
            .bind(id)
            .fetch_all(pool)
            .await?;
    Ok(Some((b, ids.into_iter().map(|r| r.0).collect())))
}

/// Whether any stored grasp or batch was computed for `robot` (`grasps.robot` is not a foreign
/// key, so deleting a robot asks here before it refuses with 409).
pub async fn robot_in_use(pool: &SqlitePool, robot: &str) -> Result<bool, sqlx::Error> {
    let (n,): (i64,) = sqlx::query_as(
        "SELECT (SELECT COUNT(*) FROM grasps WHERE robot = ?) + (SELECT COUNT(*) FROM grasp_batches WHERE robot = ?)",
    )
    .bind(robot)
    .bind(robot)
    .fetch_one(pool)
    .await?;
    Ok(n > 0)
}

/// The newest grasps first (the dashboard's list).
/// How many grasps are stored.
pub async fn count_grasps(pool: &SqlitePool) -> Result<i64, sqlx::Error> {
    sqlx::query_scalar("SELECT COUNT(*) FROM grasps")
        .fetch_one(pool)
        .await
}

pub async fn list_grasps(pool: &SqlitePool, limit: u32) -> Result<Vec<GraspRow>, sqlx::Error> {
    sqlx::query_as(
        "SELECT id, robot, object_id, object, request, result, feasible, batch_id, created_at \
         FROM grasps ORDER BY created_at DESC LIMIT ?",
    )
    .bind(i64::from(limit))
    .fetch_all(pool)
    .await
}
