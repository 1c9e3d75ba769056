//! Tests of the human layer: model FK against closed forms, ingest exactness, every rejection,
//! and the generator's motor-control properties.
#![allow(clippy::needless_range_loop)] // index loops mirror the closed forms being checked

use nalgebra::{Isometry3, Point3, Translation3, Vector3};

use super::*;
use crate::kinematics::{Data, forward_kinematics};

fn dims() -> HandDims {
    HandDims::from_measurements(0.19, 0.087).unwrap()
}

mod model_fk {
    use super::*;

    #[test]
    fn hand_q_order_is_the_glove_order_with_twenty_dof_in_fifteen_joints() {
        let m = hand_model(&dims(), Handedness::Right);
        assert_eq!(m.nq(), HAND_DOF);
        assert_eq!(m.joint_names(), &GLOVE_CHANNELS[..20]);
        // Anatomical joints: CMC/MCP (2 DoF), then two 1-DoF joints, per finger.
        let spec = hand_spec(&dims(), Handedness::Right);
        let mut anatomical: Vec<String> = spec
            .iter()
            .filter(|j| j.axis.is_some())
            .map(|j| {
                let mut parts = j.name.split('_');
                format!("{}_{}", parts.next().unwrap(), parts.next().unwrap())
            })
            .collect();
        anatomical.dedup();
        assert_eq!(anatomical.len(), 15, "{anatomical:?}");
        for f in FINGER_NAMES {
            assert!(m.frame_id(&format!("{f}_tip")).is_some());
        }
    }

    fn base_of(m: &crate::kinematics::Model, data: &Data, f: usize) -> Isometry3<f64> {
        let name = if f == 0 {
            "thumb_proximal".to_string()
        } else {
            format!("{}_mcp", FINGER_NAMES[f])
        };
        *data.frame(m.frame_id(&name).unwrap())
    }

    #[test]
    fn a_straight_finger_reaches_the_sum_of_its_phalanges_from_the_mcp() {
        let d = dims();
        for hand in [Handedness::Right, Handedness::Left] {
            let m = hand_model(&d, hand);
            let mut data = Data::new(&m);
            forward_kinematics(&m, &mut data, &[0.0; 20]);
            for f in 1..5 {
                let mcp = base_of(&m, &data, f).translation.vector;
                let tip = data.frame(m.frame_id(&format!("{}_tip", FINGER_NAMES[f])).unwrap());
                let sum: f64 = d.fingers[f].phalanges.iter().sum();
                assert!(((tip.translation.vector - mcp).norm() - sum).abs() < 1e-12);
            }
            // Thumb: from the MCP joint, proximal + distal phalanx.
            let mcp = base_of(&m, &data, 0).translation.vector;
            let tip = data
                .frame(m.frame_id("thumb_tip").unwrap())
                .translation
                .vector;
            let p = d.fingers[0].phalanges;
            assert!(((tip - mcp).norm() - (p[1] + p[2])).abs() < 1e-12);
        }
    }

    #[test]
    fn finger_flexion_follows_the_planar_closed_form() {
        let d = dims();
        let m = hand_model(&d, Handedness::Right);
        let mut data = Data::new(&m);
        let angles = [
            (0.3, 0.5, 0.2),
            (1.2, 0.1, 0.9),
            (-0.2, 1.5, 0.4),
            (std::f64::consts::FRAC_PI_2, 0.0, 0.0),
        ];
        for f in 1..5 {
            for &(a, b, c) in &angles {
                let mut q = [0.0; 20];
                q[4 * f + 1] = a;
                q[4 * f + 2] = b;
                q[4 * f + 3] = c;
                forward_kinematics(&m, &mut data, &q);
                let base = base_of(&m, &data, f);
                let tip = data.frame(m.frame_id(&format!("{}_tip", FINGER_NAMES[f])).unwrap());
                let local = base.inverse() * tip;
                let [p1, p2, p3] = d.fingers[f].phalanges;
                // Flexion turns x towards the palmar z axis.
                let x = p1 * a.cos() + p2 * (a + b).cos() + p3 * (a + b + c).cos();
                let z = p1 * a.sin() + p2 * (a + b).sin() + p3 * (a + b + c).sin();
                let expected = Vector3::new(x, 0.0, z);
                assert!(
                    (local.translation.vector - expected).norm() < 1e-12,
                    "finger {f}"
                );
                // Tip frame: x along the distal phalanx, z its palmar normal.
                let s = a + b + c;
                let xa = local.rotation * Vector3::x();
                let za = local.rotation * Vector3::z();
                assert!((xa - Vector3::new(s.cos(), 0.0, s.sin())).norm() < 1e-12);
                assert!((za - Vector3::new(-s.sin(), 0.0, s.cos())).norm() < 1e-12);
            }
        }
    }

    #[test]
    fn abduction_turns_the_finger_in_the_palm_plane_away_from_the_middle_finger() {
        let d = dims();
        let m = hand_model(&d, Handedness::Right);
        let mut data = Data::new(&m);
        let mut q = [0.0; 20];
        q[4] = 0.3; // index abduction: radial (−y in a right hand)
        q[16] = 0.3; // little abduction: ulnar (+y)
        forward_kinematics(&m, &mut data, &q);
        for (f, sign) in [(1usize, -1.0), (4, 1.0)] {
            // Compare with the base frame before abduction (the joint origin).
            let spec = hand_spec(&d, Handedness::Right);
            let origin = spec
                .iter()
                .find(|j| j.name == format!("{}_mcp_abduction", FINGER_NAMES[f]))
                .unwrap()
                .origin;
            let tip = data.frame(m.frame_id(&format!("{}_tip", FINGER_NAMES[f])).unwrap());
            let local = (origin.inverse() * Point3::from(tip.translation.vector)).coords;
            let sum: f64 = d.fingers[f].phalanges.iter().sum();
            let expected = Vector3::new(sum * 0.3f64.cos(), sign * sum * 0.3f64.sin(), 0.0);
            assert!((local - expected).norm() < 1e-12, "finger {f}: {local:?}");
        }
    }

    #[test]
    fn left_hand_is_the_mirror_image_of_the_right() {
        let d = dims();
        let mut r = HandKinematics::new(&d, Handedness::Right);
        let mut l = HandKinematics::new(&d, Handedness::Left);
        let q: [f64; 20] = std::array::from_fn(|k| 0.05 * k as f64 - 0.2);
        let tr = r.fingertips_local(&q);
        let tl = l.fingertips_local(&q);
        for (a, b) in tr.iter().zip(&tl) {
            let (pa, pb) = (a.translation.vector, b.translation.vector);
            assert!((pa - Vector3::new(pb.x, -pb.y, pb.z)).norm() < 1e-12);
        }
    }

    #[test]
    fn arm_segments_and_elbow_flexion_match_the_closed_form() {
        let a = ArmDims::from_stature(1.75).unwrap();
        let m = arm_model(&a, Handedness::Right);
        assert_eq!(m.joint_names(), &ARM_JOINTS);
        let mut data = Data::new(&m);
        let elbow = m.frame_id("forearm").unwrap();
        let hand = m.frame_id("hand").unwrap();
        forward_kinematics(&m, &mut data, &[0.0; 7]);
        assert!(
            (data.frame(elbow).translation.vector - Vector3::new(0.0, 0.0, -a.upper_arm)).norm()
                < 1e-12
        );
        let h = data.frame(hand);
        assert!((h.translation.vector - Vector3::new(0.0, 0.0, -a.reach())).norm() < 1e-12);
        // Anatomical position: hand x distal (down), z palmar (forward), y ulnar (medial, +y).
        assert!((h.rotation * Vector3::x() - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        assert!((h.rotation * Vector3::z() - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        // Elbow flexed 90°: the forearm points forward.
        let mut q = [0.0; 7];
        q[3] = std::f64::consts::FRAC_PI_2;
        forward_kinematics(&m, &mut data, &q);
        let w = data.frame(hand).translation.vector;
        assert!((w - Vector3::new(a.forearm, 0.0, -a.upper_arm)).norm() < 1e-12);
        // Shoulder flexion 90° raises the straight arm forward.
        let mut q = [0.0; 7];
        q[0] = std::f64::consts::FRAC_PI_2;
        forward_kinematics(&m, &mut data, &q);
        let w = data.frame(hand).translation.vector;
        assert!((w - Vector3::new(a.reach(), 0.0, 0.0)).norm() < 1e-12);
    }
}

/// A demonstration with analytic signals: positions linear in time, a constant-rate wrist
/// rotation, glove angles linear in time — all reproduced exactly by linear/slerp resampling.
pub(super) fn analytic_input(duration: f64) -> DemonstrationInput {
    let nt = (duration * 240.0) as usize + 1;
    let ng = (duration * 90.0) as usize + 1;
    let tracker_t: Vec<f64> = (0..nt).map(|k| k as f64 / 240.0).collect();
    let glove_t: Vec<f64> = (0..ng).map(|k| k as f64 / 90.0).collect();
    DemonstrationInput {
        subject: Subject::average("S0"),
        object: ObjectSpec {
            name: "ball".into(),
            shape: ObjectShape::Sphere { radius: 0.04 },
            pose: Pose {
                position: [0.4, 0.0, 0.05],
                orientation: [1.0, 0.0, 0.0, 0.0],
            },
        },
        labels: Labels {
            task: "grasp".into(),
            position_index: 1,
            trial: 2,
            synthetic: false,
            external_id: Some("ext-1".into()),
        },
        tracker: TrackerStream {
            shoulder: tracker_t
                .iter()
                .map(|&t| analytic::shoulder(t).to_vec())
                .collect(),
            elbow: tracker_t
                .iter()
                .map(|&t| analytic::elbow(t).to_vec())
                .collect(),
            wrist: tracker_t
                .iter()
                .map(|&t| analytic::wrist(t).to_vec())
                .collect(),
            wrist_orientation: tracker_t
                .iter()
                .map(|&t| {
                    let q = analytic::rotation(t);
                    vec![q.w, q.i, q.j, q.k]
                })
                .collect(),
            t: tracker_t,
        },
        glove: GloveStream {
            angles: Some(
                glove_t
                    .iter()
                    .map(|&t| analytic::angles(t).to_vec())
                    .collect(),
            ),
            t: glove_t,
            raw: None,
            calibration: None,
        },
        keypoints: None,
        sync: SyncOptions::default(),
    }
}

pub(super) mod analytic {
    use nalgebra::{UnitQuaternion, Vector3};
    pub fn shoulder(t: f64) -> [f64; 3] {
        [-0.15 + 0.01 * t, 0.0, 0.33]
    }
    pub fn elbow(t: f64) -> [f64; 3] {
        [-0.1 + 0.1 * t, -0.1, 0.1 + 0.02 * t]
    }
    pub fn wrist(t: f64) -> [f64; 3] {
        [0.1 + 0.2 * t, -0.05 + 0.03 * t, 0.05 + 0.05 * t]
    }
    pub fn rotation(t: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.2))
            * UnitQuaternion::from_scaled_axis(
                Vector3::new(0.6, -0.3, 0.74).normalize() * (1.1 * t),
            )
    }
    pub fn angles(t: f64) -> [f64; 22] {
        std::array::from_fn(|k| 0.02 * k as f64 - 0.1 + (0.3 - 0.01 * k as f64) * t)
    }
}

mod ingest_path {
    use super::*;

    fn close3(a: &Point3<f64>, b: [f64; 3]) -> bool {
        (a.coords - Vector3::from(b)).norm() < 1e-12
    }

    #[test]
    fn analytic_streams_are_resampled_exactly_and_fingertips_come_from_hand_fk() {
        let input = analytic_input(2.0);
        let demo = ingest(&input).unwrap();
        let s = demo.summary;
        assert_eq!(s.frames, 241);
        assert!((s.duration_s - 2.0).abs() < 1e-9);
        assert!((s.tracker_rate_hz - 240.0).abs() < 1e-9 && (s.glove_rate_hz - 90.0).abs() < 1e-9);
        let mut hk = HandKinematics::new(&input.subject.hand_dims().unwrap(), Handedness::Right);
        for (f, g) in demo.frames.iter().zip(&demo.glove) {
            let t = f.t;
            assert!(close3(&f.shoulder, analytic::shoulder(t)));
            assert!(close3(&f.elbow, analytic::elbow(t)));
            assert!(close3(
                &Point3::from(f.wrist.translation.vector),
                analytic::wrist(t)
            ));
            assert!(f.wrist.rotation.angle_to(&analytic::rotation(t)) < 1e-10);
            let a = analytic::angles(t);
            for k in 0..22 {
                assert!((g[k] - a[k]).abs() < 1e-12);
            }
            let wrist = Isometry3::from_parts(
                Translation3::from(Vector3::from(analytic::wrist(t))),
                analytic::rotation(t),
            );
            let tips = hk.fingertips(&wrist, &a[..20]);
            for (p, q) in tips.iter().zip(&f.fingertips) {
                assert!((p.translation.vector - q.translation.vector).norm() < 1e-10);
                assert!(p.rotation.angle_to(&q.rotation) < 1e-10);
            }
        }
    }

    #[test]
    fn a_glove_clock_offset_is_applied_before_resampling() {
        let base = ingest(&analytic_input(1.5)).unwrap();
        let mut shifted = analytic_input(1.5);
        shifted.glove.t.iter_mut().for_each(|t| *t += 100.0);
        shifted.sync.glove_offset_s = -100.0;
        let demo = ingest(&shifted).unwrap();
        assert_eq!(demo.frames.len(), base.frames.len());
        for (a, b) in demo.glove.iter().zip(&base.glove) {
            for k in 0..22 {
                assert!((a[k] - b[k]).abs() < 1e-9);
            }
        }
        // Streams that share no time at all.
        shifted.sync.glove_offset_s = 0.0;
        assert!(matches!(
            ingest(&shifted),
            Err(HumanError::NoOverlap { .. })
        ));
    }

    #[test]
    fn raw_glove_values_with_a_calibration_give_the_same_angles() {
        let input = analytic_input(1.0);
        let angles = ingest(&input).unwrap().glove;
        let gain: Vec<f64> = (0..22).map(|k| 0.01 + 0.001 * k as f64).collect();
        let offset: Vec<f64> = (0..22).map(|k| -0.5 + 0.05 * k as f64).collect();
        let mut raw_input = input.clone();
        let raw = input.glove.angles.as_ref().unwrap().iter().map(|r| {
            r.iter()
                .enumerate()
                .map(|(k, a)| (a - offset[k]) / gain[k])
                .collect()
        });
        raw_input.glove.raw = Some(raw.collect());
        raw_input.glove.angles = None;
        raw_input.glove.calibration = Some(GloveCalibration { gain, offset });
        let calibrated = ingest(&raw_input).unwrap().glove;
        for (a, b) in angles.iter().zip(&calibrated) {
            for k in 0..22 {
                assert!((a[k] - b[k]).abs() < 1e-12);
            }
        }
    }

    fn same_frames(a: &Demonstration, b: &Demonstration) -> bool {
        a.frames.len() == b.frames.len()
            && a.frames.iter().zip(&b.frames).all(|(x, y)| {
                (x.t - y.t).abs() < 1e-12
                    && (x.elbow - y.elbow).norm() < 1e-12
                    && x.fingertips
                        .iter()
                        .zip(&y.fingertips)
                        .all(|(p, q)| (p.translation.vector - q.translation.vector).norm() < 1e-12)
            })
    }

    #[test]
    fn the_json_document_round_trips_and_csv_gives_the_same_demonstration() {
        let input = analytic_input(0.5);
        let json = serde_json::to_string(&input).unwrap();
        let back: DemonstrationInput = serde_json::from_str(&json).unwrap();
        assert_eq!(back.labels, input.labels);
        assert_eq!(back.subject, input.subject);
        let reference = ingest(&input).unwrap();
        assert!(same_frames(&ingest(&back).unwrap(), &reference));
        let mut from_csv = input.clone();
        from_csv.tracker = csv::parse_tracker_csv(&csv::tracker_to_csv(&input.tracker)).unwrap();
        from_csv.glove = csv::parse_glove_csv(&csv::glove_to_csv(&input.glove), None).unwrap();
        assert!(same_frames(&ingest(&from_csv).unwrap(), &reference));
    }

    #[test]
    fn unnormalised_quaternions_are_normalised() {
        let mut input = analytic_input(0.5);
        input
            .tracker
            .wrist_orientation
            .iter_mut()
            .for_each(|q| q.iter_mut().for_each(|v| *v *= 3.0));
        let a = ingest(&input).unwrap();
        let b = ingest(&analytic_input(0.5)).unwrap();
        for (x, y) in a.frames.iter().zip(&b.frames) {
            assert!(x.wrist.rotation.angle_to(&y.wrist.rotation) < 1e-12);
        }
    }
}

mod rejections {
    use super::*;

    fn reject(edit: impl FnOnce(&mut DemonstrationInput)) -> HumanError {
        let mut input = analytic_input(1.0);
        edit(&mut input);
        ingest(&input).unwrap_err()
    }

    fn at(e: &HumanError, stream: &str, index: usize, field: &str) {
        assert_eq!(e.stream(), Some(stream), "{e}");
        assert_eq!(e.index(), Some(index), "{e}");
        assert!(e.field().unwrap().starts_with(field), "{e}");
    }

    #[test]
    fn timestamps_that_do_not_increase_are_rejected() {
        let e = reject(|i| i.tracker.t[7] = i.tracker.t[6]);
        assert!(matches!(e, HumanError::NotIncreasing { .. }));
        at(&e, "tracker", 7, "t");
        let e = reject(|i| i.glove.t.swap(3, 4));
        at(&e, "glove", 4, "t");
        assert_eq!(e.path(), "glove.t[4]");
    }

    #[test]
    fn nan_and_infinite_values_are_rejected() {
        let e = reject(|i| i.tracker.elbow[12][1] = f64::NAN);
        assert!(matches!(e, HumanError::NonFinite { .. }));
        at(&e, "tracker", 12, "elbow");
        assert_eq!(e.path(), "tracker.elbow[12]");
        let e = reject(|i| i.glove.angles.as_mut().unwrap()[5][9] = f64::INFINITY);
        at(&e, "glove", 5, "angles");
        let e = reject(|i| i.tracker.t[3] = f64::NAN);
        at(&e, "tracker", 3, "t");
    }

    #[test]
    fn rows_of_the_wrong_width_are_rejected() {
        let e = reject(|i| i.tracker.wrist_orientation[20].pop().map(|_| ()).unwrap());
        assert!(matches!(
            e,
            HumanError::WrongWidth {
                expected: 4,
                got: 3,
                ..
            }
        ));
        at(&e, "tracker", 20, "wrist_orientation");
        let e = reject(|i| i.glove.angles.as_mut().unwrap()[8].push(0.0));
        assert!(matches!(
            e,
            HumanError::WrongWidth {
                expected: 22,
                got: 23,
                ..
            }
        ));
        at(&e, "glove", 8, "angles");
        let e = reject(|i| {
            i.tracker.shoulder.pop();
        });
        assert!(matches!(e, HumanError::LengthMismatch { .. }));
    }

    #[test]
    fn gaps_over_the_limit_are_rejected() {
        let e = reject(|i| {
            i.sync.max_gap_s = 0.05;
            for t in &mut i.tracker.t[100..] {
                *t += 0.2;
            }
        });
        assert!(matches!(e, HumanError::Gap { .. }));
        at(&e, "tracker", 100, "t");
    }

    #[test]
    fn glove_angles_beyond_180_degrees_are_rejected() {
        let e = reject(|i| i.glove.angles.as_mut().unwrap()[30][6] = 3.3);
        assert!(matches!(e, HumanError::AngleOutOfRange { .. }));
        at(&e, "glove", 30, "angles[6] (index_pip_flexion)");
    }

    #[test]
    fn positions_farther_than_three_metres_are_rejected() {
        let e = reject(|i| i.tracker.shoulder[2] = vec![2.5, 2.0, 0.0]);
        assert!(matches!(e, HumanError::PositionOutOfRange { .. }));
        at(&e, "tracker", 2, "shoulder");
    }

    #[test]
    fn a_zero_quaternion_is_rejected() {
        let e = reject(|i| i.tracker.wrist_orientation[40] = vec![0.0; 4]);
        assert!(matches!(e, HumanError::DegenerateQuaternion { .. }));
        at(&e, "tracker", 40, "wrist_orientation");
    }

    #[test]
    fn empty_streams_are_rejected() {
        let e = reject(|i| i.tracker = TrackerStream::default());
        assert_eq!(e, HumanError::EmptyStream { stream: "tracker" });
        let e = reject(|i| {
            i.glove.t.clear();
            i.glove.angles = Some(vec![]);
        });
        assert_eq!(e, HumanError::EmptyStream { stream: "glove" });
    }

    #[test]
    fn a_glove_without_angles_or_with_a_short_calibration_is_rejected() {
        let e = reject(|i| i.glove.angles = None);
        assert_eq!(e.field(), Some("glove.angles"));
        let e = reject(|i| {
            i.glove.raw = i.glove.angles.take();
            i.glove.calibration = Some(GloveCalibration {
                gain: vec![1.0; 21],
                offset: vec![0.0; 22],
            });
        });
        assert!(matches!(
            e,
            HumanError::LengthMismatch {
                expected: 22,
                got: 21,
                ..
            }
        ));
    }

    #[test]
    fn implausible_subjects_objects_and_sync_settings_are_rejected() {
        let e = reject(|i| i.subject.hand_breadth_m = 0.5);
        assert_eq!(e.field(), Some("subject.hand_breadth_m"));
        let e = reject(|i| i.object.shape = ObjectShape::Sphere { radius: -1.0 });
        assert_eq!(e.field(), Some("object.shape.radius"));
        let e = reject(|i| i.sync.rate_hz = 0.0);
        assert_eq!(e.field(), Some("sync.rate_hz"));
    }
}

pub(super) mod gen_props {
    use super::*;
    use crate::human::synth::{TrialSpec, min_jerk};

    pub fn clean_trial(
        object: ObjectKind,
        position: usize,
        trial: usize,
    ) -> (DemonstrationInput, Demonstration) {
        let cfg = StudyConfig {
            noise: false,
            ..StudyConfig::default()
        };
        let subject = cfg.study_subjects()[trial % 5].clone();
        let spec = TrialSpec {
            subject,
            subject_index: trial % 5,
            object,
            position_index: position,
            trial,
            noise: false,
            rate_hz: 240.0,
        };
        let input = generate_trial(&spec, 7).unwrap();
        let demo = ingest(&input).unwrap();
        (input, demo)
    }

    /// Wrist speed per tracker sample (central differences of the raw stream).
    pub fn wrist_speed(input: &DemonstrationInput) -> Vec<f64> {
        let t = &input.tracker.t;
        let w = &input.tracker.wrist;
        (1..t.len() - 1)
            .map(|k| {
                let d: f64 = (0..3)
                    .map(|c| (w[k + 1][c] - w[k - 1][c]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                d / (t[k + 1] - t[k - 1])
            })
            .collect()
    }

    /// Movement onset/offset: first and last time the wrist speed exceeds 1 % of its peak.
    pub fn movement_window(input: &DemonstrationInput) -> (f64, f64) {
        let v = wrist_speed(input);
        let peak = v.iter().cloned().fold(0.0, f64::max);
        let on = v.iter().position(|&s| s > 0.01 * peak).unwrap();
        let off = v.iter().rposition(|&s| s > 0.01 * peak).unwrap();
        (input.tracker.t[on + 1], input.tracker.t[off + 1])
    }

    pub fn apertures(demo: &Demonstration) -> Vec<f64> {
        demo.frames
            .iter()
            .map(|f| {
                (f.fingertips[0].translation.vector - f.fingertips[1].translation.vector).norm()
            })
            .collect()
    }

    fn local_maxima(v: &[f64], floor: f64) -> usize {
        (1..v.len() - 1)
            .filter(|&k| v[k] > floor && v[k] >= v[k - 1] && v[k] > v[k + 1])
            .count()
    }

    #[test]
    fn minimum_jerk_profile_is_smooth_at_both_ends() {
        assert_eq!(min_jerk(0.0), 0.0);
        assert_eq!(min_jerk(1.0), 1.0);
        assert!((min_jerk(0.5) - 0.5).abs() < 1e-15);
        // Zero velocity at the ends (central differences).
        let h = 1e-6;
        assert!((min_jerk(h) - min_jerk(0.0)) / h < 1e-9);
        assert!((min_jerk(1.0) - min_jerk(1.0 - h)) / h < 1e-9);
    }

    #[test]
    fn wrist_speed_is_single_peaked_and_the_aperture_peaks_at_60_to_80_percent() {
        for object in ObjectKind::ALL {
            for p in 0..5 {
                let (input, demo) = clean_trial(object, p, 2 * p + 1);
                let v = wrist_speed(&input);
                let peak = v.iter().cloned().fold(0.0, f64::max);
                assert_eq!(local_maxima(&v, 0.01 * peak), 1, "{object:?} p{p}");
                let (on, off) = movement_window(&input);
                let ap = apertures(&demo);
                let k = (0..ap.len()).fold(0, |b, k| if ap[k] > ap[b] { k } else { b });
                let timing = (demo.frames[k].t - on) / (off - on);
                assert!((0.6..=0.8).contains(&timing), "{object:?} p{p}: {timing}");
            }
        }
    }

    #[test]
    fn peak_aperture_grows_with_object_size() {
        let mut by_size: Vec<(f64, f64)> = ObjectKind::ALL
            .iter()
            .map(|&o| {
                let mean = (0..10)
                    .map(|k| {
                        apertures(&clean_trial(o, k % 5, k).1)
                            .into_iter()
                            .fold(0.0, f64::max)
                    })
                    .sum::<f64>()
                    / 10.0;
                (o.grasp_size(), mean)
            })
            .collect();
        by_size.sort_by(|a, b| a.0.total_cmp(&b.0));
        for w in by_size.windows(2) {
            assert!(w[1].1 > w[0].1, "{by_size:?}");
        }
        // And every peak aperture exceeds the object it prepares for.
        assert!(by_size.iter().all(|(size, mga)| mga > size));
    }

    #[test]
    fn the_hand_ends_closed_on_the_object_with_joints_inside_human_ranges() {
        let cfg = StudyConfig {
            noise: false,
            ..StudyConfig::default()
        };
        let study = generate_study(&StudyConfig { trials: 2, ..cfg }).unwrap();
        assert_eq!(study.len(), 50);
        let spec = hand_spec(&HandDims::default(), Handedness::Right);
        let limits: Vec<(f64, f64)> = spec
            .iter()
            .filter(|j| j.axis.is_some())
            .map(|j| (j.lower, j.upper))
            .collect();
        let (mut contacts, mut checked) = (0, 0);
        for input in &study {
            let demo = ingest(input).unwrap();
            let last = demo.frames.last().unwrap();
            let obj = input.object.pose.to_isometry();
            for f in [0, 1] {
                let local = obj.inverse() * Point3::from(last.fingertips[f].translation.vector);
                let d = input.object.shape.signed_distance(&local.coords);
                assert!(
                    d.abs() < 0.015,
                    "{} finger {f}: {d}",
                    input.labels.external_id.as_ref().unwrap()
                );
                // Pad contact: the tip's centre line sits a pad's half thickness (4 mm) out.
                contacts += usize::from((d - 0.004).abs() < 0.001);
                checked += 1;
            }
            // Wrist near the object: within a hand length of its centre.
            let w = last.wrist.translation.vector;
            assert!((w - obj.translation.vector).norm() < input.subject.hand_length_m);
            for row in input.glove.angles.as_ref().unwrap() {
                for (k, &(lo, hi)) in limits.iter().enumerate() {
                    assert!(
                        row[k] >= lo - 1e-9 && row[k] <= hi + 1e-9,
                        "channel {k}: {}",
                        row[k]
                    );
                }
                // Wrist flexion (−70..80°) and deviation (−20..35°) of the arm model.
                assert!((-70f64.to_radians()..=80f64.to_radians()).contains(&row[20]));
                assert!(
                    (-20f64.to_radians()..=35f64.to_radians()).contains(&row[21]),
                    "{}",
                    row[21].to_degrees()
                );
            }
            let arm = input.subject.arm_dims().unwrap();
            let tr = &input.tracker;
            for k in 0..tr.t.len() {
                let p = |v: &Vec<f64>| Vector3::new(v[0], v[1], v[2]);
                let (s, e, w) = (p(&tr.shoulder[k]), p(&tr.elbow[k]), p(&tr.wrist[k]));
                let (upper, fore) = (e - s, w - e);
                assert!((upper.norm() - arm.upper_arm).abs() < 1e-9);
                assert!((fore.norm() - arm.forearm).abs() < 1e-9);
                let flexion = upper.angle(&fore).to_degrees();
                assert!((0.0..=150.0).contains(&flexion), "elbow {flexion}");
                // The elbow hangs below the shoulder-wrist line or level with it.
                assert!(e.z <= s.z + 1e-9);
            }
        }
        assert!(
            contacts as f64 >= 0.95 * checked as f64,
            "{contacts}/{checked} thumb/index pads touch"
        );
    }

    #[test]
    fn the_generator_is_deterministic_per_seed() {
        let cfg = StudyConfig {
            subjects: 2,
            positions: 2,
            trials: 2,
            ..StudyConfig::default()
        };
        let a = generate_study(&cfg).unwrap();
        let b = generate_study(&cfg).unwrap();
        assert_eq!(a, b);
        let c = generate_study(&StudyConfig {
            seed: 2,
            ..cfg.clone()
        })
        .unwrap();
        assert_ne!(a[0].tracker.wrist, c[0].tracker.wrist);
        // A trial does not depend on which other trials are generated.
        let one = generate_study(&StudyConfig {
            subjects: 1,
            positions: 1,
            trials: 1,
            ..cfg
        })
        .unwrap();
        assert_eq!(one[0], a[0]);
    }

    #[test]
    fn the_default_study_is_the_papers_design_and_labelled_synthetic() {
        let cfg = StudyConfig::default();
        assert_eq!(cfg.len(), 250);
        let trials = cfg.trials();
        assert_eq!(trials.len(), 250);
        let subjects = cfg.study_subjects();
        let statures: Vec<f64> = subjects.iter().map(|s| s.stature_m).collect();
        assert!(
            statures.iter().cloned().fold(0.0, f64::max)
                - statures.iter().cloned().fold(9.0, f64::min)
                > 0.15
        );
        // Every subject meets every object once, each object at every position across subjects.
        for s in 0..5 {
            let mut objs: Vec<_> = trials
                .iter()
                .filter(|t| t.subject_index == s && t.trial == 0)
                .map(|t| t.object)
                .collect();
            objs.sort_by_key(|o| o.name());
            objs.dedup();
            assert_eq!(objs.len(), 5);
        }
        let demo = generate_trial(&trials[17], cfg.seed).unwrap();
        assert!(demo.labels.synthetic);
        assert!(
            demo.labels
                .external_id
                .as_ref()
                .unwrap()
                .starts_with("synth-1-")
        );
        assert!(
            StudyConfig {
                trials: 0,
                ..StudyConfig::default()
            }
            .validate()
            .is_err()
        );
        assert!(
            StudyConfig {
                positions: 6,
                ..StudyConfig::default()
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn sensor_noise_matches_the_stated_accuracy() {
        let spec = |noise| {
            let cfg = StudyConfig {
                noise,
                ..StudyConfig::default()
            };
            generate_study(&StudyConfig {
                subjects: 1,
                positions: 1,
                trials: 1,
                ..cfg
            })
            .unwrap()
            .remove(0)
        };
        let (noisy, clean) = (spec(true), spec(false));
        let mut pos = Vec::new();
        for (a, b) in noisy.tracker.shoulder.iter().zip(&clean.tracker.shoulder) {
            pos.extend(a.iter().zip(b).map(|(x, y)| x - y));
        }
        let sd = (pos.iter().map(|d| d * d).sum::<f64>() / pos.len() as f64).sqrt();
        let stated = 0.03 * 0.0254;
        assert!(sd > 0.3 * stated && sd < 0.7 * stated, "{sd}");
        let mut ang = Vec::new();
        for (a, b) in noisy
            .glove
            .angles
            .as_ref()
            .unwrap()
            .iter()
            .zip(clean.glove.angles.as_ref().unwrap())
        {
            ang.extend(a.iter().zip(b).map(|(x, y)| x - y));
        }
        let sd = (ang.iter().map(|d| d * d).sum::<f64>() / ang.len() as f64)
            .sqrt()
            .to_degrees();
        assert!(sd > 0.3 && sd < 0.7, "{sd}");
        // Noisy data still ingests.
        assert!(ingest(&noisy).is_ok());
    }
}
