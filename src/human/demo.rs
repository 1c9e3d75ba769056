//! The demonstration format (paper §II-A, §II-D) and the ingest path: validate the two sensor
//! streams, put them on one clock, resample to a common rate and derive the human kinematics.
//!
//! Canonical JSON (angles in radians, lengths in metres, time in seconds, quaternions
//! `[w, x, y, z]`):
//!
//! ```json
//! {
//!   "subject": {"id": "S1", "stature_m": 1.75, "hand_length_m": 0.19, "hand_breadth_m": 0.086,
//!               "handedness": "right"},
//!   "object": {"name": "bottle", "shape": {"type": "cylinder", "radius": 0.035, "height": 0.22},
//!              "pose": {"position": [0.35, 0.0, 0.11], "orientation": [1, 0, 0, 0]}},
//!   "labels": {"task": "grasp", "position_index": 2, "trial": 7, "synthetic": false,
//!              "external_id": "lab-2024-S1-bottle-2-7"},
//!   "tracker": {"t": [..], "shoulder": [[x, y, z], ..], "elbow": [..], "wrist": [..],
//!               "wrist_orientation": [[w, x, y, z], ..]},
//!   "glove": {"t": [..], "angles": [[22 values], ..]},
//!   "sync": {"glove_offset_s": 0.0, "rate_hz": 120.0, "max_gap_s": 0.1}
//! }
//! ```
//!
//! Instead of `angles` the glove may carry `raw` sensor values plus
//! `"calibration": {"gain": [22], "offset": [22]}`; then `angle = gain · raw + offset`.
//! Channel order: [`GLOVE_CHANNELS`].
//!
//! Clock: the tracker's. Glove time on that clock is `t + sync.glove_offset_s`. Frames are put at
//! `start + k / rate_hz` over the interval both streams cover; positions and angles are
//! interpolated linearly, the wrist orientation by slerp.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::HumanFrame;
use super::anthropometry::{ArmDims, HandDims, check_range};
use super::derive::HandKinematics;
use super::error::HumanError;
use super::model::GLOVE_CHANNELS;
use super::resample::{Cursor, lerp, slerp};

/// Positions farther than this from the tracker origin are outside any magnetic tracker's range.
pub const MAX_POSITION_M: f64 = 3.0;
/// Quaternions with a norm below this cannot be normalised meaningfully.
pub const MIN_QUATERNION_NORM: f64 = 1e-6;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Handedness {
    #[default]
    Right,
    Left,
}

/// The demonstrating person: id and the anthropometry the model is scaled by (within the
/// ranges the parametric hand and arm models are defined for).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Subject {
    pub id: String,
    /// Stature, m (default 1.72).
    #[serde(default = "default_stature")]
    #[schema(minimum = 1.0, maximum = 2.3)]
    pub stature_m: f64,
    /// Wrist crease to the tip of the middle finger, m (default 0.185).
    #[serde(default = "default_hand_length")]
    #[schema(minimum = 0.10, maximum = 0.30)]
    pub hand_length_m: f64,
    /// Across the metacarpal heads, m (default 0.085).
    #[serde(default = "default_hand_breadth")]
    #[schema(minimum = 0.04, maximum = 0.15)]
    pub hand_breadth_m: f64,
    /// Default `right`.
    #[serde(default)]
    pub handedness: Handedness,
}

fn default_stature() -> f64 {
    super::anthropometry::DEFAULT_STATURE_M
}
fn default_hand_length() -> f64 {
    super::anthropometry::DEFAULT_HAND_LENGTH_M
}
fn default_hand_breadth() -> f64 {
    super::anthropometry::DEFAULT_HAND_BREADTH_M
}

impl Subject {
    /// An average adult (the anthropometry defaults), right-handed.
    pub fn average(id: impl Into<String>) -> Self {
        Self {
            id: id.into(),
            stature_m: default_stature(),
            hand_length_m: default_hand_length(),
            hand_breadth_m: default_hand_breadth(),
            handedness: Handedness::Right,
        }
    }
    pub fn hand_dims(&self) -> Result<HandDims, HumanError> {
        HandDims::from_measurements(self.hand_length_m, self.hand_breadth_m)
    }
    pub fn arm_dims(&self) -> Result<ArmDims, HumanError> {
        ArmDims::from_stature(self.stature_m)
    }
}

/// Object geometry in its own frame (cylinder and capsule axes along `z`, centred at the origin).
/// Every length is 0.0001 to 2 m.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, utoipa::ToSchema)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ObjectShape {
    Sphere {
        #[schema(minimum = 0.0001, maximum = 2.0)]
        radius: f64,
    },
    Cylinder {
        #[schema(minimum = 0.0001, maximum = 2.0)]
        radius: f64,
        #[schema(minimum = 0.0001, maximum = 2.0)]
        height: f64,
    },
    /// Full edge lengths along x, y, z.
    Box {
        #[schema(min_items = 3, max_items = 3)]
        size: [f64; 3],
    },
    Capsule {
        #[schema(minimum = 0.0001, maximum = 2.0)]
        radius: f64,
        #[schema(minimum = 0.0001, maximum = 2.0)]
        height: f64,
    },
}

/// Read through [`ObjectShapeWire`] so that a bad field names its own path
/// (`$.object.shape.radius`): a derived internally tagged enum is buffered and its errors stop
/// at `$.object.shape`.
impl<'de> Deserialize<'de> for ObjectShape {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::wire::tagged(d, "type", "a shape object with a `type`").map(ObjectShapeWire::into)
    }
}

/// [`ObjectShape`] externally tagged (`{"sphere": {"radius": 0.1}}`), as
/// [`crate::wire::tagged`] reads it.
#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum ObjectShapeWire {
    Sphere {
        radius: f64,
    },
    Cylinder {
        radius: f64,
        height: f64,
    },
    Box {
        #[serde(deserialize_with = "crate::wire::exact")]
        size: [f64; 3],
    },
    Capsule {
        radius: f64,
        height: f64,
    },
}

impl From<ObjectShapeWire> for ObjectShape {
    fn from(w: ObjectShapeWire) -> Self {
        match w {
            ObjectShapeWire::Sphere { radius } => ObjectShape::Sphere { radius },
            ObjectShapeWire::Cylinder { radius, height } => {
                ObjectShape::Cylinder { radius, height }
            }
            ObjectShapeWire::Box { size } => ObjectShape::Box { size },
            ObjectShapeWire::Capsule { radius, height } => ObjectShape::Capsule { radius, height },
        }
    }
}

impl ObjectShape {
    /// Signed distance from a point in the object frame to the surface (negative inside).
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        match *self {
            Self::Sphere { radius } => p.norm() - radius,
            Self::Cylinder { radius, height } => {
                let dr = p.xy().norm() - radius;
                let dz = p.z.abs() - 0.5 * height;
                let outside = (dr.max(0.0).powi(2) + dz.max(0.0).powi(2)).sqrt();
                outside + dr.max(dz).min(0.0)
            }
            Self::Box { size } => {
                let q = Vector3::new(
                    p.x.abs() - 0.5 * size[0],
                    p.y.abs() - 0.5 * size[1],
                    p.z.abs() - 0.5 * size[2],
                );
                q.map(|v| v.max(0.0)).norm() + q.x.max(q.y).max(q.z).min(0.0)
            }
            Self::Capsule { radius, height } => {
                let z = p.z.clamp(-0.5 * height, 0.5 * height);
                (p - Vector3::new(0.0, 0.0, z)).norm() - radius
            }
        }
    }

    /// The smallest width across the object that a hand would span (grasp size).
    pub fn grasp_width(&self) -> f64 {
        match *self {
            Self::Sphere { radius }
            | Self::Cylinder { radius, .. }
            | Self::Capsule { radius, .. } => 2.0 * radius,
            Self::Box { size } => size[0].min(size[1]).min(size[2]),
        }
    }

    fn validate(&self) -> Result<(), HumanError> {
        let dims: Vec<(&str, f64)> = match *self {
            Self::Sphere { radius } => vec![("object.shape.radius", radius)],
            Self::Cylinder { radius, height } | Self::Capsule { radius, height } => {
                vec![
                    ("object.shape.radius", radius),
                    ("object.shape.height", height),
                ]
            }
            Self::Box { size } => vec![
                ("object.shape.size[0]", size[0]),
                ("object.shape.size[1]", size[1]),
                ("object.shape.size[2]", size[2]),
            ],
        };
        for (field, v) in dims {
            check_range(field, v, 1e-4, 2.0)?;
        }
        Ok(())
    }
}

/// A pose in the tracker frame: position (m, each coordinate within the tracker's 3 m) and
/// orientation quaternion `[w, x, y, z]` (not zero; normalised on ingest).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = DemoPose)]
pub struct Pose {
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub position: [f64; 3],
    #[schema(min_items = 4, max_items = 4)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub orientation: [f64; 4],
}

impl Default for Pose {
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            orientation: [1.0, 0.0, 0.0, 0.0],
        }
    }
}

impl Pose {
    pub fn from_isometry(iso: &Isometry3<f64>) -> Self {
        let q = iso.rotation.quaternion();
        let p = iso.translation.vector;
        Self {
            position: [p.x, p.y, p.z],
            orientation: [q.w, q.i, q.j, q.k],
        }
    }
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let [w, x, y, z] = self.orientation;
        Isometry3::from_parts(
            Translation3::new(self.position[0], self.position[1], self.position[2]),
            UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
        )
    }
}

/// The grasped object of a demonstration, in the tracker frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = DemoObject)]
pub struct ObjectSpec {
    /// What the object is (`ball`, `bottle`, ...); a free label.
    pub name: String,
    pub shape: ObjectShape,
    /// Default: at the tracker origin, identity orientation.
    #[serde(default)]
    pub pose: Pose,
}

/// What the trial was (the study design's labels).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Labels {
    /// Default `grasp`.
    #[serde(default = "default_task")]
    pub task: String,
    /// Default 0.
    #[serde(default)]
    pub position_index: u32,
    /// Default 0.
    #[serde(default)]
    pub trial: u32,
    /// Default false.
    #[serde(default)]
    pub synthetic: bool,
    /// Client-chosen id; a re-upload with the same id returns the existing record.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub external_id: Option<String>,
}

fn default_task() -> String {
    "grasp".to_string()
}

/// The magnetic tracker stream: one row per sample in each column, as many rows as `t` has;
/// positions `[x, y, z]` within 3 m of the tracker's origin, orientations `[w, x, y, z]`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TrackerStream {
    /// Sample times, s, strictly increasing.
    pub t: Vec<f64>,
    pub shoulder: Vec<Vec<f64>>,
    pub elbow: Vec<Vec<f64>>,
    pub wrist: Vec<Vec<f64>>,
    /// Wrist frame orientation `[w, x, y, z]`.
    pub wrist_orientation: Vec<Vec<f64>>,
}

/// Per-channel linear calibration of raw glove values: `angle = gain · raw + offset` (radians).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GloveCalibration {
    /// One per glove channel, in the channel order of the glove format.
    #[schema(min_items = 22, max_items = 22)]
    pub gain: Vec<f64>,
    #[schema(min_items = 22, max_items = 22)]
    pub offset: Vec<f64>,
}

/// The data-glove stream: calibrated `angles` (radians), or `raw` values with a `calibration`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GloveStream {
    /// Sample times on the glove's clock, s, strictly increasing.
    pub t: Vec<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angles: Option<Vec<Vec<f64>>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw: Option<Vec<Vec<f64>>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<GloveCalibration>,
}

/// Clock alignment and resampling settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SyncOptions {
    /// Added to glove timestamps to put them on the tracker's clock, seconds (default 0).
    #[serde(default)]
    #[schema(minimum = -3600.0, maximum = 3600.0)]
    pub glove_offset_s: f64,
    /// Common output rate, Hz (default 120).
    #[serde(default = "default_rate")]
    #[schema(minimum = 1.0, maximum = 1000.0)]
    pub rate_hz: f64,
    /// Largest accepted gap between consecutive samples of a stream, seconds (default 0.1).
    #[serde(default = "default_max_gap")]
    #[schema(minimum = 0.0001, maximum = 60.0)]
    pub max_gap_s: f64,
}

fn default_rate() -> f64 {
    120.0
}
fn default_max_gap() -> f64 {
    0.1
}

impl Default for SyncOptions {
    fn default() -> Self {
        Self {
            glove_offset_s: 0.0,
            rate_hz: default_rate(),
            max_gap_s: default_max_gap(),
        }
    }
}

/// A hand keypoint recording (issue 22): per sample the 21 keypoints in the MANO / MediaPipe
/// order ([`super::KEYPOINT_NAMES`]); optionally the elbow and shoulder centres and the wrist
/// frame's orientation (otherwise derived from the palm keypoints, see [`super::keypoints`]).
/// Positions in metres, within 10 m of the recording's origin; one row per `t` in every column.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct KeypointStream {
    /// Sample times, s, strictly increasing.
    pub t: Vec<f64>,
    /// Per sample, 21 points `[x, y, z]`.
    pub points: Vec<Vec<Vec<f64>>>,
    /// Per sample `[w, x, y, z]` (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrist_orientation: Option<Vec<Vec<f64>>>,
    /// Per sample `[x, y, z]`, both or neither: the arm's transport and elbow terms read them.
    /// A recording without them (the hand alone; its frames store the wrist position there)
    /// maps only onto a hand on a fixed base.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elbow: Option<Vec<Vec<f64>>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shoulder: Option<Vec<Vec<f64>>>,
}

/// What a client uploads (or the synthetic generator emits): a tracker and data-glove
/// recording, or a keypoint recording (`keypoints`, with `tracker` and `glove` left out).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemonstrationInput {
    pub subject: Subject,
    pub object: ObjectSpec,
    pub labels: Labels,
    #[serde(default)]
    pub tracker: TrackerStream,
    #[serde(default)]
    pub glove: GloveStream,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keypoints: Option<KeypointStream>,
    #[serde(default)]
    pub sync: SyncOptions,
}

/// Key figures of an ingested demonstration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IngestSummary {
    /// Time of the first frame on the tracker clock, seconds.
    pub start_s: f64,
    pub duration_s: f64,
    pub frames: usize,
    pub rate_hz: f64,
    pub tracker_samples: usize,
    pub glove_samples: usize,
    /// Mean sampling rates of the raw streams.
    pub tracker_rate_hz: f64,
    pub glove_rate_hz: f64,
    /// `tracker_glove`, or `keypoints` (then `tracker_*` count the keypoint samples and the
    /// glove figures are 0: there are no glove angles).
    #[serde(default)]
    pub source: Source,
    /// Whether the frames carry the subject's elbow and shoulder (false for a keypoint recording
    /// of the hand alone, which maps only onto a hand on a fixed base).
    #[serde(default = "yes")]
    pub arm: bool,
}

fn yes() -> bool {
    true
}

/// Where a demonstration's hand comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// A magnetic tracker and a data glove (the paper's set-up).
    #[default]
    TrackerGlove,
    /// Hand keypoints (camera, headset, motion-capture suit).
    Keypoints,
}

/// An ingested demonstration: metadata plus derived kinematics on the common clock.
#[derive(Debug, Clone, PartialEq)]
pub struct Demonstration {
    pub subject: Subject,
    pub object: ObjectSpec,
    pub labels: Labels,
    pub summary: IngestSummary,
    pub frames: Vec<HumanFrame>,
    /// Resampled calibrated glove angles per frame ([`GLOVE_CHANNELS`] order), radians.
    pub glove: Vec<[f64; 22]>,
}

/// Validated tracker sample arrays.
struct Tracker {
    t: Vec<f64>,
    shoulder: Vec<Vector3<f64>>,
    elbow: Vec<Vector3<f64>>,
    wrist: Vec<Vector3<f64>>,
    orientation: Vec<UnitQuaternion<f64>>,
}

fn check_times(stream: &'static str, t: &[f64], max_gap: f64) -> Result<(), HumanError> {
    if t.is_empty() {
        return Err(HumanError::EmptyStream { stream });
    }
    for (i, &ti) in t.iter().enumerate() {
        if !ti.is_finite() {
            return Err(HumanError::NonFinite {
                stream,
                index: i,
                field: "t".into(),
                value: ti,
            });
        }
        if i > 0 {
            let prev = t[i - 1];
            if ti <= prev {
                return Err(HumanError::NotIncreasing {
                    stream,
                    index: i,
                    previous: prev,
                    t: ti,
                });
            }
            if ti - prev > max_gap {
                return Err(HumanError::Gap {
                    stream,
                    index: i,
                    gap: ti - prev,
                    limit: max_gap,
                });
            }
        }
    }
    Ok(())
}

fn check_len(stream: &'static str, field: &str, n: usize, got: usize) -> Result<(), HumanError> {
    if n != got {
        return Err(HumanError::LengthMismatch {
            stream,
            field: field.into(),
            expected: n,
            got,
        });
    }
    Ok(())
}

fn row<'a>(
    stream: &'static str,
    field: &str,
    index: usize,
    values: &'a [f64],
    width: usize,
) -> Result<&'a [f64], HumanError> {
    if values.len() != width {
        return Err(HumanError::WrongWidth {
            stream,
            index,
            field: field.into(),
            expected: width,
            got: values.len(),
        });
    }
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(HumanError::NonFinite {
            stream,
            index,
            field: format!("{field}[{k}]"),
            value: values[k],
        });
    }
    Ok(values)
}

fn position(field: &str, index: usize, values: &[f64]) -> Result<Vector3<f64>, HumanError> {
    let v = row("tracker", field, index, values, 3)?;
    let p = Vector3::new(v[0], v[1], v[2]);
    let d = p.norm();
    if d > MAX_POSITION_M {
        return Err(HumanError::PositionOutOfRange {
            stream: "tracker",
            index,
            field: field.into(),
            distance: d,
            limit: MAX_POSITION_M,
        });
    }
    Ok(p)
}

/// A sample's quaternion `[w, x, y, z]`, normalised (a zero one is an error naming it).
fn orientation(
    stream: &'static str,
    field: &str,
    index: usize,
    values: &[f64],
) -> Result<UnitQuaternion<f64>, HumanError> {
    let q = row(stream, field, index, values, 4)?;
    let quat = Quaternion::new(q[0], q[1], q[2], q[3]);
    let norm = quat.norm();
    if norm < MIN_QUATERNION_NORM {
        return Err(HumanError::DegenerateQuaternion {
            stream,
            index,
            field: field.into(),
            norm,
        });
    }
    Ok(UnitQuaternion::from_quaternion(quat))
}

fn validate_tracker(s: &TrackerStream, max_gap: f64) -> Result<Tracker, HumanError> {
    const STREAM: &str = "tracker";
    check_times(STREAM, &s.t, max_gap)?;
    let n = s.t.len();
    check_len(STREAM, "shoulder", n, s.shoulder.len())?;
    check_len(STREAM, "elbow", n, s.elbow.len())?;
    check_len(STREAM, "wrist", n, s.wrist.len())?;
    check_len(STREAM, "wrist_orientation", n, s.wrist_orientation.len())?;
    let mut out = Tracker {
        t: s.t.clone(),
        shoulder: Vec::with_capacity(n),
        elbow: Vec::with_capacity(n),
        wrist: Vec::with_capacity(n),
        orientation: Vec::with_capacity(n),
    };
    for i in 0..n {
        out.shoulder.push(position("shoulder", i, &s.shoulder[i])?);
        out.elbow.push(position("elbow", i, &s.elbow[i])?);
        out.wrist.push(position("wrist", i, &s.wrist[i])?);
        out.orientation.push(orientation(
            STREAM,
            "wrist_orientation",
            i,
            &s.wrist_orientation[i],
        )?);
    }
    Ok(out)
}

/// Validated, calibrated glove angles as a flat row-major `n × 22` array.
fn validate_glove(s: &GloveStream, max_gap: f64) -> Result<Vec<[f64; 22]>, HumanError> {
    const STREAM: &str = "glove";
    check_times(STREAM, &s.t, max_gap)?;
    let n = s.t.len();
    let (values, field, cal) = match (&s.angles, &s.raw, &s.calibration) {
        (Some(a), None, None) => (a, "angles", None),
        (None, Some(r), Some(c)) => {
            for (name, v) in [
                ("calibration.gain", &c.gain),
                ("calibration.offset", &c.offset),
            ] {
                if v.len() != 22 {
                    return Err(HumanError::LengthMismatch {
                        stream: STREAM,
                        field: name.into(),
                        expected: 22,
                        got: v.len(),
                    });
                }
                if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                    return Err(HumanError::InvalidParameter {
                        field: format!("glove.{name}[{k}]"),
                        value: v[k],
                        reason: "not a finite number",
                    });
                }
            }
            (r, "raw", Some(c))
        }
        _ => {
            return Err(HumanError::InvalidParameter {
                field: "glove.angles".into(),
                value: f64::NAN,
                reason: "the glove stream needs either `angles`, or `raw` together with \
                         `calibration`",
            });
        }
    };
    check_len(STREAM, field, n, values.len())?;
    let mut out = Vec::with_capacity(n);
    for (i, r) in values.iter().enumerate() {
        let v = row(STREAM, field, i, r, 22)?;
        let mut a = [0.0; 22];
        for k in 0..22 {
            a[k] = match cal {
                Some(c) => c.gain[k] * v[k] + c.offset[k],
                None => v[k],
            };
            if a[k].abs() > std::f64::consts::PI {
                return Err(HumanError::AngleOutOfRange {
                    stream: STREAM,
                    index: i,
                    field: format!("{field}[{k}] ({})", GLOVE_CHANNELS[k]),
                    value: a[k],
                });
            }
        }
        out.push(a);
    }
    Ok(out)
}

fn validate_sync(s: &SyncOptions) -> Result<(), HumanError> {
    check_range("sync.rate_hz", s.rate_hz, 1.0, 1000.0)?;
    check_range("sync.max_gap_s", s.max_gap_s, 1e-4, 60.0)?;
    check_range("sync.glove_offset_s", s.glove_offset_s, -3600.0, 3600.0)?;
    Ok(())
}

fn validate_object(o: &ObjectSpec) -> Result<(), HumanError> {
    o.shape.validate()?;
    for (k, v) in o.pose.position.iter().enumerate() {
        check_range(
            &format!("object.pose.position[{k}]"),
            *v,
            -MAX_POSITION_M,
            MAX_POSITION_M,
        )?;
    }
    let q = o.pose.orientation;
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm.is_finite() && norm >= MIN_QUATERNION_NORM) {
        return Err(HumanError::InvalidParameter {
            field: "object.pose.orientation".into(),
            value: norm,
            reason: "quaternion norm is zero or not finite; cannot be normalised",
        });
    }
    Ok(())
}

/// Frames on the grid `start + k·dt` within `[start, end]` (none when `end ≤ start`), with a
/// hair of tolerance so that an end exactly on the grid is kept despite rounding.
fn grid_frames(start: f64, end: f64, dt: f64) -> usize {
    if end > start {
        ((end - start) / dt + 1e-9).floor() as usize + 1
    } else {
        0
    }
}

fn mean_rate(t: &[f64]) -> f64 {
    if t.len() < 2 {
        0.0
    } else {
        (t.len() - 1) as f64 / (t[t.len() - 1] - t[0])
    }
}

/// Validate a demonstration, align and resample its streams, and derive the human kinematics of
/// every frame (the one ingest path for uploads, CSV and synthetic data).
pub fn ingest(input: &DemonstrationInput) -> Result<Demonstration, HumanError> {
    if let Some(k) = &input.keypoints {
        return ingest_keypoints(input, k);
    }
    let hand = input.subject.hand_dims()?;
    input.subject.arm_dims()?;
    validate_object(&input.object)?;
    validate_sync(&input.sync)?;
    let tracker = validate_tracker(&input.tracker, input.sync.max_gap_s)?;
    let glove = validate_glove(&input.glove, input.sync.max_gap_s)?;
    let off = input.sync.glove_offset_s;
    let gt: Vec<f64> = input.glove.t.iter().map(|t| t + off).collect();

    let (t0, t1) = (tracker.t[0], tracker.t[tracker.t.len() - 1]);
    let (g0, g1) = (gt[0], gt[gt.len() - 1]);
    let start = t0.max(g0);
    let end = t1.min(g1);
    let dt = 1.0 / input.sync.rate_hz;
    let n = grid_frames(start, end, dt);
    if n < 2 {
        return Err(HumanError::NoOverlap {
            tracker_start: t0,
            tracker_end: t1,
            glove_start: g0,
            glove_end: g1,
        });
    }

    let mut kin = HandKinematics::new(&hand, input.subject.handedness);
    let mut frames = Vec::with_capacity(n);
    let mut angles = Vec::with_capacity(n);
    let mut tc = Cursor::default();
    let mut gc = Cursor::default();
    for k in 0..n {
        let t = (start + k as f64 * dt).min(end);
        let (i, a) = tc.locate(&tracker.t, t);
        let j = (i + 1).min(tracker.t.len() - 1);
        let shoulder = lerp(&tracker.shoulder[i], &tracker.shoulder[j], a);
        let elbow = lerp(&tracker.elbow[i], &tracker.elbow[j], a);
        let wp = lerp(&tracker.wrist[i], &tracker.wrist[j], a);
        let wq = slerp(&tracker.orientation[i], &tracker.orientation[j], a);
        let wrist = Isometry3::from_parts(Translation3::from(wp), wq);

        let (gi, ga) = gc.locate(&gt, t);
        let gj = (gi + 1).min(gt.len() - 1);
        let mut g = [0.0; 22];
        for c in 0..22 {
            g[c] = glove[gi][c] + ga * (glove[gj][c] - glove[gi][c]);
        }
        let fingertips = kin.fingertips(&wrist, &g[..20]);
        frames.push(HumanFrame {
            t,
            shoulder: Point3::from(shoulder),
            elbow: Point3::from(elbow),
            wrist,
            fingertips,
        });
        angles.push(g);
    }
    Ok(Demonstration {
        subject: input.subject.clone(),
        object: input.object.clone(),
        labels: input.labels.clone(),
        summary: IngestSummary {
            start_s: start,
            duration_s: frames[n - 1].t - start,
            frames: n,
            rate_hz: input.sync.rate_hz,
            tracker_samples: tracker.t.len(),
            glove_samples: gt.len(),
            tracker_rate_hz: mean_rate(&tracker.t),
            glove_rate_hz: mean_rate(&gt),
            source: Source::TrackerGlove,
            arm: true,
        },
        frames,
        glove: angles,
    })
}

/// A keypoint recording's ingest: validate every column, resample at `sync.rate_hz` on its own
/// clock (points and arm positions linearly, a given wrist orientation by slerp) and derive
/// each frame's human kinematics ([`super::keypoints::human_frame`]). Glove angles do not exist:
/// they are stored as NaN and answered as empty.
fn ingest_keypoints(
    input: &DemonstrationInput,
    k: &KeypointStream,
) -> Result<Demonstration, HumanError> {
    use super::keypoints::{KEYPOINT_COUNT, KeypointFrame, human_frame};
    const STREAM: &str = "keypoints";
    input.subject.hand_dims()?;
    input.subject.arm_dims()?;
    validate_object(&input.object)?;
    validate_sync(&input.sync)?;
    if input.tracker != TrackerStream::default() || input.glove != GloveStream::default() {
        return Err(HumanError::InvalidParameter {
            field: "keypoints".into(),
            value: f64::NAN,
            reason: "a demonstration is either a tracker + glove recording or a keypoint                      recording: leave out `tracker` and `glove` with `keypoints`",
        });
    }
    check_times(STREAM, &k.t, input.sync.max_gap_s)?;
    let n = k.t.len();
    check_len(STREAM, "points", n, k.points.len())?;
    let arm = match (&k.elbow, &k.shoulder) {
        (Some(e), Some(s)) => {
            check_len(STREAM, "elbow", n, e.len())?;
            check_len(STREAM, "shoulder", n, s.len())?;
            Some((e, s))
        }
        (None, None) => None,
        (e, _) => {
            return Err(HumanError::InvalidParameter {
                field: format!(
                    "keypoints.{}",
                    if e.is_none() { "elbow" } else { "shoulder" }
                ),
                value: f64::NAN,
                reason: "give the elbow and the shoulder together, or neither (the hand alone)",
            });
        }
    };
    if let Some(q) = &k.wrist_orientation {
        check_len(STREAM, "wrist_orientation", n, q.len())?;
    }
    let vec3 = |field: &str, i: usize, v: &[f64]| -> Result<Vector3<f64>, HumanError> {
        let v = row(STREAM, field, i, v, 3)?;
        Ok(Vector3::new(v[0], v[1], v[2]))
    };
    let mut samples: Vec<KeypointFrame> = Vec::with_capacity(n);
    for i in 0..n {
        let pts = &k.points[i];
        if pts.len() != KEYPOINT_COUNT {
            return Err(HumanError::WrongWidth {
                stream: STREAM,
                index: i,
                field: "points".into(),
                expected: KEYPOINT_COUNT,
                got: pts.len(),
            });
        }
        let mut points = [Point3::origin(); KEYPOINT_COUNT];
        for (j, p) in pts.iter().enumerate() {
            points[j] = Point3::from(vec3(&format!("points[{j}]"), i, p)?);
        }
        let wrist_orientation = match &k.wrist_orientation {
            None => None,
            Some(qs) => Some(orientation(STREAM, "wrist_orientation", i, &qs[i])?),
        };
        let sample = KeypointFrame {
            t: k.t[i],
            points,
            wrist_orientation,
            elbow: arm
                .map(|(e, _)| vec3("elbow", i, &e[i]).map(Point3::from))
                .transpose()?,
            shoulder: arm
                .map(|(_, s)| vec3("shoulder", i, &s[i]).map(Point3::from))
                .transpose()?,
        };
        // Every sample checked (and its palm), not only those the resampling reads.
        human_frame(&sample, input.subject.handedness, STREAM, i)?;
        samples.push(sample);
    }
    let (start, end) = (k.t[0], k.t[n - 1]);
    let dt = 1.0 / input.sync.rate_hz;
    let count = grid_frames(start, end, dt);
    if count < 2 {
        return Err(HumanError::InvalidParameter {
            field: "keypoints.t".into(),
            value: end - start,
            reason: "the recording is shorter than two frames at `sync.rate_hz`",
        });
    }
    let mut cursor = Cursor::default();
    let mut frames = Vec::with_capacity(count);
    for f in 0..count {
        let t = (start + f as f64 * dt).min(end);
        let (i, a) = cursor.locate(&k.t, t);
        let j = (i + 1).min(n - 1);
        let (s0, s1) = (&samples[i], &samples[j]);
        let p = |x: &Point3<f64>, y: &Point3<f64>| Point3::from(lerp(&x.coords, &y.coords, a));
        let frame = KeypointFrame {
            t,
            points: std::array::from_fn(|m| p(&s0.points[m], &s1.points[m])),
            wrist_orientation: s0
                .wrist_orientation
                .zip(s1.wrist_orientation)
                .map(|(x, y)| slerp(&x, &y, a)),
            elbow: s0.elbow.zip(s1.elbow).map(|(x, y)| p(&x, &y)),
            shoulder: s0.shoulder.zip(s1.shoulder).map(|(x, y)| p(&x, &y)),
        };
        frames.push(human_frame(&frame, input.subject.handedness, STREAM, i)?);
    }
    Ok(Demonstration {
        subject: input.subject.clone(),
        object: input.object.clone(),
        labels: input.labels.clone(),
        summary: IngestSummary {
            start_s: start,
            duration_s: frames[count - 1].t - start,
            frames: count,
            rate_hz: input.sync.rate_hz,
            tracker_samples: n,
            glove_samples: 0,
            tracker_rate_hz: mean_rate(&k.t),
            glove_rate_hz: 0.0,
            source: Source::Keypoints,
            arm: arm.is_some(),
        },
        glove: vec![[f64::NAN; 22]; count],
        frames,
    })
}
