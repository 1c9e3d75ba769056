//! Plans: one request from object and task to a humanlike motion ending in a task-specific
//! grasp, and optionally its execution.
//!
//! A plan is one unit of work: its grasp, trajectory, execution and plan rows are written in
//! one transaction, so they are stored together or not at all (a failure after the grasp
//! leaves no grasp behind). The dispatcher is woken only after the commit; it reads the queue
//! through other connections, so it never sees an execution whose plan was rolled back.

use super::{Context, Error};
use crate::bridge::{ExecutionPayload, Hub, Mode, WorkerName};
use crate::motion::ControlParams;
use crate::store::grasps::{self as grasp_repo, GraspRow, NewGrasp};
use crate::store::plans::{self as plan_repo, NewPlan, PlanRow};
use crate::store::trajectories::{self, StoredTrajectory, TrajectoryDraft};

/// What to queue with a plan.
#[derive(Debug, Clone)]
pub struct ExecutionRequest {
    pub mode: Mode,
    /// Run on this worker only (default: any idle worker of the robot).
    pub worker: Option<WorkerName>,
    /// The model's law for a closed-loop execution (`model_id`, its parameters).
    pub law: Option<(String, ControlParams)>,
}

/// Everything a plan stores, computed before anything is written.
#[derive(Debug, Clone)]
pub struct PlanRows {
    pub grasp: NewGrasp,
    /// The motion to the grasp, when the plan is feasible.
    pub trajectory: Option<TrajectoryDraft>,
    /// Queued only with a trajectory.
    pub execution: Option<ExecutionRequest>,
    /// The plan row; its grasp, trajectory and execution ids are filled in here.
    pub plan: NewPlan,
}

/// The rows of a stored plan.
#[derive(Debug, Clone)]
pub struct StoredPlan {
    pub grasp: GraspRow,
    pub trajectory: Option<StoredTrajectory>,
    pub execution_id: Option<String>,
    pub plan: PlanRow,
}

/// The writes of a plan, in order (for tests that make one fail).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Write {
    Grasp,
    Trajectory,
    Execution,
}

/// The one execution payload builder: a stored trajectory to follow (open loop), or the
/// model's law run to the trajectory's goal (closed loop).
pub fn payload(
    mode: Mode,
    trajectory: &StoredTrajectory,
    law: Option<&(String, ControlParams)>,
) -> Result<ExecutionPayload, Error> {
    match (mode, law) {
        (Mode::OpenLoop, _) => Ok(ExecutionPayload::Trajectory {
            trajectory_id: trajectory.id.clone(),
            joint_names: trajectory.joint_names.clone(),
            points: trajectory.points.clone(),
        }),
        (Mode::ClosedLoop, Some((model_id, params))) => Ok(ExecutionPayload::Model {
            model_id: model_id.clone(),
            params: params.clone(),
            goal: trajectory.goal.clone(),
        }),
        (Mode::ClosedLoop, None) => Err(Error::internal(anyhow::anyhow!(
            "a closed-loop execution needs the model's law"
        ))),
    }
}

/// Stores a plan's rows in one transaction.
pub async fn store(ctx: &Context, rows: PlanRows) -> Result<StoredPlan, Error> {
    store_with(ctx, rows, |_| Ok(())).await
}

/// [`store`], calling `after` once each write has been made (inside the transaction): an
/// error from it rolls back everything.
pub(crate) async fn store_with(
    ctx: &Context,
    rows: PlanRows,
    after: impl Fn(Write) -> Result<(), Error>,
) -> Result<StoredPlan, Error> {
    let PlanRows {
        grasp,
        trajectory,
        execution,
        mut plan,
    } = rows;
    let mut tx = ctx.db.begin().await?;
    let grasp = grasp_repo::insert_grasp_in(&mut tx, &grasp, None).await?;
    after(Write::Grasp)?;
    let trajectory = match &trajectory {
        Some(t) => Some(trajectories::insert_trajectory_in(&mut tx, &t.as_new()).await?),
        None => None,
    };
    after(Write::Trajectory)?;
    let mut execution_id = None;
    if let (Some(e), Some(t)) = (&execution, &trajectory) {
        let p = payload(e.mode, t, e.law.as_ref())?;
        // The library reads through another pooled connection; in WAL mode that read does not
        // wait for this transaction.
        ctx.bridges.check(&plan.robot, e.mode, &p).await?;
        let id = Hub::insert_in(&mut tx, &plan.robot, e.mode, &p, e.worker.as_ref()).await?;
        execution_id = Some(id);
    }
    after(Write::Execution)?;
    plan.grasp_id = grasp.id.clone();
    plan.trajectory_id = trajectory.as_ref().map(|t| t.id.clone());
    plan.execution_id = execution_id.clone();
    let plan = plan_repo::insert_in(&mut tx, plan).await?;
    tx.commit().await?;
    if execution_id.is_some() {
        ctx.bridges.wake();
    }
    Ok(StoredPlan {
        grasp,
        trajectory,
        execution_id,
        plan,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::TrajectoryPoint;

    const ROBOT: &str = "wam_t42";

    /// A plan's rows for the bundled robot: a two-point trajectory between configurations
    /// inside the joint limits, queued open loop.
    async fn rows(ctx: &Context) -> PlanRows {
        let system = ctx.robots.system(ROBOT).await.expect("bundled robot");
        let model = &system.model;
        let names = model.joint_names().to_vec();
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        // A configuration a fraction `w` of the way through each joint's range (0 when the
        // joint is unbounded).
        let at = |w: f64| -> Vec<f64> {
            lo.iter()
                .zip(hi)
                .map(|(l, h)| {
                    if l.is_finite() && h.is_finite() {
                        (1.0 - w) * l + w * h
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let (mid, near) = (at(0.5), at(0.6));
        let zeros = vec![0.0; names.len()];
        let point = |t: f64, q: &[f64]| TrajectoryPoint {
            t,
            positions: q.to_vec(),
            velocities: zeros.clone(),
            accelerations: zeros.clone(),
        };
        PlanRows {
            grasp: NewGrasp {
                robot: ROBOT.into(),
                object_id: None,
                object: "{}".into(),
                request: "{}".into(),
                result: "{}".into(),
                feasible: true,
            },
            trajectory: Some(TrajectoryDraft {
                model_id: None,
                robot: ROBOT.into(),
                joint_names: names,
                points: vec![point(0.0, &mid), point(1.0, &near)],
                start: mid.clone(),
                goal: near.clone(),
                duration: 1.0,
                request: "{}".into(),
                summary: "{}".into(),
            }),
            execution: Some(ExecutionRequest {
                mode: Mode::OpenLoop,
                worker: None,
                law: None,
            }),
            plan: NewPlan {
                robot: ROBOT.into(),
                model_id: None,
                grasp_id: String::new(),
                trajectory_id: None,
                execution_id: None,
                feasible: true,
                reason: None,
                request: "{}".into(),
                timings: "{}".into(),
            },
        }
    }

    async fn count(ctx: &Context, table: &str) -> i64 {
        let sql = match table {
            "grasps" => "SELECT COUNT(*) FROM grasps",
            "trajectories" => "SELECT COUNT(*) FROM trajectories",
            "executions" => "SELECT COUNT(*) FROM executions",
            "plans" => "SELECT COUNT(*) FROM plans",
            other => panic!("no table {other}"),
        };
        let (n,): (i64,) = sqlx::query_as(sql).fetch_one(&ctx.db).await.expect("count");
        n
    }

    const TABLES: [&str; 4] = ["grasps", "trajectories", "executions", "plans"];

    #[tokio::test]
    async fn a_failure_after_any_write_leaves_no_row_of_the_plan() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = super::super::test_context(dir.path()).await;
        for failing in [Write::Grasp, Write::Trajectory, Write::Execution] {
            let r = store_with(&ctx, rows(&ctx).await, |w| {
                if w == failing {
                    Err(Error::internal(anyhow::anyhow!("injected after {w:?}")))
                } else {
                    Ok(())
                }
            })
            .await;
            assert!(
                r.is_err(),
                "the injected failure after {failing:?} is reported"
            );
            for t in TABLES {
                assert_eq!(
                    count(&ctx, t).await,
                    0,
                    "{t} after a failure after {failing:?}"
                );
            }
        }
        // The same rows without a failure are all stored and linked: the empty tables above
        // are the rollback, not writes that never happened.
        let stored = store(&ctx, rows(&ctx).await).await.expect("stored");
        for t in TABLES {
            assert_eq!(count(&ctx, t).await, 1, "{t} after a plan is stored");
        }
        assert_eq!(stored.plan.grasp_id, stored.grasp.id);
        assert_eq!(
            stored.plan.trajectory_id.as_deref(),
            stored.trajectory.as_ref().map(|t| t.id.as_str())
        );
        let execution = stored.execution_id.expect("queued");
        assert_eq!(
            stored.plan.execution_id.as_deref(),
            Some(execution.as_str())
        );
        let (source,): (String,) = sqlx::query_as("SELECT source_id FROM executions WHERE id = ?")
            .bind(&execution)
            .fetch_one(&ctx.db)
            .await
            .unwrap();
        assert_eq!(Some(source), stored.plan.trajectory_id);
    }
}
