//! Plans: one request from object and task to a humanlike motion ending in a task-specific
//! grasp, and optionally its execution.
//!
//! A plan is one unit of work: its grasp, trajectory, execution and plan rows are written in
//! one transaction, so they are stored together or not at all (a failure after the grasp
//! leaves no grasp behind). The dispatcher is woken only after the commit; it reads the queue
//! through other connections, so it never sees an execution whose plan was rolled back.

use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::grasps::GraspIn;
use super::models::{AutoOr, JointValues};
use super::trajectories::{CreateTrajectory, GoalIn, Rejected};
use super::{Context, Error, Keyword};
use crate::bridge::protocol::Capability;
use crate::bridge::{
    ExecutionPayload, Hub, Mode, PhysicsScene, PhysicsTrial, TrialSpec, WorkerName,
};
use crate::geometry::SceneShape;
use crate::grasp::{HandArm, PathClearance};
use crate::motion::ControlParams;
use crate::store::grasps::{self as grasp_repo, GraspRow, NewGrasp};
use crate::store::models as model_repo;
use crate::store::payload::SafetySpec;
use crate::store::plans::{self as plan_repo, NewPlan};
use crate::store::trajectories::{self, StoredTrajectory, TrajectoryDraft};

pub use crate::store::plans::PlanRow;

/// Where the trajectory starts.
///
/// Deserialized by hand rather than as an untagged enum, so that a bad field inside the
/// configuration is reported at its own path (`$.start.positions`: "invalid type: string
/// \"zero\", expected a sequence") instead of "did not match any variant".
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(untagged)]
pub enum StartIn {
    /// A configuration: every independent joint of the robot once, any order.
    Configuration(JointValues),
    /// A word. `"current"`: where the connected worker for the robot (the one named by
    /// `worker`, if given) will be when an execution queued now starts: the end of what it runs
    /// or has queued before, else its state as its last heartbeat or feedback reported it.
    /// `"zero"`: the robot's zero configuration (every independent joint at 0, or at its
    /// nearest position limit when 0 is outside its range), whichever robot is asked for.
    Word(String),
}

impl<'de> Deserialize<'de> for StartIn {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Start;
        impl<'de> serde::de::Visitor<'de> for Start {
            type Value = StartIn;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "a configuration {\"joint_names\": [...], \"positions\": [...]}, \"current\" or \"zero\"",
                )
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<StartIn, E> {
                Ok(StartIn::Word(v.to_owned()))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<StartIn, A::Error> {
                // The same map access: its keys stay on the error path.
                JointValues::deserialize(serde::de::value::MapAccessDeserializer::new(map))
                    .map(StartIn::Configuration)
            }
        }
        d.deserialize_any(Start)
    }
}

/// Object and task in, humanlike motion to a task-specific grasp out.
///
/// The wire form is flat (the grasp request's fields beside the plan's own); it is read
/// through [`PlanWire`], a plain struct, because serde's `flatten` buffers the fields and
/// loses their paths (`"robot": 123` was reported at `$`).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(from = "PlanWire")]
pub struct PlanIn {
    /// Robot, object (`object_id` or inline `object`), task directions, quality measure and the
    /// grasp optimiser's settings: the body of `POST /v1/grasps`.
    #[serde(flatten)]
    pub grasp: GraspIn,
    /// Start of the motion: a configuration, `"current"` (where the connected worker will be:
    /// its measured state, or the end of what it runs or has queued before), or `"zero"` (the
    /// robot's zero configuration, clamped into its joint limits). With `execute`, a
    /// configuration farther than the worker's start tolerance from that is a 422.
    pub start: StartIn,
    /// Motion model id (default: the robot's default model).
    pub model: Option<String>,
    /// `"auto"` (learned from the demonstrations, default) or seconds.
    pub duration: Option<AutoOr>,
    /// Trajectory output rate, Hz (default 100).
    pub rate: Option<f64>,
    /// Queue the motion for execution on a bridge worker.
    #[serde(default)]
    pub execute: bool,
    /// Verify the grasp in physics (implies `execute`): the execution goes to a worker with the
    /// `grasp_trial` capability (a physics worker), which runs the motion with contacts in the
    /// plan's scene (the grasp's object with its `mass` and `friction`, its support, the
    /// obstacles) and then the grasp trial; the plan's `verification` reports the verdict. The
    /// object must have a mass and a friction coefficient (the seeded objects have).
    #[serde(default)]
    pub verify: bool,
    /// The grasp trial's lift, hold and shakes (only with `verify`; default 0.1 m, 2 s, 2).
    pub trial: Option<crate::bridge::TrialSpec>,
    /// Execution mode (default `open_loop`: follow the trajectory; `closed_loop`: the worker
    /// runs the model's law along the trajectory's path to the grasp configuration, with a
    /// clock that waits while the robot is pushed off it).
    pub mode: Option<crate::bridge::RequestedMode>,
    /// Worker to execute on (default: the connected worker of the robot the start was checked
    /// against, or any when none is connected); also the worker whose state `"current"` reads.
    pub worker: Option<String>,
    /// Further obstacles in the robot base frame besides the object and its support (at most
    /// 32): the humanlike path is moved to keep a margin from them, the object and the support
    /// (`trajectory.report.avoidance`), and the result's exact clearance is reported.
    #[serde(default)]
    #[schema(max_items = 32)]
    pub obstacles: Vec<crate::geometry::ObstacleSpec>,
    /// Pre-grasp standoff, m, in [0, 0.25] (0.06 is a typical value): the path then ends at the
    /// palm this far back along the approach direction with the hand opened, then moves in along
    /// a straight line and closes (`trajectory.report.approach`). Absent: none, unless the path
    /// without one collides with the object; then 0.06 is tried and used where it is
    /// collision-free. 0: none at all.
    #[schema(minimum = 0, maximum = 0.25)]
    pub approach_standoff: Option<f64>,
}

/// The flat wire form of [`PlanIn`]: every field of [`GraspIn`] and the plan's own, so that
/// each is deserialized (and reported) at its own path. `a_plan_reads_every_grasp_field` keeps
/// it in step with [`GraspIn`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanWire {
    robot: String,
    object_id: Option<String>,
    object: Option<super::grasps::ObjectIn>,
    #[serde(default)]
    task_directions: Vec<super::grasps::TaskDirectionIn>,
    quality: Option<crate::grasp::QualityMeasure>,
    weights: Option<crate::grasp::Weights>,
    starts: Option<usize>,
    max_starts: Option<usize>,
    seed: Option<u64>,
    #[serde(default, deserialize_with = "crate::wire::exact")]
    elbow_reference: Option<[f64; 3]>,
    start: StartIn,
    model: Option<String>,
    duration: Option<AutoOr>,
    rate: Option<f64>,
    #[serde(default)]
    execute: bool,
    #[serde(default)]
    verify: bool,
    trial: Option<crate::bridge::TrialSpec>,
    mode: Option<crate::bridge::RequestedMode>,
    worker: Option<String>,
    #[serde(default)]
    obstacles: Vec<crate::geometry::ObstacleSpec>,
    approach_standoff: Option<f64>,
}

impl From<PlanWire> for PlanIn {
    fn from(w: PlanWire) -> Self {
        PlanIn {
            grasp: GraspIn {
                robot: w.robot,
                object_id: w.object_id,
                object: w.object,
                task_directions: w.task_directions,
                quality: w.quality,
                weights: w.weights,
                starts: w.starts,
                max_starts: w.max_starts,
                seed: w.seed,
                elbow_reference: w.elbow_reference,
            },
            start: w.start,
            model: w.model,
            duration: w.duration,
            rate: w.rate,
            execute: w.execute,
            verify: w.verify,
            trial: w.trial,
            mode: w.mode,
            worker: w.worker,
            obstacles: w.obstacles,
            approach_standoff: w.approach_standoff,
        }
    }
}

impl PlanIn {
    /// Whether the motion is queued for execution (`execute`, or `verify`, which implies it).
    pub fn executes(&self) -> bool {
        self.execute || self.verify
    }

    /// The capabilities the executing worker needs beyond the mode's.
    fn needs(&self) -> &'static [Capability] {
        if self.verify {
            &[Capability::GraspTrial]
        } else {
            &[]
        }
    }
}

/// How long each step took (s), over every grasp tried.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlanTimings {
    pub grasp_s: f64,
    pub trajectory_s: f64,
    pub total_s: f64,
    /// Grasps found and dropped before the plan's own, because no collision-free motion
    /// reached them (only where the request set no grasp `seed`: the search then runs again
    /// with the next one, at most [`GRASP_ATTEMPTS`] grasps in all).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected_grasps: Vec<RejectedGrasp>,
}

/// A grasp a plan dropped: the search's seed that found it, and why its motion was refused.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RejectedGrasp {
    pub seed: u64,
    pub reason: String,
}

/// Most grasps a plan tries (see [`PlanTimings::rejected_grasps`]): a grasp search and a
/// trajectory each; measured over the 120-plan survey, 4 grasps had no collision-free motion,
/// and a second or third seed reached a clear one for 3 of them. 5 rather than 3 since
/// 2026-12-07: with 64 grasp starts the pa10_ob4f bottle force plan from the bent elbow found
/// no clear motion for seeds 0-3 (the palm through the bottle, or a fingertip 10.5 mm into it)
/// and one for seed 4. A plan with no collision-free motion at all costs up to five grasp
/// searches and trajectories before it answers infeasible.
pub const GRASP_ATTEMPTS: usize = 5;

/// The model to plan with: the named one, or the robot's default. While first-start seeding
/// is still training the default, 503 `not-ready` names the job to watch.
async fn resolve_model(ctx: &Context, body: &PlanIn) -> Result<String, Error> {
    if let Some(m) = &body.model {
        return Ok(m.clone());
    }
    let robot = &body.grasp.robot;
    if let Some(row) = model_repo::default_model_for(&ctx.db, robot).await? {
        return Ok(row.id);
    }
    if let Some(job) = ctx.seed.pending_job(robot) {
        return Err(Error::NotReady {
            message: format!(
                "the default model of '{robot}' is still being prepared by first-start seeding; \
                 retry when job {job} has finished (GET /v1/jobs/{job})"
            ),
            job,
        });
    }
    Err(Error::invalid(
        "$.model",
        format!(
            "robot '{robot}' has no trained model; train one (POST /v1/models) or name one here"
        ),
    ))
}

/// The start configuration; `"current"` reads where the connected worker will be when an
/// execution queued now starts: the end of what it runs or has queued before, else its measured
/// state; `"zero"` is the robot's zero configuration (clamped into the limits, so that it is
/// always a valid start of that robot). With `"current"`, also the worker it read.
async fn resolve_start(
    ctx: &Context,
    body: &PlanIn,
) -> Result<(JointValues, Option<String>), Error> {
    match &body.start {
        StartIn::Configuration(v) => Ok((v.clone(), None)),
        StartIn::Word(s) if Keyword::parse(s) == Some(Keyword::Zero) => {
            let system = ctx.robots.system(&body.grasp.robot).await?;
            Ok((zero_configuration(&system.model), None))
        }
        StartIn::Word(s) if Keyword::parse(s) == Some(Keyword::Current) => {
            let robot = &body.grasp.robot;
            let needs = body.needs();
            let state =
                super::bridges::expected_states(ctx, robot, body.worker.as_deref(), needs)
                    .await?
                    .into_iter()
                    .next()
                    .ok_or_else(|| {
                        let physics = if needs.is_empty() {
                            ""
                        } else {
                            " with the grasp_trial capability (verify)"
                        };
                        Error::invalid(
                            "$.start",
                            match &body.worker {
                                Some(n) => format!(
                                    "\"current\" needs worker '{n}' connected for robot '{robot}'{physics} and reporting its state"
                                ),
                                None => format!(
                                    "\"current\" needs a worker connected for robot '{robot}'{physics} and reporting its state; give a configuration instead"
                                ),
                            },
                        )
                    })?;
            Ok((
                JointValues {
                    joint_names: state.joint_names,
                    positions: state.positions,
                },
                Some(state.worker),
            ))
        }
        StartIn::Word(other) => Err(Error::invalid(
            "$.start",
            format!(
                "must be a configuration {{joint_names, positions}}, \"current\" or \"zero\", got \"{other}\""
            ),
        )),
    }
}

/// Every independent joint of `model` at 0, or at its nearest position limit when 0 is outside
/// the joint's range.
pub fn zero_configuration(model: &crate::kinematics::Model) -> JointValues {
    JointValues {
        joint_names: model.joint_names().to_vec(),
        positions: model
            .lower_limits()
            .iter()
            .zip(model.upper_limits())
            .map(|(&lo, &hi)| 0.0_f64.clamp(lo, hi))
            .collect(),
    }
}

/// Plans (and optionally queues) one grasping motion; the work of `POST /v1/plans` and
/// `reachgrasp plan`. Everything is computed first; the rows are then stored as one unit of
/// work ([`store`]).
pub async fn plan(ctx: &Context, body: &PlanIn) -> Result<Planned, Error> {
    let t0 = Instant::now();
    let robot = body.grasp.robot.clone();
    let worker = body.worker.as_deref().map(WorkerName::parse).transpose()?;
    let obstacles = super::trajectories::scene_obstacles(&body.obstacles)?;
    super::trajectories::approach_standoff(body.approach_standoff, "$.approach_standoff")?;
    super::robots::robot_field(ctx, &robot, "$.robot").await?;
    let verified = check_verify(ctx, body).await?;
    let model_id = resolve_model(ctx, body).await?;
    let (start, read_from) = resolve_start(ctx, body).await?;
    let (model_robot, q_start) = super::trajectories::check_start(ctx, &model_id, &start).await?;
    if model_robot != robot {
        return Err(Error::invalid(
            "$.model",
            format!("model '{model_id}' is of robot '{model_robot}', not '{robot}'"),
        ));
    }
    // A motion to execute must start where the robot will be: checked against the connected
    // workers now (nothing to check without one; the worker checks again when it starts), and
    // the execution goes to the worker it was checked against.
    let worker = match (body.executes(), worker, read_from) {
        (true, None, Some(w)) => Some(WorkerName::parse(&w)?),
        (true, w, None) => {
            let checked = super::bridges::check_start(
                ctx,
                &robot,
                (w.as_ref().map(WorkerName::as_str), body.needs()),
                &start.joint_names,
                &start.positions,
                "$.start",
            )
            .await?;
            match (w, checked) {
                (Some(w), _) => Some(w),
                (None, c) => c.as_deref().map(WorkerName::parse).transpose()?,
            }
        }
        (_, w, _) => w,
    };

    // A plan's grasp must land in the model's certified goal regions: the search starts at
    // their centre (the arm branch and hand posture the demonstrations end on) and keeps inside.
    let regions = super::models::goal_regions(ctx, &model_id).await?;
    let prepared = match verified {
        Some(p) => p,
        None => super::grasps::prepare(ctx, &body.grasp).await?,
    };
    let trial_object = body.verify.then(|| prepared.object().spec().clone());
    // (checked and resolved above without waiting: a bad request is answered at once)
    let search = grasp_search(
        ctx.clone(),
        body.clone(),
        prepared,
        regions,
        model_id.clone(),
        start,
        q_start,
        obstacles,
    );
    let (found, rejected) = ctx.compute.run(search).await??;
    let (grasp_s, trajectory_s) = (found.grasp_s, found.trajectory_s);
    let Attempt {
        grasp: new_grasp,
        trajectory,
        safety,
        law_system,
        mut reason,
        idle_fingers,
        ..
    } = found;

    let mut execution = match (body.executes(), &trajectory) {
        (true, Some(_)) if reason.is_none() => {
            let mode = body.mode.map_or(Mode::OpenLoop, Mode::from);
            let law = match mode {
                Mode::OpenLoop | Mode::Streaming => None,
                Mode::ClosedLoop => Some((
                    model_id.clone(),
                    model_repo::load_params(&ctx.db, &model_id)
                        .await?
                        .ok_or_else(|| {
                            Error::internal(anyhow::anyhow!("model {model_id} has no parameters"))
                        })?,
                )),
            };
            Some(ExecutionRequest {
                mode,
                worker,
                law,
                safety,
                trial: trial_object
                    .clone()
                    .map(|o| physics_trial(body, o, idle_fingers.clone())),
            })
        }
        _ => None,
    };
    // A closed-loop law is run here first, as the reference worker runs it (along its path,
    // through its safety filter, no pushes): a law that stops short of the grasp is no plan to
    // queue.
    if let (
        Some(ExecutionRequest {
            law: Some((model, params)),
            safety: Some(spec),
            ..
        }),
        Some(t),
        Some(sys),
    ) = (&execution, &trajectory, &law_system)
    {
        let payload = law_payload((model, params), &t.goal, &t.points, Some(spec.clone()));
        let (names, start) = (t.joint_names.clone(), t.start.clone());
        if let Some(why) = law_short(sys.clone(), names, start, payload).await? {
            reason = Some(format!(
                "closed loop: {why}; plan it open loop, or from another start"
            ));
            execution = None;
        }
    }
    let timings = PlanTimings {
        grasp_s,
        trajectory_s,
        total_s: t0.elapsed().as_secs_f64(),
        rejected_grasps: rejected,
    };
    let rows = PlanRows {
        grasp: new_grasp,
        trajectory,
        execution,
        plan: plan_repo::NewPlan {
            robot: robot.clone(),
            model_id: Some(model_id.clone()),
            grasp_id: String::new(),
            trajectory_id: None,
            execution_id: None,
            feasible: reason.is_none(),
            reason: reason.clone(),
            request: request_json(body)?,
            timings: serde_json::to_string(&timings).map_err(Error::internal)?,
        },
    };
    let stored = store(ctx, rows).await?;
    Ok(Planned {
        stored,
        reason,
        timings,
    })
}

/// Refuses what a physics check could not honour, before anything is computed: `trial`
/// without `verify`, a trial out of range, an object without a mass or a friction coefficient.
async fn check_verify(
    ctx: &Context,
    body: &PlanIn,
) -> Result<Option<super::grasps::Prepared>, Error> {
    if let Some(t) = &body.trial {
        if !body.verify {
            return Err(Error::invalid(
                "$.trial",
                "a grasp trial is run only with \"verify\": true",
            ));
        }
        if let Some((field, why)) = t.invalid_field() {
            return Err(Error::invalid(format!("$.trial.{field}"), why));
        }
    }
    if !body.verify {
        return Ok(None);
    }
    // (a named worker that is not connected may still come: the execution waits for it)
    if let Some(name) = &body.worker
        && let Some(w) = ctx.bridges.workers().into_iter().find(|w| w.name == *name)
        && !w.can(Capability::GraspTrial)
    {
        return Err(Error::invalid(
            "$.worker",
            format!(
                "worker '{name}' does not announce the grasp_trial capability: a verified plan \
                 runs only on a physics worker"
            ),
        ));
    }
    let prepared = super::grasps::prepare(ctx, &body.grasp).await?;
    if let Some((field, meaning)) = prepared.object().spec().missing_physics() {
        return Err(match &body.grasp.object_id {
            Some(id) => Error::invalid(
                "$.object_id",
                format!(
                    "object '{id}' has no {field}: a physics check (verify) needs {meaning}; \
                     store the object again with \"{field}\" (POST /v1/objects) or give it \
                     inline"
                ),
            ),
            None => Error::invalid(
                format!("$.object.{field}"),
                format!("required with \"verify\": true ({meaning})"),
            ),
        });
    }
    Ok(Some(prepared))
}

/// The grasp trial of a plan with `verify`: the grasp's own object (as the grasp was computed,
/// with its support), the request's obstacles and the grasp's idle fingers.
fn physics_trial(
    body: &PlanIn,
    object: crate::grasp::ObjectSpec,
    idle_fingers: Vec<String>,
) -> PhysicsTrial {
    PhysicsTrial {
        idle_fingers,
        scene: PhysicsScene {
            support: object.support,
            object,
            obstacles: body.obstacles.clone(),
        },
        trial: body.trial.unwrap_or_default(),
    }
}

/// Why a plan whose motion is not collision-free is infeasible: which link meets what, where
/// and how deep (`None`: the motion is collision-free).
fn collision_reason(c: &PathClearance) -> Option<String> {
    if c.collision_free {
        return None;
    }
    Some(match c.collision_words() {
        Some(words) if c.complete => format!(
            "no collision-free motion to the grasp: {words}; the trajectory is kept for inspection"
        ),
        _ => "the motion's clearance could not be checked along the whole path within the \
              check's step budget"
            .to_owned(),
    })
}

/// One grasp and the motion to it, as a plan computes them.
struct Attempt {
    grasp: NewGrasp,
    trajectory: Option<TrajectoryDraft>,
    safety: Option<SafetySpec>,
    /// The system a closed-loop law is simulated on before it is queued.
    law_system: Option<Arc<HandArm>>,
    /// Why the plan would be infeasible with them.
    reason: Option<String>,
    /// The motion collides (a grasp with another seed may not).
    collided: bool,
    /// The grasp's fingers kept off the object (the physics trial leaves them as they are).
    idle_fingers: Vec<String>,
    grasp_s: f64,
    trajectory_s: f64,
}

/// The attempts of one plan (owned: it runs on the compute gate's task): a grasp that no
/// collision-free motion reaches is followed by the same search with the next seed, while the
/// request left the seed to us. Other starts end on other grasps, and one of them is often
/// reachable (the pa10_ihy ball from zero: the thumb pressed 5.0 mm into the ball with seed 0,
/// seeds 1-3 clear). The last attempt, its times the sums over all, and the grasps rejected.
#[allow(clippy::too_many_arguments)]
async fn grasp_search(
    ctx: Context,
    body: PlanIn,
    mut prepared: super::grasps::Prepared,
    regions: Vec<super::models::NamedGoalRegion>,
    model_id: String,
    start: JointValues,
    q_start: Vec<f64>,
    obstacles: Vec<SceneShape>,
) -> Result<(Attempt, Vec<RejectedGrasp>), Error> {
    let mut seed = body.grasp.seed.unwrap_or(0);
    let mut rejected = Vec::new();
    let (mut grasp_s, mut trajectory_s) = (0.0, 0.0);
    loop {
        let mut a = attempt(
            &ctx, &body, &prepared, &regions, &model_id, &start, &q_start, &obstacles,
        )
        .await?;
        grasp_s += a.grasp_s;
        trajectory_s += a.trajectory_s;
        match a.reason.take() {
            Some(why)
                if a.collided
                    && body.grasp.seed.is_none()
                    && rejected.len() + 1 < GRASP_ATTEMPTS =>
            {
                rejected.push(RejectedGrasp { seed, reason: why });
                seed += 1;
                prepared.with_seed(seed);
            }
            reason => {
                a.reason = reason;
                (a.grasp_s, a.trajectory_s) = (grasp_s, trajectory_s);
                return Ok((a, rejected));
            }
        }
    }
}

/// The grasp `prepared` asks for (in the model's goal regions) and the motion to it from
/// `start` (`q_start`, checked clear of the scene here).
#[allow(clippy::too_many_arguments)]
async fn attempt(
    ctx: &Context,
    body: &PlanIn,
    prepared: &super::grasps::Prepared,
    regions: &[super::models::NamedGoalRegion],
    model_id: &str,
    start: &JointValues,
    q_start: &[f64],
    obstacles: &[SceneShape],
) -> Result<Attempt, Error> {
    let t_attempt = Instant::now();
    let (new_grasp, result, scene) = prepared.compute(regions).await?;
    // (the scene is known once the grasp's object is: a plan from a colliding start is refused
    // whether or not a grasp is found)
    super::trajectories::start_clear(&scene.sys, scene.object.as_ref(), obstacles, q_start)?;
    let grasp_s = t_attempt.elapsed().as_secs_f64();
    let mut collided = false;
    let mut reason = (!result.feasible).then(|| {
        format!(
            "no feasible grasp: {}",
            result.reason.as_deref().unwrap_or("no reason given")
        )
    });
    let mut trajectory = None;
    let mut safety = None;
    // (the system a closed-loop law is simulated on before it is queued)
    let mut law_system = None;
    if reason.is_none() {
        let (joint_names, positions) = result
            .q_arm
            .iter()
            .chain(&result.q_hand)
            .map(|j| (j.name.clone(), j.value))
            .unzip();
        let request = CreateTrajectory {
            model: model_id.to_owned(),
            start: start.clone(),
            goal: GoalIn {
                joint_names: Some(joint_names),
                positions: Some(positions),
                grasp: None,
            },
            duration: body.duration.clone(),
            rate: body.rate,
            obstacles: body.obstacles.clone(),
            approach_standoff: body.approach_standoff,
        };
        // A closed-loop execution runs this trajectory's path (`motion::PathFollower`), the
        // straight entry into the workspace included, so it is planned as open loop is.
        let closed_loop =
            body.executes() && body.mode == Some(crate::bridge::RequestedMode::ClosedLoop);
        // What the worker's safety filter keeps that law clear of (issue 18 item 3).
        safety = closed_loop.then(|| {
            SafetySpec::new(
                scene.object.as_ref().map(|o| o.spec().clone()),
                body.obstacles.clone(),
            )
        });
        law_system = closed_loop.then(|| scene.sys.clone());
        match super::trajectories::compute(ctx, &request, Some(scene)).await {
            // A motion that collides is kept with the plan for inspection, but the plan is
            // infeasible and nothing is queued.
            Ok((t, clearance)) => {
                collided = clearance.as_ref().is_some_and(|c| !c.collision_free);
                reason = clearance.as_ref().and_then(collision_reason);
                trajectory = Some(t);
            }
            // The grasp is the goal: a goal the model cannot certify (outside its goal region
            // or its joint limits) makes the plan infeasible, not the request bad.
            Err(Rejected::Goal(reasons)) => {
                let why: Vec<&str> = reasons.iter().map(|f| f.message.as_str()).collect();
                reason = Some(format!(
                    "the grasp is no goal the model can reach with its convergence guarantee: {}",
                    why.join("; ")
                ));
            }
            Err(Rejected::Other(e)) => return Err(e),
        }
    }
    Ok(Attempt {
        grasp: new_grasp,
        trajectory_s: t_attempt.elapsed().as_secs_f64() - grasp_s,
        trajectory,
        safety,
        law_system,
        reason,
        collided,
        idle_fingers: result.idle_fingers.clone(),
        grasp_s,
    })
}

/// The request as stored with the plan (what was asked, including the resolved start).
fn request_json(body: &PlanIn) -> Result<String, Error> {
    let value = serde_json::json!({
        "robot": body.grasp.robot,
        "object_id": body.grasp.object_id,
        "inline_object": body.grasp.object.is_some(),
        "start": body.start,
        "model": body.model,
        "duration": body.duration,
        "rate": body.rate,
        "execute": body.execute,
        "verify": body.verify,
        "trial": body.trial,
        "mode": body.mode,
        "worker": body.worker,
        "obstacles": body.obstacles,
    });
    serde_json::to_string(&value).map_err(Error::internal)
}

/// Plans, newest first, optionally of one robot; with how many match without the page.
pub async fn list(
    ctx: &Context,
    robot: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<(Vec<PlanRow>, i64), Error> {
    Ok(plan_repo::list(&ctx.db, robot, limit.into(), offset.into()).await?)
}

/// Stored plan `id` with its grasp and trajectory (a plan whose grasp or trajectory has been
/// deleted since conflicts with the stored state).
pub async fn get(ctx: &Context, id: &str) -> Result<StoredPlan, Error> {
    let plan = plan_repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("plan", id))?;
    let grasp = grasp_repo::get_grasp(&ctx.db, &plan.grasp_id)
        .await?
        .ok_or_else(|| {
            Error::Conflict(format!(
                "the plan's grasp {} no longer exists",
                plan.grasp_id
            ))
        })?;
    let trajectory = match &plan.trajectory_id {
        Some(t) => Some(
            trajectories::get_trajectory(&ctx.db, t)
                .await?
                .ok_or_else(|| {
                    Error::Conflict(format!("the plan's trajectory {t} no longer exists"))
                })?,
        ),
        None => None,
    };
    let verification = verification(ctx, plan.execution_id.as_deref()).await?;
    Ok(StoredPlan {
        grasp,
        trajectory,
        execution_id: plan.execution_id.clone(),
        plan,
        verification,
    })
}

/// The physics check of a plan whose execution is `execution` (`None`: it has none, or its
/// execution runs no grasp trial, or was deleted).
pub async fn verification(
    ctx: &Context,
    execution: Option<&str>,
) -> Result<Option<Verification>, Error> {
    let Some(id) = execution else {
        return Ok(None);
    };
    Ok(match crate::store::executions::get(&ctx.db, id).await? {
        Some(row) if row.grasp_trial => {
            let trial = crate::store::executions::trial(&ctx.db, id).await?;
            Verification::of_stored(&row, trial)
        }
        _ => None,
    })
}

/// A stored plan with why it is infeasible, if it is, and how long its steps took.
#[derive(Debug, Clone)]
pub struct Planned {
    pub stored: StoredPlan,
    pub reason: Option<String>,
    pub timings: PlanTimings,
}

/// What to queue with a plan.
#[derive(Debug, Clone)]
pub struct ExecutionRequest {
    pub mode: Mode,
    /// Run on this worker only (default: any idle worker of the robot).
    pub worker: Option<WorkerName>,
    /// The model's law for a closed-loop execution (`model_id`, its parameters).
    pub law: Option<(String, ControlParams)>,
    /// The scene the worker's safety filter keeps a closed-loop law clear of.
    pub safety: Option<SafetySpec>,
    /// A grasp trial in physics after the motion (`verify`).
    pub trial: Option<crate::bridge::PhysicsTrial>,
}

/// Everything a plan stores, computed before anything is written.
#[derive(Debug, Clone)]
pub struct PlanRows {
    pub grasp: NewGrasp,
    /// The motion to the grasp, when one was generated (a plan infeasible because it collides
    /// keeps it for inspection).
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
    /// The physics check of a plan with `verify`, as far as it has come.
    pub verification: Option<Verification>,
}

/// A plan's physics check (`verify`): its execution on a physics worker, which runs the motion
/// with contacts and then the grasp trial, and the trial's verdict once the worker reported it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Verification {
    /// The execution (`GET /v1/executions/{id}`: the whole report under `tracking.physics`).
    pub execution_id: String,
    /// The execution's state: `queued` until a worker with the `grasp_trial` capability takes
    /// it, `running`, then `succeeded` (the motion arrived and the object is held), `failed`
    /// (with `reason`), `aborted`, `cancelled` or `interrupted`.
    pub state: String,
    /// Why the execution failed or stopped, as the worker or the service said.
    pub reason: Option<String>,
    /// The trial run: lift, hold, shakes.
    pub trial: TrialSpec,
    /// The simulator that ran it, once it reported.
    pub engine: Option<String>,
    /// The object is off the support, at least half the lift above where it started and
    /// touching the hand at the end (absent until reported, or when no trial ran: the motion
    /// did not arrive).
    pub held: Option<bool>,
    /// The object moved more than 1 cm relative to the hand.
    pub slipped: Option<bool>,
    /// The object's displacement relative to the hand from the end of closing to the end, m.
    pub slip_m: Option<f64>,
    /// How far the object rose, m.
    pub object_lift_m: Option<f64>,
    /// Mean total normal force on the object during the hold, N.
    pub contact_force_total_mean_n: Option<f64>,
    /// Deepest overlap seen in the simulation, m, per pair kind.
    pub max_penetration_m: Option<std::collections::BTreeMap<String, f64>>,
}

impl Verification {
    /// The check of execution `row` with its stored grasp trial: none where it runs no trial
    /// (or its trial is not stored).
    pub fn of_stored(
        row: &crate::store::executions::ExecutionRow,
        trial: Option<PhysicsTrial>,
    ) -> Option<Verification> {
        trial
            .filter(|_| row.grasp_trial)
            .map(|t| Verification::of(row, t.trial))
    }

    /// The check of execution `row` (one with a grasp trial, `trial`).
    pub fn of(row: &crate::store::executions::ExecutionRow, trial: TrialSpec) -> Verification {
        let physics = row
            .tracking
            .as_deref()
            .and_then(|t| serde_json::from_str::<crate::bridge::TrackingSummary>(t).ok())
            .and_then(|t| t.physics);
        let verdict = physics.as_ref().and_then(|p| p.trial.as_ref());
        Verification {
            execution_id: row.id.clone(),
            state: row.state.to_string(),
            reason: row.reason.clone(),
            trial,
            engine: physics.as_ref().map(|p| p.engine.clone()),
            held: verdict.map(|v| v.held),
            slipped: verdict.map(|v| v.slipped),
            slip_m: verdict.map(|v| v.slip_m),
            object_lift_m: verdict.map(|v| v.object_lift_m),
            contact_force_total_mean_n: verdict.and_then(|v| v.contact_force_total_mean_n),
            max_penetration_m: verdict.and_then(|v| v.max_penetration_m.clone()),
        }
    }
}

/// The writes of a plan, in order (for tests that make one fail).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Write {
    Grasp,
    Trajectory,
    Execution,
}

/// Runs a closed-loop payload on the reference worker's simulated robot from `start`, off the
/// async runtime: `None` when it arrives, else why not. The one rule for a plan's law and for a
/// stored trajectory's law run by id (`executions`): a law that stops short is not queued.
pub(super) async fn law_short(
    sys: Arc<HandArm>,
    joint_names: Vec<String>,
    start: Vec<f64>,
    payload: ExecutionPayload,
) -> Result<Option<String>, Error> {
    tokio::task::spawn_blocking(move || simulate_law(&sys, &joint_names, &start, payload))
        .await
        .map_err(Error::internal)?
        .map_err(|e| Error::internal(anyhow::anyhow!("simulating the law: {e}")))
}

/// Runs a closed-loop payload on the reference worker's simulated robot from `start` (at its
/// default acceleration limit, no pushes): `None` when it arrives, else why not.
fn simulate_law(
    sys: &crate::grasp::HandArm,
    joint_names: &[String],
    start: &[f64],
    payload: ExecutionPayload,
) -> Result<Option<String>, String> {
    use crate::bridge::protocol::{Execute, Outcome};
    use crate::bridge::sim::{DEFAULT_ACCELERATION_LIMIT, Run, RunOptions, SimLimits, SimRobot};
    let m = &*sys.model;
    let limits = SimLimits::new(
        m.lower_limits(),
        m.upper_limits(),
        m.velocity_limits(),
        DEFAULT_ACCELERATION_LIMIT,
    );
    let mut robot = SimRobot::new(limits, start.to_vec());
    let execute = Execute {
        execution_id: String::new(),
        mode: Mode::ClosedLoop,
        payload,
        scene: None,
        trial: None,
        idle_fingers: Vec::new(),
    };
    let opts = RunOptions::default();
    let mut run = Run::new(&execute, joint_names, &robot, opts, None, Some(sys))?;
    let dt = 0.01;
    // (bounded: the run ends failed at its convergence timeout)
    let (outcome, why) = loop {
        if let Some(done) = run.tick(&mut robot, dt) {
            break done;
        }
    };
    if outcome == Outcome::Succeeded {
        return Ok(None);
    }
    let closest = run
        .safety_report()
        .and_then(|r| match (r.link, r.other, r.min_distance_m, r.time_s) {
            (Some(link), Some(other), Some(d), Some(t)) => Some(format!(
                "; its closest pair: '{link}' {:.1} mm from '{other}' at t = {t:.2} s",
                1e3 * d
            )),
            _ => None,
        })
        .unwrap_or_default();
    Ok(Some(format!(
        "the model's law, run from the start through its safety filter as the reference \
         worker runs it ({DEFAULT_ACCELERATION_LIMIT} rad/s², no pushes), does not arrive: \
         {}{closest}",
        why.unwrap_or_else(|| "it stopped".into())
    )))
}

/// The one execution payload builder: a stored trajectory to follow (open loop), or the
/// model's law run along the trajectory's path to its goal (closed loop).
pub fn payload(
    mode: Mode,
    trajectory: &StoredTrajectory,
    law: Option<&(String, ControlParams)>,
    safety: Option<SafetySpec>,
) -> Result<ExecutionPayload, Error> {
    match (mode, law) {
        (Mode::OpenLoop, _) => Ok(ExecutionPayload::Trajectory {
            trajectory_id: trajectory.id.clone(),
            joint_names: trajectory.joint_names.clone(),
            points: trajectory.points.clone(),
        }),
        (Mode::ClosedLoop, Some((model_id, params))) => Ok(law_payload(
            (model_id, params),
            &trajectory.goal,
            &trajectory.points,
            safety,
        )),
        (Mode::ClosedLoop, None) => Err(Error::internal(anyhow::anyhow!(
            "a closed-loop execution needs the model's law"
        ))),
        (Mode::Streaming, _) => Err(Error::internal(anyhow::anyhow!(
            "a plan's execution follows its trajectory or its model's law, not a stream"
        ))),
    }
}

/// The model's law run along a trajectory's `path` to its `goal` (what a closed-loop plan
/// queues, and what it runs itself before queueing).
fn law_payload(
    (model_id, params): (&String, &ControlParams),
    goal: &[f64],
    path: &[crate::motion::TrajectoryPoint],
    safety: Option<SafetySpec>,
) -> ExecutionPayload {
    ExecutionPayload::Model {
        model_id: model_id.clone(),
        params: params.clone(),
        goal: goal.to_vec(),
        safety: safety.map(Box::new),
        path: Some(path.to_vec()),
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
    let mut tx = crate::store::begin_write(&ctx.db).await?;
    let grasp = grasp_repo::insert_grasp_in(&mut tx, &grasp, None).await?;
    after(Write::Grasp)?;
    let trajectory = match &trajectory {
        Some(t) => Some(trajectories::insert_trajectory_in(&mut tx, &t.as_new()).await?),
        None => None,
    };
    after(Write::Trajectory)?;
    let mut execution_id = None;
    let mut verification = None;
    if let (Some(e), Some(t)) = (&execution, &trajectory) {
        let p = payload(e.mode, t, e.law.as_ref(), e.safety.clone())?;
        // The library reads through another pooled connection; in WAL mode that read does not
        // wait for this transaction.
        ctx.bridges.check(&plan.robot, e.mode, &p).await?;
        let id = Hub::insert_in(
            &mut tx,
            &plan.robot,
            e.mode,
            &p,
            e.worker.as_ref(),
            e.trial.as_ref(),
        )
        .await?;
        verification = e.trial.as_ref().map(|trial| Verification {
            execution_id: id.clone(),
            state: crate::store::executions::ExecutionState::Queued.to_string(),
            reason: None,
            trial: trial.trial,
            engine: None,
            held: None,
            slipped: None,
            slip_m: None,
            object_lift_m: None,
            contact_force_total_mean_n: None,
            max_penetration_m: None,
        });
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
        verification,
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
                safety: None,
                trial: None,
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

    /// The path serde_path_to_error reports for a bad plan body.
    fn bad_path(body: &str) -> String {
        let mut de = serde_json::Deserializer::from_str(body);
        let err = serde_path_to_error::deserialize::<_, PlanIn>(&mut de).unwrap_err();
        err.path().to_string()
    }

    #[test]
    fn a_plan_reads_every_grasp_field() {
        // Every property of the grasp request is a field of the plan's flat wire form: a
        // value of the wrong type is refused at its own path, never ignored.
        let schema = serde_json::to_value(<GraspIn as utoipa::PartialSchema>::schema()).unwrap();
        let props = schema["properties"]
            .as_object()
            .expect("GraspIn has properties");
        assert!(props.len() >= 9, "{schema}");
        for name in props.keys() {
            let robot = if name == "robot" {
                ""
            } else {
                r#""robot": "r", "#
            };
            let body = format!(r#"{{{robot}"start": "current", "{name}": true}}"#);
            assert_eq!(bad_path(&body), *name, "{body}");
        }
    }

    #[test]
    fn bad_plan_fields_are_reported_at_their_own_path() {
        assert_eq!(bad_path(r#"{"robot": 123, "start": "current"}"#), "robot");
        assert_eq!(
            bad_path(r#"{"robot": "r", "start": {"joint_names": ["a"], "positions": "zero"}}"#),
            "start.positions"
        );
        assert_eq!(bad_path(r#"{"robot": "r", "start": 5}"#), "start");
        let ok: PlanIn = serde_json::from_str(
            r#"{"robot": "r", "object_id": "ball", "start": {"joint_names": ["a"], "positions": [0.5]}, "execute": true}"#,
        )
        .unwrap();
        assert_eq!(ok.grasp.robot, "r");
        assert_eq!(ok.grasp.object_id.as_deref(), Some("ball"));
        assert!(ok.execute);
        assert!(matches!(ok.start, StartIn::Configuration(ref v) if v.positions == [0.5]));
        let current: PlanIn =
            serde_json::from_str(r#"{"robot": "r", "start": "current"}"#).unwrap();
        assert!(matches!(current.start, StartIn::Word(ref s) if s == "current"));
    }

    /// The same `"start": "zero"` is each robot's own zero configuration (the dashboard's form
    /// sends it with whichever robot is chosen), and an unknown word names the two there are.
    #[tokio::test]
    async fn a_zero_start_is_the_zero_configuration_of_the_robot_asked_for() {
        let dir = tempfile::tempdir().unwrap();
        let ctx = super::super::test_context(dir.path()).await;
        for robot in ["wam_ihy", "pa10_t42"] {
            let body: PlanIn = serde_json::from_value(serde_json::json!({
                "robot": robot, "object_id": "ball", "start": "zero"}))
            .unwrap();
            let (start, worker) = resolve_start(&ctx, &body).await.expect(robot);
            let model = ctx.robots.system(robot).await.unwrap().model.clone();
            assert_eq!(start.joint_names, model.joint_names(), "{robot}");
            assert!(start.positions.iter().all(|&v| v == 0.0), "{robot}");
            assert_eq!(worker, None);
        }
        // A joint whose range excludes 0 starts at its nearest limit.
        let mut b = crate::kinematics::ModelBuilder::new("base");
        let limits = crate::kinematics::JointLimits::new(0.2, 1.0, 1.0, 1.0);
        let axis = nalgebra::Vector3::z_axis();
        b.add_joint(
            "j",
            b.root(),
            "l",
            crate::kinematics::JointKind::Revolute { axis },
            nalgebra::Isometry3::identity(),
            limits,
            None,
        )
        .unwrap();
        assert_eq!(zero_configuration(&b.build().unwrap()).positions, [0.2]);
        let body: PlanIn = serde_json::from_value(serde_json::json!({
            "robot": "wam_ihy", "object_id": "ball", "start": "home"}))
        .unwrap();
        let e = resolve_start(&ctx, &body).await.unwrap_err().to_string();
        assert!(e.contains("\"zero\"") && e.contains("\"home\""), "{e}");
    }
}
