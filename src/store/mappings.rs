//! The `mappings` and `mapping_demonstrations` tables (migration 0005).
//!
//! A mapping row exists from submission on (its status is its job's); the summary and the
//! per-demonstration rows are written by [`store_results`] inside the transaction that marks the
//! job succeeded, so a failed or cancelled mapping never has part of its results stored.
//! Joint trajectories and per-frame metrics are `store::blob` arrays (see the migration).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use sqlx::sqlite::SqliteRow;
use sqlx::{Sqlite, SqlitePool, Transaction};

use crate::mapping::{FrameMetrics, MAX_FINGERS, MappedTrajectory, Registration};
use crate::store::blob;

/// A mapping and its job's status.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct MappingRow {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    /// The job's: `queued|running|succeeded|failed|cancelled`.
    pub status: String,
    /// The validated request (JSON).
    pub request: String,
    /// Aggregate metrics (JSON), set once the job succeeded.
    pub summary: Option<String>,
    pub created_at: String,
}

/// One demonstration of a succeeded mapping, decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredMappedDemo {
    pub demonstration_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: u32,
    pub trial: u32,
    pub trajectory: MappedTrajectory,
}

/// A stored mapped demonstration without its arrays (for listings).
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct MappedDemoRow {
    /// Place in the request order, from 0.
    pub position: i64,
    pub demonstration_id: String,
    pub subject_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: i64,
    pub trial: i64,
    pub frame_count: i64,
    /// Per-demonstration aggregate metrics (JSON).
    pub summary: String,
}

#[derive(Debug, sqlx::FromRow)]
struct FullDemoRow {
    #[sqlx(flatten)]
    meta: MappedDemoRow,
    joint_names: String,
    frames: Vec<u8>,
    metrics: Vec<u8>,
    registration: String,
}

/// Column layout of the `metrics` BLOB (one row of f64 per frame).
pub const METRIC_COLUMNS: [&str; 23] = [
    "t",
    "fingers",
    "position_error[0]",
    "position_error[1]",
    "position_error[2]",
    "position_error[3]",
    "position_error[4]",
    "orientation_error[0]",
    "orientation_error[1]",
    "orientation_error[2]",
    "orientation_error[3]",
    "orientation_error[4]",
    "elbow_distance",
    "elbow_distance_mean",
    "objective",
    "iterations",
    "converged",
    "swivel_human",
    "swivel_robot",
    "swivel_difference",
    "elbow_bound",
    "support_clearance",
    "object_clearance",
];
const METRIC_WIDTH: usize = METRIC_COLUMNS.len();
/// Rows stored before the swivel and clearance columns (read with those NaN).
const METRIC_WIDTH_V1: usize = 17;
const _: () = assert!(MAX_FINGERS == 5, "METRIC_COLUMNS spells out five fingers");

/// A mapping row to create at submission.
#[derive(Debug, Clone)]
pub struct NewMapping {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub request: String,
    pub created_at: String,
}

/// One mapped demonstration, encoded for [`store_results`] (encode off the async runtime with
/// [`encode_demo`]: the arrays can be large).
#[derive(Debug, Clone)]
pub struct NewMappedDemo {
    pub demonstration_id: String,
    pub subject_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: u32,
    pub trial: u32,
    pub frame_count: usize,
    joint_names: String,
    frames: Vec<u8>,
    metrics: Vec<u8>,
    registration: String,
    /// Per-demonstration aggregate metrics (JSON).
    pub summary: String,
}

/// The labels a stored mapped demonstration carries (copied from the demonstration).
#[derive(Debug, Clone)]
pub struct DemoLabels {
    pub demonstration_id: String,
    pub subject_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: u32,
    pub trial: u32,
}

/// A stored [`Registration`]. Rows written before the scene-keeping registration carry only
/// `rotation`, `translation` and `scale` (a similarity anchored at the tracker origin).
#[derive(serde::Serialize, serde::Deserialize)]
struct RegistrationJson {
    /// `[w, x, y, z]`.
    rotation: [f64; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    translation: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scale: Option<f64>,
    #[serde(default)]
    human_anchor: [f64; 3],
    #[serde(default)]
    robot_anchor: Option<[f64; 3]>,
    #[serde(default)]
    up: Option<[f64; 3]>,
    #[serde(default)]
    transport_scale: Option<f64>,
    #[serde(default)]
    vertical_scale: Option<f64>,
    #[serde(default)]
    hand_scale: Option<f64>,
    #[serde(default)]
    support: Option<f64>,
    #[serde(default)]
    object: Option<ObjectJson>,
    /// Hand-only systems: the robot hand root's frame the fingertips are registered in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    hand_frame: Option<PoseJson>,
}

/// A pose: position and `[w, x, y, z]` orientation.
#[derive(serde::Serialize, serde::Deserialize)]
struct PoseJson {
    position: [f64; 3],
    orientation: [f64; 4],
}

#[derive(serde::Serialize, serde::Deserialize)]
struct ObjectJson {
    shape: crate::human::ObjectShape,
    position: [f64; 3],
    /// `[w, x, y, z]`.
    orientation: [f64; 4],
}

impl RegistrationJson {
    fn of(r: &Registration) -> Self {
        let q = r.rotation.quaternion();
        let p3 = |p: &nalgebra::Point3<f64>| [p.x, p.y, p.z];
        RegistrationJson {
            rotation: [q.w, q.i, q.j, q.k],
            translation: None,
            scale: None,
            human_anchor: p3(&r.human_anchor),
            robot_anchor: Some(p3(&r.robot_anchor)),
            up: Some([r.up.x, r.up.y, r.up.z]),
            transport_scale: Some(r.transport_scale),
            vertical_scale: Some(r.vertical_scale),
            hand_scale: Some(r.hand_scale),
            support: r.support,
            object: r.object.map(|o| {
                let t = o.pose.translation.vector;
                let q = o.pose.rotation.quaternion();
                ObjectJson {
                    shape: o.shape,
                    position: [t.x, t.y, t.z],
                    orientation: [q.w, q.i, q.j, q.k],
                }
            }),
            hand_frame: r.hand_frame.map(|f| {
                let t = f.translation.vector;
                let q = f.rotation.quaternion();
                PoseJson {
                    position: [t.x, t.y, t.z],
                    orientation: [q.w, q.i, q.j, q.k],
                }
            }),
        }
    }

    fn registration(&self) -> Registration {
        let quat =
            |[w, x, y, z]: [f64; 4]| UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let old = self.scale.unwrap_or(1.0);
        Registration {
            rotation: quat(self.rotation),
            human_anchor: self.human_anchor.into(),
            robot_anchor: self
                .robot_anchor
                .or(self.translation)
                .unwrap_or_default()
                .into(),
            up: self.up.map_or(Vector3::z(), Vector3::from),
            transport_scale: self.transport_scale.unwrap_or(old),
            vertical_scale: self.vertical_scale.unwrap_or(old),
            hand_scale: self.hand_scale.unwrap_or(old),
            support: self.support,
            object: self.object.as_ref().map(|o| crate::mapping::HumanObject {
                shape: o.shape,
                pose: nalgebra::Isometry3::from_parts(
                    Vector3::from(o.position).into(),
                    quat(o.orientation),
                ),
            }),
            hand_frame: self.hand_frame.as_ref().map(|f| {
                nalgebra::Isometry3::from_parts(
                    Vector3::from(f.position).into(),
                    quat(f.orientation),
                )
            }),
        }
    }
}

fn encode_err(e: impl std::fmt::Display) -> sqlx::Error {
    sqlx::Error::Encode(e.to_string().into())
}

/// Encodes a mapped trajectory and its labels for storage.
pub fn encode_demo(
    labels: DemoLabels,
    trajectory: &MappedTrajectory,
    summary: String,
) -> Result<NewMappedDemo, sqlx::Error> {
    let n = trajectory.times.len();
    let nq = trajectory.nq();
    if trajectory.positions.len() != n * nq || trajectory.metrics.len() != n {
        return Err(encode_err(format!(
            "mapped trajectory of {} has {n} times, {} positions for {nq} joints and {} metric rows",
            labels.demonstration_id,
            trajectory.positions.len(),
            trajectory.metrics.len()
        )));
    }
    let mut frames = Vec::with_capacity(n * (1 + nq));
    let mut metrics = Vec::with_capacity(n * METRIC_WIDTH);
    for k in 0..n {
        frames.push(trajectory.times[k]);
        frames.extend_from_slice(trajectory.frame(k));
        let m = &trajectory.metrics[k];
        metrics.push(m.t);
        metrics.push(m.fingers as f64);
        metrics.extend_from_slice(&m.position_error);
        metrics.extend_from_slice(&m.orientation_error);
        metrics.extend_from_slice(&[
            m.elbow_distance,
            m.elbow_distance_mean,
            m.objective,
            m.iterations as f64,
            if m.converged { 1.0 } else { 0.0 },
            m.swivel_human,
            m.swivel_robot,
            m.swivel_difference,
            m.elbow_bound,
            m.support_clearance,
            m.object_clearance,
        ]);
    }
    let registration = RegistrationJson::of(&trajectory.registration);
    Ok(NewMappedDemo {
        demonstration_id: labels.demonstration_id,
        subject_id: labels.subject_id,
        object_name: labels.object_name,
        task: labels.task,
        position_index: labels.position_index,
        trial: labels.trial,
        frame_count: n,
        joint_names: serde_json::to_string(&trajectory.joint_names).map_err(encode_err)?,
        frames: blob::encode(&[n, 1 + nq], &frames).map_err(encode_err)?,
        metrics: blob::encode(&[n, METRIC_WIDTH], &metrics).map_err(encode_err)?,
        registration: serde_json::to_string(&registration).map_err(encode_err)?,
        summary,
    })
}

fn decode_err(what: &str, id: &str, e: impl std::fmt::Display) -> sqlx::Error {
    sqlx::Error::Decode(format!("mapping_demonstrations.{what} of {id}: {e}").into())
}

impl FullDemoRow {
    fn decode(self) -> Result<StoredMappedDemo, sqlx::Error> {
        let id = self.meta.demonstration_id.clone();
        let joint_names: Vec<String> = serde_json::from_str(&self.joint_names)
            .map_err(|e| decode_err("joint_names", &id, e))?;
        let nq = joint_names.len();
        let frames = blob::decode::<f64>(&self.frames).map_err(|e| decode_err("frames", &id, e))?;
        let metrics =
            blob::decode::<f64>(&self.metrics).map_err(|e| decode_err("metrics", &id, e))?;
        let n = usize::try_from(self.meta.frame_count)
            .map_err(|e| decode_err("frame_count", &id, e))?;
        let width = metrics.shape.get(1).copied().unwrap_or(0);
        if frames.shape != [n, 1 + nq]
            || metrics.shape.len() != 2
            || metrics.shape[0] != n
            || !(width == METRIC_WIDTH || width == METRIC_WIDTH_V1)
        {
            return Err(decode_err(
                "frames/metrics",
                &id,
                format!(
                    "shapes {:?} and {:?} do not match {n} frames of {nq} joints",
                    frames.shape, metrics.shape
                ),
            ));
        }
        let mut times = Vec::with_capacity(n);
        let mut positions = Vec::with_capacity(n * nq);
        for row in frames.data.chunks_exact(1 + nq) {
            times.push(row[0]);
            positions.extend_from_slice(&row[1..]);
        }
        let metrics = metrics
            .data
            .chunks_exact(width)
            .map(|r| FrameMetrics {
                t: r[0],
                fingers: r[1] as usize,
                position_error: std::array::from_fn(|i| r[2 + i]),
                orientation_error: std::array::from_fn(|i| r[7 + i]),
                elbow_distance: r[12],
                elbow_distance_mean: r[13],
                objective: r[14],
                iterations: r[15] as usize,
                converged: r[16] != 0.0,
                swivel_human: r.get(17).copied().unwrap_or(f64::NAN),
                swivel_robot: r.get(18).copied().unwrap_or(f64::NAN),
                swivel_difference: r.get(19).copied().unwrap_or(f64::NAN),
                elbow_bound: r.get(20).copied().unwrap_or(f64::NAN),
                support_clearance: r.get(21).copied().unwrap_or(f64::NAN),
                object_clearance: r.get(22).copied().unwrap_or(f64::NAN),
            })
            .collect();
        let reg: RegistrationJson = serde_json::from_str(&self.registration)
            .map_err(|e| decode_err("registration", &id, e))?;
        let registration = reg.registration();
        let u32_of = |what: &str, v: i64| u32::try_from(v).map_err(|e| decode_err(what, &id, e));
        Ok(StoredMappedDemo {
            position_index: u32_of("position_index", self.meta.position_index)?,
            trial: u32_of("trial", self.meta.trial)?,
            demonstration_id: self.meta.demonstration_id,
            object_name: self.meta.object_name,
            task: self.meta.task,
            trajectory: MappedTrajectory {
                joint_names,
                times,
                positions,
                metrics,
                registration,
            },
        })
    }
}

/// Creates the mapping row at submission. A no-op if [`store_results`] already wrote it (the
/// job may finish before the handler gets here).
pub async fn insert_mapping(pool: &SqlitePool, m: &NewMapping) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO mappings (id, job_id, robot, request, summary, created_at) \
         VALUES (?, ?, ?, ?, NULL, ?) ON CONFLICT (id) DO NOTHING",
    )
    .bind(&m.id)
    .bind(&m.job_id)
    .bind(&m.robot)
    .bind(&m.request)
    .bind(&m.created_at)
    .execute(pool)
    .await?;
    Ok(())
}

/// Writes a succeeded mapping's summary and every mapped demonstration (in request order) inside
/// the job's result transaction. Creates the mapping row too if the handler has not yet.
pub async fn store_results(
    tx: &mut Transaction<'static, Sqlite>,
    m: &NewMapping,
    summary: &str,
    demos: &[NewMappedDemo],
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO mappings (id, job_id, robot, request, summary, created_at) \
         VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT (id) DO UPDATE SET summary = excluded.summary",
    )
    .bind(&m.id)
    .bind(&m.job_id)
    .bind(&m.robot)
    .bind(&m.request)
    .bind(summary)
    .bind(&m.created_at)
    .execute(&mut **tx)
    .await?;
    for (k, d) in demos.iter().enumerate() {
        sqlx::query(
            "INSERT INTO mapping_demonstrations (mapping_id, position, demonstration_id, \
             subject_id, object_name, task, position_index, trial, joint_names, frame_count, \
             frames, metrics, registration, summary) \
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        )
        .bind(&m.id)
        .bind(k as i64)
        .bind(&d.demonstration_id)
        .bind(&d.subject_id)
        .bind(&d.object_name)
        .bind(&d.task)
        .bind(i64::from(d.position_index))
        .bind(i64::from(d.trial))
        .bind(&d.joint_names)
        .bind(d.frame_count as i64)
        .bind(&d.frames)
        .bind(&d.metrics)
        .bind(&d.registration)
        .bind(&d.summary)
        .execute(&mut **tx)
        .await?;
    }
    Ok(())
}

macro_rules! mapping_select {
    () => {
        "SELECT m.id, m.job_id, m.robot, j.status, m.request, m.summary, m.created_at \
         FROM mappings m JOIN jobs j ON j.id = m.job_id"
    };
}

pub async fn get_mapping(pool: &SqlitePool, id: &str) -> Result<Option<MappingRow>, sqlx::Error> {
    sqlx::query_as(concat!(mapping_select!(), " WHERE m.id = ?"))
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// Mappings, newest first, optionally of one robot and/or status, and the number matching
/// without the page.
pub async fn list_mappings(
    pool: &SqlitePool,
    limit: i64,
    offset: i64,
    robot: Option<&str>,
    status: Option<&str>,
) -> Result<(Vec<MappingRow>, i64), sqlx::Error> {
    macro_rules! filter {
        () => {
            " WHERE (?1 IS NULL OR m.robot = ?1) AND (?2 IS NULL OR j.status = ?2)"
        };
    }
    let rows = sqlx::query_as(concat!(
        mapping_select!(),
        filter!(),
        " ORDER BY m.created_at DESC, m.id LIMIT ?3 OFFSET ?4"
    ))
    .bind(robot)
    .bind(status)
    .bind(limit)
    .bind(offset)
    .fetch_all(pool)
    .await?;
    let total: i64 = sqlx::query_scalar(concat!(
        "SELECT COUNT(*) FROM mappings m JOIN jobs j ON j.id = m.job_id",
        filter!()
    ))
    .bind(robot)
    .bind(status)
    .fetch_one(pool)
    .await?;
    Ok((rows, total))
}

macro_rules! demo_page_filter {
    () => {
        " WHERE mapping_id = ?1 AND (?2 IS NULL OR demonstration_id = ?2)"
    };
}
macro_rules! demo_meta_columns {
    () => {
        "position, demonstration_id, subject_id, object_name, task, position_index, trial, \
         frame_count, summary"
    };
}

/// One page of a mapping's `mapping_demonstrations` rows (query `sql`, request order,
/// optionally one demonstration id) and the number matching without the page.
async fn fetch_page<T>(
    pool: &SqlitePool,
    sql: &'static str,
    mapping_id: &str,
    demonstration: Option<&str>,
    limit: i64,
    offset: i64,
) -> Result<(Vec<T>, i64), sqlx::Error>
where
    T: for<'r> sqlx::FromRow<'r, SqliteRow> + Send + Unpin,
{
    let rows: Vec<T> = sqlx::query_as(sql)
        .bind(mapping_id)
        .bind(demonstration)
        .bind(limit)
        .bind(offset)
        .fetch_all(pool)
        .await?;
    let total: i64 = sqlx::query_scalar(concat!(
        "SELECT COUNT(*) FROM mapping_demonstrations",
        demo_page_filter!()
    ))
    .bind(mapping_id)
    .bind(demonstration)
    .fetch_one(pool)
    .await?;
    Ok((rows, total))
}

/// The stored demonstrations of a mapping (request order) without their arrays, optionally only
/// those of one demonstration id, paged; and the number matching without the page.
pub async fn list_demos(
    pool: &SqlitePool,
    mapping_id: &str,
    demonstration: Option<&str>,
    limit: i64,
    offset: i64,
) -> Result<(Vec<MappedDemoRow>, i64), sqlx::Error> {
    const SQL: &str = concat!(
        "SELECT ",
        demo_meta_columns!(),
        " FROM mapping_demonstrations",
        demo_page_filter!(),
        " ORDER BY position LIMIT ?3 OFFSET ?4"
    );
    fetch_page(pool, SQL, mapping_id, demonstration, limit, offset).await
}

/// [`list_demos`] with the decoded trajectories and metrics.
pub async fn load_page(
    pool: &SqlitePool,
    mapping_id: &str,
    demonstration: Option<&str>,
    limit: i64,
    offset: i64,
) -> Result<(Vec<(MappedDemoRow, StoredMappedDemo)>, i64), sqlx::Error> {
    const SQL: &str = concat!(
        "SELECT ",
        demo_meta_columns!(),
        ", joint_names, frames, metrics, registration FROM mapping_demonstrations",
        demo_page_filter!(),
        " ORDER BY position LIMIT ?3 OFFSET ?4"
    );
    let (rows, total): (Vec<FullDemoRow>, i64) =
        fetch_page(pool, SQL, mapping_id, demonstration, limit, offset).await?;
    let out = rows
        .into_iter()
        .map(|r| {
            let meta = r.meta.clone();
            r.decode().map(|d| (meta, d))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((out, total))
}

/// Demonstrations of a succeeded mapping, in request order; empty for an unfinished one.
pub async fn load_trajectories(
    pool: &SqlitePool,
    mapping_id: &str,
) -> Result<Vec<StoredMappedDemo>, sqlx::Error> {
    let (rows, _) = load_page(pool, mapping_id, None, i64::MAX, 0).await?;
    Ok(rows.into_iter().map(|(_, d)| d).collect())
}

/// A filter over the stored demonstrations (every given field must match).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DemoSelection {
    pub subject: Option<String>,
    pub object: Option<String>,
    pub task: Option<String>,
    pub position_index: Option<i64>,
    pub synthetic: Option<bool>,
    pub job_id: Option<String>,
}

/// Ids of the demonstrations matching `f`, oldest first in insertion order, at most `limit`.
///
/// A study stores all its trials under one `created_at`, so the tie-break is the rowid (the
/// order they were written), not the random UUID: ordering by id made the mapping's input order,
/// and with it the trained model and every plan built on it, differ from run to run.
pub async fn select_demonstrations(
    pool: &SqlitePool,
    f: &DemoSelection,
    limit: i64,
) -> Result<Vec<String>, sqlx::Error> {
    sqlx::query_scalar(
        "SELECT id FROM demonstrations WHERE (?1 IS NULL OR subject_id = ?1) \
         AND (?2 IS NULL OR object_name = ?2) AND (?3 IS NULL OR task = ?3) \
         AND (?4 IS NULL OR position_index = ?4) AND (?5 IS NULL OR synthetic = ?5) \
         AND (?6 IS NULL OR job_id = ?6) ORDER BY created_at, rowid LIMIT ?7",
    )
    .bind(f.subject.as_deref())
    .bind(f.object.as_deref())
    .bind(f.task.as_deref())
    .bind(f.position_index)
    .bind(f.synthetic)
    .bind(f.job_id.as_deref())
    .bind(limit)
    .fetch_all(pool)
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trajectory() -> MappedTrajectory {
        let metrics = |k: usize| FrameMetrics {
            t: 0.1 * k as f64,
            fingers: 3,
            position_error: [0.01, 0.02, 0.03 + k as f64, 0.0, 0.0],
            orientation_error: [0.1, 0.2, 0.3, 0.0, 0.0],
            elbow_distance: 0.5,
            elbow_distance_mean: 0.25,
            objective: 1.5 + k as f64,
            iterations: 7 + k,
            converged: k != 1,
            swivel_human: 0.3,
            swivel_robot: -0.1 * k as f64,
            swivel_difference: 0.3 + 0.1 * k as f64,
            elbow_bound: 0.05,
            support_clearance: 0.01 * k as f64,
            object_clearance: -0.002,
        };
        MappedTrajectory {
            joint_names: vec!["a".into(), "b".into()],
            times: vec![0.0, 0.1, 0.2],
            positions: vec![0.0, 1.0, 0.5, -1.0, 0.25, 2.0],
            metrics: (0..3).map(metrics).collect(),
            registration: Registration {
                rotation: UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
                human_anchor: nalgebra::Point3::new(0.3, 0.1, 0.05),
                robot_anchor: nalgebra::Point3::new(0.1, -0.2, 0.3),
                up: Vector3::z(),
                transport_scale: 1.25,
                vertical_scale: 1.0,
                hand_scale: 0.9,
                support: Some(0.0),
                object: Some(crate::mapping::HumanObject {
                    shape: crate::human::ObjectShape::Sphere { radius: 0.04 },
                    pose: nalgebra::Isometry3::translation(0.1, -0.2, 0.3),
                }),
                hand_frame: Some(nalgebra::Isometry3::from_parts(
                    nalgebra::Translation3::new(0.0, 0.1, 0.2),
                    UnitQuaternion::from_euler_angles(0.3, -0.2, 0.1),
                )),
            },
        }
    }

    async fn pool() -> (tempfile::TempDir, SqlitePool) {
        let dir = tempfile::tempdir().unwrap();
        let pool = crate::store::connect(&dir.path().join("t.db"))
            .await
            .unwrap();
        (dir, pool)
    }

    async fn job(pool: &SqlitePool, id: &str, status: &str) {
        sqlx::query(
            "INSERT INTO jobs (id, kind, status, created_at) VALUES (?, 'mapping', ?, '2026')",
        )
        .bind(id)
        .bind(status)
        .execute(pool)
        .await
        .unwrap();
    }

    #[tokio::test]
    async fn results_round_trip_and_unfinished_mappings_have_none() {
        let (_dir, pool) = pool().await;
        sqlx::query(
            "INSERT INTO demonstrations (id, subject_id, object_name, task, position_index, \
             trial, synthetic, subject, object, summary, frame_count, frames, created_at) \
             VALUES ('d1', 's', 'ball', 'pick', 2, 3, 1, '{}', '{}', '{}', 0, x'', '2026')",
        )
        .execute(&pool)
        .await
        .unwrap();
        job(&pool, "j1", "running").await;
        let m = NewMapping {
            id: "m1".into(),
            job_id: "j1".into(),
            robot: "wam_ihy".into(),
            request: "{}".into(),
            created_at: crate::store::now(),
        };
        insert_mapping(&pool, &m).await.unwrap();
        let row = get_mapping(&pool, "m1").await.unwrap().unwrap();
        assert_eq!(row.status, "running");
        assert!(row.summary.is_none());
        assert!(load_trajectories(&pool, "m1").await.unwrap().is_empty());

        let traj = trajectory();
        let labels = DemoLabels {
            demonstration_id: "d1".into(),
            subject_id: "s".into(),
            object_name: "ball".into(),
            task: "pick".into(),
            position_index: 2,
            trial: 3,
        };
        let demo = encode_demo(labels, &traj, "{\"x\":1}".into()).unwrap();
        let mut tx = pool.begin().await.unwrap();
        store_results(&mut tx, &m, "{\"n\":1}", &[demo.clone(), demo])
            .await
            .unwrap();
        tx.commit().await.unwrap();
        // Re-inserting at submission (the job finished first) keeps the summary.
        insert_mapping(&pool, &m).await.unwrap();
        let row = get_mapping(&pool, "m1").await.unwrap().unwrap();
        assert_eq!(row.summary.as_deref(), Some("{\"n\":1}"));
        let back = load_trajectories(&pool, "m1").await.unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].trajectory.joint_names, traj.joint_names);
        assert_eq!(back[0].trajectory.times, traj.times);
        assert_eq!(back[0].trajectory.positions, traj.positions);
        assert_eq!(back[0].trajectory.metrics, traj.metrics);
        let (r0, r1) = (back[0].trajectory.registration, traj.registration);
        assert!(r0.rotation.angle_to(&r1.rotation) < 1e-12);
        assert_eq!(r0.robot_anchor, r1.robot_anchor);
        assert_eq!(r0.human_anchor, r1.human_anchor);
        assert_eq!(
            (r0.transport_scale, r0.hand_scale, r0.support, r0.object),
            (r1.transport_scale, r1.hand_scale, r1.support, r1.object)
        );
        assert_eq!((back[0].position_index, back[0].trial), (2, 3));
        let (page, total) = list_demos(&pool, "m1", Some("d1"), 1, 1).await.unwrap();
        assert_eq!((page.len(), total, page[0].position), (1, 2, 1));
        let (rows, total) = list_mappings(&pool, 10, 0, Some("wam_ihy"), None)
            .await
            .unwrap();
        assert_eq!((rows.len(), total), (1, 1));
        let (rows, total) = list_mappings(&pool, 10, 0, None, Some("failed"))
            .await
            .unwrap();
        assert_eq!((rows.len(), total), (0, 0));
    }

    #[test]
    fn inconsistent_trajectories_are_refused() {
        let mut t = trajectory();
        t.positions.pop();
        let labels = DemoLabels {
            demonstration_id: "d".into(),
            subject_id: "s".into(),
            object_name: "o".into(),
            task: "t".into(),
            position_index: 0,
            trial: 0,
        };
        assert!(encode_demo(labels, &t, String::new()).is_err());
    }
}
