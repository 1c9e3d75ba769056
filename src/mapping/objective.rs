//! The mapping objective `F = w_x·P + w_o·Σ d_o + w_D·D` (eq. 1-5) and its analytic gradient.
//!
//! Terms are `Term { weight, objective }` pairs so a weight can never drift from its term. One
//! [`Evaluator`] runs forward kinematics once per point and the frame Jacobians once per gradient;
//! every term reads the shared result. Value and gradient are written into caller buffers.

use std::sync::Arc;

use nalgebra::{Matrix6xX, Point3, UnitQuaternion, Vector3};

use super::MappingError;
use super::goals::{FingerGoal, MAX_FINGERS};
use super::registration::{BodyAxes, RobotAnchor};
use crate::geometry::RobotGeometry;
use crate::kinematics::{
    Data, FrameId, Model, SpreadPair, System, forward_kinematics, frame_jacobian,
};
use crate::optim::{MAX_PAIRS, PairOrder};

/// Weights of eq. 5, plus the elbow swivel term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weights {
    /// `w_x`, on the squared fingertip position errors (eq. 1), per m².
    pub position: f64,
    /// `w_o`, on the quaternion distances (eq. 2-3), per rad.
    pub orientation: f64,
    /// `w_D`, on the squared elbow distances (eq. 4), per m².
    pub elbow: f64,
    /// `w_φ`, on `‖n_robot − n_human‖² = 2 (1 − cos Δφ)`: the elbow swivel difference (the unit
    /// normals `n` from the shoulder–wrist axis to the elbow). Not in the paper; see
    /// [`Objective::Swivel`].
    pub swivel: f64,
}

impl Default for Weights {
    /// Fingertip positions dominate (1 cm costs 1e-4); the robot hands' tip frames can rarely
    /// match a human fingertip frame, so orientation only breaks ties (1 rad costs 1e-4). The
    /// anthropomorphism terms resolve the arm's redundancy: a 10 cm elbow distance costs 1e-4
    /// (eq. 4, as before) and a 15° swivel difference 6.8e-4. Chosen on the default study over
    /// the six systems (`mapping::tests::probe_registration_and_weights`): `swivel = 1e-2`
    /// brings the median swivel difference from 96-156° (both terms off) to 55-71°; `1e-1`
    /// only gains another 3-25° for 3-6 cm more fingertip error; `elbow = 5e-3` let a wam_ihy
    /// finger into the object before the grasp.
    fn default() -> Self {
        Self {
            position: 1.0,
            orientation: 1e-4,
            elbow: 1e-2,
            swivel: 1e-2,
        }
    }
}

impl Weights {
    /// Rejects negative, non-finite and all-zero weights.
    pub fn validate(&self) -> Result<(), MappingError> {
        for (field, w) in [
            ("position", self.position),
            ("orientation", self.orientation),
            ("elbow", self.elbow),
            ("swivel", self.swivel),
        ] {
            if !(w.is_finite() && w >= 0.0) {
                return Err(MappingError::InvalidWeight { field, value: w });
            }
        }
        if self.position == 0.0
            && self.orientation == 0.0
            && self.elbow == 0.0
            && self.swivel == 0.0
        {
            return Err(MappingError::AllWeightsZero);
        }
        Ok(())
    }

    /// The weights with the anthropomorphism terms off (`elbow = swivel = 0`): the baseline the
    /// tests compare the default against.
    pub fn without_anthropomorphism(self) -> Self {
        Self {
            elbow: 0.0,
            swivel: 0.0,
            ..self
        }
    }

    /// The weighted terms (zero weights dropped).
    pub fn terms(&self) -> Vec<Term> {
        [
            (self.position, Objective::FingertipPosition),
            (self.orientation, Objective::FingertipOrientation),
            (self.elbow, Objective::ElbowDistance),
            (self.swivel, Objective::Swivel),
        ]
        .into_iter()
        .filter(|(w, _)| *w != 0.0)
        .map(|(weight, objective)| Term { weight, objective })
        .collect()
    }
}

/// One summand of eq. 5. The set is closed (the paper's three terms), hence an enum: cheap,
/// `Copy`, and exhaustively matched by the metrics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Objective {
    /// `P = Σ_i ‖x_i − x_goal_i‖²` (eq. 1).
    FingertipPosition,
    /// `Σ_i d_o(h_c_i, h_g_i)`, `d_o = min(acos⟨h_c,h_g⟩, acos⟨h_c,−h_g⟩) = acos|⟨h_c,h_g⟩|`
    /// (eq. 2-3).
    FingertipOrientation,
    /// `D = Σ_j ‖s_j − s_elbow‖²` over the descriptor's robot joint frames (eq. 4).
    ElbowDistance,
    /// `‖n_r − n_h‖²`, `n = unit(e − â (e·â))`, `e` = elbow − shoulder, `â` the shoulder→wrist
    /// axis: the squared chord between the robot's and the human's elbow swivel directions,
    /// `2 (1 − cos Δφ)`. Eq. 4 alone pulls the robot elbow towards the human elbow *point*,
    /// which a robot with longer links cannot reach, so the swivel it settles on is whichever
    /// side the nearest point lies; comparing directions makes the arm plane humanlike for any
    /// link lengths (issue 16). Needs the system's shoulder, elbow and wrist frames.
    Swivel,
}

/// A weight paired with its objective.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Term {
    pub weight: f64,
    pub objective: Objective,
}

/// Goals of one frame, in the robot base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameGoals {
    /// `fingers[0..m]`, in the robot's finger order.
    pub fingers: [FingerGoal; MAX_FINGERS],
    /// Registered human elbow (`s_elbow` of eq. 4).
    pub elbow: Point3<f64>,
    /// The human elbow's swivel direction `n_h` (unit, or zero for a straight arm).
    pub swivel: Vector3<f64>,
    /// Registered human shoulder and wrist (the swivel axis; metrics only).
    pub shoulder: Point3<f64>,
    pub wrist: Point3<f64>,
}

impl Default for FrameGoals {
    fn default() -> Self {
        Self {
            fingers: [FingerGoal::default(); MAX_FINGERS],
            elbow: Point3::origin(),
            swivel: Vector3::zeros(),
            shoulder: Point3::origin(),
            wrist: Point3::origin(),
        }
    }
}

/// The robot frames whose origins span the arm plane: shoulder centre, elbow, wrist.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ArmFrames {
    pub shoulder: FrameId,
    pub elbow: FrameId,
    pub wrist: FrameId,
}

/// The unit direction from the shoulder→wrist axis to the elbow (zero when the arm is straight).
pub fn swivel_direction(
    shoulder: &Point3<f64>,
    elbow: &Point3<f64>,
    wrist: &Point3<f64>,
) -> Vector3<f64> {
    let a = wrist - shoulder;
    let e = elbow - shoulder;
    let aa = a.norm_squared();
    if aa < 1e-18 {
        return Vector3::zeros();
    }
    let p = e - a * (e.dot(&a) / aa);
    let n = p.norm();
    if n < 1e-9 { Vector3::zeros() } else { p / n }
}

/// The elbow swivel angle: the rotation about the shoulder→wrist axis from the lowest point of
/// the elbow circle (the direction of `−up` across the axis) to the elbow, right-handed about
/// the axis, in `(−π, π]` (for a right arm reaching forward, positive is inward/up-left).
pub fn swivel_angle(
    shoulder: &Point3<f64>,
    elbow: &Point3<f64>,
    wrist: &Point3<f64>,
    up: &Vector3<f64>,
) -> f64 {
    let a = (wrist - shoulder).normalize();
    let n = swivel_direction(shoulder, elbow, wrist);
    let mut r = -up + a * up.dot(&a);
    if r.norm() < 1e-9 {
        // Axis along the vertical: measure from the base's forward axis instead.
        r = Vector3::x() - a * a.x;
    }
    let r = r.normalize();
    a.cross(&r).dot(&n).atan2(r.dot(&n))
}

/// The per-system description the objective needs, names resolved to typed ids once.
#[derive(Clone, Debug)]
pub struct MappingModel {
    pub model: Arc<Model>,
    /// Fingertip frames, robot finger order (`m = tips.len()`).
    pub tips: Vec<FrameId>,
    /// Index into `tips` of the finger that takes the human thumb.
    pub thumb: usize,
    /// The robot joint frames of eq. 4 (shoulder and end effector excluded by the descriptor).
    pub elbow_frames: Vec<FrameId>,
    /// The arm's shoulder centre (default registration target).
    pub shoulder: FrameId,
    /// Shoulder, elbow and wrist frames of the swivel term (`None`: no arm, e.g. a hand on a
    /// fixed base, or no elbow frame).
    pub arm: Option<ArmFrames>,
    /// Spread orderings (eq. 28) between two different coordinates; those within one coordinate
    /// (e.g. the iHY's mirrored spread joints) are folded into `lower`/`upper`.
    pub orders: Vec<PairOrder>,
    /// Bounds on `q` (eq. 7): the independent joints' limits intersected with the limits of every
    /// mimic joint they drive (`l ≤ k q + o ≤ u`), so couplings substituted into `q` respect
    /// the coupled joints' own limits too.
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// The system's collision shapes: every mapped frame's exact support and object clearances
    /// are measured with them (`None`: not measured).
    pub geometry: Option<Arc<RobotGeometry>>,
    /// The wrist frame's pose when no joint moves it (a hand on a fixed base).
    pub fixed_wrist: Option<nalgebra::Isometry3<f64>>,
}

impl MappingModel {
    /// The mapping view of an arm-hand system.
    pub fn from_system(system: &System) -> Result<Self, MappingError> {
        Self::new(
            system.model.clone(),
            system.fingers.iter().map(|f| f.tip).collect(),
            system.thumb,
            system.elbow_frames.clone(),
            system.shoulder_frame,
            system.elbow_frames.first().map(|&elbow| ArmFrames {
                shoulder: system.shoulder_frame,
                elbow,
                wrist: system.wrist_frame,
            }),
            &system.spread_pairs,
        )
        .map(|mm| {
            // No joint moves the wrist: a hand on a fixed base, registered relative to it.
            let fixed_wrist = system.arm_joints.is_empty().then(|| {
                let mut data = Data::new(&system.model);
                forward_kinematics(&system.model, &mut data, &mm.neutral());
                *data.frame(system.wrist_frame)
            });
            Self {
                geometry: Some(Arc::new(RobotGeometry::from_system(system))),
                fixed_wrist,
                ..mm
            }
        })
    }

    pub fn new(
        model: Arc<Model>,
        tips: Vec<FrameId>,
        thumb: usize,
        elbow_frames: Vec<FrameId>,
        shoulder: FrameId,
        arm: Option<ArmFrames>,
        spread_pairs: &[SpreadPair],
    ) -> Result<Self, MappingError> {
        if tips.is_empty() || tips.len() > MAX_FINGERS || thumb >= tips.len() {
            return Err(MappingError::UnsupportedHand {
                fingers: tips.len(),
                thumb,
            });
        }
        let mut lower = model.lower_limits().to_vec();
        let mut upper = model.upper_limits().to_vec();
        for joint in model.joints() {
            let (Some(_), Some(act)) = (&joint.mimic, joint.actuation) else {
                continue;
            };
            if act.multiplier == 0.0 {
                continue;
            }
            let a = (joint.limits.lower - act.offset) / act.multiplier;
            let b = (joint.limits.upper - act.offset) / act.multiplier;
            let (a, b) = if a <= b { (a, b) } else { (b, a) };
            let k = act.q_index;
            lower[k] = lower[k].max(a);
            upper[k] = upper[k].min(b);
        }
        // Eq. 28: m_a q_i + o_a ≤ m_b q_j + o_b.
        let mut orders = Vec::new();
        for pair in spread_pairs {
            let (a, b) = (pair.lower, pair.upper);
            if a.q_index == b.q_index {
                // (m_a − m_b) q ≤ o_b − o_a: a bound on one coordinate.
                let (c, r) = (a.multiplier - b.multiplier, b.offset - a.offset);
                let k = a.q_index;
                if c > 0.0 {
                    upper[k] = upper[k].min(r / c);
                } else if c < 0.0 {
                    lower[k] = lower[k].max(r / c);
                } else if r < 0.0 {
                    return Err(MappingError::InfeasibleSpreadPair {
                        lower: pair.lower_joint.clone(),
                        upper: pair.upper_joint.clone(),
                    });
                }
            } else {
                orders.push(PairOrder {
                    i: a.q_index,
                    j: b.q_index,
                    alpha: a.multiplier,
                    beta: -b.multiplier,
                    gamma: b.offset - a.offset,
                });
            }
        }
        let mut used = vec![false; lower.len()];
        for o in &orders {
            if orders.len() > MAX_PAIRS || used[o.i] || used[o.j] {
                return Err(MappingError::UnsupportedSpreadPairs {
                    reason: format!(
                        "at most {MAX_PAIRS} spread pairs on disjoint coordinates are supported"
                    ),
                });
            }
            used[o.i] = true;
            used[o.j] = true;
        }
        for k in 0..lower.len() {
            if lower[k].is_nan() || upper[k].is_nan() || lower[k] > upper[k] {
                return Err(MappingError::EmptyJointRange {
                    joint: model.joint_names()[k].clone(),
                    lower: lower[k],
                    upper: upper[k],
                });
            }
        }
        Ok(Self {
            model,
            tips,
            thumb,
            elbow_frames,
            shoulder,
            arm,
            orders,
            lower,
            upper,
            geometry: None,
            fixed_wrist: None,
        })
    }

    pub fn fingers(&self) -> usize {
        self.tips.len()
    }

    /// The robot side of the default registration: the descriptor's shoulder centre at the
    /// neutral configuration, base axes x forward / z up, and the reach as the largest
    /// shoulder-to-fingertip distance over a fixed seeded sample of configurations (a sample, not
    /// a closed form, so it holds for any arm; 512 samples land within a few % of the maximum).
    pub fn anchor(&self) -> RobotAnchor {
        use rand::{RngExt, SeedableRng};
        let model = &self.model;
        let mut data = Data::new(model);
        let mut q = self.neutral();
        forward_kinematics(model, &mut data, &q);
        let shoulder = Point3::from(data.frame(self.shoulder).translation.vector);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5ea5);
        let mut reach = 0.0_f64;
        for _ in 0..512 {
            for (k, x) in q.iter_mut().enumerate() {
                let l = self.lower[k].max(-std::f64::consts::PI);
                let u = self.upper[k].min(std::f64::consts::PI);
                *x = if l < u { rng.random_range(l..=u) } else { l };
            }
            forward_kinematics(model, &mut data, &q);
            for &tip in &self.tips {
                reach = reach.max((data.frame(tip).translation.vector - shoulder.coords).norm());
            }
        }
        RobotAnchor {
            shoulder,
            axes: BodyAxes::default(),
            reach,
            // The shipped systems stand on the table they work on (`grasp::objects`).
            support: 0.0,
            fixed_wrist: self.fixed_wrist,
        }
    }

    /// Mid-range configuration (0, clamped into range, where a coordinate is unbounded).
    pub fn neutral(&self) -> Vec<f64> {
        self.lower
            .iter()
            .zip(&self.upper)
            .map(|(&l, &u)| {
                if l.is_finite() && u.is_finite() {
                    0.5 * (l + u)
                } else {
                    0.0_f64.max(l).min(u)
                }
            })
            .collect()
    }
}

/// Quaternion distance of eq. 2-3 and its gradient with respect to the world angular velocity
/// of the current frame.
///
/// With `r = h_g ⊗ h_c*`: `⟨h_c, h_g⟩ = r_w` and, since `ḣ_c = ½ ω ⊗ h_c`, `∂⟨h_c,h_g⟩/∂ω =
/// ½ r_v`. `d = acos|r_w|` and `√(1 − r_w²) = ‖r_v‖` give `∂d/∂ω = −½ sign(r_w) r_v/‖r_v‖`:
/// a unit-length direction (the distance is a cone at `d = 0`, where the subgradient 0 is used).
#[inline]
pub fn quaternion_distance(
    current: &UnitQuaternion<f64>,
    goal: &UnitQuaternion<f64>,
) -> (f64, Vector3<f64>) {
    let r = goal * current.conjugate();
    let w = r.w;
    let v = r.imag();
    let d = w.abs().min(1.0).acos();
    let n = v.norm();
    let g = if n > 1e-12 {
        v * (-0.5 * w.signum() / n)
    } else {
        Vector3::zeros()
    };
    (d, g)
}

/// Per-worker scratch: FK data, frame Jacobians, memo of the last evaluated point.
pub struct Evaluator {
    pub(crate) mm: MappingModel,
    data: Data,
    tip_jac: Vec<Matrix6xX<f64>>,
    elbow_jac: Vec<Matrix6xX<f64>>,
    /// Shoulder, elbow, wrist Jacobians of the swivel term.
    arm_jac: [Matrix6xX<f64>; 3],
    last_q: Vec<f64>,
    fk_valid: bool,
    jac_valid: bool,
    arm_jac_valid: bool,
}

impl Evaluator {
    pub fn new(mm: MappingModel) -> Self {
        let nq = mm.model.nq();
        Self {
            data: Data::new(&mm.model),
            tip_jac: vec![Matrix6xX::zeros(nq); mm.tips.len()],
            elbow_jac: vec![Matrix6xX::zeros(nq); mm.elbow_frames.len()],
            arm_jac: std::array::from_fn(|_| Matrix6xX::zeros(nq)),
            last_q: vec![f64::NAN; nq],
            fk_valid: false,
            jac_valid: false,
            arm_jac_valid: false,
            mm,
        }
    }

    pub fn model(&self) -> &MappingModel {
        &self.mm
    }

    pub fn nq(&self) -> usize {
        self.mm.model.nq()
    }

    /// Runs FK at `q` unless it already ran there.
    pub fn update(&mut self, q: &[f64]) {
        if self.fk_valid && self.last_q.as_slice() == q {
            return;
        }
        forward_kinematics(&self.mm.model, &mut self.data, q);
        self.last_q.copy_from_slice(q);
        self.fk_valid = true;
        self.jac_valid = false;
        self.arm_jac_valid = false;
    }

    /// The FK placements of the last updated point, lent to the clearance penalty (which swaps
    /// them into its collision scratch and back, so they come back unchanged).
    pub(crate) fn kinematics_mut(&mut self) -> &mut Data {
        &mut self.data
    }

    fn update_arm_jacobians(&mut self) {
        let Some(arm) = self.mm.arm else { return };
        if self.arm_jac_valid {
            return;
        }
        let zero = Vector3::zeros();
        for (id, j) in [arm.shoulder, arm.elbow, arm.wrist]
            .iter()
            .zip(self.arm_jac.iter_mut())
        {
            frame_jacobian(&self.mm.model, &self.data, *id, &zero, j);
        }
        self.arm_jac_valid = true;
    }

    /// Robot shoulder, elbow and wrist origins after [`Self::update`] (`None` without arm
    /// frames).
    pub fn arm_points(&self) -> Option<[Point3<f64>; 3]> {
        let arm = self.mm.arm?;
        Some(
            [arm.shoulder, arm.elbow, arm.wrist]
                .map(|f| Point3::from(self.data.frame(f).translation.vector)),
        )
    }

    fn update_jacobians(&mut self) {
        if self.jac_valid {
            return;
        }
        let zero = Vector3::zeros();
        for (id, j) in self.mm.tips.iter().zip(self.tip_jac.iter_mut()) {
            frame_jacobian(&self.mm.model, &self.data, *id, &zero, j);
        }
        for (id, j) in self.mm.elbow_frames.iter().zip(self.elbow_jac.iter_mut()) {
            frame_jacobian(&self.mm.model, &self.data, *id, &zero, j);
        }
        self.jac_valid = true;
    }

    /// Fingertip `i` world position after [`Self::update`].
    pub fn tip_position(&self, i: usize) -> Point3<f64> {
        Point3::from(self.data.frame(self.mm.tips[i]).translation.vector)
    }

    /// Fingertip `i` world orientation after [`Self::update`].
    pub fn tip_orientation(&self, i: usize) -> UnitQuaternion<f64> {
        self.data.frame(self.mm.tips[i]).rotation
    }

    /// Eq. 4 joint position `j` after [`Self::update`].
    pub fn elbow_point(&self, j: usize) -> Point3<f64> {
        Point3::from(self.data.frame(self.mm.elbow_frames[j]).translation.vector)
    }

    /// Unweighted value of one objective at the last updated point.
    pub fn objective_value(&self, objective: Objective, goals: &FrameGoals) -> f64 {
        let m = self.mm.tips.len();
        match objective {
            Objective::FingertipPosition => (0..m)
                .map(|i| (self.tip_position(i) - goals.fingers[i].position).norm_squared())
                .sum(),
            Objective::FingertipOrientation => (0..m)
                .map(|i| {
                    quaternion_distance(&self.tip_orientation(i), &goals.fingers[i].orientation).0
                })
                .sum(),
            Objective::ElbowDistance => (0..self.mm.elbow_frames.len())
                .map(|j| (self.elbow_point(j) - goals.elbow).norm_squared())
                .sum(),
            Objective::Swivel => match self.arm_points() {
                Some([s, e, w]) => (swivel_direction(&s, &e, &w) - goals.swivel).norm_squared(),
                None => 0.0,
            },
        }
    }

    /// `F(q)` (eq. 5).
    pub fn value(&mut self, terms: &[Term], goals: &FrameGoals, q: &[f64]) -> f64 {
        self.update(q);
        terms
            .iter()
            .map(|t| t.weight * self.objective_value(t.objective, goals))
            .sum()
    }

    /// `∇F(q)` into `grad` (overwritten); returns `F(q)`.
    pub fn value_and_gradient(
        &mut self,
        terms: &[Term],
        goals: &FrameGoals,
        q: &[f64],
        grad: &mut [f64],
    ) -> f64 {
        self.update(q);
        self.update_jacobians();
        if terms.iter().any(|t| t.objective == Objective::Swivel) {
            self.update_arm_jacobians();
        }
        grad.fill(0.0);
        let mut f = 0.0;
        for t in terms {
            f += t.weight * self.add_gradient(t.objective, t.weight, goals, grad);
        }
        f
    }

    /// `grad += weight · ∇objective`; returns the unweighted objective value.
    fn add_gradient(
        &self,
        objective: Objective,
        weight: f64,
        goals: &FrameGoals,
        grad: &mut [f64],
    ) -> f64 {
        let m = self.mm.tips.len();
        let mut value = 0.0;
        match objective {
            Objective::FingertipPosition => {
                // ∂‖x − g‖²/∂q = 2 J_vᵀ (x − g)
                for i in 0..m {
                    let e = self.tip_position(i) - goals.fingers[i].position;
                    value += e.norm_squared();
                    add_jt(&self.tip_jac[i], 0, &(e * (2.0 * weight)), grad);
                }
            }
            Objective::FingertipOrientation => {
                for i in 0..m {
                    let (d, dw) = quaternion_distance(
                        &self.tip_orientation(i),
                        &goals.fingers[i].orientation,
                    );
                    value += d;
                    add_jt(&self.tip_jac[i], 3, &(dw * weight), grad);
                }
            }
            Objective::ElbowDistance => {
                for j in 0..self.mm.elbow_frames.len() {
                    let e = self.elbow_point(j) - goals.elbow;
                    value += e.norm_squared();
                    add_jt(&self.elbow_jac[j], 0, &(e * (2.0 * weight)), grad);
                }
            }
            Objective::Swivel => {
                let Some([s, el, w]) = self.arm_points() else {
                    return 0.0;
                };
                // T = ‖n − n_h‖², n = p/|p|, p = e − a (e·a)/(a·a), e = el − s, a = w − s.
                let (a, e) = (w - s, el - s);
                let aa = a.norm_squared();
                if aa < 1e-18 {
                    return goals.swivel.norm_squared();
                }
                let ea = e.dot(&a);
                let p = e - a * (ea / aa);
                let pn = p.norm();
                if pn < 1e-9 {
                    // Straight arm: no swivel direction; the term is flat here.
                    return goals.swivel.norm_squared();
                }
                let n = p / pn;
                let d = n - goals.swivel;
                value = d.norm_squared();
                // ∂T/∂p = (2/|p|)(I − n nᵀ) d
                let gp = (d - n * n.dot(&d)) * (2.0 / pn);
                // ∂p/∂e = I − a aᵀ/(a·a) (symmetric)
                let ag = a.dot(&gp);
                let ge = gp - a * (ag / aa);
                // ∂p/∂a: dp = −[da (a·e) + a (e·da)]/aa + 2 a (a·e)(a·da)/aa²
                let ga = -(gp * ea + e * ag) / aa + a * (2.0 * ea * ag / (aa * aa));
                add_jt(&self.arm_jac[1], 0, &(ge * weight), grad);
                add_jt(&self.arm_jac[2], 0, &(ga * weight), grad);
                add_jt(&self.arm_jac[0], 0, &(-(ge + ga) * weight), grad);
            }
        }
        value
    }
}

/// `grad += J[row0..row0+3, :]ᵀ v`.
#[inline]
fn add_jt(j: &Matrix6xX<f64>, row0: usize, v: &Vector3<f64>, grad: &mut [f64]) {
    for (k, g) in grad.iter_mut().enumerate() {
        let c = j.column(k);
        *g += c[row0] * v.x + c[row0 + 1] * v.y + c[row0 + 2] * v.z;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kinematics::{JointKind, JointLimits, Mimic, ModelBuilder};
    use nalgebra::{Isometry3, Translation3};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A 7-joint arm with a 3-finger hand: finger 0 (thumb) 2 joints, fingers 1-2 a coupled
    /// spread joint (mimic −1) and two flexion joints whose distal one mimics the proximal.
    pub(crate) fn toy_system() -> MappingModel {
        let mut b = ModelBuilder::new("base");
        let lim = |l: f64, u: f64| JointLimits::new(l, u, 2.0, 10.0);
        let ax = |x: f64, y: f64, z: f64| nalgebra::Unit::new_normalize(Vector3::new(x, y, z));
        let at = |x: f64, y: f64, z: f64| Isometry3::translation(x, y, z);
        let axes = [
            ax(0., 0., 1.),
            ax(0., 1., 0.),
            ax(0., 0., 1.),
            ax(0., 1., 0.),
            ax(0., 0., 1.),
            ax(0., 1., 0.),
            ax(0., 0., 1.),
        ];
        let offs = [
            at(0., 0., 0.3),
            at(0., 0., 0.05),
            at(0., 0., 0.25),
            at(0.04, 0., 0.25),
            at(-0.04, 0., 0.2),
            at(0., 0., 0.2),
            at(0., 0., 0.05),
        ];
        let mut parent = b.root();
        let mut elbow = Vec::new();
        for k in 0..7 {
            parent = b
                .add_joint(
                    &format!("a{k}"),
                    parent,
                    &format!("arm{k}"),
                    JointKind::Revolute { axis: axes[k] },
                    offs[k],
                    lim(-2.5, 2.5),
                    None,
                )
                .unwrap();
            if k == 3 || k == 4 {
                elbow.push(parent);
            }
        }
        let palm = b.add_fixed_frame("palm", parent, at(0., 0., 0.06)).unwrap();
        let mut tips = Vec::new();
        // Thumb.
        let t1 = b
            .add_joint(
                "t1",
                palm,
                "t1l",
                JointKind::Revolute {
                    axis: ax(1., 0., 0.),
                },
                at(0., -0.03, 0.0),
                lim(-0.2, 1.4),
                None,
            )
            .unwrap();
        let t2 = b
            .add_joint(
                "t2",
                t1,
                "t2l",
                JointKind::Revolute {
                    axis: ax(1., 0., 0.),
                },
                at(0., 0., 0.05),
                lim(0.0, 1.2),
                None,
            )
            .unwrap();
        tips.push(
            b.add_fixed_frame(
                "t_tip",
                t2,
                Isometry3::from_parts(
                    Translation3::new(0., 0., 0.04),
                    UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
                ),
            )
            .unwrap(),
        );
        for (f, y, mult) in [(1, 0.02, 1.0), (2, -0.02, -1.0)] {
            let spread_mimic = (f == 2).then(|| Mimic {
                joint: "f1s".into(),
                multiplier: mult,
                offset: 0.0,
            });
            let s = b
                .add_joint(
                    &format!("f{f}s"),
                    palm,
                    &format!("f{f}sl"),
                    JointKind::Revolute {
                        axis: ax(0., 0., 1.),
                    },
                    at(0.0, y, 0.0),
                    lim(-0.6, 0.6),
                    spread_mimic,
                )
                .unwrap();
            let p = b
                .add_joint(
                    &format!("f{f}p"),
                    s,
                    &format!("f{f}pl"),
                    JointKind::Revolute {
                        axis: ax(-1., 0., 0.),
                    },
                    at(0.0, 0.0, 0.02),
                    lim(0.0, 1.5),
                    None,
                )
                .unwrap();
            let d = b
                .add_joint(
                    &format!("f{f}d"),
                    p,
                    &format!("f{f}dl"),
                    JointKind::Revolute {
                        axis: ax(-1., 0., 0.),
                    },
                    at(0.0, 0.0, 0.05),
                    lim(0.0, 1.0),
                    Some(Mimic {
                        joint: format!("f{f}p"),
                        multiplier: 0.8,
                        offset: 0.0,
                    }),
                )
                .unwrap();
            tips.push(
                b.add_fixed_frame(&format!("f{f}_tip"), d, at(0.0, 0.0, 0.04))
                    .unwrap(),
            );
        }
        let model = Arc::new(b.build().unwrap());
        let shoulder = model.frame_id("arm1").unwrap();
        let arm = ArmFrames {
            shoulder,
            elbow: elbow[0],
            wrist: model.frame_id("arm6").unwrap(),
        };
        MappingModel::new(model, tips, 0, elbow, shoulder, Some(arm), &[]).unwrap()
    }

    pub(crate) fn random_goals(rng: &mut ChaCha8Rng, m: usize) -> FrameGoals {
        let mut g = FrameGoals::default();
        let mut p = || {
            Point3::new(
                rng.random_range(-0.8..0.8),
                rng.random_range(-0.8..0.8),
                rng.random_range(0.0..1.2),
            )
        };
        g.elbow = p();
        for i in 0..m {
            g.fingers[i].position = p();
        }
        g.swivel = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .normalize();
        for i in 0..m {
            g.fingers[i].orientation = UnitQuaternion::from_euler_angles(
                rng.random_range(-3.0..3.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(-3.0..3.0),
            );
        }
        g
    }

    /// Central differences of `F` at √ε-scale steps against the analytic gradient.
    pub(crate) fn check_gradient(mm: MappingModel, seed: u64, samples: usize) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let m = mm.fingers();
        let (lo, hi) = (mm.lower.clone(), mm.upper.clone());
        let mut ev = Evaluator::new(mm);
        let terms = Weights {
            position: 1.3,
            orientation: 0.7,
            elbow: 0.4,
            swivel: 0.9,
        }
        .terms();
        let nq = ev.nq();
        let mut g = vec![0.0; nq];
        for _ in 0..samples {
            let goals = random_goals(&mut rng, m);
            let q: Vec<f64> = (0..nq)
                .map(|k| {
                    let (l, u) = (lo[k].max(-3.0), hi[k].min(3.0));
                    rng.random_range(l..=u)
                })
                .collect();
            let f = ev.value_and_gradient(&terms, &goals, &q, &mut g);
            assert!((f - ev.value(&terms, &goals, &q)).abs() <= 1e-12 * f.abs().max(1.0));
            let h = 1e-6;
            let mut x = q.clone();
            for k in 0..nq {
                x[k] = q[k] + h;
                let fp = ev.value(&terms, &goals, &x);
                x[k] = q[k] - h;
                let fm = ev.value(&terms, &goals, &x);
                x[k] = q[k];
                let fd = (fp - fm) / (2.0 * h);
                assert!(
                    (fd - g[k]).abs() <= 1e-6 * (1.0 + g[k].abs()),
                    "coordinate {k} ({}): analytic {} vs central difference {fd}",
                    ev.model().model.joint_names()[k],
                    g[k]
                );
            }
        }
    }

    #[test]
    fn gradient_matches_central_differences_on_a_coupled_arm_hand() {
        check_gradient(toy_system(), 7, 20);
    }

    pub(crate) const SYSTEMS: [&str; 6] = [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ];

    pub(crate) fn system(name: &str) -> System {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("robots/systems")
            .join(format!("{name}.toml"));
        System::from_file(&path).unwrap()
    }

    #[test]
    fn gradient_matches_central_differences_for_all_six_systems() {
        for (k, name) in SYSTEMS.iter().enumerate() {
            let mm = MappingModel::from_system(&system(name)).unwrap();
            check_gradient(mm, 100 + k as u64, 6);
        }
    }

    #[test]
    fn ihy_spread_ordering_folds_into_a_bound() {
        let sys = system("wam_ihy");
        let mm = MappingModel::from_system(&sys).unwrap();
        // finger2_spread = −finger1_spread, so value(f2) ≤ value(f1) ⇔ q_f1 ≥ 0.
        let k = sys.model.q_index("ihy_finger1_spread").unwrap();
        assert_eq!(mm.lower[k], sys.model.lower_limits()[k].max(0.0));
        assert!(mm.orders.is_empty());
    }

    #[test]
    fn mimic_limits_tighten_the_driver_bounds() {
        let mm = toy_system();
        let k = mm.model.q_index("f1p").unwrap();
        // f1d = 0.8 f1p must stay in [0, 1]: f1p ≤ 1.25 although its own limit is 1.5.
        assert!((mm.upper[k] - 1.25).abs() < 1e-12 && mm.lower[k] == 0.0);
        let s = mm.model.q_index("f1s").unwrap();
        assert!(mm.lower[s] == -0.6 && mm.upper[s] == 0.6);
    }

    #[test]
    fn quaternion_distance_is_half_the_rotation_angle_and_antipodal_blind() {
        let a = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let b = a * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.8);
        let (d, _) = quaternion_distance(&a, &b);
        assert!((d - 0.4).abs() < 1e-12);
        let neg = UnitQuaternion::new_unchecked(-b.into_inner());
        assert!((quaternion_distance(&a, &neg).0 - d).abs() < 1e-12);
        assert_eq!(quaternion_distance(&a, &a).0, 0.0);
    }

    #[test]
    fn quaternion_distance_gradient_matches_finite_differences_in_angular_velocity() {
        let goal = UnitQuaternion::from_euler_angles(-0.7, 0.4, 2.0);
        for cur in [
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            // Beyond 90° of quaternion angle: the antipodal branch is the active one.
            UnitQuaternion::new_unchecked(
                -UnitQuaternion::from_euler_angles(2.5, 0.1, -2.9).into_inner(),
            ),
        ] {
            let (_, g) = quaternion_distance(&cur, &goal);
            let h = 1e-6;
            for k in 0..3 {
                let mut w = Vector3::zeros();
                w[k] = h;
                let plus = UnitQuaternion::from_scaled_axis(w) * cur;
                let minus = UnitQuaternion::from_scaled_axis(-w) * cur;
                let fd = (quaternion_distance(&plus, &goal).0
                    - quaternion_distance(&minus, &goal).0)
                    / (2.0 * h);
                assert!((fd - g[k]).abs() < 1e-7, "axis {k}: fd {fd} vs {}", g[k]);
            }
        }
    }

    #[test]
    fn weights_reject_negative_nan_and_all_zero() {
        assert!(Weights::default().validate().is_ok());
        let bad = |position, orientation, elbow| {
            Weights {
                position,
                orientation,
                elbow,
                swivel: 0.0,
            }
            .validate()
            .unwrap_err()
        };
        assert!(matches!(
            bad(-1.0, 0.0, 0.0),
            MappingError::InvalidWeight {
                field: "position",
                ..
            }
        ));
        assert!(matches!(
            bad(1.0, f64::NAN, 0.0),
            MappingError::InvalidWeight {
                field: "orientation",
                ..
            }
        ));
        assert!(matches!(
            bad(1.0, 0.0, f64::INFINITY),
            MappingError::InvalidWeight { field: "elbow", .. }
        ));
        assert_eq!(bad(0.0, 0.0, 0.0), MappingError::AllWeightsZero);
        assert_eq!(
            Weights {
                position: 1.0,
                orientation: 0.0,
                elbow: 0.0,
                swivel: 0.0,
            }
            .terms()
            .len(),
            1
        );
    }
}
