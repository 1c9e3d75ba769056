//! Trained motion models (migration 0006). A row is inserted when the training job is submitted
//! and completed (model + report) in the job's success transaction; its `status` is the job's.
//!
//! The robot's *default model* ([`default_model_for`]) is the succeeded model explicitly marked
//! default ([`set_default`], or `default: true` in the training request) if there is one, else the
//! most recently created succeeded model of that robot. An explicit mark survives newer training
//! runs, so a lab can pin a model; without one, retraining moves the default forward.

use sqlx::{Sqlite, SqlitePool, Transaction};

use super::now;
use crate::motion::{ControlParams, MotionModel};

/// A model row (without the trained parameters; see [`load_model`]).
#[derive(Debug, Clone, PartialEq, sqlx::FromRow)]
pub struct ModelRow {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    /// The job's: `queued|running|succeeded|failed|cancelled`.
    pub status: String,
    /// The training request as given (JSON).
    pub request: String,
    /// The training report (JSON), `None` until trained.
    pub report: Option<String>,
    pub created_at: String,
}

/// A model about to be trained (inserted at submission).
#[derive(Debug, Clone)]
pub struct NewModel {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub request: String,
    /// The model's joint order.
    pub joint_names: Vec<String>,
    /// Closed-loop gains for [`load_params`]: on-manifold convergence rate (1/s) and `K_⊥`.
    pub control_rate: f64,
    pub k_perp: f64,
    /// Make it the robot's default once trained.
    pub make_default: bool,
}

// A macro rather than a const so the queries stay `&'static str` literals via `concat!`.
macro_rules! select {
    () => {
        "SELECT m.id, m.job_id, m.robot, j.status, m.request, m.report, m.created_at \
         FROM models m JOIN jobs j ON j.id = m.job_id "
    };
}

fn decode_error(e: impl std::error::Error + Send + Sync + 'static) -> sqlx::Error {
    sqlx::Error::Decode(Box::new(e))
}

/// Records a model whose training job was just submitted. Idempotent: when the job already
/// finished and stored the trained row ([`store_trained`]), nothing changes.
pub async fn insert_pending(pool: &SqlitePool, m: &NewModel) -> Result<(), sqlx::Error> {
    let names = serde_json::to_string(&m.joint_names).map_err(decode_error)?;
    sqlx::query(
        "INSERT INTO models (id, job_id, robot, request, joint_names, control_rate, k_perp, created_at) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT(id) DO NOTHING",
    )
    .bind(&m.id)
    .bind(&m.job_id)
    .bind(&m.robot)
    .bind(&m.request)
    .bind(names)
    .bind(m.control_rate)
    .bind(m.k_perp)
    .bind(now())
    .execute(pool)
    .await?;
    Ok(())
}

/// Stores the trained model and its report inside the job's success transaction (inserting the
/// row if the submitting request has not yet), and moves the default mark when asked.
pub async fn store_trained(
    tx: &mut Transaction<'_, Sqlite>,
    m: &NewModel,
    model: &MotionModel,
    report: &str,
) -> Result<(), sqlx::Error> {
    let names = serde_json::to_string(&m.joint_names).map_err(decode_error)?;
    let json = serde_json::to_string(model).map_err(decode_error)?;
    sqlx::query(
        "INSERT INTO models (id, job_id, robot, request, joint_names, control_rate, k_perp, report, model, created_at) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?) \
         ON CONFLICT(id) DO UPDATE SET report = excluded.report, model = excluded.model",
    )
    .bind(&m.id)
    .bind(&m.job_id)
    .bind(&m.robot)
    .bind(&m.request)
    .bind(names)
    .bind(m.control_rate)
    .bind(m.k_perp)
    .bind(report)
    .bind(json)
    .bind(now())
    .execute(&mut **tx)
    .await?;
    if m.make_default {
        mark_default(tx, &m.robot, &m.id).await?;
    }
    Ok(())
}

async fn mark_default(
    tx: &mut Transaction<'_, Sqlite>,
    robot: &str,
    id: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE models SET is_default = 0 WHERE robot = ? AND is_default = 1")
        .bind(robot)
        .execute(&mut **tx)
        .await?;
    sqlx::query("UPDATE models SET is_default = 1 WHERE id = ?")
        .bind(id)
        .execute(&mut **tx)
        .await?;
    Ok(())
}

/// Marks a trained model as its robot's default (clearing any other mark). Returns false when
/// the model does not exist or is not trained.
pub async fn set_default(pool: &SqlitePool, id: &str) -> Result<bool, sqlx::Error> {
    let mut tx = super::begin_write(pool).await?;
    let robot: Option<String> =
        sqlx::query_scalar("SELECT robot FROM models WHERE id = ? AND model IS NOT NULL")
            .bind(id)
            .fetch_optional(&mut **tx)
            .await?;
    let Some(robot) = robot else {
        return Ok(false);
    };
    mark_default(&mut tx, &robot, id).await?;
    tx.commit().await?;
    Ok(true)
}

pub async fn get_model(pool: &SqlitePool, id: &str) -> Result<Option<ModelRow>, sqlx::Error> {
    sqlx::query_as(concat!(select!(), "WHERE m.id = ?"))
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// Models, newest first, optionally of one robot; with the total count of the filter.
pub async fn list_models(
    pool: &SqlitePool,
    robot: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<(Vec<ModelRow>, i64), sqlx::Error> {
    let rows = sqlx::query_as(concat!(
        select!(),
        "WHERE (?1 IS NULL OR m.robot = ?1) ORDER BY m.created_at DESC, m.id LIMIT ?2 OFFSET ?3"
    ))
    .bind(robot)
    .bind(i64::from(limit))
    .bind(i64::from(offset))
    .fetch_all(pool)
    .await?;
    let total = sqlx::query_scalar("SELECT COUNT(*) FROM models WHERE (?1 IS NULL OR robot = ?1)")
        .bind(robot)
        .fetch_one(pool)
        .await?;
    Ok((rows, total))
}

/// The robot's default model (see the module doc), `None` when it has no trained model.
pub async fn default_model_for(
    pool: &SqlitePool,
    robot: &str,
) -> Result<Option<ModelRow>, sqlx::Error> {
    sqlx::query_as(concat!(
        select!(),
        "WHERE m.robot = ? AND m.model IS NOT NULL AND j.status = 'succeeded' \
         ORDER BY m.is_default DESC, m.created_at DESC, m.id LIMIT 1"
    ))
    .bind(robot)
    .fetch_optional(pool)
    .await
}

/// Whether the model is explicitly marked as its robot's default.
pub async fn is_marked_default(pool: &SqlitePool, id: &str) -> Result<bool, sqlx::Error> {
    let v: Option<i64> = sqlx::query_scalar("SELECT is_default FROM models WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?;
    Ok(v == Some(1))
}

/// The model's joint order (`None` for an unknown id).
pub async fn joint_names(pool: &SqlitePool, id: &str) -> Result<Option<Vec<String>>, sqlx::Error> {
    let v: Option<String> = sqlx::query_scalar("SELECT joint_names FROM models WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?;
    v.map(|s| serde_json::from_str(&s).map_err(decode_error))
        .transpose()
}

/// The trained model (None while training or when it failed).
pub async fn load_model(pool: &SqlitePool, id: &str) -> Result<Option<MotionModel>, sqlx::Error> {
    let v: Option<Option<String>> = sqlx::query_scalar("SELECT model FROM models WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await?;
    v.flatten()
        .map(|s| serde_json::from_str(&s).map_err(decode_error))
        .transpose()
}

/// `MotionModel` -> `ControlParams` (what GET /v1/models/{id}/params returns and what a bridge
/// runs), with the joint names and gains stored with the model.
pub async fn load_params(
    pool: &SqlitePool,
    id: &str,
) -> Result<Option<ControlParams>, sqlx::Error> {
    let row: Option<(Option<String>, String, f64, f64)> =
        sqlx::query_as("SELECT model, joint_names, control_rate, k_perp FROM models WHERE id = ?")
            .bind(id)
            .fetch_optional(pool)
            .await?;
    let Some((Some(model), names, rate, k_perp)) = row else {
        return Ok(None);
    };
    let model: MotionModel = serde_json::from_str(&model).map_err(decode_error)?;
    let names: Vec<String> = serde_json::from_str(&names).map_err(decode_error)?;
    Ok(Some(model.control_params(names, rate, k_perp)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::synthetic::{SyntheticStudy, curved_study};
    use crate::motion::{Components, TrainOptions, TrajectoryOptions, train};
    use crate::store::trajectories::{self, NewTrajectory};

    async fn pool() -> (tempfile::TempDir, SqlitePool) {
        let dir = tempfile::tempdir().unwrap();
        let pool = crate::store::connect(&dir.path().join("t.db"))
            .await
            .unwrap();
        (dir, pool)
    }

    async fn job(pool: &SqlitePool, status: &str) -> String {
        let id = uuid::Uuid::new_v4().to_string();
        sqlx::query("INSERT INTO jobs (id, kind, status, created_at) VALUES (?, 'model', ?, ?)")
            .bind(&id)
            .bind(status)
            .bind(now())
            .execute(pool)
            .await
            .unwrap();
        id
    }

    fn new_model(job_id: &str, robot: &str, make_default: bool) -> NewModel {
        NewModel {
            id: uuid::Uuid::new_v4().to_string(),
            job_id: job_id.to_owned(),
            robot: robot.to_owned(),
            request: "{}".into(),
            joint_names: (0..11).map(|j| format!("j{j}")).collect(),
            control_rate: 2.0,
            k_perp: 3.0,
            make_default,
        }
    }

    async fn trained(pool: &SqlitePool, m: &NewModel, model: &MotionModel) {
        let mut tx = pool.begin().await.unwrap();
        store_trained(&mut tx, m, model, "{\"ok\":true}")
            .await
            .unwrap();
        tx.commit().await.unwrap();
    }

    #[tokio::test]
    async fn models_round_trip_and_the_default_follows_the_documented_rule() {
        let (_dir, pool) = pool().await;
        let data = curved_study(&SyntheticStudy {
            trials_per_position: 3,
            frames: 40,
            ..SyntheticStudy::default()
        });
        let opts = TrainOptions {
            groups: data.groups.clone(),
            components: Components::VarianceThreshold(0.97),
            ..TrainOptions::default()
        };
        let (model, _) = train(&data.demos, &data.limits, &opts).unwrap();

        // pending: visible with the job's status, no parameters yet
        let j1 = job(&pool, "running").await;
        let m1 = new_model(&j1, "wam_t42", false);
        insert_pending(&pool, &m1).await.unwrap();
        let row = get_model(&pool, &m1.id).await.unwrap().unwrap();
        assert_eq!(
            (row.status.as_str(), row.report.as_deref()),
            ("running", None)
        );
        assert!(load_model(&pool, &m1.id).await.unwrap().is_none());
        assert!(load_params(&pool, &m1.id).await.unwrap().is_none());
        assert!(default_model_for(&pool, "wam_t42").await.unwrap().is_none());

        // trained (the job succeeds in the same transaction in the service)
        trained(&pool, &m1, &model).await;
        sqlx::query("UPDATE jobs SET status = 'succeeded' WHERE id = ?")
            .bind(&j1)
            .execute(&pool)
            .await
            .unwrap();
        // exact round trip (serde_json's `float_roundtrip`): the stored model is the trained one
        let loaded = load_model(&pool, &m1.id).await.unwrap().unwrap();
        assert_eq!(loaded, model);
        let q = data.demos[0].frame(7, 11).to_vec();
        let goal = data.demos[1].frame(39, 11).to_vec();
        let a = model
            .trajectory(&q, &goal, &TrajectoryOptions::default())
            .unwrap();
        let params = load_params(&pool, &m1.id).await.unwrap().unwrap();
        assert_eq!(params.joint_names, m1.joint_names);
        assert_eq!(params.k_perp, 3.0);
        assert_eq!(params.groups.len(), model.manifolds.len());
        // a late insert_pending (the job finished first) changes nothing
        insert_pending(&pool, &m1).await.unwrap();
        assert!(load_model(&pool, &m1.id).await.unwrap().is_some());
        assert_eq!(
            default_model_for(&pool, "wam_t42")
                .await
                .unwrap()
                .unwrap()
                .id,
            m1.id
        );

        // a newer succeeded model becomes the default; a failed or other-robot one does not
        let j2 = job(&pool, "succeeded").await;
        let m2 = new_model(&j2, "wam_t42", false);
        trained(&pool, &m2, &model).await;
        let j3 = job(&pool, "failed").await;
        insert_pending(&pool, &new_model(&j3, "wam_t42", false))
            .await
            .unwrap();
        let j4 = job(&pool, "succeeded").await;
        trained(&pool, &new_model(&j4, "pa10_t42", false), &model).await;
        assert_eq!(
            default_model_for(&pool, "wam_t42")
                .await
                .unwrap()
                .unwrap()
                .id,
            m2.id
        );
        // an explicit mark pins the older one, and survives a newer model
        assert!(set_default(&pool, &m1.id).await.unwrap());
        let j5 = job(&pool, "succeeded").await;
        trained(&pool, &new_model(&j5, "wam_t42", false), &model).await;
        assert_eq!(
            default_model_for(&pool, "wam_t42")
                .await
                .unwrap()
                .unwrap()
                .id,
            m1.id
        );
        // marking another (via the training request) moves the single mark
        let j6 = job(&pool, "succeeded").await;
        let m6 = new_model(&j6, "wam_t42", true);
        trained(&pool, &m6, &model).await;
        assert!(is_marked_default(&pool, &m6.id).await.unwrap());
        assert!(!is_marked_default(&pool, &m1.id).await.unwrap());
        assert_eq!(
            default_model_for(&pool, "wam_t42")
                .await
                .unwrap()
                .unwrap()
                .id,
            m6.id
        );
        assert!(!set_default(&pool, "nope").await.unwrap());
        let (rows, total) = list_models(&pool, Some("wam_t42"), 10, 0).await.unwrap();
        assert_eq!((rows.len(), total), (5, 5));
        assert!(rows.windows(2).all(|w| w[0].created_at >= w[1].created_at));

        // trajectories: times and positions round-trip exactly; velocities and accelerations
        // are stored as f32 rounded towards zero (issue 20), and a create returns what a read
        // gives back
        let names = m1.joint_names.clone();
        let new = NewTrajectory {
            model_id: Some(&m1.id),
            robot: "wam_t42",
            joint_names: &names,
            points: &a.points,
            start: &q,
            goal: &goal,
            duration: a.duration,
            request: "{}",
            summary: "{}",
        };
        let stored = trajectories::insert_trajectory(&pool, &new).await.unwrap();
        let got = trajectories::get_trajectory(&pool, &stored.id)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(got, stored);
        assert_eq!(got.points.len(), a.points.len());
        for (g, p) in got.points.iter().zip(&a.points) {
            assert_eq!((g.t, &g.positions), (p.t, &p.positions));
            let stored = g.velocities.iter().chain(&g.accelerations);
            for (x, y) in stored.zip(p.velocities.iter().chain(&p.accelerations)) {
                assert!(
                    x.abs() <= y.abs() && (x - y).abs() <= 1.2e-7 * y.abs(),
                    "{x} vs {y}"
                );
            }
        }
        assert!(
            trajectories::get_trajectory(&pool, "nope")
                .await
                .unwrap()
                .is_none()
        );
        let (list, total) = trajectories::list_trajectories(&pool, Some(&m1.id), 10, 0)
            .await
            .unwrap();
        assert_eq!((list.len(), total), (1, 1));
        // a trajectory of an unknown model violates the foreign key and stores nothing
        let bad = NewTrajectory {
            model_id: Some("nope"),
            ..new
        };
        assert!(trajectories::insert_trajectory(&pool, &bad).await.is_err());
        assert_eq!(
            trajectories::list_trajectories(&pool, None, 10, 0)
                .await
                .unwrap()
                .1,
            1
        );
    }
}
