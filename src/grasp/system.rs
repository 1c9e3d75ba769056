//! What the grasp optimiser needs to know about an arm-hand system, resolved once to typed
//! indices: which `q` columns are arm and hand, the grasp (palm) frame, fingertip contact
//! spheres, spread pairs (eq. 28), the elbow frame (eq. 4 reference) and the link spheres that
//! must stay out of the object and above the support plane (eq. 29).

use std::sync::Arc;

use nalgebra::{Point3, Vector3};
use parry3d_f64::shape::{Shape, TypedShape};

use crate::geometry::RobotGeometry;
use crate::kinematics::{Data, FrameId, JointKind, Model, System, forward_kinematics};

use super::GraspError;

/// One finger: its fingertip contact sphere (centre fixed in the tip frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Finger {
    /// Finger name.
    pub name: String,
    /// Tip frame.
    pub tip: FrameId,
    /// Contact-sphere centre in the tip frame.
    pub tip_offset: Vector3<f64>,
    /// Contact-sphere radius.
    pub radius: f64,
    /// Unit outward normal of the finger's pad (its inner, flexion-side face) in the tip frame:
    /// the side that presses into the object when the finger closes. The bundled hand
    /// descriptors put it on the tip frame's `z` ("z palmar normal").
    pub pad_normal: Vector3<f64>,
}

impl Finger {
    /// The contact-sphere centre in the world, at the posture `data` holds.
    pub fn contact_point(&self, data: &Data) -> Point3<f64> {
        data.frame(self.tip) * Point3::from(self.tip_offset)
    }
}

/// A joint value as an affine function of one independent coordinate:
/// `multiplier · q[q_index] + offset` (mimic joints included).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointValue {
    /// Independent coordinate.
    pub q_index: usize,
    /// Coupling factor.
    pub multiplier: f64,
    /// Offset.
    pub offset: f64,
}

impl JointValue {
    /// An independent joint.
    pub fn independent(q_index: usize) -> Self {
        JointValue {
            q_index,
            multiplier: 1.0,
            offset: 0.0,
        }
    }

    /// Its value at `q`.
    pub fn at(&self, q: &[f64]) -> f64 {
        self.multiplier * q[self.q_index] + self.offset
    }
}

/// Spread ordering of eq. 28: `value(lower) ≤ value(upper)` (abduction/adduction collisions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpreadOrder {
    /// Joint that must stay below.
    pub lower: JointValue,
    /// Joint that must stay above.
    pub upper: JointValue,
}

/// A sphere rigidly attached to a link: one element of the discrete point set `S_i` of eq. 29.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkSphere {
    /// Link frame.
    pub frame: FrameId,
    /// Centre in the link frame.
    pub center: Vector3<f64>,
    /// Radius.
    pub radius: f64,
    /// The finger the link belongs to (`None`: the palm, the wrist, or links several fingers
    /// share).
    pub finger: Option<usize>,
}

/// A link sphere of one finger and a sphere of another finger, kept disjoint by the grasp
/// optimiser (fingers must not pass through each other).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkPair {
    /// Two link spheres (indices into [`HandArm::link_spheres`]).
    Links(usize, usize),
    /// A link sphere and another finger's contact sphere (finger index).
    Tip(usize, usize),
}

/// The arm-hand system as the grasp optimiser sees it.
#[derive(Debug, Clone)]
pub struct HandArm {
    /// System name.
    pub name: String,
    /// The combined kinematic model.
    pub model: Arc<Model>,
    /// `q` indices of the arm joints, base to tip.
    pub arm_joints: Vec<usize>,
    /// `q` indices of the independent hand joints.
    pub hand_joints: Vec<usize>,
    /// The grasp frame: TC (eq. 16) is evaluated for the arm Jacobian at its origin.
    pub palm: FrameId,
    /// The fingers that touch the object (eq. 27 holds for each); `thumb` indexes the opposing
    /// one if any.
    pub fingers: Vec<Finger>,
    /// Fingers of the hand kept off the object ([`HandArm::with_contact_fingers`]): a grasp with
    /// fewer contacts. Their links stay out of the object and above the support like the palm's,
    /// and apart from the other fingers; empty for the whole hand.
    pub idle_fingers: Vec<Finger>,
    /// Index of the thumb finger.
    pub thumb: Option<usize>,
    /// Ordered spread pairs (eq. 28): `value(lower) ≤ value(upper)`.
    pub spread_pairs: Vec<SpreadOrder>,
    /// Elbow frame for the anthropomorphism term D.
    pub elbow: Option<FrameId>,
    /// Link spheres kept out of the object and above the support plane (eq. 29).
    pub link_spheres: Vec<LinkSphere>,
    /// Points with radii whose lowest point over a plane is at or below the lowest point of
    /// the same links' collision shapes (exact for boxes and balls, within 0.9 % of the radius
    /// for cylinders): the optimiser's support rows (eq. 29 against the table) use these, not
    /// the inscribed `link_spheres`, so that no box corner passes under the table unseen.
    pub support_cover: Vec<LinkSphere>,
    /// Spheres of different fingers kept apart (besides the contact spheres, which the
    /// optimiser keeps apart pairwise).
    pub link_pairs: Vec<LinkPair>,
    /// Every separable pair of spheres of different fingers, first links included: the grasp
    /// starts' preshape avoids crossing fingers by these.
    pub crossing_pairs: Vec<LinkPair>,
    /// How many of the last arm joints move links with spheres ([`Self::collect_link_spheres`]).
    pub wrist_joints: usize,
    /// The exact collision shapes of every link (arm and hand): the optimiser's geometry rows
    /// (eq. 27-29) and the `feasible` verdict use exact distances between them.
    pub geometry: Arc<RobotGeometry>,
}

/// Sample a collision shape by spheres: balls as themselves, capsules and cylinders along
/// their axis, boxes on a grid; spheres fit inside the shape.
fn spheres_of(
    shape_dyn: &dyn Shape,
    origin: &nalgebra::Isometry3<f64>,
    out: &mut Vec<(Vector3<f64>, f64)>,
) {
    let push = |out: &mut Vec<(Vector3<f64>, f64)>, p: Point3<f64>, r: f64| {
        out.push(((origin * p).coords, r));
    };
    match shape_dyn.as_typed_shape() {
        TypedShape::Ball(b) => push(out, Point3::origin(), b.radius),
        TypedShape::Capsule(c) => {
            let (a, b) = (c.segment.a, c.segment.b);
            let len = (b - a).norm();
            let n = ((len / c.radius).ceil() as usize).clamp(1, 8);
            for k in 0..=n {
                push(out, a + (b - a) * (k as f64 / n as f64), c.radius);
            }
        }
        TypedShape::Cylinder(c) => {
            let r = c.radius.min(c.half_height);
            let n = ((2.0 * c.half_height / c.radius).ceil() as usize).clamp(1, 8);
            for k in 0..=n {
                let y = -c.half_height + r + (2.0 * (c.half_height - r)) * (k as f64 / n as f64);
                push(out, Point3::new(0.0, y, 0.0), c.radius);
            }
        }
        TypedShape::Cuboid(b) => {
            let he = b.half_extents;
            let r = he.min();
            let counts = he.map(|h| ((h / r).round() as usize).clamp(1, 4));
            for i in 0..counts.x {
                for j in 0..counts.y {
                    for k in 0..counts.z {
                        let coord = |idx: usize, n: usize, h: f64| {
                            if n == 1 {
                                0.0
                            } else {
                                -h + r + (2.0 * (h - r)) * idx as f64 / (n - 1) as f64
                            }
                        };
                        push(
                            out,
                            Point3::new(
                                coord(i, counts.x, he.x),
                                coord(j, counts.y, he.y),
                                coord(k, counts.z, he.z),
                            ),
                            r,
                        );
                    }
                }
            }
        }
        _ => {
            // Meshes and other shapes: a bounding-sphere-free fallback is not conservative, so
            // use the local AABB centre with the inscribed radius of the AABB.
            let aabb = shape_dyn.compute_local_aabb();
            let he = aabb.half_extents();
            push(out, aabb.center(), he.min());
        }
    }
}

/// Rim samples per end disk of a cylinder in the support cover.
const RIM_SAMPLES: usize = 24;

/// A support-plane cover of a collision shape: points with radii such that for every plane
/// the smallest `distance(point) − radius` is at most the shape's own smallest distance.
/// Balls and capsules: their centres or segment ends with their radius (exact). Boxes: their 8
/// corners (exact). Cylinders: `RIM_SAMPLES` points on each end rim, each with radius
/// `r (1 − cos(π / RIM_SAMPLES))`, the most the rim can dip between two samples (conservative).
/// Anything else: the corners of its local bounding box (conservative).
fn support_cover_of(
    shape_dyn: &dyn Shape,
    origin: &nalgebra::Isometry3<f64>,
    out: &mut Vec<(Vector3<f64>, f64)>,
) {
    let mut push = |p: Point3<f64>, r: f64| out.push(((origin * p).coords, r));
    let mut corners = |mins: Point3<f64>, maxs: Point3<f64>| {
        for k in 0..8 {
            let pick = |bit: usize, lo: f64, hi: f64| if k & bit == 0 { lo } else { hi };
            push(
                Point3::new(
                    pick(1, mins.x, maxs.x),
                    pick(2, mins.y, maxs.y),
                    pick(4, mins.z, maxs.z),
                ),
                0.0,
            );
        }
    };
    match shape_dyn.as_typed_shape() {
        TypedShape::Ball(b) => push(Point3::origin(), b.radius),
        TypedShape::Capsule(c) => {
            push(c.segment.a, c.radius);
            push(c.segment.b, c.radius);
        }
        TypedShape::Cuboid(b) => {
            let he = b.half_extents;
            corners(Point3::from(-he), Point3::from(he));
        }
        TypedShape::Cylinder(c) => {
            let dip = c.radius * (1.0 - (std::f64::consts::PI / RIM_SAMPLES as f64).cos());
            for y in [-c.half_height, c.half_height] {
                for k in 0..RIM_SAMPLES {
                    let a = std::f64::consts::TAU * k as f64 / RIM_SAMPLES as f64;
                    push(Point3::new(c.radius * a.cos(), y, c.radius * a.sin()), dip);
                }
            }
        }
        _ => {
            let aabb = shape_dyn.compute_local_aabb();
            corners(aabb.mins, aabb.maxs);
        }
    }
}

/// Gap between the two spheres of a link pair at the posture in `data` (m; < 0: overlap).
fn pair_gap(h: &HandArm, spheres: &[LinkSphere], data: &Data, p: LinkPair) -> f64 {
    let at = |s: &LinkSphere| data.frame(s.frame) * Point3::from(s.center);
    let (a, c, r) = match p {
        LinkPair::Links(a, b) => (a, at(&spheres[b]), spheres[b].radius),
        LinkPair::Tip(a, f) => {
            let fi = &h.fingers[f];
            (a, fi.contact_point(data), fi.radius)
        }
    };
    (at(&spheres[a]) - c).norm() - spheres[a].radius - r
}

/// The finger a link frame belongs to, and how many moving joints of that finger carry it (1:
/// the finger's first link, which sits on the palm). Walking from `frame` towards the root, the
/// first frame on exactly one finger's chain names it; a frame on several chains (palm, wrist)
/// ends the walk, and a link reached before any finger's chain belongs to no finger.
fn finger_of(model: &Model, frame: FrameId, chains: &[Vec<FrameId>]) -> (Option<usize>, usize) {
    let (mut finger, mut depth) = (None, 0);
    let mut fr = Some(frame);
    while let Some(f) = fr {
        let mut on = chains.iter().enumerate().filter(|(_, c)| c.contains(&f));
        match (on.next(), on.next()) {
            (Some(_), Some(_)) => break,
            (Some((i, _)), None) => {
                finger.get_or_insert(i);
            }
            _ => {}
        }
        if model.joint_of_frame(f).is_some_and(|j| !j.kind.is_fixed()) {
            depth += 1;
        }
        fr = model.frame_parent(f);
    }
    (finger, depth)
}

impl HandArm {
    /// Smallest gap over the crossing pairs at the posture in `data` (forward kinematics done;
    /// m, < 0: overlap; infinite without pairs).
    pub fn min_crossing_gap(&self, data: &Data) -> f64 {
        self.crossing_pairs
            .iter()
            .map(|&p| pair_gap(self, &self.link_spheres, data, p))
            .fold(f64::INFINITY, f64::min)
    }

    /// Each finger's kinematic chain: its tip frame and every ancestor, tip first.
    pub fn finger_chains(&self) -> Vec<Vec<FrameId>> {
        Self::chains_of(&self.model, &self.fingers)
    }

    fn chains_of(model: &Model, fingers: &[Finger]) -> Vec<Vec<FrameId>> {
        fingers
            .iter()
            .map(|f| {
                let mut chain = vec![f.tip];
                let mut fr = f.tip;
                while let Some(p) = model.frame_parent(fr) {
                    chain.push(p);
                    fr = p;
                }
                chain
            })
            .collect()
    }

    /// A ball every fingertip contact sphere stays inside over the whole configuration space:
    /// centre at the origin of the chain's first moving joint (fixed in the world, since only
    /// fixed frames lie above it), radius the sum of the constant distances between successive
    /// joint origins down to the contact sphere, plus its radius. Revolute joints rotate their
    /// child about an axis through the child's origin, so each such distance is invariant; with
    /// a prismatic joint on a chain there is no such bound (`None`).
    pub fn reach_ball(&self) -> Option<(Point3<f64>, f64)> {
        let model = &*self.model;
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, &model.neutral());
        let origin = |f: FrameId| Point3::from(data.frame(f).translation.vector);
        let mut centre: Option<Point3<f64>> = None;
        let mut radius: f64 = 0.0;
        for (chain, finger) in self.finger_chains().iter().zip(&self.fingers) {
            let tip = finger.contact_point(&data);
            // Moving frames, tip side first.
            let mut moving = Vec::new();
            for &f in chain {
                match model.joint_of_frame(f).map(|j| j.kind) {
                    Some(JointKind::Prismatic { .. }) => return None,
                    Some(JointKind::Revolute { .. } | JointKind::Continuous { .. }) => {
                        moving.push(origin(f))
                    }
                    _ => {}
                }
            }
            let first = *moving.last()?;
            if centre.is_some_and(|c| (c - first).norm() > 1e-9) {
                // Fingers hanging off different fixed roots: no common centre.
                return None;
            }
            centre = Some(first);
            let mut r = finger.radius;
            let mut at = tip;
            for &o in &moving {
                r += (at - o).norm();
                at = o;
            }
            radius = radius.max(r);
        }
        centre.map(|c| (c, radius))
    }

    /// Collect the link spheres of eq. 29 from the model's collision shapes: every link moved by
    /// a hand joint, plus links moved by any of the last `wrist_joints` arm joints (the parts
    /// that come near the object and the table). Spheres on a fingertip link that overlap its
    /// contact sphere are dropped: the contact sphere is what touches the surface (eq. 27).
    pub fn collect_link_spheres(&mut self, wrist_joints: usize) {
        self.wrist_joints = wrist_joints;
        let model = &self.model;
        let wrist: Vec<usize> = self
            .arm_joints
            .iter()
            .rev()
            .take(wrist_joints)
            .copied()
            .collect();
        // Frames rigidly attached to each fingertip (the tip's body): spheres there that overlap
        // the contact sphere are dropped, the rest shrunk to the contact radius, because the
        // contact sphere is the finger pad that touches the surface (eq. 27).
        let tip_body: Vec<Vec<FrameId>> = self
            .fingers
            .iter()
            .map(|f| {
                let mut body = vec![f.tip];
                let mut fr = f.tip;
                while let (Some(j), Some(parent)) =
                    (model.joint_of_frame(fr), model.frame_parent(fr))
                {
                    if !j.kind.is_fixed() {
                        break;
                    }
                    body.push(parent);
                    fr = parent;
                }
                // The moving link carrying the tip (the distal phalanx) is also the tip's body.
                if let Some(j) = model.joint_of_frame(fr)
                    && !j.kind.is_fixed()
                {
                    body.push(fr);
                }
                body
            })
            .collect();
        // Idle fingers after the contact fingers: their links are a finger's (kept apart from
        // the others), their tips keep every sphere (they must not touch the object).
        let chains = Self::chains_of(model, &self.all_fingers());
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, &model.neutral());
        let mut spheres = Vec::new();
        let mut cover = Vec::new();
        // per sphere: how many of its finger's moving joints carry it
        let mut depth = Vec::new();
        let mut buf = Vec::new();
        for c in model.collisions() {
            let sup = model.supporting_q(c.frame);
            let moved_by_hand = sup.iter().any(|q| self.hand_joints.contains(q));
            let moved_by_wrist = sup.iter().any(|q| wrist.contains(q));
            if !(moved_by_hand || moved_by_wrist) {
                continue;
            }
            buf.clear();
            support_cover_of(c.shape.as_ref(), &c.origin, &mut buf);
            for &(center, radius) in &buf {
                cover.push(LinkSphere {
                    frame: c.frame,
                    center,
                    radius,
                    finger: finger_of(model, c.frame, &chains).0,
                });
            }
            buf.clear();
            spheres_of(c.shape.as_ref(), &c.origin, &mut buf);
            'sphere: for &(center, mut radius) in &buf {
                for (f, body) in self.fingers.iter().zip(&tip_body) {
                    if body.contains(&c.frame) {
                        let world = data.frame(c.frame) * Point3::from(center);
                        let tip = f.contact_point(&data);
                        if (world - tip).norm() < f.radius + radius {
                            continue 'sphere;
                        }
                        radius = radius.min(0.9 * f.radius);
                    }
                }
                if radius > 1e-4 {
                    let (finger, d) = finger_of(model, c.frame, &chains);
                    spheres.push(LinkSphere {
                        frame: c.frame,
                        center,
                        radius,
                        finger,
                    });
                    depth.push(d);
                }
            }
        }
        // Pairs of spheres on different fingers. A pair that overlaps in every posture of a
        // sweep from the open to the closed hand (all hand joints at the same fraction of their
        // range) is part of the hand's design: no posture could separate it. The optimiser's rows
        // also leave out a finger's first link (the one on the palm): the bundled OB4F's thumb
        // and middle finger bases are 10 mm apart and their first two links' spheres 16 mm
        // across, so with them no ball grasp was found; the starts' preshape still uses them to
        // tell crossed fingers.
        let mut candidates = Vec::new();
        for (a, sa) in spheres.iter().enumerate() {
            let Some(fa) = sa.finger else { continue };
            for (b, sb) in spheres.iter().enumerate().skip(a + 1) {
                if sb.finger.is_some_and(|fb| fb != fa) {
                    candidates.push(LinkPair::Links(a, b));
                }
            }
            for f in 0..self.fingers.len() {
                if f != fa {
                    candidates.push(LinkPair::Tip(a, f));
                }
            }
        }
        let mut separable = vec![false; candidates.len()];
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let mut q = model.neutral();
        for frac in [0.0, 0.25, 0.5, 0.75, 1.0] {
            for &h in &self.hand_joints {
                if lo[h].is_finite() && hi[h].is_finite() {
                    q[h] = lo[h] + frac * (hi[h] - lo[h]);
                }
            }
            forward_kinematics(model, &mut data, &q);
            for (ok, &p) in separable.iter_mut().zip(&candidates) {
                *ok |= pair_gap(self, &spheres, &data, p) > super::optimizer::FINGER_CLEARANCE;
            }
        }
        let crossing: Vec<LinkPair> = candidates
            .into_iter()
            .zip(separable)
            .filter_map(|(p, ok)| ok.then_some(p))
            .collect();
        self.link_pairs = crossing
            .iter()
            .copied()
            .filter(|p| match *p {
                LinkPair::Links(a, b) => depth[a].min(depth[b]) > 1,
                LinkPair::Tip(a, _) => depth[a] > 1,
            })
            .collect();
        self.link_spheres = spheres;
        self.support_cover = cover;
        self.crossing_pairs = crossing;
    }

    /// The grasp view of a kinematic [`System`]: the wrist frame is the grasp frame, the first
    /// elbow frame is D's elbow, contact spheres are centred on the tip frames, link spheres come
    /// from the hand's and the last three arm joints' collision shapes.
    pub fn from_system(sys: &System) -> Result<HandArm, GraspError> {
        let mut h = HandArm {
            name: sys.name.clone(),
            model: sys.model.clone(),
            arm_joints: sys.arm_joints.clone(),
            hand_joints: sys.hand_joints.clone(),
            palm: sys.wrist_frame,
            fingers: sys
                .fingers
                .iter()
                .map(|f| Finger {
                    name: f.name.clone(),
                    tip: f.tip,
                    tip_offset: Vector3::zeros(),
                    radius: f.contact_radius,
                    pad_normal: Vector3::z(),
                })
                .collect(),
            idle_fingers: Vec::new(),
            thumb: Some(sys.thumb),
            spread_pairs: sys
                .spread_pairs
                .iter()
                .map(|p| SpreadOrder {
                    lower: JointValue {
                        q_index: p.lower.q_index,
                        multiplier: p.lower.multiplier,
                        offset: p.lower.offset,
                    },
                    upper: JointValue {
                        q_index: p.upper.q_index,
                        multiplier: p.upper.multiplier,
                        offset: p.upper.offset,
                    },
                })
                .collect(),
            elbow: sys.elbow_frames.first().copied(),
            link_spheres: Vec::new(),
            support_cover: Vec::new(),
            link_pairs: Vec::new(),
            crossing_pairs: Vec::new(),
            wrist_joints: 0,
            geometry: Arc::new(RobotGeometry::from_system(sys)),
        };
        h.collect_link_spheres(3);
        h.validate()?;
        Ok(h)
    }

    /// Every finger of the hand: those on the object, then the idle ones.
    fn all_fingers(&self) -> Vec<Finger> {
        self.fingers
            .iter()
            .chain(&self.idle_fingers)
            .cloned()
            .collect()
    }

    /// The same system grasping with the fingers `keep` only (indices into
    /// [`Self::fingers`] followed by [`Self::idle_fingers`], ascending, at least two): the others
    /// become the idle fingers, kept off the object. The link spheres and pairs are collected
    /// again (an idle fingertip keeps the spheres a contact finger gives up to its contact
    /// sphere).
    pub fn with_contact_fingers(&self, keep: &[usize]) -> HandArm {
        let mut h = self.clone();
        let all = self.all_fingers();
        h.fingers = keep.iter().map(|&i| all[i].clone()).collect();
        h.idle_fingers = (0..all.len())
            .filter(|i| !keep.contains(i))
            .map(|i| all[i].clone())
            .collect();
        h.thumb = self.thumb.and_then(|t| keep.iter().position(|&i| i == t));
        let wrist = self.wrist_joints;
        h.collect_link_spheres(wrist);
        h
    }

    /// Check indices and sizes; called once when a system is registered.
    pub fn validate(&self) -> Result<(), GraspError> {
        let nq = self.model.nq();
        let bad = |field: &'static str, reason: String| {
            Err(GraspError::InvalidParameter { field, reason })
        };
        if self.fingers.len() < 2 {
            return bad(
                "fingers",
                format!(
                    "a grasp needs at least 2 fingers, got {}",
                    self.fingers.len()
                ),
            );
        }
        for &q in self.arm_joints.iter().chain(&self.hand_joints) {
            if q >= nq {
                return bad("joints", format!("q index {q} beyond nq = {nq}"));
            }
        }
        for f in &self.fingers {
            if !(f.radius.is_finite() && f.radius > 0.0) {
                return bad(
                    "fingers.radius",
                    format!("finger '{}' radius {}", f.name, f.radius),
                );
            }
        }
        Ok(())
    }
}
