//! The immutable kinematic description (`Model`) and its builder.
//!
//! Following Pinocchio's Model/Data split, a `Model` holds only constants: the frame tree in
//! topological order (every parent before its children), joint placements, axes, limits and the
//! table that maps each moving joint to a column of `q` (mimic joints folded into their driver).
//! Per-evaluation buffers live in [`crate::kinematics::Data`]. Names are resolved once to
//! [`FrameId`]s and `q` indices; the hot loops in `algorithms.rs` never touch strings.

use std::collections::HashMap;
use std::fmt;

use nalgebra::{Isometry3, Unit, Vector3};
use parry3d_f64::shape::SharedShape;

use super::error::{KinematicsError, check_finite};

/// A frame of the model: a link or a fixed frame. Index into every per-frame table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FrameId(pub usize);

/// How a joint moves its child frame relative to the joint frame. Axes are expressed in the joint
/// frame (URDF convention: the child frame coincides with the joint frame at zero).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum JointKind {
    Fixed,
    Revolute {
        axis: Unit<Vector3<f64>>,
    },
    /// A revolute joint without position limits.
    Continuous {
        axis: Unit<Vector3<f64>>,
    },
    Prismatic {
        axis: Unit<Vector3<f64>>,
    },
}

impl JointKind {
    pub fn is_fixed(&self) -> bool {
        matches!(self, JointKind::Fixed)
    }
    pub fn axis(&self) -> Option<Unit<Vector3<f64>>> {
        match *self {
            JointKind::Fixed => None,
            JointKind::Revolute { axis }
            | JointKind::Continuous { axis }
            | JointKind::Prismatic { axis } => Some(axis),
        }
    }
    pub fn type_name(&self) -> &'static str {
        match self {
            JointKind::Fixed => "fixed",
            JointKind::Revolute { .. } => "revolute",
            JointKind::Continuous { .. } => "continuous",
            JointKind::Prismatic { .. } => "prismatic",
        }
    }
}

/// Position (rad or m), velocity (rad/s or m/s) and effort (N·m or N) limits. Unbounded values
/// are `±f64::INFINITY` (continuous joints, a URDF without velocity/effort limits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimits {
    pub lower: f64,
    pub upper: f64,
    pub velocity: f64,
    pub effort: f64,
}

impl JointLimits {
    pub fn new(lower: f64, upper: f64, velocity: f64, effort: f64) -> Self {
        Self {
            lower,
            upper,
            velocity,
            effort,
        }
    }
    /// No limit at all (fixed and continuous joints).
    pub fn unbounded() -> Self {
        Self {
            lower: f64::NEG_INFINITY,
            upper: f64::INFINITY,
            velocity: f64::INFINITY,
            effort: f64::INFINITY,
        }
    }
}

/// URDF `<mimic>`: `value = multiplier * value(joint) + offset` (paper eq. 26 when offset = 0).
#[derive(Clone, Debug, PartialEq)]
pub struct Mimic {
    pub joint: String,
    pub multiplier: f64,
    pub offset: f64,
}

/// A joint as described (read-only view for the API and descriptors).
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    pub name: String,
    pub parent: FrameId,
    pub child: FrameId,
    pub kind: JointKind,
    pub origin: Isometry3<f64>,
    pub limits: JointLimits,
    /// The mimic as declared (`None` for independent and fixed joints).
    pub mimic: Option<Mimic>,
    /// How the joint value follows `q`: `None` for fixed joints.
    pub actuation: Option<Actuation>,
}

/// `value = multiplier * q[q_index] + offset`, with mimic chains already composed, so that
/// `q_index` always names an independent joint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Actuation {
    pub q_index: usize,
    pub multiplier: f64,
    pub offset: f64,
}

/// Per-frame motion table used by the hot loops (no strings, no indirection through `Joint`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Motion {
    Fixed,
    Revolute {
        axis: Unit<Vector3<f64>>,
        act: Actuation,
    },
    Prismatic {
        axis: Unit<Vector3<f64>>,
        act: Actuation,
    },
}

/// The FK table entry of a frame, derived from [`Motion`] at build time so the hot loops branch
/// once per frame on plain numbers: revolute joints about ±z (every DH-style URDF, both bundled
/// arms) get their own case, the sign of a −z axis folded into the multiplier and offset, and
/// prismatic axes are pre-rotated into the parent frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Step {
    Fixed,
    RevoluteZ {
        q_index: usize,
        multiplier: f64,
        offset: f64,
    },
    Revolute {
        axis: Vector3<f64>,
        q_index: usize,
        multiplier: f64,
        offset: f64,
    },
    Prismatic {
        /// The axis in the parent frame (`origin.rotation * axis`).
        axis_in_parent: Vector3<f64>,
        q_index: usize,
        multiplier: f64,
        offset: f64,
    },
}

impl Step {
    fn of(motion: &Motion, origin: &Isometry3<f64>) -> Step {
        match *motion {
            Motion::Fixed => Step::Fixed,
            Motion::Revolute { axis, act } => {
                let sign = if axis.x == 0.0 && axis.y == 0.0 {
                    Some(axis.z.signum())
                } else {
                    None
                };
                match sign {
                    Some(sign) => Step::RevoluteZ {
                        q_index: act.q_index,
                        multiplier: sign * act.multiplier,
                        offset: sign * act.offset,
                    },
                    None => Step::Revolute {
                        axis: axis.into_inner(),
                        q_index: act.q_index,
                        multiplier: act.multiplier,
                        offset: act.offset,
                    },
                }
            }
            Motion::Prismatic { axis, act } => Step::Prismatic {
                axis_in_parent: origin.rotation * axis.into_inner(),
                q_index: act.q_index,
                multiplier: act.multiplier,
                offset: act.offset,
            },
        }
    }
}

/// A collision primitive or mesh rigidly attached to a frame.
#[derive(Clone)]
pub struct Collision {
    pub frame: FrameId,
    /// Placement of the shape in the frame.
    pub origin: Isometry3<f64>,
    pub shape: SharedShape,
}

impl fmt::Debug for Collision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Collision")
            .field("frame", &self.frame)
            .field("origin", &self.origin)
            .field("shape", &self.shape.shape_type())
            .finish()
    }
}

/// A link's `<visual>` shape, rigidly attached to a frame like a [`Collision`]; for drawing only.
#[derive(Clone)]
pub struct Visual {
    pub frame: FrameId,
    /// Placement of the shape in the frame.
    pub origin: Isometry3<f64>,
    pub shape: SharedShape,
}

impl fmt::Debug for Visual {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Visual")
            .field("frame", &self.frame)
            .field("origin", &self.origin)
            .field("shape", &self.shape.shape_type())
            .finish()
    }
}

/// The immutable kinematic tree. Build it with [`ModelBuilder`] or the URDF loader; share it as
/// `Arc<Model>`.
#[derive(Clone, Debug)]
pub struct Model {
    pub(crate) frame_names: Vec<String>,
    /// `parents[0]` is `usize::MAX` (the root); otherwise `parents[i] < i`.
    pub(crate) parents: Vec<usize>,
    /// Placement of the joint frame in the parent frame, per frame (identity for the root).
    pub(crate) origins: Vec<Isometry3<f64>>,
    pub(crate) motions: Vec<Motion>,
    /// `motions` specialised for FK and Jacobians (see [`Step`]).
    pub(crate) steps: Vec<Step>,
    /// The joint whose child is this frame (`None` for the root).
    pub(crate) joint_of_frame: Vec<Option<usize>>,
    pub(crate) frame_index: HashMap<String, usize>,
    pub(crate) joints: Vec<Joint>,
    pub(crate) joint_index: HashMap<String, usize>,
    /// Independent joints, in the order of `q`.
    pub(crate) q_joint_names: Vec<String>,
    pub(crate) q_joints: Vec<usize>,
    pub(crate) lower: Vec<f64>,
    pub(crate) upper: Vec<f64>,
    pub(crate) velocity: Vec<f64>,
    pub(crate) effort: Vec<f64>,
    pub(crate) collisions: Vec<Collision>,
    pub(crate) visuals: Vec<Visual>,
    pub(crate) visual_errors: Vec<KinematicsError>,
}

impl Model {
    /// Number of independent coordinates (mimic joints folded into their drivers).
    pub fn nq(&self) -> usize {
        self.q_joint_names.len()
    }
    /// Independent joints, in the order of `q`.
    pub fn joint_names(&self) -> &[String] {
        &self.q_joint_names
    }
    pub fn lower_limits(&self) -> &[f64] {
        &self.lower
    }
    pub fn upper_limits(&self) -> &[f64] {
        &self.upper
    }
    pub fn velocity_limits(&self) -> &[f64] {
        &self.velocity
    }
    pub fn effort_limits(&self) -> &[f64] {
        &self.effort
    }
    /// A link or fixed frame by name.
    pub fn frame_id(&self, name: &str) -> Option<FrameId> {
        self.frame_index.get(name).map(|&i| FrameId(i))
    }
    pub fn frame_name(&self, id: FrameId) -> &str {
        &self.frame_names[id.0]
    }
    pub fn n_frames(&self) -> usize {
        self.frame_names.len()
    }
    /// The parent frame (`None` for the root).
    pub fn frame_parent(&self, id: FrameId) -> Option<FrameId> {
        let p = self.parents[id.0];
        (p != usize::MAX).then_some(FrameId(p))
    }
    /// Every joint, fixed and mimic ones included, in tree order.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }
    pub fn joint(&self, name: &str) -> Option<&Joint> {
        self.joint_index.get(name).map(|&i| &self.joints[i])
    }
    /// The joint that moves `frame` relative to its parent (`None` for the root).
    pub fn joint_of_frame(&self, frame: FrameId) -> Option<&Joint> {
        self.joint_of_frame[frame.0].map(|j| &self.joints[j])
    }
    /// Index in `q` of an independent joint.
    pub fn q_index(&self, joint_name: &str) -> Option<usize> {
        let j = self.joint(joint_name)?;
        if j.mimic.is_some() {
            return None;
        }
        j.actuation.map(|a| a.q_index)
    }
    /// The `q` indices that move `frame` (its ancestors' independent coordinates), root first,
    /// without repetition.
    pub fn supporting_q(&self, frame: FrameId) -> Vec<usize> {
        let mut out = Vec::new();
        let mut i = frame.0;
        while i != usize::MAX {
            if let Motion::Revolute { act, .. } | Motion::Prismatic { act, .. } = self.motions[i]
                && !out.contains(&act.q_index)
            {
                out.push(act.q_index);
            }
            i = self.parents[i];
        }
        out.reverse();
        out
    }
    /// The independent joint behind `q[k]`.
    pub fn q_joint(&self, k: usize) -> &Joint {
        &self.joints[self.q_joints[k]]
    }
    pub fn collisions(&self) -> &[Collision] {
        &self.collisions
    }
    /// The URDF `<visual>` shapes (drawing only; nothing kinematic reads them).
    pub fn visuals(&self) -> &[Visual] {
        &self.visuals
    }
    /// Why `<visual>` elements could not be kept (a mesh file not supplied or malformed, a bad
    /// size), in document order. Loading tolerates them; registering a robot refuses them.
    pub fn visual_errors(&self) -> &[KinematicsError] {
        &self.visual_errors
    }
    /// Midpoint of the limits (0 for unbounded coordinates): a neutral configuration.
    pub fn neutral(&self) -> Vec<f64> {
        self.lower
            .iter()
            .zip(&self.upper)
            .map(|(&l, &u)| {
                if l.is_finite() && u.is_finite() {
                    0.5 * (l + u)
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// Builds a [`Model`] programmatically (the URDF loader and the human model use it).
///
/// Frames are added parent first, so the tree is topologically ordered by construction; mimic
/// references are resolved at [`ModelBuilder::build`], so a mimic may name a joint added later.
#[derive(Clone, Debug)]
pub struct ModelBuilder {
    frame_names: Vec<String>,
    parents: Vec<usize>,
    frame_index: HashMap<String, usize>,
    joints: Vec<Joint>,
    joint_index: HashMap<String, usize>,
    collisions: Vec<Collision>,
    visuals: Vec<Visual>,
    visual_errors: Vec<KinematicsError>,
}

fn check_isometry(path: impl Fn() -> String, iso: &Isometry3<f64>) -> Result<(), KinematicsError> {
    for &v in iso
        .translation
        .vector
        .iter()
        .chain(iso.rotation.coords.iter())
    {
        check_finite(&path, v)?;
    }
    Ok(())
}

impl ModelBuilder {
    /// A tree with a single root frame, placed at the world origin.
    pub fn new(root_frame: &str) -> Self {
        let mut frame_index = HashMap::new();
        frame_index.insert(root_frame.to_owned(), 0);
        Self {
            frame_names: vec![root_frame.to_owned()],
            parents: vec![usize::MAX],
            frame_index,
            joints: Vec::new(),
            joint_index: HashMap::new(),
            collisions: Vec::new(),
            visuals: Vec::new(),
            visual_errors: Vec::new(),
        }
    }

    pub fn root(&self) -> FrameId {
        FrameId(0)
    }

    pub fn frame_id(&self, name: &str) -> Option<FrameId> {
        self.frame_index.get(name).map(|&i| FrameId(i))
    }

    pub fn has_joint(&self, name: &str) -> bool {
        self.joint_index.contains_key(name)
    }

    /// Adds joint `name` from `parent` to a new frame `child_frame` placed at `origin` (in the
    /// parent frame) when the joint is at zero. Continuous joints ignore the position limits.
    #[allow(clippy::too_many_arguments)]
    pub fn add_joint(
        &mut self,
        name: &str,
        parent: FrameId,
        child_frame: &str,
        kind: JointKind,
        origin: Isometry3<f64>,
        limits: JointLimits,
        mimic: Option<Mimic>,
    ) -> Result<FrameId, KinematicsError> {
        if self.joint_index.contains_key(name) {
            return Err(KinematicsError::DuplicateJoint {
                name: name.to_owned(),
            });
        }
        if self.frame_index.contains_key(child_frame) {
            return Err(KinematicsError::DuplicateFrame {
                name: child_frame.to_owned(),
            });
        }
        if parent.0 >= self.frame_names.len() {
            return Err(KinematicsError::UnknownParentFrame {
                joint: name.to_owned(),
                parent: parent.0,
            });
        }
        check_isometry(|| format!("joint '{name}' origin"), &origin)?;
        let mut limits = limits;
        if let Some(axis) = kind.axis() {
            for &v in axis.iter() {
                check_finite(|| format!("joint '{name}' axis"), v)?;
            }
            if (axis.norm() - 1.0).abs() > 1e-6 {
                return Err(KinematicsError::ZeroAxis {
                    joint: name.to_owned(),
                });
            }
        }
        match kind {
            JointKind::Fixed => {
                if mimic.is_some() {
                    return Err(KinematicsError::FixedJointMimic {
                        joint: name.to_owned(),
                    });
                }
                limits = JointLimits::unbounded();
            }
            JointKind::Continuous { .. } => {
                limits.lower = f64::NEG_INFINITY;
                limits.upper = f64::INFINITY;
            }
            JointKind::Revolute { .. } | JointKind::Prismatic { .. } => {
                check_finite(|| format!("joint '{name}' lower limit"), limits.lower)?;
                check_finite(|| format!("joint '{name}' upper limit"), limits.upper)?;
            }
        }
        if limits.lower > limits.upper {
            return Err(KinematicsError::LimitsInverted {
                joint: name.to_owned(),
                lower: limits.lower,
                upper: limits.upper,
            });
        }
        for (field, value) in [
            ("velocity limit", limits.velocity),
            ("effort limit", limits.effort),
        ] {
            if value.is_nan() {
                return Err(KinematicsError::NonFinite {
                    path: format!("joint '{name}' {field}"),
                    value,
                });
            }
            if value < 0.0 {
                return Err(KinematicsError::NegativeLimit {
                    joint: name.to_owned(),
                    field,
                    value,
                });
            }
        }
        if let Some(m) = &mimic {
            check_finite(|| format!("joint '{name}' mimic multiplier"), m.multiplier)?;
            check_finite(|| format!("joint '{name}' mimic offset"), m.offset)?;
        }
        let child = self.frame_names.len();
        self.frame_names.push(child_frame.to_owned());
        self.parents.push(parent.0);
        self.frame_index.insert(child_frame.to_owned(), child);
        self.joint_index.insert(name.to_owned(), self.joints.len());
        self.joints.push(Joint {
            name: name.to_owned(),
            parent,
            child: FrameId(child),
            kind,
            origin,
            limits,
            mimic,
            actuation: None,
        });
        Ok(FrameId(child))
    }

    /// A frame rigidly attached to `parent` (a fixed joint named `<frame>_joint`).
    pub fn add_fixed_frame(
        &mut self,
        frame: &str,
        parent: FrameId,
        origin: Isometry3<f64>,
    ) -> Result<FrameId, KinematicsError> {
        let joint = format!("{frame}_joint");
        self.add_joint(
            &joint,
            parent,
            frame,
            JointKind::Fixed,
            origin,
            JointLimits::unbounded(),
            None,
        )
    }

    /// Attaches a collision shape to `frame` at `origin` (in the frame).
    pub fn add_collision(
        &mut self,
        frame: FrameId,
        origin: Isometry3<f64>,
        shape: SharedShape,
    ) -> Result<(), KinematicsError> {
        let name = self.frame_names.get(frame.0).cloned().unwrap_or_default();
        check_isometry(|| format!("link '{name}' collision origin"), &origin)?;
        self.collisions.push(Collision {
            frame,
            origin,
            shape,
        });
        Ok(())
    }

    /// Attaches a visual shape to `frame` at `origin` (in the frame); a non-finite origin is
    /// recorded as a visual error instead.
    pub fn add_visual(&mut self, frame: FrameId, origin: Isometry3<f64>, shape: SharedShape) {
        let name = self.frame_names.get(frame.0).cloned().unwrap_or_default();
        match check_isometry(|| format!("link '{name}' visual origin"), &origin) {
            Ok(()) => self.visuals.push(Visual {
                frame,
                origin,
                shape,
            }),
            Err(e) => self.visual_errors.push(e),
        }
    }

    /// Records why a `<visual>` element could not be kept.
    pub fn add_visual_error(&mut self, error: KinematicsError) {
        self.visual_errors.push(error);
    }

    /// Resolves mimic chains, numbers the independent joints and freezes the tree.
    pub fn build(mut self) -> Result<Model, KinematicsError> {
        let n_joints = self.joints.len();
        // Independent coordinates first, in insertion order.
        let mut q_joints = Vec::new();
        for (j, joint) in self.joints.iter_mut().enumerate() {
            if !joint.kind.is_fixed() && joint.mimic.is_none() {
                joint.actuation = Some(Actuation {
                    q_index: q_joints.len(),
                    multiplier: 1.0,
                    offset: 0.0,
                });
                q_joints.push(j);
            }
        }
        // Compose mimic chains: value_j = m * value_driver + o, followed to an independent joint.
        for j in 0..n_joints {
            if self.joints[j].mimic.is_none() {
                continue;
            }
            let (mut mult, mut off) = (1.0, 0.0);
            let mut cur = j;
            let mut steps = 0;
            let act = loop {
                let Some(m) = self.joints[cur].mimic.clone() else {
                    let a = self.joints[cur]
                        .actuation
                        .expect("independent joint has an index");
                    break a;
                };
                steps += 1;
                if steps > n_joints {
                    return Err(KinematicsError::MimicCycle {
                        joint: self.joints[j].name.clone(),
                    });
                }
                let Some(&driver) = self.joint_index.get(&m.joint) else {
                    return Err(KinematicsError::MimicUnknownJoint {
                        joint: self.joints[cur].name.clone(),
                        mimicked: m.joint,
                    });
                };
                if self.joints[driver].kind.is_fixed() {
                    return Err(KinematicsError::MimicOfFixed {
                        joint: self.joints[cur].name.clone(),
                        mimicked: m.joint,
                    });
                }
                // value_cur = m.mult * value_driver + m.off; value_j = mult * value_cur + off
                off += mult * m.offset;
                mult *= m.multiplier;
                cur = driver;
            };
            self.joints[j].actuation = Some(Actuation {
                q_index: act.q_index,
                multiplier: mult * act.multiplier,
                offset: off + mult * act.offset,
            });
        }

        let n_frames = self.frame_names.len();
        let mut origins = vec![Isometry3::identity(); n_frames];
        let mut motions = vec![Motion::Fixed; n_frames];
        let mut joint_of_frame = vec![None; n_frames];
        for (j, joint) in self.joints.iter().enumerate() {
            let c = joint.child.0;
            origins[c] = joint.origin;
            joint_of_frame[c] = Some(j);
            motions[c] = match (joint.kind, joint.actuation) {
                (JointKind::Revolute { axis } | JointKind::Continuous { axis }, Some(act)) => {
                    Motion::Revolute { axis, act }
                }
                (JointKind::Prismatic { axis }, Some(act)) => Motion::Prismatic { axis, act },
                _ => Motion::Fixed,
            };
        }
        let steps = motions
            .iter()
            .zip(&origins)
            .map(|(m, o)| Step::of(m, o))
            .collect();
        let q_joint_names = q_joints
            .iter()
            .map(|&j| self.joints[j].name.clone())
            .collect();
        let lim = |f: fn(&JointLimits) -> f64| {
            q_joints
                .iter()
                .map(|&j| f(&self.joints[j].limits))
                .collect()
        };
        let lower = lim(|l| l.lower);
        let upper = lim(|l| l.upper);
        let velocity = lim(|l| l.velocity);
        let effort = lim(|l| l.effort);
        Ok(Model {
            frame_names: self.frame_names,
            parents: self.parents,
            origins,
            motions,
            steps,
            joint_of_frame,
            frame_index: self.frame_index,
            joints: self.joints,
            joint_index: self.joint_index,
            q_joint_names,
            q_joints,
            lower,
            upper,
            velocity,
            effort,
            collisions: self.collisions,
            visuals: self.visuals,
            visual_errors: self.visual_errors,
        })
    }
}
