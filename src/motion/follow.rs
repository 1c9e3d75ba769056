//! The closed-loop law that runs the open-loop humanlike motion (issue 19, "one motion"): the
//! timed path the model generates for this start and goal (the flow, its residual profile, the
//! groups' phase maps, an approach phase and any clearance refinement: exactly what open loop
//! follows) is the reference, and a **governed clock** says where on it the robot should be.
//!
//! Per control period, with `p(τ)`, `ṗ(τ)` the path's positions and velocities at the clock
//! `τ`, `e = ‖p(τ) − q‖∞` and `g = 1/(1 + (e/e₀)²)`:
//!
//! ```text
//! u = g·ṗ(τ) + K (p(τ) − q),        τ ← min(τ + g·dt, T)
//! ```
//!
//! with each joint's feedback held below `√(2 a_j |e_j|)` where the robot brakes at `a_j`, so a
//! pushed joint comes back to the path without overshooting it.
//!
//! On the path (`e ≪ e₀`) the clock runs at real time and the robot moves as in open loop. A push
//! raises `e`: the clock all but stops (`g = 0.14` at `e = 2.5 e₀`), the feedback brings the robot
//! back to where it left the path, and the motion goes on from there; the same happens while a
//! safety filter holds the robot back. So the executed path is the open-loop path between
//! pushes, not a new motion from wherever the push left the robot.
//!
//! Convergence: `g > 0` for every bounded error, so `τ` reaches `T` in finite time; from then on
//! `u = K (q_goal − q)`, which converges exponentially (a velocity-controlled joint). The law
//! with no path (eq. 8, [`super::ControlParams::control`]) stays what a worker runs when the
//! service knows no start to generate the path from.
//!
//! Why not the navigation function's gradient with the profile added as a state-dependent
//! offset: the profile is indexed by arc-length progress along the path, which is not a
//! function of the state (the hand opens and closes again over the same joint values, and a
//! push moves the state to another flow line whose progress is undefined), and the groups'
//! phase maps couple the hand's progress to the arm's, which a per-group gradient law cannot
//! express. The clock is the one state the law keeps.

use super::TrajectoryPoint;

/// The error `e₀` (rad, largest joint deviation) at which the clock runs at half speed: a few
/// times the tracking lag of a velocity-controlled arm on a humanlike path at 100 Hz (measured
/// 1-4 mrad on the reference worker), a fraction of a push.
pub const CLOCK_TOLERANCE: f64 = 0.02;

/// A governed clock on a timed path (see the module docs). Allocation-free per period.
#[derive(Clone, Debug, PartialEq)]
pub struct PathFollower {
    /// Feedback gain `K`, 1/s.
    pub gain: f64,
    /// `e₀`, rad.
    pub tolerance: f64,
    /// Per joint, the deceleration the robot can brake at (rad/s²; empty: no bound). The
    /// feedback on a joint is at most `√(2 a |e_j|)`, the speed from which it stops on the
    /// reference: above it a pushed joint would overshoot the path on its way back.
    pub braking: Vec<f64>,
    /// The clock `τ`, s of path time.
    pub clock: f64,
    /// Index of the path point at or before the clock.
    cursor: usize,
}

impl PathFollower {
    pub fn new(gain: f64, tolerance: f64, braking: Vec<f64>) -> Self {
        PathFollower {
            gain,
            tolerance,
            braking,
            clock: 0.0,
            cursor: 0,
        }
    }

    /// One control period of `dt` from the measured `q`: the command into `u`, the reference
    /// `p(τ)` into `reference`, and the clock advanced. Returns `e` (before the step). `path`
    /// must be non-empty with strictly increasing times and `n` values per vector.
    pub fn step(
        &mut self,
        path: &[TrajectoryPoint],
        q: &[f64],
        dt: f64,
        reference: &mut [f64],
        u: &mut [f64],
    ) -> f64 {
        let t0 = path[0].t;
        let t_end = path[path.len() - 1].t;
        let tau = (t0 + self.clock).min(t_end);
        while self.cursor + 1 < path.len() && path[self.cursor + 1].t <= tau {
            self.cursor += 1;
        }
        let a = &path[self.cursor];
        let moving = self.cursor + 1 < path.len();
        let mut e = 0.0f64;
        if moving {
            let b = &path[self.cursor + 1];
            let s = ((tau - a.t) / (b.t - a.t)).clamp(0.0, 1.0);
            for j in 0..q.len() {
                reference[j] = a.positions[j] + s * (b.positions[j] - a.positions[j]);
                u[j] = a.velocities[j] + s * (b.velocities[j] - a.velocities[j]);
                e = e.max((reference[j] - q[j]).abs());
            }
        } else {
            for j in 0..q.len() {
                reference[j] = a.positions[j];
                u[j] = 0.0;
                e = e.max((reference[j] - q[j]).abs());
            }
        }
        let g = 1.0 / (1.0 + (e / self.tolerance).powi(2));
        for j in 0..q.len() {
            let e = reference[j] - q[j];
            let mut fb = self.gain * e;
            if let Some(&a) = self.braking.get(j) {
                let stop = (2.0 * a * e.abs()).sqrt();
                fb = fb.clamp(-stop, stop);
            }
            u[j] = g * u[j] + fb;
        }
        self.clock = (self.clock + g * dt).min(t_end - t0);
        e
    }

    /// Share of the path's time the clock has run, in [0, 1].
    pub fn progress(&self, path: &[TrajectoryPoint]) -> f64 {
        let span = path[path.len() - 1].t - path[0].t;
        if span > 0.0 {
            (self.clock / span).min(1.0)
        } else {
            1.0
        }
    }

    /// The clock has reached the path's end (from here the law is `K (q_goal − q)`).
    pub fn at_end(&self, path: &[TrajectoryPoint]) -> bool {
        self.progress(path) >= 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A planar quarter circle `p(t) = (cos θ, sin θ)`, `θ = (π/2)·x(t/T)` with the minimum-jerk
    /// time law `x = 10s³ − 15s⁴ + 6s⁵` (closed form; at rest at both ends).
    fn arc(duration: f64, rate: f64) -> Vec<TrajectoryPoint> {
        let a = std::f64::consts::FRAC_PI_2;
        let count = (duration * rate).round() as usize + 1;
        (0..count)
            .map(|i| {
                let t = i as f64 / rate;
                let x = t / duration;
                let th = a * x.powi(3) * (10.0 - 15.0 * x + 6.0 * x * x);
                let w = a * 30.0 * x * x * (1.0 - x).powi(2) / duration;
                let (s, c) = th.sin_cos();
                TrajectoryPoint {
                    t,
                    positions: vec![c, s],
                    velocities: vec![-w * s, w * c],
                    accelerations: vec![0.0, 0.0],
                }
            })
            .collect()
    }

    /// Distance of `q` from the unit circle's quarter arc (closed form).
    fn off_arc(q: &[f64]) -> f64 {
        let angle = q[1].atan2(q[0]).clamp(0.0, std::f64::consts::FRAC_PI_2);
        ((q[0] - angle.cos()).powi(2) + (q[1] - angle.sin()).powi(2)).sqrt()
    }

    /// Integrates `q̇ = u` at 100 Hz for 20 s, pushing `q` by `push` at `push_at` s; the
    /// states and the clock after each period.
    fn run(path: &[TrajectoryPoint], push_at: f64, push: [f64; 2]) -> Vec<([f64; 2], f64)> {
        let mut f = PathFollower::new(8.0, CLOCK_TOLERANCE, Vec::new());
        let mut q = [1.0, 0.0];
        let (mut r, mut u) = ([0.0; 2], [0.0; 2]);
        let dt = 0.01;
        let mut states = Vec::new();
        for k in 0..2000 {
            if k as f64 * dt == push_at {
                q[0] += push[0];
                q[1] += push[1];
            }
            f.step(path, &q, dt, &mut r, &mut u);
            q[0] += dt * u[0];
            q[1] += dt * u[1];
            states.push((q, f.clock));
        }
        assert!(f.at_end(path));
        states
    }

    #[test]
    fn an_unpushed_run_stays_on_the_path_and_arrives() {
        let path = arc(2.0, 100.0);
        let states = run(&path, f64::INFINITY, [0.0; 2]);
        let worst = states.iter().map(|(q, _)| off_arc(q)).fold(0.0, f64::max);
        let (last, _) = states.last().unwrap();
        // Exact feed-forward leaves the 100 Hz Euler steps' sag: each step along the tangent
        // leaves the circle by (v·dt)²/2 ≈ 1.1e-4 at the peak speed 1.47, which the feedback
        // removes at K·dt = 0.08 per step: ≈ 1.4e-3 in steady state.
        assert!(worst < 2e-3, "{worst}");
        assert!(
            last[0].abs() < 1e-9 && (last[1] - 1.0).abs() < 1e-9,
            "{last:?}"
        );
    }

    #[test]
    fn a_pushed_run_returns_to_where_it_left_the_path_and_goes_on_from_there() {
        let path = arc(2.0, 100.0);
        // pushed outward and backward at 0.6 s (0.28 m off the arc)
        let states = run(&path, 0.6, [0.2, 0.2]);
        let (_, left) = states[59];
        let back = 60
            + states[60..]
                .iter()
                .position(|(q, _)| off_arc(q) < 0.01)
                .expect("back on the path");
        let (_, rejoined) = states[back];
        // The return took `back − 60` periods (about 0.4 s at K = 8); a clock that ran on
        // would have moved the reference as far ahead, the governed one waited.
        let away = (back - 60) as f64 * 0.01;
        assert!(away > 0.3, "{away}");
        assert!(
            rejoined - left < 0.4 * away,
            "the clock ran {} s of {away} s away",
            rejoined - left
        );
        // after rejoining it follows the arc again
        let after = states[back..]
            .iter()
            .map(|(q, _)| off_arc(q))
            .fold(0.0, f64::max);
        assert!(after < 0.011, "{after}");
    }
}
