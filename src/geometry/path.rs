//! Continuous collision checking along a joint-space path by conservative advancement.
//!
//! The path is `q(s)`, `s ∈ [0, end]` (a polyline through configurations, or any path that can
//! bound its joint rates `|dq_k/ds|` over an interval). Over `[s, s + Δ]` every point of a robot
//! shape moves at most `L·Δ` relative to the other member of a pair, with `L` from the shape's
//! joint-speed gains ([`super::robot`]) and the rate bounds (for two robot shapes only the joints
//! below their common ancestor count), so the pair's signed distance falls by at most `L·Δ`.
//! Each step is the largest `Δ` with `L_p·Δ ≤ d_p − m_c + tol` for every pair `p`, where `d_p`
//! is a lower bound of the pair's distance at `s` (exact, or an earlier exact value minus the
//! motion since, or the bounding spheres' or capsules' gap), `m_c` the smallest exact distance found so far in
//! the pair's category, or its exact minimum at the end of the path when that is lower and not
//! negative (the end is evaluated first), and `tol` the tolerance. Pairs whose bound limits the step are evaluated
//! exactly until the limiting pair is exact, so steps are at least `tol / L`.
//!
//! Guarantee (when the report is `complete`): for every non-allowed pair and every `s`, the
//! signed distance is at least the reported category minimum minus `tol`; the reported minimum
//! is an exact distance at a sampled `s`, so the true minimum lies within `tol` below it. A
//! collision deeper than `tol` cannot be missed, and before the reported first collision no pair
//! is more than `tol` inside.

use super::checker::{Category, CheckData, CollisionChecker};
use super::solid::SignedDistance;

/// A joint-space path `q(s)`, `s ∈ [0, end]`.
pub trait JointPath {
    /// Number of coordinates of `q`.
    fn nq(&self) -> usize;
    /// The parameter runs over `[0, end]`.
    fn end(&self) -> f64;
    /// `q(s)`.
    fn eval(&self, s: f64, q: &mut [f64]);
    /// `out[k] ≥ sup |dq_k/ds|` over `[s0, s1]`.
    fn rate_bound(&self, s0: f64, s1: f64, out: &mut [f64]);
}

/// The piecewise-linear path through configurations `points` (`n × nq`, row-major); `s` counts
/// segments (`q(k) = points[k]`).
#[derive(Clone, Copy, Debug)]
pub struct Polyline<'a> {
    points: &'a [f64],
    nq: usize,
}

impl<'a> Polyline<'a> {
    /// Panics unless `points` holds at least one configuration of `nq` values.
    pub fn new(points: &'a [f64], nq: usize) -> Self {
        assert!(nq > 0 && points.len() >= nq && points.len().is_multiple_of(nq));
        Polyline { points, nq }
    }
    fn count(&self) -> usize {
        self.points.len() / self.nq
    }
}

impl JointPath for Polyline<'_> {
    fn nq(&self) -> usize {
        self.nq
    }
    fn end(&self) -> f64 {
        (self.count() - 1) as f64
    }
    fn eval(&self, s: f64, q: &mut [f64]) {
        let n = self.nq;
        let last = self.count() - 1;
        if last == 0 {
            q.copy_from_slice(&self.points[..n]);
            return;
        }
        let s = s.clamp(0.0, last as f64);
        let k = (s.floor() as usize).min(last - 1);
        let t = s - k as f64;
        let (a, b) = (
            &self.points[k * n..(k + 1) * n],
            &self.points[(k + 1) * n..(k + 2) * n],
        );
        for i in 0..n {
            q[i] = a[i] + t * (b[i] - a[i]);
        }
    }
    fn rate_bound(&self, s0: f64, s1: f64, out: &mut [f64]) {
        let n = self.nq;
        out.fill(0.0);
        let last = self.count() - 1;
        if last == 0 {
            return;
        }
        let k0 = (s0.max(0.0).floor() as usize).min(last - 1);
        let k1 = ((s1.ceil() as usize).saturating_sub(1)).clamp(k0, last - 1);
        for k in k0..=k1 {
            let (a, b) = (
                &self.points[k * n..(k + 1) * n],
                &self.points[(k + 1) * n..(k + 2) * n],
            );
            for i in 0..n {
                out[i] = out[i].max((b[i] - a[i]).abs());
            }
        }
    }
}

/// Options of [`CollisionChecker::check_path`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathOptions {
    /// Metres: the true minimum lies at most this far below the reported one.
    pub tolerance: f64,
    /// Step budget (deterministic); the report says `complete: false` when it runs out.
    pub max_steps: usize,
}

impl Default for PathOptions {
    fn default() -> Self {
        PathOptions {
            tolerance: 5e-4,
            max_steps: 100_000,
        }
    }
}

/// An exact distance found along a path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathHit {
    /// Path parameter.
    pub s: f64,
    /// Index into [`CollisionChecker::pairs`].
    pub pair: usize,
    pub distance: SignedDistance,
}

/// Result of a continuous check (see the module docs for what it guarantees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathReport {
    /// Smallest exact distance over all non-allowed pairs.
    pub min: Option<PathHit>,
    /// Per category, indexed by `Category as usize`.
    pub by_category: [Option<PathHit>; 4],
    /// First sampled penetration (distance < 0).
    pub first_collision: Option<PathHit>,
    pub tolerance: f64,
    /// False when the step budget ran out before the end (then only `[0, reached]` is covered).
    pub complete: bool,
    pub reached: f64,
    pub steps: usize,
    pub exact_queries: usize,
}

impl PathReport {
    /// Smallest exact distance (`+∞` without pairs).
    pub fn distance(&self) -> f64 {
        self.min.map_or(f64::INFINITY, |h| h.distance.distance)
    }
    /// Certified lower bound on every non-allowed pair's distance along the covered path.
    pub fn lower_bound(&self) -> f64 {
        self.distance() - self.tolerance
    }
    pub fn category(&self, c: Category) -> Option<&PathHit> {
        self.by_category[c as usize].as_ref()
    }
    pub fn category_distance(&self, c: Category) -> f64 {
        self.category(c)
            .map_or(f64::INFINITY, |h| h.distance.distance)
    }
}

struct Tracker {
    m: [f64; 4],
    report: PathReport,
}

impl Tracker {
    fn record(&mut self, cat: Category, s: f64, pair: usize, d: SignedDistance) {
        let c = cat as usize;
        let hit = PathHit {
            s,
            pair,
            distance: d,
        };
        if d.distance < self.m[c] {
            self.m[c] = d.distance;
            self.report.by_category[c] = Some(hit);
            if self
                .report
                .min
                .is_none_or(|h| d.distance < h.distance.distance)
            {
                self.report.min = Some(hit);
            }
        }
        if d.distance < 0.0 && self.report.first_collision.is_none() {
            self.report.first_collision = Some(hit);
        }
    }
}

impl CollisionChecker {
    /// The suffix sums for the rates in `data.rates` (made non-negative), then every pair's
    /// motion bound (`data.pair_rates`, 0 for an allowed pair). Runs once or twice per step of
    /// a path check and once per point check of the avoidance, so it reads flat copies of the
    /// chains and the pairs' suffix indices rather than the shapes and pairs themselves.
    pub(crate) fn fill_suffix(&self, data: &mut CheckData) {
        data.rates.iter_mut().for_each(|r| *r = r.abs());
        let (q, gain) = (&self.chain_q, &self.chain_gain);
        for w in self.suffix_offset.windows(2) {
            // a shape's chain at [w[0], w[1] - 1), its empty suffix at w[1] - 1
            let last = w[1] - 1;
            data.suffix[last] = 0.0;
            for k in (w[0]..last).rev() {
                data.suffix[k] = data.suffix[k + 1] + gain[k] * data.rates[q[k] as usize];
            }
        }
        for (i, &[a, b]) in self.pair_suffix.iter().enumerate() {
            data.pair_rates[i] = if self.is_allowed(i) {
                0.0
            } else if b == u32::MAX {
                data.suffix[a as usize]
            } else {
                data.suffix[a as usize] + data.suffix[b as usize]
            };
        }
    }

    /// Exact minimum per category at the current sample (branch and bound on sphere gaps),
    /// recorded; the pairs evaluated become exact.
    fn resolve_sample(&self, data: &mut CheckData, s: f64, t: &mut Tracker) {
        let cl = self.clearance_at_update(data);
        for c in Category::ALL {
            if let Some(h) = cl.by_category[c as usize] {
                data.bound[h.pair] = h.distance.distance;
                data.exact[h.pair] = true;
                t.record(c, s, h.pair, h.distance);
            }
        }
    }

    /// Continuous check of `path` against every non-allowed pair (see the module docs).
    pub fn check_path(
        &self,
        data: &mut CheckData,
        path: &dyn JointPath,
        opts: &PathOptions,
    ) -> PathReport {
        assert_eq!(
            path.nq(),
            self.robot().model().nq(),
            "path has the wrong nq"
        );
        let tol = opts.tolerance.max(1e-9);
        let n_pairs = self.pairs().len();
        let queries0 = data.exact_queries;
        let mut t = Tracker {
            m: [f64::INFINITY; 4],
            report: PathReport {
                min: None,
                by_category: [None; 4],
                first_collision: None,
                tolerance: tol,
                complete: false,
                reached: 0.0,
                steps: 0,
                exact_queries: 0,
            },
        };
        let end = path.end();
        let mut q = std::mem::take(&mut data.q);
        // The exact category minima at the end, not below 0, as a floor for the steps: a
        // distance that falls towards the end (a hand approaching what it grasps) then no longer
        // limits every step to the tolerance over the running minimum (16 steps a segment on a
        // plan's approach). Steps still keep every pair above the minimum the report ends with
        // (the end is sampled too), less the tolerance; never below 0, so a collision deeper
        // than the tolerance is still found first where it begins.
        let mut floor = [f64::INFINITY; 4];
        if end > 0.0 {
            path.eval(end, &mut q);
            self.update(data, &q);
            let cl = self.clearance_at_update(data);
            for c in Category::ALL {
                if let Some(h) = cl.by_category[c as usize] {
                    floor[c as usize] = h.distance.distance.max(0.0);
                }
            }
        }
        let mut s = 0.0;
        path.eval(s, &mut q);
        self.update(data, &q);
        data.exact.fill(false);
        data.capsuled.fill(false);
        self.resolve_sample(data, s, &mut t);
        let mut step = end;
        let mut complete = end <= 0.0;
        while !complete && t.report.steps < opts.max_steps {
            t.report.steps += 1;
            let mut try_end = (s + step).min(end);
            let mut rates = std::mem::take(&mut data.rates);
            path.rate_bound(s, try_end, &mut rates);
            data.rates = rates;
            self.fill_suffix(data);
            // Evaluate limiting pairs until the limiting pair is exact. Each pair's step limit is
            // computed once per step and again only when its inputs change: its own bound, or
            // its category's running minimum (the scans for the limiting pair were most of this
            // loop's time, a division per pair per scan).
            let level = |t: &Tracker, c: usize| t.m[c].min(floor[c]);
            let limit_of = |data: &CheckData, t: &Tracker, i: usize| {
                let c = self.pairs()[i].category as usize;
                (data.bound[i] - level(t, c) + tol) / data.pair_rates[i]
            };
            for i in 0..n_pairs {
                // (0 for an allowed pair)
                data.keys[i] = if data.pair_rates[i] <= 0.0 {
                    f64::INFINITY
                } else {
                    limit_of(data, &t, i)
                };
            }
            let mut limit;
            loop {
                limit = f64::INFINITY;
                let mut arg = usize::MAX;
                for (i, &key) in data.keys.iter().enumerate() {
                    if key < limit {
                        limit = key;
                        arg = i;
                    }
                }
                if arg == usize::MAX || data.exact[arg] {
                    break;
                }
                // The bounding capsules first: for a long link they often lift the bound above
                // the step's need, and cost a segment distance instead of a GJK run.
                if !data.capsuled[arg] {
                    data.capsuled[arg] = true;
                    let b = self.capsule_bound(data, arg);
                    if b > data.bound[arg] {
                        data.bound[arg] = b;
                        data.keys[arg] = limit_of(data, &t, arg);
                        continue;
                    }
                }
                let d = self.pair_distance(data, arg);
                data.bound[arg] = d.distance;
                data.exact[arg] = true;
                let c = self.pairs()[arg].category;
                let was = level(&t, c as usize);
                t.record(c, s, arg, d);
                data.keys[arg] = limit_of(data, &t, arg);
                if level(&t, c as usize) != was {
                    for i in 0..n_pairs {
                        if data.pair_rates[i] > 0.0 && self.pairs()[i].category == c {
                            data.keys[i] = limit_of(data, &t, i);
                        }
                    }
                }
            }
            let delta = if limit < try_end - s {
                // Shorter than tried: rates over the shorter interval are no larger, so the
                // bound still holds; carry the motion with those rates.
                try_end = s + limit;
                let mut rates = std::mem::take(&mut data.rates);
                path.rate_bound(s, try_end, &mut rates);
                data.rates = rates;
                self.fill_suffix(data);
                limit
            } else {
                try_end - s
            };
            for i in 0..n_pairs {
                if !self.is_allowed(i) {
                    data.bound[i] -= data.pair_rates[i] * delta;
                }
            }
            s = try_end;
            step = 2.0 * delta.max(1e-12);
            path.eval(s, &mut q);
            self.update(data, &q);
            data.exact.fill(false);
            data.capsuled.fill(false);
            if s >= end {
                self.resolve_sample(data, s, &mut t);
                complete = true;
            } else {
                for i in 0..n_pairs {
                    if !self.is_allowed(i) {
                        let b = self.sphere_bound(data, i);
                        if b > data.bound[i] {
                            data.bound[i] = b;
                        }
                    }
                }
            }
        }
        data.q = q;
        t.report.complete = complete;
        t.report.reached = s;
        t.report.exact_queries = data.exact_queries - queries0;
        t.report
    }
}
