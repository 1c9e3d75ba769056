//! Hand keypoint streams (issue 22): 21 points per frame in the MANO / MediaPipe order, from a
//! camera, a headset's hand tracking or a motion-capture suit, plus optionally the wrist
//! orientation, the elbow and the shoulder. They become the same [`HumanFrame`] a tracker +
//! data-glove recording becomes, so the mapping (eq. 1-7) reads either.
//!
//! Order ([`KEYPOINT_NAMES`]): 0 wrist; thumb 1 CMC, 2 MCP, 3 IP, 4 tip; then index, middle,
//! ring and little finger, each MCP, PIP, DIP, tip (5-8, 9-12, 13-16, 17-20).
//!
//! What is derived, and how exactly:
//! - **Wrist position**: keypoint 0. **Wrist frame** (see [`crate::human`]): the given
//!   `wrist_orientation` if any; otherwise `x` towards the middle-finger MCP (keypoint 9) —
//!   exactly the model's definition — and `y` the part of the index-to-little MCP direction
//!   (little-to-index for a left hand) orthogonal to `x`, `z = x × y` the palmar normal. The
//!   knuckles' arch puts the MCPs slightly off the wrist's `xy` plane, so this `y` is within a few
//!   degrees of a glove recording's (measured in the tests against the hand model's FK).
//! - **Fingertip positions**: keypoints 4, 8, 12, 16, 20, exactly.
//! - **Fingertip orientations**: `x` along the distal phalanx (DIP to tip), exact; `z` the pad
//!   normal, taken orthogonal to `x` and to the wrist's lateral axis `y`. A keypoint skeleton does
//!   not say how a phalanx is rolled about its own axis, so this is an estimate (exact for an
//!   unabducted finger); the mapping weighs fingertip orientation only to break ties (1e-4).
//! - **Elbow, shoulder**: as given. A stream without them has no arm: it can drive a hand on a
//!   fixed base (hand-only system); an arm's transport and elbow terms need both.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::HumanFrame;
use super::demo::Handedness;
use super::error::HumanError;

/// Points per hand frame.
pub const KEYPOINT_COUNT: usize = 21;

/// The 21 keypoints in stream order (MediaPipe's names with the anatomical `little`).
pub const KEYPOINT_NAMES: [&str; KEYPOINT_COUNT] = [
    "wrist",
    "thumb_cmc",
    "thumb_mcp",
    "thumb_ip",
    "thumb_tip",
    "index_mcp",
    "index_pip",
    "index_dip",
    "index_tip",
    "middle_mcp",
    "middle_pip",
    "middle_dip",
    "middle_tip",
    "ring_mcp",
    "ring_pip",
    "ring_dip",
    "ring_tip",
    "little_mcp",
    "little_pip",
    "little_dip",
    "little_tip",
];

/// Keypoint index of each fingertip, thumb to little ([`crate::human::FINGER_NAMES`] order).
pub const TIPS: [usize; 5] = [4, 8, 12, 16, 20];
/// Keypoint index of the joint proximal to each fingertip (thumb IP, finger DIPs).
pub const DISTAL_JOINTS: [usize; 5] = [3, 7, 11, 15, 19];
const INDEX_MCP: usize = 5;
const MIDDLE_MCP: usize = 9;
const LITTLE_MCP: usize = 17;

/// Keypoints may lie this far from their frame's origin: camera and headset frames span a room,
/// more than a magnetic tracker's 3 m.
pub const MAX_KEYPOINT_DISTANCE_M: f64 = 10.0;

/// Palm segments shorter than this (m) give no direction: the keypoints are degenerate.
const MIN_SEGMENT_M: f64 = 1e-3;

/// One frame of a keypoint stream, in the stream's own frame (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeypointFrame {
    pub t: f64,
    pub points: [Point3<f64>; KEYPOINT_COUNT],
    /// The wrist frame's orientation, when the tracking gives it (e.g. a headset's wrist pose).
    pub wrist_orientation: Option<UnitQuaternion<f64>>,
    pub elbow: Option<Point3<f64>>,
    pub shoulder: Option<Point3<f64>>,
}

impl KeypointFrame {
    /// Whether the frame carries the arm (elbow and shoulder).
    pub fn has_arm(&self) -> bool {
        self.elbow.is_some() && self.shoulder.is_some()
    }
}

/// The wrist frame the keypoints define (module documentation), or `None` when the palm
/// keypoints give no frame (wrist on the middle MCP, or the MCP row along the wrist's `x`).
pub fn palm_orientation(
    points: &[Point3<f64>; KEYPOINT_COUNT],
    handedness: Handedness,
) -> Option<UnitQuaternion<f64>> {
    let x = points[MIDDLE_MCP] - points[0];
    if x.norm() < MIN_SEGMENT_M {
        return None;
    }
    let x = x.normalize();
    let across = match handedness {
        Handedness::Right => points[LITTLE_MCP] - points[INDEX_MCP],
        Handedness::Left => points[INDEX_MCP] - points[LITTLE_MCP],
    };
    let y = across - x * x.dot(&across);
    if y.norm() < MIN_SEGMENT_M {
        return None;
    }
    let y = y.normalize();
    Some(frame(x, y))
}

/// The rotation with columns `x`, `y`, `x × y` (`x`, `y` orthonormal).
fn frame(x: Vector3<f64>, y: Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(
        &[x, y, x.cross(&y)],
    )))
}

/// A fingertip frame: `x` along the distal phalanx, `z` orthogonal to it and to the wrist's
/// lateral axis (module documentation). Falls back to the wrist's axes where the phalanx gives
/// no direction or lies along the lateral axis.
fn tip_orientation(
    dip: &Point3<f64>,
    tip: &Point3<f64>,
    wrist: &UnitQuaternion<f64>,
) -> UnitQuaternion<f64> {
    let (wx, wy, wz) = (
        wrist * Vector3::x(),
        wrist * Vector3::y(),
        wrist * Vector3::z(),
    );
    let d = tip - dip;
    let x = if d.norm() < MIN_SEGMENT_M {
        wx
    } else {
        d.normalize()
    };
    let y = wy - x * x.dot(&wy);
    let y = if y.norm() < 1e-6 {
        // Phalanx along the lateral axis: the palmar normal is the best remaining reference.
        x.cross(&(wz - x * x.dot(&wz))).normalize()
    } else {
        y.normalize()
    };
    frame(x, y)
}

/// The keypoint recording a perfect hand tracker would have made of an ingested glove
/// demonstration: at every derived frame, the subject's hand model's 21 joint centres
/// ([`super::HandKinematics::keypoints`]) at that frame's glove angles and wrist pose, with its
/// elbow and shoulder. `None` for a demonstration without glove angles (itself a keypoint
/// recording).
pub fn recording_of(demo: &super::Demonstration) -> Option<super::KeypointStream> {
    let dims = demo.subject.hand_dims().ok()?;
    let mut hand = super::HandKinematics::new(&dims, demo.subject.handedness);
    let xyz = |p: &Point3<f64>| vec![p.x, p.y, p.z];
    let mut k = super::KeypointStream {
        elbow: Some(Vec::with_capacity(demo.frames.len())),
        shoulder: Some(Vec::with_capacity(demo.frames.len())),
        ..super::KeypointStream::default()
    };
    for (f, g) in demo.frames.iter().zip(&demo.glove) {
        if !g.iter().all(|a| a.is_finite()) {
            return None;
        }
        k.t.push(f.t);
        k.points
            .push(hand.keypoints(&f.wrist, &g[..20]).iter().map(xyz).collect());
        k.elbow.as_mut()?.push(xyz(&f.elbow));
        k.shoulder.as_mut()?.push(xyz(&f.shoulder));
    }
    Some(k)
}

/// Checks a keypoint frame: every coordinate finite and within [`MAX_KEYPOINT_DISTANCE_M`], the
/// orientation (if any) normalisable. `stream` and `index` locate errors (`keypoints`, sample).
pub fn validate(kp: &KeypointFrame, stream: &'static str, index: usize) -> Result<(), HumanError> {
    let check = |field: String, p: &Point3<f64>| -> Result<(), HumanError> {
        if let Some(k) = p.coords.iter().position(|v| !v.is_finite()) {
            return Err(HumanError::NonFinite {
                stream,
                index,
                field: format!("{field}[{k}]"),
                value: p[k],
            });
        }
        let d = p.coords.norm();
        if d > MAX_KEYPOINT_DISTANCE_M {
            return Err(HumanError::PositionOutOfRange {
                stream,
                index,
                field,
                distance: d,
                limit: MAX_KEYPOINT_DISTANCE_M,
            });
        }
        Ok(())
    };
    if !kp.t.is_finite() {
        return Err(HumanError::NonFinite {
            stream,
            index,
            field: "t".into(),
            value: kp.t,
        });
    }
    for (j, p) in kp.points.iter().enumerate() {
        check(format!("points[{j}] ({})", KEYPOINT_NAMES[j]), p)?;
    }
    if let Some(e) = &kp.elbow {
        check("elbow".into(), e)?;
    }
    if let Some(s) = &kp.shoulder {
        check("shoulder".into(), s)?;
    }
    if let Some(q) = &kp.wrist_orientation
        && !q.coords.iter().all(|v| v.is_finite())
    {
        return Err(HumanError::NonFinite {
            stream,
            index,
            field: "wrist_orientation".into(),
            value: f64::NAN,
        });
    }
    Ok(())
}

/// The human kinematics of one keypoint frame (module documentation). Without an elbow or a
/// shoulder those points are the wrist's position (a hand-only frame; [`KeypointFrame::has_arm`]
/// says which). `stream` and `index` locate errors.
pub fn human_frame(
    kp: &KeypointFrame,
    handedness: Handedness,
    stream: &'static str,
    index: usize,
) -> Result<HumanFrame, HumanError> {
    validate(kp, stream, index)?;
    let rotation = match kp.wrist_orientation {
        Some(q) => q,
        None => {
            palm_orientation(&kp.points, handedness).ok_or_else(|| HumanError::DegenerateHand {
                stream,
                index,
                reason: "the wrist, middle-finger MCP and index/little MCP keypoints do not span \
                         a palm (give wrist_orientation, or check the keypoint order)"
                    .into(),
            })?
        }
    };
    let w = kp.points[0];
    let wrist = Isometry3::from_parts(Translation3::from(w.coords), rotation);
    let fingertips = std::array::from_fn(|f| {
        let (dip, tip) = (&kp.points[DISTAL_JOINTS[f]], &kp.points[TIPS[f]]);
        Isometry3::from_parts(
            Translation3::from(tip.coords),
            tip_orientation(dip, tip, &rotation),
        )
    });
    Ok(HumanFrame {
        t: kp.t,
        shoulder: kp.shoulder.unwrap_or(w),
        elbow: kp.elbow.unwrap_or(w),
        wrist,
        fingertips,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::human::{HandDims, HandKinematics, HumanFrame};

    /// The 21 keypoints of the human hand model at `q` (glove order) with the wrist at `w`
    /// ([`HandKinematics::keypoints`], the model's joint centres: an independent reference, the
    /// glove path's own forward kinematics), and its fingertip poses.
    fn model_keypoints(
        hk: &mut HandKinematics,
        w: &Isometry3<f64>,
        q: &[f64],
    ) -> ([Point3<f64>; KEYPOINT_COUNT], [Isometry3<f64>; 5]) {
        let points = hk.keypoints(w, q);
        let tips = hk.fingertips(w, q);
        // The keypoint order: the tips where the fingertip frames are, the wrist at its origin.
        for (f, tip) in tips.iter().enumerate() {
            assert!((points[TIPS[f]].coords - tip.translation.vector).norm() < 1e-12);
        }
        assert!((points[0].coords - w.translation.vector).norm() < 1e-12);
        (points, tips)
    }

    fn wrist_pose() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.15),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -1.1, 0.7)),
        )
    }

    fn postures() -> Vec<[f64; 20]> {
        // Open, a power grasp, a pinch, abducted: within the model's ranges.
        let mut open = [0.0; 20];
        open[1] = 0.3;
        let mut power = [0.0; 20];
        for f in 0..4 {
            power[5 + 4 * f] = 0.9;
            power[6 + 4 * f] = 1.2;
            power[7 + 4 * f] = 0.6;
        }
        power[0] = 0.6;
        power[1] = 0.9;
        power[2] = 0.4;
        power[3] = 0.5;
        let mut spread = open;
        spread[4] = 0.3;
        spread[12] = 0.25;
        spread[16] = 0.3;
        spread[5] = 0.4;
        vec![open, power, spread]
    }

    #[test]
    fn keypoints_of_the_hand_model_give_its_wrist_frame_and_fingertips() {
        let dims = HandDims::from_measurements(0.185, 0.085).unwrap();
        for hand in [Handedness::Right, Handedness::Left] {
            let mut hk = HandKinematics::new(&dims, hand);
            let w = wrist_pose();
            for q in postures() {
                let (points, tips) = model_keypoints(&mut hk, &w, &q);
                let kp = KeypointFrame {
                    t: 0.0,
                    points,
                    wrist_orientation: None,
                    elbow: None,
                    shoulder: None,
                };
                let f: HumanFrame = human_frame(&kp, hand, "keypoints", 0).unwrap();
                // Wrist frame: the MCP arch makes `y` approximate (documented: a few degrees).
                let err = f.wrist.rotation.angle_to(&w.rotation).to_degrees();
                assert!(err < 5.0, "{hand:?} wrist frame {err:.2} deg off");
                // `x` itself is exact: towards the middle MCP.
                let x_err = (f.wrist.rotation * Vector3::x())
                    .angle(&(w.rotation * Vector3::x()))
                    .to_degrees();
                assert!(x_err < 1.0, "{hand:?} wrist x {x_err:.3} deg off");
                for (k, (a, b)) in f.fingertips.iter().zip(&tips).enumerate() {
                    let d = (a.translation.vector - b.translation.vector).norm();
                    assert!(d < 1e-12, "tip {k}: {d}");
                    // The phalanx axis is exact; the roll about it an estimate.
                    let ax = (a.rotation * Vector3::x()).angle(&(b.rotation * Vector3::x()));
                    assert!(ax < 1e-9, "tip {k} axis {ax}");
                    if k > 0 {
                        let roll = a.rotation.angle_to(&b.rotation).to_degrees();
                        assert!(roll < 30.0, "{hand:?} tip {k} roll {roll:.1} deg");
                    }
                }
                assert_eq!(f.elbow, points[0]);
                assert!(!kp.has_arm());
            }
        }
    }

    #[test]
    fn a_given_wrist_orientation_wins_and_bad_frames_name_the_keypoint() {
        let dims = HandDims::from_measurements(0.185, 0.085).unwrap();
        let mut hk = HandKinematics::new(&dims, Handedness::Right);
        let w = wrist_pose();
        let (points, _) = model_keypoints(&mut hk, &w, &postures()[1]);
        let given = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.5));
        let kp = KeypointFrame {
            t: 1.0,
            points,
            wrist_orientation: Some(given),
            elbow: Some(Point3::new(0.1, 0.0, 0.3)),
            shoulder: Some(Point3::new(0.0, 0.0, 0.6)),
        };
        let f = human_frame(&kp, Handedness::Right, "keypoints", 3).unwrap();
        assert!(f.wrist.rotation.angle_to(&given) < 1e-12);
        assert_eq!(f.shoulder, Point3::new(0.0, 0.0, 0.6));
        let mut bad = kp;
        bad.points[8].y = f64::NAN;
        let e = human_frame(&bad, Handedness::Right, "keypoints", 3).unwrap_err();
        assert_eq!(e.path(), "keypoints.points[3]");
        assert!(e.to_string().contains("points[8] (index_tip)[1]"), "{e}");
        let mut far = kp;
        far.points[0].x = 20.0;
        let e = human_frame(&far, Handedness::Right, "keypoints", 0).unwrap_err();
        assert!(matches!(e, HumanError::PositionOutOfRange { .. }), "{e}");
        // All palm points on one spot: no wrist frame to derive.
        let mut flat = kp;
        flat.wrist_orientation = None;
        flat.points = [Point3::new(0.1, 0.1, 0.1); KEYPOINT_COUNT];
        let e = human_frame(&flat, Handedness::Right, "keypoints", 7).unwrap_err();
        assert!(
            matches!(e, HumanError::DegenerateHand { index: 7, .. }),
            "{e}"
        );
    }

    /// A study demonstration recorded as keypoints (its hand model's joint centres at every
    /// derived frame, with the elbow and shoulder): ingested at the same rate it gives the glove
    /// ingest's fingertips exactly, and through CSV the same; bad rows name their sample.
    #[test]
    fn a_keypoint_recording_ingests_into_the_glove_recordings_frames() {
        use crate::human::demo::{DemonstrationInput, Source};
        use crate::human::{StudyConfig, generate_study, ingest};
        let cfg = StudyConfig {
            seed: 5,
            subjects: 1,
            positions: 1,
            trials: 1,
            rate_hz: 60.0,
            ..StudyConfig::default()
        };
        let input = generate_study(&cfg).unwrap().remove(0);
        let demo = ingest(&input).unwrap();
        let dims = demo.subject.hand_dims().unwrap();
        let mut hk = HandKinematics::new(&dims, demo.subject.handedness);
        // The model's keypoints at every frame (checked against its fingertips by
        // `model_keypoints`), as `recording_of` writes them.
        for (f, g) in demo.frames.iter().zip(&demo.glove) {
            model_keypoints(&mut hk, &f.wrist, &g[..20]);
        }
        let k = recording_of(&demo).unwrap();
        assert!(
            recording_of(
                &ingest(&DemonstrationInput {
                    tracker: Default::default(),
                    glove: Default::default(),
                    keypoints: Some(k.clone()),
                    ..input.clone()
                })
                .unwrap()
            )
            .is_none()
        );
        let mut kin = DemonstrationInput {
            tracker: Default::default(),
            glove: Default::default(),
            keypoints: Some(k.clone()),
            ..input.clone()
        };
        kin.sync.rate_hz = demo.summary.rate_hz;
        let from_kp = ingest(&kin).unwrap();
        assert_eq!(from_kp.summary.source, Source::Keypoints);
        assert_eq!(from_kp.frames.len(), demo.frames.len());
        assert!(from_kp.glove.iter().flatten().all(|a| a.is_nan()));
        for (a, b) in from_kp.frames.iter().zip(&demo.frames) {
            assert!((a.t - b.t).abs() < 1e-9);
            assert!((a.elbow - b.elbow).norm() < 1e-9);
            for (p, q) in a.fingertips.iter().zip(&b.fingertips) {
                let d = (p.translation.vector - q.translation.vector).norm();
                assert!(d < 1e-9, "fingertip {d} m off the glove ingest's");
            }
            assert!(a.wrist.rotation.angle_to(&b.wrist.rotation).to_degrees() < 5.0);
        }
        // CSV: the same stream, the same frames.
        let csv = crate::human::csv::keypoints_to_csv(&k);
        let back = crate::human::csv::parse_keypoint_csv(&csv).unwrap();
        assert_eq!(back, k);
        // A short row names its sample; tracker and keypoints together are refused.
        let mut short = kin.clone();
        short.keypoints.as_mut().unwrap().points[7].pop();
        let e = ingest(&short).unwrap_err();
        assert_eq!(e.path(), "keypoints.points[7]", "{e}");
        let mut both = kin.clone();
        both.tracker = input.tracker.clone();
        let e = ingest(&both).unwrap_err();
        assert_eq!(e.path(), "keypoints", "{e}");
        let mut short_elbow = kin.clone();
        short_elbow
            .keypoints
            .as_mut()
            .unwrap()
            .elbow
            .as_mut()
            .unwrap()
            .pop();
        let e = ingest(&short_elbow).unwrap_err();
        assert_eq!(e.path(), "keypoints.elbow", "{e}");
        let mut no_elbow = kin.clone();
        no_elbow.keypoints.as_mut().unwrap().elbow = None;
        let e = ingest(&no_elbow).unwrap_err();
        assert_eq!(e.path(), "keypoints.elbow", "{e}");
        // The hand alone: the frames keep the fingertips and put the arm points on the wrist,
        // which no arm system can register (tested in `mapping::registration`).
        let mut hand = kin;
        let k = hand.keypoints.as_mut().unwrap();
        (k.elbow, k.shoulder) = (None, None);
        let alone = ingest(&hand).unwrap();
        assert!(from_kp.summary.arm && !alone.summary.arm);
        for (a, b) in alone.frames.iter().zip(&from_kp.frames) {
            assert_eq!(a.fingertips, b.fingertips);
            assert_eq!(a.elbow.coords, a.wrist.translation.vector);
        }
        let csv = crate::human::csv::keypoints_to_csv(hand.keypoints.as_ref().unwrap());
        assert!(!csv.contains("elbow_x"));
        assert_eq!(
            &crate::human::csv::parse_keypoint_csv(&csv).unwrap(),
            hand.keypoints.as_ref().unwrap()
        );
    }
}
