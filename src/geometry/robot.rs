//! The robot's collision shapes (`Model::collisions()`, from the URDF), resolved once: the link
//! and finger each belongs to, its rigid body (links joined by fixed joints move as one), and a
//! configuration-independent bound on how fast its points move per unit joint motion.
//!
//! Speed bound (why conservative advancement cannot miss a collision): for a revolute joint `j`
//! carrying a shape, a point `x` of the shape moves at `|q̇_j| · |m_j| · dist(x, axis_j)` from
//! that joint (`m_j` the mimic multiplier). Walking from the shape up the tree, the shape lies,
//! for every value of the joints below `j`, inside a ball fixed in `j`'s frame: at the shape's
//! own frame the ball is its bounding sphere; through a fixed joint it is carried along; through
//! a revolute joint with axis `a` its centre `c` moves onto the axis and its radius grows by
//! `dist(c, a)` (the ball swept by the rotation); through a prismatic joint the centre moves to
//! the middle of the stroke and the radius grows by half of it. The gain of joint `j` is
//! `|m_j| · (dist(c_j, a_j) + ρ_j)` (`|m_j|` for a prismatic joint), so every point of the shape
//! moves at most `Σ_j gain_j |q̇_j|` in the world, and relative to any ancestor frame at most the
//! same sum over the joints below that frame.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};

use crate::kinematics::{Data, FrameId, JointKind, Model, System};

use super::solid::Solid;

/// A moving joint above a shape, with its speed gain (m/s per unit of `q̇[q]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct ChainJoint {
    /// The frame the joint moves (its child).
    pub frame: usize,
    /// The independent coordinate driving it.
    pub q: usize,
    pub gain: f64,
}

/// One collision shape of the robot.
#[derive(Clone, Debug)]
pub struct LinkShape {
    /// The link (frame) the shape is attached to.
    pub frame: FrameId,
    /// Its name.
    pub link: String,
    /// The finger the link belongs to (index into [`RobotGeometry::finger_names`]); `None` for
    /// arm links, the palm and links several fingers share.
    pub finger: Option<usize>,
    /// Placement of the parry shape in the link frame.
    pub origin: Isometry3<f64>,
    pub(crate) solid: Solid,
    /// Root frame of the rigid body (links joined by fixed joints) the shape belongs to.
    pub(crate) body: usize,
    /// Moving joints carrying the shape, root first.
    pub(crate) chain: Vec<ChainJoint>,
}

impl LinkShape {
    pub fn solid(&self) -> &Solid {
        &self.solid
    }
    /// True when no joint moves the shape (the robot's fixed base).
    pub fn is_static(&self) -> bool {
        self.chain.is_empty()
    }
}

/// The robot's collision geometry, shared (`Arc`) like the `Model` it was built from.
#[derive(Clone, Debug)]
pub struct RobotGeometry {
    model: Arc<Model>,
    shapes: Vec<LinkShape>,
    /// Per frame: root frame of its rigid body.
    body_of_frame: Vec<usize>,
    fingers: Vec<String>,
}

fn body_of(model: &Model) -> Vec<usize> {
    let mut body = vec![0; model.n_frames()];
    for i in 0..model.n_frames() {
        let f = FrameId(i);
        body[i] = match (model.joint_of_frame(f), model.frame_parent(f)) {
            (Some(j), Some(p)) if j.kind.is_fixed() => body[p.0],
            _ => i,
        };
    }
    body
}

/// The finger each frame belongs to: walking towards the root, the first frame on the chain of
/// exactly one finger's tip names it; a frame on several chains (palm, wrist) or none names none.
fn finger_of_frames(model: &Model, tips: &[FrameId]) -> Vec<Option<usize>> {
    let n = model.n_frames();
    // on[f] = bitmask of fingers whose tip chain contains frame f (≤ 64 fingers).
    let mut on = vec![0u64; n];
    for (k, &tip) in tips.iter().enumerate().take(64) {
        let mut f = Some(tip);
        while let Some(fr) = f {
            on[fr.0] |= 1 << k;
            f = model.frame_parent(fr);
        }
    }
    (0..n)
        .map(|i| {
            let mut f = Some(FrameId(i));
            while let Some(fr) = f {
                let m = on[fr.0];
                if m != 0 {
                    return (m.count_ones() == 1).then(|| m.trailing_zeros() as usize);
                }
                f = model.frame_parent(fr);
            }
            None
        })
        .collect()
}

/// The moving joints above `frame` with their speed gains for a shape whose bounding sphere in
/// `frame` is `(center, radius)` (see the module docs).
fn chain_of(model: &Model, frame: FrameId, center: Point3<f64>, radius: f64) -> Vec<ChainJoint> {
    let (mut c, mut r) = (center, radius);
    let mut chain = Vec::new();
    let mut f = frame;
    while let (Some(j), Some(parent)) = (model.joint_of_frame(f), model.frame_parent(f)) {
        match (j.kind, j.actuation) {
            (JointKind::Revolute { axis } | JointKind::Continuous { axis }, Some(act)) => {
                let on_axis = Point3::from(axis.into_inner() * axis.dot(&c.coords));
                let delta = (c - on_axis).norm();
                chain.push(ChainJoint {
                    frame: f.0,
                    q: act.q_index,
                    gain: act.multiplier.abs() * (delta + r),
                });
                c = j.origin * on_axis;
                r += delta;
            }
            (JointKind::Prismatic { axis }, Some(act)) => {
                let (lo, hi) = (
                    model.lower_limits()[act.q_index],
                    model.upper_limits()[act.q_index],
                );
                let (a, b) = (
                    act.multiplier * lo + act.offset,
                    act.multiplier * hi + act.offset,
                );
                let (vlo, vhi) = (a.min(b), a.max(b));
                chain.push(ChainJoint {
                    frame: f.0,
                    q: act.q_index,
                    gain: act.multiplier.abs(),
                });
                c = j.origin * (c + axis.into_inner() * (0.5 * (vlo + vhi)));
                r += 0.5 * (vhi - vlo);
            }
            _ => c = j.origin * c,
        }
        f = parent;
    }
    chain.reverse();
    chain
}

impl RobotGeometry {
    /// The collision shapes of a model, without finger information.
    pub fn new(model: Arc<Model>) -> RobotGeometry {
        Self::build(model, &[], Vec::new())
    }

    /// The collision shapes of an arm-hand system, each link tagged with its finger.
    pub fn from_system(sys: &System) -> RobotGeometry {
        let tips: Vec<FrameId> = sys.fingers.iter().map(|f| f.tip).collect();
        let names = sys.fingers.iter().map(|f| f.name.clone()).collect();
        Self::build(sys.model.clone(), &tips, names)
    }

    fn build(model: Arc<Model>, tips: &[FrameId], fingers: Vec<String>) -> RobotGeometry {
        let body_of_frame = body_of(&model);
        let finger = finger_of_frames(&model, tips);
        let shapes = model
            .collisions()
            .iter()
            .map(|c| {
                let solid = Solid::new(c.shape.clone());
                let center = c.origin * solid.center;
                LinkShape {
                    frame: c.frame,
                    link: model.frame_name(c.frame).to_owned(),
                    finger: finger[c.frame.0],
                    origin: c.origin,
                    body: body_of_frame[c.frame.0],
                    chain: chain_of(&model, c.frame, center, solid.bound),
                    solid,
                }
            })
            .collect();
        RobotGeometry {
            model,
            shapes,
            body_of_frame,
            fingers,
        }
    }

    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// Every collision shape, in `Model::collisions()` order.
    pub fn shapes(&self) -> &[LinkShape] {
        &self.shapes
    }

    /// Finger names, in the system descriptor's order (empty without a system).
    pub fn finger_names(&self) -> &[String] {
        &self.fingers
    }

    /// Root frame of the rigid body a frame belongs to.
    pub fn body(&self, frame: FrameId) -> FrameId {
        FrameId(self.body_of_frame[frame.0])
    }

    /// Links on the same rigid body, or on bodies joined by one moving joint: always allowed to
    /// touch (MoveIt's "adjacent" rule, with fixed joints collapsed).
    pub fn adjacent(&self, a: FrameId, b: FrameId) -> bool {
        let (ba, bb) = (self.body_of_frame[a.0], self.body_of_frame[b.0]);
        let parent_body = |b: usize| {
            self.model
                .frame_parent(FrameId(b))
                .map(|p| self.body_of_frame[p.0])
        };
        ba == bb || parent_body(ba) == Some(bb) || parent_body(bb) == Some(ba)
    }

    /// World poses of every shape after `forward_kinematics(model, data, q)`.
    pub fn pose_shapes(&self, data: &Data, poses: &mut [Isometry3<f64>]) {
        for (p, s) in poses.iter_mut().zip(&self.shapes) {
            *p = data.frame(s.frame) * s.origin;
        }
    }

    /// Upper bound on the world speed of any point of `shape` for joint rates `rates` (absolute
    /// values are taken), m per unit of the rates' parameter.
    pub fn speed_bound(&self, shape: usize, rates: &[f64]) -> f64 {
        self.shapes[shape]
            .chain
            .iter()
            .map(|c| c.gain * rates[c.q].abs())
            .sum()
    }

    /// The links carrying each finger's tip rigidly (the distal phalanx and fixed frames on it):
    /// the shapes a grasp's pads belong to. Indices into [`Self::shapes`].
    pub fn tip_shapes(&self, sys: &System, finger: usize) -> Vec<usize> {
        let body = self.body_of_frame[sys.fingers[finger].tip.0];
        (0..self.shapes.len())
            .filter(|&i| self.shapes[i].body == body)
            .collect()
    }
}
