//! Contact repair on the exact geometry, after the optimiser.
//!
//! Why a separate stage: the optimiser works on a cheap sphere model of the links (eq. 27-29 as
//! point sets), which is not the robot: measured on the seeded objects, 0 of 90 of its grasps
//! were clean against the URDF collision shapes (links 7-17 mm deep in the object, median).
//! Putting exact rows inside the optimiser did not converge (every start infeasible, branch
//! `issue-23-exact-rows-wip`), so the optimiser's answer is taken as a posture to start from and
//! placed on the real geometry here, deterministically and with a bounded number of exact
//! distance queries:
//!
//! 1. the palm and wrist (every link no finger moves) are backed off the object and the support
//!    along the exact penetration normal (damped least squares on the arm, orientation kept);
//! 2. each finger is moved along its flexion coordinate only (couplings hold by substitution:
//!    mimic joints follow their driver; spread and opposition joints stay), first stepping to
//!    bracket the posture where its deepest link just touches the object, then bisecting to a
//!    contact band of `[-0.5, +0.25]` mm.
//!
//! The verdict (`Verdict::passed`) is then taken on the exact distances at the repaired posture;
//! the repair never decides feasibility itself.

use crate::geometry::{CollisionChecker, SignedDistance, Target};
use crate::kinematics::{Data, forward_kinematics};

use crate::grasp::system::HandArm;

use super::{Eval, ExactGeometry, finite_or, palm_ik};

/// Deepest a finger may sit in the object after placement (m); half the verdict's tolerance.
const BAND_LO: f64 = -5e-4;
/// Farthest a placed finger may stay from the object (m).
const BAND_HI: f64 = 2.5e-4;
/// Flexion step while bracketing (rad). At the bundled fingertips (≤ 0.12 m from the first
/// flexion axis) a step moves a link at most ~4 mm, less than the thinnest finger (16 mm) plus
/// the thinnest seeded object (8 mm), so a link cannot jump across an object between steps.
const STEP: f64 = 0.03;
const MAX_STEPS: usize = 120;
const BISECTIONS: usize = 40;
const BACK_OFF_ROUNDS: usize = 4;
const LIFT_ROUNDS: usize = 3;

/// A finger's exact geometry, resolved once per request.
#[derive(Debug, Clone)]
pub(super) struct FingerGeometry {
    /// Object pairs (indices into the checker's pairs) of every link of the finger.
    pub links: Vec<usize>,
    /// Object pairs of its pad links (the rigid body carrying the tip frame).
    pub pads: Vec<usize>,
    /// The flexion coordinate (`q` index) and the sign that closes the finger.
    pub flex: Option<(usize, f64)>,
}

/// The exact geometry of every finger, plus the object and support pairs of the links no finger
/// moves (palm, wrist, arm), and the support pairs of the finger links.
pub(super) fn finger_geometry(
    sys: &HandArm,
    checker: &CollisionChecker,
) -> (Vec<FingerGeometry>, Vec<usize>, Vec<usize>) {
    let model = &*sys.model;
    let geo = &sys.geometry;
    let chains = sys.finger_chains();
    // A shape belongs to a finger when it lies on that finger's chain only and a hand joint
    // moves it (the palm lies on every chain; a shared spread link on two).
    let finger_of_shape: Vec<Option<usize>> = geo
        .shapes()
        .iter()
        .map(|s| {
            let moved = model
                .supporting_q(s.frame)
                .iter()
                .any(|q| sys.hand_joints.contains(q));
            let mut on = chains
                .iter()
                .enumerate()
                .filter(|(_, c)| c.contains(&s.frame));
            match (moved, on.next(), on.next()) {
                (true, Some((f, _)), None) => Some(f),
                _ => None,
            }
        })
        .collect();
    let mut fingers: Vec<FingerGeometry> = sys
        .fingers
        .iter()
        .map(|_| FingerGeometry {
            links: Vec::new(),
            pads: Vec::new(),
            flex: None,
        })
        .collect();
    let mut body = Vec::new();
    let mut finger_support = Vec::new();
    for (p, pair) in checker.pairs().iter().enumerate() {
        match (pair.other, finger_of_shape[pair.shape]) {
            (Target::Object, Some(f)) => {
                fingers[f].links.push(p);
                let frame = geo.shapes()[pair.shape].frame;
                if geo.body(frame) == geo.body(sys.fingers[f].tip) {
                    fingers[f].pads.push(p);
                }
            }
            (Target::Object | Target::Support, None) => body.push(p),
            (Target::Support, Some(_)) => finger_support.push(p),
            _ => {}
        }
    }
    // Flexion coordinate: among the hand coordinates moving this finger's tip and no other
    // finger's, the one whose motion carries the tip furthest along its pad normal (at least
    // 60° towards it), measured at the mid-range hand.
    let mut data = Data::new(model);
    let mut q = model.neutral();
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    for &h in &sys.hand_joints {
        q[h] = 0.5 * (finite_or(lo[h], -1.0) + finite_or(hi[h], 1.0));
    }
    forward_kinematics(model, &mut data, &q);
    let tip_state = |data: &Data, f: usize| {
        let fi = &sys.fingers[f];
        let pose = data.frame(fi.tip);
        (pose * nalgebra::Point3::from(fi.tip_offset), pose.rotation)
    };
    let supports: Vec<Vec<usize>> = sys
        .fingers
        .iter()
        .map(|f| model.supporting_q(f.tip))
        .collect();
    for f in 0..sys.fingers.len() {
        let (p0, rot) = tip_state(&data, f);
        let mut best: Option<(usize, f64, f64)> = None;
        for &c in supports[f]
            .iter()
            .filter(|c| sys.hand_joints.contains(c))
            .filter(|c| (0..supports.len()).all(|g| g == f || !supports[g].contains(c)))
        {
            let h = 1e-4;
            let x = q[c];
            q[c] = x + h;
            forward_kinematics(model, &mut data, &q);
            let (p1, _) = tip_state(&data, f);
            q[c] = x;
            let dp = rot.inverse() * (p1 - p0) / h;
            let along = dp.dot(&sys.fingers[f].pad_normal);
            if dp.norm() > 1e-9
                && along.abs() >= 0.5 * dp.norm()
                && best.is_none_or(|b| along.abs() > b.2)
            {
                best = Some((c, along.signum(), along.abs()));
            }
        }
        forward_kinematics(model, &mut data, &q);
        fingers[f].flex = best.map(|(c, s, _)| (c, s));
    }
    (fingers, body, finger_support)
}

impl ExactGeometry {
    /// Smallest exact distance of any of `pairs` at the checker's last update (m).
    fn min_distance(&mut self, pairs_of: impl Fn(&Self) -> &[usize]) -> Option<SignedDistance> {
        let mut best: Option<SignedDistance> = None;
        for k in 0..pairs_of(self).len() {
            let p = pairs_of(self)[k];
            let d = self.checker.pair_distance(&mut self.cd, p);
            if best.is_none_or(|b| d.distance < b.distance) {
                best = Some(d);
            }
        }
        best
    }
}

impl Eval<'_> {
    /// Exact distance of finger `f`'s deepest link to the object with its flexion coordinate
    /// at `s` (the rest of `self.kin.q` unchanged).
    fn finger_gap(&mut self, f: usize, qi: usize, s: f64) -> f64 {
        self.kin.q[qi] = s;
        self.exact.checker.update(&mut self.exact.cd, &self.kin.q);
        self.exact
            .min_distance(|x| &x.fingers_geo[f].links)
            .map_or(f64::INFINITY, |d| d.distance)
    }

    /// Place the arm and every finger on the exact geometry (see the module docs). `u` is
    /// updated in place; the returned note says which finger could not be placed, if any.
    pub(super) fn repair(&mut self, u: &mut [f64]) -> Option<String> {
        self.set_q(u);
        self.kin.fresh = false;
        let mut note = None;
        // A finger placed on the object may press into the table (the contact spheres keep the
        // pad centres above it, not the phalanx corners): lift the hand by that depth and place
        // the fingers again.
        for _ in 0..LIFT_ROUNDS {
            self.back_off();
            note = None;
            for f in 0..self.sys.fingers.len() {
                if let Err(msg) = self.place_finger(f) {
                    note.get_or_insert(msg);
                }
            }
            self.exact.checker.update(&mut self.exact.cd, &self.kin.q);
            let deepest = self
                .exact
                .min_distance(|x| &x.finger_support)
                .map_or(f64::INFINITY, |d| d.distance);
            if deepest >= BAND_LO {
                break;
            }
        }
        for (k, &i) in self.layout.sel.iter().enumerate() {
            u[k] = self.kin.q[i];
        }
        self.kin.fresh = false;
        note
    }

    /// Move the palm out of the object and the support, and the fingers out of the support,
    /// along the exact penetration normal.
    fn back_off(&mut self) {
        for _ in 0..BACK_OFF_ROUNDS {
            self.exact.checker.update(&mut self.exact.cd, &self.kin.q);
            let body = self.exact.min_distance(|x| &x.body_pairs);
            let fingers = self.exact.min_distance(|x| &x.finger_support);
            let Some(d) = [body, fingers]
                .into_iter()
                .flatten()
                .min_by(|a, b| a.distance.total_cmp(&b.distance))
            else {
                return;
            };
            if d.distance >= 0.0 {
                return;
            }
            // `normal` points from the robot's link into the other member: move against it.
            let shift = d.normal * (d.distance - 1e-3);
            forward_kinematics(&self.sys.model, &mut self.scratch.fd_data, &self.kin.q);
            let mut target = *self.scratch.fd_data.frame(self.sys.palm);
            target.translation.vector += shift;
            self.exact.q_saved.clone_from(&self.kin.q);
            // A plan's grasp keeps to its goal region: the self-motion is pulled towards the
            // regions' centre while the palm backs off.
            let rest = (!self.req.goal_regions.is_empty()).then(|| {
                let mut rest = self.kin.q.clone();
                for g in &self.req.goal_regions {
                    for (&j, c) in g.joints.iter().zip(g.centre()) {
                        rest[j] = c;
                    }
                }
                rest
            });
            palm_ik(
                self.sys,
                &mut self.scratch.ik,
                &mut self.kin.q,
                &target,
                rest.as_deref(),
            );
            // The seeding IK is a heuristic: keep its answer only where it reached the shifted
            // palm pose (within 1 mm, 0.01 rad); at joint limits it may wander off instead.
            forward_kinematics(&self.sys.model, &mut self.scratch.fd_data, &self.kin.q);
            let at = self.scratch.fd_data.frame(self.sys.palm);
            let reached = (at.translation.vector - target.translation.vector).norm() < 1e-3
                && (at.rotation.inverse() * target.rotation).angle() < 1e-2;
            if !reached {
                self.kin.q.clone_from(&self.exact.q_saved);
                return;
            }
        }
    }

    /// Move finger `f` along its flexion coordinate until its deepest link touches the object
    /// within the contact band.
    fn place_finger(&mut self, f: usize) -> Result<(), String> {
        let Some((qi, close)) = self.exact.fingers_geo[f].flex else {
            return Ok(());
        };
        let model = &*self.sys.model;
        let lo = finite_or(model.lower_limits()[qi], -10.0);
        let hi = finite_or(model.upper_limits()[qi], 10.0);
        let name = self.sys.fingers[f].name.clone();
        let s0 = self.kin.q[qi];
        let g0 = self.finger_gap(f, qi, s0);
        if (BAND_LO..=BAND_HI).contains(&g0) {
            return Ok(());
        }
        // Walk from s0 in `dir` until the gap crosses the band; (clear end, penetrating end).
        let walk = |e: &mut Self, dir: f64| -> Option<(f64, f64)> {
            let mut s = s0;
            let mut g = g0;
            for _ in 0..MAX_STEPS {
                let n = (s + dir * STEP).clamp(lo, hi);
                if n == s {
                    return None;
                }
                let gn = e.finger_gap(f, qi, n);
                if (BAND_LO..=BAND_HI).contains(&gn) {
                    return Some((n, n));
                }
                if (g > BAND_HI) != (gn > BAND_HI) {
                    return Some(if gn > BAND_HI { (n, s) } else { (s, n) });
                }
                (s, g) = (n, gn);
            }
            None
        };
        // Clear: close onto the object. Penetrating: open out of it, or (object on the back of
        // the finger) close out of it.
        let bracket = if g0 > BAND_HI {
            walk(self, close)
        } else {
            walk(self, -close).or_else(|| walk(self, close))
        };
        let Some((mut a, mut b)) = bracket else {
            let s_end = self.kin.q[qi];
            self.kin.q[qi] = s0;
            return Err(if g0 > BAND_HI {
                format!(
                    "finger '{name}' cannot close onto the object: its links stay {:.1} mm away \
                     over its flexion range",
                    1e3 * self.finger_gap(f, qi, s_end.clamp(lo, hi)).min(g0)
                )
            } else {
                format!(
                    "finger '{name}' stays {:.1} mm inside the object over its flexion range",
                    -1e3 * g0
                )
            });
        };
        if a == b {
            self.kin.q[qi] = a;
            return Ok(());
        }
        for _ in 0..BISECTIONS {
            let m = 0.5 * (a + b);
            let g = self.finger_gap(f, qi, m);
            if (BAND_LO..=BAND_HI).contains(&g) {
                a = m;
                break;
            }
            if g > BAND_HI { a = m } else { b = m }
        }
        self.kin.q[qi] = a;
        Ok(())
    }
}

/// Palm steps of the exact polish, coarse to fine: (translation m, rotation rad).
const POLISH_STEPS: [(f64, f64); 3] = [(4e-3, 0.08), (2e-3, 0.04), (1e-3, 0.02)];
/// Candidate postures one polish may judge (each a palm IK, a contact repair and a verdict).
pub(super) const POLISH_BUDGET: usize = 48;

impl Eval<'_> {
    /// A deterministic pattern search on the exact verdict around a repaired posture that fails
    /// it: the palm is translated along and rotated about the world axes (about the fingertips'
    /// centroid), each candidate placed again by [`Self::repair`] and kept when its verdict is
    /// closer to passing ([`Verdict::violation`]), with steps halving down to 1 mm / 0.02 rad.
    ///
    /// Why: the optimiser's contact spheres sit inside the pads, several millimetres short of the
    /// fingertip's end, so on a thin object (the 8 mm pencil on the table) its answers touch
    /// with the pad's end edge, a few degrees beyond the verdict's cone, or just graze another
    /// link; nothing in the sphere model can see this, the exact geometry can. Returns whether
    /// the verdict at the updated `u` passes and its violation; `u` is only ever replaced by a
    /// better candidate.
    pub(super) fn polish(&mut self, u: &mut [f64]) -> (bool, f64, Option<String>) {
        let (passed, mut best) = self.exact_score(u);
        let mut note = None;
        if passed {
            return (true, 0.0, note);
        }
        let n = u.len();
        let mut cand = vec![0.0; n];
        let mut budget = POLISH_BUDGET;
        'levels: for &(dt, dr) in &POLISH_STEPS {
            let mut improved = true;
            while improved {
                improved = false;
                for axis in 0..6 {
                    for sign in [1.0, -1.0] {
                        if budget == 0 {
                            break 'levels;
                        }
                        budget -= 1;
                        cand.copy_from_slice(u);
                        if !self.move_palm(&mut cand, axis, sign * if axis < 3 { dt } else { dr }) {
                            continue;
                        }
                        let cand_note = self.repair(&mut cand);
                        let (passed, score) = self.exact_score(&cand);
                        if passed || score < best {
                            best = score;
                            u.copy_from_slice(&cand);
                            note = cand_note;
                            improved = true;
                            if passed {
                                return (true, 0.0, note);
                            }
                        }
                    }
                }
            }
        }
        (false, best, note)
    }

    /// Move the palm of posture `cand` by `delta` along world axis `axis` (0-2, m) or about world
    /// axis `axis − 3` through the fingertips' centroid (rad), through the arm's IK; false when
    /// the IK does not reach the moved pose.
    fn move_palm(&mut self, cand: &mut [f64], axis: usize, delta: f64) -> bool {
        self.set_q(cand);
        self.kin.fresh = false;
        let model = &*self.sys.model;
        forward_kinematics(model, &mut self.scratch.fd_data, &self.kin.q);
        let mut target = *self.scratch.fd_data.frame(self.sys.palm);
        if axis < 3 {
            target.translation.vector[axis] += delta;
        } else {
            let m = self.sys.fingers.len() as f64;
            let pivot = self
                .sys
                .fingers
                .iter()
                .map(|f| f.contact_point(&self.scratch.fd_data).coords)
                .sum::<nalgebra::Vector3<f64>>()
                / m;
            let mut w = nalgebra::Vector3::zeros();
            w[axis - 3] = delta;
            let r = nalgebra::UnitQuaternion::from_scaled_axis(w);
            let p = target.translation.vector - pivot;
            target.translation.vector = pivot + r * p;
            target.rotation = r * target.rotation;
        }
        palm_ik(
            self.sys,
            &mut self.scratch.ik,
            &mut self.kin.q,
            &target,
            None,
        );
        forward_kinematics(model, &mut self.scratch.fd_data, &self.kin.q);
        let at = self.scratch.fd_data.frame(self.sys.palm);
        let reached = (at.translation.vector - target.translation.vector).norm() < 5e-4
            && (at.rotation.inverse() * target.rotation).angle() < 5e-3;
        if reached {
            for (k, &i) in self.layout.sel.iter().enumerate() {
                cand[k] = self.kin.q[i];
            }
        }
        reached
    }
}
