//! Motion models: PCA + navigation-function models learned from stored mappings (paper eq.
//! 8-9; training is a job), loaded once and cached, and their closed-loop law.
//!
//! Joint vectors travel as `{joint_names, positions}` (any order, every independent joint of the
//! robot once); answers use the model's joint order. A start or goal the model cannot certify
//! (outside the workspace or the goal region) is refused: no plan is made without the
//! convergence guarantee.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex, OnceLock};

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{Context, Error, Invalid, Keyword};
use crate::jobs::{JobError, JobOutput, JobRecord, ResultRef};
use crate::kinematics::{JointVector, KinematicsError, System};
use crate::motion::mapped::{
    DEFAULT_ACCELERATION_LIMIT, DEFAULT_JERK_LIMIT, system_groups, system_limits,
};
use crate::motion::{
    Certificate, CertificateKind, Components, ControlParams, CriticalPointCertificate,
    DEFAULT_PROFILE_RIDGE, HeldOutReport, JointTrajectory, KChoice, MotionError, MotionModel,
    TrainOptions, TrainReport, train,
};
use crate::store::{mappings as mapping_repo, models as repo};

/// Largest spline resolution (knot intervals per PCA axis) a request may ask for.
pub use crate::motion::MAX_SPLINE_INTERVALS;
/// Highest output rate of a trajectory (Hz).
pub const MAX_RATE: f64 = 1000.0;
/// Longest trajectory a request may ask for (s).
pub const MAX_DURATION: f64 = 60.0;

/// `"auto"` or a number.
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(untagged)]
pub enum AutoOr {
    Value(f64),
    Auto(String),
}

/// By hand rather than untagged, so that a wrong value says what is expected (`expected
/// "auto" or a number`) instead of "did not match any variant of untagged enum AutoOr".
impl<'de> Deserialize<'de> for AutoOr {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit;
        impl serde::de::Visitor<'_> for Visit {
            type Value = AutoOr;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("\"auto\" or a number")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<AutoOr, E> {
                Ok(AutoOr::Value(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<AutoOr, E> {
                Ok(AutoOr::Value(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<AutoOr, E> {
                Ok(AutoOr::Value(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<AutoOr, E> {
                Ok(AutoOr::Auto(v.to_owned()))
            }
        }
        d.deserialize_any(Visit)
    }
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
    #[schema(min_length = 1)]
    pub robot: String,
    /// Ids of succeeded mappings whose demonstrations are the training data (at least one).
    #[schema(min_items = 1)]
    pub mappings: Vec<String>,
    /// Fixed number of principal components per joint group (arm, hand), 1 to 5 and at most
    /// the robot's smallest joint group; give this or `variance_threshold`.
    #[schema(minimum = 1, maximum = 5)]
    pub components: Option<usize>,
    /// Keep the fewest components explaining this fraction of the variance, in (0, 1]
    /// (default 0.88).
    #[schema(exclusive_minimum = 0, maximum = 1)]
    pub variance_threshold: Option<f64>,
    /// Spline resolution: knot intervals per PCA axis of the learned field, 1 to 12 (default 6,
    /// lowered for a manifold with so many components that the spline would exceed its
    /// coefficient budget; an explicit value is never lowered).
    #[schema(minimum = 1, maximum = 12)]
    pub spline_intervals: Option<usize>,
    /// Weight of the spline fit's smoothness + ridge penalty, positive (default 3).
    #[schema(exclusive_minimum = 0)]
    pub regularisation: Option<f64>,
    /// `k` of eq. 9: `"auto"` (the smallest certified value, default) or a number ≥ 1 (the
    /// learned field is shrunk until the certificate holds).
    pub k: Option<AutoOr>,
    /// Evaluate humanlikeness on held-out object positions (train on the others, one fold per
    /// position; default true).
    pub held_out: Option<bool>,
    /// Learn the goal-conditioned residual profile that shapes each path between its exact start
    /// and goal like the demonstrations (default true). The NF flow approaches its goal
    /// and its field does not depend on the goal, so on its own it cannot follow a hand that opens
    /// before it closes or a reach whose shape changes with the object's position; the profile
    /// carries that part. Flow, certificate and closed-loop law are the same either way.
    pub residual_profile: Option<bool>,
    /// Ridge of the residual profile's fit (default 0.1, per demonstration and rad² of
    /// start-goal difference); must be positive.
    #[schema(exclusive_minimum = 0)]
    pub profile_ridge: Option<f64>,
    /// Which certificate decides how much of the learned field is kept (default
    /// `gamma_decreasing`: `γ` strictly decreasing; `no_critical_point` keeps more of the field,
    /// lets `γ` rise on the way and takes 4-9 times longer to train).
    pub certificate: Option<CertificateKind>,
    /// Joint acceleration limit, rad/s², positive (default 5; URDF has none).
    #[schema(exclusive_minimum = 0)]
    pub acceleration_limit: Option<f64>,
    /// Joint jerk limit, rad/s³, positive (default 150; URDF has none). Trajectories keep it:
    /// the humanlike clock where it can, else the jerk-bounded time-optimal time law.
    #[schema(exclusive_minimum = 0)]
    pub jerk_limit: Option<f64>,
    pub control: Option<ControlGains>,
    /// Make this the robot's default model once trained (default false).
    #[serde(default)]
    pub default: bool,
}

/// A convergence certificate (DESIGN §5) for every goal in the goal region and start in the
/// workspace ball: `gamma_decreasing` (`bound < 2k`: `γ` strictly decreases along the flow) or
/// `no_critical_point` (navigation-function theory: `φ` has no critical point but the goal,
/// proved by branch and bound; `γ` may rise on the way), whichever `kind` says.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct CertificateDto {
    /// `arm` or `hand`.
    pub group: String,
    /// The theorem the field's shrink was chosen for; `holds` refers to it. (Reports stored
    /// before the choice existed read as `gamma_decreasing`, which they were.)
    #[serde(default)]
    pub kind: CertificateKind,
    pub k: f64,
    pub spline_bound: f64,
    pub workspace_bound: f64,
    /// `spline_bound + workspace_bound`, the closed-form bound of `sup (y − y_d)·∇log β`.
    pub bound: f64,
    pub holds: bool,
    /// `bound < 2k`: `γ` strictly decreases along the flow.
    #[serde(default = "stored_before_kinds")]
    pub gamma_decreasing: bool,
    /// With `gamma_decreasing`: `γ̇ ≤ −decay_rate·γ` (per unit flow time); no guaranteed decay
    /// when it is not positive.
    pub decay_rate: f64,
    /// The branch and bound proving that `φ` has no critical point but the goal; absent for
    /// models trained before it existed.
    #[serde(default)]
    pub critical_points: Option<CriticalPointCertificate>,
    /// Factor the fitted field was multiplied by to satisfy the certificate (1 = unshrunk).
    pub shrink: f64,
    /// Workspace ball in PCA coordinates (starts must lie strictly inside).
    pub workspace_center: Vec<f64>,
    pub workspace_radius: f64,
}

/// Every certificate stored before `kind` existed was a `γ`-decreasing one that held (training
/// refused any other).
fn stored_before_kinds() -> bool {
    true
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
/// held-out mapped trajectory, for the NF model, the straight joint line and two learned baselines
/// trained on the same demonstrations: a DMP (Pastor's goal-change form, one forcing term per
/// joint) and a ProMP conditioned on the start and the goal.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct HeldOutDto {
    pub demonstrations: usize,
    /// Held-out demonstrations outside the fold model's goal region or workspace (refused).
    pub refused: usize,
    pub nf: f64,
    pub joint_line: f64,
    /// Absent in models trained before the baselines were reported.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dmp: Option<f64>,
    /// Absent in models trained before the baselines were reported.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub promp: Option<f64>,
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

fn default_jerk_limit() -> f64 {
    DEFAULT_JERK_LIMIT
}

/// What training produced (stored with the model).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelReportDto {
    pub training_demonstrations: usize,
    pub manifolds: Vec<ManifoldDto>,
    pub duration: DurationDto,
    /// Joint limits used (model order): acceleration limit, rad/s².
    pub acceleration_limit: f64,
    /// Jerk limit, rad/s³ (models trained before it was configurable use the default).
    #[serde(default = "default_jerk_limit")]
    pub jerk_limit: f64,
    pub held_out: Option<HeldOutSummaryDto>,
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

pub fn group_name(system_groups: usize, g: usize) -> String {
    match (system_groups, g) {
        (2, 0) => "arm".into(),
        (2, 1) => "hand".into(),
        (_, g) => format!("group{g}"),
    }
}

pub fn certificate_dto(group: String, c: &Certificate) -> CertificateDto {
    CertificateDto {
        group,
        kind: c.kind,
        k: c.k,
        spline_bound: c.spline_bound,
        workspace_bound: c.workspace_bound,
        bound: c.bound,
        holds: c.holds,
        gamma_decreasing: c.gamma_decreasing,
        decay_rate: c.decay_rate,
        critical_points: c.critical_points.clone(),
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
        dmp: h.dmp,
        promp: h.promp,
        ratio_to_joint_line: h.ratio_to_joint_line,
    }
}

/// A joint vector in model order, with errors pointing into the request (`base` is e.g.
/// `$.start`).
pub fn joint_values(system: &System, v: &JointValues, base: &str) -> Result<Vec<f64>, Error> {
    let model = &system.model;
    if v.joint_names.len() != v.positions.len() {
        return Err(Error::invalid(
            format!("{base}.positions"),
            format!(
                "{} positions for {} joint names",
                v.positions.len(),
                v.joint_names.len()
            ),
        ));
    }
    if let Some(i) = v.positions.iter().position(|x| !x.is_finite()) {
        return Err(Error::invalid(
            format!("{base}.positions[{i}]"),
            format!("joint '{}' must be a finite number", v.joint_names[i]),
        ));
    }
    let q = JointVector::from_named(model, &v.joint_names, &v.positions).map_err(|e| {
        let path = match &e {
            KinematicsError::UnknownJoint { name, .. }
            | KinematicsError::RepeatedJoint { name } => {
                let i = v
                    .joint_names
                    .iter()
                    .rposition(|n| n == name)
                    .unwrap_or_default();
                format!("{base}.joint_names[{i}]")
            }
            _ => format!("{base}.joint_names"),
        };
        Error::invalid(path, e.to_string())
    })?;
    Ok(q.as_slice().to_vec())
}

/// Checks `q` (model order) against the position limits; errors name the request index.
pub fn check_limits(
    model: &MotionModel,
    names: &[String],
    q: &[f64],
    request_names: Option<&[String]>,
    base: &str,
) -> Result<(), Error> {
    let mut errors = Vec::new();
    for (j, &v) in q.iter().enumerate() {
        let (lo, hi) = (model.limits.lower[j], model.limits.upper[j]);
        let tol = 1e-9 * (1.0 + v.abs());
        if v < lo - tol || v > hi + tol {
            let path = match request_names.and_then(|r| r.iter().position(|n| *n == names[j])) {
                Some(i) => format!("{base}.positions[{i}]"),
                None => base.to_owned(),
            };
            errors.push(Invalid::new(
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
        Err(Error::Invalid(errors))
    }
}

pub fn region_error(e: MotionError, groups: usize, start: &str, goal: &str) -> Error {
    match e {
        MotionError::GoalOutsideRegion {
            group,
            distance,
            radius,
        } => Error::invalid(
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
        } => Error::invalid(
            start,
            format!(
                "the start is outside the model's workspace ({} joints: {distance:.4} from its centre, radius {radius:.4}), where the closed-loop law is certified; an open-loop motion enters it along the straight joint line first",
                group_name(groups, group)
            ),
        ),
        MotionError::InvalidOption { field, .. } => {
            Error::invalid(format!("$.{field}"), e.to_string())
        }
        other => Error::invalid("$", other.to_string()),
    }
}

/// A trained model with its joint order and closed-loop parameters. Trained models never
/// change, so they are cached by id (bounded) instead of parsed on every control call.
#[derive(Debug)]
pub struct Loaded {
    pub robot: String,
    pub names: Vec<String>,
    pub model: MotionModel,
    pub params: ControlParams,
}

fn model_cache() -> &'static Mutex<HashMap<String, Arc<Loaded>>> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<Loaded>>>> = OnceLock::new();
    CACHE.get_or_init(Default::default)
}

/// A trained model's certified goal region of one joint group, joints by name: where a plan's
/// grasp must end for the model to take the arm there with its convergence guarantee.
pub struct NamedGoalRegion {
    pub group: String,
    pub joints: Vec<String>,
    pub mean: Vec<f64>,
    pub components: Vec<f64>,
    pub center: Vec<f64>,
    pub radius: f64,
}

/// The goal regions of trained model `id`, one per joint group.
pub async fn goal_regions(ctx: &Context, id: &str) -> Result<Vec<NamedGoalRegion>, Error> {
    let l = loaded_model(ctx, id, Some("$.model")).await?;
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

/// The trained model `id`: 404 if unknown, 409 while it is not trained (`field`: where the id
/// came from in a body, `None` for a path parameter).
pub async fn loaded_model(
    ctx: &Context,
    id: &str,
    field: Option<&str>,
) -> Result<Arc<Loaded>, Error> {
    if let Some(l) = model_cache().lock().expect("model cache").get(id) {
        return Ok(l.clone());
    }
    let unknown = || match field {
        Some(f) => Error::invalid(f, format!("unknown model '{id}'")),
        None => Error::not_found("model", id),
    };
    let row = repo::get_model(&ctx.db, id).await?.ok_or_else(unknown)?;
    let model = repo::load_model(&ctx.db, id).await?;
    let params = repo::load_params(&ctx.db, id).await?;
    let (Some(model), Some(params)) = (model, params) else {
        let msg = format!(
            "model '{id}' is not trained (status {}); watch job {}",
            row.status, row.job_id
        );
        return Err(match field {
            Some(f) => Error::invalid(f, msg),
            None => Error::Conflict(msg),
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

struct Validated {
    options: TrainOptions,
    acceleration: f64,
    jerk: f64,
    gains: ControlGains,
    held_out: bool,
}

/// The request's training options as [`TrainOptions`], checked once by
/// [`TrainOptions::check`] (each problem at the request field of the same name); the request's
/// own rules (one of `components` and `variance_threshold`, the keyword of `k`, a ridge only
/// with a profile) and the service's options (acceleration limit, gains) are checked here.
fn validate_training(body: &CreateModel, system: &System) -> Result<Validated, Error> {
    let mut errors = Vec::new();
    let groups = system_groups(system);
    let n = groups.iter().map(Vec::len).sum();
    let components = match (body.components, body.variance_threshold) {
        (Some(_), Some(_)) => {
            errors.push(Invalid::new(
                "$.components",
                "give components or variance_threshold, not both",
            ));
            Components::default()
        }
        (Some(c), None) => Components::Count(c),
        (None, Some(t)) => Components::VarianceThreshold(t),
        (None, None) => Components::default(),
    };
    let k = match &body.k {
        None => KChoice::Auto,
        Some(AutoOr::Value(k)) => KChoice::Value(*k),
        Some(AutoOr::Auto(s)) => match Keyword::parse(s) {
            Some(Keyword::Auto) => KChoice::Auto,
            _ => {
                errors.push(Invalid::new(
                    "$.k",
                    format!("must be \"auto\" or a number ≥ 1, got \"{s}\""),
                ));
                KChoice::Auto
            }
        },
    };
    let profile_ridge = body.profile_ridge.unwrap_or(DEFAULT_PROFILE_RIDGE);
    let options = TrainOptions {
        groups,
        components,
        spline_intervals: body.spline_intervals.unwrap_or(6),
        // the default resolution is lowered where many components would exceed the
        // coefficient budget; an explicit one is honoured or refused
        cap_spline_intervals: body.spline_intervals.is_none(),
        regularisation: body.regularisation.unwrap_or(3.0),
        k,
        profile_ridge: body
            .residual_profile
            .unwrap_or(true)
            .then_some(profile_ridge),
        certificate: body.certificate.unwrap_or_default(),
        ..TrainOptions::default()
    };
    errors.extend(options.check(n).into_iter().map(option_error));
    let acceleration = body
        .acceleration_limit
        .unwrap_or(DEFAULT_ACCELERATION_LIMIT);
    if !(acceleration > 0.0 && acceleration.is_finite()) {
        errors.push(Invalid::new(
            "$.acceleration_limit",
            format!("must be a positive number, got {acceleration}"),
        ));
    }
    let jerk = body.jerk_limit.unwrap_or(DEFAULT_JERK_LIMIT);
    if !(jerk > 0.0 && jerk.is_finite()) {
        errors.push(Invalid::new(
            "$.jerk_limit",
            format!("must be a positive number, got {jerk}"),
        ));
    }
    if body.residual_profile == Some(false) && body.profile_ridge.is_some() {
        errors.push(Invalid::new(
            "$.profile_ridge",
            "given with residual_profile false",
        ));
    }
    let gains = body.control.unwrap_or_default();
    if !(gains.rate > 0.0 && gains.rate.is_finite()) {
        errors.push(Invalid::new("$.control.rate", "must be a positive number"));
    }
    if !(gains.k_perp >= 0.0 && gains.k_perp.is_finite()) {
        errors.push(Invalid::new(
            "$.control.k_perp",
            "must be a non-negative number",
        ));
    }
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    Ok(Validated {
        options,
        acceleration,
        jerk,
        gains,
        held_out: body.held_out.unwrap_or(true),
    })
}

/// A training option [`TrainOptions::check`] refused, at the request field of its name.
fn option_error(e: MotionError) -> Invalid {
    match e {
        MotionError::InvalidOption { field, reason, .. } => {
            Invalid::new(format!("$.{field}"), reason)
        }
        MotionError::SplineTooLarge {
            intervals,
            components,
            coefficients,
            max,
        } => Invalid::new(
            "$.spline_intervals",
            format!(
                "{intervals} intervals on {components} components need {coefficients} spline coefficients, at most {max} supported"
            ),
        ),
        other => Invalid::new("$", other.to_string()),
    }
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
    limits: (f64, f64),
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
        acceleration_limit: limits.0,
        jerk_limit: limits.1,
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
    let (mut sum_nf, mut sum_jl) = (0.0, 0.0);
    // A baseline's overall figure only when every fold that trained has it.
    let (mut sum_dmp, mut sum_promp) = (Some(0.0), Some(0.0));
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
                sum_dmp = sum_dmp.zip(h.dmp).map(|(s, v)| s + v * n as f64);
                sum_promp = sum_promp.zip(h.promp).map(|(s, v)| s + v * n as f64);
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
            dmp: sum_dmp.map(|s| s / u),
            promp: sum_promp.map(|s| s / u),
            ratio_to_joint_line: sum_nf / sum_jl.max(f64::MIN_POSITIVE),
        }
    });
    Some(HeldOutSummaryDto { folds, overall })
}

fn train_error(e: MotionError) -> JobError {
    JobError::failed(format!("training failed: {e}"))
}

/// Validates a training request against its robot and the stored mappings and submits the
/// training job; the model is stored at once as pending. Returns the job and the model id.
pub async fn train_model(ctx: &Context, body: &CreateModel) -> Result<(JobRecord, String), Error> {
    let system = super::robots::robot_field(ctx, &body.robot, "$.robot").await?;
    let v = validate_training(body, &system)?;
    if body.mappings.is_empty() {
        return Err(Error::invalid("$.mappings", "give at least one mapping id"));
    }
    let names = system.model.joint_names().to_vec();
    let mut demos = Vec::new();
    let mut positions = Vec::new();
    let mut seen = BTreeSet::new();
    for (i, id) in body.mappings.iter().enumerate() {
        let path = format!("$.mappings[{i}]");
        if !seen.insert(id.clone()) {
            return Err(Error::invalid(path, "mapping listed twice"));
        }
        let row = mapping_repo::get_mapping(&ctx.db, id)
            .await?
            .ok_or_else(|| Error::invalid(&path, format!("unknown mapping '{id}'")))?;
        if row.robot != body.robot {
            return Err(Error::invalid(
                path,
                format!(
                    "mapping '{id}' is of robot '{}', not '{}'",
                    row.robot, body.robot
                ),
            ));
        }
        if row.status != "succeeded" {
            return Err(Error::invalid(
                path,
                format!(
                    "mapping '{id}' has status {} (job {}); only succeeded mappings can be trained on",
                    row.status, row.job_id
                ),
            ));
        }
        for d in mapping_repo::load_trajectories(&ctx.db, id).await? {
            if d.trajectory.joint_names != names {
                return Err(Error::invalid(
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
        return Err(Error::invalid(
            "$.mappings",
            format!(
                "too few demonstrations: {} in the mappings, at least {needed} needed for the requested components",
                demos.len()
            ),
        ));
    }
    let limits = system_limits(&system, v.acceleration, v.jerk);
    let request = serde_json::to_string(&body).map_err(Error::internal)?;
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
    let job = ctx
        .jobs
        .submit("model", move |job| {
            let steps = if v.held_out { 6.0 } else { 1.0 };
            job.progress(0.0, "training the model");
            let (model, report) = train(&demos, &limits, &v.options).map_err(train_error)?;
            job.check_cancelled()?;
            let held = if v.held_out {
                held_out_folds(&demos, &positions, &limits, &v.options, |f, n| {
                    job.progress(
                        (1.0 + 5.0 * f as f64 / n as f64) / steps,
                        format!("held-out fold {} of {n}", f + 1),
                    );
                })
            } else {
                None
            };
            job.check_cancelled()?;
            let dto = model_report(&system, &model, &report, (v.acceleration, v.jerk), held);
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
    if let Err(e) = repo::insert_pending(&ctx.db, &new_model).await {
        // Without its row the model could not be found; stop the job rather than orphan it.
        let _ = ctx.jobs.cancel(job.id).await;
        return Err(e.into());
    }
    Ok((job, model_id))
}

/// A stored model: its row (status is its job's), the request as given, the training report
/// once trained, whether it is marked its robot's default, and its joint names.
#[derive(Debug, Clone)]
pub struct StoredModel {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub status: String,
    pub request: serde_json::Value,
    pub report: Option<ModelReportDto>,
    pub default: bool,
    pub joint_names: Vec<String>,
    pub created_at: String,
}

async fn stored_model(ctx: &Context, row: repo::ModelRow) -> Result<StoredModel, Error> {
    let joint_names = repo::joint_names(&ctx.db, &row.id)
        .await?
        .unwrap_or_default();
    let default = repo::is_marked_default(&ctx.db, &row.id).await?;
    Ok(StoredModel {
        request: serde_json::from_str(&row.request).map_err(Error::internal)?,
        report: row
            .report
            .as_deref()
            .map(serde_json::from_str)
            .transpose()
            .map_err(Error::internal)?,
        id: row.id,
        job_id: row.job_id,
        robot: row.robot,
        status: row.status,
        default,
        joint_names,
        created_at: row.created_at,
    })
}

/// Model `id`, pending and failed ones included.
pub async fn get(ctx: &Context, id: &str) -> Result<StoredModel, Error> {
    let row = repo::get_model(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("model", id))?;
    stored_model(ctx, row).await
}

/// Models, newest first, optionally of one robot; with how many match without the page.
pub async fn list(
    ctx: &Context,
    robot: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<(Vec<StoredModel>, i64), Error> {
    let (rows, total) = repo::list_models(&ctx.db, robot, limit, offset).await?;
    let mut items = Vec::with_capacity(rows.len());
    for row in rows {
        items.push(stored_model(ctx, row).await?);
    }
    Ok((items, total))
}

/// The closed-loop law's parameters of trained model `id`.
pub async fn params(ctx: &Context, id: &str) -> Result<ControlParams, Error> {
    Ok(loaded_model(ctx, id, None).await?.params.clone())
}

/// The closed-loop law `u(q)` of model `id` for a measured state and a goal in its goal region;
/// returns the model's joint order and `u`.
pub async fn control(
    ctx: &Context,
    id: &str,
    body: &ControlRequest,
) -> Result<(Vec<String>, Vec<f64>), Error> {
    let l = loaded_model(ctx, id, None).await?;
    let system = super::robots::system(ctx, &l.robot).await?;
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
    Ok((l.names.clone(), u))
}
