//! Moving a joint-space path the least amount needed for a clearance margin.
//!
//! The path is a curve through joint space given by control configurations (a cubic
//! B-spline's, whose points are weighted sums of at most four of them) and sampled at progress
//! values `x ∈ [0, 1]`; its first and last control configurations are its ends and stay. Each
//! round, every sample closer than its target to the object, the support, an obstacle or (with
//! a small margin) another link gets the minimum-norm joint step that lifts each such pair's
//! signed distance to the target to first order (`Δq = g (target − d) / |g|²`, `g` the exact
//! distance gradient from the witness points; at most `max_step`, a trust region), carried to
//! the control configurations that make the sample by the minimum-norm change (`w_r / Σ w²`),
//! spread over neighbouring control configurations with a Gaussian weight and held inside the
//! joint limits. Overlapping corrections are averaged, not added. Rounds stop when no sample is
//! below target, after `patience` rounds without progress, or after the round budget
//! (deterministic: no wall clock).
//!
//! Targets are per category and ramp towards each end from that end's own clearance: the
//! motion may start in contact (a robot holding what it grasped) and must end in the grasp's
//! contacts (the fingertips on the object), so within `ramp` of an end the target falls
//! linearly to that end's clearance.
//!
//! This is a refinement of the humanlike path, not a planner: it finds a way around what the
//! humanlike motion grazes or passes through locally, not around a wall that blocks it. The
//! exact, continuous check of the timed result ([`super::path`]) decides what is reported.

use super::checker::{Category, CheckData, CollisionChecker};
use super::solid::SignedDistance;

/// How far below its target a point may be and count as keeping it (m).
const SLACK: f64 = 1e-4;

/// Margins and budget of [`refine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvoidOptions {
    /// Clearance kept from the object, the support and obstacles away from the ends (m).
    pub margin: f64,
    /// Clearance kept between two links of the robot (m).
    pub self_margin: f64,
    /// Progress over which a target ramps from an end's clearance to the margin.
    pub ramp: f64,
    /// Progress from the start over which the target stays at the start's own clearance
    /// before its ramp begins: a departure from a held object opens the hand before the arm
    /// backs off, and a target rising meanwhile would move the arm while the fingers still
    /// wrap the object (measured: a wam_ihy thumb pushed 2.9 mm into the ball). 0: none.
    pub hold_start: f64,
    /// Added to the ramps towards the ends (m; the targets never exceed the margin).
    pub buffer: f64,
    /// Gaussian width of the spread of a correction, in configurations.
    pub spread: f64,
    /// Rounds at most.
    pub rounds: usize,
    /// Rounds without progress (no fewer points below target, and the deficit summed over every
    /// pair below target not `min_progress` smaller than its best) after which the refinement
    /// stops early.
    pub patience: usize,
    /// The summed deficit's decrease that counts as progress (m).
    pub min_progress: f64,
    /// Largest joint step of a configuration in one round (rad).
    pub max_step: f64,
}

impl Default for AvoidOptions {
    fn default() -> Self {
        AvoidOptions {
            margin: 0.02,
            self_margin: 0.002,
            ramp: 0.2,
            hold_start: 0.0,
            buffer: 0.003,
            spread: 3.0,
            rounds: 40,
            patience: 5,
            min_progress: 1e-3,
            max_step: 0.05,
        }
    }
}

/// The early stop of [`refine`]: a round makes progress when fewer points are below target
/// than ever before, or the deficit summed over every pair below target is `min_progress`
/// below its best; `patience` rounds in a row without progress stop the rounds.
#[derive(Debug, Clone, Copy)]
struct Progress {
    best_below: usize,
    best_deficit: f64,
    idle: usize,
    min_progress: f64,
    patience: usize,
}

impl Progress {
    fn new(opts: &AvoidOptions) -> Self {
        Progress {
            best_below: usize::MAX,
            best_deficit: f64::INFINITY,
            idle: 0,
            min_progress: opts.min_progress,
            patience: opts.patience,
        }
    }

    /// Records a round; true when the rounds should stop for want of progress.
    fn stalled(&mut self, below: usize, deficit: f64) -> bool {
        if below < self.best_below || deficit < self.best_deficit - self.min_progress {
            self.best_below = self.best_below.min(below);
            self.best_deficit = self.best_deficit.min(deficit);
            self.idle = 0;
        } else {
            self.idle += 1;
        }
        self.idle >= self.patience
    }
}

/// What [`refine`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AvoidReport {
    /// Rounds run (0: the path met every target as it was).
    pub rounds: usize,
    /// Path points below target before the first round.
    pub below_target: usize,
    /// Path points still below target after the last round.
    pub still_below: usize,
    /// Largest joint displacement of a configuration from the given path (rad).
    pub max_displacement: f64,
    /// Smallest clearance minus target over the path points, before and after (m).
    pub worst_before: f64,
    pub worst_after: f64,
}

/// A point of the path: the configuration at progress `x` is `Σ_r w[r] · ctrl[first + r]`
/// (a B-spline's basis; a control polygon sampled at its vertices has one weight 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurveSample {
    pub x: f64,
    pub first: usize,
    pub w: [f64; 4],
}

/// Reusable buffers of [`refine`] (nothing is allocated per configuration).
pub struct AvoidScratch {
    hits: Vec<(usize, SignedDistance)>,
    /// Per curve sample, its last round's step (`nq` values) and what it added to the round's
    /// figures: a sample none of whose control configurations moved since is not checked
    /// again (its step is a function of them alone).
    sample_step: Vec<f64>,
    sample: Vec<SampleStep>,
    /// Per curve sample: a lower bound of every pair's distance (`pairs` values) at `q_ref`
    /// (`nq` values), the configuration of its last check, if `known`.
    lower: Vec<f64>,
    q_ref: Vec<f64>,
    known: Vec<bool>,
    /// Per control configuration: moved in the last round.
    moved: Vec<bool>,
    grad: Vec<f64>,
    q: Vec<f64>,
    step: Vec<f64>,
    corr: Vec<f64>,
    spread: Vec<f64>,
    weight: Vec<f64>,
}

impl AvoidScratch {
    /// For `count` control configurations of `nq` joint values.
    pub fn new(nq: usize, count: usize) -> Self {
        AvoidScratch {
            hits: Vec::with_capacity(64),
            sample_step: Vec::new(),
            sample: Vec::new(),
            lower: Vec::new(),
            q_ref: Vec::new(),
            known: Vec::new(),
            moved: vec![true; count],
            grad: vec![0.0; nq],
            q: vec![0.0; nq],
            step: vec![0.0; nq],
            corr: vec![0.0; nq * count],
            spread: vec![0.0; nq * count],
            weight: vec![0.0; count],
        }
    }
}

/// The step of curve sample `m` (into `s.step`, after the trust region) and what it adds to the
/// round's figures: every pair below its category's target within the first-order
/// minimum-norm step that lifts it there.
///
/// Each sample keeps a lower bound of every pair's distance from its last check: since then
/// every point of a shape has moved at most the gain-weighted sum of the joint changes
/// ([`super::robot`]), so the old bound less that motion still bounds the distance, and a pair
/// it keeps at or above its target is not queried again. (In a wam_ihy plan's 40 rounds 13,000
/// self-collision queries, three quarters of all, found no pair within the 2 mm self margin;
/// the joints between two fingers' links hardly move from one round to the next.) The pairs
/// found are those the uncached scan finds.
#[allow(clippy::too_many_arguments)]
fn sample_step(
    checker: &CollisionChecker,
    data: &mut CheckData,
    ctrl: &[f64],
    nq: usize,
    m: usize,
    cs: &CurveSample,
    target: &dyn Fn(Category) -> f64,
    opts: &AvoidOptions,
    s: &mut AvoidScratch,
) -> SampleStep {
    point(ctrl, nq, cs, &mut s.q);
    s.hits.clear();
    s.step.fill(0.0);
    let mut out = SampleStep {
        movable: false,
        worst: f64::INFINITY,
        deficit: 0.0,
    };
    let np = checker.pairs().len();
    let lower = &mut s.lower[m * np..(m + 1) * np];
    let q_ref = &mut s.q_ref[m * nq..(m + 1) * nq];
    if s.known[m] {
        checker.carry_bounds(data, q_ref, &s.q, lower);
    } else {
        lower.fill(f64::NEG_INFINITY);
        s.known[m] = true;
    }
    q_ref.copy_from_slice(&s.q);
    // (0.1 mm short of the target counts as kept: a point next to an end in contact is at its
    // target only up to rounding)
    let cutoff = Category::ALL.map(|cat| target(cat) - SLACK);
    let pairs = checker.pairs();
    if (0..np).all(|i| checker.is_allowed(i) || lower[i] >= cutoff[pairs[i].category as usize]) {
        return out;
    }
    // one forward kinematics per point
    checker.update(data, &s.q);
    let hits = &mut s.hits;
    checker.for_each_within_bounded(data, &cutoff, lower, |pair, d| hits.push((pair, *d)));
    // Category by category, as the pairs were once scanned: the step below is a sum, and its
    // order decides its last bits.
    for k in 1..hits.len() {
        let mut j = k;
        while j > 0 && pairs[hits[j - 1].0].category > pairs[hits[j].0].category {
            hits.swap(j - 1, j);
            j -= 1;
        }
    }
    for &(pair, d) in &s.hits {
        let t = target(pairs[pair].category);
        s.grad.fill(0.0);
        checker.add_distance_gradient(data, pair, &d, &mut s.grad);
        let g2: f64 = s.grad.iter().map(|g| g * g).sum();
        // A pair no joint moves apart (the base on the table, a link turning about the normal)
        // is what it is: not a target the path can be held to.
        if g2 < 1e-10 {
            continue;
        }
        out.movable = true;
        out.worst = out.worst.min(d.distance - t);
        out.deficit += (t - d.distance).max(0.0);
        let f = (t - d.distance) / g2;
        for (c, g) in s.step.iter_mut().zip(&s.grad) {
            *c += f * g;
        }
    }
    // A trust region: the first-order step is good for small moves only (a weak gradient asks
    // for a large one), and a large move bends the path.
    let big = s.step.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    if big > opts.max_step {
        let f = opts.max_step / big;
        s.step.iter_mut().for_each(|c| *c *= f);
    }
    out
}

/// What one curve sample contributed to a round (see [`AvoidScratch::sample`]).
#[derive(Debug, Clone, Copy, Default)]
struct SampleStep {
    /// Some pair below target that a joint can move apart.
    movable: bool,
    /// Smallest clearance minus target and the summed deficit of its movable pairs (m).
    worst: f64,
    deficit: f64,
}

fn margin_of(c: Category, o: &AvoidOptions) -> f64 {
    match c {
        Category::SelfCollision => o.self_margin,
        _ => o.margin,
    }
}

fn point(ctrl: &[f64], nq: usize, cs: &CurveSample, out: &mut [f64]) {
    out.fill(0.0);
    for (r, &w) in cs.w.iter().enumerate() {
        if w != 0.0 {
            let row = &ctrl[(cs.first + r) * nq..(cs.first + r + 1) * nq];
            for (o, v) in out.iter_mut().zip(row) {
                *o += w * v;
            }
        }
    }
}

/// Moves the interior control configurations of a path (`ctrl`, `count × nq` row-major) until
/// the path keeps its target clearance at every one of `curve` (see the module docs), inside
/// `[lower, upper]`. The first and last control configurations are the path's ends and stay.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    checker: &CollisionChecker,
    data: &mut CheckData,
    ctrl: &mut [f64],
    curve: &[CurveSample],
    lower: &[f64],
    upper: &[f64],
    opts: &AvoidOptions,
    s: &mut AvoidScratch,
) -> AvoidReport {
    let nq = lower.len();
    let count = ctrl.len() / nq;
    assert_eq!(
        ctrl.len(),
        nq * count,
        "control configurations of nq values"
    );
    assert!(count >= 2 && s.corr.len() == nq * count && s.grad.len() == nq);
    let ends = [0, count - 1].map(|k| {
        let c = checker.clearance(data, &ctrl[k * nq..(k + 1) * nq]);
        Category::ALL.map(|cat| c.category_distance(cat).min(margin_of(cat, opts)))
    });
    let target = |x: f64, cat: Category| {
        let m = margin_of(cat, opts);
        let c = cat as usize;
        // From an end's own clearance (negative when it starts inside something) linearly to
        // the margin over the ramp, and `buffer` above that: the hand keeps off the object
        // until the last moment and meets it from outside. (Points nearest an end cannot keep
        // the buffer, being mostly the fixed end; they use up the round budget, measured as
        // better than a buffer that vanishes at the end: 72 against 64 of 82 plans clear.)
        let ramp = |d: f64, u: f64| d + (m - d) * (u / opts.ramp).min(1.0) + opts.buffer;
        m.min(ramp(ends[0][c], (x - opts.hold_start).max(0.0)))
            .min(ramp(ends[1][c], 1.0 - x))
    };
    let given: Vec<f64> = ctrl.to_vec();
    let mut report = AvoidReport::default();
    let mut progress = Progress::new(opts);
    for round in 0..=opts.rounds {
        s.corr.fill(0.0);
        s.weight.fill(0.0);
        let mut below = 0;
        let mut worst = f64::INFINITY;
        let mut deficit = 0.0;
        let samples = curve.len();
        if s.sample.len() != samples || s.lower.len() != samples * checker.pairs().len() {
            s.sample = vec![SampleStep::default(); samples];
            s.sample_step = vec![0.0; samples * nq];
            s.lower = vec![0.0; samples * checker.pairs().len()];
            s.q_ref = vec![0.0; samples * nq];
        }
        if round == 0 {
            s.known.clear();
            s.known.resize(samples, false);
        }
        for (m, cs) in curve.iter().enumerate() {
            if cs.x <= 0.0 || cs.x >= 1.0 {
                continue;
            }
            let fresh = round > 0
                && !(0..cs.w.len()).any(|r| s.moved.get(cs.first + r).copied().unwrap_or(true));
            if !fresh {
                s.sample[m] = sample_step(
                    checker,
                    data,
                    ctrl,
                    nq,
                    m,
                    cs,
                    &|cat| target(cs.x, cat),
                    opts,
                    s,
                );
                s.sample_step[m * nq..(m + 1) * nq].copy_from_slice(&s.step);
            }
            let done = s.sample[m];
            if !done.movable {
                continue;
            }
            worst = worst.min(done.worst);
            deficit += done.deficit;
            below += 1;
            s.step.copy_from_slice(&s.sample_step[m * nq..(m + 1) * nq]);
            // The minimum-norm change of the control configurations that moves this point by
            // the step.
            // (Over all four, the fixed ends included: near an end a sample is mostly the end,
            // and asking the free ones for all of it would swing them far.)
            let free = |r: usize| {
                let i = cs.first + r;
                i != 0 && i != count - 1
            };
            let w2: f64 = cs.w.iter().map(|w| w * w).sum();
            for (r, &w) in cs.w.iter().enumerate() {
                let i = cs.first + r;
                if w == 0.0 || !free(r) {
                    continue;
                }
                s.weight[i] += w;
                for (c, st) in s.corr[i * nq..(i + 1) * nq].iter_mut().zip(&s.step) {
                    *c += w / w2 * st;
                }
            }
        }
        if round == 0 {
            report.below_target = below;
            report.worst_before = worst.min(0.0);
        }
        report.still_below = below;
        report.worst_after = worst.min(0.0);
        // (points next to an end in contact often cannot reach their target at all: without
        // this the budget is spent on them). Progress is summed over every pair below target,
        // not read off the worst one: a worst pair that hardly moves stopped the rounds while a
        // thumb pad was still being lifted out of the ball (6.8 mm deep at 22 rounds, 3.9 mm at
        // 40). A relative threshold (2 %) stopped sooner and lost more plans than it saved.
        let stalled = progress.stalled(below, deficit);
        if below == 0 || round == opts.rounds || stalled {
            break;
        }
        report.rounds = round + 1;
        // Spread: each control configuration moves by the weighted corrections around it,
        // divided by the weight of the corrections (so overlapping ones are not added up).
        let reach = (3.0 * opts.spread).ceil() as isize;
        let w = |d: isize| (-(d * d) as f64 / (2.0 * opts.spread * opts.spread)).exp();
        s.spread.fill(0.0);
        for k in 1..count - 1 {
            let mut norm = 0.0;
            let row = &mut s.spread[k * nq..(k + 1) * nq];
            for d in -reach..=reach {
                let i = k as isize + d;
                if i <= 0 || i >= count as isize - 1 || s.weight[i as usize] == 0.0 {
                    continue;
                }
                let wi = w(d);
                norm += wi * s.weight[i as usize];
                let i = i as usize;
                for (r, c) in row.iter_mut().zip(&s.corr[i * nq..(i + 1) * nq]) {
                    *r += wi * c;
                }
            }
            if norm > 1.0 {
                row.iter_mut().for_each(|r| *r /= norm);
            }
        }
        s.moved.fill(false);
        for k in 1..count - 1 {
            let row = &mut ctrl[k * nq..(k + 1) * nq];
            for j in 0..nq {
                let moved = (row[j] + s.spread[k * nq + j]).clamp(lower[j], upper[j]);
                s.moved[k] |= moved != row[j];
                row[j] = moved;
            }
        }
    }
    report.max_displacement = ctrl
        .iter()
        .zip(&given)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    report
}

#[cfg(test)]
mod progress_tests {
    use super::*;

    /// Rounds until the stop, for a sequence of (points below target, summed deficit).
    fn stops_after(rounds: &[(usize, f64)]) -> Option<usize> {
        let mut p = Progress::new(&AvoidOptions::default());
        rounds
            .iter()
            .position(|&(below, deficit)| p.stalled(below, deficit))
    }

    #[test]
    fn a_summed_deficit_falling_by_a_millimetre_a_round_keeps_the_rounds_going() {
        // the same points stay below target (their worst pair need not move at all) while the
        // deficit summed over them falls 2 mm a round: 30 rounds, no stop
        let rounds: Vec<(usize, f64)> = (0..30).map(|r| (27, 0.2 - 0.002 * r as f64)).collect();
        assert_eq!(stops_after(&rounds), None);
    }

    #[test]
    fn rounds_that_gain_less_than_a_millimetre_stop_after_the_patience() {
        // a first round sets the best; then 0.1 mm a round: the fifth such round stops
        let rounds: Vec<(usize, f64)> = (0..30).map(|r| (27, 0.2 - 0.0001 * r as f64)).collect();
        assert_eq!(stops_after(&rounds), Some(5));
        // an oscillating deficit is no progress either, however large its swings
        let swings: Vec<(usize, f64)> = (0..30)
            .map(|r| (27, if r % 2 == 0 { 0.2 } else { 0.25 }))
            .collect();
        assert_eq!(stops_after(&swings), Some(5));
        // fewer points below target is progress even with a larger deficit
        let fewer: Vec<(usize, f64)> = (0..30).map(|r| (30 - r.min(29), 0.3)).collect();
        assert_eq!(stops_after(&fewer), None);
    }
}
