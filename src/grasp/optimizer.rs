//! The task-specific grasp problem (eq. 22-29), solved through [`crate::optim`].
//!
//! Decision variables `u = [q_arm, q_hand]` (eq. 23, independent joints: couplings (26) are
//! exact by substitution because mimic joints are folded into their drivers by the model).
//! Cost (eq. 22) `w_TC·TC + w_GC·GC + w_Q·Q̂ + w_D·D` with `Q̂` the chosen quality measure made
//! dimensionless by the object's bounding radius ρ (`Q_DC/ρ`, or `−Q_AGP/ρ²` since the area is
//! maximised). Constraints: joint limits (25) as bounds; fingertip contact spheres tangent to
//! the surface (27) as equalities `sd(p_i) − r_i = 0`; spread ordering (28), link spheres
//! outside the object and a conservative cover of the links above the support plane (29) as
//! inequalities (the cover's lowest point is at or below the shapes' own: box corners, ball
//! centres, cylinder rim samples with the rim's largest dip between samples; it replaced the
//! inscribed spheres against the table, which let phalanx corners 5 mm under it: with the
//! cover 89 of 180 seeded requests are exactly feasible at 4 starts, 78 without); and fingertip contact
//! spheres of different fingers disjoint, `r_i + r_j + δ − ‖c_i − c_j‖ ≤ 0`, and likewise every
//! link sphere of a finger (beyond its first link) and every link or contact sphere of another
//! ([`super::system::LinkPair`]). The paper has no such rows, but without them nothing keeps
//! fingers apart: 70 of the 90 seeded grasps had two fingers' links overlapping by 1-17 mm (the
//! T42's fingers crossed each other around the ball), and under GC the optimiser put two
//! of them on the same spot, where the grasp matrix turns rank-deficient, its pseudo-inverse
//! blows up and the hand's "velocity ratio" reaches 20-135 m/s per rad/s — an artefact of the
//! numerics, not a grasp.
//!
//! `feasible` is decided on the real geometry ([`ExactCheck`], issue 23): the optimiser works
//! on the sphere model above plus a soft pad-cone penalty (each pad normal within 45° of the
//! inward surface normal at its contact sphere) and contact-sphere rows against the support;
//! each start's answer then goes through a deterministic contact repair (`repair`: palm and
//! fingers backed out of the object and the table along the exact penetration normal, each
//! finger moved along its flexion coordinate onto the object), and is judged by parry signed
//! distances ([`crate::geometry::CollisionChecker`]) between every link's URDF collision shape
//! and the object, the support half-space and every non-adjacent link of the system: penetration
//! ≤ 1 mm, no two links intersecting, each pad (the links carrying its tip) within 1 mm of the
//! surface and within [`PAD_CONE_DEG`] of the contact normal, spread order (eq. 28). The best
//! start is the exact-feasible one of lowest eq. 22 cost at its repaired posture, where every
//! term, contact and residual is reported. The sphere model alone was not conservative: 0 of 90
//! seeded grasps passed the exact check when it decided `feasible`.
//!
//! Starts run in rounds: the request's `starts`, then, while none is exactly feasible and firm
//! (its contact normals able to balance, [`FIRM_BALANCE`]), rounds that double the starts run,
//! up to `max_starts` (default [`DEFAULT_MAX_STARTS`]); the answer is the firm feasible start of
//! lowest cost, else the feasible one of lowest cost. On the
//! seeded-object survey (six systems x five objects x {force, velocity} x {x, y, z}, objects at
//! (0.5, 0) on the table) this raised the exactly feasible requests from 89/180 at 4 starts to
//! 141/180 at 16 and 145/180 at 32; 29 of the 35 left are the pencil lying on the table (pads
//! more than 60° off the contact normal: the fingertips poke it or touch it with their sides).
//! Firm feasible requests keep their time (the first round answers); an infeasible one, or one
//! whose feasible starts are not firm, costs up to 16x the first round (and the fewer-finger
//! searches below when none is feasible). A round without a
//! feasible start first polishes its least infeasible start on the exact geometry
//! (`Eval::polish` in `repair`: a bounded pattern search over the palm pose, every candidate
//! placed by the contact repair and judged by the verdict) before the next round: the optimiser's contact spheres cannot see a fingertip's end edge or a link
//! grazing another, the verdict can (on the pencil and sunglasses, issue 23: 42 of 72 requests
//! feasible with it at the escalated starts, 37 without).
//!
//! Fewer fingers: when no start with every finger on the object passes, the same search runs
//! with one finger fewer, then two, down to two (`fewer_fingers`), the others idle (kept out of
//! the object and off the table, reported in [`GraspResult::idle_fingers`]). Not in the paper,
//! whose eq. 27 puts every fingertip on the object; on the survey above it makes every pencil
//! request feasible (159 -> 180 of 180: the iHY pinches it with two fingers, the OB4F with two
//! or three), and no request that was feasible changes its answer.
//!
//! Determinism: every start is budgeted in solver iterations (never wall time) and seeded from
//! its index alone; starts run on any number of threads and are sorted by index before the best
//! is chosen, so the same request gives a bit-identical answer on an idle and on a loaded machine.
//! A per-start wall-clock limit remains only as a safety net and is reported as `timed_out`.
//!
//! In the cost the quality measures are evaluated on the contact-sphere centres, i.e. on the
//! object's surface offset by the sphere radius, where (27) keeps them; this keeps their
//! gradients exact. The reported Q values use the contact points on the surface itself.

use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{
    Isometry3, Matrix3, Matrix3xX, Matrix6, Matrix6xX, Point3, Rotation3, UnitQuaternion, Vector3,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::geometry::{
    Category, CheckData, Clearance, CollisionChecker, Plane, Scene, SceneShape, SignedDistance,
};
use crate::kinematics::{
    Data, IkOptions, IkPosture, IkSolver, IkTarget, add_point_jacobian_transpose,
    forward_kinematics, frame_jacobian,
};
use crate::optim::{Constraints, Problem, Settings, SolveReport, SolveStatus, Solver};

use super::GraspError;
use super::indexes::{self, Ellipsoids, TaskDirection};
use super::objects::{Object, SurfaceQuery};
use super::system::{HandArm, LinkPair};

/// Fingertip surface-distance tolerance for a feasible grasp (m).
pub const SURFACE_TOLERANCE: f64 = 1e-3;
/// Largest accepted penetration of a link sphere into the object or support plane (m).
pub const PENETRATION_TOLERANCE: f64 = 5e-4;
/// Largest exact penetration of any link's collision shape into the object or the support for
/// the exact check to pass (m). The fingertip pads touch the object, so their links may press
/// this much.
pub const EXACT_PENETRATION_TOLERANCE: f64 = 1e-3;
/// Largest angle between a finger's pad normal and the object's inward surface normal at its
/// contact for a feasible grasp (deg). At 60° at least half of the pad's closing motion
/// (cos 60°) presses into the object, and the contact lies on the palmar face or the palmar
/// half of the finger's edge; beyond it the finger touches with its side or back, and closing
/// the hand pushes the object away instead of holding it.
pub const PAD_CONE_DEG: f64 = 60.0;
/// The pad cone the optimiser steers towards (deg): inside [`PAD_CONE_DEG`], so that the contact
/// repair's flexion moves (which turn the pad) leave the contact within the verdict's cone. A
/// soft penalty `PAD_WEIGHT · Σ max(0, cos 45° + n_pad · n_out)²` in the cost, not a constraint
/// row: as rows (hard), no start converged (the seeds put the fingertips inside the object,
/// where the surface normal flips), 0 of 120 requests feasible.
const PAD_CONE_OPT_DEG: f64 = 45.0;
const PAD_WEIGHT: f64 = 5.0;
/// Largest opposition `d` of the contact normals ([`indexes::normal_balance`], the distance from
/// the origin to their convex hull) for a feasible start to count as firm. Not in the paper,
/// whose eq. 22 has nothing that makes the contacts oppose each other; the objective is left as
/// the paper has it and `d` only ranks the exactly feasible starts: a firm one is preferred to a
/// cheaper one that is not, and while no start is firm the start rounds go on as for an
/// infeasible request. A grip with friction coefficient μ cannot balance its contact forces at
/// all when `d > sin(atan μ)` (0.51 for the worker's 0.6), and closing the hand presses
/// unevenly well before that: in the physics survey of 51 feasible grasps before this rule
/// (`workers/mujoco/survey.py grasps`) 28 of the 34 with `d < 0.12` held their object, 1 of the
/// 9 with `0.12 ≤ d < 0.45` and none of the 8 above; the rest were squeezed out of the closing
/// hand. With the rule 40 of 51 held (0.45 instead of 0.12: 34).
pub const FIRM_BALANCE: f64 = 0.12;
/// Default cap of the start rounds ([`GraspRequest::max_starts`]): an infeasible request costs
/// up to this many starts (16x the default first round) before it answers infeasible. 64
/// rather than 32 (2026-12-07) because a plan's grasp must also lie in the model's goal region,
/// where firm grasps are rarer: the wam_t42 and pa10_t42 pencil plans found only grasps that
/// were not firm (or none) in 32 starts and firm ones in 64, which took the MuJoCo plans survey
/// from 44 to 47 of 60 held (59 to 60 of 60 feasible). Requests firm within 32 starts keep their
/// answers.
pub const DEFAULT_MAX_STARTS: usize = 64;

/// Safety net only: wall time after which a start stops (reported as `timed_out`). The
/// iteration budget ends every start long before it on a working machine.
const START_WALL_LIMIT: Duration = Duration::from_secs(5);
/// Clearance `δ` the optimiser keeps between the contact spheres of two fingers (m). A feasible
/// grasp may eat up to half of it, so contact spheres never overlap.
pub const FINGER_CLEARANCE: f64 = 1e-3;

/// The grasp quality measure of eq. 20-21.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum QualityMeasure {
    /// `Q_DC` (eq. 20), minimised.
    CentroidDistance,
    /// `Q_AGP` (eq. 21), maximised; needs three or more fingers.
    PolygonArea,
}

impl QualityMeasure {
    /// Fingers needed for the measure to be meaningful.
    pub fn min_fingers(self) -> usize {
        match self {
            QualityMeasure::CentroidDistance => 2,
            QualityMeasure::PolygonArea => 3,
        }
    }

    fn name(self) -> &'static str {
        match self {
            QualityMeasure::CentroidDistance => "centroid_distance",
            QualityMeasure::PolygonArea => "polygon_area",
        }
    }
}

/// Weights of eq. 22.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default)]
pub struct Weights {
    /// Task compatibility of the arm.
    pub tc: f64,
    /// Grasp compatibility of the hand.
    pub gc: f64,
    /// Grasp quality.
    pub q: f64,
    /// Anthropomorphism (elbow distance to the human reference).
    pub d: f64,
}

impl Default for Weights {
    fn default() -> Self {
        Weights {
            tc: 1.0,
            gc: 0.0,
            q: 1.0,
            d: 1.0,
        }
    }
}

/// A motion model's certified goal region for one group of joints: a ball in the group's PCA
/// coordinates, `‖Wᵀ(q_g − μ) − c‖ ≤ radius`. A grasp for a plan must end inside it, or the
/// model cannot take the arm there with its convergence guarantee.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalRegion {
    /// Name of the group (`arm`, `hand`), for the infeasibility reason.
    pub name: String,
    /// `q` indices (system order) of the group's joints.
    pub joints: Vec<usize>,
    /// PCA mean per joint.
    pub mean: Vec<f64>,
    /// PCA components, row-major `joints × centre.len()`.
    pub components: Vec<f64>,
    pub center: Vec<f64>,
    pub radius: f64,
}

/// A grasp's goal region rows keep it this fraction of the radius inside: the contact repair
/// after the optimiser moves the arm (measured up to 0.05 rad on the test arm), and the
/// repaired grasp must still be inside the model's region.
pub const GOAL_REGION_MARGIN: f64 = 0.8;

impl GoalRegion {
    /// The joint values at the region's centre, `μ + W c`, in the order of `joints`.
    pub fn centre(&self) -> Vec<f64> {
        let d = self.center.len();
        (0..self.joints.len())
            .map(|g| {
                self.mean[g]
                    + (0..d)
                        .map(|i| self.components[g * d + i] * self.center[i])
                        .sum::<f64>()
            })
            .collect()
    }

    /// The distance of `q`'s projection from the centre; `diff` receives `y − c` (its first
    /// `center.len()` entries), from which the row's gradient follows.
    fn distance(&self, q: &[f64], diff: &mut [f64]) -> f64 {
        let d = self.center.len();
        for (i, di) in diff.iter_mut().enumerate().take(d) {
            let mut y = 0.0;
            for (g, &j) in self.joints.iter().enumerate() {
                y += self.components[g * d + i] * (q[j] - self.mean[g]);
            }
            *di = y - self.center[i];
        }
        diff[..d].iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    fn check(&self, nq: usize) -> bool {
        let (n, d) = (self.joints.len(), self.center.len());
        n > 0
            && d > 0
            && self.mean.len() == n
            && self.components.len() == n * d
            && self.joints.iter().all(|&j| j < nq)
            && self.radius.is_finite()
            && self.radius > 0.0
            && self
                .mean
                .iter()
                .chain(&self.components)
                .chain(&self.center)
                .all(|x| x.is_finite())
    }
}

/// One grasp request.
#[derive(Debug, Clone)]
pub struct GraspRequest {
    /// The object (pose included).
    pub object: Object,
    /// Task directions (world frame, unit), used by TC and GC.
    pub task: Vec<TaskDirection>,
    /// Quality measure.
    pub quality: QualityMeasure,
    /// Weights of eq. 22.
    pub weights: Weights,
    /// Number of starts of the multi-start search (its first round).
    pub starts: usize,
    /// While no start is exactly feasible, further rounds double the starts run, up to this
    /// many in all (at least `starts`). Measured on the seeded-object survey (issue 23): 89 of 180
    /// requests exactly feasible at 4 starts, 111 at 8, 141 at 16.
    pub max_starts: usize,
    /// Seed of the start perturbations.
    pub seed: u64,
    /// Human elbow reference for D (world); D is 0 without it.
    pub elbow_reference: Option<Point3<f64>>,
    /// Worker threads for the starts.
    pub threads: usize,
    /// A configuration (`q` of the system) every start begins from instead of mid-range: the
    /// arm joints seed its inverse kinematics, the hand joints its preshape (where the fingers
    /// do not cross). A plan passes its motion model's goal-region centre, so the grasp lands
    /// on the arm branch and near the hand posture the demonstrations end on.
    pub arm_seed: Option<Vec<f64>>,
    /// Goal regions the grasp's configuration must lie in (a plan's motion model's), as
    /// inequality rows of the optimisation (paper: not part of eq. 22-29; issue 23 item 5).
    pub goal_regions: Vec<GoalRegion>,
}

impl GraspRequest {
    /// A request with default weights, 4 starts, seed 0, 2 threads.
    pub fn new(object: Object, task: Vec<TaskDirection>, quality: QualityMeasure) -> Self {
        GraspRequest {
            object,
            task,
            quality,
            weights: Weights::default(),
            starts: 4,
            max_starts: DEFAULT_MAX_STARTS,
            seed: 0,
            elbow_reference: None,
            threads: 2,
            arm_seed: None,
            goal_regions: Vec::new(),
        }
    }

    /// Reject what the numerics must never see, naming the field.
    pub fn validate(&self, sys: &HandArm) -> Result<(), GraspError> {
        for (index, t) in self.task.iter().enumerate() {
            let n = t.direction.norm();
            if !n.is_finite() || n < 1e-9 {
                return Err(GraspError::InvalidDirection { index });
            }
        }
        for (field, value) in [
            ("tc", self.weights.tc),
            ("gc", self.weights.gc),
            ("q", self.weights.q),
            ("d", self.weights.d),
        ] {
            if !value.is_finite() || value < 0.0 {
                return Err(GraspError::InvalidWeight { field, value });
            }
        }
        if sys.fingers.len() < self.quality.min_fingers() {
            return Err(GraspError::UnusableQuality {
                measure: self.quality.name(),
                needed: self.quality.min_fingers(),
                fingers: sys.fingers.len(),
            });
        }
        let nq = sys.model.nq();
        if let Some(q) = &self.arm_seed
            && (q.len() != nq || !q.iter().all(|x| x.is_finite()))
        {
            return Err(GraspError::InvalidParameter {
                field: "arm_seed",
                reason: format!("must be {nq} finite joint values, got {}", q.len()),
            });
        }
        if let Some(g) = self.goal_regions.iter().find(|g| !g.check(nq)) {
            return Err(GraspError::InvalidParameter {
                field: "goal_regions",
                reason: format!(
                    "the '{}' goal region is malformed (joints, mean, components, centre and a \
                     positive radius must agree)",
                    g.name
                ),
            });
        }
        if self.starts == 0 || self.starts > 64 {
            return Err(GraspError::InvalidParameter {
                field: "starts",
                reason: format!("must be between 1 and 64, got {}", self.starts),
            });
        }
        if self.max_starts > 64 {
            return Err(GraspError::InvalidParameter {
                field: "max_starts",
                reason: format!("must be at most 64, got {}", self.max_starts),
            });
        }
        if let Some(r) = &self.elbow_reference
            && !r.coords.iter().all(|x| x.is_finite())
        {
            return Err(GraspError::NonFinite {
                field: "elbow_reference".into(),
            });
        }
        Ok(())
    }
}

/// A joint value with its name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct NamedJoint {
    /// Joint name.
    pub name: String,
    /// Value (rad or m).
    pub value: f64,
}

/// A fingertip contact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Contact {
    /// Finger name.
    pub finger: String,
    /// Contact point on the object surface (world).
    pub point: [f64; 3],
    /// Outward surface normal there.
    pub normal: [f64; 3],
    /// Exact signed distance between the finger's pad (the links carrying its tip) and the
    /// object, m (0 = touching, < 0 pressing in; eq. 27 on the real geometry).
    pub surface_distance: f64,
    /// Angle between the finger's pad normal and the inward surface normal (deg): 0 is a
    /// contact square on the pad; above 60° ([`PAD_CONE_DEG`]) the contact is not on the pad
    /// (90+: the side or the back of the finger) and the grasp is infeasible.
    pub pad_angle_deg: f64,
}

/// Every term of eq. 22 and the indexes behind it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Terms {
    /// Total cost (eq. 22).
    pub cost: f64,
    /// Task compatibility index of the arm (eq. 16).
    pub tc: f64,
    /// Grasp compatibility index of the hand (eq. 19).
    pub gc: f64,
    /// Selected quality measure on the contact points.
    pub quality: QualityMeasure,
    /// `Q_DC` on the contact points (eq. 20), m.
    pub q_dc: f64,
    /// `Q_AGP` on the contact points (eq. 21), m².
    pub q_agp: f64,
    /// Anthropomorphism term: squared elbow distance to the reference (m²), 0 without one.
    pub d: f64,
    /// Arm manipulability at the grasp frame (eq. 12, full 6-D Jacobian of the arm joints).
    pub manipulability: f64,
    /// Arm ratio (α or β per direction's kind) along each task direction (eq. 14-15).
    pub arm_ratios: Vec<f64>,
    /// Hand ratio along each task direction (eq. 17-18).
    pub hand_ratios: Vec<f64>,
}

/// Constraint residuals at the returned configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Residuals {
    /// Largest |signed distance| of a contact sphere from the surface (eq. 27), m.
    pub max_surface_distance: f64,
    /// Largest penetration of a link sphere into the object (eq. 29), m (≤ 0: clear).
    pub max_object_penetration: f64,
    /// Largest penetration of a link sphere into the support plane, m (≤ 0: clear).
    pub max_support_penetration: f64,
    /// Smallest distance of a joint to its limits (eq. 25), rad or m (≥ 0 by construction).
    pub min_limit_margin: f64,
    /// Largest spread-order violation `q_a − q_b` (eq. 28; ≤ 0 holds).
    pub max_spread_violation: f64,
    /// Largest coupling error `|q_i − k_i q_driver − offset|` over mimic joints (eq. 26).
    pub max_coupling_error: f64,
    /// Smallest gap `‖c_i − c_j‖ − r_i − r_j` between the contact spheres of two different
    /// fingers, m (≥ 0: disjoint; the optimiser keeps 1 mm). 1 for a one-finger hand.
    pub min_finger_separation: f64,
    /// Smallest gap between a link sphere of one finger (beyond its first link) and a link or
    /// contact sphere of another, m (≥ 0: disjoint, fingers do not pass through each other; the
    /// optimiser keeps 1 mm). 1 when the hand has no such pairs.
    pub min_link_separation: f64,
}

/// The exact check of a result against the real geometry (the URDF collision shapes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ExactCheck {
    /// Every condition below holds: penetrations ≤ 1 mm, no two links intersecting, every
    /// pad within 1 mm of the surface, every contact within 60° of its pad normal. Together with
    /// the spread order (eq. 28) this is the `feasible` verdict.
    pub passed: bool,
    /// Largest exact penetration of any link's collision shape into the object, m (≤ 0: clear
    /// by that much).
    pub max_object_penetration: f64,
    /// The link of `max_object_penetration`.
    pub object_link: Option<String>,
    /// Largest exact penetration of any moving link into the support half-space, m (≤ 0:
    /// clear; −1 without a support).
    pub max_support_penetration: f64,
    /// The link of `max_support_penetration`.
    pub support_link: Option<String>,
    /// Smallest exact distance between two non-adjacent links of the system (arm and hand, every
    /// finger link included), m (< 0: they intersect; 1 without pairs).
    pub min_link_separation: f64,
    /// The two links of `min_link_separation`, "a / b".
    pub closest_links: Option<String>,
    /// Largest |exact signed distance| between a finger's pad (the links carrying its tip) and
    /// the object, m.
    pub max_pad_distance: f64,
    /// Largest angle between a pad normal and the inward surface normal at its contact, deg.
    pub max_pad_angle_deg: f64,
    /// Opposition of the contacts: distance from the origin to the convex hull of their unit
    /// surface normals (0: the normal forces can balance; 1: every contact pushes the same way;
    /// above `sin(atan μ)` no grip with friction coefficient μ can hold, the closing hand
    /// squeezes the object out). Not part of the verdict: feasible starts with at most 0.12
    /// ([`FIRM_BALANCE`]) are preferred and searched for. 0 for a one-finger hand.
    pub normal_balance: f64,
    /// The check passed and `normal_balance` is at most 0.12: the contacts can press against
    /// each other, the grasp the search looks for. When no start is firm the answer is the
    /// cheapest feasible one, which the closing hand is likely to squeeze out: in the physics
    /// survey (`workers/mujoco/survey.py grasps`, seeded objects × six systems × two tasks) 49
    /// of the 53 firm grasps held their object and none of the 7 feasible ones that were not.
    // (Grasps stored before this field existed lack it: `GraspResult::from_stored` derives it.)
    #[serde(default)]
    pub firm: bool,
}

/// Whether a grasp with this verdict and opposition is firm (see [`ExactCheck::firm`]).
fn firm(passed: bool, normal_balance: f64) -> bool {
    passed && normal_balance <= FIRM_BALANCE
}

impl GraspResult {
    /// A result as stored (JSON), with [`ExactCheck::firm`] derived where a grasp stored before
    /// that field lacks it.
    pub fn from_stored(json: &str) -> serde_json::Result<Self> {
        let mut r: GraspResult = serde_json::from_str(json)?;
        r.exact.firm = firm(r.exact.passed, r.exact.normal_balance);
        Ok(r)
    }
}

/// The solver report of the returned start, in plain units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SolverSummary {
    /// How the solve ended.
    pub status: String,
    /// Inner iterations.
    pub iterations: usize,
    /// Outer (augmented Lagrangian) iterations.
    pub outer_iterations: usize,
    /// Cost at the solution.
    pub cost: f64,
    /// Largest general-constraint violation at the solution.
    pub max_constraint_violation: f64,
    /// Solve time, s.
    pub time_s: f64,
}

impl From<&SolveReport> for SolverSummary {
    fn from(r: &SolveReport) -> Self {
        SolverSummary {
            status: serde_json::to_value(r.status)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default(),
            iterations: r.iterations,
            outer_iterations: r.outer_iterations,
            cost: r.cost,
            max_constraint_violation: r.max_constraint_violation,
            time_s: r.time.as_secs_f64(),
        }
    }
}

/// Outcome of a grasp request. An infeasible request is a result with `feasible: false`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GraspResult {
    /// The grasp holds on the real geometry ([`ExactCheck::passed`]: exact penetration ≤ 1 mm,
    /// no two links intersecting, pads within 1 mm of the surface and 60° of the contact normal)
    /// with limits, couplings and spread order.
    pub feasible: bool,
    /// Plain-language reason when infeasible.
    pub reason: Option<String>,
    /// Arm joint values.
    pub q_arm: Vec<NamedJoint>,
    /// Independent hand joint values.
    pub q_hand: Vec<NamedJoint>,
    /// Contacts, one per finger on the object.
    pub contacts: Vec<Contact>,
    /// Fingers kept off the object: empty when every finger touches it. A grasp with fewer
    /// fingers (a pinch, the others clear of the object and the table) is searched only when
    /// none with every finger passes the exact check; not in the paper, whose eq. 27 puts every
    /// fingertip on the object.
    #[serde(default)]
    pub idle_fingers: Vec<String>,
    /// Cost terms and indexes.
    pub terms: Terms,
    /// Constraint residuals of the optimiser's sphere model at the returned (repaired) posture;
    /// informative only, `feasible` is `exact.passed`.
    pub residuals: Residuals,
    /// The exact check against the real geometry: the `feasible` verdict.
    pub exact: ExactCheck,
    /// Velocity/force ellipsoids of the arm at the grasp frame (eq. 10-11).
    pub arm_ellipsoids: Ellipsoids,
    /// Velocity/force ellipsoids of the hand-object Jacobian.
    pub hand_ellipsoids: Ellipsoids,
    /// Solver report of the returned start.
    pub solver: Option<SolverSummary>,
    /// Wall time of the whole request, s.
    pub time_s: f64,
    /// Starts run.
    pub starts_used: usize,
    /// Starts that ended feasible (exact verdict, after the contact repair).
    pub starts_feasible: usize,
    /// A start was cut short by the wall-clock safety net instead of its iteration budget: this
    /// answer may differ on a less loaded machine.
    pub timed_out: bool,
}

/// Per-worker evaluation state: FK once per distinct `u`, shared by cost, gradient, residuals
/// and constraint Jacobian (the closures all go through it).
struct Eval<'a> {
    sys: &'a HandArm,
    req: &'a GraspRequest,
    layout: Layout,
    kin: KinState,
    exact: ExactGeometry,
    scratch: Scratch,
}

/// What the system and the request fix for the whole run: read by every evaluation, written by
/// none, so it can be borrowed freely while the state below is mutated.
struct Layout {
    /// `u[k]` is `q[sel[k]]`.
    sel: Vec<usize>,
    na: usize,
    /// Rank of each arm column along the chain (base = 0), for ∂J/∂q.
    arm_rank: Vec<usize>,
    n_spread: usize,
    plane: bool,
    /// Finger pairs `(i, j)`, `i < j`, whose contact spheres must stay disjoint.
    pairs: Vec<(usize, usize)>,
    rho: f64,
}

/// The sphere model's kinematics at the last `u`: valid as a whole or not at all (`fresh`,
/// `last_u`), so cost, gradient, residuals and Jacobian share one FK pass.
struct KinState {
    q: Vec<f64>,
    data: Data,
    last_u: Vec<f64>,
    fresh: bool,
    /// `dj` and `tip_hn` are current: they serve the gradient alone, so the evaluations of a
    /// line search and the constraint residuals, which read neither, do not compute them.
    derivatives: bool,
    palm_j: Matrix6xX<f64>,
    jv_arm: Matrix3xX<f64>,
    dj: Vec<Matrix3xX<f64>>,
    tip_p: Vec<Point3<f64>>,
    tip_q: Vec<SurfaceQuery>,
    tip_j: Vec<Matrix6xX<f64>>,
    s_p: Vec<Point3<f64>>,
    s_q: Vec<SurfaceQuery>,
    /// World positions of the support cover's points.
    cover_p: Vec<Point3<f64>>,
    /// Pad normals (world).
    tip_z: Vec<Vector3<f64>>,
    /// Per finger: the derivative of the outward surface normal at the contact-sphere centre
    /// along the pad normal (`H n_pad`, H the Hessian of the object's signed distance, taken by
    /// a central difference), for the pad-cone rows' gradient.
    tip_hn: Vec<Vector3<f64>>,
    elbow_p: Point3<f64>,
}

/// Exact geometry for the verdict and the repair, which judge the real links rather than the
/// optimiser's spheres: every link against the object, the support and every non-adjacent link.
struct ExactGeometry {
    checker: CollisionChecker,
    cd: CheckData,
    /// Per finger: its links' and pads' object pairs and its flexion coordinate.
    fingers_geo: Vec<repair::FingerGeometry>,
    /// Object and support pairs of the links no finger moves.
    body_pairs: Vec<usize>,
    /// Support pairs of the finger links.
    finger_support: Vec<usize>,
    /// Scratch copy of `q` for the repair.
    q_saved: Vec<f64>,
    /// Per finger: the exact distance of its pad to the object at the last verdict.
    pads: Vec<Option<SignedDistance>>,
}

/// Buffers the evaluations overwrite before reading, kept to spare the hot loops allocations;
/// nothing in them survives a call, so they never make the cached state stale.
struct Scratch {
    /// FK off the cached point (GC's finite differences, seeding, the repair's palm moves),
    /// so `KinState::data` stays valid.
    fd_data: Data,
    tmp_j: Matrix6xX<f64>,
    hand_gj: Matrix6xX<f64>,
    point_grad: Vec<Vector3<f64>>,
    grad_q: Vec<f64>,
    grad_arm: Vec<f64>,
    /// `y − c` of a goal region (scratch, the largest region's dimension).
    region_diff: Vec<f64>,
    /// The palm IK of the seeding and the repair ([`palm_ik`]).
    ik: IkSolver,
    /// Per finger: contact normal and hull weight ([`Eval::balance_at_last_check`]).
    normals: Vec<Vector3<f64>>,
    weights: Vec<f64>,
}

impl KinState {
    /// `q[sel[k]] = u[k]`.
    fn set_q(&mut self, sel: &[usize], u: &[f64]) {
        for (k, &i) in sel.iter().enumerate() {
            self.q[i] = u[k];
        }
    }

    /// FK, Jacobians and surface queries at `u`; false (and nothing done) when `u` is unchanged.
    fn update(&mut self, sys: &HandArm, req: &GraspRequest, layout: &Layout, u: &[f64]) -> bool {
        if self.fresh && self.last_u == u {
            return false;
        }
        self.last_u.clear();
        self.last_u.extend_from_slice(u);
        self.fresh = true;
        self.set_q(&layout.sel, u);
        let model = &*sys.model;
        forward_kinematics(model, &mut self.data, &self.q);
        frame_jacobian(
            model,
            &self.data,
            sys.palm,
            &Vector3::zeros(),
            &mut self.palm_j,
        );
        for (i, f) in sys.fingers.iter().enumerate() {
            self.tip_p[i] = f.contact_point(&self.data);
            self.tip_z[i] = self.data.frame(f.tip).rotation * f.pad_normal;
            self.tip_q[i] = req.object.query(&self.tip_p[i]);
            frame_jacobian(model, &self.data, f.tip, &f.tip_offset, &mut self.tip_j[i]);
        }
        // Link-sphere Jacobians are not formed here: their constraints enter the solver only
        // through `J_vᵀ d` with `d` zero for every sphere clear of the object and plane, so
        // `jacobian_t` applies them lazily (most of the spheres, most of the time).
        for (i, s) in sys.link_spheres.iter().enumerate() {
            self.s_p[i] = self.data.frame(s.frame) * Point3::from(s.center);
            self.s_q[i] = req.object.query(&self.s_p[i]);
        }
        if layout.plane {
            for (p, c) in self.cover_p.iter_mut().zip(&sys.support_cover) {
                *p = self.data.frame(c.frame) * Point3::from(c.center);
            }
        }
        if let Some(e) = sys.elbow {
            self.elbow_p = Point3::from(self.data.frame(e).translation.vector);
        }
        for (a, &qa) in sys.arm_joints.iter().enumerate() {
            for r in 0..3 {
                self.jv_arm[(r, a)] = self.palm_j[(r, qa)];
            }
        }
        self.derivatives = false;
        true
    }

    /// `dj` and `tip_hn` at the last [`Self::update`] (once per point).
    fn derivatives(&mut self, sys: &HandArm, req: &GraspRequest, layout: &Layout) {
        if self.derivatives {
            return;
        }
        self.derivatives = true;
        for i in 0..sys.fingers.len() {
            let h = 1e-5;
            let np = req.object.query(&(self.tip_p[i] + self.tip_z[i] * h));
            let nm = req.object.query(&(self.tip_p[i] - self.tip_z[i] * h));
            self.tip_hn[i] = (np.normal - nm.normal) / (2.0 * h);
        }
        // Arm translational Jacobian at the grasp frame and its partial derivatives. For a
        // serial chain of revolute joints with world axes z and columns J_j = z_j × (p − p_j):
        // ∂J_j/∂q_i = z_i × J_j when joint i precedes j (or i = j), z_j × J_i otherwise.
        for i in 0..layout.na {
            let zi = self
                .palm_j
                .fixed_view::<3, 1>(3, sys.arm_joints[i])
                .into_owned();
            for j in 0..layout.na {
                let zj = self
                    .palm_j
                    .fixed_view::<3, 1>(3, sys.arm_joints[j])
                    .into_owned();
                let col = if layout.arm_rank[i] <= layout.arm_rank[j] {
                    zi.cross(&self.jv_arm.column(j))
                } else {
                    zj.cross(&self.jv_arm.column(i))
                };
                self.dj[i].set_column(j, &col);
            }
        }
    }

    /// Pad-cone excess of finger `i`: `cos(PAD_CONE_OPT_DEG) + n_pad · n_out` (> 0: the pad
    /// normal is outside the cone around the inward surface normal).
    fn pad_excess(&self, i: usize) -> f64 {
        PAD_CONE_OPT_DEG.to_radians().cos() + self.tip_z[i].dot(&self.tip_q[i].normal)
    }
}

/// The grasp's scene for the exact checker: the object and its support half-space.
fn grasp_checker(sys: &HandArm, req: &GraspRequest) -> CollisionChecker {
    grasp_checker_for(sys, &req.object)
}

/// The exact checker of `object` (and its support half-space) against the system's links.
pub(super) fn grasp_checker_for(sys: &HandArm, object: &Object) -> CollisionChecker {
    let (shape, pose) = object.shape();
    let mut scene = Scene::new().with_object(SceneShape::new(
        object.spec().name.clone(),
        shape.clone(),
        *pose,
    ));
    if let Some(p) = object.support().and_then(|sp| Plane::try_from(sp).ok()) {
        scene = scene.with_support(p);
    }
    CollisionChecker::new(sys.geometry.clone(), scene)
}

impl<'a> Eval<'a> {
    fn new(sys: &'a HandArm, req: &'a GraspRequest) -> Self {
        let model = &sys.model;
        let nq = model.nq();
        let sel: Vec<usize> = sys
            .arm_joints
            .iter()
            .chain(&sys.hand_joints)
            .copied()
            .collect();
        let na = sys.arm_joints.len();
        let chain = model.supporting_q(sys.palm);
        let arm_rank = sys
            .arm_joints
            .iter()
            .map(|q| chain.iter().position(|c| c == q).unwrap_or(usize::MAX))
            .collect();
        let m = sys.fingers.len();
        let s = sys.link_spheres.len();
        let checker = grasp_checker(sys, req);
        let cd = checker.data();
        let (fingers_geo, body_pairs, finger_support) = repair::finger_geometry(sys, &checker);
        // Placeholder until the first update queries the object.
        let no_query = SurfaceQuery {
            signed_distance: 0.0,
            point: Point3::origin(),
            normal: Vector3::z(),
        };
        Eval {
            sys,
            req,
            layout: Layout {
                sel,
                na,
                arm_rank,
                n_spread: sys.spread_pairs.len(),
                plane: req.object.support().is_some(),
                pairs: (0..m)
                    .flat_map(|i| (i + 1..m).map(move |j| (i, j)))
                    .collect(),
                rho: req.object.bounding_radius(),
            },
            kin: KinState {
                q: model.neutral(),
                data: Data::new(model),
                last_u: Vec::new(),
                fresh: false,
                derivatives: false,
                palm_j: Matrix6xX::zeros(nq),
                jv_arm: Matrix3xX::zeros(na),
                dj: vec![Matrix3xX::zeros(na); na],
                tip_p: vec![Point3::origin(); m],
                tip_q: vec![no_query; m],
                tip_j: vec![Matrix6xX::zeros(nq); m],
                s_p: vec![Point3::origin(); s],
                s_q: vec![no_query; s],
                cover_p: vec![Point3::origin(); sys.support_cover.len()],
                tip_z: vec![Vector3::z(); m],
                tip_hn: vec![Vector3::zeros(); m],
                elbow_p: Point3::origin(),
            },
            exact: ExactGeometry {
                checker,
                cd,
                fingers_geo,
                body_pairs,
                finger_support,
                q_saved: model.neutral(),
                pads: vec![None; m],
            },
            scratch: Scratch {
                fd_data: Data::new(model),
                tmp_j: Matrix6xX::zeros(nq),
                hand_gj: Matrix6xX::zeros(sys.hand_joints.len()),
                point_grad: vec![Vector3::zeros(); m],
                grad_q: vec![0.0; nq],
                grad_arm: vec![0.0; na],
                region_diff: vec![
                    0.0;
                    req.goal_regions
                        .iter()
                        .map(|g| g.center.len())
                        .max()
                        .unwrap_or(0)
                ],
                ik: IkSolver::new(model),
                normals: vec![Vector3::z(); m],
                weights: vec![0.0; m],
            },
        }
    }

    fn n(&self) -> usize {
        self.layout.sel.len()
    }

    fn n_eq(&self) -> usize {
        self.sys.fingers.len()
    }

    fn n_ineq(&self) -> usize {
        let s = self.sys.link_spheres.len();
        let c = self.sys.support_cover.len();
        let m = self.sys.fingers.len();
        self.layout.n_spread
            + s
            + if self.layout.plane { c } else { 0 }
            + if self.layout.plane { m } else { 0 }
            + self.layout.pairs.len()
            + self.sys.link_pairs.len()
            + self.req.goal_regions.len()
    }

    /// Index of the first goal-region row (the last rows).
    fn region_row(&self) -> usize {
        self.n_eq() + self.n_ineq() - self.req.goal_regions.len()
    }

    /// Index of the first contact-sphere support row (with a support): per finger the contact
    /// sphere above the support plane, `r_i − h(c_i) ≤ 0` (the pads were unchecked against the
    /// table: pad centres up to 10 mm under it).
    fn pad_row(&self) -> usize {
        let s = self.sys.link_spheres.len();
        let c = self.sys.support_cover.len();
        self.n_eq() + self.layout.n_spread + s + if self.layout.plane { c } else { 0 }
    }

    /// Index of the first fingertip-pair row in the residual vector.
    fn pair_row(&self) -> usize {
        self.link_pair_row() - self.layout.pairs.len()
    }

    /// Index of the first link-pair row.
    fn link_pair_row(&self) -> usize {
        self.region_row() - self.sys.link_pairs.len()
    }

    /// World centre and radius of the other sphere of a link pair.
    fn partner(&self, pair: LinkPair) -> (usize, Point3<f64>, f64) {
        match pair {
            LinkPair::Links(a, b) => (a, self.kin.s_p[b], self.sys.link_spheres[b].radius),
            LinkPair::Tip(a, f) => (a, self.kin.tip_p[f], self.sys.fingers[f].radius),
        }
    }

    fn set_q(&mut self, u: &[f64]) {
        self.kin.set_q(&self.layout.sel, u);
    }

    /// FK, Jacobians and surface queries at `u` (skipped when `u` is unchanged).
    fn update(&mut self, u: &[f64]) {
        if self.kin.update(self.sys, self.req, &self.layout, u) {
            // (the placements `kin.update` has just computed at `kin.q`)
            self.exact
                .checker
                .update_from(&mut self.exact.cd, &self.kin.data);
        }
    }

    fn quality_surrogate(&self) -> f64 {
        match self.req.quality {
            QualityMeasure::CentroidDistance => {
                indexes::q_dc(&self.kin.tip_p, &self.req.object.centroid()) / self.layout.rho
            }
            QualityMeasure::PolygonArea => {
                -indexes::q_agp(&self.kin.tip_p) / (self.layout.rho * self.layout.rho)
            }
        }
    }

    fn elbow_term(&self) -> f64 {
        match (&self.req.elbow_reference, self.sys.elbow) {
            (Some(r), Some(_)) => (self.kin.elbow_p - r).norm_squared(),
            _ => 0.0,
        }
    }

    fn cost(&mut self, u: &[f64]) -> f64 {
        self.update(u);
        let w = self.req.weights;
        let mut c = 0.0;
        if w.tc > 0.0 {
            let m = indexes::transmission_matrix(&self.kin.jv_arm);
            c += w.tc * indexes::compatibility_index(&m, &self.req.task);
        }
        if w.gc > 0.0 {
            c += w.gc
                * hand_gc(
                    self.sys,
                    self.req,
                    &self.kin.data,
                    &mut self.scratch.tmp_j,
                    &mut self.scratch.hand_gj,
                )
                .0;
        }
        if w.q > 0.0 {
            c += w.q * self.quality_surrogate();
        }
        if w.d > 0.0 {
            c += w.d * self.elbow_term();
        }
        c + PAD_WEIGHT * self.pad_penalty()
    }

    /// `Σ max(0, excess)²`: zero inside the cone, C¹.
    fn pad_penalty(&self) -> f64 {
        (0..self.sys.fingers.len())
            .map(|i| self.kin.pad_excess(i).max(0.0).powi(2))
            .sum()
    }

    fn gradient(&mut self, u: &[f64], g: &mut [f64]) {
        self.update(u);
        self.kin.derivatives(self.sys, self.req, &self.layout);
        let w = self.req.weights;
        self.scratch.grad_q.iter_mut().for_each(|x| *x = 0.0);
        if w.q > 0.0 {
            let cg = self.req.object.centroid();
            let scale = match self.req.quality {
                QualityMeasure::CentroidDistance => {
                    indexes::q_dc_point_gradient(
                        &self.kin.tip_p,
                        &cg,
                        &mut self.scratch.point_grad,
                    );
                    w.q / self.layout.rho
                }
                QualityMeasure::PolygonArea => {
                    indexes::q_agp_point_gradient(&self.kin.tip_p, &mut self.scratch.point_grad);
                    -w.q / (self.layout.rho * self.layout.rho)
                }
            };
            for (i, pg) in self.scratch.point_grad.iter().enumerate() {
                add_point_gradient(&mut self.scratch.grad_q, &self.kin.tip_j[i], &(pg * scale));
            }
        }
        if w.d > 0.0
            && let (Some(r), Some(frame)) = (&self.req.elbow_reference, self.sys.elbow)
        {
            let e = (self.kin.elbow_p - r) * (2.0 * w.d);
            add_point_jacobian_transpose(
                &self.sys.model,
                &self.kin.data,
                frame,
                &Vector3::zeros(),
                &e,
                &mut self.scratch.grad_q,
            );
        }
        if w.tc > 0.0 {
            indexes::compatibility_index_gradient(
                &self.kin.jv_arm,
                &self.kin.dj,
                &self.req.task,
                &mut self.scratch.grad_arm,
            );
            for (a, &qa) in self.sys.arm_joints.iter().enumerate() {
                self.scratch.grad_q[qa] += w.tc * self.scratch.grad_arm[a];
            }
        }
        // Pad penalty: ∂(n_pad · n_out)/∂q_k = ω_k · (n_pad × n_out) + (H n_pad) · v_k (ω, v
        // the tip's angular and linear Jacobian columns, H the symmetric Hessian of the signed
        // distance).
        for i in 0..self.sys.fingers.len() {
            let e = self.kin.pad_excess(i);
            if e <= 0.0 {
                continue;
            }
            let s = 2.0 * PAD_WEIGHT * e;
            let wv = self.kin.tip_z[i].cross(&self.kin.tip_q[i].normal) * s;
            let v = self.kin.tip_hn[i] * s;
            let j = &self.kin.tip_j[i];
            for (c, g) in self.scratch.grad_q.iter_mut().enumerate() {
                *g += j[(3, c)] * wv.x + j[(4, c)] * wv.y + j[(5, c)] * wv.z;
                *g += j[(0, c)] * v.x + j[(1, c)] * v.y + j[(2, c)] * v.z;
            }
        }
        for (k, &i) in self.layout.sel.iter().enumerate() {
            g[k] = self.scratch.grad_q[i];
        }
        if w.gc > 0.0 {
            // GC goes through the pseudo-inverse of the grasp matrix, whose derivative has no
            // compact closed form when G is rank-deficient (two-finger hands); its gradient is
            // taken by central differences on a separate scratch Data (2n extra FK passes).
            let h = 1e-6;
            let mut up = self.kin.last_u.clone();
            for k in 0..self.n() {
                let x = up[k];
                up[k] = x + h;
                let fp = self.gc_at(&up);
                up[k] = x - h;
                let fm = self.gc_at(&up);
                up[k] = x;
                g[k] += w.gc * (fp - fm) / (2.0 * h);
            }
        }
    }

    fn gc_at(&mut self, u: &[f64]) -> f64 {
        self.kin.set_q(&self.layout.sel, u);
        forward_kinematics(&self.sys.model, &mut self.scratch.fd_data, &self.kin.q);
        let v = hand_gc(
            self.sys,
            self.req,
            &self.scratch.fd_data,
            &mut self.scratch.tmp_j,
            &mut self.scratch.hand_gj,
        )
        .0;
        // restore q of the cached point
        let last = std::mem::take(&mut self.kin.last_u);
        self.set_q(&last);
        self.kin.last_u = last;
        v
    }

    fn residuals(&mut self, u: &[f64], r: &mut [f64]) {
        self.update(u);
        let m = self.n_eq();
        for ((ri, tq), f) in r.iter_mut().zip(&self.kin.tip_q).zip(&self.sys.fingers) {
            *ri = tq.signed_distance - f.radius;
        }
        let mut k = m;
        for sp in &self.sys.spread_pairs {
            r[k] = sp.lower.at(&self.kin.q) - sp.upper.at(&self.kin.q);
            k += 1;
        }
        for (i, s) in self.sys.link_spheres.iter().enumerate() {
            r[k] = s.radius - self.kin.s_q[i].signed_distance;
            k += 1;
        }
        if let Some(pl) = self.req.object.support() {
            for (c, p) in self.sys.support_cover.iter().zip(&self.kin.cover_p) {
                r[k] = c.radius - pl.signed_distance(p);
                k += 1;
            }
        }
        if let Some(pl) = self.req.object.support() {
            for (i, f) in self.sys.fingers.iter().enumerate() {
                r[k] = f.radius - pl.signed_distance(&self.kin.tip_p[i]);
                k += 1;
            }
        }
        for &(i, j) in &self.layout.pairs {
            let (fi, fj) = (&self.sys.fingers[i], &self.sys.fingers[j]);
            r[k] = fi.radius + fj.radius + FINGER_CLEARANCE
                - (self.kin.tip_p[i] - self.kin.tip_p[j]).norm();
            k += 1;
        }
        for &pair in &self.sys.link_pairs {
            let (a, c, rb) = self.partner(pair);
            r[k] = self.sys.link_spheres[a].radius + rb + FINGER_CLEARANCE
                - (self.kin.s_p[a] - c).norm();
            k += 1;
        }
        // (‖y − c‖² − (m r)²) / 2r: about the distance past the margin near the boundary, smooth
        // at the centre.
        for g in &self.req.goal_regions {
            let dist = g.distance(&self.kin.q, &mut self.scratch.region_diff);
            let rm = GOAL_REGION_MARGIN * g.radius;
            r[k] = (dist * dist - rm * rm) / (2.0 * g.radius);
            k += 1;
        }
    }

    fn jacobian_t(&mut self, u: &[f64], d: &[f64], out: &mut [f64]) {
        self.update(u);
        self.scratch.grad_q.iter_mut().for_each(|x| *x = 0.0);
        let m = self.n_eq();
        for (i, di) in d.iter().enumerate().take(m) {
            add_point_gradient(
                &mut self.scratch.grad_q,
                &self.kin.tip_j[i],
                &(self.kin.tip_q[i].normal * *di),
            );
        }
        let mut k = m;
        for sp in &self.sys.spread_pairs {
            self.scratch.grad_q[sp.lower.q_index] += sp.lower.multiplier * d[k];
            self.scratch.grad_q[sp.upper.q_index] -= sp.upper.multiplier * d[k];
            k += 1;
        }
        let model = &*self.sys.model;
        let n_spheres = self.sys.link_spheres.len();
        let plane = self.req.object.support().map(|pl| Vector3::from(pl.normal));
        for (i, s) in self.sys.link_spheres.iter().enumerate() {
            let v = self.kin.s_q[i].normal * -d[k + i];
            if v != Vector3::zeros() {
                add_point_jacobian_transpose(
                    model,
                    &self.kin.data,
                    s.frame,
                    &s.center,
                    &v,
                    &mut self.scratch.grad_q,
                );
            }
        }
        if let Some(n) = &plane {
            let k0 = k + n_spheres;
            for (i, c) in self.sys.support_cover.iter().enumerate() {
                let di = d[k0 + i];
                if di != 0.0 {
                    add_point_jacobian_transpose(
                        model,
                        &self.kin.data,
                        c.frame,
                        &c.center,
                        &(n * -di),
                        &mut self.scratch.grad_q,
                    );
                }
            }
        }
        let k0 = self.pad_row();
        if let Some(n) = &plane {
            for i in 0..self.sys.fingers.len() {
                let di = d[k0 + i];
                if di != 0.0 {
                    add_point_gradient(&mut self.scratch.grad_q, &self.kin.tip_j[i], &(n * -di));
                }
            }
        }
        // ∂(−‖c_i − c_j‖)/∂q = −eᵀ (J_i − J_j), e the unit vector from c_j to c_i; at
        // coincident centres the row has no gradient and contributes none.
        let k0 = self.pair_row();
        for (p, &(i, j)) in self.layout.pairs.iter().enumerate() {
            let dp = d[k0 + p];
            if dp == 0.0 {
                continue;
            }
            let Some(e) = (self.kin.tip_p[i] - self.kin.tip_p[j]).try_normalize(1e-12) else {
                continue;
            };
            add_point_gradient(&mut self.scratch.grad_q, &self.kin.tip_j[i], &(e * -dp));
            add_point_gradient(&mut self.scratch.grad_q, &self.kin.tip_j[j], &(e * dp));
        }
        // Link pairs the same way; their rows are zero in `d` while the spheres are clear, so
        // the link Jacobians are applied only for active pairs.
        let k0 = self.link_pair_row();
        for (p, &pair) in self.sys.link_pairs.iter().enumerate() {
            let dp = d[k0 + p];
            if dp == 0.0 {
                continue;
            }
            let (a, c, _) = self.partner(pair);
            let Some(e) = (self.kin.s_p[a] - c).try_normalize(1e-12) else {
                continue;
            };
            let sa = &self.sys.link_spheres[a];
            add_point_jacobian_transpose(
                model,
                &self.kin.data,
                sa.frame,
                &sa.center,
                &(e * -dp),
                &mut self.scratch.grad_q,
            );
            match pair {
                LinkPair::Links(_, b) => {
                    let sb = &self.sys.link_spheres[b];
                    add_point_jacobian_transpose(
                        model,
                        &self.kin.data,
                        sb.frame,
                        &sb.center,
                        &(e * dp),
                        &mut self.scratch.grad_q,
                    );
                }
                LinkPair::Tip(_, f) => {
                    add_point_gradient(&mut self.scratch.grad_q, &self.kin.tip_j[f], &(e * dp));
                }
            }
        }
        let k0 = self.region_row();
        for (p, g) in self.req.goal_regions.iter().enumerate() {
            let dp = d[k0 + p];
            if dp == 0.0 {
                continue;
            }
            g.distance(&self.kin.q, &mut self.scratch.region_diff);
            let dim = g.center.len();
            for (gi, &j) in g.joints.iter().enumerate() {
                let row = &g.components[gi * dim..(gi + 1) * dim];
                let v: f64 = row
                    .iter()
                    .zip(&self.scratch.region_diff)
                    .map(|(w, y)| w * y)
                    .sum();
                self.scratch.grad_q[j] += dp * v / g.radius;
            }
        }
        for (k, &i) in self.layout.sel.iter().enumerate() {
            out[k] = self.scratch.grad_q[i];
        }
    }
}

impl Eval<'_> {
    /// Exact check at the current `u`: every pair, smallest distance per category, and each
    /// finger's pad against the object.
    fn clearance(&mut self, u: &[f64]) -> Clearance {
        self.update(u);
        self.exact.clearance_at_update()
    }

    /// Signed distance of finger `i`'s pad from the object surface (m): exact between its pad
    /// links and the object, or the contact sphere's (eq. 27) for a finger without pad shapes.
    fn pad_distance(&self, i: usize) -> f64 {
        self.exact.pads[i].map_or(
            self.kin.tip_q[i].signed_distance - self.sys.fingers[i].radius,
            |d| d.distance,
        )
    }

    /// Opposition of the contact normals ([`indexes::normal_balance`]) at the posture of the
    /// last exact check (a verdict or clearance), from each finger's exact pad contact normal
    /// (the contact sphere's without pad shapes). 0 for a one-finger hand.
    fn balance_at_last_check(&mut self) -> f64 {
        let m = self.n_eq();
        if m < 2 {
            return 0.0;
        }
        for i in 0..m {
            self.scratch.normals[i] =
                self.exact.pads[i].map_or(self.kin.tip_q[i].normal, |d| -d.normal);
        }
        indexes::normal_balance(&self.scratch.normals, &mut self.scratch.weights)
    }

    /// Angle between finger `i`'s pad normal and the inward surface normal at its contact, deg
    /// (the exact contact's normal, pointing from the pad into the object; the contact sphere's
    /// without pad shapes).
    fn pad_angle_deg(&self, i: usize) -> f64 {
        let inward = self.exact.pads[i].map_or(-self.kin.tip_q[i].normal, |d| d.normal);
        inward
            .dot(&self.kin.tip_z[i])
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }
}

impl ExactGeometry {
    /// Every pair at the checker's last update, and each finger's pad against the object.
    fn clearance_at_update(&mut self) -> Clearance {
        let c = self.checker.clearance_at_update(&mut self.cd);
        for f in 0..self.pads.len() {
            let mut best: Option<SignedDistance> = None;
            for k in 0..self.fingers_geo[f].pads.len() {
                let p = self.fingers_geo[f].pads[k];
                let d = self.checker.pair_distance(&mut self.cd, p);
                if best.is_none_or(|b| d.distance < b.distance) {
                    best = Some(d);
                }
            }
            self.pads[f] = best;
        }
        c
    }
}

/// The exact check of a configuration ([`ExactCheck`]).
struct Verdict {
    clearance: Clearance,
    /// Smallest exact distance of a link to the object, to the support and between two
    /// non-adjacent links, m (`+∞` without pairs).
    object: f64,
    support: f64,
    links: f64,
    /// Largest |exact pad distance| and its finger.
    pad: (f64, usize),
    /// Largest pad angle (deg) and its finger.
    pad_angle: (f64, usize),
    /// Largest spread-order violation (eq. 28).
    spread: f64,
}

impl Verdict {
    fn passed(&self) -> bool {
        self.pad.0 <= SURFACE_TOLERANCE
            && self.object >= -EXACT_PENETRATION_TOLERANCE
            && self.support >= -EXACT_PENETRATION_TOLERANCE
            && self.links >= 0.0
            && self.pad_angle.0 <= PAD_CONE_DEG
            && self.spread <= 1e-9
    }

    /// How far from passing (m, degrees weighted by 1 mm each), to rank infeasible starts.
    fn violation(&self) -> f64 {
        (self.pad.0 - SURFACE_TOLERANCE).max(0.0)
            + (-self.object - EXACT_PENETRATION_TOLERANCE).max(0.0)
            + (-self.support - EXACT_PENETRATION_TOLERANCE).max(0.0)
            + (-self.links).max(0.0)
            + 1e-3 * (self.pad_angle.0 - PAD_CONE_DEG).max(0.0)
            + self.spread.max(0.0)
    }
}

impl Eval<'_> {
    fn verdict(&mut self, u: &[f64]) -> Verdict {
        let clearance = self.clearance(u);
        let worst = |v: Vec<f64>| {
            v.into_iter()
                .enumerate()
                .fold((0.0, 0), |m, (i, x)| if x > m.0 { (x, i) } else { m })
        };
        let pad = worst(
            (0..self.n_eq())
                .map(|i| self.pad_distance(i).abs())
                .collect(),
        );
        let pad_angle = worst((0..self.n_eq()).map(|i| self.pad_angle_deg(i)).collect());
        let spread = self
            .sys
            .spread_pairs
            .iter()
            .map(|sp| sp.lower.at(&self.kin.q) - sp.upper.at(&self.kin.q))
            .fold(f64::NEG_INFINITY, f64::max);
        Verdict {
            object: clearance.category_distance(Category::Object),
            support: clearance.category_distance(Category::Support),
            links: clearance.category_distance(Category::SelfCollision),
            clearance,
            pad,
            pad_angle,
            spread,
        }
    }

    /// Why a verdict fails, naming the finger, link or link pair and the numbers.
    fn verdict_reason(&self, v: &Verdict) -> Option<String> {
        let pair = |c: Category| {
            v.clearance.category(c).map(|cl| {
                let l = self.exact.checker.label(cl.pair);
                (l.link, l.other, -cl.distance.distance * 1e3)
            })
        };
        let tol = EXACT_PENETRATION_TOLERANCE * 1e3;
        if v.pad.0 > SURFACE_TOLERANCE {
            let f = v.pad.1;
            let d = self.pad_distance(f);
            return Some(format!(
                "the pad of finger '{}' is {:.1} mm {} the object surface (at most {:.1} mm \
                 allowed)",
                self.sys.fingers[f].name,
                d.abs() * 1e3,
                if d > 0.0 { "away from" } else { "inside" },
                SURFACE_TOLERANCE * 1e3
            ));
        }
        if v.object < -EXACT_PENETRATION_TOLERANCE
            && let Some((link, other, depth)) = pair(Category::Object)
        {
            return Some(format!(
                "link '{link}' penetrates the object '{other}' by {depth:.1} mm (at most {tol:.1} \
                 mm allowed)"
            ));
        }
        if v.support < -EXACT_PENETRATION_TOLERANCE
            && let Some((link, _, depth)) = pair(Category::Support)
        {
            return Some(format!(
                "link '{link}' penetrates the support surface by {depth:.1} mm (at most {tol:.1} \
                 mm allowed): the object sits too low to be grasped without touching the table"
            ));
        }
        if v.links < 0.0
            && let Some((a, b, depth)) = pair(Category::SelfCollision)
        {
            return Some(format!("links '{a}' and '{b}' intersect by {depth:.1} mm"));
        }
        if v.pad_angle.0 > PAD_CONE_DEG {
            return Some(format!(
                "finger '{}' touches the object {:.0} deg off its pad normal (at most {:.0} deg \
                 allowed): the contact is on the side or back of the finger",
                self.sys.fingers[v.pad_angle.1].name, v.pad_angle.0, PAD_CONE_DEG
            ));
        }
        if v.spread > 1e-9 {
            return Some(format!(
                "the spread ordering of the fingers is violated by {:.3} rad",
                v.spread
            ));
        }
        None
    }
}

/// `grad_q += J_vᵀ v` for a point Jacobian (rows 0..3 of a 6 × nq Jacobian).
fn add_point_gradient(grad_q: &mut [f64], j: &Matrix6xX<f64>, v: &Vector3<f64>) {
    for (c, g) in grad_q.iter_mut().enumerate() {
        *g += j[(0, c)] * v.x + j[(1, c)] * v.y + j[(2, c)] * v.z;
    }
}

/// Contact points on the surface: each contact-sphere centre moved along the normal by its
/// signed distance (the closest surface point).
fn contact_points(sys: &HandArm, obj: &Object, data: &Data) -> Vec<(Point3<f64>, SurfaceQuery)> {
    sys.fingers
        .iter()
        .map(|f| {
            let p = f.contact_point(data);
            let q = obj.query(&p);
            (q.point, q)
        })
        .collect()
}

/// Hand transmission matrix `M_h = H_v H_vᵀ` and GC (eq. 17-19) at the FK state in `data`.
/// `H = (Gᵀ)⁺ J_h` is formed as `(G Gᵀ)⁺ G J_h` (the same matrix, since `A⁺ = (AᵀA)⁺Aᵀ`) with a
/// fixed-size 6 × 6 pseudo-inverse, so that it allocates nothing.
fn hand_gc(
    sys: &HandArm,
    req: &GraspRequest,
    data: &Data,
    tmp_j: &mut Matrix6xX<f64>,
    gj: &mut Matrix6xX<f64>,
) -> (f64, Matrix3<f64>) {
    let cg = req.object.centroid();
    let mut ggt = Matrix6::<f64>::zeros();
    gj.fill(0.0);
    for f in &sys.fingers {
        let p = f.contact_point(data);
        let q = req.object.query(&p);
        let c = q.point;
        let local = data.frame(f.tip).inverse_transform_point(&c);
        frame_jacobian(&sys.model, data, f.tip, &local.coords, tmp_j);
        let r = c - cg;
        let skew = r.cross_matrix();
        // G_i = [I; [r]×]
        let mut gi = nalgebra::Matrix6x3::<f64>::zeros();
        gi.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        gi.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew);
        ggt += gi * gi.transpose();
        for (h, &qh) in sys.hand_joints.iter().enumerate() {
            let jcol = Vector3::new(tmp_j[(0, qh)], tmp_j[(1, qh)], tmp_j[(2, qh)]);
            let col = gi * jcol;
            for rr in 0..6 {
                gj[(rr, h)] += col[rr];
            }
        }
    }
    // (G Gᵀ)⁺ through a fixed-size symmetric eigendecomposition; eigenvalues below a relative
    // threshold are the rotation about the contact line of two-finger grasps (null space).
    let eig = nalgebra::SymmetricEigen::new(ggt);
    let lmax = eig.eigenvalues.max().max(1e-300);
    let mut inv = Matrix6::<f64>::zeros();
    for k in 0..6 {
        let l = eig.eigenvalues[k];
        if l > 1e-10 * lmax {
            let v = eig.eigenvectors.column(k);
            inv += v * v.transpose() / l;
        }
    }
    let h = inv * &*gj;
    let hv = h.rows(0, 3);
    let m = hv * hv.transpose();
    let m3 = Matrix3::from_iterator(m.iter().copied());
    (indexes::compatibility_index(&m3, &req.task), m3)
}

/// A start: arm configuration from a pre-grasp palm pose (the kinematics IK), hand
/// preshape at mid-range, perturbed per start.
fn seed_start(
    sys: &HandArm,
    req: &GraspRequest,
    start: usize,
    data: &mut Data,
    ik: &mut IkSolver,
    u: &mut [f64],
) {
    let model = &*sys.model;
    let mut rng =
        ChaCha8Rng::seed_from_u64(req.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ start as u64);
    let mut q = model.neutral();
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    if let Some(seed) = &req.arm_seed {
        for &a in &sys.arm_joints {
            q[a] = seed[a].clamp(lo[a], hi[a]);
        }
    }
    // Hand preshape: mid-range, jittered on later starts. Where fingers cross each other there
    // (the T42's and the iHY's overlap at mid-range) the hand is opened towards the lower limits,
    // where the bundled hands are open, a tenth of the range at a time until the fingers are
    // clear: a start with crossed fingers does not untangle them (a hand that no opening clears
    // keeps mid-range).
    let jitter: Vec<f64> = sys
        .hand_joints
        .iter()
        .map(|_| {
            if start == 0 {
                0.0
            } else {
                rng.random_range(-0.15..0.15)
            }
        })
        .collect();
    let preshape = |frac: f64, q: &mut [f64]| {
        for (&h, j) in sys.hand_joints.iter().zip(&jitter) {
            let (l, u) = (finite_or(lo[h], -1.0), finite_or(hi[h], 1.0));
            q[h] = (l + (frac + j) * (u - l)).clamp(l, u);
        }
    };
    // The most closed preshape (of mid-range and on towards open) whose fingers are clear of each
    // other and whose thumb pad faces the other fingertips; else the most closed one with the
    // fingers clear; else mid-range. At mid-range the OB4F's thumb pad faces away from the other
    // tips (cosine -0.44), and its starts found grips with the thumb on top of the object and the
    // fingers on a side.
    let mut clear = None;
    let mut chosen = None;
    for step in 0..=5 {
        let frac = 0.5 - 0.1 * step as f64;
        preshape(frac, &mut q);
        forward_kinematics(model, data, &q);
        if sys.min_crossing_gap(data) >= FINGER_CLEARANCE {
            clear.get_or_insert(frac);
            if thumb_facing(sys, data) >= THUMB_FACING {
                chosen = Some(frac);
                break;
            }
        }
    }
    let chosen = chosen.or(clear).unwrap_or(0.5);
    preshape(chosen, &mut q);
    // A seed's hand posture (a plan's demonstrated final grasp) replaces the preshape where its
    // fingers are clear of each other.
    if let Some(seed) = &req.arm_seed {
        let before = q.clone();
        for (&h, j) in sys.hand_joints.iter().zip(&jitter) {
            let (l, u) = (finite_or(lo[h], -1.0), finite_or(hi[h], 1.0));
            q[h] = (seed[h] + j * (u - l)).clamp(l, u);
        }
        forward_kinematics(model, data, &q);
        if sys.min_crossing_gap(data) < FINGER_CLEARANCE {
            q = before;
        }
    }
    // Fingertip geometry in the palm frame at the preshape.
    forward_kinematics(model, data, &q);
    let palm = *data.frame(sys.palm);
    let tips: Vec<Vector3<f64>> = sys
        .fingers
        .iter()
        .map(|f| palm.inverse_transform_point(&f.contact_point(data)).coords)
        .collect();
    let centroid_local = tips.iter().sum::<Vector3<f64>>() / tips.len() as f64;
    let approach_local = centroid_local
        .try_normalize(1e-9)
        .unwrap_or_else(Vector3::z);
    // Closing direction: thumb (or first finger) towards the others.
    let t = sys.thumb.unwrap_or(0);
    let others = (centroid_local * tips.len() as f64 - tips[t]) / (tips.len() - 1) as f64;
    let close = others - tips[t];
    let close_local = (close - approach_local * approach_local.dot(&close))
        .try_normalize(1e-9)
        .unwrap_or_else(|| approach_local.cross(&Vector3::x()).normalize());
    // Candidate approach directions (world): horizontal from the shoulder, top-down, 45° down.
    let cg = req.object.centroid();
    let shoulder = sys
        .arm_joints
        .first()
        .map(|&a| first_frame_of_q(sys, a, data))
        .unwrap_or_else(Point3::origin);
    let mut horiz = cg - shoulder;
    horiz.z = 0.0;
    let horiz = horiz.try_normalize(1e-9).unwrap_or_else(Vector3::x);
    let down = -Vector3::z();
    let candidates = [horiz, (horiz + down).normalize(), down];
    let k = start % (2 * candidates.len());
    let mut approach = candidates[k / 2];
    let mut roll = if k.is_multiple_of(2) {
        0.0
    } else {
        std::f64::consts::FRAC_PI_2
    };
    if start >= 2 * candidates.len() {
        approach = (approach
            + Vector3::new(
                rng.random_range(-0.4..0.4),
                rng.random_range(-0.4..0.4),
                rng.random_range(-0.4..0.4),
            ))
        .try_normalize(1e-9)
        .unwrap_or(approach);
        roll += rng.random_range(-0.8..0.8);
    }
    // For objects with an axis, close across it: the closing direction is perpendicular to
    // both the approach and the object axis when roll = 0.
    let axis = req.object.pose().rotation * Vector3::z();
    let mut close_world = approach.cross(&axis);
    if close_world.norm() < 1e-3 {
        close_world = approach.cross(&Vector3::x());
        if close_world.norm() < 1e-3 {
            close_world = approach.cross(&Vector3::y());
        }
    }
    let close_world =
        UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(approach), roll)
            * close_world.normalize();
    let r_local = Rotation3::from_basis_unchecked(&[
        approach_local,
        close_local,
        approach_local.cross(&close_local),
    ]);
    let r_world =
        Rotation3::from_basis_unchecked(&[approach, close_world, approach.cross(&close_world)]);
    let rot = UnitQuaternion::from_rotation_matrix(&(r_world * r_local.transpose()));
    let target = Isometry3::from_parts((cg.coords - rot * centroid_local).into(), rot);
    palm_ik(sys, ik, &mut q, &target, None);
    for (k, &i) in sys.arm_joints.iter().chain(&sys.hand_joints).enumerate() {
        u[k] = q[i];
    }
}

/// Cosine between the thumb's pad normal and the direction from its contact point to the other
/// fingers' mean contact point a seed's preshape must reach (60°).
const THUMB_FACING: f64 = 0.5;

/// Cosine between the thumb's pad normal and the direction from its contact point to the other
/// fingers' mean contact point, at the FK in `data` (1 for a hand without thumb or other fingers).
fn thumb_facing(sys: &HandArm, data: &Data) -> f64 {
    let Some(t) = sys.thumb else { return 1.0 };
    if sys.fingers.len() < 2 {
        return 1.0;
    }
    let tip = sys.fingers[t].contact_point(data);
    let others = sys
        .fingers
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != t)
        .map(|(_, f)| f.contact_point(data).coords)
        .sum::<Vector3<f64>>()
        / (sys.fingers.len() - 1) as f64;
    let Some(dir) = (others - tip.coords).try_normalize(1e-9) else {
        return 1.0;
    };
    let f = &sys.fingers[t];
    (data.frame(f.tip).rotation * f.pad_normal).dot(&dir)
}

fn finite_or(v: f64, d: f64) -> f64 {
    if v.is_finite() { v } else { d }
}

/// World position of the frame moved by `q[qi]` (the joint's child frame) at the FK in `data`.
fn first_frame_of_q(sys: &HandArm, qi: usize, data: &Data) -> Point3<f64> {
    let joint = sys.model.q_joint(qi);
    Point3::from(data.frame(joint.child).translation.vector)
}

/// The palm pose by the kinematics IK over the arm joints, from `q`, into `q` (its best
/// configuration, within limits, whether or not it reached the pose): a seeding and repair
/// heuristic, so one attempt of at most 60 iterations of at most 0.1 rad per joint and no random
/// restarts (the answer depends on the request only), position to 0.1 mm and orientation
/// weighted by 0.3 m.
///
/// With `rest` (a configuration), the arm's self-motion is pulled towards it in the Jacobian's
/// null space ([`IkPosture`]), which moves no palm pose to first order: the contact repair backs
/// a plan's grasp out of the object without leaving its goal region.
fn palm_ik(
    sys: &HandArm,
    ik: &mut IkSolver,
    q: &mut [f64],
    target: &Isometry3<f64>,
    rest: Option<&[f64]>,
) {
    let model = &*sys.model;
    let opts = IkOptions {
        position_weight: 1.0,
        orientation_weight: 0.3,
        position_tolerance: 1e-4,
        orientation_tolerance: 1e-4 / 0.3,
        max_iterations_per_attempt: 60,
        max_iterations: 60,
        max_restarts: 0,
        active_joints: Some(sys.arm_joints.clone()),
        // Measured on the exact-verdict survey (180 requests): 146 feasible with 0.3 rad
        // steps, 149 unbounded or 0.2, 154-155 with 0.1-0.15 (150 with the former
        // hand-rolled DLS).
        max_step: Some(0.1),
        posture: rest.map(|r| IkPosture {
            rest: r.to_vec(),
            gain: 0.3,
        }),
        ..IkOptions::default()
    };
    let target = IkTarget {
        frame: sys.palm,
        point_in_frame: Vector3::zeros(),
        pose: *target,
    };
    // No restarts: the generator is never drawn from.
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let r = ik.solve(model, &target, q, &opts, &mut rng);
    q.copy_from_slice(&r.q);
}

#[derive(Clone)]
struct StartOutcome {
    start: usize,
    u: Vec<f64>,
    timed_out: bool,
    report: SolveReport,
    feasible: bool,
    /// The contacts' opposition at `u` ([`Eval::balance_at_last_check`]).
    balance: f64,
    score: f64,
    /// What the contact repair could not do, if anything.
    note: Option<String>,
}

impl StartOutcome {
    /// Feasible with contacts that can balance (see [`FIRM_BALANCE`]).
    fn firm(&self) -> bool {
        firm(self.feasible, self.balance)
    }

    /// Order of preference, lowest first: feasible, then firm, then lowest score.
    fn rank(&self) -> (bool, bool, f64) {
        (!self.feasible, !self.firm(), self.score)
    }
}

fn solver_settings() -> Settings {
    Settings {
        tolerance: 1e-5,
        // 0.1 mm: an order of magnitude inside the feasibility tolerances above.
        constraint_tolerance: 1e-4,
        max_inner_iterations: 500,
        // 12, not the solver's default 30: on the grasp bench (six systems x 15 requests, 1,020
        // starts) 192 starts ran all 30 outer iterations, each raising the penalty fivefold
        // until the inner problems took their 500 iterations, for 48 % of all inner iterations;
        // 4 of them ended exactly feasible. Stopping at 12 keeps every request's verdict (159 of
        // 180 exactly feasible on the seeded-object survey either way) and halves the median
        // request time (wam_ob4f 117 -> 40 ms, pa10_t42 31 -> 6 ms; 15 gives back most of it).
        max_outer_iterations: 12,
        initial_penalty: 100.0,
        penalty_update_factor: 5.0,
        lbfgs_memory: 10,
        // The budget is the iteration counts above; the wall clock is only a safety net (a
        // start it ends is reported as `timed_out`), so the answer does not depend on load.
        max_duration: Some(START_WALL_LIMIT),
    }
}

fn run_start(sys: &HandArm, req: &GraspRequest, start: usize) -> StartOutcome {
    run_start_with(sys, req, start, solver_settings())
}

fn run_start_with(
    sys: &HandArm,
    req: &GraspRequest,
    start: usize,
    settings: Settings,
) -> StartOutcome {
    let eval = std::cell::RefCell::new(Eval::new(sys, req));
    let (n, n_eq, n_ineq) = {
        let e = eval.borrow();
        (e.n(), e.n_eq(), e.n_ineq())
    };
    let mut u = vec![0.0; n];
    {
        let mut e = eval.borrow_mut();
        let e = &mut *e;
        let s = &mut e.scratch;
        seed_start(sys, req, start, &mut s.fd_data, &mut s.ik, &mut u);
    }
    let (lo, hi) = bounds(sys);
    let problem = Problem::new(
        n,
        |x: &[f64]| eval.borrow_mut().cost(x),
        |x: &[f64], g: &mut [f64]| eval.borrow_mut().gradient(x, g),
    )
    .with_bounds(&lo, &hi)
    .expect("model limits are ordered")
    .with_constraints(Constraints::new(
        n_eq,
        n_ineq,
        |x: &[f64], r: &mut [f64]| eval.borrow_mut().residuals(x, r),
        |x: &[f64], d: &[f64], out: &mut [f64]| eval.borrow_mut().jacobian_t(x, d, out),
    ));
    let mut solver = Solver::new(n, n_eq + n_ineq, settings);
    let report = solver
        .solve(&problem, &mut u)
        .expect("problem is well-formed");
    // The optimiser's answer is a posture on the sphere model; place it on the exact geometry
    // and judge it there (see `repair`), inside the goal regions a plan asks for.
    let mut e = eval.borrow_mut();
    let note = e.repair(&mut u);
    let (passed, violation) = e.exact_score(&u);
    let feasible = report.status != SolveStatus::NumericalFailure && passed;
    let score = if feasible {
        e.cost(&u) - PAD_WEIGHT * e.pad_penalty()
    } else {
        violation
    };
    // `exact_score` has just checked `u` exactly (and `cost` leaves that check alone).
    let balance = e.balance_at_last_check();
    drop(e);
    StartOutcome {
        start,
        u,
        timed_out: report.status == SolveStatus::OutOfTime,
        report,
        feasible,
        balance,
        score,
        note,
    }
}

impl Eval<'_> {
    /// The exact verdict at `u` with the request's goal regions: whether it passes, and how far
    /// from passing it is (0 when it passes).
    fn exact_score(&mut self, u: &[f64]) -> (bool, f64) {
        let v = self.verdict(u);
        let outside = region_excess(self.sys, self.req, u);
        let passed = v.passed() && outside.is_none();
        (
            passed,
            v.violation() + outside.map_or(0.0, |(_, d, g)| d - g.radius),
        )
    }
}

/// Polish an infeasible start on the exact geometry (`Eval::polish`); the outcome is replaced
/// when the polished posture is closer to passing.
fn polish_start(sys: &HandArm, req: &GraspRequest, o: &mut StartOutcome) {
    if o.feasible || o.report.status == SolveStatus::NumericalFailure {
        return;
    }
    let mut e = Eval::new(sys, req);
    let mut u = o.u.clone();
    let (passed, score, note) = e.polish(&mut u);
    if passed {
        o.feasible = true;
        o.score = e.cost(&u) - PAD_WEIGHT * e.pad_penalty();
        // The polish's last exact check passed at `u`.
        o.balance = e.balance_at_last_check();
        o.u = u;
        o.note = note;
    } else if score < o.score {
        o.score = score;
        o.u = u;
        o.note = note;
    }
}

/// Infeasible starts of a round polished on the exact geometry (`Eval::polish`) before more
/// starts are run: the least infeasible ones, ties by index, so the choice depends on the
/// round's outcomes only.
const POLISHED_PER_ROUND: usize = 1;

fn bounds(sys: &HandArm) -> (Vec<f64>, Vec<f64>) {
    let m = &sys.model;
    sys.arm_joints
        .iter()
        .chain(&sys.hand_joints)
        .map(|&i| (m.lower_limits()[i], m.upper_limits()[i]))
        .unzip()
}

/// Compute a task-specific grasp: multi-start constrained optimisation of eq. 22-29, best
/// feasible result (lowest cost) returned, or the least-infeasible one with a reason.
pub fn plan_grasp(sys: &HandArm, req: &GraspRequest) -> Result<GraspResult, GraspError> {
    req.validate(sys)?;
    let t0 = Instant::now();
    let mut req = req.clone();
    for t in req.task.iter_mut() {
        t.direction = t.direction.normalize();
    }
    let req = &req;
    // An object beyond the reach ball cannot be grasped from any start: no further rounds.
    let beyond = sys.reach_ball().and_then(|(c, r)| {
        let gap = (req.object.centroid() - c).norm() - req.object.bounding_radius();
        (gap > r).then_some((gap, r))
    });
    let cap = req.max_starts.max(req.starts);
    let mut outcomes = search(sys, req, cap, beyond.is_some());
    let mut starts_used = outcomes.len();
    let mut timed_out = outcomes.iter().any(|o| o.timed_out);
    // No start with every finger on the object passed: a grasp with fewer fingers, the others
    // kept off the object, if one passes (the pencil lying on the table, see `fewer_fingers`).
    let mut grasping: Option<HandArm> = None;
    if !outcomes.iter().any(|o| o.feasible) && beyond.is_none() {
        let (fewer, used, late) = fewer_fingers(sys, req);
        starts_used += used;
        timed_out |= late;
        if let Some((sub, outs)) = fewer {
            grasping = Some(sub);
            outcomes = outs;
        }
    }
    let sys = grasping.as_ref().unwrap_or(sys);
    let starts_feasible = outcomes.iter().filter(|o| o.feasible).count();
    let best = best_outcome(&outcomes);
    let mut result = describe(sys, req, &best.u, Some(best.report.clone()));
    // `describe` leaves the exact verdict's reason in `reason`.
    let exact_reason = result.reason.take();
    result.feasible = best.feasible;
    result.reason = if best.feasible {
        None
    } else {
        // Far from the surface on the optimiser's own model too: the object is out of reach
        // or too large, which says more than the exact pad distance.
        let mut why = if let Some((gap, reach)) = beyond {
            format!(
                "the object is out of reach: its nearest point is at least {gap:.3} m from the \
                 arm's first joint, beyond the {reach:.3} m the fingertips can reach"
            )
        } else if let Some(why) = region_reason(sys, req, &best.u) {
            why
        } else if result.residuals.max_surface_distance > SURFACE_TOLERANCE
            && result.exact.max_pad_distance > SURFACE_TOLERANCE
        {
            out_of_reach(sys, req, &result)
        } else {
            exact_reason.unwrap_or_else(|| "the solver failed numerically".to_owned())
        };
        if beyond.is_none() {
            why.push_str(" in every start found");
        }
        if let Some(note) = best.note.as_ref().filter(|_| beyond.is_none()) {
            why.push_str("; contact repair: ");
            why.push_str(note);
        }
        Some(why)
    };
    result.starts_used = starts_used;
    result.starts_feasible = starts_feasible;
    result.timed_out = timed_out;
    result.time_s = t0.elapsed().as_secs_f64();
    Ok(result)
}

/// The firm feasible outcome of lowest score, else the feasible one, else the least infeasible.
fn best_outcome(outcomes: &[StartOutcome]) -> &StartOutcome {
    outcomes
        .iter()
        .min_by(|a, b| a.rank().partial_cmp(&b.rank()).expect("finite scores"))
        .expect("at least one start")
}

/// Rounds of starts: the request's `starts`, then doubling up to `cap` while no start is firm
/// and exactly feasible (one round when the object is `beyond` reach). Start k is seeded from
/// k alone, so the starts run are a prefix of one fixed sequence and the answer does not depend
/// on threads or load. A round without a feasible start polishes its least infeasible one.
fn search(sys: &HandArm, req: &GraspRequest, cap: usize, beyond: bool) -> Vec<StartOutcome> {
    let mut outcomes: Vec<StartOutcome> = Vec::new();
    let mut round = req.starts.min(cap);
    loop {
        let first = outcomes.len();
        let threads = req.threads.clamp(1, round);
        let mut more: Vec<StartOutcome> = crate::parallel::map_indexed(
            round,
            threads,
            || (),
            |_, k| run_start(sys, req, first + k),
        );
        more.sort_by_key(|o| o.start);
        if !more.iter().any(|o| o.feasible) && !beyond {
            let mut order: Vec<usize> = (0..more.len()).collect();
            order.sort_by(|&a, &b| more[a].score.total_cmp(&more[b].score).then(a.cmp(&b)));
            order.truncate(POLISHED_PER_ROUND);
            let polished: Vec<StartOutcome> = crate::parallel::map_indexed(
                order.len(),
                req.threads.clamp(1, order.len()),
                || (),
                |_, k| {
                    let mut p = more[order[k]].clone();
                    polish_start(sys, req, &mut p);
                    p
                },
            );
            for (k, p) in order.into_iter().zip(polished) {
                more[k] = p;
            }
        }
        outcomes.append(&mut more);
        if outcomes.iter().any(|o| o.firm()) || outcomes.len() >= cap || beyond {
            return outcomes;
        }
        round = outcomes.len().min(cap - outcomes.len());
    }
}

/// Starts per finger subset in [`fewer_fingers`]: two rounds of the default four.
const SUBSET_STARTS: usize = 8;

/// A grasp with fewer fingers on the object when none with every finger passed: the subsets of
/// the hand's fingers from one finger fewer down to two (three for `Q_AGP`), each searched with
/// up to [`SUBSET_STARTS`] starts, the idle fingers' links kept out of the object and the
/// support; the first size with a feasible subset answers, its best start over the subsets (in
/// a fixed order, so the answer stays deterministic). Humans pick a pencil off a table with the
/// thumb and one or two fingers, the others curled away; with every finger required on it, the
/// iHY and OB4F found none (their third and fourth fingertips meet the thin cylinder with the
/// side or the end of the finger, 64-90 deg off the pad). Not in the paper, whose eq. 27 puts
/// every fingertip on the object. Returns the subset's system and outcomes, the starts run and
/// whether any hit the wall-clock safety net.
fn fewer_fingers(
    sys: &HandArm,
    req: &GraspRequest,
) -> (Option<(HandArm, Vec<StartOutcome>)>, usize, bool) {
    let m = sys.fingers.len();
    let least = req.quality.min_fingers().max(2);
    let (mut used, mut late) = (0, false);
    let req = &GraspRequest {
        starts: req.starts.min(SUBSET_STARTS),
        ..req.clone()
    };
    for size in (least..m).rev() {
        let mut found: Option<(HandArm, Vec<StartOutcome>)> = None;
        for keep in subsets(m, size) {
            let sub = sys.with_contact_fingers(&keep);
            let outs = search(&sub, req, SUBSET_STARTS, false);
            used += outs.len();
            late |= outs.iter().any(|o| o.timed_out);
            if !outs.iter().any(|o| o.feasible) {
                continue;
            }
            let better = found
                .as_ref()
                .is_none_or(|(_, f)| best_outcome(&outs).rank() < best_outcome(f).rank());
            if better {
                found = Some((sub, outs));
            }
        }
        if found.is_some() {
            return (found, used, late);
        }
    }
    (None, used, late)
}

/// The `size`-element subsets of `0..m`, ascending, in lexicographic order.
fn subsets(m: usize, size: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    let mut pick: Vec<usize> = (0..size).collect();
    loop {
        out.push(pick.clone());
        let Some(i) = (0..size).rev().find(|&i| pick[i] < m - size + i) else {
            return out;
        };
        pick[i] += 1;
        for k in i + 1..size {
            pick[k] = pick[k - 1] + 1;
        }
    }
}

fn out_of_reach(sys: &HandArm, req: &GraspRequest, r: &GraspResult) -> String {
    let res = &r.residuals;
    let cg = req.object.centroid();
    let palm_reach = r
        .contacts
        .iter()
        .map(|c| (Point3::from(c.point) - cg).norm())
        .fold(0.0, f64::max);
    let worst = r
        .contacts
        .iter()
        .max_by(|a, b| {
            a.surface_distance
                .abs()
                .total_cmp(&b.surface_distance.abs())
        })
        .map(|c| c.finger.clone())
        .unwrap_or_default();
    let hand_span = sys.fingers.len();
    format!(
        "fingertip '{worst}' stays {:.1} mm from the object surface: the object is out of reach \
         of the arm or too large for the {hand_span}-finger hand (object radius {:.1} mm, \
         contacts up to {:.1} mm from its centroid)",
        res.max_surface_distance * 1e3,
        req.object.bounding_radius() * 1e3,
        palm_reach * 1e3
    )
}

/// The goal region `u` is furthest outside, with its distance from the centre (`None`: inside
/// every region).
fn region_excess<'r>(
    sys: &HandArm,
    req: &'r GraspRequest,
    u: &[f64],
) -> Option<(Vec<f64>, f64, &'r GoalRegion)> {
    if req.goal_regions.is_empty() {
        return None;
    }
    let mut q = sys.model.neutral();
    for (&i, &v) in sys.arm_joints.iter().chain(&sys.hand_joints).zip(u) {
        q[i] = v;
    }
    req.goal_regions
        .iter()
        .filter_map(|g| {
            let mut diff = vec![0.0; g.center.len()];
            let d = g.distance(&q, &mut diff);
            (d > g.radius).then_some((d - g.radius, d, g))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, d, g)| (q, d, g))
}

/// Why `u` is no goal of the plan's model: the region, and the joints furthest from its centre.
fn region_reason(sys: &HandArm, req: &GraspRequest, u: &[f64]) -> Option<String> {
    let (q, d, g) = region_excess(sys, req, u)?;
    let names = sys.model.joint_names();
    let mut worst: Vec<(f64, usize)> = g
        .joints
        .iter()
        .zip(g.centre())
        .map(|(&j, c)| ((q[j] - c).abs(), j))
        .collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    let list: Vec<String> = worst
        .iter()
        .take(3)
        .map(|(dq, j)| format!("{} {:.2} rad from the region's centre", names[*j], dq))
        .collect();
    Some(format!(
        "the grasp lies outside the motion model's certified goal region of the {} joints \
         ({d:.3} from its centre, radius {:.3}; furthest: {})",
        g.name,
        g.radius,
        list.join(", ")
    ))
}

/// Evaluate every term, index, residual and ellipsoid at a decision vector.
pub(crate) fn describe(
    sys: &HandArm,
    req: &GraspRequest,
    u: &[f64],
    report: Option<SolveReport>,
) -> GraspResult {
    let mut e = Eval::new(sys, req);
    // Eq. 22 without the optimiser's pad penalty.
    let cost = e.cost(u) - PAD_WEIGHT * e.pad_penalty();
    let n_eq = e.n_eq();
    let mut r = vec![0.0; n_eq + e.n_ineq()];
    e.residuals(u, &mut r);
    let v = e.verdict(u);
    let model = &*sys.model;
    let names = model.joint_names();
    let q_arm = sys
        .arm_joints
        .iter()
        .map(|&i| NamedJoint {
            name: names[i].clone(),
            value: e.kin.q[i],
        })
        .collect();
    let q_hand = sys
        .hand_joints
        .iter()
        .map(|&i| NamedJoint {
            name: names[i].clone(),
            value: e.kin.q[i],
        })
        .collect();
    // Contacts where the pads touch: the exact witness point on the object, its outward normal
    // and the pad's signed distance (the contact sphere's for a finger without pad shapes).
    let cps = contact_points(sys, &req.object, &e.kin.data);
    let contacts: Vec<Contact> = sys
        .fingers
        .iter()
        .zip(&cps)
        .enumerate()
        .map(|(i, (f, (p, q)))| {
            let (p, n) = e.exact.pads[i].map_or((*p, q.normal), |d| (d.point_b, -d.normal));
            Contact {
                finger: f.name.clone(),
                point: [p.x, p.y, p.z],
                normal: [n.x, n.y, n.z],
                surface_distance: e.pad_distance(i),
                pad_angle_deg: e.pad_angle_deg(i),
            }
        })
        .collect();
    let points: Vec<Point3<f64>> = contacts.iter().map(|c| Point3::from(c.point)).collect();
    let normal_balance = e.balance_at_last_check();
    let label = |c: Category| {
        v.clearance.category(c).map(|cl| {
            let l = e.exact.checker.label(cl.pair);
            match c {
                Category::SelfCollision => format!("{} / {}", l.link, l.other),
                _ => l.link,
            }
        })
    };
    // Without a pair: clear by a metre, to keep JSON finite.
    let finite_or_clear = |d: f64| if d.is_finite() { d } else { 1.0 };
    let passed = v.passed();
    let exact = ExactCheck {
        passed,
        max_object_penetration: -finite_or_clear(v.object),
        object_link: label(Category::Object),
        max_support_penetration: -finite_or_clear(v.support),
        support_link: label(Category::Support),
        min_link_separation: finite_or_clear(v.links),
        closest_links: label(Category::SelfCollision),
        max_pad_distance: v.pad.0,
        max_pad_angle_deg: v.pad_angle.0,
        normal_balance,
        firm: firm(passed, normal_balance),
    };
    let exact_reason = e.verdict_reason(&v);
    let m_arm = indexes::transmission_matrix(&e.kin.jv_arm);
    let mut tmp = Matrix6xX::zeros(model.nq());
    let mut gj = Matrix6xX::zeros(sys.hand_joints.len());
    let (gc, m_hand) = hand_gc(sys, req, &e.kin.data, &mut tmp, &mut gj);
    let mut arm6 = Matrix6xX::zeros(sys.arm_joints.len());
    for (a, &qa) in sys.arm_joints.iter().enumerate() {
        arm6.set_column(a, &e.kin.palm_j.column(qa));
    }
    let ns = sys.spread_pairs.len();
    let s = sys.link_spheres.len();
    let obj_pen = r[n_eq + ns..n_eq + ns + s]
        .iter()
        .fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    let pair_row = e.pair_row();
    let link_row = e.link_pair_row();
    // Rows `r_a + r_b + δ − ‖c_a − c_b‖` → the smallest gap; 1 m without rows.
    let min_gap = |rows: &[f64]| {
        rows.iter()
            .map(|v| FINGER_CLEARANCE - v)
            .fold(f64::INFINITY, f64::min)
            .min(1.0)
    };
    let min_link_sep = min_gap(&r[link_row..]);
    let min_sep = min_gap(&r[pair_row..link_row]);
    let plane_pen = r[n_eq + ns + s..e.pad_row()]
        .iter()
        .fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    let (lo, hi) = bounds(sys);
    let margin = u
        .iter()
        .zip(lo.iter().zip(&hi))
        .map(|(x, (l, h))| (x - l).min(h - x))
        .fold(f64::INFINITY, f64::min)
        .min(1e6); // unbounded (continuous) joints: keep JSON finite
    let coupling = model
        .joints()
        .iter()
        .filter(|j| j.mimic.is_some())
        .filter_map(|j| {
            let m = j.mimic.as_ref()?;
            let driver = model.joint(&m.joint)?.actuation?;
            let act = j.actuation?;
            // The joint's value as the model applies it vs. the declared coupling (eq. 26).
            let applied = act.multiplier * e.kin.q[act.q_index] + act.offset;
            let declared = m.multiplier
                * (driver.multiplier * e.kin.q[driver.q_index] + driver.offset)
                + m.offset;
            Some((applied - declared).abs())
        })
        .fold(0.0, f64::max);
    GraspResult {
        feasible: false,
        reason: exact_reason,
        q_arm,
        q_hand,
        contacts,
        idle_fingers: sys.idle_fingers.iter().map(|f| f.name.clone()).collect(),
        terms: Terms {
            cost,
            tc: indexes::compatibility_index(&m_arm, &req.task),
            gc,
            quality: req.quality,
            q_dc: indexes::q_dc(&points, &req.object.centroid()),
            q_agp: indexes::q_agp(&points),
            d: e.elbow_term(),
            manipulability: crate::kinematics::manipulability(&arm6),
            arm_ratios: req
                .task
                .iter()
                .map(|t| indexes::transmission_ratio(&m_arm, &t.direction, t.kind))
                .collect(),
            hand_ratios: req
                .task
                .iter()
                .map(|t| indexes::transmission_ratio(&m_hand, &t.direction, t.kind))
                .collect(),
        },
        residuals: Residuals {
            max_surface_distance: r[..n_eq].iter().fold(0.0, |m, v| m.max(v.abs())),
            max_object_penetration: if s > 0 { obj_pen } else { f64::NEG_INFINITY }.max(-1.0),
            max_support_penetration: if plane_pen.is_finite() {
                plane_pen
            } else {
                -1.0
            },
            min_limit_margin: margin,
            max_spread_violation: r[n_eq..n_eq + ns]
                .iter()
                .fold(f64::NEG_INFINITY, |m, &v| m.max(v))
                .max(-10.0),
            max_coupling_error: coupling,
            min_finger_separation: min_sep,
            min_link_separation: min_link_sep,
        },
        exact,
        arm_ellipsoids: Ellipsoids::of(&m_arm),
        hand_ellipsoids: Ellipsoids::of(&m_hand),
        solver: report.as_ref().map(SolverSummary::from),
        time_s: 0.0,
        starts_used: 0,
        starts_feasible: 0,
        timed_out: false,
    }
}

/// Shared model handle re-exported for callers building [`HandArm`]s.
pub type SharedModel = Arc<crate::kinematics::Model>;

#[path = "repair.rs"]
mod repair;

#[cfg(test)]
#[path = "optimizer_tests.rs"]
pub(crate) mod tests;
