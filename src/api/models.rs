//! `/v1/models` (PCA + navigation-function motion models learned from stored mappings, paper
//! eq. 8-9; training is a job) and `/v1/trajectories` (humanlike trajectories generated from a
//! model, stored).
//!
//! Joint vectors travel as `{joint_names, positions}` (any order, every independent joint of the
//! robot once), as in `/v1/robots`; answers use the model's joint order and name it. A start or
//! goal the model cannot certify (outside the workspace or the goal region) is refused with 422:
//! no plan is made without the convergence guarantee.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex, OnceLock};

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, FieldError, Json, Path, Problem, Query};
use crate::grasp::GraspResult;
use crate::jobs::{JobError, JobOutput, JobRecord, ResultRef};
use crate::kinematics::{Data, JointVector, KinematicsError, System, forward_kinematics};
use crate::motion::mapped::{DEFAULT_ACCELERATION_LIMIT, system_groups, system_limits};
use crate::motion::{
    Certificate, Components, ControlParams, DEFAULT_PROFILE_RIDGE, HeldOutReport, JointTrajectory,
    KChoice, MAX_DIM, MotionError, MotionModel, TensorBSpline, TrainOptions, TrainReport,
    Trajectory, TrajectoryOptions, TrajectoryPoint, train,
};
use crate::store::library::LibraryError;
use crate::store::trajectories::TrajectoryDraft;
use crate::store::{grasps as grasp_repo, mappings as mapping_repo, models as repo, trajectories};

/// Largest spline resolution (knot intervals per PCA axis) a request may ask for.
pub const MAX_SPLINE_INTERVALS: usize = 12;
/// Highest output rate of a trajectory (Hz).
pub const MAX_RATE: f64 = 1000.0;
/// Longest trajectory a request may ask for (s).
pub const MAX_DURATION: f64 = 60.0;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_models, create_model))
        .routes(routes!(get_model))
        .routes(routes!(get_params))
        .routes(routes!(control))
        .routes(routes!(list_trajectories, create_trajectory))
        .routes(routes!(get_trajectory))
}

// ---------------------------------------------------------------------------------------------
// DTOs

/// `"auto"` or a number.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum AutoOr {
    Value(f64),
    Auto(String),
}

/// Closed-loop gains stored with the model (what `/params` hands to bridge workers).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ControlGains {
    /// On-manifold convergence rate near the goal, 1/s (sets each group's `K_p`; default 2).
    pub rate: f64,
    /// Off-manifold gain `K_⊥`, 1/s (default 2).
    pub k_perp: f64,
}

impl Default for ControlGains {
    fn default() -> Self {
        ControlGains {
            rate: 2.0,
            k_perp: 2.0,
        }
    }
}

/// Train a motion model from stored mappings.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateModel {
    /// Robot (arm-hand system) id; every mapping must be of this robot.
    pub robot: String,
    /// Ids of succeeded mappings whose demonstrations are the training data.
    pub mappings: Vec<String>,
    /// Fixed number of principal components per joint group (arm, hand); give this or
    /// `variance_threshold`.
    pub components: Option<usize>,
    /// Keep the fewest components explaining this fraction of the variance (default 0.88).
    pub variance_threshold: Option<f64>,
    /// Spline resolution: knot intervals per PCA axis of the learned field (default 6, lowered
    /// for a manifold with so many components that the spline would exceed its coefficient
    /// budget; an explicit value is never lowered).
    pub spline_intervals: Option<usize>,
    /// Weight of the spline fit's smoothness + ridge penalty (default 3).
    pub regularisation: Option<f64>,
    /// `k` of eq. 9: `"auto"` (the smallest certified value, default) or a number ≥ 1 (the
    /// learned field is shrunk until the certificate holds).
    pub k: Option<AutoOr>,
    /// Evaluate humanlikeness on held-out object positions (train on the others, one fold per
    /// position; default true).
    pub held_out: Option<bool>,
    /// Learn the goal-conditioned residual profile that shapes each path between its exact start
    /// and goal like the demonstrations (default true). The NF flow strictly approaches its goal
    /// and its field does not depend on the goal, so on its own it cannot follow a hand that opens
    /// before it closes or a reach whose shape changes with the object's position; the profile
    /// carries that part. Flow, certificate and closed-loop law are the same either way.
    pub residual_profile: Option<bool>,
    /// Ridge of the residual profile's fit (default 0.1, per demonstration and rad² of
    /// start-goal difference); must be positive.
    pub profile_ridge: Option<f64>,
    /// Joint acceleration limit, rad/s² (default 5; URDF has none).
    pub acceleration_limit: Option<f64>,
    pub control: Option<ControlGains>,
    /// Make this the robot's default model once trained (default false).
    #[serde(default)]
    pub default: bool,
}

/// A convergence certificate (DESIGN §5): `γ` strictly decreases along the flow for every goal in
/// the goal region and start in the workspace ball, since `bound < 2k`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct CertificateDto {
    /// `arm` or `hand`.
    pub group: String,
    pub k: f64,
    pub spline_bound: f64,
    pub workspace_bound: f64,
    /// `spline_bound + workspace_bound`, the closed-form bound of `sup (y − y_d)·∇log β`.
    pub bound: f64,
    pub holds: bool,
    /// Guaranteed decay: `γ̇ ≤ −decay_rate·γ` (per unit flow time).
    pub decay_rate: f64,
    /// Factor the fitted field was multiplied by to satisfy the certificate (1 = unshrunk).
    pub shrink: f64,
    /// Workspace ball in PCA coordinates (starts must lie strictly inside).
    pub workspace_center: Vec<f64>,
    pub workspace_radius: f64,
}

/// The goal region of one joint group: a ball in PCA coordinates.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GoalRegionDto {
    pub group: String,
    pub center: Vec<f64>,
    /// Radius in PCA coordinates (rad: the PCA basis is orthonormal).
    pub radius: f64,
    /// The centre back-projected into the group's joints (`joint_names` of the group).
    pub center_positions: Vec<f64>,
}

/// One joint group's manifold and fit.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ManifoldDto {
    /// `arm` or `hand`.
    pub group: String,
    pub joint_names: Vec<String>,
    pub components: usize,
    /// Fraction of the group's variance explained by each kept component.
    pub explained_variance: Vec<f64>,
    pub cumulative_explained_variance: f64,
    /// Fractions of every component (descending), for scree plots.
    pub all_explained_variance: Vec<f64>,
    /// Demonstrated points in the spline fit.
    pub spline_points: usize,
    /// Knot intervals per PCA axis of the learned field.
    pub spline_intervals: usize,
    /// Mean cosine between the flow and the demonstrated velocity (training data).
    pub train_alignment: f64,
    /// Ridge of the learned residual profile that shapes this group's paths; absent when the
    /// model was trained without one (`residual_profile: false`).
    pub residual_profile_ridge: Option<f64>,
    /// What the residual profile is linear in: `all_ends` (start and goal of all joints, what
    /// the service trains) or `group_delta` (goal − start of the group's joints: models trained
    /// before the choice existed); absent without a profile.
    pub residual_profile_inputs: Option<String>,
    pub certificate: CertificateDto,
    pub goal_region: GoalRegionDto,
}

/// Humanlikeness on held-out data: mean arc-length-resampled joint-space deviation (rad) from the
/// held-out mapped trajectory, for the NF model, the straight joint line and the straight line in
/// PCA space (`k → ∞`).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct HeldOutDto {
    pub demonstrations: usize,
    /// Held-out demonstrations outside the fold model's goal region or workspace (refused).
    pub refused: usize,
    pub nf: f64,
    pub joint_line: f64,
    pub pca_line: f64,
    /// `nf / joint_line` (the goal: ≤ 0.7).
    pub ratio_to_joint_line: f64,
}

/// One held-out fold: trained without one object position, tested on it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FoldDto {
    pub position_index: u32,
    /// `None` when the fold could not be trained (`error` says why).
    pub result: Option<HeldOutDto>,
    /// Flow-demonstration alignment on the held-out data, per group.
    pub held_out_alignment: Vec<Option<f64>>,
    pub error: Option<String>,
}

/// Held-out evaluation over every object position.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct HeldOutSummaryDto {
    pub folds: Vec<FoldDto>,
    /// Means over every evaluated held-out demonstration of all folds.
    pub overall: Option<HeldOutDto>,
}

/// Learned duration `T(d) = max(intercept + slope·d, min_duration)`, `d` the joint-space
/// distance (rad) from start to goal.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DurationDto {
    pub intercept: f64,
    pub slope: f64,
    pub min_duration: f64,
}

/// What training produced (stored with the model).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelReportDto {
    pub training_demonstrations: usize,
    pub manifolds: Vec<ManifoldDto>,
    pub duration: DurationDto,
    /// Joint limits used (model order): acceleration limit, rad/s².
    pub acceleration_limit: f64,
    pub held_out: Option<HeldOutSummaryDto>,
}

/// A model: its training request, status (the job's) and, once trained, its report.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelDto {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    /// `queued|running|succeeded|failed|cancelled` (the training job's).
    pub status: String,
    /// Explicitly marked as the robot's default.
    pub default: bool,
    /// The model's joint order.
    pub joint_names: Vec<String>,
    #[schema(value_type = Object)]
    pub request: serde_json::Value,
    pub report: Option<ModelReportDto>,
    pub created_at: String,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ModelList {
    pub items: Vec<ModelDto>,
    pub total: i64,
    pub limit: u32,
    pub offset: u32,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ModelQuery {
    /// Only models of this robot.
    pub robot: Option<String>,
    /// Page size, 1 to 500 (default 50).
    pub limit: Option<u32>,
    /// Models to skip (default 0).
    pub offset: Option<u32>,
}

/// A joint vector: values paired with names (every independent joint once, any order).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JointValues {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
}

/// Evaluate the closed-loop law `u(q) = W(−K_p ∇_y φ) + K_⊥(I − WWᵀ)(q_d − q)`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ControlRequest {
    /// Measured state.
    pub q: JointValues,
    /// Goal configuration (must lie in the model's goal region).
    pub goal: JointValues,
}

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ControlResponse {
    /// Order of `u`: the model's joints.
    pub joint_names: Vec<String>,
    /// Joint velocity command, rad/s.
    pub u: Vec<f64>,
}

/// A trajectory goal: a configuration (`joint_names` + `positions`), or `{"grasp": id}` (the
/// stored grasp's arm and hand joint values, `/v1/grasps`).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GoalIn {
    pub joint_names: Option<Vec<String>>,
    pub positions: Option<Vec<f64>>,
    pub grasp: Option<String>,
}

/// Generate a humanlike trajectory with a model.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateTrajectory {
    /// Model id.
    pub model: String,
    pub start: JointValues,
    pub goal: GoalIn,
    /// `"auto"` (learned from the demonstrations, default) or seconds. A duration too short for
    /// the joint limits is replaced by the shortest feasible one (`stretched`, `note`).
    pub duration: Option<AutoOr>,
    /// Output rate, Hz (default 100, at most 1000).
    pub rate: Option<f64>,
}

/// A path of one frame in Cartesian space (robot base frame, metres), one position per point.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FramePathDto {
    /// Finger name, or the frame name for the elbow.
    pub name: String,
    pub frame: String,
    pub positions: Vec<[f64; 3]>,
}

/// A timed point (model joint order).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PointDto {
    pub t: f64,
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
}

/// Where the flow of one group stopped.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GroupErrorDto {
    pub group: String,
    /// Distance to the goal (rad, joint space of the group's manifold) where the flow stopped,
    /// before the exact goal closed the path.
    pub error: f64,
    pub flow_steps: usize,
}

/// How a trajectory was generated (stored with it).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryReportDto {
    /// Seconds (the last point's `t`).
    pub duration: f64,
    /// The duration asked for (`None`: auto).
    pub requested_duration: Option<f64>,
    /// The duration learned from the demonstrations for this distance.
    pub learned_duration: f64,
    /// The duration was lengthened to respect the velocity/acceleration limits.
    pub stretched: bool,
    /// Why the duration differs from the request, when it does.
    pub note: Option<String>,
    pub rate: f64,
    /// Every group's flow reached the goal within tolerance (`γ` decreasing, certified).
    pub converged: bool,
    /// Largest group error (rad), see `errors`.
    pub final_error: f64,
    pub errors: Vec<GroupErrorDto>,
    pub certificates: Vec<CertificateDto>,
    /// Largest fraction of a velocity / acceleration limit used (≤ 1).
    pub max_velocity_ratio: f64,
    pub max_acceleration_ratio: f64,
    pub fingertip_paths: Vec<FramePathDto>,
    pub elbow_paths: Vec<FramePathDto>,
    /// The grasp the goal came from, if any.
    pub grasp: Option<String>,
}

/// A stored trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryDto {
    pub id: String,
    pub model_id: Option<String>,
    pub robot: String,
    /// Order of every vector of `start`, `goal` and `points`.
    pub joint_names: Vec<String>,
    pub start: Vec<f64>,
    pub goal: Vec<f64>,
    pub points: Vec<PointDto>,
    pub report: TrajectoryReportDto,
    pub created_at: String,
}

/// A trajectory in a listing (no points).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectorySummaryDto {
    pub id: String,
    pub model_id: Option<String>,
    pub robot: String,
    pub duration: f64,
    pub converged: bool,
    pub stretched: bool,
    pub created_at: String,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryList {
    pub items: Vec<TrajectorySummaryDto>,
    pub total: i64,
    pub limit: u32,
    pub offset: u32,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct TrajectoryQuery {
    /// Only trajectories of this model.
    pub model: Option<String>,
    /// Page size, 1 to 500 (default 50).
    pub limit: Option<u32>,
    /// Trajectories to skip (default 0).
    pub offset: Option<u32>,
}

// ---------------------------------------------------------------------------------------------
// Helpers

fn group_name(system_groups: usize, g: usize) -> String {
    match (system_groups, g) {
        (2, 0) => "arm".into(),
        (2, 1) => "hand".into(),
        (_, g) => format!("group{g}"),
    }
}

fn certificate_dto(group: String, c: &Certificate) -> CertificateDto {
    CertificateDto {
        group,
        k: c.k,
        spline_bound: c.spline_bound,
        workspace_bound: c.workspace_bound,
        bound: c.bound,
        holds: c.holds,
        decay_rate: c.decay_rate,
        shrink: c.shrink,
        workspace_center: c.workspace_center.clone(),
        workspace_radius: c.workspace_radius,
    }
}

fn held_out_dto(h: &HeldOutReport) -> HeldOutDto {
    HeldOutDto {
        demonstrations: h.demonstrations,
        refused: h.refused,
        nf: h.nf,
        joint_line: h.joint_line,
        pca_line: h.pca_line,
        ratio_to_joint_line: h.ratio_to_joint_line,
    }
}

/// A joint vector in model order, with errors pointing into the request (`base` is e.g.
/// `$.start`).
fn joint_values(system: &System, v: &JointValues, base: &str) -> Result<Vec<f64>, ApiError> {
    let model = &system.model;
    if v.joint_names.len() != v.positions.len() {
        return Err(ApiError::invalid_field(
            format!("{base}.positions"),
            format!(
                "{} positions for {} joint names",
                v.positions.len(),
                v.joint_names.len()
            ),
        ));
    }
    if let Some(i) = v.positions.iter().position(|x| !x.is_finite()) {
        return Err(ApiError::invalid_field(
            format!("{base}.positions[{i}]"),
            format!("joint '{}' must be a finite number", v.joint_names[i]),
        ));
    }
    let q = JointVector::from_named(model, &v.joint_names, &v.positions).map_err(|e| {
        let path = match &e {
            KinematicsError::UnknownJoint { name } | KinematicsError::RepeatedJoint { name } => {
                let i = v
                    .joint_names
                    .iter()
                    .rposition(|n| n == name)
                    .unwrap_or_default();
                format!("{base}.joint_names[{i}]")
            }
            _ => format!("{base}.joint_names"),
        };
        ApiError::invalid_field(path, e.to_string())
    })?;
    Ok(q.as_slice().to_vec())
}

/// Checks `q` (model order) against the position limits; errors name the request index.
fn check_limits(
    model: &MotionModel,
    names: &[String],
    q: &[f64],
    request_names: Option<&[String]>,
    base: &str,
) -> Result<(), ApiError> {
    let mut errors = Vec::new();
    for (j, &v) in q.iter().enumerate() {
        let (lo, hi) = (model.limits.lower[j], model.limits.upper[j]);
        let tol = 1e-9 * (1.0 + v.abs());
        if v < lo - tol || v > hi + tol {
            let path = match request_names.and_then(|r| r.iter().position(|n| *n == names[j])) {
                Some(i) => format!("{base}.positions[{i}]"),
                None => base.to_owned(),
            };
            errors.push(FieldError::new(
                path,
                format!(
                    "joint '{}' = {v} is outside its limits [{lo}, {hi}]",
                    names[j]
                ),
            ));
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(ApiError::validation(errors))
    }
}

fn region_error(e: MotionError, groups: usize, start: &str, goal: &str) -> ApiError {
    match e {
        MotionError::GoalOutsideRegion {
            group,
            distance,
            radius,
        } => ApiError::invalid_field(
            goal,
            format!(
                "the goal is outside the model's certified goal region ({} joints: {distance:.4} from its centre, radius {radius:.4}); no plan is made without the convergence guarantee",
                group_name(groups, group)
            ),
        ),
        MotionError::StartOutsideWorkspace {
            group,
            distance,
            radius,
        } => ApiError::invalid_field(
            start,
            format!(
                "the start is outside the model's workspace ({} joints: {distance:.4} from its centre, radius {radius:.4})",
                group_name(groups, group)
            ),
        ),
        MotionError::InvalidOption { field, .. } => {
            ApiError::invalid_field(format!("$.{field}"), e.to_string())
        }
        other => ApiError::invalid_field("$", other.to_string()),
    }
}

/// A trained model with its joint order and closed-loop parameters. Trained models never
/// change, so they are cached by id (bounded) instead of parsed on every control call.
#[derive(Debug)]
struct Loaded {
    robot: String,
    names: Vec<String>,
    model: MotionModel,
    params: ControlParams,
}

fn model_cache() -> &'static Mutex<HashMap<String, Arc<Loaded>>> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<Loaded>>>> = OnceLock::new();
    CACHE.get_or_init(Default::default)
}

/// The trained model `id`: 404 if unknown, 409 while it is not trained (`field`: where the id
/// came from in a body, `None` for a path parameter).
async fn loaded_model(
    state: &AppState,
    id: &str,
    field: Option<&str>,
) -> Result<Arc<Loaded>, ApiError> {
    if let Some(l) = model_cache().lock().expect("model cache").get(id) {
        return Ok(l.clone());
    }
    let unknown = || match field {
        Some(f) => ApiError::invalid_field(f, format!("unknown model '{id}'")),
        None => ApiError::not_found("model", id),
    };
    let row = repo::get_model(&state.db, id).await?.ok_or_else(unknown)?;
    let model = repo::load_model(&state.db, id).await?;
    let params = repo::load_params(&state.db, id).await?;
    let (Some(model), Some(params)) = (model, params) else {
        let msg = format!(
            "model '{id}' is not trained (status {}); watch job {}",
            row.status, row.job_id
        );
        return Err(match field {
            Some(f) => ApiError::invalid_field(f, msg),
            None => ApiError::conflict(msg),
        });
    };
    let loaded = Arc::new(Loaded {
        robot: row.robot,
        names: params.joint_names.clone(),
        model,
        params,
    });
    let mut cache = model_cache().lock().expect("model cache");
    if cache.len() >= 64 {
        cache.clear();
    }
    cache.insert(id.to_owned(), loaded.clone());
    Ok(loaded)
}

fn model_dto(row: repo::ModelRow, names: Vec<String>, default: bool) -> Result<ModelDto, ApiError> {
    Ok(ModelDto {
        request: serde_json::from_str(&row.request).map_err(ApiError::internal)?,
        report: row
            .report
            .as_deref()
            .map(serde_json::from_str)
            .transpose()
            .map_err(ApiError::internal)?,
        id: row.id,
        job_id: row.job_id,
        robot: row.robot,
        status: row.status,
        default,
        joint_names: names,
        created_at: row.created_at,
    })
}

// ---------------------------------------------------------------------------------------------
// Training

struct Validated {
    options: TrainOptions,
    acceleration: f64,
    gains: ControlGains,
    held_out: bool,
}

fn validate_training(body: &CreateModel, system: &System) -> Result<Validated, ApiError> {
    let mut errors = Vec::new();
    let groups = system_groups(system);
    let smallest = groups.iter().map(Vec::len).min().unwrap_or(0);
    let components = match (body.components, body.variance_threshold) {
        (Some(_), Some(_)) => {
            errors.push(FieldError::new(
                "$.components",
                "give components or variance_threshold, not both",
            ));
            Components::default()
        }
        (Some(c), None) => {
            let max = MAX_DIM.min(smallest);
            if c == 0 || c > max {
                errors.push(FieldError::new(
                    "$.components",
                    format!(
                        "must be between 1 and {max} (the smallest joint group of this robot has {smallest} joints; at most {MAX_DIM} supported), got {c}"
                    ),
                ));
            }
            Components::Count(c)
        }
        (None, Some(t)) => {
            if !(t > 0.0 && t <= 1.0) {
                errors.push(FieldError::new(
                    "$.variance_threshold",
                    format!("must be in (0, 1], got {t}"),
                ));
            }
            Components::VarianceThreshold(t)
        }
        (None, None) => Components::default(),
    };
    let intervals = body.spline_intervals.unwrap_or(6);
    if !(1..=MAX_SPLINE_INTERVALS).contains(&intervals) {
        errors.push(FieldError::new(
            "$.spline_intervals",
            format!("must be between 1 and {MAX_SPLINE_INTERVALS}, got {intervals}"),
        ));
    } else if let Components::Count(c) = components
        && body.spline_intervals.is_some()
        && (1..=MAX_DIM).contains(&c)
    {
        let coefficients = TensorBSpline::coefficient_count(c, intervals);
        if coefficients > crate::motion::MAX_SPLINE_COEFFICIENTS {
            errors.push(FieldError::new(
                "$.spline_intervals",
                format!(
                    "{intervals} intervals on {c} components need {coefficients} spline coefficients, at most {} supported",
                    crate::motion::MAX_SPLINE_COEFFICIENTS
                ),
            ));
        }
    }
    let regularisation = body.regularisation.unwrap_or(3.0);
    if !(regularisation > 0.0 && regularisation.is_finite()) {
        errors.push(FieldError::new(
            "$.regularisation",
            format!("must be a positive number, got {regularisation}"),
        ));
    }
    let k = match &body.k {
        None => KChoice::Auto,
        Some(AutoOr::Auto(s)) if s == "auto" => KChoice::Auto,
        Some(AutoOr::Auto(s)) => {
            errors.push(FieldError::new(
                "$.k",
                format!("must be \"auto\" or a number ≥ 1, got \"{s}\""),
            ));
            KChoice::Auto
        }
        Some(AutoOr::Value(k)) => {
            if !(*k >= 1.0 && k.is_finite()) {
                errors.push(FieldError::new(
                    "$.k",
                    format!("must be \"auto\" or a number ≥ 1, got {k}"),
                ));
            }
            KChoice::Value(*k)
        }
    };
    let acceleration = body
        .acceleration_limit
        .unwrap_or(DEFAULT_ACCELERATION_LIMIT);
    if !(acceleration > 0.0 && acceleration.is_finite()) {
        errors.push(FieldError::new(
            "$.acceleration_limit",
            format!("must be a positive number, got {acceleration}"),
        ));
    }
    let profile_ridge = body.profile_ridge.unwrap_or(DEFAULT_PROFILE_RIDGE);
    if !(profile_ridge > 0.0 && profile_ridge.is_finite()) {
        errors.push(FieldError::new(
            "$.profile_ridge",
            format!("must be a positive number, got {profile_ridge}"),
        ));
    }
    if body.residual_profile == Some(false) && body.profile_ridge.is_some() {
        errors.push(FieldError::new(
            "$.profile_ridge",
            "given with residual_profile false",
        ));
    }
    let gains = body.control.unwrap_or_default();
    if !(gains.rate > 0.0 && gains.rate.is_finite()) {
        errors.push(FieldError::new(
            "$.control.rate",
            "must be a positive number",
        ));
    }
    if !(gains.k_perp >= 0.0 && gains.k_perp.is_finite()) {
        errors.push(FieldError::new(
            "$.control.k_perp",
            "must be a non-negative number",
        ));
    }
    if !errors.is_empty() {
        return Err(ApiError::validation(errors));
    }
    Ok(Validated {
        options: TrainOptions {
            groups,
            components,
            spline_intervals: intervals,
            // the default resolution is lowered where many components would exceed the
            // coefficient budget; an explicit one is honoured or refused
            cap_spline_intervals: body.spline_intervals.is_none(),
            regularisation,
            k,
            profile_ridge: body
                .residual_profile
                .unwrap_or(true)
                .then_some(profile_ridge),
            ..TrainOptions::default()
        },
        acceleration,
        gains,
        held_out: body.held_out.unwrap_or(true),
    })
}

/// The fewest demonstrations a model with these components can be trained from: every
/// demonstration gives one start-goal pair, and the goal region and the spline fit need more pairs
/// than the manifold has dimensions.
fn demonstrations_needed(components: Components) -> usize {
    match components {
        Components::Count(c) => (c + 1).max(3),
        Components::VarianceThreshold(_) => 3,
    }
}

/// The report stored with a model (training fit, certificate, goal region, held-out folds).
fn model_report(
    system: &System,
    model: &MotionModel,
    report: &TrainReport,
    acceleration: f64,
    held_out: Option<HeldOutSummaryDto>,
) -> ModelReportDto {
    let names = system.model.joint_names();
    let ng = model.manifolds.len();
    let manifolds = model
        .manifolds
        .iter()
        .zip(&report.manifolds)
        .enumerate()
        .map(|(g, (m, fit))| {
            let mut center = vec![0.0; m.joints.len()];
            m.pca.back_project(&m.certificate.goal_center, &mut center);
            ManifoldDto {
                group: group_name(ng, g),
                joint_names: m.joints.iter().map(|&j| names[j].clone()).collect(),
                components: fit.components,
                explained_variance: fit.explained_variance.clone(),
                cumulative_explained_variance: fit.cumulative_explained_variance,
                all_explained_variance: m.pca.all_explained_variance.clone(),
                spline_points: fit.spline_points,
                spline_intervals: m.nf.spline.intervals(),
                train_alignment: fit.train_alignment,
                residual_profile_ridge: m.profile.as_ref().map(|p| p.ridge),
                residual_profile_inputs: m.profile.as_ref().and_then(|p| {
                    serde_json::to_value(p.inputs)
                        .ok()
                        .and_then(|v| v.as_str().map(str::to_owned))
                }),
                certificate: certificate_dto(group_name(ng, g), &m.certificate),
                goal_region: GoalRegionDto {
                    group: group_name(ng, g),
                    center: m.certificate.goal_center.clone(),
                    radius: m.certificate.goal_radius,
                    center_positions: center,
                },
            }
        })
        .collect();
    ModelReportDto {
        training_demonstrations: report.training_demonstrations,
        manifolds,
        duration: DurationDto {
            intercept: report.duration.intercept,
            slope: report.duration.slope,
            min_duration: report.duration.min_duration,
        },
        acceleration_limit: acceleration,
        held_out,
    }
}

/// Held-out humanlikeness, one fold per object position (train on the others). Positions are
/// the demonstrations' `position_index` labels; `None` with fewer than two positions.
pub fn held_out_folds(
    demos: &[JointTrajectory],
    positions: &[u32],
    limits: &crate::motion::JointLimits,
    options: &TrainOptions,
    mut progress: impl FnMut(usize, usize),
) -> Option<HeldOutSummaryDto> {
    let distinct: BTreeSet<u32> = positions.iter().copied().collect();
    if distinct.len() < 2 {
        return None;
    }
    let mut folds = Vec::new();
    let (mut sum_nf, mut sum_jl, mut sum_pl) = (0.0, 0.0, 0.0);
    let (mut total, mut used, mut refused) = (0usize, 0usize, 0usize);
    for (f, &p) in distinct.iter().enumerate() {
        progress(f, distinct.len());
        let opts = TrainOptions {
            held_out: positions
                .iter()
                .enumerate()
                .filter(|(_, q)| **q == p)
                .map(|(i, _)| i)
                .collect(),
            ..options.clone()
        };
        match train(demos, limits, &opts) {
            Ok((_, r)) => {
                let h = r.held_out.expect("a fold holds demonstrations out");
                let n = h.demonstrations - h.refused;
                total += h.demonstrations;
                refused += h.refused;
                used += n;
                sum_nf += h.nf * n as f64;
                sum_jl += h.joint_line * n as f64;
                sum_pl += h.pca_line * n as f64;
                folds.push(FoldDto {
                    position_index: p,
                    result: Some(held_out_dto(&h)),
                    held_out_alignment: r.manifolds.iter().map(|m| m.held_out_alignment).collect(),
                    error: None,
                });
            }
            Err(e) => folds.push(FoldDto {
                position_index: p,
                result: None,
                held_out_alignment: Vec::new(),
                error: Some(e.to_string()),
            }),
        }
    }
    let overall = (used > 0).then(|| {
        let u = used as f64;
        HeldOutDto {
            demonstrations: total,
            refused,
            nf: sum_nf / u,
            joint_line: sum_jl / u,
            pca_line: sum_pl / u,
            ratio_to_joint_line: sum_nf / sum_jl.max(f64::MIN_POSITIVE),
        }
    });
    Some(HeldOutSummaryDto { folds, overall })
}

fn train_error(e: MotionError) -> JobError {
    JobError::failed(format!("training failed: {e}"))
}

// ---------------------------------------------------------------------------------------------
// Handlers: models

/// Train a motion model (PCA + navigation function per joint group) from stored mappings, as a
/// job (202). The model is listed at once with the job's status; the job's result points at it.
#[utoipa::path(post, path = "/v1/models", tag = "models", request_body = CreateModel,
    responses((status = 202, body = JobRecord, description = "Training job; `Content-Location` is the model"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_model(
    State(state): State<AppState>,
    Json(body): Json<CreateModel>,
) -> Result<Response, ApiError> {
    let system = super::robots::robot_field(&state, &body.robot, "$.robot").await?;
    let v = validate_training(&body, &system)?;
    if body.mappings.is_empty() {
        return Err(ApiError::invalid_field(
            "$.mappings",
            "give at least one mapping id",
        ));
    }
    let names = system.model.joint_names().to_vec();
    let mut demos = Vec::new();
    let mut positions = Vec::new();
    let mut seen = BTreeSet::new();
    for (i, id) in body.mappings.iter().enumerate() {
        let path = format!("$.mappings[{i}]");
        if !seen.insert(id.clone()) {
            return Err(ApiError::invalid_field(path, "mapping listed twice"));
        }
        let row = mapping_repo::get_mapping(&state.db, id)
            .await?
            .ok_or_else(|| ApiError::invalid_field(&path, format!("unknown mapping '{id}'")))?;
        if row.robot != body.robot {
            return Err(ApiError::invalid_field(
                path,
                format!(
                    "mapping '{id}' is of robot '{}', not '{}'",
                    row.robot, body.robot
                ),
            ));
        }
        if row.status != "succeeded" {
            return Err(ApiError::invalid_field(
                path,
                format!(
                    "mapping '{id}' has status {} (job {}); only succeeded mappings can be trained on",
                    row.status, row.job_id
                ),
            ));
        }
        for d in mapping_repo::load_trajectories(&state.db, id).await? {
            if d.trajectory.joint_names != names {
                return Err(ApiError::invalid_field(
                    path,
                    format!(
                        "demonstration '{}' of mapping '{id}' has joints {:?}, the robot has {:?}",
                        d.demonstration_id, d.trajectory.joint_names, names
                    ),
                ));
            }
            demos.push(JointTrajectory::from(&d.trajectory));
            positions.push(d.position_index);
        }
    }
    let needed = demonstrations_needed(v.options.components);
    if demos.len() < needed {
        return Err(ApiError::invalid_field(
            "$.mappings",
            format!(
                "too few demonstrations: {} in the mappings, at least {needed} needed for the requested components",
                demos.len()
            ),
        ));
    }
    let limits = system_limits(&system, v.acceleration);
    let request = serde_json::to_string(&body).map_err(ApiError::internal)?;
    let model_id = uuid::Uuid::new_v4().to_string();
    let mut new_model = repo::NewModel {
        id: model_id.clone(),
        job_id: String::new(),
        robot: body.robot.clone(),
        request,
        joint_names: names,
        control_rate: v.gains.rate,
        k_perp: v.gains.k_perp,
        make_default: body.default,
    };
    let job_model = new_model.clone();
    let job = state
        .jobs
        .submit("model", move |ctx| {
            let steps = if v.held_out { 6.0 } else { 1.0 };
            ctx.progress(0.0, "training the model");
            let (model, report) = train(&demos, &limits, &v.options).map_err(train_error)?;
            ctx.check_cancelled()?;
            let held = if v.held_out {
                held_out_folds(&demos, &positions, &limits, &v.options, |f, n| {
                    ctx.progress(
                        (1.0 + 5.0 * f as f64 / n as f64) / steps,
                        format!("held-out fold {} of {n}", f + 1),
                    );
                })
            } else {
                None
            };
            ctx.check_cancelled()?;
            let dto = model_report(&system, &model, &report, v.acceleration, held);
            let report = serde_json::to_string(&dto).map_err(JobError::failed)?;
            Ok(JobOutput::persist_with(move |job_id, tx| {
                Box::pin(async move {
                    let m = repo::NewModel {
                        job_id: job_id.to_string(),
                        ..job_model
                    };
                    repo::store_trained(tx, &m, &model, &report).await?;
                    Ok(ResultRef::new("models", &m.id))
                })
            }))
        })
        .await?;
    new_model.job_id = job.id.to_string();
    if let Err(e) = repo::insert_pending(&state.db, &new_model).await {
        // Without its row the model could not be found; stop the job rather than orphan it.
        let _ = state.jobs.cancel(job.id).await;
        return Err(e.into());
    }
    Ok(super::accepted_job(
        job,
        Some(format!("/v1/models/{model_id}")),
    ))
}

/// List models, newest first (pending and failed ones included, with their job's status).
#[utoipa::path(get, path = "/v1/models", tag = "models", params(ModelQuery),
    responses((status = 200, description = "OK", body = ModelList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_models(
    State(state): State<AppState>,
    Query(q): Query<ModelQuery>,
) -> Result<Json<ModelList>, ApiError> {
    let limit = super::extract::page_limit(q.limit)?;
    let offset = q.offset.unwrap_or(0);
    let (rows, total) = repo::list_models(&state.db, q.robot.as_deref(), limit, offset).await?;
    let mut items = Vec::with_capacity(rows.len());
    for row in rows {
        let names = repo::joint_names(&state.db, &row.id)
            .await?
            .unwrap_or_default();
        let default = repo::is_marked_default(&state.db, &row.id).await?;
        items.push(model_dto(row, names, default)?);
    }
    Ok(Json(ModelList {
        items,
        total,
        limit,
        offset,
    }))
}

/// One model: status, explained variance, training and held-out fit, certificates, goal regions.
#[utoipa::path(get, path = "/v1/models/{id}", tag = "models",
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, description = "OK", body = ModelDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_model(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ModelDto>, ApiError> {
    let row = repo::get_model(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("model", &id))?;
    let names = repo::joint_names(&state.db, &id).await?.unwrap_or_default();
    let default = repo::is_marked_default(&state.db, &id).await?;
    Ok(Json(model_dto(row, names, default)?))
}

/// The closed-loop law's parameters in the compact form a bridge worker runs locally (joint
/// names, `K_⊥`, per group: joint indices, PCA mean and basis, navigation function, `K_p`).
#[utoipa::path(get, path = "/v1/models/{id}/params", tag = "models",
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, body = Object, description = "`motion::ControlParams` as JSON"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, body = Problem, content_type = "application/problem+json", description = "Not trained (yet)")))]
async fn get_params(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ControlParams>, ApiError> {
    let l = loaded_model(&state, &id, None).await?;
    Ok(Json(l.params.clone()))
}

/// Evaluate the closed-loop law `u(q)` for a measured state and a goal.
#[utoipa::path(post, path = "/v1/models/{id}/control", tag = "models", request_body = ControlRequest,
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, description = "OK", body = ControlResponse),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn control(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<ControlRequest>,
) -> Result<Json<ControlResponse>, ApiError> {
    let l = loaded_model(&state, &id, None).await?;
    let system = super::robots::system(&state, &l.robot).await?;
    let q = joint_values(&system, &body.q, "$.q")?;
    let goal = joint_values(&system, &body.goal, "$.goal")?;
    check_limits(
        &l.model,
        &l.names,
        &goal,
        Some(&body.goal.joint_names),
        "$.goal",
    )?;
    l.model
        .check_regions(&goal, &goal)
        .map_err(|e| region_error(e, l.model.manifolds.len(), "$.goal", "$.goal"))?;
    let mut u = vec![0.0; q.len()];
    l.params.control(&q, &goal, &mut u);
    Ok(Json(ControlResponse {
        joint_names: l.names.clone(),
        u,
    }))
}

// ---------------------------------------------------------------------------------------------
// Handlers: trajectories

/// FK along the points: fingertip and elbow paths (robot base frame).
fn cartesian_paths(
    system: &System,
    points: &[TrajectoryPoint],
) -> (Vec<FramePathDto>, Vec<FramePathDto>) {
    let model = &system.model;
    let mut data = Data::new(model);
    let mut tips: Vec<FramePathDto> = system
        .fingers
        .iter()
        .map(|f| FramePathDto {
            name: f.name.clone(),
            frame: model.frame_name(f.tip).to_owned(),
            positions: Vec::with_capacity(points.len()),
        })
        .collect();
    let mut elbows: Vec<FramePathDto> = system
        .elbow_frames
        .iter()
        .map(|&f| FramePathDto {
            name: model.frame_name(f).to_owned(),
            frame: model.frame_name(f).to_owned(),
            positions: Vec::with_capacity(points.len()),
        })
        .collect();
    for p in points {
        forward_kinematics(model, &mut data, &p.positions);
        for (path, f) in tips.iter_mut().zip(&system.fingers) {
            path.positions
                .push(data.frame(f.tip).translation.vector.into());
        }
        for (path, &f) in elbows.iter_mut().zip(&system.elbow_frames) {
            path.positions.push(data.frame(f).translation.vector.into());
        }
    }
    (tips, elbows)
}

fn trajectory_report(
    system: &System,
    model: &MotionModel,
    t: &Trajectory,
    requested: Option<f64>,
    rate: f64,
    grasp: Option<String>,
) -> TrajectoryReportDto {
    let ng = model.manifolds.len();
    let (fingertip_paths, elbow_paths) = cartesian_paths(system, &t.points);
    let note = t.stretched.then(|| match requested {
        Some(r) => format!(
            "the requested duration {r} s is too short for the joint velocity/acceleration limits; the shortest feasible duration {:.4} s was used",
            t.duration
        ),
        None => format!(
            "the learned duration {:.4} s was lengthened to {:.4} s to respect the joint velocity/acceleration limits",
            t.learned_duration, t.duration
        ),
    });
    TrajectoryReportDto {
        duration: t.duration,
        requested_duration: requested,
        learned_duration: t.learned_duration,
        stretched: t.stretched,
        note,
        rate,
        converged: t.converged,
        final_error: t.final_errors.iter().copied().fold(0.0, f64::max),
        errors: t
            .final_errors
            .iter()
            .zip(&t.flow_steps)
            .enumerate()
            .map(|(g, (&error, &flow_steps))| GroupErrorDto {
                group: group_name(ng, g),
                error,
                flow_steps,
            })
            .collect(),
        certificates: t
            .certificates
            .iter()
            .enumerate()
            .map(|(g, c)| certificate_dto(group_name(ng, g), c))
            .collect(),
        max_velocity_ratio: t.max_velocity_ratio,
        max_acceleration_ratio: t.max_acceleration_ratio,
        fingertip_paths,
        elbow_paths,
        grasp,
    }
}

pub(crate) fn trajectory_dto(t: trajectories::StoredTrajectory) -> Result<TrajectoryDto, ApiError> {
    Ok(TrajectoryDto {
        report: serde_json::from_str(&t.summary).map_err(ApiError::internal)?,
        id: t.id,
        model_id: t.model_id,
        robot: t.robot,
        joint_names: t.joint_names,
        start: t.start,
        goal: t.goal,
        points: t
            .points
            .into_iter()
            .map(|p| PointDto {
                t: p.t,
                positions: p.positions,
                velocities: p.velocities,
                accelerations: p.accelerations,
            })
            .collect(),
        created_at: t.created_at,
    })
}

/// The goal configuration (model order) and the grasp it came from.
async fn resolve_goal(
    state: &AppState,
    system: &System,
    robot: &str,
    goal: &GoalIn,
) -> Result<(Vec<f64>, Option<Vec<String>>, Option<String>), ApiError> {
    match (&goal.grasp, &goal.joint_names, &goal.positions) {
        (Some(id), None, None) => {
            let row = grasp_repo::get_grasp(&state.db, id).await?.ok_or_else(|| {
                ApiError::invalid_field("$.goal.grasp", format!("unknown grasp '{id}'"))
            })?;
            if row.robot != robot {
                return Err(ApiError::invalid_field(
                    "$.goal.grasp",
                    format!(
                        "grasp '{id}' was computed for robot '{}', the model is of '{robot}'",
                        row.robot
                    ),
                ));
            }
            let result: GraspResult =
                serde_json::from_str(&row.result).map_err(ApiError::internal)?;
            if !result.feasible {
                return Err(ApiError::invalid_field(
                    "$.goal.grasp",
                    format!(
                        "grasp '{id}' is infeasible ({}); it is no goal to move to",
                        result.reason.as_deref().unwrap_or("no reason given")
                    ),
                ));
            }
            let (names, values): (Vec<String>, Vec<f64>) = result
                .q_arm
                .iter()
                .chain(&result.q_hand)
                .map(|j| (j.name.clone(), j.value))
                .unzip();
            let q = joint_values(
                system,
                &JointValues {
                    joint_names: names,
                    positions: values,
                },
                "$.goal.grasp",
            )?;
            Ok((q, None, Some(id.clone())))
        }
        (None, Some(names), Some(positions)) => {
            let v = JointValues {
                joint_names: names.clone(),
                positions: positions.clone(),
            };
            Ok((
                joint_values(system, &v, "$.goal")?,
                Some(names.clone()),
                None,
            ))
        }
        _ => Err(ApiError::invalid_field(
            "$.goal",
            "give either joint_names and positions, or grasp (a grasp id)",
        )),
    }
}

/// Generate a humanlike trajectory from `start` to `goal` with a model and store it (201): flow
/// integration per manifold, back-projection keeping the exact start and goal, minimum-jerk
/// timing over the learned (or requested) duration, stretched where a joint limit would be
/// exceeded; fingertip and elbow paths by forward kinematics.
#[utoipa::path(post, path = "/v1/trajectories", tag = "trajectories", request_body = CreateTrajectory,
    responses((status = 201, description = "Created", body = TrajectoryDto),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_trajectory(
    State(state): State<AppState>,
    Json(body): Json<CreateTrajectory>,
) -> Result<Response, ApiError> {
    let dto = generate_trajectory(&state, &body).await?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/trajectories/{}", dto.id),
        dto,
    ))
}

/// Checks that `model` is trained and that `start` is a valid configuration for it (names,
/// finite values, joint limits) before a caller does expensive work; returns the model's robot.
pub(crate) async fn check_start(
    state: &AppState,
    model: &str,
    start: &JointValues,
) -> Result<String, ApiError> {
    let l = loaded_model(state, model, Some("$.model")).await?;
    let system = super::robots::system(state, &l.robot).await?;
    let q = joint_values(&system, start, "$.start")?;
    check_limits(&l.model, &l.names, &q, Some(&start.joint_names), "$.start")?;
    Ok(l.robot.clone())
}

/// A trained model's certified goal region of one joint group, joints by name: where a plan's
/// grasp must end for the model to take the arm there with its convergence guarantee.
pub(crate) struct NamedGoalRegion {
    pub group: String,
    pub joints: Vec<String>,
    pub mean: Vec<f64>,
    pub components: Vec<f64>,
    pub center: Vec<f64>,
    pub radius: f64,
}

/// The goal regions of a trained model, one per joint group.
pub(crate) async fn goal_regions(
    state: &AppState,
    model: &str,
) -> Result<Vec<NamedGoalRegion>, ApiError> {
    let l = loaded_model(state, model, Some("$.model")).await?;
    let groups = l.model.manifolds.len();
    Ok(l.model
        .manifolds
        .iter()
        .enumerate()
        .map(|(gi, m)| NamedGoalRegion {
            group: group_name(groups, gi),
            joints: m.joints.iter().map(|&j| l.names[j].clone()).collect(),
            mean: m.pca.mean.clone(),
            components: m.pca.components.clone(),
            center: m.certificate.goal_center[..m.pca.d()].to_vec(),
            radius: m.certificate.goal_radius,
        })
        .collect())
}

/// Why no trajectory was computed.
#[derive(Debug)]
pub(crate) enum Rejected {
    /// The goal is none the model can reach with its convergence guarantee (outside its joint
    /// limits or its certified goal region, or no goal of this model): a plan whose grasp this
    /// is becomes infeasible, the request is not bad.
    Goal(ApiError),
    /// Anything else.
    Other(ApiError),
}

impl From<ApiError> for Rejected {
    fn from(e: ApiError) -> Self {
        Rejected::Other(e)
    }
}

impl From<Rejected> for ApiError {
    fn from(r: Rejected) -> Self {
        match r {
            Rejected::Goal(e) | Rejected::Other(e) => e,
        }
    }
}

/// Generates and stores one trajectory (the work of `POST /v1/trajectories`).
async fn generate_trajectory(
    state: &AppState,
    body: &CreateTrajectory,
) -> Result<TrajectoryDto, ApiError> {
    let draft = compute_trajectory(state, body).await?;
    trajectory_dto(trajectories::insert_trajectory(&state.db, &draft.as_new()).await?)
}

/// Generates one trajectory, not yet stored (shared with `/v1/plans`, which stores it with its
/// grasp).
pub(crate) async fn compute_trajectory(
    state: &AppState,
    body: &CreateTrajectory,
) -> Result<TrajectoryDraft, Rejected> {
    let requested = match &body.duration {
        None => None,
        Some(AutoOr::Auto(s)) if s == "auto" => None,
        Some(AutoOr::Value(t)) if *t > 0.0 && *t <= MAX_DURATION => Some(*t),
        Some(other) => {
            return Err(ApiError::invalid_field(
                "$.duration",
                format!("must be \"auto\" or seconds in (0, {MAX_DURATION}], got {other:?}"),
            )
            .into());
        }
    };
    let rate = body.rate.unwrap_or(100.0);
    if !(rate > 0.0 && rate <= MAX_RATE) {
        return Err(ApiError::invalid_field(
            "$.rate",
            format!("must be in (0, {MAX_RATE}] Hz, got {rate}"),
        )
        .into());
    }
    let l = loaded_model(state, &body.model, Some("$.model")).await?;
    let system = match state.robots.system(&l.robot).await {
        Err(LibraryError::UnknownRobot(_)) => {
            return Err(ApiError::conflict(format!(
                "the model's robot '{}' no longer exists",
                l.robot
            ))
            .into());
        }
        other => other.map_err(ApiError::from)?,
    };
    let start = joint_values(&system, &body.start, "$.start")?;
    let (goal, goal_names, grasp) = resolve_goal(state, &system, &l.robot, &body.goal)
        .await
        .map_err(Rejected::Goal)?;
    check_limits(
        &l.model,
        &l.names,
        &start,
        Some(&body.start.joint_names),
        "$.start",
    )?;
    let goal_base = if grasp.is_some() {
        "$.goal.grasp"
    } else {
        "$.goal"
    };
    check_limits(&l.model, &l.names, &goal, goal_names.as_deref(), goal_base)
        .map_err(Rejected::Goal)?;
    let opts = TrajectoryOptions {
        duration: requested,
        rate,
        ..TrajectoryOptions::default()
    };
    let (traj, report) = {
        let (l, system, start, goal, grasp) = (
            l.clone(),
            system.clone(),
            start.clone(),
            goal.clone(),
            grasp.clone(),
        );
        tokio::task::spawn_blocking(move || {
            let traj = l.model.trajectory(&start, &goal, &opts).map_err(|e| {
                let outside = matches!(e, MotionError::GoalOutsideRegion { .. });
                let e = region_error(e, l.model.manifolds.len(), "$.start", goal_base);
                if outside {
                    Rejected::Goal(e)
                } else {
                    Rejected::Other(e)
                }
            })?;
            let report = trajectory_report(&system, &l.model, &traj, requested, rate, grasp);
            Ok::<_, Rejected>((traj, report))
        })
        .await
        .map_err(ApiError::internal)??
    };
    let request = serde_json::to_string(&body).map_err(ApiError::internal)?;
    let summary = serde_json::to_string(&report).map_err(ApiError::internal)?;
    Ok(TrajectoryDraft {
        model_id: Some(body.model.clone()),
        robot: l.robot.clone(),
        joint_names: l.names.clone(),
        points: traj.points,
        start,
        goal,
        duration: traj.duration,
        request,
        summary,
    })
}

/// One stored trajectory with its points and report.
#[utoipa::path(get, path = "/v1/trajectories/{id}", tag = "trajectories",
    params(("id" = String, Path, description = "Trajectory id")),
    responses((status = 200, description = "OK", body = TrajectoryDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_trajectory(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<TrajectoryDto>, ApiError> {
    let t = trajectories::get_trajectory(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("trajectory", &id))?;
    Ok(Json(trajectory_dto(t)?))
}

/// List stored trajectories, newest first (without points).
#[utoipa::path(get, path = "/v1/trajectories", tag = "trajectories", params(TrajectoryQuery),
    responses((status = 200, description = "OK", body = TrajectoryList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_trajectories(
    State(state): State<AppState>,
    Query(q): Query<TrajectoryQuery>,
) -> Result<Json<TrajectoryList>, ApiError> {
    let limit = super::extract::page_limit(q.limit)?;
    let offset = q.offset.unwrap_or(0);
    let (rows, total) =
        trajectories::list_trajectories(&state.db, q.model.as_deref(), limit, offset).await?;
    let mut items = Vec::with_capacity(rows.len());
    for r in rows {
        let s: TrajectoryReportDto =
            serde_json::from_str(&r.summary).map_err(ApiError::internal)?;
        items.push(TrajectorySummaryDto {
            id: r.id,
            model_id: r.model_id,
            robot: r.robot,
            duration: r.duration,
            converged: s.converged,
            stretched: s.stretched,
            created_at: r.created_at,
        });
    }
    Ok(Json(TrajectoryList {
        items,
        total,
        limit,
        offset,
    }))
}
