//! Arm-hand systems: one kinematic [`Model`] (arm + mount + hand, or one combined URDF) plus the
//! descriptor the planners need — finger chains and fingertip frames with contact-sphere radii,
//! the thumb, spread-ordering pairs (paper eq. 28) and the frames whose origins enter the
//! anthropomorphism term (eq. 4). Names are resolved to indices here, once.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::error::{KinematicsError, check_finite};
use super::model::{Actuation, FrameId, Model, ModelBuilder};
use super::urdf::{Attach, DirMeshes, MeshSource, append_robot, parse_urdf, read_text, root_link};

/// The descriptor as written in `robots/systems/*.toml` or posted as JSON. The names it uses
/// (frames, joints) must exist in the system's URDF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SystemDescriptor {
    /// Not blank.
    #[schema(pattern = r"\S")]
    pub name: String,
    /// Arm URDF path, relative to the descriptor file (files only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_urdf: Option<String>,
    /// Hand URDF path, relative to the descriptor file (files only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_urdf: Option<String>,
    /// One combined arm-with-hand URDF instead of `arm_urdf` + `hand_urdf` (files only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub urdf: Option<String>,
    /// Where the hand's root link attaches to the arm (required with a separate hand URDF).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mount: Option<Mount>,
    /// The frame where the arm ends and the hand begins; defaults to the hand URDF's root link
    /// (required for a combined URDF). Arm joints are those moving this frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrist_frame: Option<String>,
    /// The arm's shoulder centre (where a human shoulder is registered by default).
    pub shoulder_frame: String,
    /// At least one; names are unique.
    #[schema(min_items = 1)]
    pub fingers: Vec<FingerSpec>,
    /// Name of the finger that plays the thumb.
    pub thumb: String,
    /// Spread ordering, eq. 28: each `[a, b]` requires `value(a) <= value(b)`.
    #[serde(default)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub spread_pairs: Vec<[String; 2]>,
    /// Frames whose origins are the "robot joint positions" of eq. 4 (shoulder and end effector
    /// excluded).
    pub elbow_frames: Vec<String>,
}

/// Where the hand's root link attaches to the arm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Mount {
    /// Arm frame the hand is attached to (usually the flange).
    pub parent_frame: String,
    /// Translation, metres (default zero).
    #[serde(default)]
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub xyz: [f64; 3],
    /// Fixed-axis roll, pitch, yaw (URDF convention), radians (default zero).
    #[serde(default)]
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub rpy: [f64; 3],
}

/// One finger of the hand.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct FingerSpec {
    pub name: String,
    /// The finger's joints from palm to tip (mimic joints may be listed; they fold into drivers).
    #[schema(min_items = 1)]
    pub joints: Vec<String>,
    pub tip_frame: String,
    /// Radius of the fingertip contact sphere centred on the tip frame, metres.
    #[schema(exclusive_minimum = 0)]
    pub contact_radius: f64,
}

/// A finger with names resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct Finger {
    pub name: String,
    pub tip: FrameId,
    pub contact_radius: f64,
    /// Independent `q` indices of the finger's joints, palm to tip, without repetition.
    pub joints: Vec<usize>,
}

/// Eq. 28 with couplings resolved: `lower.multiplier*q[lower.q_index] + lower.offset <=
/// upper.multiplier*q[upper.q_index] + upper.offset`.
#[derive(Clone, Debug, PartialEq)]
pub struct SpreadPair {
    pub lower_joint: String,
    pub upper_joint: String,
    pub lower: Actuation,
    pub upper: Actuation,
}

/// An arm-hand system ready for the planners.
#[derive(Clone, Debug)]
pub struct System {
    pub name: String,
    pub model: Arc<Model>,
    /// Independent `q` indices moving the wrist frame (the arm), in `q` order.
    pub arm_joints: Vec<usize>,
    /// All other independent `q` indices (the hand), in `q` order.
    pub hand_joints: Vec<usize>,
    pub shoulder_frame: FrameId,
    pub wrist_frame: FrameId,
    pub fingers: Vec<Finger>,
    /// Index into `fingers`.
    pub thumb: usize,
    pub spread_pairs: Vec<SpreadPair>,
    pub elbow_frames: Vec<FrameId>,
    pub descriptor: SystemDescriptor,
}

/// The URDF text(s) behind a system: an arm and a separate hand, or one combined URDF.
pub enum UrdfSources<'a> {
    ArmAndHand { arm: &'a str, hand: &'a str },
    Combined(&'a str),
}

fn desc_err(field: impl Into<String>, reason: impl Into<String>) -> KinematicsError {
    KinematicsError::Descriptor {
        field: field.into(),
        reason: reason.into(),
    }
}

impl System {
    /// Loads `robots/systems/x.toml`-style descriptors; URDF and mesh paths resolve relative to
    /// the files that name them.
    pub fn from_file(path: &Path) -> Result<System, KinematicsError> {
        let text = read_text(path)?;
        let desc: SystemDescriptor = toml::from_str(&text)
            .map_err(|e| desc_err(path.display().to_string(), e.message().to_owned()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let load = |rel: &str| -> Result<(String, DirMeshes), KinematicsError> {
            let p = dir.join(rel);
            let text = read_text(&p)?;
            Ok((
                text,
                DirMeshes {
                    base: p.parent().unwrap_or(Path::new(".")).to_path_buf(),
                },
            ))
        };
        match (&desc.arm_urdf, &desc.hand_urdf, &desc.urdf) {
            (Some(a), Some(h), None) => {
                let (arm, arm_meshes) = load(a)?;
                let (hand, hand_meshes) = load(h)?;
                Self::build(
                    desc.clone(),
                    UrdfSources::ArmAndHand {
                        arm: &arm,
                        hand: &hand,
                    },
                    &arm_meshes,
                    &hand_meshes,
                )
            }
            (None, None, Some(c)) => {
                let (text, meshes) = load(c)?;
                Self::build(desc.clone(), UrdfSources::Combined(&text), &meshes, &meshes)
            }
            _ => Err(desc_err(
                "urdf",
                "give either arm_urdf and hand_urdf, or urdf (one combined file)",
            )),
        }
    }

    /// Builds a system from URDF texts (the API path). Path fields of the descriptor are ignored.
    pub fn from_sources(
        desc: SystemDescriptor,
        sources: UrdfSources<'_>,
        meshes: &dyn MeshSource,
    ) -> Result<System, KinematicsError> {
        Self::build(desc, sources, meshes, meshes)
    }

    fn build(
        desc: SystemDescriptor,
        sources: UrdfSources<'_>,
        arm_meshes: &dyn MeshSource,
        hand_meshes: &dyn MeshSource,
    ) -> Result<System, KinematicsError> {
        if desc.name.trim().is_empty() {
            return Err(desc_err("name", "must not be empty"));
        }
        let (model, default_wrist) = match sources {
            UrdfSources::ArmAndHand { arm, hand } => {
                let arm = parse_urdf(arm)?;
                let hand = parse_urdf(hand)?;
                let mount = desc.mount.as_ref().ok_or_else(|| {
                    desc_err("mount", "required when the hand is a separate URDF")
                })?;
                for (k, &v) in mount.xyz.iter().chain(mount.rpy.iter()).enumerate() {
                    check_finite(
                        || format!("mount.{}[{}]", if k < 3 { "xyz" } else { "rpy" }, k % 3),
                        v,
                    )?;
                }
                let origin = Isometry3::from_parts(
                    Translation3::new(mount.xyz[0], mount.xyz[1], mount.xyz[2]),
                    UnitQuaternion::from_euler_angles(mount.rpy[0], mount.rpy[1], mount.rpy[2]),
                );
                let mut b = ModelBuilder::new(&root_link(&arm)?);
                append_robot(&mut b, &arm, None, arm_meshes)?;
                let parent = b.frame_id(&mount.parent_frame).ok_or_else(|| {
                    KinematicsError::UnknownFrame {
                        field: "mount.parent_frame".into(),
                        name: mount.parent_frame.clone(),
                    }
                })?;
                let hand_root = root_link(&hand)?;
                append_robot(
                    &mut b,
                    &hand,
                    Some(Attach {
                        parent,
                        origin,
                        joint: "hand_mount_joint",
                    }),
                    hand_meshes,
                )?;
                (b.build()?, Some(hand_root))
            }
            UrdfSources::Combined(text) => {
                let robot = parse_urdf(text)?;
                let mut b = ModelBuilder::new(&root_link(&robot)?);
                append_robot(&mut b, &robot, None, arm_meshes)?;
                (b.build()?, None)
            }
        };
        let frame = |field: &str, name: &str| -> Result<FrameId, KinematicsError> {
            model
                .frame_id(name)
                .ok_or_else(|| KinematicsError::UnknownFrame {
                    field: field.into(),
                    name: name.into(),
                })
        };
        let moving = |field: &str, name: &str| -> Result<Actuation, KinematicsError> {
            model.joint(name).and_then(|j| j.actuation).ok_or_else(|| {
                KinematicsError::UnknownJointInDescriptor {
                    field: field.into(),
                    name: name.into(),
                }
            })
        };
        let wrist_name = desc
            .wrist_frame
            .clone()
            .or(default_wrist)
            .ok_or_else(|| desc_err("wrist_frame", "required for a combined URDF"))?;
        let wrist_frame = frame("wrist_frame", &wrist_name)?;
        let shoulder_frame = frame("shoulder_frame", &desc.shoulder_frame)?;
        let mut arm_joints = model.supporting_q(wrist_frame);
        arm_joints.sort_unstable();
        let hand_joints: Vec<usize> = (0..model.nq())
            .filter(|k| !arm_joints.contains(k))
            .collect();

        if desc.fingers.is_empty() {
            return Err(desc_err("fingers", "at least one finger is required"));
        }
        let mut names = HashSet::new();
        let mut fingers = Vec::with_capacity(desc.fingers.len());
        for (i, f) in desc.fingers.iter().enumerate() {
            let field = |s: &str| format!("fingers[{i}].{s}");
            if !names.insert(f.name.as_str()) {
                return Err(desc_err(
                    field("name"),
                    format!("finger '{}' is listed twice", f.name),
                ));
            }
            if f.joints.is_empty() {
                return Err(desc_err(
                    field("joints"),
                    "a finger needs at least one joint",
                ));
            }
            let mut joints = Vec::new();
            for j in &f.joints {
                let a = moving(&field("joints"), j)?;
                if arm_joints.contains(&a.q_index) {
                    return Err(desc_err(
                        field("joints"),
                        format!("joint '{j}' belongs to the arm, not the hand"),
                    ));
                }
                if !joints.contains(&a.q_index) {
                    joints.push(a.q_index);
                }
            }
            let tip = frame(&field("tip_frame"), &f.tip_frame)?;
            check_finite(|| field("contact_radius"), f.contact_radius)?;
            if f.contact_radius <= 0.0 {
                return Err(desc_err(
                    field("contact_radius"),
                    format!("must be positive, got {}", f.contact_radius),
                ));
            }
            fingers.push(Finger {
                name: f.name.clone(),
                tip,
                contact_radius: f.contact_radius,
                joints,
            });
        }
        let thumb = fingers
            .iter()
            .position(|f| f.name == desc.thumb)
            .ok_or_else(|| {
                desc_err(
                    "thumb",
                    format!("'{}' is not one of the fingers", desc.thumb),
                )
            })?;
        let mut spread_pairs = Vec::with_capacity(desc.spread_pairs.len());
        for (i, [a, b]) in desc.spread_pairs.iter().enumerate() {
            let field = format!("spread_pairs[{i}]");
            spread_pairs.push(SpreadPair {
                lower_joint: a.clone(),
                upper_joint: b.clone(),
                lower: moving(&field, a)?,
                upper: moving(&field, b)?,
            });
        }
        let elbow_frames = desc
            .elbow_frames
            .iter()
            .enumerate()
            .map(|(i, n)| frame(&format!("elbow_frames[{i}]"), n))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(System {
            name: desc.name.clone(),
            model: Arc::new(model),
            arm_joints,
            hand_joints,
            shoulder_frame,
            wrist_frame,
            fingers,
            thumb,
            spread_pairs,
            elbow_frames,
            descriptor: desc,
        })
    }
}
