//! The approach phase of a grasp (issue 18, item 3): a pre-grasp standoff with the hand
//! preshaped open, then the final approach and the closing.
//!
//! A humanlike path that runs straight into the grasp configuration sweeps the half-closed
//! hand across the object (a pa10_t42 proximal link passed 44 mm through the bottle that way).
//! The pre-grasp is the grasp's palm pose moved back along the approach direction (palm towards
//! the fingertips' centroid) by a standoff, reached by the arm alone (damped least squares
//! seeded at the grasp, so the arm stays on the grasp's branch), with every independent hand
//! joint opened part of the way towards the limit that spreads the fingertips. It is accepted
//! only where the exact distances of the URDF collision shapes keep a margin from the object
//! and the obstacles, the support no closer than at the grasp, and no link inside another.
//!
//! The path is then reshaped ([`shape_path`]): the humanlike path runs over the first part of
//! the progress with a smooth offset that carries its end from the grasp to the pre-grasp (the
//! hand opens on the way, as a human's does before it closes), then the arm moves the palm in
//! along the straight line to the grasp with the hand still open ([`PreGrasp::line`]), and the
//! hand closes last. Not in the paper, whose flow ends at the grasp configuration itself.

use nalgebra::{Isometry3, Translation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::geometry::{Category, CheckData, CollisionChecker, SceneShape};
use crate::kinematics::{IkOptions, IkSolver, IkTarget};

use super::clearance::scene_checker;
use super::optimizer::EXACT_PENETRATION_TOLERANCE;
use super::{HandArm, Object};

/// How the pre-grasp is sought.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApproachOptions {
    /// Palm standoff from the grasp along the approach direction (m); the search also tries
    /// 1.5 and 2 times it.
    pub standoff: f64,
    /// How far each hand joint opens from its grasp value towards its open limit (fraction of
    /// that distance); the search also tries half of it and none.
    pub open: f64,
    /// Clearance kept from the object and the obstacles at the pre-grasp (m).
    pub margin: f64,
    /// Share of the path's progress the final approach and closing take.
    pub share: f64,
}

/// A standoff the size of a fingertip's travel when the hand closes: far enough that the
/// opened fingers clear the object, near enough that the final approach stays a short,
/// nearly straight move. (Requests ask for one; the service's default is no approach phase.)
pub const DEFAULT_STANDOFF: f64 = 0.06;

impl Default for ApproachOptions {
    fn default() -> Self {
        ApproachOptions {
            standoff: DEFAULT_STANDOFF,
            open: 0.6,
            margin: 5e-3,
            share: 0.2,
        }
    }
}

/// Largest palm rotation from the grasp's at a pre-grasp (rad): the final approach should not
/// turn the hand much.
const MAX_TILT: f64 = 0.1;

/// Support clearance a pre-grasp may lose against the grasp's own (m): a link resting on the
/// table at the grasp (a PA10 base on its mounting plane) stays there to rounding.
const SUPPORT_SLACK: f64 = 1e-4;

/// The pre-grasp configuration and how it was found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreGrasp {
    /// Full joint vector (model order).
    pub q: Vec<f64>,
    /// Palm displacement from the grasp along `direction` (m), and that unit direction (robot
    /// base frame).
    pub standoff_m: f64,
    pub direction: [f64; 3],
    /// Fraction of the way each hand joint opened towards its open limit.
    pub open_fraction: f64,
    /// Exact clearance at the pre-grasp: from the object, the support and the obstacles (m;
    /// `+∞` where there is none).
    pub object_clearance_m: f64,
    pub support_clearance_m: f64,
    pub obstacle_clearance_m: f64,
    /// Share of the progress of the final approach and closing.
    pub share: f64,
    /// The final approach as a straight palm line: [`LINE_STEPS`]` + 1` rows of joint values
    /// (model order), from `q` to the grasp, the palm's position moved evenly along the
    /// straight line and its orientation slerped between them, solved by the arm alone (empty:
    /// no such line was found, and the arm moves in along the joint line).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub line: Vec<f64>,
}

/// The pre-grasp of `goal` (model order) in the scene, or why there is none.
pub fn pre_grasp(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    goal: &[f64],
    opts: &ApproachOptions,
) -> Result<PreGrasp, String> {
    let model = &*sys.model;
    let checker = scene_checker(sys, object, obstacles);
    let mut data = checker.data();
    // only the support's distance at the grasp is needed (the pre-grasp may not come closer)
    let at_goal = checker.category_clearance(&mut data, goal, &[Category::Support]);
    let kin = data.kinematics();
    let palm = *kin.frame(sys.palm);
    let tips: Vector3<f64> = sys
        .fingers
        .iter()
        .map(|f| f.contact_point(kin).coords)
        .sum::<Vector3<f64>>()
        / sys.fingers.len().max(1) as f64;
    let approach = (tips - palm.translation.vector)
        .try_normalize(1e-9)
        .unwrap_or_else(|| palm.rotation * Vector3::z());
    // The support's normal points away from it: a second way back lifts the hand off it.
    let up = object
        .and_then(|o| o.support())
        .and_then(|s| Vector3::from(s.normal).try_normalize(1e-12));
    let open = open_targets(sys, &mut data, goal, &checker);
    let support_floor = at_goal
        .category_distance(Category::Support)
        .min(opts.margin)
        .max(-EXACT_PENETRATION_TOLERANCE)
        - SUPPORT_SLACK;
    let mut ik = IkSolver::new(model);
    let ik_opts = IkOptions {
        position_tolerance: 1e-4,
        orientation_tolerance: 1e-3,
        max_iterations_per_attempt: 200,
        max_iterations: 200,
        max_restarts: 0,
        active_joints: Some(sys.arm_joints.clone()),
        ..IkOptions::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut directions = vec![-approach];
    if let Some(n) = up
        && let Some(d) = (n - approach).try_normalize(1e-9)
    {
        directions.push(d);
    }
    let mut best: Option<(f64, String)> = None;
    let mut q = goal.to_vec();
    for direction in &directions {
        for scale in [1.0, 1.5, 2.0] {
            let standoff = opts.standoff * scale;
            let target = IkTarget {
                frame: sys.palm,
                point_in_frame: Vector3::zeros(),
                pose: Translation3::from(direction * standoff) * palm,
            };
            // Best effort: an arm joint on its limit can stop the solve short of the target (the
            // grasp optimiser often ends on a limit). A pre-grasp that got at least half the way
            // back, nearly straight and with the palm nearly as oriented, serves as well: its
            // clearance is checked exactly below, and its real standoff is what is reported.
            let solved = ik.solve(model, &target, goal, &ik_opts, &mut rng);
            checker.update(&mut data, &solved.q);
            let moved =
                data.kinematics().frame(sys.palm).translation.vector - palm.translation.vector;
            let along = moved.dot(direction);
            if along < 0.5 * standoff
                || (moved - direction * along).norm() > 0.5 * along
                || solved.orientation_error > MAX_TILT
            {
                continue;
            }
            for open_fraction in [opts.open, 0.5 * opts.open, 0.0] {
                q.copy_from_slice(&solved.q);
                for (&h, &(g, o)) in sys.hand_joints.iter().zip(&open) {
                    q[h] = g + open_fraction * (o - g);
                }
                let c = checker.clearance(&mut data, &q);
                let (obj, sup, obs, own) = (
                    c.category_distance(Category::Object),
                    c.category_distance(Category::Support),
                    c.category_distance(Category::Obstacle),
                    c.category_distance(Category::SelfCollision),
                );
                // each category's distance above what it must keep; the worst decides
                let (worst, category) = [
                    (obj - opts.margin, Category::Object),
                    (obs - opts.margin, Category::Obstacle),
                    (sup - support_floor, Category::Support),
                    (own + EXACT_PENETRATION_TOLERANCE, Category::SelfCollision),
                ]
                .into_iter()
                .fold((f64::INFINITY, Category::Object), |a, b| {
                    if b.0 < a.0 { b } else { a }
                });
                if worst >= 0.0 {
                    // (`data` holds the pre-grasp's kinematics from the clearance above)
                    let from = *data.kinematics().frame(sys.palm);
                    let line =
                        straight_line(sys, &mut ik, &ik_opts, &mut rng, &q, goal, (from, palm));
                    return Ok(PreGrasp {
                        line,
                        q: q.clone(),
                        standoff_m: along,
                        direction: [direction.x, direction.y, direction.z],
                        open_fraction,
                        object_clearance_m: obj,
                        support_clearance_m: sup,
                        obstacle_clearance_m: obs,
                        share: opts.share,
                    });
                }
                if best.as_ref().is_none_or(|(w, _)| worst > *w)
                    && let Some(m) = c.category(category)
                {
                    let l = checker.label(m.pair);
                    best = Some((
                        worst,
                        format!(
                            "'{}' {:.1} mm from '{}' at a {:.0} mm standoff",
                            l.link,
                            1e3 * m.distance.distance,
                            l.other,
                            1e3 * along
                        ),
                    ));
                }
            }
        }
    }
    Err(match best {
        Some((_, why)) => format!(
            "no pre-grasp keeps its clearance (nearest miss: {why}); the path runs into the grasp directly"
        ),
        None => {
            "the arm reaches no palm pose behind the grasp; the path runs into the grasp directly"
                .to_string()
        }
    })
}

/// Intervals of the straight final approach ([`PreGrasp::line`]): the arm's joint-space path
/// between two of its poses deviates from the straight palm line at second order in their
/// distance, well under a millimetre over the 8 mm or so between poses of a 60 mm standoff.
pub const LINE_STEPS: usize = 8;

/// Largest joint move between two poses of the straight line, relative to the joint line's
/// own step (plus a small floor): a larger one is the IK jumping to another branch, which the
/// interpolation between them would sweep through the scene.
const LINE_JUMP: f64 = 3.0;

/// The straight palm line from `pre` (the pre-grasp configuration) to `goal`, between their
/// palm poses `ends`, solved pose by pose by the arm alone, each seeded at the one before; empty when
/// the arm jumps between two of them (see [`PreGrasp::line`]). Where an arm joint on its limit
/// keeps a pose off the line (the grasp optimiser often ends on one), the IK's best effort is
/// the reachable pose nearest to it, which still bends less than the joint line. Why: the
/// joint line from the pre-grasp bends the palm's path sideways by up to centimetres, and at the
/// end of it a finger that must slide past the object at its surface (a hand open at its limit
/// around a 65 mm bottle) is swept into it; a straight palm line keeps the pads on their own
/// tangent planes.
fn straight_line(
    sys: &HandArm,
    ik: &mut IkSolver,
    opts: &IkOptions,
    rng: &mut ChaCha8Rng,
    pre: &[f64],
    goal: &[f64],
    (from, palm): (Isometry3<f64>, Isometry3<f64>),
) -> Vec<f64> {
    let model = &*sys.model;
    let nq = model.nq();
    let mut rows = Vec::with_capacity((LINE_STEPS + 1) * nq);
    rows.extend_from_slice(pre);
    let opts = IkOptions {
        position_tolerance: 1e-5,
        orientation_tolerance: 1e-4,
        ..opts.clone()
    };
    for k in 1..LINE_STEPS {
        let u = k as f64 / LINE_STEPS as f64;
        let target = IkTarget {
            frame: sys.palm,
            point_in_frame: Vector3::zeros(),
            pose: from.lerp_slerp(&palm, u),
        };
        let seed = &rows[(k - 1) * nq..k * nq];
        let solved = ik.solve(model, &target, seed, &opts, rng);
        let jump = solved
            .q
            .iter()
            .zip(seed)
            .zip(pre.iter().zip(goal))
            .map(|((a, b), (p, g))| (a - b).abs() / ((g - p).abs() / LINE_STEPS as f64 + 0.02))
            .fold(0.0, f64::max);
        if jump > LINE_JUMP {
            return Vec::new();
        }
        rows.extend_from_slice(&solved.q);
    }
    rows.extend_from_slice(goal);
    // the hand joints follow their own phase; the line carries the arm's
    for k in 0..=LINE_STEPS {
        for &h in &sys.hand_joints {
            rows[k * nq + h] = pre[h];
        }
    }
    rows
}

/// Per independent hand joint: its grasp value and the limit that opens the hand: the one of
/// the two towards which the fingertips move back from their pads (against each pad's outward
/// normal, the side that presses into the object when the finger closes), judged by a small
/// step of every hand joint at once. (Their spread about their centroid cannot tell: fingers
/// that close past each other spread again.)
fn open_targets(
    sys: &HandArm,
    data: &mut CheckData,
    goal: &[f64],
    checker: &CollisionChecker,
) -> Vec<(f64, f64)> {
    let model = &*sys.model;
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    let finite = |v: f64, g: f64| if v.is_finite() { v } else { g };
    let pads = |data: &CheckData| -> Vec<(Vector3<f64>, Vector3<f64>)> {
        let kin = data.kinematics();
        sys.fingers
            .iter()
            .map(|f| {
                (
                    f.contact_point(kin).coords,
                    kin.frame(f.tip).rotation * f.pad_normal,
                )
            })
            .collect()
    };
    checker.update(data, goal);
    let at_goal = pads(data);
    let mut q = goal.to_vec();
    // how far the pads advance (m, summed) when every hand joint steps towards `limit`
    let mut advance = |limit: &dyn Fn(usize) -> f64| {
        for &h in &sys.hand_joints {
            let l = finite(limit(h), goal[h]);
            q[h] = goal[h] + (l - goal[h]).clamp(-OPENING_PROBE, OPENING_PROBE);
        }
        checker.update(data, &q);
        pads(data)
            .iter()
            .zip(&at_goal)
            .map(|((p, _), (p0, n))| (p - p0).dot(n))
            .sum::<f64>()
    };
    let to_lower = advance(&|h| lo[h]);
    let to_upper = advance(&|h| hi[h]);
    sys.hand_joints
        .iter()
        .map(|&h| {
            let limit = if to_lower <= to_upper { lo[h] } else { hi[h] };
            (goal[h], finite(limit, goal[h]))
        })
        .collect()
}

/// Step of each hand joint (rad) by which the opening direction is judged.
const OPENING_PROBE: f64 = 0.05;

/// Reshapes a path sampled at progress `xs` (rows of `nq`, first row the start, last the
/// goal) into the approach: the humanlike path compressed into the first `1 - share` of the
/// progress, its end carried smoothly from the goal to the pre-grasp; then the arm joints move
/// in along `pre.line` (the straight palm line; the joint line without one) over the first
/// 60 % of the remaining progress while the hand stays open, and the hand joints close over the
/// last 60 % (overlapping by a fifth so the motion never stops dead). Returns `1 - share`, the
/// factor the given path's progress was compressed by (a departure at its start now ends that
/// much sooner).
pub fn shape_path(path: &mut [f64], xs: &[f64], nq: usize, sys: &HandArm, pre: &PreGrasp) -> f64 {
    let given = Given::new(path, xs, nq, sys);
    let goal = &given.original[(xs.len() - 1) * nq..];
    let s = pre.share.clamp(0.05, 0.5);
    for (k, &x) in xs.iter().enumerate() {
        let row = &mut path[k * nq..(k + 1) * nq];
        if x <= 1.0 - s {
            let y = x / (1.0 - s);
            given.offset_at(y, smooth(y), &pre.q, goal, row);
        } else {
            let z = (x - (1.0 - s)) / s;
            given.phase(z, false, &pre.q, goal, &pre.line, false, row);
        }
    }
    1.0 - s
}

/// Share of the progress the departure from a held object takes ([`shape_departure`]).
pub const DEPARTURE_SHARE: f64 = 0.15;

/// Reshapes a path sampled at progress `xs` (rows of `nq`, first row the start, last the goal)
/// whose start holds the object (the end of a previous plan: the pads on it) into a departure,
/// the approach's closing run backwards: over the first [`DEPARTURE_SHARE`] of the progress
/// the hand joints open to the start's own pre-grasp `dep` over the first 60 % of it, while the
/// arm joints stay, then back off to it over the last 60 % (overlapping by a fifth); the
/// humanlike path follows over the rest of the progress with an offset that carries its start
/// from the start to `dep` and fades out smoothly, so the goal is unchanged. Why: run from a
/// held object as it is, the humanlike path moves the arm while the fingers still wrap the
/// object, and a finger is dragged through it (measured: a wam_ihy thumb 2.6 mm into the ball
/// on the README quickstart's second plan).
pub fn shape_departure(path: &mut [f64], xs: &[f64], nq: usize, sys: &HandArm, dep: &PreGrasp) {
    let given = Given::new(path, xs, nq, sys);
    let start = &given.original[..nq];
    let s = DEPARTURE_SHARE;
    for (k, &x) in xs.iter().enumerate() {
        let row = &mut path[k * nq..(k + 1) * nq];
        if x < s {
            given.phase(x / s, true, start, &dep.q, &dep.line, true, row);
        } else {
            let y = (x - s) / (1.0 - s);
            given.offset_at(y, 1.0 - smooth(y), &dep.q, start, row);
        }
    }
}

/// Joint `j` of the straight line's poses ([`PreGrasp::line`]) at `u ∈ [0, 1]`: the uniform
/// Catmull-Rom spline through them (end poses repeated), so the velocity has no kinks where
/// a piecewise-linear interpolation would have them at every pose.
fn line_at(line: &[f64], nq: usize, u: f64, j: usize) -> f64 {
    let t = u.clamp(0.0, 1.0) * LINE_STEPS as f64;
    let p = |k: isize| line[(k.clamp(0, LINE_STEPS as isize) as usize) * nq + j];
    let i = t.floor() as isize;
    let w = t - i as f64;
    if w == 0.0 {
        // at a pose (both ends included), its own values to the last bit
        return p(i);
    }
    let (p0, p1, p2, p3) = (p(i - 1), p(i), p(i + 1), p(i + 2));
    let (w2, w3) = (w * w, w * w * w);
    0.5 * (2.0 * p1
        + (p2 - p0) * w
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * w2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * w3)
}

/// `3t² − 2t³` on `[0, 1]`, clamped outside.
fn smooth(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A path as given to a reshaping, before it changes.
struct Given<'a> {
    original: Vec<f64>,
    xs: &'a [f64],
    nq: usize,
    is_hand: Vec<bool>,
}

impl<'a> Given<'a> {
    fn new(path: &[f64], xs: &'a [f64], nq: usize, sys: &HandArm) -> Self {
        assert_eq!(
            path.len(),
            xs.len() * nq,
            "path rows do not match the progress samples"
        );
        let mut is_hand = vec![false; nq];
        for &h in &sys.hand_joints {
            is_hand[h] = true;
        }
        Given {
            original: path.to_vec(),
            xs,
            nq,
            is_hand,
        }
    }

    /// The given path at progress `y` (linear between its samples) plus `b (to − from)`.
    fn offset_at(&self, y: f64, b: f64, to: &[f64], from: &[f64], row: &mut [f64]) {
        let (xs, nq) = (self.xs, self.nq);
        let i = xs.partition_point(|&v| v <= y).clamp(1, xs.len() - 1);
        let (x0, x1) = (xs[i - 1], xs[i]);
        let w = if x1 > x0 {
            ((y - x0) / (x1 - x0)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        for j in 0..nq {
            let a = self.original[(i - 1) * nq + j];
            let c = self.original[i * nq + j];
            row[j] = a + w * (c - a) + b * (to[j] - from[j]);
        }
    }

    /// From `a` to `b` at phase `z ∈ [0, 1]`: one group of joints over the first 60 %, the other
    /// over the last 60 % (the hand first with `hand_first`, else the arm). The arm follows
    /// `line` where there is one ([`PreGrasp::line`], which runs from `b` to `a` when
    /// `reversed`), else the joint line.
    #[allow(clippy::too_many_arguments)]
    fn phase(
        &self,
        z: f64,
        hand_first: bool,
        a: &[f64],
        b: &[f64],
        line: &[f64],
        reversed: bool,
        row: &mut [f64],
    ) {
        let (early, late) = (smooth(z / 0.6), smooth((z - 0.4) / 0.6));
        for j in 0..self.nq {
            let f = if self.is_hand[j] == hand_first {
                early
            } else {
                late
            };
            row[j] = if self.is_hand[j] || line.is_empty() {
                a[j] + f * (b[j] - a[j])
            } else {
                line_at(line, self.nq, if reversed { 1.0 - f } else { f }, j)
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Point3, Vector3};
    use parry3d_f64::shape::SharedShape;

    use super::*;
    use crate::grasp::objects::{ObjectSpec, ShapeSpec};
    use crate::grasp::optimizer::tests::test_system;
    use crate::kinematics::{Data, forward_kinematics};

    /// The test arm above a small ball held between its two fingers: the goal configuration,
    /// the ball's centre (the fingertips' centroid) and the palm pose there.
    fn grasp_scene(sys: &HandArm) -> (Vec<f64>, Vector3<f64>, Isometry3<f64>) {
        grasp_scene_flexed(sys, 0.6)
    }

    /// [`grasp_scene`] with every hand joint at `flex`.
    fn grasp_scene_flexed(sys: &HandArm, flex: f64) -> (Vec<f64>, Vector3<f64>, Isometry3<f64>) {
        let model = &*sys.model;
        let mut goal = vec![0.0; model.nq()];
        goal[model.q_index("j2").unwrap()] = 0.9;
        goal[model.q_index("j4").unwrap()] = 1.2;
        for &h in &sys.hand_joints {
            goal[h] = flex;
        }
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, &goal);
        let centre = sys
            .fingers
            .iter()
            .map(|f| f.contact_point(&data).coords)
            .sum::<Vector3<f64>>()
            / 2.0;
        (goal, centre, *data.frame(sys.palm))
    }

    /// The point a fraction `y` along the straight joint line from `a` to `b`.
    fn joint_line(a: &[f64], b: &[f64], y: f64) -> Vec<f64> {
        a.iter().zip(b).map(|(a, b)| a + y * (b - a)).collect()
    }

    fn ball(centre: Vector3<f64>, radius: f64) -> Object {
        Object::new(ObjectSpec {
            name: "ball".into(),
            shape: ShapeSpec::Sphere { radius },
            position: [centre.x, centre.y, centre.z],
            orientation: [1.0, 0.0, 0.0, 0.0],
            support: None,
            mass: None,
            friction: None,
        })
        .unwrap()
    }

    /// Distance of a ball to the test arm's collision shapes at `q`, in closed form (point to
    /// segment for the capsules, clamping into the box for the palm), independent of the parry
    /// queries the checker runs.
    fn ball_distance(sys: &HandArm, q: &[f64], c: Vector3<f64>, r: f64) -> f64 {
        let model = &*sys.model;
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, q);
        let frame = |n: &str| *data.frame(model.frame_id(n).unwrap());
        let capsule = |link: &str, z0: f64, z1: f64, rc: f64| {
            let f = frame(link);
            let (a, b) = (
                (f * Point3::new(0.0, 0.0, z0)).coords,
                (f * Point3::new(0.0, 0.0, z1)).coords,
            );
            let t = ((c - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
            (c - (a + (b - a) * t)).norm() - rc - r
        };
        let mut d = capsule("j4_link", 0.05, 0.22, 0.035);
        for k in 0..2 {
            d = d.min(capsule(&format!("f{k}_prox_link"), 0.012, 0.05, 0.008));
            d = d.min(capsule(&format!("f{k}_dist_link"), 0.0, 0.036, 0.008));
        }
        let local =
            frame("palm").inverse_transform_point(&Point3::from(c)) - Vector3::new(0.0, 0.0, -0.02);
        let half = Vector3::new(0.025, 0.05, 0.02);
        let outside = local.coords.zip_map(&half, |v, h| (v.abs() - h).max(0.0));
        d.min(outside.norm() - r)
    }

    #[test]
    fn the_pre_grasp_backs_the_palm_off_along_the_approach_with_the_hand_opened() {
        let sys = test_system();
        let model = &*sys.model;
        let (goal, centre, palm) = grasp_scene(&sys);
        let r = 0.012;
        let opts = ApproachOptions::default();
        let pre = pre_grasp(&sys, Some(&ball(centre, r)), &[], &goal, &opts).unwrap();
        // straight back, away from the fingertips' centroid
        let back = -(centre - palm.translation.vector).normalize();
        assert!(
            Vector3::from(pre.direction).dot(&back) > 1.0 - 1e-12,
            "{pre:?}"
        );
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, &pre.q);
        let at_pre = *data.frame(sys.palm);
        let moved = at_pre.translation.vector - palm.translation.vector;
        assert!((moved - back * opts.standoff).norm() < 2e-4, "{moved:?}");
        assert!((pre.standoff_m - opts.standoff).abs() < 2e-4, "{pre:?}");
        assert!(at_pre.rotation.angle_to(&palm.rotation) < 2e-3);
        // these fingers close by flexing towards each other: open is the lower limit (-0.6)
        for &h in &sys.hand_joints {
            let want = 0.6 + opts.open * (-0.6 - 0.6);
            assert!((pre.q[h] - want).abs() < 1e-12, "{} vs {want}", pre.q[h]);
        }
        // the reported clearance is the closed-form one, and keeps the margin
        let exact = ball_distance(&sys, &pre.q, centre, r);
        assert!(
            (pre.object_clearance_m - exact).abs() < 1e-6,
            "{pre:?} vs {exact}"
        );
        assert!(exact >= opts.margin, "{exact}");
        assert!(ball_distance(&sys, &goal, centre, r) < opts.margin);
    }

    /// Distance of `p` from the segment `a`-`b` (closed form).
    fn segment_distance(p: Vector3<f64>, a: Vector3<f64>, b: Vector3<f64>) -> f64 {
        let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
        (p - (a + (b - a) * t)).norm()
    }

    #[test]
    fn the_final_approach_moves_the_palm_in_along_a_straight_line() {
        let sys = test_system();
        let model = &*sys.model;
        let nq = model.nq();
        let (goal, centre, palm) = grasp_scene(&sys);
        // twice the default standoff: the joint line's bend grows with the distance
        let opts = ApproachOptions {
            standoff: 0.12,
            ..ApproachOptions::default()
        };
        let pre = pre_grasp(&sys, Some(&ball(centre, 0.012)), &[], &goal, &opts).unwrap();
        assert_eq!(pre.line.len(), (LINE_STEPS + 1) * nq, "{pre:?}");
        let mut data = Data::new(model);
        let mut palm_at = |q: &[f64]| {
            forward_kinematics(model, &mut data, q);
            data.frame(sys.palm).translation.vector
        };
        let (from, to) = (palm_at(&pre.q), palm.translation.vector);
        let start = vec![0.1; nq];
        let xs: Vec<f64> = (0..=400).map(|k| k as f64 / 400.0).collect();
        let mut path: Vec<f64> = xs
            .iter()
            .flat_map(|&x| joint_line(&start, &goal, x))
            .collect();
        shape_path(&mut path, &xs, nq, &sys, &pre);
        let mut worst: f64 = 0.0;
        for (k, &x) in xs.iter().enumerate() {
            if x >= 0.8 {
                worst = worst.max(segment_distance(
                    palm_at(&path[k * nq..(k + 1) * nq]),
                    from,
                    to,
                ));
            }
        }
        // the same phase along the joint line instead: the test can tell the two apart
        let mut bent: f64 = 0.0;
        for k in 0..=100 {
            let q = joint_line(&pre.q, &goal, k as f64 / 100.0);
            bent = bent.max(segment_distance(palm_at(&q), from, to));
        }
        assert!(worst < 2e-4, "palm {worst} m off the straight line");
        assert!(
            bent > 2e-3,
            "the joint line bends the palm's path only {bent} m"
        );
    }

    #[test]
    fn a_pre_grasp_inside_an_obstacle_is_refused_with_the_obstacle_named() {
        let sys = test_system();
        let (goal, centre, palm) = grasp_scene(&sys);
        let back = -(centre - palm.translation.vector).normalize();
        // a block filling 4-14 cm behind the palm: every standoff tried (6, 9, 12 cm) ends in it
        let wall = SceneShape::new(
            "wall",
            SharedShape::cuboid(0.05, 0.05, 0.05),
            Isometry3::translation(
                palm.translation.x + 0.09 * back.x,
                palm.translation.y + 0.09 * back.y,
                palm.translation.z + 0.09 * back.z,
            ),
        );
        let opts = ApproachOptions::default();
        let clear = pre_grasp(&sys, Some(&ball(centre, 0.012)), &[], &goal, &opts);
        assert!(clear.is_ok());
        let why = pre_grasp(&sys, Some(&ball(centre, 0.012)), &[wall], &goal, &opts).unwrap_err();
        assert!(why.contains("'wall'"), "{why}");
    }

    /// From a held ball (the fingertips on it: its radius is their closed-form distance from
    /// the centroid), the departure opens the hand before the arm moves, reaches the start's
    /// pre-grasp at its share, never comes nearer the ball than the start (closed-form
    /// distance, fine steps), and leaves the rest of the path's end unchanged.
    #[test]
    fn the_departure_from_a_held_ball_opens_the_hand_first_and_never_nears_the_ball() {
        let sys = test_system();
        let nq = sys.model.nq();
        // the fingers half as flexed as the approach tests' grasp: a ball of a few centimetres
        let (held, centre, _) = grasp_scene_flexed(&sys, 0.3);
        let r = ball_distance(&sys, &held, centre, 0.0);
        assert!(r > 1e-3, "{r}");
        let object = ball(centre, r);
        let dep = pre_grasp(&sys, Some(&object), &[], &held, &ApproachOptions::default()).unwrap();
        let mut goal = held.clone();
        goal[sys.model.q_index("j1").unwrap()] += 0.8;
        let xs: Vec<f64> = (0..=400).map(|k| k as f64 / 400.0).collect();
        let mut path: Vec<f64> = xs
            .iter()
            .flat_map(|&x| joint_line(&held, &goal, x))
            .collect();
        shape_departure(&mut path, &xs, nq, &sys, &dep);
        let row = |k: usize| &path[k * nq..(k + 1) * nq];
        assert_eq!(row(0), &held[..]);
        assert_eq!(row(400), &goal[..]);
        assert_eq!(row(60), &dep.q[..], "at the departure's share (0.15)");
        let at_start = ball_distance(&sys, &held, centre, r);
        assert!(at_start.abs() < 1e-9, "{at_start}");
        for (k, &x) in xs.iter().enumerate().take(61) {
            let q = row(k);
            if x <= 0.4 * DEPARTURE_SHARE {
                // only the hand moves
                for j in (0..nq).filter(|j| !sys.hand_joints.contains(j)) {
                    assert_eq!(q[j], held[j], "x {x} joint {j}");
                }
            }
            let d = ball_distance(&sys, q, centre, r);
            assert!(d >= at_start - 1e-9, "x {x}: {d} m");
        }
        // the hand is open (away from the ball) by the time the arm starts to move
        let k = (0.4 * DEPARTURE_SHARE * 400.0).round() as usize;
        assert!(ball_distance(&sys, row(k), centre, r) > 1e-3);
    }

    #[test]
    fn the_shaped_path_runs_to_the_pre_grasp_then_moves_the_arm_in_and_closes_the_hand() {
        let sys = test_system();
        let nq = sys.model.nq();
        let (goal, _, _) = grasp_scene(&sys);
        let start = vec![0.1; nq];
        let mut pre_q = goal.clone();
        for (j, v) in pre_q.iter_mut().enumerate() {
            *v += 0.05 * (j as f64 + 1.0);
        }
        let pre = PreGrasp {
            q: pre_q.clone(),
            standoff_m: 0.06,
            direction: [0.0, 0.0, 1.0],
            open_fraction: 0.6,
            object_clearance_m: 0.01,
            support_clearance_m: f64::INFINITY,
            obstacle_clearance_m: f64::INFINITY,
            share: 0.2,
            line: Vec::new(),
        };
        let xs: Vec<f64> = (0..=40).map(|k| k as f64 / 40.0).collect();
        // a straight joint line from the start to the goal
        let line = |y: f64| joint_line(&start, &goal, y);
        let mut path: Vec<f64> = xs.iter().flat_map(|&x| line(x)).collect();
        shape_path(&mut path, &xs, nq, &sys, &pre);
        let row = |k: usize| &path[k * nq..(k + 1) * nq];
        let is_hand = |j: usize| sys.hand_joints.contains(&j);
        let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
        for (k, &x) in xs.iter().enumerate() {
            for j in 0..nq {
                let want = if x <= 0.8 + 1e-12 {
                    let y = x / 0.8;
                    line(y)[j] + smooth(y) * (pre_q[j] - goal[j])
                } else {
                    let z = (x - 0.8) / 0.2;
                    let f = if is_hand(j) {
                        smooth(((z - 0.4) / 0.6).clamp(0.0, 1.0))
                    } else {
                        smooth((z / 0.6).clamp(0.0, 1.0))
                    };
                    pre_q[j] + f * (goal[j] - pre_q[j])
                };
                assert!((row(k)[j] - want).abs() < 1e-12, "x {x} joint {j}");
            }
        }
        assert_eq!(row(0), &start[..]);
        assert_eq!(row(32), &pre_q[..]);
        assert_eq!(row(40), &goal[..]);
    }
}
