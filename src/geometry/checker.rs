//! Posture queries: every pair of a robot shape with the scene (object, support, obstacles) and
//! with every non-adjacent robot shape, an allowed-contact list (MoveIt ACM style), and the
//! smallest signed distance overall and per category with the pair and its witness points.
//!
//! Broad phase: every shape carries a bounding sphere; the sphere gap is a lower bound on the
//! signed distance on both sides of zero (a translation separating the spheres separates the
//! shapes), so the exact minimum needs exact queries only for pairs whose sphere gap is below
//! the best exact distance found so far.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};

use crate::kinematics::{Data, FrameId, add_point_jacobian_transpose, forward_kinematics};

use super::robot::RobotGeometry;
use super::scene::{Scene, SceneShape};
use super::solid::{QueryScratch, SignedDistance, half_space_distance, signed_distance};

/// Added to a carried pair bound's motion allowance (m): the bound and the exact distance it
/// stands for come from GJK, which is exact only to rounding.
const CARRY_SLACK: f64 = 1e-9;

/// The second member of a pair (the first is always a robot shape).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    Object,
    Support,
    /// Index into `Scene::obstacles`.
    Obstacle(usize),
    /// Another robot shape (index into `RobotGeometry::shapes`).
    Shape(usize),
}

/// What a pair is about; minima are reported per category.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Category {
    Object = 0,
    Support = 1,
    Obstacle = 2,
    /// Two non-adjacent links of the robot.
    SelfCollision = 3,
}

impl Category {
    pub const ALL: [Category; 4] = [
        Category::Object,
        Category::Support,
        Category::Obstacle,
        Category::SelfCollision,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Category::Object => "object",
            Category::Support => "support",
            Category::Obstacle => "obstacle",
            Category::SelfCollision => "self",
        }
    }
}

/// A checked pair: robot shape `shape` against `other`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pair {
    pub shape: usize,
    pub other: Target,
    pub category: Category,
    /// Where the relative motion starts in each member's chain: joints before these indices are
    /// shared by both shapes and move them rigidly together (self pairs only).
    pub(crate) a_from: usize,
    pub(crate) b_from: usize,
}

/// One side of an allowed contact.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Member {
    /// Every shape of a link.
    Link(FrameId),
    /// One robot shape (index into `RobotGeometry::shapes`).
    Shape(usize),
    Object,
    Support,
    /// One obstacle (index into `Scene::obstacles`).
    Obstacle(usize),
    /// Every obstacle.
    AnyObstacle,
}

/// Pairs that may touch or overlap (besides adjacent links, which always may, and the robot's
/// fixed base against the support it stands on). Set by the caller per phase: e.g. the
/// fingertip links against the object in the final closing phase.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AllowedContacts {
    entries: Vec<(Member, Member)>,
}

impl AllowedContacts {
    /// Nothing but the always-allowed pairs.
    pub fn none() -> Self {
        Self::default()
    }

    /// Allow `a` and `b` to touch (order does not matter).
    pub fn allow(&mut self, a: Member, b: Member) -> &mut Self {
        self.entries.push((a, b));
        self
    }

    pub fn entries(&self) -> &[(Member, Member)] {
        &self.entries
    }

    fn matches_shape(m: Member, robot: &RobotGeometry, shape: usize) -> bool {
        match m {
            Member::Link(f) => robot.shapes()[shape].frame == f,
            Member::Shape(s) => s == shape,
            _ => false,
        }
    }

    fn matches_target(m: Member, robot: &RobotGeometry, t: Target) -> bool {
        match (m, t) {
            (Member::Object, Target::Object) | (Member::Support, Target::Support) => true,
            (Member::Obstacle(i), Target::Obstacle(j)) => i == j,
            (Member::AnyObstacle, Target::Obstacle(_)) => true,
            (m, Target::Shape(s)) => Self::matches_shape(m, robot, s),
            _ => false,
        }
    }

    /// Whether this list allows `pair`.
    pub fn allows(&self, robot: &RobotGeometry, pair: &Pair) -> bool {
        self.entries.iter().any(|&(a, b)| {
            (Self::matches_shape(a, robot, pair.shape)
                && Self::matches_target(b, robot, pair.other))
                || (Self::matches_shape(b, robot, pair.shape)
                    && Self::matches_target(a, robot, pair.other))
        })
    }
}

/// The closest non-allowed pair of a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Closest {
    /// Index into [`CollisionChecker::pairs`].
    pub pair: usize,
    pub distance: SignedDistance,
}

/// Smallest signed distances of a posture: overall and per [`Category`] (`None`: no pair).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Clearance {
    pub min: Option<Closest>,
    /// Indexed by `Category as usize`.
    pub by_category: [Option<Closest>; 4],
}

impl Clearance {
    /// Smallest distance (metres; `+∞` without pairs).
    pub fn distance(&self) -> f64 {
        self.min.map_or(f64::INFINITY, |c| c.distance.distance)
    }
    pub fn category(&self, c: Category) -> Option<&Closest> {
        self.by_category[c as usize].as_ref()
    }
    /// Smallest distance in a category (`+∞` without pairs).
    pub fn category_distance(&self, c: Category) -> f64 {
        self.category(c)
            .map_or(f64::INFINITY, |c| c.distance.distance)
    }
}

/// Names of a pair's members, for reports.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PairLabel {
    pub link: String,
    pub finger: Option<String>,
    pub category: Category,
    /// "object", "support", the obstacle's name or the other link's name.
    pub other: String,
}

/// Per-worker scratch of a [`CollisionChecker`] (FK placements, shape poses, broad-phase and
/// GJK/EPA buffers). Build one with [`CollisionChecker::data`]; queries then allocate nothing
/// (meshes aside, see `solid`).
#[derive(Debug)]
pub struct CheckData {
    pub(crate) kin: Data,
    pub(crate) poses: Vec<Isometry3<f64>>,
    pub(crate) centers: Vec<Point3<f64>>,
    pub(crate) scratch: QueryScratch,
    /// Per pair: broad-phase lower bound (posture queries) or carried lower bound (paths).
    pub(crate) bound: Vec<f64>,
    pub(crate) exact: Vec<bool>,
    /// Path checks: per pair, its bounding capsules were measured at the current sample.
    pub(crate) capsuled: Vec<bool>,
    /// Path checks: per shape the suffix sums of chain gains times joint rates.
    pub(crate) suffix: Vec<f64>,
    pub(crate) rates: Vec<f64>,
    /// Path checks: per pair its relative motion bound over the current step (0 where
    /// allowed), computed once per step rather than at every scan for the limiting pair.
    pub(crate) pair_rates: Vec<f64>,
    /// Path checks: per pair the step it allows (see `check_path`).
    pub(crate) keys: Vec<f64>,
    pub(crate) q: Vec<f64>,
    pub(crate) exact_queries: usize,
}

impl CheckData {
    /// Exact pair queries run since this scratch was built.
    pub fn exact_queries(&self) -> usize {
        self.exact_queries
    }
    /// World poses of the robot shapes as of the last update.
    pub fn shape_poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }
    /// The FK placements as of the last update.
    pub fn kinematics(&self) -> &Data {
        &self.kin
    }
    /// Exchanges the FK placements with `kin` (built for the same model): lend placements
    /// computed elsewhere to [`CollisionChecker::for_each_within_posed`] and take them back
    /// after, without copying or recomputing them.
    pub fn swap_kinematics(&mut self, kin: &mut Data) {
        std::mem::swap(&mut self.kin, kin);
    }
}

/// Robot geometry + scene + allowed contacts: every pair to check, resolved once.
#[derive(Clone, Debug)]
pub struct CollisionChecker {
    robot: Arc<RobotGeometry>,
    scene: Scene,
    pairs: Vec<Pair>,
    allowed: Vec<bool>,
    acm: AllowedContacts,
    /// Per shape: offset of its chain in `CheckData::suffix` (chain length + 1 entries).
    pub(crate) suffix_offset: Vec<usize>,
    /// The chains' joints (`q` index) and gains in the layout of `CheckData::suffix`, and per
    /// pair the suffix entries whose sum is its motion bound (`u32::MAX`: no second shape).
    pub(crate) chain_q: Vec<u32>,
    pub(crate) chain_gain: Vec<f64>,
    pub(crate) pair_suffix: Vec<[u32; 2]>,
    /// Per shape: its bounding sphere's centre in its link frame, so the broad phase of
    /// [`Self::for_each_within_posed`] places one point per shape instead of a whole pose.
    local_centers: Vec<Point3<f64>>,
}

impl CollisionChecker {
    /// Every robot shape against the object, the support (shapes no joint moves excepted: the
    /// base stands on it) and every obstacle, and every two shapes on non-adjacent links.
    pub fn new(robot: Arc<RobotGeometry>, scene: Scene) -> CollisionChecker {
        let shapes = robot.shapes();
        let mut pairs = Vec::new();
        for (i, s) in shapes.iter().enumerate() {
            let scene_pair = |other, category| Pair {
                shape: i,
                other,
                category,
                a_from: 0,
                b_from: 0,
            };
            if scene.object.is_some() {
                pairs.push(scene_pair(Target::Object, Category::Object));
            }
            if scene.support.is_some() && !s.is_static() {
                pairs.push(scene_pair(Target::Support, Category::Support));
            }
            for k in 0..scene.obstacles.len() {
                pairs.push(scene_pair(Target::Obstacle(k), Category::Obstacle));
            }
        }
        for i in 0..shapes.len() {
            for j in i + 1..shapes.len() {
                let (a, b) = (&shapes[i], &shapes[j]);
                if robot.adjacent(a.frame, b.frame) || (a.is_static() && b.is_static()) {
                    continue;
                }
                let shared = a
                    .chain
                    .iter()
                    .zip(&b.chain)
                    .take_while(|(x, y)| x.frame == y.frame)
                    .count();
                pairs.push(Pair {
                    shape: i,
                    other: Target::Shape(j),
                    category: Category::SelfCollision,
                    a_from: shared,
                    b_from: shared,
                });
            }
        }
        let mut suffix_offset = Vec::with_capacity(shapes.len() + 1);
        let mut off = 0;
        for s in shapes {
            suffix_offset.push(off);
            off += s.chain.len() + 1;
        }
        suffix_offset.push(off);
        let (mut chain_q, mut chain_gain) = (Vec::with_capacity(off), Vec::with_capacity(off));
        for s in shapes {
            chain_q.extend(s.chain.iter().map(|c| c.q as u32).chain([u32::MAX]));
            chain_gain.extend(s.chain.iter().map(|c| c.gain).chain([0.0]));
        }
        let pair_suffix = pairs
            .iter()
            .map(|p| {
                let a = (suffix_offset[p.shape] + p.a_from) as u32;
                match p.other {
                    Target::Shape(j) => [a, (suffix_offset[j] + p.b_from) as u32],
                    _ => [a, u32::MAX],
                }
            })
            .collect();
        let allowed = vec![false; pairs.len()];
        let local_centers = shapes.iter().map(|s| s.origin * s.solid.center).collect();
        CollisionChecker {
            robot,
            scene,
            pairs,
            allowed,
            acm: AllowedContacts::none(),
            suffix_offset,
            chain_q,
            chain_gain,
            pair_suffix,
            local_centers,
        }
    }

    /// Replace the allowed-contact list (no allocation beyond the list itself).
    pub fn set_allowed(&mut self, acm: &AllowedContacts) {
        for (flag, p) in self.allowed.iter_mut().zip(&self.pairs) {
            *flag = acm.allows(&self.robot, p);
        }
        self.acm = acm.clone();
    }

    pub fn with_allowed(mut self, acm: &AllowedContacts) -> Self {
        self.set_allowed(acm);
        self
    }

    pub fn allowed_contacts(&self) -> &AllowedContacts {
        &self.acm
    }

    pub fn robot(&self) -> &Arc<RobotGeometry> {
        &self.robot
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Every candidate pair (allowed ones included; see [`Self::is_allowed`]).
    pub fn pairs(&self) -> &[Pair] {
        &self.pairs
    }

    pub fn is_allowed(&self, pair: usize) -> bool {
        self.allowed[pair]
    }

    /// Indices of the non-allowed pairs of the given categories: resolved once, so a hot loop
    /// ([`Self::for_each_within_posed`]) visits only the pairs it asks about.
    pub fn pairs_in(&self, categories: &[Category]) -> Vec<usize> {
        (0..self.pairs.len())
            .filter(|&i| !self.allowed[i] && categories.contains(&self.pairs[i].category))
            .collect()
    }

    /// Scratch for this checker (one per worker thread).
    pub fn data(&self) -> CheckData {
        let model = self.robot.model();
        let n = self.robot.shapes().len();
        CheckData {
            kin: Data::new(model),
            poses: vec![Isometry3::identity(); n],
            centers: vec![Point3::origin(); n],
            scratch: QueryScratch::default(),
            bound: vec![0.0; self.pairs.len()],
            exact: vec![false; self.pairs.len()],
            capsuled: vec![false; self.pairs.len()],
            suffix: vec![0.0; *self.suffix_offset.last().unwrap_or(&0)],
            rates: vec![0.0; model.nq()],
            pair_rates: vec![0.0; self.pairs.len()],
            keys: vec![0.0; self.pairs.len()],
            q: vec![0.0; model.nq()],
            exact_queries: 0,
        }
    }

    /// Names of a pair's members.
    pub fn label(&self, pair: usize) -> PairLabel {
        let p = &self.pairs[pair];
        let s = &self.robot.shapes()[p.shape];
        let other = match p.other {
            Target::Object => self
                .scene
                .object
                .as_ref()
                .map_or("object".to_owned(), |o| o.name.clone()),
            Target::Support => "support".to_owned(),
            Target::Obstacle(k) => self.scene.obstacles[k].name.clone(),
            Target::Shape(j) => self.robot.shapes()[j].link.clone(),
        };
        PairLabel {
            link: s.link.clone(),
            finger: s.finger.map(|f| self.robot.finger_names()[f].clone()),
            category: p.category,
            other,
        }
    }

    /// Forward kinematics at `q` and the world pose of every shape.
    pub fn update(&self, data: &mut CheckData, q: &[f64]) {
        forward_kinematics(self.robot.model(), &mut data.kin, q);
        self.pose(data);
    }

    /// [`Self::update`] from FK placements `kin` computed elsewhere (for this checker's model):
    /// a caller that has just run forward kinematics does not run it twice.
    pub fn update_from(&self, data: &mut CheckData, kin: &Data) {
        data.kin.copy_from(kin);
        self.pose(data);
    }

    /// The world pose of every shape from the placements in `data`.
    fn pose(&self, data: &mut CheckData) {
        self.robot.pose_shapes(&data.kin, &mut data.poses);
        for ((c, p), s) in data
            .centers
            .iter_mut()
            .zip(&data.poses)
            .zip(self.robot.shapes())
        {
            *c = p * s.solid.center;
        }
    }

    /// Broad-phase lower bound of a pair's signed distance at the last update.
    pub(crate) fn sphere_bound(&self, data: &CheckData, pair: usize) -> f64 {
        self.bound_at(pair, |i| data.centers[i])
    }

    /// A pair's bounding spheres' gap, each robot shape's sphere centred at `center(shape)`: a
    /// lower bound on its signed distance.
    fn bound_at(&self, pair: usize, center: impl Fn(usize) -> Point3<f64>) -> f64 {
        let p = &self.pairs[pair];
        let shapes = self.robot.shapes();
        let (c, r) = (center(p.shape), shapes[p.shape].solid.bound);
        match p.other {
            Target::Support => self.scene.support.expect("support pair").height(&c) - r,
            Target::Shape(j) => (c - center(j)).norm() - r - shapes[j].solid.bound,
            t => {
                let o = self.scene_shape(t);
                (c - o.center).norm() - r - o.solid.bound
            }
        }
    }

    /// The object or obstacle a pair's robot shape is paired with.
    fn scene_shape(&self, t: Target) -> &SceneShape {
        match t {
            Target::Object => self
                .scene
                .object
                .as_ref()
                .expect("object pair without object"),
            Target::Obstacle(k) => &self.scene.obstacles[k],
            _ => unreachable!("not a scene shape: {t:?}"),
        }
    }

    /// The gap of a pair's bounding capsules at the shape poses in `data` (the pair's must be
    /// current): a second lower bound on its signed distance, tighter than the spheres' for
    /// long links. (In the avoidance rounds of a wam_ihy bottle plan 10,000 object pairs passed
    /// the sphere test, 3,900 were within the cutoff; the capsules let 4,600 through.)
    pub(crate) fn capsule_bound(&self, data: &CheckData, pair: usize) -> f64 {
        let p = &self.pairs[pair];
        let shapes = self.robot.shapes();
        let (cap, pose) = (&shapes[p.shape].solid.capsule, &data.poses[p.shape]);
        match p.other {
            Target::Support => cap.height(pose, &self.scene.support.expect("support pair").0),
            Target::Shape(j) => cap.gap(pose, &shapes[j].solid.capsule, &data.poses[j]),
            t => {
                let o = self.scene_shape(t);
                cap.gap(pose, &o.solid.capsule, &o.pose)
            }
        }
    }

    /// Exact signed distance of a pair at the last [`Self::update`] (the robot shape first).
    pub fn pair_distance(&self, data: &mut CheckData, pair: usize) -> SignedDistance {
        data.exact_queries += 1;
        let p = &self.pairs[pair];
        let s = &self.robot.shapes()[p.shape];
        let pose = &data.poses[p.shape];
        match p.other {
            Target::Support => {
                half_space_distance(&s.solid, pose, &self.scene.support.expect("support").0)
            }
            Target::Shape(j) => {
                let b = &self.robot.shapes()[j];
                let pb = data.poses[j];
                signed_distance(&s.solid, pose, &b.solid, &pb, &mut data.scratch)
            }
            t => {
                let o = self.scene_shape(t);
                signed_distance(&s.solid, pose, &o.solid, &o.pose, &mut data.scratch)
            }
        }
    }

    /// Smallest signed distance over all non-allowed pairs at `q`, overall and per category,
    /// with the pair and witness points.
    pub fn clearance(&self, data: &mut CheckData, q: &[f64]) -> Clearance {
        self.update(data, q);
        self.clearance_at_update(data)
    }

    /// [`Self::clearance`] at the posture of the last [`Self::update`].
    pub fn clearance_at_update(&self, data: &mut CheckData) -> Clearance {
        self.clearance_in(data, &Category::ALL)
    }

    /// [`Self::clearance`] over the pairs of the given categories only (e.g. support and object
    /// without the self-collision pairs), at `q`.
    pub fn category_clearance(
        &self,
        data: &mut CheckData,
        q: &[f64],
        categories: &[Category],
    ) -> Clearance {
        self.update(data, q);
        self.clearance_in(data, categories)
    }

    fn clearance_in(&self, data: &mut CheckData, categories: &[Category]) -> Clearance {
        let mut out = Clearance::default();
        let mut first: [Option<(usize, f64)>; 4] = [None; 4];
        for i in 0..self.pairs.len() {
            if self.allowed[i] || !categories.contains(&self.pairs[i].category) {
                continue;
            }
            let b = self.sphere_bound(data, i);
            data.bound[i] = b;
            let c = self.pairs[i].category as usize;
            if first[c].is_none_or(|(_, v)| b < v) {
                first[c] = Some((i, b));
            }
        }
        for (c, f) in first.iter().enumerate() {
            let Some((i0, _)) = *f else { continue };
            let d0 = self.pair_distance(data, i0);
            let mut best = Closest {
                pair: i0,
                distance: d0,
            };
            for i in 0..self.pairs.len() {
                if i == i0
                    || self.allowed[i]
                    || self.pairs[i].category as usize != c
                    || data.bound[i] >= best.distance.distance
                {
                    continue;
                }
                let d = self.pair_distance(data, i);
                if d.distance < best.distance.distance {
                    best = Closest {
                        pair: i,
                        distance: d,
                    };
                }
            }
            out.by_category[c] = Some(best);
            if out
                .min
                .is_none_or(|m| best.distance.distance < m.distance.distance)
            {
                out.min = Some(best);
            }
        }
        out
    }

    /// Calls `f(pair, distance)` for every non-allowed pair closer than `cutoff` at `q` (exact
    /// distances; pairs whose bounding spheres or capsules are `cutoff` or more apart are skipped).
    pub fn for_each_within(
        &self,
        data: &mut CheckData,
        q: &[f64],
        cutoff: f64,
        f: impl FnMut(usize, &SignedDistance),
    ) {
        self.for_each_within_in(data, q, cutoff, &Category::ALL, f);
    }

    /// [`Self::for_each_within`] over the pairs of the given categories only.
    pub fn for_each_within_in(
        &self,
        data: &mut CheckData,
        q: &[f64],
        cutoff: f64,
        categories: &[Category],
        f: impl FnMut(usize, &SignedDistance),
    ) {
        self.update(data, q);
        self.for_each_within_current(data, cutoff, categories, f);
    }

    /// [`Self::for_each_within_in`] at the configuration of the last [`Self::update`] of
    /// `data`: a caller that asks several questions of one configuration (a cutoff per
    /// category) runs the forward kinematics and poses the shapes once.
    pub fn for_each_within_current(
        &self,
        data: &mut CheckData,
        cutoff: f64,
        categories: &[Category],
        mut f: impl FnMut(usize, &SignedDistance),
    ) {
        for i in 0..self.pairs.len() {
            if self.allowed[i]
                || !categories.contains(&self.pairs[i].category)
                || self.sphere_bound(data, i) >= cutoff
                || self.capsule_bound(data, i) >= cutoff
            {
                continue;
            }
            let d = self.pair_distance(data, i);
            if d.distance < cutoff {
                f(i, &d);
            }
        }
    }

    /// Carries per-pair lower bounds (`lower`, see [`Self::for_each_within_bounded`]) from
    /// configuration `from` to `to`: every point of a shape moves at most the gain-weighted sum
    /// of the joint changes ([`super::robot`]), so each bound falls by its pair's relative
    /// motion bound, and by [`CARRY_SLACK`].
    pub(crate) fn carry_bounds(
        &self,
        data: &mut CheckData,
        from: &[f64],
        to: &[f64],
        lower: &mut [f64],
    ) {
        for ((r, a), b) in data.rates.iter_mut().zip(from).zip(to) {
            *r = b - a;
        }
        self.fill_suffix(data);
        for (l, moved) in lower.iter_mut().zip(&data.pair_rates) {
            *l -= moved + CARRY_SLACK;
        }
    }

    /// [`Self::for_each_within_current`] with a cutoff per category (indexed by `Category as
    /// usize`) and a lower bound per pair that the caller carries from one call to the next:
    /// on entry `lower[i]` is a lower bound of pair `i`'s signed distance at the configuration
    /// of the last update (`f64::NEG_INFINITY` where none is known), on return the best one
    /// this call found (the exact distance where it ran the exact query). A pair whose bound
    /// already reaches its cutoff is skipped before the broad phase, so the pairs passed to `f`
    /// (in pair order) are those the uncached scan finds.
    pub fn for_each_within_bounded(
        &self,
        data: &mut CheckData,
        cutoff: &[f64; 4],
        lower: &mut [f64],
        mut f: impl FnMut(usize, &SignedDistance),
    ) {
        assert_eq!(lower.len(), self.pairs.len(), "a bound per pair");
        for i in 0..self.pairs.len() {
            let c = cutoff[self.pairs[i].category as usize];
            if self.allowed[i] || lower[i] >= c {
                continue;
            }
            let b = self.sphere_bound(data, i);
            if b >= c {
                lower[i] = lower[i].max(b);
                continue;
            }
            let b = self.capsule_bound(data, i);
            if b >= c {
                lower[i] = lower[i].max(b);
                continue;
            }
            let d = self.pair_distance(data, i);
            lower[i] = d.distance;
            if d.distance < c {
                f(i, &d);
            }
        }
    }

    /// [`Self::for_each_within`] over the listed pairs (from [`Self::pairs_in`]) at the FK
    /// placements already in `data` ([`CheckData::swap_kinematics`]: a caller that has just run
    /// forward kinematics at `q` lends them instead of running it again). The same exact
    /// distances, the same pairs: a pair is skipped only when its bounding spheres or capsules are `cutoff`
    /// or more apart (a lower bound on its signed distance), and only the shapes of the pairs
    /// that pass are posed. Afterwards `data`'s shape poses are current for those shapes only.
    pub fn for_each_within_posed(
        &self,
        data: &mut CheckData,
        cutoff: f64,
        pairs: &[usize],
        mut f: impl FnMut(usize, &SignedDistance),
    ) {
        let shapes = self.robot.shapes();
        let center =
            |data: &CheckData, i: usize| data.kin.frame(shapes[i].frame) * self.local_centers[i];
        for &i in pairs {
            let p = &self.pairs[i];
            let s = &shapes[p.shape];
            let bound = self.bound_at(i, |k| center(data, k));
            if bound >= cutoff {
                continue;
            }
            data.poses[p.shape] = data.kin.frame(s.frame) * s.origin;
            if let Target::Shape(j) = p.other {
                data.poses[j] = data.kin.frame(shapes[j].frame) * shapes[j].origin;
            }
            if self.capsule_bound(data, i) >= cutoff {
                continue;
            }
            let d = self.pair_distance(data, i);
            if d.distance < cutoff {
                f(i, &d);
            }
        }
    }

    /// `grad += ∂distance/∂q` of a pair at the last update, from its witness points and normal
    /// (valid where the closest points are unique: the normal times the relative velocity of the
    /// witness points).
    pub fn add_distance_gradient(
        &self,
        data: &CheckData,
        pair: usize,
        d: &SignedDistance,
        grad: &mut [f64],
    ) {
        let model = self.robot.model();
        let p = &self.pairs[pair];
        let point_in = |shape: usize, w: &Point3<f64>| {
            let f = self.robot.shapes()[shape].frame;
            (f, data.kin.frame(f).inverse_transform_point(w).coords)
        };
        let (fa, la) = point_in(p.shape, &d.point_a);
        add_point_jacobian_transpose(model, &data.kin, fa, &la, &(-d.normal), grad);
        if let Target::Shape(j) = p.other {
            let (fb, lb) = point_in(j, &d.point_b);
            add_point_jacobian_transpose(model, &data.kin, fb, &lb, &d.normal, grad);
        }
    }
}
