//! Fingertip goal assignment (paper §III-A.1, the paragraph after eq. 3).
//!
//! The human thumb tip is the goal of the robot's thumb finger. The other `m − 1` robot fingers
//! get points of a smooth spline through the index, middle, ring and pinky tips, equally spaced in
//! arc length: both ends when `m − 1 ≥ 2`, the middle point when `m − 1 = 1`.
//!
//! **Which spline and why: centripetal Catmull-Rom (α = ½).** It interpolates the four tips
//! exactly (the robot's outer fingers land on the human index and pinky when `m − 1 ≥ 2`), it is
//! local and closed-form (no linear solve per frame, so the 5,000 frames/s budget is untouched),
//! and — unlike the uniform or chordal variants and unlike a natural cubic spline on a uniform
//! parameter — it provably has no cusps or self-intersections within a segment however unevenly
//! the four tips are spaced (Yuksel et al. 2011). Fingertips bunch together when the hand closes
//! and spread when it opens, so uneven spacing is the normal case. The end segments use mirrored
//! phantom points (`P₋₁ = 2P₀ − P₁`), which keeps collinear, evenly spaced tips on a straight
//! line traversed at constant speed.
//!
//! Arc length is integrated with 8-point Gauss-Legendre quadrature per segment (the speed of a
//! cubic is smooth, so this is accurate to ~1e-10 relative for fingertip-scale curves) and
//! inverted with safeguarded Newton steps. Everything lives in fixed-size arrays: no allocation.

use nalgebra::{Point3, UnitQuaternion, Vector3};

/// Most robot fingers a hand can have here (the human hand has five).
pub const MAX_FINGERS: usize = 5;

/// Position and orientation goal of one robot fingertip, in the robot base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FingerGoal {
    pub position: Point3<f64>,
    pub orientation: UnitQuaternion<f64>,
}

impl Default for FingerGoal {
    fn default() -> Self {
        Self {
            position: Point3::origin(),
            orientation: UnitQuaternion::identity(),
        }
    }
}

/// 8-point Gauss-Legendre nodes and weights on [-1, 1].
const GL_NODES: [f64; 8] = [
    -0.960_289_856_497_536_3,
    -0.796_666_477_413_626_7,
    -0.525_532_409_916_329,
    -0.183_434_642_495_649_8,
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
const GL_WEIGHTS: [f64; 8] = [
    0.101_228_536_290_376_26,
    0.222_381_034_453_374_47,
    0.313_706_645_877_887_3,
    0.362_683_783_378_362,
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_47,
    0.101_228_536_290_376_26,
];

/// One cubic segment `C(u) = a u³ + b u² + c u + d`, `u ∈ [0, 1]`.
#[derive(Clone, Copy, Debug)]
struct Cubic {
    a: Vector3<f64>,
    b: Vector3<f64>,
    c: Vector3<f64>,
    d: Vector3<f64>,
}

impl Cubic {
    fn eval(&self, u: f64) -> Vector3<f64> {
        ((self.a * u + self.b) * u + self.c) * u + self.d
    }
    fn speed(&self, u: f64) -> f64 {
        (self.a * (3.0 * u * u) + self.b * (2.0 * u) + self.c).norm()
    }
    /// Arc length over `[0, u]`.
    fn length_to(&self, u: f64) -> f64 {
        let half = 0.5 * u;
        let mut s = 0.0;
        for (x, w) in GL_NODES.iter().zip(GL_WEIGHTS.iter()) {
            s += w * self.speed(half * (x + 1.0));
        }
        s * half
    }
    /// Parameter `u` at which the arc length from 0 equals `s` (`0 ≤ s ≤ total`).
    fn param_at(&self, s: f64, total: f64) -> f64 {
        if total <= 0.0 {
            return 0.5;
        }
        let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
        let mut u = (s / total).clamp(0.0, 1.0);
        // Newton on L(u) − s with a bisection bracket: the speed can get small near a tight bend.
        for _ in 0..40 {
            let f = self.length_to(u) - s;
            if f.abs() <= 1e-13 * total.max(1e-300) {
                break;
            }
            if f > 0.0 {
                hi = u;
            } else {
                lo = u;
            }
            let v = self.speed(u);
            let mut next = if v > 1e-300 { u - f / v } else { f64::NAN };
            if next.is_nan() || next <= lo || next >= hi {
                next = 0.5 * (lo + hi);
            }
            u = next;
        }
        u
    }
}

/// A centripetal Catmull-Rom curve through exactly four points (index, middle, ring, pinky tips).
#[derive(Clone, Copy, Debug)]
pub struct CatmullRom4 {
    segments: [Cubic; 3],
    lengths: [f64; 3],
}

impl CatmullRom4 {
    /// Builds the curve through `p[0..4]` in order.
    pub fn new(p: &[Point3<f64>; 4]) -> Self {
        let v = |i: usize| p[i].coords;
        // Mirrored phantom end points.
        let ext = [v(0) * 2.0 - v(1), v(0), v(1), v(2), v(3), v(3) * 2.0 - v(2)];
        // Centripetal knots: interval = |ΔP|^½, floored so coincident tips stay finite.
        let mut dt = [0.0; 5];
        for (i, d) in dt.iter_mut().enumerate() {
            *d = (ext[i + 1] - ext[i]).norm().max(1e-12).sqrt();
        }
        let mut segments = [Cubic {
            a: Vector3::zeros(),
            b: Vector3::zeros(),
            c: Vector3::zeros(),
            d: Vector3::zeros(),
        }; 3];
        let mut lengths = [0.0; 3];
        for s in 0..3 {
            // Segment from ext[s+1] to ext[s+2], neighbours ext[s], ext[s+3].
            let (p0, p1, p2, p3) = (ext[s], ext[s + 1], ext[s + 2], ext[s + 3]);
            let (t01, t12, t23) = (dt[s], dt[s + 1], dt[s + 2]);
            // Hermite tangents of the Barry-Goldman pyramid, rescaled to u ∈ [0, 1].
            let m1 = ((p1 - p0) / t01 - (p2 - p0) / (t01 + t12) + (p2 - p1) / t12) * t12;
            let m2 = ((p2 - p1) / t12 - (p3 - p1) / (t12 + t23) + (p3 - p2) / t23) * t12;
            let cubic = Cubic {
                a: p1 * 2.0 - p2 * 2.0 + m1 + m2,
                b: p1 * -3.0 + p2 * 3.0 - m1 * 2.0 - m2,
                c: m1,
                d: p1,
            };
            lengths[s] = cubic.length_to(1.0);
            segments[s] = cubic;
        }
        Self { segments, lengths }
    }

    /// Total arc length.
    pub fn length(&self) -> f64 {
        self.lengths.iter().sum()
    }

    /// Point at curve parameter `t ∈ [0, 3]` (segment `⌊t⌋`, local `t − ⌊t⌋`).
    pub fn eval(&self, t: f64) -> Point3<f64> {
        let t = t.clamp(0.0, 3.0);
        let seg = (t.floor() as usize).min(2);
        Point3::from(self.segments[seg].eval(t - seg as f64))
    }

    /// Curve parameter `t ∈ [0, 3]` at arc length `s` from the first tip, with the segment and
    /// the fraction of that segment's arc length.
    pub fn param_at_arc_length(&self, s: f64) -> (f64, usize, f64) {
        let mut rest = s.clamp(0.0, self.length());
        for seg in 0..3 {
            let len = self.lengths[seg];
            if rest <= len || seg == 2 {
                let rest = rest.min(len);
                let u = self.segments[seg].param_at(rest, len);
                let frac = if len > 0.0 { rest / len } else { 0.5 };
                return (seg as f64 + u, seg, frac);
            }
            rest -= len;
        }
        unreachable!("the loop returns on its last segment")
    }

    /// The point at arc length `s` from the first tip: `(point, segment, fraction of that
    /// segment's arc length)`.
    pub fn at_arc_length(&self, s: f64) -> (Point3<f64>, usize, f64) {
        let (t, seg, frac) = self.param_at_arc_length(s);
        let p = Point3::from(self.segments[seg].eval(t - seg as f64));
        (p, seg, frac)
    }
}

/// Arc-length positions (fraction of the total) of `k` goals on the spline: both ends included
/// when `k ≥ 2`, the middle point when `k = 1`.
pub fn arc_fractions(k: usize, out: &mut [f64]) {
    match k {
        0 => {}
        1 => out[0] = 0.5,
        _ => {
            for (j, o) in out.iter_mut().take(k).enumerate() {
                *o = j as f64 / (k - 1) as f64;
            }
        }
    }
}

/// Robot fingertip goals for one frame.
///
/// `tips` are the registered human fingertip poses (thumb, index, middle, ring, pinky);
/// `robot_fingers` the robot's finger count `m`; `thumb` the robot finger that takes the human
/// thumb. The other robot fingers, in their descriptor order (radial to ulnar), take the spline
/// points from the index end to the pinky end. Writes `out[0..m]`.
pub fn finger_goals(
    tips: &[(Point3<f64>, UnitQuaternion<f64>); 5],
    robot_fingers: usize,
    thumb: usize,
    out: &mut [FingerGoal],
) {
    debug_assert!(robot_fingers <= MAX_FINGERS && thumb < robot_fingers);
    out[thumb] = FingerGoal {
        position: tips[0].0,
        orientation: tips[0].1,
    };
    let k = robot_fingers - 1;
    if k == 0 {
        return;
    }
    let pts = [tips[1].0, tips[2].0, tips[3].0, tips[4].0];
    let curve = CatmullRom4::new(&pts);
    let total = curve.length();
    let mut fractions = [0.0; MAX_FINGERS];
    arc_fractions(k, &mut fractions);
    let mut j = 0;
    for (finger, goal) in out.iter_mut().enumerate().take(robot_fingers) {
        if finger == thumb {
            continue;
        }
        let (position, seg, frac) = curve.at_arc_length(fractions[j] * total);
        // Orientation: slerp between the two human tip frames bounding the segment, by the
        // arc-length fraction within it (nalgebra's slerp takes the shorter arc).
        let orientation = tips[1 + seg].1.slerp(&tips[2 + seg].1, frac);
        *goal = FingerGoal {
            position,
            orientation,
        };
        j += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Independent arc-length reference: a dense polyline.
    fn polyline_length(curve: &CatmullRom4, t0: f64, t1: f64) -> f64 {
        let n = 200_000;
        let mut s = 0.0;
        let mut prev = curve.eval(t0);
        for i in 1..=n {
            let p = curve.eval(t0 + (t1 - t0) * i as f64 / n as f64);
            s += (p - prev).norm();
            prev = p;
        }
        s
    }

    fn tips_from(points: [Point3<f64>; 4]) -> [(Point3<f64>, UnitQuaternion<f64>); 5] {
        let q = UnitQuaternion::identity();
        [
            (Point3::new(0.0, -0.05, 0.0), q),
            (points[0], q),
            (points[1], q),
            (points[2], q),
            (points[3], q),
        ]
    }

    #[test]
    fn spline_interpolates_the_four_tips() {
        let p = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.02, 0.01, 0.003),
            Point3::new(0.035, 0.012, -0.004),
            Point3::new(0.06, 0.0, 0.001),
        ];
        let c = CatmullRom4::new(&p);
        for (i, pi) in p.iter().enumerate() {
            assert!((c.eval(i as f64) - pi).norm() < 1e-14);
        }
    }

    #[test]
    fn collinear_uneven_tips_give_goals_on_the_line_equally_spaced() {
        let dir = Vector3::new(1.0, 2.0, -0.5).normalize();
        let o = Point3::new(0.3, -0.1, 0.2);
        let along = [0.0, 0.013, 0.041, 0.052];
        let pts = along.map(|a| o + dir * a);
        for k in 1..=4 {
            let mut out = [FingerGoal::default(); 5];
            finger_goals(&tips_from(pts), k + 1, 0, &mut out);
            let goals: Vec<f64> = out[1..=k]
                .iter()
                .map(|g| (g.position - o).dot(&dir))
                .collect();
            for g in &out[1..=k] {
                let off = (g.position - o) - dir * (g.position - o).dot(&dir);
                assert!(off.norm() < 1e-12, "goal left the line by {}", off.norm());
            }
            if k == 1 {
                assert!((goals[0] - 0.026).abs() < 1e-9, "middle {}", goals[0]);
            } else {
                for (j, g) in goals.iter().enumerate() {
                    let want = 0.052 * j as f64 / (k - 1) as f64;
                    assert!((g - want).abs() < 1e-9, "k={k} j={j}: {g} vs {want}");
                }
            }
        }
    }

    #[test]
    fn tips_on_a_circle_give_symmetric_goals_near_the_circle() {
        let r = 0.08;
        let c = Point3::new(0.1, 0.2, 0.3);
        let step = 20.0_f64.to_radians();
        let pts: [Point3<f64>; 4] = std::array::from_fn(|j| {
            let a = PI / 3.0 + step * j as f64;
            c + Vector3::new(r * a.cos(), r * a.sin(), 0.0)
        });
        let mid_angle = PI / 3.0 + 1.5 * step;
        // Reflection across the bisecting diameter maps the tip set onto itself.
        let axis = Vector3::new(mid_angle.cos(), mid_angle.sin(), 0.0);
        let mirror = |p: Point3<f64>| {
            let v = p - c;
            c + (axis * (2.0 * v.dot(&axis)) - v)
        };
        for k in 1..=4 {
            let mut out = [FingerGoal::default(); 5];
            finger_goals(&tips_from(pts), k + 1, 0, &mut out);
            let g: Vec<Point3<f64>> = out[1..=k].iter().map(|g| g.position).collect();
            for (j, p) in g.iter().enumerate() {
                assert!(((p - c).norm() - r).abs() < 1e-3 * r, "radius off at {j}");
                assert!(
                    (mirror(*p) - g[k - 1 - j]).norm() < 1e-9,
                    "k={k} not symmetric"
                );
                assert!(p.z == c.z || (p.z - c.z).abs() < 1e-15);
            }
            if k == 1 {
                let a = (g[0].y - c.y).atan2(g[0].x - c.x);
                assert!((a - mid_angle).abs() < 1e-9);
            }
            if k >= 2 {
                assert!((g[0] - pts[0]).norm() < 1e-12 && (g[k - 1] - pts[3]).norm() < 1e-12);
            }
        }
    }

    #[test]
    fn goals_are_equally_spaced_in_arc_length_against_a_polyline_reference() {
        let p = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.021, 0.008, 0.004),
            Point3::new(0.030, 0.010, -0.006),
            Point3::new(0.062, -0.004, 0.002),
        ];
        let curve = CatmullRom4::new(&p);
        let total = polyline_length(&curve, 0.0, 3.0);
        assert!((curve.length() - total).abs() < 1e-8 * total);
        // The goal at arc length s must sit where the reference polyline measures s.
        for frac in [0.2, 1.0 / 3.0, 0.5, 0.77] {
            let (t, seg, _) = curve.param_at_arc_length(frac * curve.length());
            let (pt, _, _) = curve.at_arc_length(frac * curve.length());
            assert!((curve.eval(t) - pt).norm() < 1e-15 && seg == t.floor() as usize);
            let s_ref = polyline_length(&curve, 0.0, t);
            assert!(
                (s_ref - frac * total).abs() < 1e-8 * total,
                "{s_ref} vs {}",
                frac * total
            );
        }
    }

    #[test]
    fn coincident_tips_stay_finite() {
        let p = Point3::new(0.1, 0.1, 0.1);
        let mut out = [FingerGoal::default(); 5];
        finger_goals(&tips_from([p, p, p, p]), 4, 1, &mut out);
        for g in &out[..4] {
            assert!(g.position.coords.iter().all(|x| x.is_finite()));
        }
        assert!((out[0].position - p).norm() < 1e-9 && (out[3].position - p).norm() < 1e-9);
    }

    #[test]
    fn spline_orientations_interpolate_on_the_sphere() {
        // Tip frames rotating about z by 0, 30, 60, 90 degrees on equally spaced collinear tips:
        // the middle goal (k = 1) sits halfway along segment 1, so its frame is at 45 degrees.
        let pts = [0.0, 0.02, 0.04, 0.06].map(|x| Point3::new(x, 0.0, 0.0));
        let mut tips = tips_from(pts);
        for (j, t) in tips[1..].iter_mut().enumerate() {
            // Flip the sign of one quaternion: the antipodal representation must not matter.
            let q =
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (30.0 * j as f64).to_radians());
            t.1 = if j == 2 {
                UnitQuaternion::new_unchecked(-q.into_inner())
            } else {
                q
            };
        }
        let mut out = [FingerGoal::default(); 5];
        finger_goals(&tips, 2, 0, &mut out);
        let want = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 45.0_f64.to_radians());
        assert!(out[1].orientation.angle_to(&want) < 1e-9);
        assert!((out[1].position.x - 0.03).abs() < 1e-12);
    }
}
