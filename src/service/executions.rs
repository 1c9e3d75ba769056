//! Executions: resolving what to run (an inline or stored trajectory, or a model's
//! closed-loop law) into the payload an execution keeps, queueing it for a bridge worker of
//! the robot, and reading executions back with the live feedback overlaid.

use super::models::JointValues;
use super::{Context, Error, Invalid};
use crate::bridge::protocol::{Capability, Feedback};
use crate::bridge::{
    ExecutionPayload, Mode, PayloadIssue, PayloadPart, TrackingSummary, WorkerName,
};
use crate::geometry::ObstacleSpec;
use crate::grasp::{ObjectSpec, PathClearance};
use crate::motion::{ControlParams, TrajectoryPoint};
use crate::store::executions as repo;
use crate::store::payload::SafetySpec;
use crate::store::{feedback, grasps, models, plans, trajectories};

pub use crate::store::executions::{ExecutionRow, ExecutionState};
pub use crate::store::feedback::{History, MAX_RATE_HZ, MAX_SAMPLES};

/// Where the parts of a payload came from in a request, for error paths
/// (`$.trajectory.points`, ...).
#[derive(Debug, Clone)]
pub struct PayloadPaths {
    pub joint_names: String,
    pub points: String,
    pub goal: String,
}

impl Default for PayloadPaths {
    fn default() -> Self {
        PayloadPaths::all(
            "$.payload.joint_names",
            "$.payload.points",
            "$.payload.goal",
        )
    }
}

impl PayloadPaths {
    fn all(joint_names: &str, points: &str, goal: &str) -> Self {
        PayloadPaths {
            joint_names: joint_names.into(),
            points: points.into(),
            goal: goal.into(),
        }
    }

    /// Each issue at the path its part came from.
    pub fn invalid(&self, issues: &[PayloadIssue]) -> Vec<Invalid> {
        issues
            .iter()
            .map(|i| {
                let base = match i.part {
                    PayloadPart::Mode => "$.mode",
                    PayloadPart::JointNames => &self.joint_names,
                    PayloadPart::Points => &self.points,
                    PayloadPart::Goal => &self.goal,
                    PayloadPart::Stream => "$",
                };
                Invalid::new(format!("{base}{}", i.at), i.message.clone())
            })
            .collect()
    }
}

/// What an execution runs, as the request names it.
#[derive(Debug, Clone)]
pub enum Source {
    /// A trajectory given in the request.
    Inline {
        joint_names: Vec<String>,
        points: Vec<TrajectoryPoint>,
    },
    /// A stored trajectory (open loop), or its model's law towards its goal (closed loop).
    Trajectory(String),
    /// A trained model's closed-loop law towards the request's `goal`.
    Model(String),
}

/// Resolves `source` into the payload the execution keeps, checks it against the robot and
/// queues it; returns the queued execution. Bad input is named at its request path.
pub async fn create(
    ctx: &Context,
    robot: &str,
    mode: Mode,
    source: Source,
    goal: Option<JointValues>,
    worker: Option<&str>,
) -> Result<ExecutionView, Error> {
    let (payload, paths) = resolve(ctx, robot, mode, source, goal).await?;
    let mut worker = worker.map(WorkerName::parse).transpose()?;
    // A trajectory, and a law that runs one (a stored trajectory in closed loop), must start
    // where the robot will be (a bare law runs from wherever it is): checked against the
    // connected workers now, and run on the one it was checked against.
    let timed = match &payload {
        ExecutionPayload::Trajectory {
            joint_names,
            points,
            ..
        } => Some((joint_names, points, &[][..])),
        ExecutionPayload::Model {
            params,
            path: Some(points),
            ..
        } => Some((
            &params.joint_names,
            points,
            &[Capability::PathFollowing][..],
        )),
        _ => None,
    };
    if let Some((joint_names, points, needs)) = timed
        && let Some(first) = points.first()
    {
        let path = if paths.points == "$.trajectory_id" {
            paths.points.clone()
        } else {
            format!("{}[0].positions", paths.points)
        };
        let checked = super::bridges::check_start(
            ctx,
            robot,
            (worker.as_ref().map(WorkerName::as_str), needs),
            joint_names,
            &first.positions,
            &path,
        )
        .await?;
        if worker.is_none() {
            worker = checked.as_deref().map(WorkerName::parse).transpose()?;
        }
    }
    let id = enqueue(ctx, robot, mode, payload, worker)
        .await
        .map_err(|e| match e {
            Error::Payload(issues) => Error::Invalid(paths.invalid(&issues)),
            other => other,
        })?;
    get(ctx, &id).await
}

/// Checks `payload` against the robot and queues it; returns the execution id.
pub async fn enqueue(
    ctx: &Context,
    robot: &str,
    mode: Mode,
    payload: ExecutionPayload,
    worker: Option<WorkerName>,
) -> Result<String, Error> {
    Ok(ctx.bridges.enqueue(robot, mode, payload, worker).await?)
}

/// An execution as it stands: its row, with the live feedback and tracking of the bridge hub
/// while it runs, else the stored ones.
#[derive(Debug, Clone)]
pub struct ExecutionView {
    pub row: ExecutionRow,
    pub last_feedback: Option<Feedback>,
    pub tracking: Option<TrackingSummary>,
    pub feedback_samples: u64,
}

pub fn view(ctx: &Context, row: ExecutionRow) -> ExecutionView {
    let live = (row.state == ExecutionState::Running)
        .then(|| ctx.bridges.live(&row.id))
        .flatten();
    let (last_feedback, tracking, feedback_samples) = match live {
        Some((fb, tr, n)) => (fb, Some(tr), n as u64),
        None => (
            row.last_feedback
                .as_deref()
                .and_then(|s| serde_json::from_str::<Option<Feedback>>(s).ok())
                .flatten(),
            row.tracking
                .as_deref()
                .and_then(|s| serde_json::from_str(s).ok()),
            row.feedback_samples.max(0) as u64,
        ),
    };
    ExecutionView {
        row,
        last_feedback,
        tracking,
        feedback_samples,
    }
}

/// An execution with the live feedback overlaid.
pub async fn get(ctx: &Context, id: &str) -> Result<ExecutionView, Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("execution", id))?;
    Ok(view(ctx, row))
}

/// A page of executions, newest first, optionally of one state and/or robot.
pub async fn list(
    ctx: &Context,
    state: Option<ExecutionState>,
    robot: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<Vec<ExecutionView>, Error> {
    let rows = repo::list(&ctx.db, state, robot, limit, offset).await?;
    Ok(rows.into_iter().map(|r| view(ctx, r)).collect())
}

/// Requests the cancellation of a queued or running execution; returns it as it stands.
pub async fn cancel(ctx: &Context, id: &str) -> Result<ExecutionView, Error> {
    ctx.bridges.cancel(id).await?;
    get(ctx, id).await
}

/// The measured state history of an execution: the live one (with what is not flushed yet)
/// while it runs, else the stored one.
pub async fn history(ctx: &Context, row: &ExecutionRow, n_joints: usize) -> Result<History, Error> {
    if row.state == ExecutionState::Running
        && let Some(h) = ctx.bridges.history(&row.id)
        && h.n_joints == n_joints
    {
        return Ok(h);
    }
    Ok(feedback::load(&ctx.db, &row.id, n_joints).await?)
}

/// An execution, the joint names of its payload and its measured state history.
pub async fn feedback(
    ctx: &Context,
    id: &str,
) -> Result<(ExecutionRow, Vec<String>, History), Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("execution", id))?;
    let joint_names = repo::joint_names(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("execution", id))?;
    let h = history(ctx, &row, joint_names.len()).await?;
    Ok((row, joint_names, h))
}

/// An execution with its payload (`None` when the row has none) and measured history, for
/// its figure.
pub async fn with_payload(
    ctx: &Context,
    id: &str,
) -> Result<(ExecutionRow, ExecutionPayload, History), Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("execution", id))?;
    let payload = repo::payload(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("execution", id))?;
    let h = history(ctx, &row, payload.joint_names().len()).await?;
    Ok((row, payload, h))
}

// ------------------------------------------------------------------------------------ payloads

async fn resolve(
    ctx: &Context,
    robot: &str,
    mode: Mode,
    source: Source,
    goal: Option<JointValues>,
) -> Result<(ExecutionPayload, PayloadPaths), Error> {
    match source {
        Source::Inline {
            joint_names,
            points,
        } => {
            if goal.is_some() {
                return Err(Error::invalid(
                    "$.goal",
                    "a trajectory ends at its own last point; goal is only for model_id",
                ));
            }
            Ok((
                ExecutionPayload::Trajectory {
                    trajectory_id: "inline".into(),
                    joint_names,
                    points,
                },
                PayloadPaths::all("$.trajectory.joint_names", "$.trajectory.points", "$.goal"),
            ))
        }
        Source::Trajectory(id) => {
            if goal.is_some() {
                return Err(Error::invalid(
                    "$.goal",
                    "a stored trajectory brings its own goal; goal is only for model_id",
                ));
            }
            stored_trajectory(ctx, robot, mode, &id).await
        }
        Source::Model(model_id) => {
            if mode != Mode::ClosedLoop {
                return Err(Error::invalid(
                    "$.mode",
                    "a model runs its law in closed_loop; for open_loop generate a trajectory \
                     (POST /v1/trajectories) and pass its trajectory_id",
                ));
            }
            let goal = goal.ok_or_else(|| Error::invalid("$.goal", "model_id needs a goal"))?;
            let params = params(ctx, &model_id, robot, "$.model_id").await?;
            let goal = ordered_goal(&goal, &params.joint_names)?;
            Ok((
                ExecutionPayload::Model {
                    model_id,
                    params,
                    goal,
                    safety: None,
                    // no start is known here to generate the open-loop path from: the worker
                    // runs the bare law (eq. 8) from where its robot is
                    path: None,
                },
                PayloadPaths::all("$.model_id", "$.model_id", "$.goal.positions"),
            ))
        }
    }
}

async fn stored_trajectory(
    ctx: &Context,
    robot: &str,
    mode: Mode,
    id: &str,
) -> Result<(ExecutionPayload, PayloadPaths), Error> {
    let t = trajectories::get_trajectory(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::invalid("$.trajectory_id", format!("unknown trajectory '{id}'")))?;
    if t.robot != robot {
        return Err(Error::invalid(
            "$.trajectory_id",
            format!(
                "trajectory '{id}' is for robot '{}', not '{robot}'",
                t.robot
            ),
        ));
    }
    // A trajectory the service itself found colliding in its scene is not sent to a robot
    // (a plan with such a motion is infeasible and queues nothing; this is the same rule for
    // a trajectory run on its own). Its points can still be run inline, on the caller's word.
    if let Some(words) = stored_collision(&t.summary) {
        return Err(Error::invalid(
            "$.trajectory_id",
            format!(
                "trajectory '{id}' is not collision-free in its own scene ({words}), so it is \
                 not run; generate it again (another start, obstacles, an approach_standoff), \
                 or send its points inline as `trajectory` to run them unchecked"
            ),
        ));
    }
    let paths = PayloadPaths::all("$.trajectory_id", "$.trajectory_id", "$.trajectory_id");
    match mode {
        Mode::OpenLoop => Ok((
            ExecutionPayload::Trajectory {
                trajectory_id: t.id,
                joint_names: t.joint_names,
                points: t.points,
            },
            paths,
        )),
        Mode::Streaming => Err(Error::invalid(
            "$.mode",
            "a streaming execution starts from the retargeting WebSocket \
             (GET /v1/robots/{id}/retarget?forward=true)",
        )),
        Mode::ClosedLoop => {
            let model_id = t.model_id.ok_or_else(|| {
                Error::invalid(
                    "$.mode",
                    format!(
                        "trajectory '{id}' was not generated by a model, so it has no \
                         closed-loop law; run it in open_loop"
                    ),
                )
            })?;
            let params = params(ctx, &model_id, robot, "$.trajectory_id").await?;
            // The model generated the trajectory in its own joint order; the law runs it.
            if t.joint_names != params.joint_names {
                return Err(Error::invalid(
                    "$.trajectory_id",
                    "the trajectory's joints differ from its model's",
                ));
            }
            let goal = ordered_goal(
                &JointValues {
                    joint_names: t.joint_names,
                    positions: t.goal,
                },
                &params.joint_names,
            )
            .map_err(|_| {
                Error::invalid(
                    "$.trajectory_id",
                    "the trajectory's joints differ from its model's",
                )
            })?;
            // The law gets the filter a closed-loop plan gives it, around the same scene.
            let safety = stored_safety(ctx, &t.id, &t.request).await?;
            let filtered = safety.is_some();
            // (the law's joint order, the trajectory's: checked equal above)
            let names = params.joint_names.clone();
            let payload = ExecutionPayload::Model {
                model_id,
                params,
                goal,
                safety: safety.map(Box::new),
                path: Some(t.points),
            };
            // And the same rule: the law is run once here, as a closed-loop plan runs it
            // before it queues it, and one that stops short is not sent to a robot.
            if filtered {
                let sys = super::grasps::robot_view(ctx, robot).await?;
                if let Some(why) =
                    super::plans::law_short(sys, names, t.start, payload.clone()).await?
                {
                    return Err(Error::invalid(
                        "$.trajectory_id",
                        format!(
                            "trajectory '{id}' in closed loop: {why}; run it in open_loop, or \
                             plan from another start"
                        ),
                    ));
                }
            }
            Ok((payload, paths))
        }
    }
}

/// The safety filter's scene for the closed-loop law of stored trajectory `id` (its request
/// JSON `request`), as a closed-loop plan sends it: the object of the stored grasp its goal
/// names or of the plan that made it, and its obstacles. `None` where it has neither (a
/// trajectory to a configuration in no scene), which runs the law as before.
async fn stored_safety(
    ctx: &Context,
    id: &str,
    request: &str,
) -> Result<Option<SafetySpec>, Error> {
    let request: serde_json::Value = serde_json::from_str(request).unwrap_or_default();
    // (validated when the trajectory was made: what does not parse now is our fault, not the
    // caller's, and is not dropped silently)
    let obstacles: Vec<ObstacleSpec> = request
        .get("obstacles")
        .map(|o| serde_json::from_value(o.clone()))
        .transpose()
        .map_err(Error::internal)?
        .unwrap_or_default();
    let grasp_id = match request["goal"]["grasp"].as_str() {
        Some(g) => Some(g.to_owned()),
        None => plans::of_trajectory(&ctx.db, id).await?.map(|p| p.grasp_id),
    };
    let object = match grasp_id {
        Some(g) => match grasps::get_grasp(&ctx.db, &g).await? {
            Some(row) => {
                Some(serde_json::from_str::<ObjectSpec>(&row.object).map_err(Error::internal)?)
            }
            None => None,
        },
        None => None,
    };
    if object.is_none() && obstacles.is_empty() {
        return Ok(None);
    }
    Ok(Some(SafetySpec::new(object, obstacles)))
}

/// Why a stored trajectory's own exact clearance check (its report's `clearance`) found it
/// colliding, or `None` (collision-free, or checked in no scene).
fn stored_collision(summary: &str) -> Option<String> {
    #[derive(serde::Deserialize)]
    struct Report {
        #[serde(default)]
        clearance: Option<PathClearance>,
    }
    let c = serde_json::from_str::<Report>(summary).ok()?.clearance?;
    if c.collision_free {
        return None;
    }
    Some(c.collision_words().unwrap_or_else(|| {
        "its clearance could not be checked along the whole path within the check's step budget"
            .to_owned()
    }))
}

/// The closed-loop parameters of a trained model of `robot`; errors name `path`.
async fn params(
    ctx: &Context,
    model_id: &str,
    robot: &str,
    path: &str,
) -> Result<ControlParams, Error> {
    let row = models::get_model(&ctx.db, model_id)
        .await?
        .ok_or_else(|| Error::invalid(path, format!("unknown model '{model_id}'")))?;
    if row.robot != robot {
        return Err(Error::invalid(
            path,
            format!(
                "model '{model_id}' is for robot '{}', not '{robot}'",
                row.robot
            ),
        ));
    }
    models::load_params(&ctx.db, model_id)
        .await?
        .ok_or_else(|| {
            Error::Conflict(format!(
                "model '{model_id}' is not trained (its job is {})",
                row.status
            ))
        })
}

/// Orders named joint values like `names`; errors name `$.goal...`.
fn ordered_goal(goal: &JointValues, names: &[String]) -> Result<Vec<f64>, Error> {
    if goal.joint_names.len() != goal.positions.len() {
        return Err(Error::invalid(
            "$.goal.positions",
            format!(
                "{} positions for {} joint names",
                goal.positions.len(),
                goal.joint_names.len()
            ),
        ));
    }
    let mut errors = Vec::new();
    let mut out = Vec::with_capacity(names.len());
    for n in names {
        match goal.joint_names.iter().position(|g| g == n) {
            Some(i) => out.push(goal.positions[i]),
            None => errors.push(Invalid::new(
                "$.goal.joint_names",
                format!("joint '{n}' is missing"),
            )),
        }
    }
    for (i, g) in goal.joint_names.iter().enumerate() {
        if !names.contains(g) {
            errors.push(Invalid::new(
                format!("$.goal.joint_names[{i}]"),
                format!("'{g}' is not a joint of this robot"),
            ));
        }
    }
    if errors.is_empty() {
        Ok(out)
    } else {
        Err(Error::Invalid(errors))
    }
}
