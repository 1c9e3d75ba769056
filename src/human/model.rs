//! Kinematic description of the human arm (7 DoF) and hand (20 DoF in 15 joints), paper §II-B.
//!
//! Both are plain kinematic trees built with the robot library's [`ModelBuilder`], so the human
//! is evaluated by exactly the same forward kinematics as the robots.
//!
//! # Hand (root frame `wrist`, see the module documentation of [`crate::human`])
//!
//! Each finger is an independent serial chain from the wrist. All flexion joints turn about the
//! link's `-y` axis so that a positive angle moves the link's `x` (distal) axis towards its `z`
//! (palmar) axis; abduction joints turn about the palmar normal. Degrees of freedom, in the order of
//! the model's `q` and of the glove channels 0..20 ([`GLOVE_CHANNELS`]):
//!
//! | # | joint | axis (link frame, right hand) | range (deg) |
//! |---|-------|------|------|
//! | 0 | `thumb_cmc_abduction` (palmar abduction, CMC) | −y | −15 … 60 |
//! | 1 | `thumb_cmc_opposition` (axial rotation of the metacarpal, CMC) | −x | −20 … 80 |
//! | 2 | `thumb_mcp_flexion` | −y | −10 … 60 |
//! | 3 | `thumb_ip_flexion` | −y | −20 … 80 |
//! | 4+4k | `<f>_mcp_abduction` (f = index, middle, ring, little; k = 0..3) | −z (index, middle), +z (ring, little) | −20 … 20 (little −20 … 35) |
//! | 5+4k | `<f>_mcp_flexion` | −y | −30 … 90 |
//! | 6+4k | `<f>_pip_flexion` | −y | −5 … 110 |
//! | 7+4k | `<f>_dip_flexion` | −y | −10 … 90 |
//!
//! The CMC (2 DoF) and MCP (2 DoF) joints each count as one anatomical joint: 3 joints per finger,
//! 15 joints and 20 DoF in all. The glove's two further channels (20: `wrist_flexion`,
//! 21: `wrist_deviation`) belong to the arm model.
//!
//! Frames: `<f>_metacarpal` (thumb only), `<f>_proximal`, `<f>_middle` (not the thumb),
//! `<f>_distal`, and the fixed fingertip frame `<f>_tip` at the end of the distal phalanx with the
//! distal phalanx's orientation (`x` along the phalanx, `z` palmar).
//!
//! # Arm (root frame `thorax`, origin at the shoulder joint centre, `x` forward, `y` left, `z` up)
//!
//! | # | joint | axis (right arm) | range (deg) |
//! |---|-------|------|------|
//! | 0 | `shoulder_flexion` | −y | −50 … 180 |
//! | 1 | `shoulder_abduction` | −x | −30 … 180 |
//! | 2 | `shoulder_rotation` (internal positive) | +z of the upper arm | −90 … 90 |
//! | 3 | `elbow_flexion` | −y of the upper arm | 0 … 150 |
//! | 4 | `forearm_pronation` (pronation positive) | +z of the forearm | −90 … 90 |
//! | 5 | `wrist_flexion` (palmar flexion positive) | −y of the hand frame | −70 … 80 |
//! | 6 | `wrist_deviation` (ulnar positive) | +z of the hand frame | −20 … 35 |
//!
//! At zero the arm hangs along `−z` in the anatomical position (palm forward); frames
//! `upper_arm`, `forearm` (origin at the elbow), `hand` (origin at the wrist, oriented as the
//! wrist frame). A left arm or hand is the mirror image through the sagittal (`xz`) plane; joint
//! angles keep their anatomical meaning.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};

use super::anthropometry::{ArmDims, HandDims};
use super::demo::Handedness;
use crate::kinematics::{JointKind, JointLimits, Model, ModelBuilder};

/// Names of the five fingers, in the order of [`super::HumanFrame::fingertips`].
pub const FINGER_NAMES: [&str; 5] = ["thumb", "index", "middle", "ring", "little"];
/// Degrees of freedom of the hand model.
pub const HAND_DOF: usize = 20;
/// Arm joint names, in the order of the arm model's `q`.
pub const ARM_JOINTS: [&str; 7] = [
    "shoulder_flexion",
    "shoulder_abduction",
    "shoulder_rotation",
    "elbow_flexion",
    "forearm_pronation",
    "wrist_flexion",
    "wrist_deviation",
];

/// The 22 glove channels: the 20 hand DoF in model order, then wrist flexion and deviation.
pub const GLOVE_CHANNELS: [&str; 22] = [
    "thumb_cmc_abduction",
    "thumb_cmc_opposition",
    "thumb_mcp_flexion",
    "thumb_ip_flexion",
    "index_mcp_abduction",
    "index_mcp_flexion",
    "index_pip_flexion",
    "index_dip_flexion",
    "middle_mcp_abduction",
    "middle_mcp_flexion",
    "middle_pip_flexion",
    "middle_dip_flexion",
    "ring_mcp_abduction",
    "ring_mcp_flexion",
    "ring_pip_flexion",
    "ring_dip_flexion",
    "little_mcp_abduction",
    "little_mcp_flexion",
    "little_pip_flexion",
    "little_dip_flexion",
    "wrist_flexion",
    "wrist_deviation",
];

/// Rest roll of the thumb metacarpal about its long axis (pad turned towards the fingers), so
/// that `thumb_cmc_opposition = 0` is the relaxed thumb rather than a thumb lying in the palm plane.
const THUMB_REST_ROLL: f64 = -0.6;

/// One joint of a human model: revolute (`axis` is `Some`) or fixed.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSpec {
    pub name: String,
    pub parent: String,
    pub child: String,
    /// Placement of the joint frame in the parent frame (at zero angle).
    pub origin: Isometry3<f64>,
    /// Rotation axis in the joint frame; `None` for a fixed joint.
    pub axis: Option<Unit<Vector3<f64>>>,
    pub lower: f64,
    pub upper: f64,
}

fn deg(d: f64) -> f64 {
    d.to_radians()
}

fn revolute(
    name: String,
    parent: String,
    child: String,
    origin: Isometry3<f64>,
    axis: Vector3<f64>,
    range_deg: (f64, f64),
) -> JointSpec {
    JointSpec {
        name,
        parent,
        child,
        origin,
        axis: Some(Unit::new_normalize(axis)),
        lower: deg(range_deg.0),
        upper: deg(range_deg.1),
    }
}

fn fixed(name: String, parent: String, child: String, origin: Isometry3<f64>) -> JointSpec {
    JointSpec {
        name,
        parent,
        child,
        origin,
        axis: None,
        lower: 0.0,
        upper: 0.0,
    }
}

fn along_x(d: f64) -> Isometry3<f64> {
    Isometry3::translation(d, 0.0, 0.0)
}

/// The hand's joints (right-hand layout, mirrored for a left hand), in model (= glove) order,
/// fixed fingertip frames last in each chain.
pub fn hand_spec(dims: &HandDims, handedness: Handedness) -> Vec<JointSpec> {
    let mut j = Vec::with_capacity(20);
    let flex = -Vector3::y();
    let root = "wrist".to_string();
    // Thumb: CMC saddle (abduction then axial opposition), MCP, IP.
    let t = &dims.fingers[0];
    let base = Isometry3::from_parts(
        Translation3::from(t.base),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), t.splay),
    );
    j.push(revolute(
        "thumb_cmc_abduction".into(),
        root.clone(),
        "thumb_cmc".into(),
        base,
        flex,
        (-15.0, 60.0),
    ));
    j.push(revolute(
        "thumb_cmc_opposition".into(),
        "thumb_cmc".into(),
        "thumb_metacarpal".into(),
        Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), THUMB_REST_ROLL),
        ),
        -Vector3::x(),
        (-20.0, 80.0),
    ));
    j.push(revolute(
        "thumb_mcp_flexion".into(),
        "thumb_metacarpal".into(),
        "thumb_proximal".into(),
        along_x(t.phalanges[0]),
        flex,
        (-10.0, 60.0),
    ));
    j.push(revolute(
        "thumb_ip_flexion".into(),
        "thumb_proximal".into(),
        "thumb_distal".into(),
        along_x(t.phalanges[1]),
        flex,
        (-20.0, 80.0),
    ));
    j.push(fixed(
        "thumb_tip_joint".into(),
        "thumb_distal".into(),
        "thumb_tip".into(),
        along_x(t.phalanges[2]),
    ));
    for (k, f) in FINGER_NAMES.iter().enumerate().skip(1) {
        let d = &dims.fingers[k];
        // Abduction positive away from the hand's middle axis; the middle finger's positive
        // direction is radial, as the glove reports it.
        let abd_axis = if k <= 2 { -Vector3::z() } else { Vector3::z() };
        let abd_range = if k == 4 { (-20.0, 35.0) } else { (-20.0, 20.0) };
        let base = Isometry3::from_parts(
            Translation3::from(d.base),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), d.splay),
        );
        j.push(revolute(
            format!("{f}_mcp_abduction"),
            root.clone(),
            format!("{f}_mcp"),
            base,
            abd_axis,
            abd_range,
        ));
        j.push(revolute(
            format!("{f}_mcp_flexion"),
            format!("{f}_mcp"),
            format!("{f}_proximal"),
            Isometry3::identity(),
            flex,
            (-30.0, 90.0),
        ));
        j.push(revolute(
            format!("{f}_pip_flexion"),
            format!("{f}_proximal"),
            format!("{f}_middle"),
            along_x(d.phalanges[0]),
            flex,
            (-5.0, 110.0),
        ));
        j.push(revolute(
            format!("{f}_dip_flexion"),
            format!("{f}_middle"),
            format!("{f}_distal"),
            along_x(d.phalanges[1]),
            flex,
            (-10.0, 90.0),
        ));
        j.push(fixed(
            format!("{f}_tip_joint"),
            format!("{f}_distal"),
            format!("{f}_tip"),
            along_x(d.phalanges[2]),
        ));
    }
    if handedness == Handedness::Left {
        j.iter_mut().for_each(mirror);
    }
    j
}

/// The arm's joints (right-arm layout, mirrored for a left arm), in model order.
pub fn arm_spec(dims: &ArmDims, handedness: Handedness) -> Vec<JointSpec> {
    let id = Isometry3::identity();
    // At zero the hand frame has x distal (−z), z palmar (+x, palm forward), y = z × x = +y.
    let hand_rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[
        -Vector3::z(),
        Vector3::y(),
        Vector3::x(),
    ]));
    let mut j = vec![
        revolute(
            "shoulder_flexion".into(),
            "thorax".into(),
            "shoulder_1".into(),
            id,
            -Vector3::y(),
            (-50.0, 180.0),
        ),
        revolute(
            "shoulder_abduction".into(),
            "shoulder_1".into(),
            "shoulder_2".into(),
            id,
            -Vector3::x(),
            (-30.0, 180.0),
        ),
        revolute(
            "shoulder_rotation".into(),
            "shoulder_2".into(),
            "upper_arm".into(),
            id,
            Vector3::z(),
            (-90.0, 90.0),
        ),
        revolute(
            "elbow_flexion".into(),
            "upper_arm".into(),
            "forearm_1".into(),
            Isometry3::translation(0.0, 0.0, -dims.upper_arm),
            -Vector3::y(),
            (0.0, 150.0),
        ),
        revolute(
            "forearm_pronation".into(),
            "forearm_1".into(),
            "forearm".into(),
            id,
            Vector3::z(),
            (-90.0, 90.0),
        ),
        revolute(
            "wrist_flexion".into(),
            "forearm".into(),
            "wrist_1".into(),
            Isometry3::from_parts(
                Translation3::new(0.0, 0.0, -dims.forearm),
                UnitQuaternion::from_rotation_matrix(&hand_rot),
            ),
            // In the hand frame palmar flexion turns x (distal) towards z (palmar): axis −y.
            -Vector3::y(),
            (-70.0, 80.0),
        ),
        revolute(
            "wrist_deviation".into(),
            "wrist_1".into(),
            "hand".into(),
            id,
            // Ulnar deviation turns x towards y (ulnar side of a right hand): axis +z.
            Vector3::z(),
            (-20.0, 35.0),
        ),
    ];
    if handedness == Handedness::Left {
        j.iter_mut().for_each(mirror);
    }
    j
}

/// Mirror a joint through the sagittal (`xz`) plane, keeping the anatomical sense of its angle:
/// with `M = diag(1, −1, 1)`, `M R(a, θ) M = R(−M a, θ)`, so axes map to `−M a`, placements to
/// `M T M`.
fn mirror(j: &mut JointSpec) {
    let m = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0));
    let r = m * j.origin.rotation.to_rotation_matrix().into_inner() * m;
    let p = m * j.origin.translation.vector;
    j.origin = Isometry3::from_parts(
        Translation3::from(p),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    if let Some(a) = j.axis {
        j.axis = Some(Unit::new_normalize(-(m * a.into_inner())));
    }
}

fn build(root: &str, spec: &[JointSpec]) -> Model {
    let mut b = ModelBuilder::new(root);
    for j in spec {
        let parent = b
            .frame_id(&j.parent)
            .expect("specs list parents before children");
        let kind = match j.axis {
            Some(axis) => JointKind::Revolute { axis },
            None => JointKind::Fixed,
        };
        // Human joints carry no velocity or effort limits: the model is only evaluated, not driven.
        let limits = JointLimits::new(j.lower, j.upper, f64::INFINITY, f64::INFINITY);
        b.add_joint(&j.name, parent, &j.child, kind, j.origin, limits, None)
            .expect("the human specs are well-formed");
    }
    b.build().expect("the human specs are well-formed")
}

/// The 20-DoF hand model for these dimensions; its `q` order is glove channels 0..20.
pub fn hand_model(dims: &HandDims, handedness: Handedness) -> Model {
    build("wrist", &hand_spec(dims, handedness))
}

/// The 7-DoF arm model for these dimensions; its `q` order is [`ARM_JOINTS`].
pub fn arm_model(dims: &ArmDims, handedness: Handedness) -> Model {
    build("thorax", &arm_spec(dims, handedness))
}
