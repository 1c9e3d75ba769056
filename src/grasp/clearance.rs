//! Exact clearance of a joint trajectory in a grasp's scene (issue 18, item 2).
//!
//! Every link's URDF collision shape against the object, the support half-space and every
//! non-adjacent link of the system, continuous along the piecewise-linear path through the
//! trajectory's points (the path a position-controlled robot interpolates between them), by the
//! conservative advancement of [`CollisionChecker::check_path`]: the true minimum distance lies
//! at most `tolerance_m` below the reported one, so no penetration deeper than that is missed.
//!
//! The fingertip pads end the trajectory on the object (the grasp's contacts, at most
//! [`EXACT_PENETRATION_TOLERANCE`] deep), so a penetration within that tolerance is contact, not
//! collision. In the closing phase (the last [`CLOSING_SHARE`] of the duration) the pads close
//! on the object and may press into it up to [`CLOSING_PRESS`] (reported as `closing_contact`);
//! any other pair deeper than the tolerance, anywhere on the path, is a collision.

use serde::{Deserialize, Serialize};

use crate::geometry::avoid::{AvoidOptions, AvoidReport, AvoidScratch, CurveSample, refine};
use crate::geometry::{
    AllowedContacts, Category, CheckData, CollisionChecker, Member, PathHit, PathOptions, Plane,
    Polyline, Scene, SceneShape,
};

use super::optimizer::EXACT_PENETRATION_TOLERANCE;
use super::{HandArm, Object};

/// Where along the trajectory a distance was found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ClearanceHit {
    /// Signed distance, m (< 0: penetration depth).
    pub distance_m: f64,
    /// Time from the trajectory's start, s.
    pub time_s: f64,
    /// The robot link.
    pub link: String,
    /// "object", "support", the obstacle's name or the other link's name.
    pub other: String,
}

/// The exact clearance of a trajectory (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PathClearance {
    /// No pair deeper than the contact tolerance anywhere on the path.
    pub collision_free: bool,
    /// Penetration accepted as contact (the grasp's own contacts at the end), m.
    pub contact_tolerance_m: f64,
    /// The true minimum lies at most this far below each reported distance, m.
    pub tolerance_m: f64,
    /// The check covered the whole path (its step budget did not run out).
    pub complete: bool,
    /// Time from which the fingertip pads may press into the object (the closing phase: the
    /// last tenth of the duration, from the trajectory point before it), s.
    pub closing_from_s: f64,
    /// How far the pads may press into the object in the closing phase, m.
    pub closing_press_m: f64,
    /// Smallest distance of a link to the object during the closing phase, the pads included
    /// (how far they press: a collision only deeper than `closing_press_m`).
    #[serde(default)]
    pub closing_contact: Option<ClearanceHit>,
    /// Smallest distance of any pair, and where.
    pub closest: Option<ClearanceHit>,
    /// Smallest distance of a link to the object.
    pub object: Option<ClearanceHit>,
    /// Smallest distance of a link to the support plane.
    pub support: Option<ClearanceHit>,
    /// Smallest distance of a link to any of the request's obstacles (absent without any).
    #[serde(default)]
    pub obstacle: Option<ClearanceHit>,
    /// Smallest distance between two non-adjacent links.
    pub self_collision: Option<ClearanceHit>,
    /// Conservative-advancement steps and exact distance queries spent.
    pub steps: usize,
    pub exact_queries: usize,
}

impl PathClearance {
    /// The pair that makes the path a collision, and whether it is a pad pressing too deep
    /// while the hand closes (`true`) rather than a link inside something (`false`, reported
    /// first): `None` where neither is found (collision-free, or a check whose budget ran out
    /// before it found one).
    pub fn collision(&self) -> Option<(&ClearanceHit, bool)> {
        let inside = self
            .closest
            .as_ref()
            .filter(|h| h.distance_m < -self.contact_tolerance_m)
            .map(|h| (h, false));
        let pressed = self
            .closing_contact
            .as_ref()
            .filter(|h| h.distance_m < -self.closing_press_m)
            .map(|h| (h, true));
        inside.or(pressed)
    }

    /// The collision in words (which link, how deep in what, when, and what is allowed), or
    /// `None` where [`Self::collision`] finds none.
    pub fn collision_words(&self) -> Option<String> {
        self.collision().map(|(h, pressed)| {
            if pressed {
                format!(
                    "link '{}' presses {:.2} mm into '{}' at t = {:.2} s while the hand closes \
                     (up to {:.2} mm is allowed)",
                    h.link,
                    -1e3 * h.distance_m,
                    h.other,
                    h.time_s,
                    1e3 * self.closing_press_m
                )
            } else {
                format!(
                    "link '{}' is {:.1} mm inside '{}' at t = {:.2} s (contact up to {:.1} mm is \
                     allowed)",
                    h.link,
                    -1e3 * h.distance_m,
                    h.other,
                    h.time_s,
                    1e3 * self.contact_tolerance_m
                )
            }
        })
    }
}

/// Steps of the conservative advancement (deterministic budget; `complete` says if it ran out).
const MAX_STEPS: usize = 200_000;
/// Tolerance of the continuous check, m.
const TOLERANCE: f64 = 5e-4;

/// The collision checker of `sys` in the scene of `object` (with its support plane) and
/// `obstacles`.
pub fn scene_checker(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
) -> CollisionChecker {
    let mut scene = Scene::new();
    if let Some(object) = object {
        let (shape, pose) = object.shape();
        scene = scene.with_object(SceneShape::new(
            object.spec().name.clone(),
            shape.clone(),
            *pose,
        ));
        if let Some(p) = object.support().and_then(|sp| Plane::try_from(sp).ok()) {
            scene = scene.with_support(p);
        }
    }
    scene.obstacles = obstacles.to_vec();
    CollisionChecker::new(sys.geometry.clone(), scene)
}

/// Moves the control configurations of a path (rows of `sys.model.nq()` values) the least
/// amount needed for its points `curve` to keep the default margins from the object, its
/// support, `obstacles` and the robot's own links ([`crate::geometry::avoid`]); over the first
/// `hold_start` of the progress (a departure) the targets stay at the start's own clearance.
pub fn avoid(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    path: &mut [f64],
    curve: &[CurveSample],
    hold_start: f64,
) -> AvoidReport {
    let checker = scene_checker(sys, object, obstacles);
    let mut data = checker.data();
    let nq = sys.model.nq();
    let mut scratch = AvoidScratch::new(nq, path.len() / nq);
    refine(
        &checker,
        &mut data,
        path,
        curve,
        sys.model.lower_limits(),
        sys.model.upper_limits(),
        &AvoidOptions {
            hold_start,
            ..AvoidOptions::default()
        },
        &mut scratch,
    )
}

/// Links within this distance of the object or the support at the goal are judged by
/// [`arrive_from_outside`] (m): the pads in contact and whatever grazes the table beside them.
const ARRIVAL_CUTOFF: f64 = 5e-3;

/// The smallest approach of such a link, as the cosine between the path's end tangent and the
/// link's inward distance gradient (0: tangential).
const ARRIVAL_COS: f64 = 0.1;

/// Over how many configurations before the goal a turned end tangent is carried (fading), per
/// candidate: the last one alone, or the final stretch turning as a whole.
const ARRIVAL_FADES: [usize; 3] = [1, 3, 6];

/// A candidate must lessen the overshoot by this much to replace the path's end (m).
const ARRIVAL_GAIN: f64 = 5e-5;

/// What [`arrive_from_outside`] found at a path's end.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Arrival {
    /// Pairs within [`ARRIVAL_CUTOFF`] of the object or the support at the goal that the path's
    /// last segment does not approach at [`ARRIVAL_COS`] or more: it brings the link there from
    /// inside (its distance rising into the goal) or nearly tangentially.
    pub from_inside: usize,
    /// How far the path's final stretch went deeper into the object or the support than the
    /// goal itself, before and after (m; 0: nowhere).
    pub overshoot_before: f64,
    pub overshoot_after: f64,
    /// Largest joint change of a configuration (rad; 0 when the path was kept).
    pub change: f64,
}

/// How far the curve at `end` (samples of the path's final stretch) goes deeper into the
/// object or the support than the goal does (m, ≥ 0).
fn overshoot(
    checker: &CollisionChecker,
    data: &mut CheckData,
    path: &[f64],
    nq: usize,
    end: &[CurveSample],
    at_goal: [f64; 2],
    q: &mut [f64],
) -> f64 {
    let mut worst = 0.0f64;
    for cs in end {
        q.fill(0.0);
        for (r, &w) in cs.w.iter().enumerate() {
            let row = &path[(cs.first + r) * nq..(cs.first + r + 1) * nq];
            q.iter_mut().zip(row).for_each(|(v, c)| *v += w * c);
        }
        let c = checker.category_clearance(data, q, &[Category::Object, Category::Support]);
        for (k, cat) in [Category::Object, Category::Support]
            .into_iter()
            .enumerate()
        {
            let d = c.category_distance(cat);
            if d < 0.0 {
                worst = worst.max(at_goal[k].min(0.0) - d);
            }
        }
    }
    worst
}

/// Turns the end of a path (rows of `nq` control configurations of a clamped cubic B-spline,
/// the last the goal) so that the links in contact at the goal arrive from outside. Why: the
/// humanlike flow ends along its own slowest direction, which for a pad already on the object
/// can point out of the surface; traversed forwards, such a pad crosses the surface and comes
/// back on the clock's slow final approach (measured on the sunglasses: a thumb pad 0.7 mm
/// through at 140 mm/s 0.1 s before the end, within the contact tolerance, and in physics the
/// 30 g box shoved 6 mm aside before the other fingers arrived).
///
/// Every link within [`ARRIVAL_CUTOFF`] of the object or the support at the goal should meet
/// `∇d · t ≤ −ARRIVAL_COS |∇d| |t|` for the end tangent `t` (the goal minus the last interior
/// configuration) and its pair's exact distance gradient `∇d`. When one does not, the smallest
/// change of the tangent that meets them all (cyclic projections; the length kept, the limits
/// kept) is carried back over the last 1, 3 or 6 configurations with a fading weight; each
/// candidate is judged on `end` (samples of the final stretch) by how much deeper than the goal
/// itself it takes any link into the object or the support, by the exact distances, and the
/// least such overshoot wins, the given path on a tie.
pub fn arrive_from_outside(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    path: &mut [f64],
    end: &[CurveSample],
) -> Arrival {
    let nq = sys.model.nq();
    let count = path.len() / nq;
    assert!(count >= 3 && path.len() == count * nq);
    let checker = scene_checker(sys, object, obstacles);
    let mut data = checker.data();
    let goal = path[(count - 1) * nq..].to_vec();
    let last = &path[(count - 2) * nq..(count - 1) * nq];
    let c = checker.category_clearance(&mut data, &goal, &[Category::Object, Category::Support]);
    let at_goal = [Category::Object, Category::Support].map(|cat| c.category_distance(cat));
    let mut near = Vec::new();
    checker.for_each_within_current(
        &mut data,
        ARRIVAL_CUTOFF,
        &[Category::Object, Category::Support],
        |pair, d| near.push((pair, *d)),
    );
    let grads: Vec<Vec<f64>> = near
        .iter()
        .map(|(pair, d)| {
            let mut g = vec![0.0; nq];
            checker.add_distance_gradient(&data, *pair, d, &mut g);
            g
        })
        .filter(|g| g.iter().map(|x| x * x).sum::<f64>() > 1e-12)
        .collect();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let t: Vec<f64> = goal.iter().zip(last).map(|(g, l)| g - l).collect();
    let len = dot(&t, &t).sqrt();
    let from_inside = if len < 1e-12 {
        0
    } else {
        grads
            .iter()
            .filter(|g| dot(g, &t) + ARRIVAL_COS * dot(g, g).sqrt() * len > 0.0)
            .count()
    };
    let mut q = vec![0.0; nq];
    let before = overshoot(&checker, &mut data, path, nq, end, at_goal, &mut q);
    let mut out = Arrival {
        from_inside,
        overshoot_before: before,
        overshoot_after: before,
        change: 0.0,
    };
    if from_inside == 0 {
        return out;
    }
    let (lo, hi) = (sys.model.lower_limits(), sys.model.upper_limits());
    let mut best: Option<(f64, Vec<f64>, f64)> = None;
    let mut trial = path.to_vec();
    let violated = |t: &[f64], g: &[f64]| dot(g, t) + ARRIVAL_COS * dot(g, g).sqrt() * len;
    let mut t = t;
    for _ in 0..50 {
        let mut worst = 0.0f64;
        for g in &grads {
            let v = violated(&t, g);
            if v > 0.0 {
                worst = worst.max(v);
                let f = v / dot(g, g);
                t.iter_mut().zip(g).for_each(|(x, gi)| *x -= f * gi);
            }
        }
        // the length is kept (the clock's speed at the end is the tangent's), and the
        // configuration stays inside the limits
        let l = dot(&t, &t).sqrt().max(1e-12);
        for (j, x) in t.iter_mut().enumerate() {
            *x = goal[j] - (goal[j] - *x * len / l).clamp(lo[j], hi[j]);
        }
        if worst <= 1e-12 {
            break;
        }
    }
    // the last interior configuration moves by −δ; the m-th before the goal by −m·δ·(1 − u)²
    let delta: Vec<f64> = (0..nq).map(|j| t[j] - (goal[j] - last[j])).collect();
    for fade in ARRIVAL_FADES {
        trial.copy_from_slice(path);
        let mut change = 0.0f64;
        for m in 1..=fade.min(count - 2) {
            let u = (m - 1) as f64 / fade as f64;
            let w = m as f64 * (1.0 - u) * (1.0 - u);
            let row = &mut trial[(count - 1 - m) * nq..(count - m) * nq];
            for j in 0..nq {
                let v = (row[j] - w * delta[j]).clamp(lo[j], hi[j]);
                change = change.max((v - row[j]).abs());
                row[j] = v;
            }
        }
        let o = overshoot(&checker, &mut data, &trial, nq, end, at_goal, &mut q);
        if best.as_ref().is_none_or(|(b, _, _)| o < *b) {
            best = Some((o, trial.clone(), change));
        }
    }
    if let Some((o, p, change)) = best.filter(|(o, _, _)| *o < before - ARRIVAL_GAIN) {
        path.copy_from_slice(&p);
        out.overshoot_after = o;
        out.change = change;
    }
    out
}

/// A configuration's deepest penetration, when it is deeper than the contact tolerance.
#[derive(Debug, Clone, PartialEq)]
pub struct PostureCollision {
    pub link: String,
    /// "object", "support", the obstacle's name or the other link's name.
    pub other: String,
    pub category: Category,
    /// Penetration depth, m (> [`EXACT_PENETRATION_TOLERANCE`]).
    pub depth_m: f64,
}

/// Whether configuration `q` (model order) of `sys` collides in the scene of `object` (with its
/// support plane) and `obstacles`, or with itself: its closest pair, exactly, when that pair is
/// deeper than the contact tolerance (a hand resting on what it grasped is in contact, not in
/// collision).
pub fn posture_collision(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    q: &[f64],
) -> Option<PostureCollision> {
    let checker = scene_checker(sys, object, obstacles);
    let mut data = checker.data();
    let closest = checker.clearance(&mut data, q).min?;
    (closest.distance.distance < -EXACT_PENETRATION_TOLERANCE).then(|| {
        let label = checker.label(closest.pair);
        PostureCollision {
            link: label.link,
            other: label.other,
            category: label.category,
            depth_m: -closest.distance.distance,
        }
    })
}

/// The final share of a trajectory's duration that is its closing phase, where the fingertip
/// pads may press into the object. Humans close the grip over about the last third of a reach
/// (peak aperture at 60-70 % of the movement time); the pads are excepted over the last tenth
/// only, so a pad that reaches the object early is still a collision.
pub const CLOSING_SHARE: f64 = 0.1;

/// How far the fingertip pads may press into the object in the closing phase (m): a soft pad
/// gives a few millimetres; deeper is a collision again.
pub const CLOSING_PRESS: f64 = 5e-3;

/// Contacts allowed in the closing phase: every shape of a link carrying a fingertip (the pad's
/// rigid body) against the object.
pub fn closing_contacts(sys: &HandArm) -> AllowedContacts {
    let geo = &*sys.geometry;
    let mut acm = AllowedContacts::none();
    for (k, shape) in geo.shapes().iter().enumerate() {
        let body = geo.body(shape.frame);
        if sys.fingers.iter().any(|f| geo.body(f.tip) == body) {
            acm.allow(Member::Shape(k), Member::Object);
        }
    }
    acm
}

/// The clearance of the path through `points` (row-major, `sys.model.nq()` joint values in
/// model order per point) at times `times` (s), in the scene of `object` (and its support plane,
/// when there is an object) and `obstacles`: every pair throughout, except the fingertip pads
/// against the object in the closing phase ([`CLOSING_SHARE`], from the last point before it).
pub fn path_clearance(
    sys: &HandArm,
    object: Option<&Object>,
    obstacles: &[SceneShape],
    points: &[f64],
    times: &[f64],
) -> PathClearance {
    let nq = sys.model.nq();
    assert_eq!(
        points.len(),
        nq * times.len(),
        "one time per point of nq values"
    );
    assert!(!times.is_empty(), "a path has at least one point");
    // The closing phase starts at the last point at or before its first instant (so the segment
    // across that instant is judged as closing, and each phase is a polyline of its own points).
    let (t0, t1) = (times[0], times[times.len() - 1]);
    let close = times
        .iter()
        .rposition(|&t| t <= t1 - CLOSING_SHARE * (t1 - t0))
        .unwrap_or(0);
    let opts = PathOptions {
        tolerance: TOLERANCE,
        max_steps: MAX_STEPS,
    };
    let mut checker = scene_checker(sys, object, obstacles);
    let mut data = checker.data();
    let approach = checker.check_path(
        &mut data,
        &Polyline::new(&points[..(close + 1) * nq], nq),
        &opts,
    );
    // the closing phase as it is (for the report: how far the pads press), and as it is judged
    // (pads on the object allowed)
    let closing_points = Polyline::new(&points[close * nq..], nq);
    let pressed = object.map(|_| checker.check_path(&mut data, &closing_points, &opts));
    checker.set_allowed(&closing_contacts(sys));
    let closing = checker.check_path(&mut data, &closing_points, &opts);
    // The path parameter counts segments: interpolate the time.
    let time = |s: f64| {
        let k = (s.floor() as usize).min(times.len() - 1);
        let next = (k + 1).min(times.len() - 1);
        times[k] + (s - k as f64) * (times[next] - times[k])
    };
    let hit = |h: Option<&PathHit>, offset: usize| {
        h.map(|h| {
            let label = checker.label(h.pair);
            ClearanceHit {
                distance_m: h.distance.distance,
                time_s: time(h.s + offset as f64),
                link: label.link,
                other: label.other,
            }
        })
    };
    // the nearer of the two phases' hits (the approach's on a tie: it comes first)
    let nearer = |a: Option<&PathHit>, b: Option<&PathHit>| match (hit(a, 0), hit(b, close)) {
        (Some(a), Some(b)) => Some(if b.distance_m < a.distance_m { b } else { a }),
        (a, b) => a.or(b),
    };
    let category = |c: Category| nearer(approach.category(c), closing.category(c));
    let closest = nearer(approach.min.as_ref(), closing.min.as_ref());
    let complete = approach.complete && closing.complete && pressed.is_none_or(|p| p.complete);
    let closing_contact = pressed.and_then(|p| hit(p.category(Category::Object), close));
    PathClearance {
        collision_free: complete
            && closest
                .as_ref()
                .is_none_or(|c| c.distance_m >= -EXACT_PENETRATION_TOLERANCE)
            && closing_contact
                .as_ref()
                .is_none_or(|c| c.distance_m >= -CLOSING_PRESS),
        contact_tolerance_m: EXACT_PENETRATION_TOLERANCE,
        closing_press_m: CLOSING_PRESS,
        tolerance_m: approach.tolerance,
        complete,
        closing_from_s: time(close as f64),
        closing_contact,
        closest,
        object: category(Category::Object),
        support: category(Category::Support),
        obstacle: category(Category::Obstacle),
        self_collision: category(Category::SelfCollision),
        steps: approach.steps + closing.steps + pressed.map_or(0, |p| p.steps),
        exact_queries: approach.exact_queries
            + closing.exact_queries
            + pressed.map_or(0, |p| p.exact_queries),
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;
    use crate::geometry::ObstacleSpec;
    use crate::grasp::objects::{ObjectSpec, ShapeSpec, SupportPlane};
    use crate::grasp::optimizer::tests::test_system;
    use crate::kinematics::{Data, forward_kinematics};

    /// Lowest height above the plane `z = h` of the test system's collision shapes, in closed
    /// form (capsule: its lower end minus the radius; box: its lowest corner), independent of
    /// the parry queries the checker runs.
    fn lowest(sys: &HandArm, data: &mut Data, q: &[f64], h: f64) -> f64 {
        let model = &*sys.model;
        forward_kinematics(model, data, q);
        let frame = |n: &str| *data.frame(model.frame_id(n).unwrap());
        let capsule = |link: &str, z0: f64, z1: f64, r: f64| {
            let f = frame(link);
            let (a, b) = (f * Point3::new(0.0, 0.0, z0), f * Point3::new(0.0, 0.0, z1));
            a.z.min(b.z) - r - h
        };
        let mut low = capsule("j4_link", 0.05, 0.22, 0.035);
        for k in 0..2 {
            low = low.min(capsule(&format!("f{k}_prox_link"), 0.012, 0.05, 0.008));
            low = low.min(capsule(&format!("f{k}_dist_link"), 0.0, 0.036, 0.008));
        }
        let palm = frame("palm");
        for sx in [-1.0, 1.0] {
            for sy in [-1.0, 1.0] {
                for sz in [-1.0, 1.0] {
                    let c = palm * Point3::new(0.025 * sx, 0.05 * sy, -0.02 + 0.02 * sz);
                    low = low.min(c.z - h);
                }
            }
        }
        low
    }

    /// The support clearance of a path, against dense closed-form sampling of the same
    /// polyline: within the check's tolerance of the sampled minimum, found at the same time
    /// inside the segment, and a dip under the table is a collision while a path above it is
    /// free.
    #[test]
    fn the_support_clearance_of_a_path_matches_dense_closed_form_sampling() {
        let sys = test_system();
        let nq = sys.model.nq();
        let table = 0.167;
        let object = Object::new(ObjectSpec {
            name: "ball".into(),
            shape: ShapeSpec::Sphere { radius: 0.033 },
            position: [0.5, 0.4, 0.2],
            orientation: [1.0, 0.0, 0.0, 0.0],
            support: Some(SupportPlane::horizontal(table)),
            mass: None,
            friction: None,
        })
        .unwrap();
        let j2 = sys.model.q_index("j2").unwrap();
        let j4 = sys.model.q_index("j4").unwrap();
        let mut data = Data::new(&sys.model);
        // One segment: the shoulder holds, the elbow sweeps through the posture where the
        // forearm points straight down (j2 + j4 = pi), so the lowest point lies inside the
        // segment, not at a given point. Shoulder forward: the hand passes under the table;
        // shoulder nearly upright: it stays clear.
        for (shoulder, dips) in [(1.6, true), (0.2, false)] {
            let points: Vec<Vec<f64>> = [-0.5, 2.5]
                .iter()
                .map(|&elbow| {
                    let mut q = vec![0.0; nq];
                    q[j2] = shoulder;
                    q[j4] = elbow;
                    q
                })
                .collect();
            let times = [0.0, 2.0];
            let c = path_clearance(&sys, Some(&object), &[], &points.concat(), &times);
            assert!(c.complete);
            let support = c.support.clone().expect("a support plane");
            assert!(c.obstacle.is_none());
            // The same table as a 10 m x 10 m x 2 m box obstacle, without object or plane: the
            // obstacle clearance is the same closed form (a link dips through its top face, the
            // nearest way out of a box that large).
            let slab = SceneShape::from_spec(
                &ObstacleSpec {
                    name: "table top".into(),
                    shape: ShapeSpec::Box {
                        size: [10.0, 10.0, 2.0],
                    },
                    position: [0.0, 0.0, table - 1.0],
                    orientation: [1.0, 0.0, 0.0, 0.0],
                },
                "$.obstacles[0].",
            )
            .unwrap();
            let o = path_clearance(&sys, None, &[slab], &points.concat(), &times);
            let hit = o.obstacle.clone().expect("an obstacle");
            assert_eq!(hit.other, "table top");
            assert!(o.support.is_none() && o.object.is_none());
            assert!(
                (hit.distance_m - support.distance_m).abs() <= 2.0 * o.tolerance_m + 2e-4,
                "obstacle {} vs support {}",
                hit.distance_m,
                support.distance_m
            );
            if dips {
                assert!(!o.collision_free);
            }
            // Dense sampling of the same polyline.
            let (mut best, mut at) = (f64::INFINITY, 0.0);
            let n = 4000;
            let mut q = vec![0.0; nq];
            for i in 0..=n {
                let f = i as f64 / n as f64;
                for j in 0..nq {
                    q[j] = points[0][j] + f * (points[1][j] - points[0][j]);
                }
                let d = lowest(&sys, &mut data, &q, table);
                if d < best {
                    (best, at) = (d, 2.0 * f);
                }
            }
            assert!(
                (support.distance_m - best).abs() <= c.tolerance_m + 2e-4,
                "reported {} vs sampled {best}",
                support.distance_m
            );
            assert!(
                (support.time_s - at).abs() < 0.05,
                "{} vs {at}",
                support.time_s
            );
            assert_eq!(best < -1e-3, dips);
            assert_eq!(
                !c.collision_free,
                dips || c.closest.as_ref().unwrap().distance_m < -1e-3
            );
            if dips {
                assert!(!c.collision_free);
                assert!(
                    at > 0.1 && at < 1.9,
                    "the lowest point lies inside the segment: {at}"
                );
            }
        }
    }

    /// Finger 0's distal capsule of the test system: radius and length (m).
    const DISTAL_RADIUS: f64 = 0.008;
    const DISTAL_LENGTH: f64 = 0.036;
    /// The ball the pad tests place on that capsule's end (m).
    const PAD_BALL_RADIUS: f64 = 0.02;

    /// The test system reaching forward and down (shoulder 0.9 rad, elbow 1.2 rad).
    fn pad_grasp(sys: &HandArm) -> Vec<f64> {
        let mut q = vec![0.0; sys.model.nq()];
        q[sys.model.q_index("j2").unwrap()] = 0.9;
        q[sys.model.q_index("j4").unwrap()] = 1.2;
        q
    }

    /// A ball pressing `depth` into the end cap of finger 0's distal capsule at posture `q`
    /// (placed along the capsule's axis by forward kinematics, so the depth is known in closed
    /// form: centre distance minus both radii), and its centre.
    fn ball_on_pad(sys: &HandArm, q: &[f64], depth: f64) -> (Object, Point3<f64>) {
        let model = &*sys.model;
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, q);
        let tip = *data.frame(model.frame_id("f0_dist_link").unwrap());
        let axis = tip.rotation * nalgebra::Vector3::z();
        let c = tip * Point3::new(0.0, 0.0, DISTAL_LENGTH)
            + axis * (PAD_BALL_RADIUS + DISTAL_RADIUS - depth);
        let ball = Object::new(ObjectSpec {
            name: "ball".into(),
            shape: ShapeSpec::Sphere {
                radius: PAD_BALL_RADIUS,
            },
            position: [c.x, c.y, c.z],
            orientation: [1.0, 0.0, 0.0, 0.0],
            support: None,
            mass: None,
            friction: None,
        })
        .unwrap();
        (ball, c)
    }

    /// The closing phase: a fingertip pad pressing 3 mm into the object at the end of the
    /// motion is contact (the press reported, the path free), 8 mm is a collision, and the same
    /// 3 mm reached halfway (before the hand closes) is a collision. The object is placed from
    /// the distal capsule's end by forward kinematics, so the depth is known in closed form
    /// (sphere against capsule end: centre distance − radii) and compared with the exact report.
    #[test]
    fn fingertip_pads_may_press_only_while_the_hand_closes_and_only_so_far() {
        let sys = test_system();
        let j2 = sys.model.q_index("j2").unwrap();
        let grasp = pad_grasp(&sys);
        let ball = |depth: f64| ball_on_pad(&sys, &grasp, depth).0;
        // lifted away by the shoulder, then down onto the ball
        let lifted = |by: f64| {
            let mut q = grasp.clone();
            q[j2] -= by;
            q
        };
        let reach = [lifted(0.4), lifted(0.2), grasp.clone()].concat();
        let times = [0.0, 0.5, 1.0];
        for (depth, free) in [(0.003, true), (0.008, false)] {
            let c = path_clearance(&sys, Some(&ball(depth)), &[], &reach, &times);
            assert!(c.complete);
            assert_eq!(c.closing_from_s, 0.5);
            let pressed = c.closing_contact.clone().expect("the pads meet the ball");
            assert_eq!(pressed.link, "f0_dist_link");
            assert!(
                (pressed.distance_m + depth).abs() <= c.tolerance_m + 1e-6,
                "{pressed:?} vs {depth}"
            );
            assert!((pressed.time_s - 1.0).abs() < 0.05, "{pressed:?}");
            assert_eq!(c.collision_free, free, "{depth}: {c:?}");
            // the pad is no collision in the closing phase: what is reported is elsewhere
            assert!(
                c.object.as_ref().is_none_or(|o| o.distance_m > -1e-3),
                "{c:?}"
            );
        }
        // the same 3 mm, reached halfway and left again: before the closing phase
        let through = [lifted(0.4), grasp.clone(), lifted(0.4)].concat();
        let c = path_clearance(&sys, Some(&ball(0.003)), &[], &through, &times);
        assert!(!c.collision_free);
        let hit = c.closest.clone().unwrap();
        assert_eq!(
            (hit.link.as_str(), hit.other.as_str()),
            ("f0_dist_link", "ball")
        );
        assert!(
            (hit.distance_m + 0.003).abs() <= c.tolerance_m + 1e-6,
            "{hit:?}"
        );
        assert!((hit.time_s - 0.5).abs() < 0.05, "{hit:?}");
    }

    /// A path whose last segment brings a fingertip pad to its contact from inside the object
    /// (the pad crosses the surface and comes back before the end) is turned so that the pad
    /// arrives from outside; a path that already does is left as it is. Judged along the spline
    /// near the end by the closed-form sphere–capsule distance of that pad (centre to the
    /// distal capsule's segment, minus both radii), not by the checker the function uses.
    #[test]
    fn a_pad_that_would_cross_the_surface_before_its_contact_arrives_from_outside() {
        let sys = test_system();
        let nq = sys.model.nq();
        let model = &*sys.model;
        let j2 = model.q_index("j2").unwrap();
        let grasp = pad_grasp(&sys);
        let mut data = Data::new(model);
        let distal = model.frame_id("f0_dist_link").unwrap();
        let (r, pad) = (PAD_BALL_RADIUS, DISTAL_RADIUS);
        // the ball touches the distal capsule's end cap at the grasp
        let (object, centre) = ball_on_pad(&sys, &grasp, 0.0);
        let mut pad_distance = |q: &[f64]| {
            forward_kinematics(model, &mut data, q);
            let f = *data.frame(distal);
            let (a, b) = (
                f * Point3::origin(),
                f * Point3::new(0.0, 0.0, DISTAL_LENGTH),
            );
            let ab = b - a;
            let s = ((centre - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
            (centre - (a + ab * s)).norm() - r - pad
        };
        let shoulder = |by: f64| {
            let mut q = grasp.clone();
            q[j2] -= by;
            q
        };
        // The clamped uniform cubic B-spline of 5 control configurations (knots 0,0,0,0, ½,
        // 1,1,1,1), its basis by the Cox–de Boor recursion, sampled over the last tenth.
        let knots = [0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0];
        fn basis(k: &[f64], i: usize, p: usize, x: f64) -> f64 {
            if p == 0 {
                return f64::from(u8::from(k[i] <= x && x < k[i + 1]));
            }
            let a = if k[i + p] > k[i] {
                (x - k[i]) / (k[i + p] - k[i]) * basis(k, i, p - 1, x)
            } else {
                0.0
            };
            let b = if k[i + p + 1] > k[i + 1] {
                (k[i + p + 1] - x) / (k[i + p + 1] - k[i + 1]) * basis(k, i + 1, p - 1, x)
            } else {
                0.0
            };
            a + b
        }
        let end: Vec<CurveSample> = (1..=200)
            .map(|i| {
                let x = 1.0 - 0.1 * i as f64 / 200.0;
                // x > 1/2: the last four configurations carry the curve
                CurveSample {
                    x,
                    first: 1,
                    w: [1, 2, 3, 4].map(|r| basis(&knots, r, 3, x)),
                }
            })
            .collect();
        for cs in &end {
            assert!((cs.w.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{cs:?}");
        }
        let along = |path: &[f64], f: &mut dyn FnMut(&[f64]) -> f64| -> Vec<f64> {
            end.iter()
                .map(|cs| {
                    let mut q = vec![0.0; nq];
                    for (k, &w) in cs.w.iter().enumerate() {
                        let row = &path[(cs.first + k) * nq..(cs.first + k + 1) * nq];
                        q.iter_mut().zip(row).for_each(|(v, c)| *v += w * c);
                    }
                    f(&q)
                })
                .collect()
        };
        let at_goal = pad_distance(&grasp);
        assert!(at_goal.abs() < 1e-9, "{at_goal}");
        // shoulder lifting the hand away: -by; the last interior configuration pushes past the
        // contact (+0.06 rad into the ball), so the curve ends coming out of it
        let crossing = [
            shoulder(0.3),
            shoulder(0.2),
            shoulder(0.1),
            shoulder(-0.06),
            grasp.clone(),
        ]
        .concat();
        let deepest = |d: &[f64]| d.iter().fold(f64::INFINITY, |m: f64, &x| m.min(x));
        let before = deepest(&along(&crossing, &mut pad_distance));
        assert!(
            before < -1e-3,
            "the test path crosses the surface: {before}"
        );
        let mut turned = crossing.clone();
        let a = arrive_from_outside(&sys, Some(&object), &[], &mut turned, &end);
        assert!(a.from_inside >= 1, "{a:?}");
        assert!(
            (a.overshoot_before + before).abs() < 2e-4,
            "reported {a:?} vs closed form {before}"
        );
        assert_eq!(&turned[4 * nq..], &grasp[..], "the goal stays");
        assert_eq!(&turned[..nq], &crossing[..nq], "the start stays");
        let after = deepest(&along(&turned, &mut pad_distance));
        assert!(
            after > -1e-5,
            "the pad arrives from outside: {after} ({a:?})"
        );
        assert!(a.overshoot_after < 1e-5 && a.change > 0.0, "{a:?}");
        // arriving from outside already: kept bit for bit
        let approaching = [
            shoulder(0.3),
            shoulder(0.2),
            shoulder(0.1),
            shoulder(0.05),
            grasp.clone(),
        ]
        .concat();
        let mut kept = approaching.clone();
        let a = arrive_from_outside(&sys, Some(&object), &[], &mut kept, &end);
        assert_eq!(a.from_inside, 0, "{a:?}");
        assert_eq!(kept, approaching);
        assert!(deepest(&along(&kept, &mut pad_distance)) > -1e-9);
    }
}
