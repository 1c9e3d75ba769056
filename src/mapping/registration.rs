//! Registration: human (tracker) frame → robot base frame, keeping the demonstration's scene.
//!
//! # The default: the scene is kept ([`RegistrationSpec::Scene`])
//!
//! The paper maps in one frame where the human and the robot share the task (§II-C, eq. 1-7):
//! the object the subject grasped is the object the robot grasps, on the same table. A
//! demonstration is registered so that
//!
//! * its **object** lands on the robot-frame **placement** of that object (exactly: the object's
//!   centre is the anchor of the map);
//! * its **support plane** (the table, `human_support` along the subject's up axis) lands on the
//!   robot's support plane: heights above the support are kept (no vertical scale), so an object
//!   resting on the subject's table rests on the robot's;
//! * the **arm plane keeps its orientation**: the only rotation is the subject's forward/up axes
//!   onto the robot base's (a yaw for level tables), so the shoulder→wrist direction is kept;
//! * the **arm transport** (shoulder, elbow, wrist) is scaled perpendicular to the up axis, about
//!   the object, by `transport_scale` (default `auto` = robot reach / human reach, 1.4-1.7 on the
//!   shipped systems; `1` is the paper's). Measured on the default study (`mapping::tests::
//!   probe_registration_and_weights`, default weights): `auto` vs `1` gives a median swivel
//!   difference of 55-59° vs 70-71° on the WAM systems and 68-71° vs 72-74° on the PA10 ones,
//!   at a median fingertip error of 18-36 mm vs 20-37 mm: the robots' longer links fold less;
//! * the **fingertips relative to the wrist are unscaled** by default (`hand_scale`, an explicit
//!   option): grip apertures and fingertip spacing are the subject's, as in the paper, which
//!   gives the robot hand the human's fingertip positions (eq. 1) without scaling.
//!
//! The default placement (no `placement` in the request) puts the object where the subject had
//! it relative to the shoulder: `horizontal(robot shoulder + transport_scale · R (object −
//! mean human shoulder))`, resting on the robot's support at the height it had above the
//! subject's table. The study's objects lie 62-80 % of an arm length in front of the shoulder,
//! 35° left to 35° right (`human::synth`), 0.37-0.48 m out horizontally: scaled by the reach
//! ratio that is 0.55-0.8 m from the shoulder axis on the table the robots stand on — inside
//! their reach (checked: an unreachable placement is an error), above the table — and the
//! subject's shoulder lands horizontally on the robot's (vertically within 3 cm: seated shoulder
//! height 0.33 m vs 0.317 m PA10 / 0.346 m WAM).
//!
//! Differences from the paper, and why: the paper states no registration at all (its subjects and
//! robots share one lab frame). Anchoring the map at the object instead of at the shoulder is
//! what makes mapped data, models and plans share one scene; the previous default (shoulder onto
//! shoulder, uniform scale robot reach / human reach) put the objects 10-17 cm under the robot's
//! table and grew the hand 1.5x (issue 16).
//!
//! A demonstration without an object (e.g. a bare arm recording) is anchored at its last wrist
//! position instead, which is where the hand grasps.
//!
//! # Explicit
//!
//! [`RegistrationSpec::Explicit`]: `p_robot = transform · (scale · p_human)` for every point,
//! fingertips included (a similarity, as given).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Unit, UnitQuaternion, Vector3};

use super::MappingError;
use crate::human::{ObjectShape, ObjectSpec};

/// Uniform scale applied to the human arm transport.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scale {
    /// Keep human dimensions.
    One,
    /// Robot reach / human reach.
    Auto,
    /// A given positive factor.
    Factor(f64),
}

/// Forward and up axes of a body, in the frame its data are expressed in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyAxes {
    pub forward: Vector3<f64>,
    pub up: Vector3<f64>,
}

impl Default for BodyAxes {
    /// Tracker and URDF base convention: x forward, z up.
    fn default() -> Self {
        Self {
            forward: Vector3::x(),
            up: Vector3::z(),
        }
    }
}

/// The demonstration's object: shape and pose in the tracker frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HumanObject {
    pub shape: ObjectShape,
    pub pose: Isometry3<f64>,
}

/// A demonstration's object spec as the registration's object.
pub fn human_object(spec: &ObjectSpec) -> HumanObject {
    HumanObject {
        shape: spec.shape,
        pose: spec.pose.to_isometry(),
    }
}

impl HumanObject {
    /// How far the object reaches below its centre along `up` (unit, tracker frame): its support
    /// function in direction `−up`.
    pub fn extent_below(&self, up: &Vector3<f64>) -> f64 {
        let d = self.pose.rotation.inverse() * (-up);
        match self.shape {
            ObjectShape::Sphere { radius } => radius,
            ObjectShape::Cylinder { radius, height } => {
                0.5 * height * d.z.abs() + radius * (1.0 - d.z * d.z).max(0.0).sqrt()
            }
            ObjectShape::Box { size } => {
                0.5 * (size[0] * d.x.abs() + size[1] * d.y.abs() + size[2] * d.z.abs())
            }
            ObjectShape::Capsule { radius, height } => 0.5 * height * d.z.abs() + radius,
        }
    }
}

/// The scene-keeping registration (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneRegistration {
    pub subject_axes: BodyAxes,
    /// Scale of the arm transport perpendicular to the up axis (default `Auto`).
    pub transport_scale: Scale,
    /// Scale of the fingertips relative to the wrist (default `1`).
    pub hand_scale: f64,
    /// Robot-frame position of the object's centre; `None`: the default placement.
    pub placement: Option<Point3<f64>>,
    /// Height of the demonstration's support plane along the subject's up axis, tracker frame
    /// (default `0`: the tracker origin is on the table, `human` module conventions).
    pub human_support: f64,
    /// The demonstration's object (set per demonstration by the caller).
    pub object: Option<HumanObject>,
}

impl Default for SceneRegistration {
    fn default() -> Self {
        Self {
            subject_axes: BodyAxes::default(),
            transport_scale: Scale::Auto,
            hand_scale: 1.0,
            placement: None,
            human_support: 0.0,
            object: None,
        }
    }
}

impl SceneRegistration {
    /// This registration for a demonstration with `object`.
    pub fn with_object(mut self, object: Option<HumanObject>) -> Self {
        self.object = object;
        self
    }
}

/// How to register a demonstration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RegistrationSpec {
    /// Object onto its placement, support onto support, axes onto axes (the default).
    Scene(SceneRegistration),
    /// `p_robot = transform · (scale · p_human)`.
    Explicit {
        transform: Isometry3<f64>,
        scale: f64,
    },
}

impl Default for RegistrationSpec {
    fn default() -> Self {
        Self::Scene(SceneRegistration::default())
    }
}

impl RegistrationSpec {
    /// The same spec for a demonstration with `object` (explicit transforms ignore objects).
    pub fn for_object(&self, object: Option<HumanObject>) -> Self {
        match *self {
            Self::Scene(s) => Self::Scene(s.with_object(object)),
            e @ Self::Explicit { .. } => e,
        }
    }
}

/// What the default registration needs to know about the robot, in its base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotAnchor {
    /// Shoulder centre (where the first arm joint axes meet, or nearly).
    pub shoulder: Point3<f64>,
    /// Base forward and up axes.
    pub axes: BodyAxes,
    /// Largest shoulder-to-fingertip distance the robot reaches.
    pub reach: f64,
    /// Height of the robot's support plane (the table it stands on) along `axes.up`.
    pub support: f64,
    /// The wrist frame's pose when no joint moves it: a hand on a fixed base (hand-only system).
    /// Such a system registers each frame's fingertips relative to the subject's wrist, not the
    /// arm's transport ([`Registration::hand_frame`]).
    pub fixed_wrist: Option<Isometry3<f64>>,
}

/// How the subject's wrist frame sits in a robot hand's root frame for a hand-only system: the
/// human wrist's `x` (distal, towards the middle-finger knuckle) along the hand root's `z` (the
/// approach axis of every bundled hand: fingers point along `+z` when open), the human palmar
/// normal `z` along the root's `x`, and `y = z × x` along `−y`. A hand whose root frame follows
/// another convention is described by a descriptor whose wrist frame does (`wrist_frame`).
pub fn hand_alignment() -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(
        &[Vector3::z(), -Vector3::y(), Vector3::x()],
    )))
}

/// The human arm points registration looks at in one frame (tracker frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmPoints {
    pub shoulder: Point3<f64>,
    pub elbow: Point3<f64>,
    pub wrist: Point3<f64>,
    /// Middle fingertip: the end of the human reach.
    pub middle_tip: Point3<f64>,
}

/// A resolved registration:
/// `point(p) = robot_anchor + s_t · horizontal(R (p − human_anchor)) + s_v · vertical(R (p −
/// human_anchor))`, with horizontal/vertical relative to the robot's `up` axis; fingertips
/// `hand_point(p, w) = point(w) + hand_scale · R (p − w)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Registration {
    /// Subject axes → robot axes.
    pub rotation: UnitQuaternion<f64>,
    /// The human point the map is anchored at (the object's centre), tracker frame.
    pub human_anchor: Point3<f64>,
    /// Where it lands (the object's placement), robot base frame.
    pub robot_anchor: Point3<f64>,
    /// Robot up axis (unit).
    pub up: Vector3<f64>,
    pub transport_scale: f64,
    pub vertical_scale: f64,
    pub hand_scale: f64,
    /// The robot's support plane height along `up` (`None` for explicit transforms).
    pub support: Option<f64>,
    /// The registered object: its shape and robot-frame pose (`None` without an object).
    pub object: Option<HumanObject>,
    /// Hand-only systems: the robot wrist's pose composed with [`hand_alignment`]. Each frame's
    /// fingertips are then `hand_frame · hand_scale · (W⁻¹ p)` with `W` that frame's human wrist
    /// pose: the hand's grasp without the arm's transport ([`Self::hand_tip`]).
    pub hand_frame: Option<Isometry3<f64>>,
}

/// Human arm segments shorter than this (m) give the arm no direction.
const MIN_SEGMENT: f64 = 1e-3;

/// Objects may sink this far into their support before the placement counts as "under" it
/// (rounding of client-given heights).
pub const SUPPORT_TOLERANCE: f64 = 1e-3;

impl Registration {
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            human_anchor: Point3::origin(),
            robot_anchor: Point3::origin(),
            up: Vector3::z(),
            transport_scale: 1.0,
            vertical_scale: 1.0,
            hand_scale: 1.0,
            support: None,
            object: None,
            hand_frame: None,
        }
    }

    /// Resolves a spec against a demonstration's arm points and the robot.
    pub fn resolve(
        spec: &RegistrationSpec,
        frames: &[ArmPoints],
        robot: &RobotAnchor,
    ) -> Result<Self, MappingError> {
        let last = frames.last().ok_or(MappingError::EmptyDemonstration)?;
        for (i, f) in frames.iter().enumerate() {
            for (field, p) in [
                ("shoulder", f.shoulder),
                ("elbow", f.elbow),
                ("wrist", f.wrist),
                ("fingertips[2]", f.middle_tip),
            ] {
                if !p.coords.iter().all(|x| x.is_finite()) {
                    return Err(MappingError::NonFinite { frame: i, field });
                }
            }
        }
        if let Some(wrist) = robot.fixed_wrist {
            return Self::resolve_hand(spec, &wrist, robot);
        }
        // An arm system registers the arm and reads its elbow: a recording without one (a
        // keypoint stream of the hand alone stores the wrist there) cannot drive it.
        for (i, f) in frames.iter().enumerate() {
            for (segment, length) in [
                ("upper arm", (f.elbow - f.shoulder).norm()),
                ("forearm", (f.wrist - f.elbow).norm()),
            ] {
                if length < MIN_SEGMENT {
                    return Err(MappingError::DegenerateArm {
                        frame: i,
                        segment,
                        length,
                    });
                }
            }
        }
        match *spec {
            RegistrationSpec::Explicit { transform, scale } => {
                check_scale(scale)?;
                if !transform.translation.vector.iter().all(|x| x.is_finite())
                    || !transform.rotation.coords.iter().all(|x| x.is_finite())
                {
                    return Err(MappingError::InvalidRegistration {
                        reason: "explicit transform is not finite".into(),
                    });
                }
                Ok(Self {
                    rotation: transform.rotation,
                    human_anchor: Point3::origin(),
                    robot_anchor: Point3::from(transform.translation.vector),
                    up: robot_up(robot)?,
                    transport_scale: scale,
                    vertical_scale: scale,
                    hand_scale: scale,
                    support: None,
                    object: None,
                    hand_frame: None,
                })
            }
            RegistrationSpec::Scene(s) => {
                check_hand_scale(s.hand_scale)?;
                if !s.human_support.is_finite() {
                    return Err(MappingError::InvalidFactor {
                        field: "human_support",
                        value: s.human_support,
                    });
                }
                let h = axes_matrix(&s.subject_axes, "subject")?;
                let r = axes_matrix(&robot.axes, "robot")?;
                let rotation = UnitQuaternion::from_rotation_matrix(
                    &Rotation3::from_matrix_unchecked(r * h.transpose()),
                );
                let (up_h, up_r) = (h.column(2).into_owned(), r.column(2).into_owned());
                if !(robot.support.is_finite() && robot.reach.is_finite() && robot.reach > 0.0) {
                    return Err(MappingError::InvalidRegistration {
                        reason: format!(
                            "robot reach {} / support height {} are not usable",
                            robot.reach, robot.support
                        ),
                    });
                }
                let transport = match s.transport_scale {
                    Scale::One => 1.0,
                    Scale::Factor(f) => {
                        check_scale(f)?;
                        f
                    }
                    Scale::Auto => robot.reach / human_reach(frames)?,
                };
                let human_anchor = match &s.object {
                    Some(o) => {
                        let c = o.pose.translation.vector;
                        if !(c.iter().all(|x| x.is_finite())
                            && o.pose.rotation.coords.iter().all(|x| x.is_finite()))
                        {
                            return Err(MappingError::InvalidRegistration {
                                reason: "the demonstration's object pose is not finite".into(),
                            });
                        }
                        Point3::from(c)
                    }
                    None => last.wrist,
                };
                let below = s.object.map_or(0.0, |o| o.extent_below(&up_h));
                let robot_anchor = match s.placement {
                    Some(p) => {
                        if !p.coords.iter().all(|x| x.is_finite()) {
                            return Err(MappingError::InvalidPlacement {
                                reason: "placement must be finite".into(),
                            });
                        }
                        p
                    }
                    None => {
                        let n = frames.len() as f64;
                        let shoulder = Point3::from(
                            frames
                                .iter()
                                .fold(Vector3::zeros(), |acc, f| acc + f.shoulder.coords)
                                / n,
                        );
                        let u = rotation * (human_anchor - shoulder);
                        let x = robot.shoulder + horizontal(&u, &up_r) * transport;
                        let height = human_anchor.coords.dot(&up_h) - s.human_support;
                        x + up_r * (robot.support + height - x.coords.dot(&up_r))
                    }
                };
                let height = robot_anchor.coords.dot(&up_r) - robot.support;
                if height < below - SUPPORT_TOLERANCE {
                    return Err(MappingError::InvalidPlacement {
                        reason: format!(
                            "the object's centre is {height:.4} m above the robot's support but \
                             the object reaches {below:.4} m below its centre: it would be under \
                             its support"
                        ),
                    });
                }
                let distance = (robot_anchor - robot.shoulder).norm();
                if distance > robot.reach {
                    return Err(MappingError::InvalidPlacement {
                        reason: format!(
                            "the object's centre is {distance:.3} m from the robot's shoulder, \
                             beyond its reach of {:.3} m",
                            robot.reach
                        ),
                    });
                }
                let object = s.object.map(|o| HumanObject {
                    shape: o.shape,
                    pose: Isometry3::from_parts(
                        robot_anchor.coords.into(),
                        rotation * o.pose.rotation,
                    ),
                });
                Ok(Self {
                    rotation,
                    human_anchor,
                    robot_anchor,
                    up: up_r,
                    transport_scale: transport,
                    vertical_scale: 1.0,
                    hand_scale: s.hand_scale,
                    support: Some(robot.support),
                    object,
                    hand_frame: None,
                })
            }
        }
    }

    /// A hand on a fixed base: only the hand scale applies (the arm points, placement and
    /// transport scale have nothing to act on). No support or object is registered: the hand's
    /// scene is its own.
    fn resolve_hand(
        spec: &RegistrationSpec,
        wrist: &Isometry3<f64>,
        robot: &RobotAnchor,
    ) -> Result<Self, MappingError> {
        let RegistrationSpec::Scene(s) = spec else {
            return Err(MappingError::InvalidRegistration {
                reason: "a hand on a fixed base is registered relative to the subject's wrist; \
                         an explicit transform does not apply"
                    .into(),
            });
        };
        check_hand_scale(s.hand_scale)?;
        if s.placement.is_some() {
            return Err(MappingError::InvalidPlacement {
                reason: "a hand on a fixed base has no placement: its fingertips are registered \
                         relative to the subject's wrist"
                    .into(),
            });
        }
        let hand_frame =
            Isometry3::from_parts(wrist.translation, wrist.rotation * hand_alignment());
        Ok(Self {
            rotation: UnitQuaternion::identity(),
            human_anchor: Point3::origin(),
            robot_anchor: Point3::from(wrist.translation.vector),
            up: robot_up(robot)?,
            transport_scale: 1.0,
            vertical_scale: 1.0,
            hand_scale: s.hand_scale,
            support: None,
            object: None,
            hand_frame: Some(hand_frame),
        })
    }

    /// A fingertip pose of a hand-only registration: relative to the subject's wrist `wrist`,
    /// placed in the robot hand's root ([`Self::hand_frame`]). `None` for arm systems.
    #[inline]
    pub fn hand_tip(
        &self,
        tip: &Isometry3<f64>,
        wrist: &Isometry3<f64>,
    ) -> Option<(Point3<f64>, UnitQuaternion<f64>)> {
        let frame = self.hand_frame?;
        let local = wrist.inverse() * tip;
        let p = frame * Point3::from(local.translation.vector * self.hand_scale);
        Some((p, frame.rotation * local.rotation))
    }

    /// An arm point (shoulder, elbow, wrist) in the robot base frame.
    #[inline]
    pub fn point(&self, p: &Point3<f64>) -> Point3<f64> {
        let u = self.rotation * (p - self.human_anchor);
        let v = self.up * u.dot(&self.up);
        self.robot_anchor + (u - v) * self.transport_scale + v * self.vertical_scale
    }

    /// A hand point (a fingertip) in the robot base frame: rigid with the wrist `wrist` (human
    /// frame) up to `hand_scale`.
    #[inline]
    pub fn hand_point(&self, p: &Point3<f64>, wrist: &Point3<f64>) -> Point3<f64> {
        self.point(wrist) + self.rotation * (p - wrist) * self.hand_scale
    }

    /// A human orientation in the robot base frame (scales do not rotate).
    #[inline]
    pub fn orientation(&self, q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        self.rotation * q
    }
}

fn horizontal(u: &Vector3<f64>, up: &Vector3<f64>) -> Vector3<f64> {
    u - up * u.dot(up)
}

fn robot_up(robot: &RobotAnchor) -> Result<Vector3<f64>, MappingError> {
    Ok(axes_matrix(&robot.axes, "robot")?.column(2).into_owned())
}

/// The hand-size factor of either registration: positive and finite.
fn check_hand_scale(value: f64) -> Result<(), MappingError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(MappingError::InvalidFactor {
            field: "hand_scale",
            value,
        })
    }
}

fn check_scale(s: f64) -> Result<(), MappingError> {
    if s.is_finite() && s > 0.0 {
        Ok(())
    } else {
        Err(MappingError::InvalidScale { value: s })
    }
}

/// Columns: forward, left, up (orthonormalised; up is made orthogonal to forward).
fn axes_matrix(axes: &BodyAxes, which: &'static str) -> Result<Matrix3<f64>, MappingError> {
    let bad = || MappingError::InvalidRegistration {
        reason: format!("{which} forward and up axes must be finite, non-zero and not parallel"),
    };
    if !axes
        .forward
        .iter()
        .chain(axes.up.iter())
        .all(|x| x.is_finite())
    {
        return Err(bad());
    }
    let f = Unit::try_new(axes.forward, 1e-9).ok_or_else(bad)?;
    let u = Unit::try_new(
        axes.up - f.into_inner() * axes.up.dot(&f),
        1e-6 * axes.up.norm(),
    )
    .ok_or_else(bad)?;
    let l = u.cross(&f);
    Ok(Matrix3::from_columns(&[f.into_inner(), l, u.into_inner()]))
}

/// Median over frames of shoulder→elbow + elbow→wrist + wrist→middle tip: the arm's full reach,
/// robust to a few bad samples.
fn human_reach(frames: &[ArmPoints]) -> Result<f64, MappingError> {
    let mut lens: Vec<f64> = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let upper = (f.elbow - f.shoulder).norm();
        let fore = (f.wrist - f.elbow).norm();
        let hand = (f.middle_tip - f.wrist).norm();
        for (segment, length) in [("upper arm", upper), ("forearm", fore), ("hand", hand)] {
            if length < MIN_SEGMENT {
                return Err(MappingError::DegenerateArm {
                    frame: i,
                    segment,
                    length,
                });
            }
        }
        lens.push(upper + fore + hand);
    }
    lens.sort_by(f64::total_cmp);
    Ok(lens[lens.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seated subject's arm: shoulder 0.33 m above the table (tracker z = 0), the hand reaching
    /// towards `target`.
    fn arm(shoulder: Point3<f64>) -> ArmPoints {
        ArmPoints {
            shoulder,
            elbow: shoulder + Vector3::new(0.0, 0.0, -0.3),
            wrist: shoulder + Vector3::new(0.25, 0.0, -0.3),
            middle_tip: shoulder + Vector3::new(0.43, 0.0, -0.3),
        }
    }

    fn robot() -> RobotAnchor {
        RobotAnchor {
            shoulder: Point3::new(0.0, 0.0, 0.35),
            axes: BodyAxes::default(),
            reach: 1.46,
            support: 0.0,
            fixed_wrist: None,
        }
    }

    fn bottle_at(x: f64, y: f64) -> HumanObject {
        HumanObject {
            shape: ObjectShape::Cylinder {
                radius: 0.033,
                height: 0.21,
            },
            pose: Isometry3::translation(x, y, 0.105),
        }
    }

    fn scene(object: Option<HumanObject>) -> RegistrationSpec {
        RegistrationSpec::Scene(SceneRegistration::default().with_object(object))
    }

    #[test]
    fn default_rests_the_object_on_the_robot_table_in_front_of_its_shoulder() {
        // Subject shoulder at (−0.15, 0.1, 0.33); bottle 0.45 m ahead and 0.2 m left of it.
        let sh = Point3::new(-0.15, 0.1, 0.33);
        let frames = [arm(sh), arm(sh + Vector3::new(0.01, 0.0, 0.0))];
        let mean_sh = Point3::new(-0.145, 0.1, 0.33);
        let o = bottle_at(0.3, 0.3);
        let one = RegistrationSpec::Scene(SceneRegistration {
            transport_scale: Scale::One,
            ..SceneRegistration::default().with_object(Some(o))
        });
        let reg = Registration::resolve(&one, &frames, &robot()).unwrap();
        // Object: horizontally where it was relative to the mean shoulder, resting on z = 0.
        let want = Point3::new(0.0 + 0.3 - mean_sh.x, 0.3 - mean_sh.y, 0.105);
        assert!((reg.robot_anchor - want).norm() < 1e-12);
        let placed = reg.object.unwrap();
        assert!((placed.pose.translation.vector - want.coords).norm() < 1e-12);
        // The registered object touches the robot's table: lowest point at height 0.
        let lowest = placed.pose.translation.vector.z - placed.extent_below(&Vector3::z());
        assert!(lowest.abs() < 1e-12, "lowest point {lowest}");
        // The subject's table (z = 0) lands on the robot's (z = 0).
        for p in [Point3::new(0.7, -0.4, 0.0), Point3::new(-0.2, 0.5, 0.0)] {
            assert!(reg.point(&p).z.abs() < 1e-12);
        }
        // The mean shoulder lands horizontally on the robot shoulder, at its own table height.
        let s = reg.point(&mean_sh);
        assert!((s.xy() - robot().shoulder.xy()).norm() < 1e-12 && (s.z - 0.33).abs() < 1e-12);
    }

    #[test]
    fn a_given_placement_gets_the_object_and_the_arm_plane_keeps_its_orientation() {
        // Subject facing tracker +y: the registration is a yaw of −90°.
        let spec = RegistrationSpec::Scene(SceneRegistration {
            subject_axes: BodyAxes {
                forward: Vector3::y(),
                up: Vector3::z(),
            },
            placement: Some(Point3::new(0.5, -0.1, 0.105)),
            transport_scale: Scale::One,
            ..SceneRegistration::default().with_object(Some(bottle_at(0.1, 0.5)))
        });
        let frames = [arm(Point3::new(0.0, 0.0, 0.33))];
        let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
        assert!(
            (reg.point(&Point3::new(0.1, 0.5, 0.105)) - Point3::new(0.5, -0.1, 0.105)).norm()
                < 1e-12
        );
        // Shoulder→wrist: tracker +y forward is robot +x; the direction is rotated, not bent.
        let f = frames[0];
        let d_h = f.wrist - f.shoulder;
        let d_r = reg.point(&f.wrist) - reg.point(&f.shoulder);
        let want = Vector3::new(d_h.y, -d_h.x, d_h.z);
        assert!((d_r - want).norm() < 1e-12);
    }

    #[test]
    fn fingertips_keep_their_distance_to_the_wrist_unless_a_hand_scale_is_given() {
        let frames = [arm(Point3::new(-0.15, 0.0, 0.33))];
        let w = Point3::new(0.2, 0.0, 0.1);
        let tip = Point3::new(0.27, 0.05, 0.02);
        for (transport, hand) in [
            (Scale::One, 1.0),
            (Scale::Factor(1.6), 1.0),
            (Scale::Auto, 0.7),
        ] {
            let spec = RegistrationSpec::Scene(SceneRegistration {
                transport_scale: transport,
                hand_scale: hand,
                ..SceneRegistration::default().with_object(Some(bottle_at(0.3, 0.0)))
            });
            let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
            let d = (reg.hand_point(&tip, &w) - reg.point(&w)).norm();
            assert!(
                (d - hand * (tip - w).norm()).abs() < 1e-12,
                "{transport:?}: {d}"
            );
        }
    }

    #[test]
    fn transport_scale_stretches_horizontally_about_the_object_and_keeps_heights() {
        let frames = [arm(Point3::origin()); 3];
        let spec = RegistrationSpec::Scene(SceneRegistration {
            transport_scale: Scale::Auto,
            ..SceneRegistration::default().with_object(Some(bottle_at(0.4, 0.0)))
        });
        let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
        let s = 1.46 / (0.3 + 0.25 + 0.18);
        assert!((reg.transport_scale - s).abs() < 1e-12);
        let p = Point3::new(0.1, 0.2, 0.3);
        let q = reg.point(&p);
        let c = reg.robot_anchor;
        assert!((q.x - c.x - s * (0.1 - 0.4)).abs() < 1e-12);
        assert!((q.y - c.y - s * 0.2).abs() < 1e-12);
        assert!((q.z - 0.3).abs() < 1e-12);
    }

    #[test]
    fn explicit_transform_is_used_as_given() {
        let t = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.0, 0.0, 0.5));
        let spec = RegistrationSpec::Explicit {
            transform: t,
            scale: 0.5,
        };
        let reg = Registration::resolve(&spec, &[arm(Point3::origin())], &robot()).unwrap();
        let p = Point3::new(0.4, 0.1, -0.2);
        assert!((reg.point(&p) - t * Point3::from(p.coords * 0.5)).norm() < 1e-15);
        let w = Point3::new(0.1, 0.0, 0.0);
        assert!((reg.hand_point(&p, &w) - t * Point3::from(p.coords * 0.5)).norm() < 1e-15);
    }

    #[test]
    fn bad_placements_and_factors_are_rejected_with_the_reason() {
        let r = robot();
        let frames = [arm(Point3::new(-0.15, 0.0, 0.33))];
        let with = |placement: Option<Point3<f64>>, hand_scale: f64| {
            RegistrationSpec::Scene(SceneRegistration {
                placement,
                hand_scale,
                ..SceneRegistration::default().with_object(Some(bottle_at(0.3, 0.0)))
            })
        };
        // The bottle's centre must be 0.105 m above the table; 0.05 puts half of it under.
        let under =
            Registration::resolve(&with(Some(Point3::new(0.5, 0.0, 0.05)), 1.0), &frames, &r);
        assert!(
            matches!(&under, Err(MappingError::InvalidPlacement { reason }) if reason.contains("under")),
            "{under:?}"
        );
        let far =
            Registration::resolve(&with(Some(Point3::new(2.0, 0.0, 0.105)), 1.0), &frames, &r);
        assert!(
            matches!(&far, Err(MappingError::InvalidPlacement { reason }) if reason.contains("reach")),
            "{far:?}"
        );
        let nan = Registration::resolve(
            &with(Some(Point3::new(f64::NAN, 0.0, 0.1)), 1.0),
            &frames,
            &r,
        );
        assert!(matches!(nan, Err(MappingError::InvalidPlacement { .. })));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Registration::resolve(&with(None, bad), &frames, &r),
                Err(MappingError::InvalidFactor {
                    field: "hand_scale",
                    ..
                })
            ));
        }
        assert!(matches!(
            Registration::resolve(&scene(None), &[], &r),
            Err(MappingError::EmptyDemonstration)
        ));
        let mut f = arm(Point3::origin());
        f.elbow.y = f64::NAN;
        assert!(matches!(
            Registration::resolve(&scene(None), &[arm(Point3::origin()), f], &r),
            Err(MappingError::NonFinite {
                frame: 1,
                field: "elbow"
            })
        ));
        // The hand alone (a keypoint recording without the arm: elbow and shoulder on the
        // wrist): no arm system registers it, whatever the scale.
        let mut hand = arm(Point3::origin());
        (hand.elbow, hand.shoulder) = (hand.wrist, hand.wrist);
        let fixed = RegistrationSpec::Scene(SceneRegistration {
            transport_scale: Scale::One,
            ..SceneRegistration::default()
        });
        assert!(matches!(
            Registration::resolve(&fixed, &[hand], &r),
            Err(MappingError::DegenerateArm {
                frame: 0,
                segment: "upper arm",
                ..
            })
        ));
        let mut f = arm(Point3::origin());
        f.elbow = f.shoulder;
        let auto = RegistrationSpec::Scene(SceneRegistration {
            transport_scale: Scale::Auto,
            ..SceneRegistration::default()
        });
        assert!(matches!(
            Registration::resolve(&auto, &[f], &r),
            Err(MappingError::DegenerateArm {
                frame: 0,
                segment: "upper arm",
                ..
            })
        ));
        let parallel = RegistrationSpec::Scene(SceneRegistration {
            subject_axes: BodyAxes {
                forward: Vector3::z(),
                up: Vector3::z() * 3.0,
            },
            ..SceneRegistration::default()
        });
        assert!(matches!(
            Registration::resolve(&parallel, &[arm(Point3::origin())], &r),
            Err(MappingError::InvalidRegistration { .. })
        ));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let s = RegistrationSpec::Scene(SceneRegistration {
                transport_scale: Scale::Factor(bad),
                ..SceneRegistration::default()
            });
            assert!(matches!(
                Registration::resolve(&s, &[arm(Point3::origin())], &r),
                Err(MappingError::InvalidScale { .. })
            ));
        }
    }
}
