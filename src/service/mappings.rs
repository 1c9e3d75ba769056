//! Mappings: human demonstrations mapped onto a robot arm-hand system (paper eq. 1-7) as a
//! job, or offline for `reachgrasp map`.
//!
//! Everything the request names is checked before the job exists (robot, every demonstration,
//! the registration of every demonstration's arm, weights, rate), so bad input is an error with
//! nothing stored. The job maps the demonstrations across all cores ([`map_batch`]: every first
//! frame solved from the first demonstration's, so one rest pose gives one posture) and stores
//! every result in the transaction that marks it succeeded; a failure or cancellation stores no
//! trajectory. [`map_offline`] is the same computation for `reachgrasp map`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use uuid::Uuid;

use super::{Context, Error, Invalid, Keyword};
use crate::human::{HumanFrame, unpack_frames};
use crate::jobs::{JobContext, JobError, JobOutput, JobRecord, ResultRef};
use crate::kinematics::System;
use crate::mapping::{
    BatchItem, BodyAxes, FrameMetrics, HumanObject, MappedTrajectory, MappingError, MappingModel,
    RegistrationSpec, RobotAnchor, Scale, SceneRegistration, SolverOptions, Weights, human_object,
    map_batch, registration_for, resample_frames, shape_spec,
};
use crate::store::mappings::{self as repo, DemoLabels, DemoSelection, NewMappedDemo, NewMapping};
use crate::store::{blob, demonstrations as demo_repo, now};

/// Most demonstrations one mapping may select.
pub const MAX_DEMONSTRATIONS: usize = 500;
/// Highest output rate, Hz: well above any tracker or robot controller rate in the study.
pub const MAX_OUTPUT_RATE_HZ: f64 = 500.0;
/// Demonstrations per page of `GET /v1/mappings/{id}` (default and maximum).
pub const DEFAULT_DEMO_PAGE: u32 = 10;
pub const MAX_DEMO_PAGE: u32 = 100;

/// Which demonstrations to map: a list of ids, or a filter (every given field must match).
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(untagged)]
pub enum SelectionIn {
    /// Demonstration ids, mapped in this order.
    Ids(Vec<String>),
    Filter(DemoFilterIn),
}

/// By hand rather than untagged, so that a bad id or filter field is reported at its own path
/// (`$.demonstrations.subject`) instead of "did not match any variant" at the selection.
impl<'de> Deserialize<'de> for SelectionIn {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Selection;
        impl<'de> serde::de::Visitor<'de> for Selection {
            type Value = SelectionIn;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a list of demonstration ids or a filter object")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                seq: A,
            ) -> Result<SelectionIn, A::Error> {
                // The same access: each item's index stays on the error path.
                Vec::deserialize(serde::de::value::SeqAccessDeserializer::new(seq))
                    .map(SelectionIn::Ids)
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<SelectionIn, A::Error> {
                DemoFilterIn::deserialize(serde::de::value::MapAccessDeserializer::new(map))
                    .map(SelectionIn::Filter)
            }
        }
        d.deserialize_any(Selection)
    }
}

/// A filter over the stored demonstrations (oldest first).
#[derive(Debug, Clone, Default, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DemoFilterIn {
    pub subject: Option<String>,
    pub object: Option<String>,
    pub task: Option<String>,
    /// Object position index.
    pub position: Option<u32>,
    pub synthetic: Option<bool>,
    /// The synthetic-study job that produced them.
    pub job_id: Option<String>,
}

/// Weights of eq. 5 and the swivel term; a missing one keeps its default (position 1,
/// orientation 1e-4, elbow 0.1, swivel 1e-2).
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct WeightsIn {
    /// `w_x`, on squared fingertip position errors (per m²).
    #[schema(minimum = 0)]
    pub position: Option<f64>,
    /// `w_o`, on fingertip quaternion distances (per rad).
    #[schema(minimum = 0)]
    pub orientation: Option<f64>,
    /// `w_D`, on squared human-elbow-to-robot-joint distances (per m²).
    #[schema(minimum = 0)]
    pub elbow: Option<f64>,
    /// On `2 (1 − cos Δφ)`, the elbow swivel-angle difference (not in the paper).
    #[schema(minimum = 0)]
    pub swivel: Option<f64>,
    /// Fingertip priority `K ≥ 1` (not in the paper): each frame's weighted solve is followed by
    /// a second one from its result with the orientation, elbow and swivel weights divided by
    /// `K`, so the fingertips (kept clear of the scene) come first and the anthropomorphism
    /// terms act in the self-motion they leave. Default 1, the paper's single weighted sum
    /// (the stage off); 1000 is the measured setting.
    #[schema(minimum = 1)]
    pub fingertip_priority: Option<f64>,
}

/// Scale of the human arm transport (horizontal, about the object): a positive number, or
/// `"auto"` (robot reach / human reach). With `transform`: the uniform scale of the similarity.
#[derive(Debug, Clone, Serialize, ToSchema)]
#[serde(untagged)]
pub enum ScaleIn {
    Factor(f64),
    Named(String),
}

/// By hand rather than untagged, so that a wrong value says what is expected instead of "did
/// not match any variant of untagged enum ScaleIn".
impl<'de> Deserialize<'de> for ScaleIn {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Scale;
        impl serde::de::Visitor<'_> for Scale {
            type Value = ScaleIn;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a positive number or \"auto\"")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<ScaleIn, E> {
                Ok(ScaleIn::Factor(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<ScaleIn, E> {
                Ok(ScaleIn::Factor(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<ScaleIn, E> {
                Ok(ScaleIn::Factor(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ScaleIn, E> {
                Ok(ScaleIn::Named(v.to_owned()))
            }
        }
        d.deserialize_any(Scale)
    }
}

/// A rigid transform: position (m) and orientation `[w, x, y, z]`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TransformIn {
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub position: [f64; 3],
    #[schema(min_items = 4, max_items = 4)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub orientation: [f64; 4],
}

/// Human (tracker) frame → robot base frame. Default (scene-keeping, `mapping::registration`):
/// each demonstration's object lands on `placement` (default: where the subject had it relative
/// to the shoulder, resting on the robot's table at z = 0), its table on the robot's table, the
/// subject's forward/up axes on the base's; arm transport scaled horizontally by `scale`
/// (default `"auto"`), fingertips relative to the wrist by `hand_scale` (default 1). With `transform`:
/// `p_robot = transform · (scale · p_human)` for every point (scale a number, default 1).
#[derive(Debug, Clone, Default, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RegistrationIn {
    pub scale: Option<ScaleIn>,
    /// Robot-frame position of the object's centre (every demonstration of the mapping), m.
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub placement: Option<[f64; 3]>,
    /// Scale of the fingertips relative to the wrist, > 0 (default 1: the subject's hand).
    pub hand_scale: Option<f64>,
    /// The subject's forward axis in the tracker frame (default `[1, 0, 0]`).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub subject_forward: Option<[f64; 3]>,
    /// The subject's up axis in the tracker frame (default `[0, 0, 1]`).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub subject_up: Option<[f64; 3]>,
    pub transform: Option<TransformIn>,
}

/// A mapping request.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MappingIn {
    /// Arm-hand system id (bundled, e.g. `wam_ihy`, or registered).
    #[schema(min_length = 1)]
    pub robot: String,
    /// Demonstration ids, or a filter `{subject, object, task, position, synthetic, job_id}`.
    pub demonstrations: SelectionIn,
    #[serde(default)]
    pub weights: WeightsIn,
    #[serde(default)]
    pub registration: RegistrationIn,
    /// Rate of the output trajectories, Hz, in (0, 500]; default: each demonstration's own.
    #[schema(exclusive_minimum = 0, maximum = 500)]
    pub output_rate_hz: Option<f64>,
}

/// The request as validated and run (stored with the mapping).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct MappingRequestDto {
    pub robot: String,
    /// The resolved demonstration ids, in mapping order.
    pub demonstrations: Vec<String>,
    /// The filter they were selected by, if any.
    pub filter: Option<DemoFilterIn>,
    pub weights: WeightsDto,
    pub registration: RegistrationIn,
    pub output_rate_hz: Option<f64>,
}

/// Weights as used.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema)]
pub struct WeightsDto {
    pub position: f64,
    pub orientation: f64,
    pub elbow: f64,
    /// Absent in mappings stored before the swivel term.
    #[serde(default)]
    pub swivel: f64,
    /// The fingertip-priority factor `K` (`1`: the paper's single weighted sum, as every
    /// mapping stored before the stage was mapped).
    #[serde(default = "single_weighted_sum")]
    pub fingertip_priority: f64,
}

fn single_weighted_sum() -> f64 {
    1.0
}

/// Aggregate metrics over frames (of one demonstration or of a whole mapping).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct MappingSummary {
    pub demonstrations: usize,
    pub frames: usize,
    /// Mean over frames and robot fingers of the fingertip position error, m.
    pub mean_fingertip_error_m: f64,
    /// Largest fingertip position error of any finger in any frame, m.
    pub max_fingertip_error_m: f64,
    /// Mean fingertip orientation error `d_o` (eq. 3), rad.
    pub mean_orientation_error_rad: f64,
    /// Mean distance between the human elbow and the robot's eq. 4 joints, m.
    pub mean_elbow_distance_m: f64,
    /// Mean `D` of eq. 4, m².
    pub mean_elbow_term_m2: f64,
    /// Mean objective `F` (eq. 5).
    pub mean_objective: f64,
    pub mean_iterations: f64,
    /// Frames whose solve did not converge (kept and reported, never hidden).
    pub unconverged_frames: usize,
    /// Median and 95th percentile over frames and robot fingers of the fingertip error, m.
    #[serde(default)]
    pub median_fingertip_error_m: f64,
    #[serde(default)]
    pub p95_fingertip_error_m: f64,
    /// Median over frames of the human-vs-robot elbow swivel-angle difference, rad (null without
    /// arm frames).
    #[serde(default)]
    pub median_swivel_difference_rad: Option<f64>,
    /// Mean over frames of the lower bound on the elbow distance that the robot's link lengths
    /// allow (distance of the human elbow to the robot elbow's circle), m.
    #[serde(default)]
    pub mean_elbow_bound_m: Option<f64>,
    /// Smallest exact clearance of any robot link or fingertip to the support plane and to the
    /// object over all frames, m (negative: penetration; null: not measured).
    #[serde(default)]
    pub min_support_clearance_m: Option<f64>,
    #[serde(default)]
    pub min_object_clearance_m: Option<f64>,
}

impl MappingSummary {
    /// Summary of one or more trajectories' metrics.
    pub fn of<'a>(trajectories: impl IntoIterator<Item = &'a [FrameMetrics]>) -> Self {
        let mut s = MappingSummary::default();
        let (mut tips, mut tip_sum, mut ori_sum) = (0usize, 0.0, 0.0);
        let (mut elbow, mut d, mut f, mut it) = (0.0, 0.0, 0.0, 0.0);
        let all: Vec<&[FrameMetrics]> = trajectories.into_iter().collect();
        for metrics in all.iter().copied() {
            s.demonstrations += 1;
            for m in metrics {
                s.frames += 1;
                for i in 0..m.fingers {
                    tips += 1;
                    tip_sum += m.position_error[i];
                    ori_sum += m.orientation_error[i];
                    s.max_fingertip_error_m = s.max_fingertip_error_m.max(m.position_error[i]);
                }
                elbow += m.elbow_distance_mean;
                d += m.elbow_distance;
                f += m.objective;
                it += m.iterations as f64;
                s.unconverged_frames += usize::from(!m.converged);
            }
        }
        let mut tip_errors = Vec::new();
        let mut swivels = Vec::new();
        let (mut bound_sum, mut bounds) = (0.0, 0usize);
        let (mut support, mut object) = (None::<f64>, None::<f64>);
        for metrics in &all {
            for m in *metrics {
                tip_errors.extend_from_slice(&m.position_error[..m.fingers]);
                if m.swivel_difference.is_finite() {
                    swivels.push(m.swivel_difference);
                }
                if m.elbow_bound.is_finite() {
                    bound_sum += m.elbow_bound;
                    bounds += 1;
                }
                let min = |acc: Option<f64>, x: f64| {
                    if x.is_finite() {
                        Some(acc.map_or(x, |a| a.min(x)))
                    } else {
                        acc
                    }
                };
                support = min(support, m.support_clearance);
                object = min(object, m.object_clearance);
            }
        }
        s.median_fingertip_error_m = quantile(&mut tip_errors, 0.5).unwrap_or(0.0);
        s.p95_fingertip_error_m = quantile(&mut tip_errors, 0.95).unwrap_or(0.0);
        s.median_swivel_difference_rad = quantile(&mut swivels, 0.5);
        s.mean_elbow_bound_m = (bounds > 0).then(|| bound_sum / bounds as f64);
        s.min_support_clearance_m = support;
        s.min_object_clearance_m = object;
        let per_tip = 1.0 / tips.max(1) as f64;
        let per_frame = 1.0 / s.frames.max(1) as f64;
        s.mean_fingertip_error_m = tip_sum * per_tip;
        s.mean_orientation_error_rad = ori_sum * per_tip;
        s.mean_elbow_distance_m = elbow * per_frame;
        s.mean_elbow_term_m2 = d * per_frame;
        s.mean_objective = f * per_frame;
        s.mean_iterations = it * per_frame;
        s
    }
}

/// The `q`-quantile (nearest rank) of `v` (sorted in place); `None` when empty.
fn quantile(v: &mut [f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let k = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    Some(v[k])
}

/// A robot joint trajectory: independent joints (mimic joints follow their drivers).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct JointTrajectoryDto {
    pub joint_names: Vec<String>,
    /// s, on the demonstration's clock.
    pub times: Vec<f64>,
    /// One row per time, in the order of `joint_names` (rad or m).
    pub positions: Vec<Vec<f64>>,
}

/// Per-frame metrics, one entry per frame in each array.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FrameMetricsDto {
    /// Robot fingers `m` (the length of each per-finger row).
    pub fingers: usize,
    /// Fingertip position error per finger, m.
    pub position_error: Vec<Vec<f64>>,
    /// Fingertip orientation error `d_o` (eq. 3) per finger, rad.
    pub orientation_error: Vec<Vec<f64>>,
    /// `D` of eq. 4, m².
    pub elbow_distance: Vec<f64>,
    /// Mean human-elbow-to-robot-joint distance, m.
    pub elbow_distance_mean: Vec<f64>,
    /// `F` of eq. 5.
    pub objective: Vec<f64>,
    pub iterations: Vec<usize>,
    pub converged: Vec<bool>,
    /// Elbow swivel angle of the registered human arm and of the robot arm, and their absolute
    /// difference, rad (null without arm frames).
    pub swivel_human: Vec<Option<f64>>,
    pub swivel_robot: Vec<Option<f64>>,
    pub swivel_difference: Vec<Option<f64>>,
    /// Lower bound on the elbow distance from the robot's link lengths, m.
    pub elbow_bound: Vec<Option<f64>>,
    /// Smallest exact clearance of any robot link or fingertip to the support plane and to the
    /// object, m (negative: penetration; null: not measured).
    pub support_clearance: Vec<Option<f64>>,
    pub object_clearance: Vec<Option<f64>>,
}

/// The resolved registration (see `mapping::registration`): arm points
/// `robot_anchor + transport_scale · horizontal(R (p − human_anchor)) + vertical_scale ·
/// vertical(R (p − human_anchor))`, fingertips rigid with the wrist up to `hand_scale`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RegistrationDto {
    /// `R`, `[w, x, y, z]`.
    #[schema(min_items = 4, max_items = 4)]
    pub rotation: [f64; 4],
    /// The human point the map is anchored at (the object's centre), tracker frame.
    #[schema(min_items = 3, max_items = 3)]
    pub human_anchor: [f64; 3],
    /// Where it lands (the object's placement), robot base frame.
    #[schema(min_items = 3, max_items = 3)]
    pub robot_anchor: [f64; 3],
    pub transport_scale: f64,
    pub vertical_scale: f64,
    pub hand_scale: f64,
    /// The registered object in the robot base frame, in the form `POST /v1/grasps` and plans
    /// take (`support`: the robot's table), so grasps and plans use the object the mapping
    /// registered. Null without an object or with an explicit transform.
    pub object: Option<crate::grasp::ObjectSpec>,
}

/// One mapped demonstration.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct MappedDemoDto {
    /// Place in the mapping order, from 0.
    pub position: usize,
    pub demonstration_id: String,
    pub subject_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: u32,
    pub trial: u32,
    pub summary: MappingSummary,
    /// Absent with `?trajectories=false`.
    pub registration: Option<RegistrationDto>,
    pub trajectory: Option<JointTrajectoryDto>,
    pub metrics: Option<FrameMetricsDto>,
}

/// Everything a mapping run needs besides the robot and the demonstrations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MappingParams {
    pub weights: Weights,
    /// [`SolverOptions::fingertip_priority`].
    pub fingertip_priority: f64,
    pub registration: RegistrationSpec,
    pub output_rate_hz: Option<f64>,
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Checks weights, registration and rate; every problem becomes a field error.
pub fn parse_params(
    weights: &WeightsIn,
    registration: &RegistrationIn,
    output_rate_hz: Option<f64>,
) -> Result<MappingParams, Error> {
    let mut errors = Vec::new();
    let d = Weights::default();
    let w = Weights {
        position: weights.position.unwrap_or(d.position),
        orientation: weights.orientation.unwrap_or(d.orientation),
        elbow: weights.elbow.unwrap_or(d.elbow),
        swivel: weights.swivel.unwrap_or(d.swivel),
    };
    let mut weights_ok = true;
    for (name, v) in [
        ("position", w.position),
        ("orientation", w.orientation),
        ("elbow", w.elbow),
        ("swivel", w.swivel),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            weights_ok = false;
            errors.push(Invalid::new(
                format!("$.weights.{name}"),
                format!("must be finite and non-negative, got {v}"),
            ));
        }
    }
    let fingertip_priority = weights
        .fingertip_priority
        .unwrap_or(SolverOptions::default().fingertip_priority);
    if !(fingertip_priority.is_finite() && fingertip_priority >= 1.0) {
        errors.push(Invalid::new(
            "$.weights.fingertip_priority",
            format!("must be finite and at least 1, got {fingertip_priority}"),
        ));
    }
    if weights_ok && w.validate().is_err() {
        errors.push(Invalid::new(
            "$.weights",
            "at least one weight must be positive (all four are zero)",
        ));
    }
    if let Some(r) = output_rate_hz
        && !(r.is_finite() && r > 0.0 && r <= MAX_OUTPUT_RATE_HZ)
    {
        errors.push(Invalid::new(
            "$.output_rate_hz",
            format!("must be in (0, {MAX_OUTPUT_RATE_HZ}] Hz, got {r}"),
        ));
    }
    let reg = registration;
    let scale = match &reg.scale {
        None => None,
        Some(ScaleIn::Factor(s)) if s.is_finite() && *s > 0.0 => Some(Scale::Factor(*s)),
        Some(ScaleIn::Named(n)) if Keyword::parse(n) == Some(Keyword::Auto) => Some(Scale::Auto),
        Some(other) => {
            errors.push(Invalid::new(
                "$.registration.scale",
                format!("must be a positive number or \"auto\", got {other:?}"),
            ));
            None
        }
    };
    let spec = match &reg.transform {
        Some(t) => {
            if reg.subject_forward.is_some()
                || reg.subject_up.is_some()
                || reg.placement.is_some()
                || reg.hand_scale.is_some()
            {
                errors.push(Invalid::new(
                    "$.registration.transform",
                    "an explicit transform replaces the subject axes, placement and hand scale; \
                     give one or the other",
                ));
            }
            let factor = match scale {
                None => 1.0,
                Some(Scale::Factor(s)) => s,
                Some(_) => {
                    errors.push(Invalid::new(
                        "$.registration.scale",
                        "\"auto\" needs the default (scene-keeping) registration; give a \
                         number with an explicit transform",
                    ));
                    1.0
                }
            };
            let q = Quaternion::new(
                t.orientation[0],
                t.orientation[1],
                t.orientation[2],
                t.orientation[3],
            );
            if !finite3(&t.position) {
                errors.push(Invalid::new(
                    "$.registration.transform.position",
                    "must be finite",
                ));
            }
            if !(q.coords.iter().all(|x| x.is_finite()) && q.norm() > 1e-9) {
                errors.push(Invalid::new(
                    "$.registration.transform.orientation",
                    "must be a finite, non-zero quaternion [w, x, y, z]",
                ));
            }
            RegistrationSpec::Explicit {
                transform: Isometry3::from_parts(
                    Translation3::from(Vector3::from(t.position)),
                    UnitQuaternion::from_quaternion(q),
                ),
                scale: factor,
            }
        }
        None => {
            let axes = BodyAxes {
                forward: reg.subject_forward.map_or(Vector3::x(), Vector3::from),
                up: reg.subject_up.map_or(Vector3::z(), Vector3::from),
            };
            let (f, u) = (axes.forward, axes.up);
            let usable = finite3(&f.into())
                && finite3(&u.into())
                && f.norm() > 1e-9
                && u.norm() > 1e-9
                && f.cross(&u).norm() > 1e-6 * f.norm() * u.norm();
            if !usable {
                errors.push(Invalid::new(
                    "$.registration.subject_up",
                    "subject_forward and subject_up must be finite, non-zero and not parallel",
                ));
            }
            if let Some(p) = reg.placement
                && !finite3(&p)
            {
                errors.push(Invalid::new(
                    "$.registration.placement",
                    "must be a finite position [x, y, z] in metres",
                ));
            }
            let hand_scale = reg.hand_scale.unwrap_or(1.0);
            if !(hand_scale.is_finite() && hand_scale > 0.0) {
                errors.push(Invalid::new(
                    "$.registration.hand_scale",
                    format!("must be a positive finite number, got {hand_scale}"),
                ));
            }
            RegistrationSpec::Scene(SceneRegistration {
                subject_axes: axes,
                transport_scale: scale.unwrap_or(Scale::Auto),
                hand_scale,
                placement: reg.placement.map(nalgebra::Point3::from),
                ..SceneRegistration::default()
            })
        }
    };
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    Ok(MappingParams {
        weights: w,
        fingertip_priority,
        registration: spec,
        output_rate_hz,
    })
}

/// A demonstration ready to map: labels, frames at the output rate and its registration (the
/// request's, with the demonstration's object).
#[derive(Debug, Clone)]
pub struct PreparedDemo {
    pub labels: DemoLabels,
    pub frames: Vec<HumanFrame>,
    pub registration: RegistrationSpec,
}

/// Resamples (at the output rate) and checks that the demonstration's arm can be registered.
/// `path` names the demonstration in the request for the error.
pub fn prepare_demo(
    labels: DemoLabels,
    frames: Vec<HumanFrame>,
    object: Option<HumanObject>,
    params: &MappingParams,
    anchor: &RobotAnchor,
    path: &str,
) -> Result<PreparedDemo, Invalid> {
    let frames = match params.output_rate_hz {
        Some(rate) => resample_frames(&frames, rate),
        None => frames,
    };
    let registration = params.registration.for_object(object);
    if let Err(e) = registration_for(&frames, &registration, anchor) {
        // A bad placement is the request's field, whichever demonstration shows it.
        let path = match e {
            MappingError::InvalidPlacement { .. } => "$.registration.placement",
            _ => path,
        };
        return Err(Invalid::new(
            path,
            format!(
                "demonstration {} cannot be registered onto the robot: {e}",
                labels.demonstration_id
            ),
        ));
    }
    Ok(PreparedDemo {
        labels,
        frames,
        registration,
    })
}

/// The robot's mapping view; a hand the mapping cannot handle is bad input on `$.robot`.
pub fn mapping_model(system: &System) -> Result<MappingModel, Error> {
    MappingModel::from_system(system).map_err(|e| {
        Error::invalid(
            "$.robot",
            format!("this robot cannot be used for mapping: {e}"),
        )
    })
}

/// Why a mapping run ended without results.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    #[error("cancelled")]
    Cancelled,
    #[error("demonstration {demonstration} ({index} in the mapping order): {source}")]
    Demonstration {
        index: usize,
        demonstration: String,
        source: MappingError,
    },
}

/// Maps every demonstration across `threads` workers. `progress(done, total)` after each one;
/// `cancelled()` is polled every few milliseconds. Any failed demonstration fails the run.
pub fn run_mapping(
    mm: &MappingModel,
    demos: &[PreparedDemo],
    params: &MappingParams,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Result<Vec<MappedTrajectory>, RunError> {
    let anchor = mm.anchor();
    let items: Vec<BatchItem<'_>> = demos
        .iter()
        .map(|d| BatchItem {
            frames: &d.frames,
            registration: &d.registration,
        })
        .collect();
    let flag = AtomicBool::new(false);
    let finished = AtomicBool::new(false);
    let result = std::thread::scope(|s| {
        // `map_batch` polls an atomic flag between frames; this bridges it to the caller's
        // cancellation source (the job's), which is not an atomic we can hand over.
        s.spawn(|| {
            while !finished.load(Ordering::Acquire) {
                if cancelled() {
                    flag.store(true, Ordering::Release);
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        let r = map_batch(
            mm,
            &anchor,
            &items,
            params.weights,
            SolverOptions {
                fingertip_priority: params.fingertip_priority,
                ..SolverOptions::default()
            },
            threads,
            progress,
            &flag,
        );
        finished.store(true, Ordering::Release);
        r
    });
    let results = result.map_err(|_| RunError::Cancelled)?;
    results
        .into_iter()
        .enumerate()
        .map(|(index, r)| {
            r.map_err(|source| RunError::Demonstration {
                index,
                demonstration: demos[index].labels.demonstration_id.clone(),
                source,
            })
        })
        .collect()
}

fn registration_dto(t: &MappedTrajectory) -> RegistrationDto {
    let r = &t.registration;
    let q = r.rotation.quaternion();
    let p3 = |p: &nalgebra::Point3<f64>| [p.x, p.y, p.z];
    RegistrationDto {
        rotation: [q.w, q.i, q.j, q.k],
        human_anchor: p3(&r.human_anchor),
        robot_anchor: p3(&r.robot_anchor),
        transport_scale: r.transport_scale,
        vertical_scale: r.vertical_scale,
        hand_scale: r.hand_scale,
        object: r.object.map(|o| {
            let c = o.pose.translation.vector;
            let q = o.pose.rotation.quaternion();
            crate::grasp::ObjectSpec {
                name: "object".into(),
                shape: shape_spec(&o.shape),
                position: [c.x, c.y, c.z],
                orientation: [q.w, q.i, q.j, q.k],
                support: r.support.map(|h| crate::grasp::SupportPlane {
                    normal: [r.up.x, r.up.y, r.up.z],
                    offset: h,
                    friction: None,
                }),
                mass: None,
                friction: None,
            }
        }),
    }
}

fn trajectory_dto(t: &MappedTrajectory) -> JointTrajectoryDto {
    JointTrajectoryDto {
        joint_names: t.joint_names.clone(),
        times: t.times.clone(),
        positions: (0..t.times.len()).map(|k| t.frame(k).to_vec()).collect(),
    }
}

fn metrics_dto(ms: &[FrameMetrics]) -> FrameMetricsDto {
    let fingers = ms.first().map_or(0, |m| m.fingers);
    FrameMetricsDto {
        fingers,
        position_error: ms
            .iter()
            .map(|m| m.position_error[..m.fingers].to_vec())
            .collect(),
        orientation_error: ms
            .iter()
            .map(|m| m.orientation_error[..m.fingers].to_vec())
            .collect(),
        elbow_distance: ms.iter().map(|m| m.elbow_distance).collect(),
        elbow_distance_mean: ms.iter().map(|m| m.elbow_distance_mean).collect(),
        objective: ms.iter().map(|m| m.objective).collect(),
        iterations: ms.iter().map(|m| m.iterations).collect(),
        converged: ms.iter().map(|m| m.converged).collect(),
        swivel_human: ms.iter().map(|m| finite(m.swivel_human)).collect(),
        swivel_robot: ms.iter().map(|m| finite(m.swivel_robot)).collect(),
        swivel_difference: ms.iter().map(|m| finite(m.swivel_difference)).collect(),
        elbow_bound: ms.iter().map(|m| finite(m.elbow_bound)).collect(),
        support_clearance: ms.iter().map(|m| finite(m.support_clearance)).collect(),
        object_clearance: ms.iter().map(|m| finite(m.object_clearance)).collect(),
    }
}

fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The DTO of one mapped demonstration (with its arrays).
pub fn mapped_demo_dto(
    position: usize,
    labels: &DemoLabels,
    t: &MappedTrajectory,
) -> MappedDemoDto {
    MappedDemoDto {
        position,
        demonstration_id: labels.demonstration_id.clone(),
        subject_id: labels.subject_id.clone(),
        object_name: labels.object_name.clone(),
        task: labels.task.clone(),
        position_index: labels.position_index,
        trial: labels.trial,
        summary: MappingSummary::of([t.metrics.as_slice()]),
        registration: Some(registration_dto(t)),
        trajectory: Some(trajectory_dto(t)),
        metrics: Some(metrics_dto(&t.metrics)),
    }
}

/// A stored mapping: its row (status is its job's), the request it was submitted with, its
/// summary once succeeded, and why its job failed.
#[derive(Debug, Clone)]
pub struct StoredMapping {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub status: String,
    pub request: MappingRequestDto,
    pub summary: Option<MappingSummary>,
    pub error: Option<crate::jobs::JobFailure>,
    pub created_at: String,
}

async fn stored_mapping(ctx: &Context, row: repo::MappingRow) -> Result<StoredMapping, Error> {
    let request: MappingRequestDto = serde_json::from_str(&row.request)
        .map_err(|e| Error::internal(anyhow::anyhow!("mappings.request of {}: {e}", row.id)))?;
    let summary = row
        .summary
        .as_deref()
        .map(serde_json::from_str)
        .transpose()
        .map_err(|e| Error::internal(anyhow::anyhow!("mappings.summary of {}: {e}", row.id)))?;
    let error = if row.status == "failed" {
        match Uuid::parse_str(&row.job_id) {
            Ok(job) => ctx.jobs.get(job).await.ok().and_then(|j| j.error),
            Err(_) => None,
        }
    } else {
        None
    };
    Ok(StoredMapping {
        id: row.id,
        job_id: row.job_id,
        robot: row.robot,
        status: row.status,
        request,
        summary,
        error,
        created_at: row.created_at,
    })
}

/// Which of a mapping's demonstrations to read, and whether with their arrays.
#[derive(Debug, Clone, Default)]
pub struct DemoPage<'a> {
    /// Only this demonstration id.
    pub demonstration: Option<&'a str>,
    /// With joint trajectories and per-frame metrics (else the summaries only).
    pub trajectories: bool,
    pub limit: u32,
    pub offset: u32,
}

/// A mapping, a page of its demonstrations (request order) and how many match without the
/// page.
pub async fn get(
    ctx: &Context,
    id: &str,
    page: &DemoPage<'_>,
) -> Result<(StoredMapping, Vec<MappedDemoDto>, i64), Error> {
    let row = repo::get_mapping(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("mapping", id))?;
    let (demo, limit, offset) = (
        page.demonstration,
        i64::from(page.limit),
        i64::from(page.offset),
    );
    let (items, total) = if page.trajectories {
        let (rows, total) = repo::load_page(&ctx.db, id, demo, limit, offset).await?;
        let items = rows
            .iter()
            .map(|(meta, d)| {
                let mut dto = mapped_demo_dto(
                    meta.position as usize,
                    &labels_of(meta, Some(d)),
                    &d.trajectory,
                );
                dto.summary = parse_summary(meta)?;
                Ok(dto)
            })
            .collect::<Result<Vec<_>, Error>>()?;
        (items, total)
    } else {
        let (rows, total) = repo::list_demos(&ctx.db, id, demo, limit, offset).await?;
        let items = rows
            .iter()
            .map(|meta| {
                let l = labels_of(meta, None);
                Ok(MappedDemoDto {
                    position: meta.position as usize,
                    demonstration_id: l.demonstration_id,
                    subject_id: l.subject_id,
                    object_name: l.object_name,
                    task: l.task,
                    position_index: l.position_index,
                    trial: l.trial,
                    summary: parse_summary(meta)?,
                    registration: None,
                    trajectory: None,
                    metrics: None,
                })
            })
            .collect::<Result<Vec<_>, Error>>()?;
        (items, total)
    };
    Ok((stored_mapping(ctx, row).await?, items, total))
}

/// Mappings, newest first, optionally of one robot and/or job status, and how many match
/// without the page.
pub async fn list(
    ctx: &Context,
    robot: Option<&str>,
    status: Option<crate::jobs::JobStatus>,
    limit: u32,
    offset: u32,
) -> Result<(Vec<StoredMapping>, i64), Error> {
    let (rows, total) = repo::list_mappings(
        &ctx.db,
        i64::from(limit),
        i64::from(offset),
        robot,
        status.map(|s| s.as_str()),
    )
    .await?;
    let mut items = Vec::with_capacity(rows.len());
    for row in rows {
        items.push(stored_mapping(ctx, row).await?);
    }
    Ok((items, total))
}

fn parse_summary(row: &repo::MappedDemoRow) -> Result<MappingSummary, Error> {
    serde_json::from_str(&row.summary).map_err(|e| {
        Error::internal(anyhow::anyhow!(
            "mapping_demonstrations.summary of {}: {e}",
            row.demonstration_id
        ))
    })
}

fn labels_of(row: &repo::MappedDemoRow, d: Option<&repo::StoredMappedDemo>) -> DemoLabels {
    DemoLabels {
        demonstration_id: row.demonstration_id.clone(),
        subject_id: row.subject_id.clone(),
        object_name: row.object_name.clone(),
        task: row.task.clone(),
        position_index: d.map_or(row.position_index as u32, |d| d.position_index),
        trial: d.map_or(row.trial as u32, |d| d.trial),
    }
}

/// The result of `reachgrasp map`.
#[derive(Debug, Serialize)]
pub struct OfflineMapping {
    pub robot: String,
    pub weights: WeightsDto,
    pub output_rate_hz: Option<f64>,
    pub summary: MappingSummary,
    pub demonstrations: Vec<MappedDemoDto>,
}

/// Maps already-ingested demonstrations offline (same validation and computation as the job).
pub fn map_offline(
    robot: &str,
    system: &System,
    demos: Vec<(DemoLabels, Vec<HumanFrame>, Option<HumanObject>)>,
    params: &MappingParams,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<OfflineMapping, Error> {
    let mm = mapping_model(system)?;
    let anchor = mm.anchor();
    let mut prepared = Vec::with_capacity(demos.len());
    let mut errors = Vec::new();
    for (i, (labels, frames, object)) in demos.into_iter().enumerate() {
        match prepare_demo(labels, frames, object, params, &anchor, &format!("$[{i}]")) {
            Ok(p) => prepared.push(p),
            Err(e) => errors.push(e),
        }
    }
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    let trajectories = run_mapping(&mm, &prepared, params, threads, progress, &|| false)
        .map_err(|e| Error::invalid("$", e.to_string()))?;
    let demonstrations: Vec<MappedDemoDto> = prepared
        .iter()
        .zip(&trajectories)
        .enumerate()
        .map(|(k, (d, t))| mapped_demo_dto(k, &d.labels, t))
        .collect();
    Ok(OfflineMapping {
        robot: robot.to_owned(),
        weights: weights_dto(params),
        output_rate_hz: params.output_rate_hz,
        summary: MappingSummary::of(trajectories.iter().map(|t| t.metrics.as_slice())),
        demonstrations,
    })
}

fn weights_dto(p: &MappingParams) -> WeightsDto {
    let w = &p.weights;
    WeightsDto {
        position: w.position,
        orientation: w.orientation,
        elbow: w.elbow,
        swivel: w.swivel,
        fingertip_priority: p.fingertip_priority,
    }
}

fn json<T: Serialize>(v: &T) -> Result<String, Error> {
    serde_json::to_string(v).map_err(Error::internal)
}

/// Resolves the selection to demonstration ids (request order), each with its request path.
async fn resolve_selection(
    ctx: &Context,
    sel: &SelectionIn,
) -> Result<(Vec<(String, String)>, Option<DemoFilterIn>), Error> {
    match sel {
        SelectionIn::Ids(ids) => {
            if ids.is_empty() {
                return Err(Error::invalid(
                    "$.demonstrations",
                    "select at least one demonstration",
                ));
            }
            if ids.len() > MAX_DEMONSTRATIONS {
                return Err(Error::invalid(
                    "$.demonstrations",
                    format!(
                        "{} demonstrations selected; at most {MAX_DEMONSTRATIONS} per mapping",
                        ids.len()
                    ),
                ));
            }
            let mut errors = Vec::new();
            let mut seen = std::collections::HashSet::new();
            for (i, id) in ids.iter().enumerate() {
                let path = format!("$.demonstrations[{i}]");
                if !seen.insert(id.as_str()) {
                    errors.push(Invalid::new(
                        path,
                        format!("demonstration {id} is listed twice"),
                    ));
                } else if demo_repo::get(&ctx.db, id).await?.is_none() {
                    errors.push(Invalid::new(path, format!("unknown demonstration '{id}'")));
                }
            }
            if !errors.is_empty() {
                return Err(Error::Invalid(errors));
            }
            let out = ids
                .iter()
                .enumerate()
                .map(|(i, id)| (id.clone(), format!("$.demonstrations[{i}]")))
                .collect();
            Ok((out, None))
        }
        SelectionIn::Filter(f) => {
            let selection = DemoSelection {
                subject: f.subject.clone(),
                object: f.object.clone(),
                task: f.task.clone(),
                position_index: f.position.map(i64::from),
                synthetic: f.synthetic,
                job_id: f.job_id.clone(),
            };
            let ids =
                repo::select_demonstrations(&ctx.db, &selection, MAX_DEMONSTRATIONS as i64 + 1)
                    .await?;
            if ids.is_empty() {
                return Err(Error::invalid(
                    "$.demonstrations",
                    "no stored demonstration matches the filter",
                ));
            }
            if ids.len() > MAX_DEMONSTRATIONS {
                return Err(Error::invalid(
                    "$.demonstrations",
                    format!(
                        "the filter matches more than {MAX_DEMONSTRATIONS} demonstrations; \
                         narrow it"
                    ),
                ));
            }
            let out = ids
                .into_iter()
                .map(|id| (id, "$.demonstrations".to_owned()))
                .collect();
            Ok((out, Some(f.clone())))
        }
    }
}

/// Loads and decodes a stored demonstration's labels, frames and object.
async fn load_demo(
    ctx: &Context,
    id: &str,
) -> Result<(DemoLabels, Vec<HumanFrame>, Option<HumanObject>), Error> {
    let row = demo_repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("demonstration", id))?;
    let bytes = demo_repo::frames(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("demonstration", id))?;
    let array = blob::decode::<f64>(&bytes).map_err(|e| Error::internal(anyhow::Error::new(e)))?;
    let (frames, _) = unpack_frames(&array.data)
        .map_err(|e| Error::internal(anyhow::anyhow!("demonstration {id}: {e}")))?;
    let u32_of = |v: i64| {
        u32::try_from(v)
            .map_err(|_| Error::internal(anyhow::anyhow!("demonstration {id}: label {v}")))
    };
    let labels = DemoLabels {
        demonstration_id: row.id.clone(),
        subject_id: row.subject_id.clone(),
        object_name: row.object_name.clone(),
        task: row.task.clone(),
        position_index: u32_of(row.position_index)?,
        trial: u32_of(row.trial)?,
    };
    let object = row.object().ok().map(|o| human_object(&o));
    Ok((labels, frames, object))
}

fn run_job(
    ctx: &JobContext,
    mm: &MappingModel,
    demos: &[PreparedDemo],
    params: &MappingParams,
    mapping: NewMapping,
) -> Result<JobOutput, JobError> {
    // The job runs inside the runner's pool: its threads, shared with the other jobs.
    let threads = crate::parallel::available_threads();
    let progress = |done: usize, total: usize| {
        ctx.progress(
            done as f64 / total.max(1) as f64,
            format!("{done} of {total} demonstrations mapped"),
        );
    };
    let trajectories = match run_mapping(mm, demos, params, threads, &progress, &|| {
        ctx.is_cancelled()
    }) {
        Ok(t) => t,
        Err(RunError::Cancelled) => return Err(JobError::Cancelled),
        Err(e) => return Err(JobError::failed(e)),
    };
    let summary = MappingSummary::of(trajectories.iter().map(|t| t.metrics.as_slice()));
    let summary_json = serde_json::to_string(&summary).map_err(JobError::failed)?;
    let encoded: Vec<NewMappedDemo> = demos
        .iter()
        .zip(&trajectories)
        .map(|(d, t)| {
            let s = serde_json::to_string(&MappingSummary::of([t.metrics.as_slice()]))
                .map_err(JobError::failed)?;
            repo::encode_demo(d.labels.clone(), t, s).map_err(|e| JobError::Internal(e.to_string()))
        })
        .collect::<Result<_, _>>()?;
    let message = format!(
        "{} demonstrations, {} frames mapped ({} unconverged)",
        summary.demonstrations, summary.frames, summary.unconverged_frames
    );
    Ok(JobOutput::persist_with(move |job_id, tx| {
        Box::pin(async move {
            let mapping = NewMapping {
                job_id: job_id.to_string(),
                ..mapping
            };
            repo::store_results(tx, &mapping, &summary_json, &encoded).await?;
            Ok(ResultRef::new("mappings", &mapping.id))
        })
    })
    .with_message(message))
}

/// Validates a mapping request (robot, every demonstration and the registration of each,
/// weights, rate) and submits the mapping job; the mapping is stored at once as pending, its
/// results in the transaction that marks the job succeeded. Returns the job and the mapping id.
pub async fn submit(ctx: &Context, body: &MappingIn) -> Result<(JobRecord, String), Error> {
    let params = parse_params(&body.weights, &body.registration, body.output_rate_hz)?;
    let system = crate::service::robots::robot_field(ctx, &body.robot, "$.robot").await?;
    let (selected, filter) = resolve_selection(ctx, &body.demonstrations).await?;
    let mut loaded = Vec::with_capacity(selected.len());
    for (id, path) in &selected {
        loaded.push((load_demo(ctx, id).await?, path.clone()));
    }
    let (mm, prepared) = tokio::task::spawn_blocking(move || {
        let mm = mapping_model(&system)?;
        let anchor = mm.anchor();
        let mut prepared = Vec::with_capacity(loaded.len());
        let mut errors = Vec::new();
        for ((labels, frames, object), path) in loaded {
            match prepare_demo(labels, frames, object, &params, &anchor, &path) {
                Ok(p) => prepared.push(p),
                Err(e) => errors.push(e),
            }
        }
        if !errors.is_empty() {
            return Err(Error::Invalid(errors));
        }
        Ok((mm, prepared))
    })
    .await
    .map_err(Error::internal)??;

    let request = MappingRequestDto {
        robot: body.robot.clone(),
        demonstrations: selected.into_iter().map(|(id, _)| id).collect(),
        filter,
        weights: weights_dto(&params),
        registration: body.registration.clone(),
        output_rate_hz: params.output_rate_hz,
    };
    let mapping_id = Uuid::new_v4().to_string();
    let new = NewMapping {
        id: mapping_id.clone(),
        job_id: String::new(),
        robot: body.robot.clone(),
        request: json(&request)?,
        created_at: now(),
    };
    let job_new = new.clone();
    let job = ctx
        .jobs
        .submit("mapping", move |job: JobContext| {
            run_job(&job, &mm, &prepared, &params, job_new)
        })
        .await?;
    let row = NewMapping {
        job_id: job.id.to_string(),
        ..new
    };
    if let Err(e) = repo::insert_mapping(&ctx.db, &row).await {
        // Without its row the mapping could not be found; stop the job rather than orphan it.
        let _ = ctx.jobs.cancel(job.id).await;
        return Err(e.into());
    }
    Ok((job, mapping_id))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::human::{StudyConfig, generate_study, ingest};

    fn labels(id: &str) -> DemoLabels {
        DemoLabels {
            demonstration_id: id.into(),
            subject_id: "S1".into(),
            object_name: "ball".into(),
            task: "pick".into(),
            position_index: 0,
            trial: 0,
        }
    }

    fn params() -> MappingParams {
        parse_params(
            &WeightsIn::default(),
            &RegistrationIn::default(),
            Some(30.0),
        )
        .unwrap()
    }

    fn paths(e: &Error) -> Vec<&str> {
        match e {
            Error::Invalid(fields) => fields.iter().map(|f| f.field.as_str()).collect(),
            _ => Vec::new(),
        }
    }

    #[test]
    fn bad_weights_scale_transform_and_rate_name_their_fields() {
        let bad = |w: WeightsIn, r: RegistrationIn, rate: Option<f64>| {
            parse_params(&w, &r, rate).expect_err("should be rejected")
        };
        let e = bad(
            WeightsIn {
                position: Some(-1.0),
                orientation: Some(f64::NAN),
                ..WeightsIn::default()
            },
            RegistrationIn::default(),
            None,
        );
        assert_eq!(paths(&e), ["$.weights.position", "$.weights.orientation"]);
        for k in [0.5, 0.0, -1.0, f64::NAN, f64::INFINITY] {
            let w = WeightsIn {
                fingertip_priority: Some(k),
                ..WeightsIn::default()
            };
            let e = bad(w, RegistrationIn::default(), None);
            assert_eq!(paths(&e), ["$.weights.fingertip_priority"], "{k}");
        }
        let zero = WeightsIn {
            position: Some(0.0),
            orientation: Some(0.0),
            elbow: Some(0.0),
            swivel: Some(0.0),
            fingertip_priority: None,
        };
        assert_eq!(
            paths(&bad(zero, RegistrationIn::default(), None)),
            ["$.weights"]
        );
        for rate in [0.0, -5.0, 501.0, f64::INFINITY] {
            let e = bad(WeightsIn::default(), RegistrationIn::default(), Some(rate));
            assert_eq!(paths(&e), ["$.output_rate_hz"]);
        }
        let reg = RegistrationIn {
            scale: Some(ScaleIn::Named("big".into())),
            ..RegistrationIn::default()
        };
        assert_eq!(
            paths(&bad(WeightsIn::default(), reg, None)),
            ["$.registration.scale"]
        );
        let reg = RegistrationIn {
            scale: Some(ScaleIn::Named("auto".into())),
            transform: Some(TransformIn {
                position: [0.0; 3],
                orientation: [0.0; 4],
            }),
            ..RegistrationIn::default()
        };
        assert_eq!(
            paths(&bad(WeightsIn::default(), reg, None)),
            [
                "$.registration.scale",
                "$.registration.transform.orientation"
            ]
        );
        let reg = RegistrationIn {
            subject_forward: Some([0.0, 0.0, 2.0]),
            ..RegistrationIn::default()
        };
        assert_eq!(
            paths(&bad(WeightsIn::default(), reg, None)),
            ["$.registration.subject_up"]
        );
        // A good explicit transform with a numeric scale passes.
        let reg = RegistrationIn {
            scale: Some(ScaleIn::Factor(1.2)),
            transform: Some(TransformIn {
                position: [0.1, 0.0, 0.0],
                orientation: [1.0, 0.0, 0.0, 0.0],
            }),
            ..RegistrationIn::default()
        };
        let p = parse_params(&WeightsIn::default(), &reg, Some(500.0)).unwrap();
        assert!(matches!(
            p.registration,
            RegistrationSpec::Explicit { scale, .. } if scale == 1.2
        ));
    }

    fn study_frames() -> Vec<HumanFrame> {
        let cfg = StudyConfig {
            subjects: 1,
            positions: 1,
            trials: 1,
            ..StudyConfig::default()
        };
        ingest(&generate_study(&cfg).unwrap()[0]).unwrap().frames
    }

    fn wam() -> System {
        System::from_file(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml"),
        )
        .unwrap()
    }

    #[test]
    fn an_arm_that_cannot_be_registered_is_named_by_its_path() {
        let mut frames = study_frames();
        for f in &mut frames {
            f.elbow = f.shoulder;
        }
        let mm = mapping_model(&wam()).unwrap();
        let e = prepare_demo(
            labels("d7"),
            frames,
            None,
            &params(),
            &mm.anchor(),
            "$.demonstrations[3]",
        )
        .unwrap_err();
        assert_eq!(e.field, "$.demonstrations[3]");
        assert!(
            e.message.contains("d7") && e.message.contains("upper arm"),
            "{}",
            e.message
        );
    }

    /// One bad demonstration fails the whole run and the error names it; cancellation ends the
    /// run without results.
    #[test]
    fn a_failing_demonstration_fails_the_run_and_cancellation_returns_nothing() {
        let sys = wam();
        let mm = mapping_model(&sys).unwrap();
        let p = params();
        let good = prepare_demo(labels("ok"), study_frames(), None, &p, &mm.anchor(), "$").unwrap();
        let mut bad = good.clone();
        bad.labels.demonstration_id = "broken".into();
        let t = bad.frames[1].t;
        bad.frames[2].t = t; // time stops: the mapping layer refuses the frame
        let demos = [good.clone(), bad];
        let err = run_mapping(&mm, &demos, &p, 2, &|_, _| {}, &|| false).unwrap_err();
        match err {
            RunError::Demonstration {
                index,
                ref demonstration,
                ..
            } => assert_eq!((index, demonstration.as_str()), (1, "broken")),
            other => panic!("unexpected {other:?}"),
        }
        assert!(err.to_string().contains("broken"));
        let cancelled = run_mapping(&mm, &[good], &p, 1, &|_, _| {}, &|| true);
        assert!(matches!(cancelled, Err(RunError::Cancelled)));
    }

    #[test]
    fn summaries_average_over_fingers_and_frames() {
        let m = |e: f64, converged: bool| FrameMetrics {
            t: 0.0,
            fingers: 2,
            position_error: [e, 3.0 * e, 99.0, 99.0, 99.0],
            orientation_error: [0.1, 0.3, 9.0, 9.0, 9.0],
            elbow_distance: 0.04,
            elbow_distance_mean: 0.2,
            objective: 2.0,
            iterations: 4,
            converged,
            swivel_human: 0.1,
            swivel_robot: 0.2,
            swivel_difference: e,
            elbow_bound: 0.1,
            support_clearance: e,
            object_clearance: -e,
        };
        let a = [m(0.01, true), m(0.02, false)];
        let b = [m(0.03, true)];
        let s = MappingSummary::of([&a[..], &b[..]]);
        assert_eq!(
            (s.demonstrations, s.frames, s.unconverged_frames),
            (2, 3, 1)
        );
        assert!((s.mean_fingertip_error_m - (0.04 + 0.08 + 0.12) / 6.0).abs() < 1e-15);
        assert!((s.max_fingertip_error_m - 0.09).abs() < 1e-15);
        assert!((s.mean_orientation_error_rad - 0.2).abs() < 1e-15);
        assert!((s.mean_elbow_distance_m - 0.2).abs() < 1e-15);
        assert_eq!(s.mean_iterations, 4.0);
        // Tip errors {0.01, 0.03, 0.02, 0.06, 0.03, 0.09}: nearest-rank median 0.03, p95 0.09.
        assert_eq!(
            (s.median_fingertip_error_m, s.p95_fingertip_error_m),
            (0.03, 0.09)
        );
        assert_eq!(s.median_swivel_difference_rad, Some(0.02));
        assert_eq!(
            (s.min_support_clearance_m, s.min_object_clearance_m),
            (Some(0.01), Some(-0.03))
        );
    }
}
