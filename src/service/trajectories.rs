//! Trajectories: humanlike motions generated from a motion model between a start and a goal
//! (a configuration or a stored grasp), with fingertip and elbow paths, stored.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::models::{
    AutoOr, CertificateDto, JointValues, MAX_DURATION, MAX_RATE, certificate_dto, check_limits,
    group_name, joint_values, loaded_model, region_error,
};
use super::{Context, Error, Invalid, Keyword};
use crate::geometry::avoid::{AvoidOptions, AvoidReport, CurveSample};
use crate::geometry::{Category, GeometryError, ObstacleSpec, SceneShape, ShapeSpec};
use crate::grasp::{
    ApproachOptions, Arrival, GraspResult, HandArm, Object, PathClearance, PreGrasp,
    arrive_from_outside, avoid, optimizer::EXACT_PENETRATION_TOLERANCE, path_clearance,
    posture_collision, pre_grasp, scene_checker, shape_departure, shape_path,
};
use crate::kinematics::{Data, System, forward_kinematics};
use crate::motion::{
    MotionError, MotionModel, Trajectory, TrajectoryOptions, TrajectoryPoint, WorkspaceEntry,
    arrival_progress, clearance_progress, cubic_basis,
};
use crate::store::grasps as grasp_repo;
use crate::store::library::LibraryError;
use crate::store::trajectories::{self, TrajectoryDraft};

pub use crate::store::trajectories::{StoredTrajectory, TrajectorySummaryRow};

/// Why no trajectory was computed.
#[derive(Debug)]
pub enum Rejected {
    /// The goal is none the model can reach with its convergence guarantee (outside its joint
    /// limits or its certified goal region, or no goal of this model): every reason. A plan
    /// whose grasp this is becomes infeasible; the request is not bad.
    Goal(Vec<Invalid>),
    /// Anything else.
    Other(Error),
}

impl Rejected {
    /// A failure while resolving or checking the goal: bad input about the goal is the goal's
    /// rejection, anything else (a store failure) stays what it is.
    fn goal(e: Error) -> Self {
        match e {
            Error::Invalid(reasons) => Rejected::Goal(reasons),
            other => Rejected::Other(other),
        }
    }
}

impl From<Error> for Rejected {
    fn from(e: Error) -> Self {
        Rejected::Other(e)
    }
}

impl From<sqlx::Error> for Rejected {
    fn from(e: sqlx::Error) -> Self {
        Rejected::Other(e.into())
    }
}

impl From<Rejected> for Error {
    fn from(r: Rejected) -> Self {
        match r {
            Rejected::Goal(reasons) => Error::Invalid(reasons),
            Rejected::Other(e) => e,
        }
    }
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
    #[schema(min_length = 1)]
    pub model: String,
    pub start: JointValues,
    pub goal: GoalIn,
    /// `"auto"` (learned from the demonstrations, default) or seconds. Where the humanlike clock
    /// would exceed a joint velocity, acceleration or jerk limit at that duration, the motion
    /// takes the jerk-bounded time-optimal time law along its path, or a blend of it and the
    /// humanlike clock at that duration if the optimum is shorter (`stretched` and `note` when
    /// the optimum is longer).
    pub duration: Option<AutoOr>,
    /// Output rate, Hz, in (0, 1000] (default 100).
    #[schema(exclusive_minimum = 0, maximum = 1000)]
    pub rate: Option<f64>,
    /// Further obstacles in the robot base frame (boxes, cylinders, spheres, capsules, meshes,
    /// each with a pose; at most 32). The trajectory's exact clearance against them is reported
    /// (`report.clearance.obstacle`), after the path was moved to keep a margin from them
    /// (`report.avoidance`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    #[schema(max_items = 32)]
    pub obstacles: Vec<ObstacleSpec>,
    /// Pre-grasp standoff, m, in [0, 0.25] (default 0: none; 0.06 is a typical value). With an
    /// object (a plan's, or a stored grasp goal's) the path then ends with an approach phase:
    /// the palm this far back along the approach direction with the hand opened, then the final
    /// approach along a straight line and the closing (`report.approach`). Absent: none, unless
    /// the path without one collides with the object; then 0.06 is tried and used where it is
    /// collision-free. 0: none at all. Not on every path: measured over 60 seeded plans it made
    /// no more grasps hold in physics and lengthened the motions by about a third (README,
    /// "Approach phase").
    #[schema(minimum = 0, maximum = 0.25)]
    pub approach_standoff: Option<f64>,
}

/// Largest pre-grasp standoff a request may ask for (m).
pub const MAX_STANDOFF: f64 = 0.25;

/// The request's pre-grasp standoff (m; none where absent), or a 422 at `field`.
pub fn approach_standoff(value: Option<f64>, field: &str) -> Result<f64, Error> {
    match value {
        None => Ok(0.0),
        Some(v) if (0.0..=MAX_STANDOFF).contains(&v) => Ok(v),
        Some(v) => Err(Error::invalid(
            field,
            format!("must be in [0, {MAX_STANDOFF}] m, got {v}"),
        )),
    }
}

/// Most obstacles one request may carry.
pub const MAX_OBSTACLES: usize = 32;

/// The request's obstacles, validated and placed; each problem at its own field.
pub fn scene_obstacles(obstacles: &[ObstacleSpec]) -> Result<Vec<SceneShape>, Error> {
    if obstacles.len() > MAX_OBSTACLES {
        return Err(Error::invalid(
            "$.obstacles",
            format!("at most {MAX_OBSTACLES} obstacles, got {}", obstacles.len()),
        ));
    }
    let mut errors = Vec::new();
    let mut shapes = Vec::with_capacity(obstacles.len());
    for (i, spec) in obstacles.iter().enumerate() {
        let prefix = format!("$.obstacles[{i}].");
        if spec.name.is_empty() {
            errors.push(Invalid::new(format!("{prefix}name"), "must not be empty"));
            continue;
        }
        if let Some(k) = spec.position.iter().position(|v| v.abs() > 1000.0) {
            errors.push(Invalid::new(
                format!("{prefix}position[{k}]"),
                format!("must be within ±1000 m, got {}", spec.position[k]),
            ));
            continue;
        }
        // The shape schema is the objects' (each dimension within 2 m across); a larger
        // obstacle is several.
        let too_large = match &spec.shape {
            ShapeSpec::Sphere { radius } => (*radius > 1.0).then_some(("radius", *radius, 1.0)),
            ShapeSpec::Cylinder { radius, height } => (*radius > 1.0)
                .then_some(("radius", *radius, 1.0))
                .or((*height > 2.0).then_some(("height", *height, 2.0))),
            ShapeSpec::Capsule { radius, length } => (*radius > 1.0)
                .then_some(("radius", *radius, 1.0))
                .or((*length > 2.0).then_some(("length", *length, 2.0))),
            ShapeSpec::Box { size } => size
                .iter()
                .position(|&v| v > 2.0)
                .map(|k| (["size[0]", "size[1]", "size[2]"][k], size[k], 2.0)),
            _ => None,
        };
        if let Some((field, value, max)) = too_large {
            errors.push(Invalid::new(
                format!("{prefix}shape.{field}"),
                format!("at most {max} m, got {value}"),
            ));
            continue;
        }
        match SceneShape::from_spec(spec, &prefix) {
            Ok(shape) => shapes.push(shape),
            Err(e) => {
                let (field, message) = match &e {
                    GeometryError::InvalidDimension { field, value } => (
                        field.clone(),
                        format!("must be a positive finite length, got {value}"),
                    ),
                    GeometryError::NonFinite { field } => {
                        (field.clone(), "must be finite and non-zero".to_owned())
                    }
                    _ => (format!("{prefix}shape"), e.to_string()),
                };
                errors.push(Invalid::new(field, message));
            }
        }
    }
    if errors.is_empty() {
        Ok(shapes)
    } else {
        Err(Error::Invalid(errors))
    }
}

/// A path of one frame in Cartesian space (robot base frame, metres), one position per point.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FramePathDto {
    /// Finger name, or the frame name for the elbow.
    pub name: String,
    pub frame: String,
    pub positions: Vec<[f64; 3]>,
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
    /// The duration was lengthened to respect the velocity/acceleration/jerk limits: the motion
    /// takes the jerk-bounded time-optimal time law along its path (every use at most 0.97).
    pub stretched: bool,
    /// The shortest duration along this path under the velocity and acceleration limits alone
    /// (time-optimal bang-bang profile, jerk unbounded): the part of `duration` the limits force.
    /// Absent in trajectories stored before it was reported.
    #[serde(default)]
    pub time_optimal_duration: Option<f64>,
    /// Why the duration differs from the request, when it does.
    pub note: Option<String>,
    pub rate: f64,
    /// Every group's flow reached the goal within tolerance (`γ` decreasing, certified).
    pub converged: bool,
    /// Largest group error (rad), see `errors`.
    pub final_error: f64,
    pub errors: Vec<GroupErrorDto>,
    pub certificates: Vec<CertificateDto>,
    /// Largest fraction of a velocity / acceleration / jerk limit used over the returned points
    /// (≤ 1; finite differences of the points agree).
    pub max_velocity_ratio: f64,
    pub max_acceleration_ratio: f64,
    /// Absent in trajectories stored before jerk was limited.
    #[serde(default)]
    pub max_jerk_ratio: Option<f64>,
    pub fingertip_paths: Vec<FramePathDto>,
    pub elbow_paths: Vec<FramePathDto>,
    /// The grasp the goal came from, if any.
    pub grasp: Option<String>,
    /// The trajectory's exact clearance in its scene: a plan's (or a stored grasp goal's) object
    /// and support plane, and the request's obstacles; every link's collision shape against them
    /// and against the other links, continuous along the path through the points. Absent for a
    /// configuration goal without obstacles. The path was moved away from them first
    /// (`avoidance`); this check of the result is what `collision_free` reports.
    #[serde(default)]
    pub clearance: Option<PathClearance>,
    /// How the humanlike path was moved for clearance before it was timed (absent without a
    /// scene, and in trajectories stored before paths were moved).
    #[serde(default)]
    pub avoidance: Option<AvoidanceDto>,
    /// How the end of the path was turned so that the links touching the object or the support
    /// at the goal arrive from outside (absent without a scene, and in trajectories stored
    /// before it was checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arrival: Option<ArrivalDto>,
    /// The straight approach of a start outside the model's workspace (absent when the start
    /// is inside it, and in trajectories stored before starts outside were planned).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace_entry: Option<WorkspaceEntryDto>,
    /// The approach phase: the pre-grasp the path passes through before the final approach and
    /// the closing, or why the path runs into the grasp directly (absent without an object,
    /// with `approach_standoff: 0`, and in trajectories stored before it was planned).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub approach: Option<ApproachDto>,
    /// The departure from a start at the object (within the approach margin of it: the end of
    /// a previous plan, the hand on the object): the start's own pre-grasp, which the path
    /// reaches first, the hand opening before the arm backs off; or why the path leaves
    /// directly (absent where the start is not at the object).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub departure: Option<ApproachDto>,
}

/// The start is within the approach margin of the object (exact, every link).
fn near_object(sys: &HandArm, object: &Object, start: &[f64]) -> bool {
    let checker = scene_checker(sys, Some(object), &[]);
    let mut data = checker.data();
    checker
        .category_clearance(&mut data, start, &[Category::Object])
        .category_distance(Category::Object)
        < ApproachOptions::default().margin
}

/// A grasp is approached from a pre-grasp: the grasp's palm pose moved back by `standoff_m`
/// along `direction` (robot base frame; the approach direction reversed, lifted off the support
/// where straight back was not clear), reached by the arm alone, with every hand joint opened
/// `open_fraction` of the way towards its open limit. The humanlike path runs to it over the
/// first `1 - share` of the progress (the hand opening on the way); then the arm moves the palm
/// in along the straight line to the grasp (`straight_line`; else along the joint line) with
/// the hand open, and the hand closes last. The clearances are exact
/// (URDF collision shapes) at the pre-grasp. Not in the paper, whose flow ends at the grasp
/// itself; the convergence certificates cover the flow, not this reshaping.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ApproachDto {
    /// The path passes through the pre-grasp (false: `note` says why not, and the path runs
    /// into the grasp directly).
    pub used: bool,
    pub standoff_m: Option<f64>,
    pub direction: Option<[f64; 3]>,
    pub open_fraction: Option<f64>,
    pub share: Option<f64>,
    /// The pre-grasp configuration, in the trajectory's `joint_names` order.
    pub pre_grasp: Option<Vec<f64>>,
    /// Exact clearance at the pre-grasp from the object, the support and the obstacles (m;
    /// absent where there is none).
    pub object_clearance_m: Option<f64>,
    pub support_clearance_m: Option<f64>,
    pub obstacle_clearance_m: Option<f64>,
    /// The arm moves the palm in along the straight line from the pre-grasp (its poses solved
    /// at even steps of the line); false: along the joint line, where the IK jumped branches.
    pub straight_line: Option<bool>,
    pub note: String,
}

impl ApproachDto {
    /// The departure's report: as the approach's, with its own note; `share` is the progress it
    /// takes (less than [`crate::grasp::DEPARTURE_SHARE`] where an approach phase follows).
    fn departure(found: &Result<PreGrasp, String>, share: f64) -> Self {
        let mut dto = ApproachDto::new(found);
        if let Ok(p) = found {
            dto.note = format!(
                "the start is at the object: over the first {:.0} % of the progress the hand opens {:.0} % of the way, then the arm backs the palm off {:.0} mm to the start's pre-grasp, where the humanlike path takes over; not in the paper, and not covered by the convergence certificates",
                100.0 * share,
                100.0 * p.open_fraction,
                1e3 * p.standoff_m
            );
            dto.share = Some(share);
        }
        dto
    }

    fn new(found: &Result<PreGrasp, String>) -> Self {
        let finite = |v: f64| v.is_finite().then_some(v);
        match found {
            Ok(p) => ApproachDto {
                used: true,
                standoff_m: Some(p.standoff_m),
                direction: Some(p.direction),
                open_fraction: Some(p.open_fraction),
                share: Some(p.share),
                pre_grasp: Some(p.q.clone()),
                object_clearance_m: finite(p.object_clearance_m),
                support_clearance_m: finite(p.support_clearance_m),
                obstacle_clearance_m: finite(p.obstacle_clearance_m),
                straight_line: Some(!p.line.is_empty()),
                note: format!(
                    "the humanlike path ends at a pre-grasp {:.0} mm back from the grasp with the hand {:.0} % open; the last {:.0} % of the progress moves the palm in {} and then closes the hand",
                    1e3 * p.standoff_m,
                    100.0 * p.open_fraction,
                    100.0 * p.share,
                    if p.line.is_empty() {
                        "along the joint line (the straight line jumped IK branches)"
                    } else {
                        "along a straight line"
                    }
                ),
            },
            Err(why) => ApproachDto {
                used: false,
                standoff_m: None,
                direction: None,
                open_fraction: None,
                share: None,
                pre_grasp: None,
                object_clearance_m: None,
                support_clearance_m: None,
                obstacle_clearance_m: None,
                straight_line: None,
                note: why.clone(),
            },
        }
    }
}

/// A start outside the model's workspace (the region its demonstrations span, where its
/// convergence certificates hold) enters it along the straight joint line towards the goal:
/// for `joint_distance_rad`, the first `progress` of the clock, until every group is
/// `motion::ENTRY_DEPTH` of its radius inside (or halfway between the goal and the boundary
/// when the goal lies deeper out); the certified humanlike flow runs from `point` on. That
/// first segment is neither humanlike nor covered by the certificates; it is checked for
/// clearance like the rest. Not in the paper, whose flow is only defined inside the workspace.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct WorkspaceEntryDto {
    /// Where the flow starts, in the trajectory's `joint_names` order.
    pub point: Vec<f64>,
    /// Fraction of the straight start-goal joint line the segment covers.
    pub line_fraction: f64,
    pub joint_distance_rad: f64,
    /// Share of the duration's progress (on the minimum-jerk clock) spent on the segment.
    pub progress: f64,
    pub groups: Vec<EntryGroupDto>,
    pub note: String,
}

/// One joint group's workspace as the start saw it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct EntryGroupDto {
    pub group: String,
    /// The start's distance from the workspace centre (PCA coordinates) and the radius.
    pub start_distance: f64,
    pub radius: f64,
}

impl WorkspaceEntryDto {
    fn new(e: &WorkspaceEntry, groups: usize) -> Self {
        let per_group: Vec<EntryGroupDto> = e
            .start_distances
            .iter()
            .zip(&e.radii)
            .enumerate()
            .map(|(g, (&start_distance, &radius))| EntryGroupDto {
                group: group_name(groups, g),
                start_distance,
                radius,
            })
            .collect();
        let outside: Vec<String> = per_group
            .iter()
            .filter(|g| g.start_distance >= g.radius)
            .map(|g| {
                format!(
                    "{} joints {:.3} from its centre, radius {:.3}",
                    g.group, g.start_distance, g.radius
                )
            })
            .collect();
        WorkspaceEntryDto {
            point: e.point.clone(),
            line_fraction: e.line_fraction,
            joint_distance_rad: e.joint_distance,
            progress: e.progress,
            groups: per_group,
            note: format!(
                "the start is outside the model's workspace ({}): the motion first follows the straight joint line towards the goal for {:.3} rad (the first {:.0} % of its progress), which is not humanlike and not covered by the certificates; the certified flow runs from there",
                outside.join("; "),
                e.joint_distance,
                100.0 * e.progress
            ),
        }
    }
}

/// The clearance refinement of a path (`geometry::avoid`): its control configurations were
/// moved, the least amount to first order, until each kept `margin_m` from the object, the
/// support and obstacles (`self_margin_m` between links), the targets ramping to each end's own
/// clearance over the last `ramp` of the progress (the grasp's contacts end the motion).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct AvoidanceDto {
    pub margin_m: f64,
    pub self_margin_m: f64,
    pub ramp: f64,
    /// Rounds run (0: the humanlike path kept every margin as it was), of at most `max_rounds`.
    pub rounds: usize,
    pub max_rounds: usize,
    /// Points of the path below target before and after (of 337: `motion::clearance_progress`).
    pub below_target_before: usize,
    pub below_target_after: usize,
    /// Largest joint displacement from the humanlike path (rad).
    pub max_displacement_rad: f64,
    /// Smallest clearance minus target over the path points, before and after (m; 0 when every
    /// target is kept).
    pub worst_before_m: f64,
    pub worst_after_m: f64,
}

impl AvoidanceDto {
    fn new(a: &AvoidReport) -> Self {
        let o = AvoidOptions::default();
        AvoidanceDto {
            margin_m: o.margin,
            self_margin_m: o.self_margin,
            ramp: o.ramp,
            rounds: a.rounds,
            max_rounds: o.rounds,
            below_target_before: a.below_target,
            below_target_after: a.still_below,
            max_displacement_rad: a.max_displacement,
            worst_before_m: a.worst_before,
            worst_after_m: a.worst_after,
        }
    }
}

/// The end of the path as it meets the grasp (`grasp::clearance::arrive_from_outside`; not in
/// the paper, whose flow ends along its own slowest direction): links within 5 mm of the object
/// or the support at the goal should arrive from outside it, the path's end tangent meeting
/// each pair's exact distance gradient at a cosine of at least 0.1. `from_inside` of them did
/// not (the tangent pointed out of the surface, or along it: such a link crosses the surface
/// and comes back); then the tangent was turned the least amount that makes them all approach,
/// carried back over the final configurations, and kept where that lessened how much deeper than
/// the goal itself the final tenth of the progress takes any link into the object or the
/// support (`overshoot_before_m`, `overshoot_after_m`; exact distances).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ArrivalDto {
    pub from_inside: usize,
    pub overshoot_before_m: f64,
    pub overshoot_after_m: f64,
    /// Largest joint change of a configuration of the path (rad; 0: the path was kept).
    pub max_change_rad: f64,
}

impl ArrivalDto {
    fn new(a: &Arrival) -> Self {
        ArrivalDto {
            from_inside: a.from_inside,
            overshoot_before_m: a.overshoot_before,
            overshoot_after_m: a.overshoot_after,
            max_change_rad: a.change,
        }
    }
}

/// The path spline of `count` control configurations at progress values `xs`, as the clearance
/// code takes it (which configurations make each point, and their weights).
fn curve_samples(count: usize, xs: &[f64]) -> Vec<CurveSample> {
    cubic_basis(count, xs)
        .into_iter()
        .map(|(x, first, w)| CurveSample { x, first, w })
        .collect()
}

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
            "the requested duration {r} s would exceed the joint velocity/acceleration/jerk limits; the motion takes the jerk-bounded time-optimal {:.4} s (velocity and acceleration alone allow at best {:.4} s)",
            t.duration, t.time_optimal_duration
        ),
        None => format!(
            "the learned duration {:.4} s would exceed the joint velocity/acceleration/jerk limits; the motion takes the jerk-bounded time-optimal {:.4} s (velocity and acceleration alone allow at best {:.4} s)",
            t.learned_duration, t.duration, t.time_optimal_duration
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
        time_optimal_duration: Some(t.time_optimal_duration),
        max_velocity_ratio: t.max_velocity_ratio,
        max_acceleration_ratio: t.max_acceleration_ratio,
        max_jerk_ratio: Some(t.max_jerk_ratio),
        fingertip_paths,
        elbow_paths,
        grasp,
        clearance: None,
        avoidance: None,
        arrival: None,
        approach: None,
        departure: None,
        workspace_entry: t.entry.as_ref().map(|e| WorkspaceEntryDto::new(e, ng)),
    }
}

/// The goal configuration (model order) and the grasp it came from.
async fn resolve_goal(
    ctx: &Context,
    system: &System,
    robot: &str,
    goal: &GoalIn,
) -> Result<(Vec<f64>, Option<Vec<String>>, Option<String>), Error> {
    match (&goal.grasp, &goal.joint_names, &goal.positions) {
        (Some(id), None, None) => {
            let row = grasp_repo::get_grasp(&ctx.db, id)
                .await?
                .ok_or_else(|| Error::invalid("$.goal.grasp", format!("unknown grasp '{id}'")))?;
            if row.robot != robot {
                return Err(Error::invalid(
                    "$.goal.grasp",
                    format!(
                        "grasp '{id}' was computed for robot '{}', the model is of '{robot}'",
                        row.robot
                    ),
                ));
            }
            let result = GraspResult::from_stored(&row.result).map_err(Error::internal)?;
            if !result.feasible {
                return Err(Error::invalid(
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
        _ => Err(Error::invalid(
            "$.goal",
            "give either joint_names and positions, or grasp (a grasp id)",
        )),
    }
}

/// Checks that `model` is trained and that `start` is a valid configuration for it (names,
/// finite values, joint limits) before a caller does expensive work; returns the model's robot
/// and the start in model order.
pub async fn check_start(
    ctx: &Context,
    model: &str,
    start: &JointValues,
) -> Result<(String, Vec<f64>), Error> {
    let l = loaded_model(ctx, model, Some("$.model")).await?;
    let system = super::robots::system(ctx, &l.robot).await?;
    let q = joint_values(&system, start, "$.start")?;
    check_limits(&l.model, &l.names, &q, Some(&start.joint_names), "$.start")?;
    Ok((l.robot.clone(), q))
}

/// A start configuration (model order) that already collides, with itself, the object, its
/// support or an obstacle, is a 422 at `$.start` naming the pair: no motion from there is safe.
/// Contact within the grasp's tolerance (a hand still on what it grasped) is allowed.
pub(super) fn start_clear(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    start: &[f64],
) -> Result<(), Error> {
    match posture_collision(sys, object, obstacles, start) {
        None => Ok(()),
        Some(c) => {
            let other = match c.category {
                Category::Object => format!("the object '{}'", c.other),
                Category::Support => "the support plane".to_owned(),
                Category::Obstacle => format!("obstacle '{}'", c.other),
                Category::SelfCollision => format!("link '{}'", c.other),
            };
            Err(Error::invalid(
                "$.start",
                format!(
                    "the start configuration collides: link '{}' is {:.1} mm inside {other} \
                     (contact up to {:.1} mm is allowed); start from a configuration clear of the \
                     scene",
                    c.link,
                    1e3 * c.depth_m,
                    1e3 * EXACT_PENETRATION_TOLERANCE
                ),
            ))
        }
    }
}

/// Stored trajectories without their points, newest first, optionally of one model; with how
/// many match without the page.
pub async fn list(
    ctx: &Context,
    model: Option<&str>,
    limit: u32,
    offset: u32,
) -> Result<(Vec<TrajectorySummaryRow>, i64), Error> {
    Ok(trajectories::list_trajectories(&ctx.db, model, limit, offset).await?)
}

/// Stored trajectory `id`.
pub async fn get(ctx: &Context, id: &str) -> Result<trajectories::StoredTrajectory, Error> {
    trajectories::get_trajectory(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("trajectory", id))
}

/// Generates and stores one trajectory (`POST /v1/trajectories`).
pub async fn create(
    ctx: &Context,
    body: &CreateTrajectory,
) -> Result<trajectories::StoredTrajectory, Error> {
    let (c, b) = (ctx.clone(), body.clone());
    let (draft, _) = ctx
        .compute
        .run(async move { compute(&c, &b, None).await })
        .await??;
    Ok(trajectories::insert_trajectory(&ctx.db, &draft.as_new()).await?)
}

/// Generates one trajectory, not yet stored (shared with `/v1/plans`, which stores it with its
/// grasp).
/// With a grasp's `scene` (a plan's, or the stored grasp's when the goal is one), the
/// trajectory's exact clearance in it is reported, and returned beside it.
/// A start outside the model's workspace enters it along the joint line
/// (`WorkspaceEntryDto`); a closed-loop law runs that segment too, along the path.
pub async fn compute(
    ctx: &Context,
    body: &CreateTrajectory,
    scene: Option<super::grasps::GraspScene>,
) -> Result<(TrajectoryDraft, Option<PathClearance>), Rejected> {
    let requested = match &body.duration {
        None => None,
        Some(AutoOr::Auto(s)) if Keyword::parse(s) == Some(Keyword::Auto) => None,
        Some(AutoOr::Value(t)) if *t > 0.0 && *t <= MAX_DURATION => Some(*t),
        Some(other) => {
            return Err(Error::invalid(
                "$.duration",
                format!("must be \"auto\" or seconds in (0, {MAX_DURATION}], got {other:?}"),
            )
            .into());
        }
    };
    let rate = body.rate.unwrap_or(100.0);
    if !(rate > 0.0 && rate <= MAX_RATE) {
        return Err(Error::invalid(
            "$.rate",
            format!("must be in (0, {MAX_RATE}] Hz, got {rate}"),
        )
        .into());
    }
    let obstacles = scene_obstacles(&body.obstacles)?;
    let standoff = approach_standoff(body.approach_standoff, "$.approach_standoff")?;
    let requested_standoff = body.approach_standoff;
    let l = loaded_model(ctx, &body.model, Some("$.model")).await?;
    let system = match ctx.robots.system(&l.robot).await {
        Err(LibraryError::UnknownRobot(_)) => {
            return Err(Error::Conflict(format!(
                "the model's robot '{}' no longer exists",
                l.robot
            ))
            .into());
        }
        other => other.map_err(Error::from)?,
    };
    let start = joint_values(&system, &body.start, "$.start")?;
    let (goal, goal_names, grasp) = resolve_goal(ctx, &system, &l.robot, &body.goal)
        .await
        .map_err(Rejected::goal)?;
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
        .map_err(Rejected::goal)?;
    // A goal that is a stored grasp brings its scene (a plan passes the one it just computed,
    // and has checked its start in it already).
    let checked = scene.is_some();
    let scene = match (scene, &grasp) {
        (Some(s), _) => Some(s),
        (None, Some(id)) => super::grasps::stored_scene(ctx, id).await?,
        (None, None) if !obstacles.is_empty() => Some(super::grasps::GraspScene {
            sys: super::grasps::robot_view(ctx, &l.robot).await?,
            object: None,
        }),
        (None, None) => None,
    };
    match &scene {
        _ if checked => {}
        Some(sc) => start_clear(&sc.sys, sc.object.as_ref(), &obstacles, &start)?,
        None => start_clear(
            &*super::grasps::robot_view(ctx, &l.robot).await?,
            None,
            &[],
            &start,
        )?,
    }
    let opts = TrajectoryOptions {
        duration: requested,
        rate,
        enter_workspace: true,
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
            let run = |standoff: f64| {
                // With an object, the path ends with the approach phase; in a scene, the humanlike
                // path is then moved the least amount needed for a clearance margin before it is
                // timed.
                let mut avoidance = None;
                let mut arrival = None;
                let mut approach = None;
                let mut departure = None;
                // Progress the departure takes, if there is one (the avoidance holds its targets
                // at the start's clearance over it).
                let mut hold = 0.0;
                let traj = l
                    .model
                    .trajectory_with(&start, &goal, &opts, |path, xs| {
                        if let Some(sc) = &scene {
                            // A start at the object (the end of a previous plan, holding it)
                            // first leaves it: the hand opens, then the arm backs off.
                            if let Some(object) = sc
                                .object
                                .as_ref()
                                .filter(|o| near_object(&sc.sys, o, &start))
                            {
                                let opts = ApproachOptions {
                                    standoff: standoff
                                        .max(crate::grasp::approach::DEFAULT_STANDOFF),
                                    ..ApproachOptions::default()
                                };
                                let found =
                                    pre_grasp(&sc.sys, Some(object), &obstacles, &start, &opts);
                                if let Ok(dep) = &found {
                                    shape_departure(path, xs, sc.sys.model.nq(), &sc.sys, dep);
                                    hold = crate::grasp::DEPARTURE_SHARE;
                                }
                                departure = Some(found);
                            }
                            if let Some(object) = sc.object.as_ref().filter(|_| standoff > 0.0) {
                                let opts = ApproachOptions {
                                    standoff,
                                    ..ApproachOptions::default()
                                };
                                let found =
                                    pre_grasp(&sc.sys, Some(object), &obstacles, &goal, &opts);
                                if let Ok(pre) = &found {
                                    // (the departure, if any, is compressed with the rest)
                                    hold *= shape_path(path, xs, sc.sys.model.nq(), &sc.sys, pre);
                                }
                                approach = Some(found);
                            }
                            let curve = curve_samples(xs.len(), &clearance_progress());
                            avoidance = Some(avoid(
                                &sc.sys,
                                sc.object.as_ref(),
                                &obstacles,
                                path,
                                &curve,
                                hold,
                            ));
                            // The links in contact at the goal arrive from outside (no pad
                            // crossing the surface and coming back on the final approach).
                            let end = curve_samples(xs.len(), &arrival_progress());
                            arrival = Some(arrive_from_outside(
                                &sc.sys,
                                sc.object.as_ref(),
                                &obstacles,
                                path,
                                &end,
                            ));
                        }
                    })
                    .map_err(|e| {
                        let outside = matches!(e, MotionError::GoalOutsideRegion { .. });
                        let e = region_error(e, l.model.manifolds.len(), "$.start", goal_base);
                        if outside {
                            Rejected::goal(e)
                        } else {
                            Rejected::Other(e)
                        }
                    })?;
                let mut report =
                    trajectory_report(&system, &l.model, &traj, requested, rate, grasp.clone());
                report.avoidance = avoidance.map(|a| AvoidanceDto::new(&a));
                report.arrival = arrival.as_ref().map(ArrivalDto::new);
                report.approach = approach.as_ref().map(ApproachDto::new);
                report.departure = departure.as_ref().map(|d| ApproachDto::departure(d, hold));
                report.clearance = scene.as_ref().map(|sc| {
                    let points: Vec<f64> = traj
                        .points
                        .iter()
                        .flat_map(|p| p.positions.iter().copied())
                        .collect();
                    let times: Vec<f64> = traj.points.iter().map(|p| p.t).collect();
                    path_clearance(&sc.sys, sc.object.as_ref(), &obstacles, &points, &times)
                });
                Ok::<_, Rejected>((traj, report))
            };
            let (traj, report) = run(standoff)?;
            // A direct path that meets the object (a finger swept across it on the way in) is
            // tried again with the default approach phase when the request left the standoff
            // to us, and replaced where that one is collision-free. Not by default for every
            // plan: the approach phase lengthens the motion by about a third (README).
            let collides =
                |r: &TrajectoryReportDto| r.clearance.as_ref().is_some_and(|c| !c.collision_free);
            let has_object = scene.as_ref().is_some_and(|sc| sc.object.is_some());
            if collides(&report) && has_object && requested_standoff.is_none() {
                let (t2, mut r2) = run(crate::grasp::approach::DEFAULT_STANDOFF)?;
                if !collides(&r2) {
                    if let Some(a) = r2.approach.as_mut() {
                        let why = report
                            .clearance
                            .as_ref()
                            .and_then(|c| c.collision())
                            .map(|(h, pressed)| {
                                format!(
                                    "'{}' {:.1} mm {} '{}' at t = {:.2} s",
                                    h.link,
                                    -1e3 * h.distance_m,
                                    if pressed { "pressing into" } else { "inside" },
                                    h.other,
                                    h.time_s
                                )
                            })
                            .unwrap_or_default();
                        a.note = format!(
                            "{}; added because the path without an approach phase collided ({why})",
                            a.note
                        );
                    }
                    return Ok((t2, r2));
                }
            }
            Ok::<_, Rejected>((traj, report))
        })
        .await
        .map_err(Error::internal)??
    };
    let request = serde_json::to_string(&body).map_err(Error::internal)?;
    let summary = serde_json::to_string(&report).map_err(Error::internal)?;
    let clearance = report.clearance.clone();
    Ok((
        TrajectoryDraft {
            model_id: Some(body.model.clone()),
            robot: l.robot.clone(),
            joint_names: l.names.clone(),
            points: traj.points,
            start,
            goal,
            duration: traj.duration,
            request,
            summary,
        },
        clearance,
    ))
}
