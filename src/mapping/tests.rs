//! Whole-demonstration tests on the `human` synthetic generator and the six shipped systems.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use super::objective::tests::{SYSTEMS, system};
use super::*;
use crate::human::{HumanFrame, StudyConfig, generate_study, ingest};
use crate::kinematics::{Data, JointKind, System, forward_kinematics};

/// `n` synthetic demonstrations (different subjects and object positions), noise on.
fn demos(n: usize, seed: u64) -> Vec<Vec<HumanFrame>> {
    demos_with_objects(n, seed)
        .into_iter()
        .map(|(frames, _)| frames)
        .collect()
}

/// [`demos`] with each demonstration's object, which the service registers onto its placement
/// ([`RegistrationSpec::for_object`]).
fn demos_with_objects(n: usize, seed: u64) -> Vec<(Vec<HumanFrame>, HumanObject)> {
    let cfg = StudyConfig {
        seed,
        subjects: n.min(5),
        positions: n.div_ceil(n.min(5)).min(5),
        trials: 1,
        rate_hz: 60.0,
        ..StudyConfig::default()
    };
    generate_study(&cfg)
        .unwrap()
        .iter()
        .take(n)
        .map(|d| {
            let demo = ingest(d).unwrap();
            (demo.frames, human_object(&demo.object))
        })
        .collect()
}

fn mapper(sys: &System, weights: Weights) -> Mapper {
    Mapper::new(
        MappingModel::from_system(sys).unwrap(),
        weights,
        SolverOptions::default(),
    )
    .unwrap()
}

/// Every joint (mimic ones included) within its own limits, every coupling exact: the child
/// frame of each moving joint sits where `origin · motion(multiplier·q + offset)` puts it.
fn check_limits_and_couplings(sys: &System, q: &[f64], data: &mut Data) {
    let model = &sys.model;
    forward_kinematics(model, data, q);
    for joint in model.joints() {
        let Some(act) = joint.actuation else { continue };
        let v = act.multiplier * q[act.q_index] + act.offset;
        if !matches!(joint.kind, JointKind::Continuous { .. }) {
            assert!(
                v >= joint.limits.lower - 1e-12 && v <= joint.limits.upper + 1e-12,
                "joint {} at {v} outside [{}, {}]",
                joint.name,
                joint.limits.lower,
                joint.limits.upper
            );
        }
        let motion = match joint.kind {
            JointKind::Revolute { axis } | JointKind::Continuous { axis } => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&axis, v),
            ),
            JointKind::Prismatic { axis } => Isometry3::from_parts(
                Translation3::from(axis.into_inner() * v),
                UnitQuaternion::identity(),
            ),
            JointKind::Fixed => continue,
        };
        let want = data.frame(joint.parent) * joint.origin * motion;
        let got = data.frame(joint.child);
        assert!(
            (want.translation.vector - got.translation.vector).norm() < 1e-12
                && want.rotation.angle_to(&got.rotation) < 1e-9,
            "coupling of {} broken",
            joint.name
        );
    }
    for pair in &sys.spread_pairs {
        let (a, b) = (pair.lower, pair.upper);
        let va = a.multiplier * q[a.q_index] + a.offset;
        let vb = b.multiplier * q[b.q_index] + b.offset;
        assert!(
            va <= vb + 1e-12,
            "spread order {} <= {} broken",
            pair.lower_joint,
            pair.upper_joint
        );
    }
}

#[test]
fn limits_couplings_spread_order_and_step_bound_hold_on_every_frame_for_all_systems() {
    let demo = &demos(1, 21)[0];
    for name in SYSTEMS {
        let sys = system(name);
        let mm = MappingModel::from_system(&sys).unwrap();
        let anchor = mm.anchor();
        let mut m = mapper(&sys, Weights::default());
        let traj = m.map(demo, &RegistrationSpec::default(), &anchor).unwrap();
        assert_eq!(traj.metrics.len(), demo.len());
        assert_eq!(traj.joint_names, sys.model.joint_names());
        let mut data = Data::new(&sys.model);
        let opts = SolverOptions::default();
        let vmax = sys.model.velocity_limits();
        for k in 0..demo.len() {
            check_limits_and_couplings(&sys, traj.frame(k), &mut data);
            if k > 0 {
                let dt = traj.times[k] - traj.times[k - 1];
                for (i, (a, b)) in traj.frame(k - 1).iter().zip(traj.frame(k)).enumerate() {
                    let v = if vmax[i].is_finite() && vmax[i] > 0.0 {
                        vmax[i]
                    } else {
                        opts.fallback_speed
                    };
                    let bound = opts.step_scale * v * dt;
                    assert!(
                        (b - a).abs() <= bound * (1.0 + 1e-9),
                        "{name}: joint {i} jumps at frame {k}"
                    );
                }
            }
        }
        let unconverged = traj.unconverged().count();
        assert!(
            unconverged * 10 <= demo.len(),
            "{name}: {unconverged} of {} frames did not converge",
            demo.len()
        );
    }
}

fn mean_errors(traj: &MappedTrajectory) -> (f64, f64) {
    let n = traj.metrics.len() as f64;
    let tip = traj
        .metrics
        .iter()
        .map(|m| m.position_error[..m.fingers].iter().sum::<f64>() / m.fingers as f64)
        .sum::<f64>()
        / n;
    let elbow = traj
        .metrics
        .iter()
        .map(|m| m.elbow_distance_mean)
        .sum::<f64>()
        / n;
    (tip, elbow)
}

/// Paper Fig. 2: with the anthropomorphism term the robot's elbow-term joints stay clearly closer
/// to the human elbow, while the fingertips are tracked nearly as well.
#[test]
fn fig2_elbow_term_brings_the_robot_elbow_to_the_human_elbow_at_little_fingertip_cost() {
    let demos = demos_with_objects(3, 5);
    // Eq. 4 alone (the paper's term); the swivel term is checked on the study below.
    let with = Weights {
        swivel: 0.0,
        ..Weights::default()
    };
    let without = with.without_anthropomorphism();
    for name in SYSTEMS {
        let sys = system(name);
        let anchor = MappingModel::from_system(&sys).unwrap().anchor();
        let (mut tip_w, mut elbow_w, mut tip_0, mut elbow_0) = (0.0, 0.0, 0.0, 0.0);
        for (demo, object) in &demos {
            let spec = RegistrationSpec::default().for_object(Some(*object));
            let a = mapper(&sys, with).map(demo, &spec, &anchor).unwrap();
            let b = mapper(&sys, without).map(demo, &spec, &anchor).unwrap();
            let (t, e) = mean_errors(&a);
            tip_w += t / demos.len() as f64;
            elbow_w += e / demos.len() as f64;
            let (t, e) = mean_errors(&b);
            tip_0 += t / demos.len() as f64;
            elbow_0 += e / demos.len() as f64;
        }
        println!(
            "fig2 {name}: elbow distance {:.1} mm (w_D > 0) vs {:.1} mm (w_D = 0); \
             fingertip error {:.1} mm vs {:.1} mm",
            elbow_w * 1e3,
            elbow_0 * 1e3,
            tip_w * 1e3,
            tip_0 * 1e3
        );
        // "Clearly lower": at least 30 mm closer on average (the arms' link lengths differ
        // from the subject's, so the distance cannot vanish); "modest": at most 5 mm more
        // fingertip error on average.
        assert!(
            elbow_w < elbow_0 - 0.03,
            "{name}: elbow {elbow_w} vs {elbow_0}"
        );
        assert!(
            tip_w <= tip_0 + 0.005,
            "{name}: fingertip {tip_w} vs {tip_0}"
        );
    }
}

#[test]
fn batch_mapping_matches_sequential_mapping_and_reports_progress() {
    let demos = demos(3, 9);
    let sys = system("wam_t42");
    let mm = MappingModel::from_system(&sys).unwrap();
    let anchor = mm.anchor();
    let spec = RegistrationSpec::default();
    let items: Vec<BatchItem> = demos
        .iter()
        .map(|d| BatchItem {
            frames: d,
            registration: &spec,
        })
        .collect();
    let calls = AtomicUsize::new(0);
    let progress = |done: usize, total: usize| {
        assert!(done <= total && total == 3);
        calls.fetch_add(1, Ordering::Relaxed);
    };
    let cancel = AtomicBool::new(false);
    let out = map_batch(
        &mm,
        &anchor,
        &items,
        Weights::default(),
        SolverOptions::default(),
        2,
        &progress,
        &cancel,
    )
    .unwrap();
    assert_eq!(calls.load(Ordering::Relaxed), 3);
    // The batch solves every first frame on the calling thread first; sequential mapping from
    // those same starts (on fresh mappers) is the batch.
    let starts = batch_starts(
        &mut mapper(&sys, Weights::default()),
        &anchor,
        &items,
        &cancel,
    )
    .expect("not cancelled");
    for ((d, r), start) in demos.iter().zip(out).zip(starts) {
        let seq = mapper(&sys, Weights::default())
            .map_from(d, &spec, &anchor, &start.expect("valid"))
            .unwrap();
        assert_eq!(
            r.unwrap(),
            seq,
            "a worker's result must not depend on scheduling"
        );
    }
    cancel.store(true, Ordering::Relaxed);
    let err = map_batch(
        &mm,
        &anchor,
        &items,
        Weights::default(),
        SolverOptions::default(),
        2,
        &progress,
        &cancel,
    )
    .unwrap_err();
    assert_eq!(
        err,
        Cancelled {
            completed: 0,
            total: 3
        }
    );
}

/// Largest range (max − min over demonstrations) of any first-frame value of the arm joints
/// that place the wrist: the IK branch. Left out:
/// - the hand joints, which follow each demonstration's own fingertip goals (with the iHY's
///   closure limit of 1.1 rad, finger 2 saturates on a few rest poses and finger 1's spread
///   takes up the aperture, 0.6 vs 1.3 rad);
/// - the last arm joint, the flange roll about the hand's own axis (PA10 S3, WAM joint 7): it
///   turns the hand to fit those fingertips and is no branch. Measured on pa10_ihy: the roll
///   spreads 0.85 rad (2.50–3.34) over ten rest poses whose finger apertures differ, while every
///   other arm joint stays within 0.44 rad on one branch (shoulder and elbow identical to 1e-3).
fn first_frame_spread(trajs: &[MappedTrajectory], sys: &System) -> f64 {
    let (_, wrist_placing) = sys.arm_joints.split_last().expect("an arm");
    wrist_placing
        .iter()
        .map(|&j| {
            let v = trajs.iter().map(|t| t.frame(0)[j]);
            v.clone().fold(f64::NEG_INFINITY, f64::max) - v.fold(f64::INFINITY, f64::min)
        })
        .fold(0.0, f64::max)
}

fn batch(
    sys: &System,
    demos: &[(Vec<HumanFrame>, HumanObject)],
    options: SolverOptions,
) -> Vec<MappedTrajectory> {
    map_study_with(
        sys,
        demos,
        &RegistrationSpec::default(),
        Weights::default(),
        options,
    )
}

/// Humanlike across a batch: the synthetic subjects start every trial from near-identical rest
/// poses, so one batch maps them to near-identical robot postures instead of to different IK
/// branches. Mapped alone, the first frames of these 10 demonstrations spread over several rad.
#[test]
fn a_batch_maps_near_identical_rest_poses_to_near_identical_first_postures() {
    let demos = demos_with_objects(10, 1);
    for name in SYSTEMS {
        let sys = system(name);
        let mm = MappingModel::from_system(&sys).unwrap();
        let spec = RegistrationSpec::default();
        // What a batch keeps consistent is the frame chain, the weighted solve's postures and
        // objectives; without the fingertip-priority stage the outputs are the chain.
        let single = SolverOptions {
            fingertip_priority: 1.0,
            ..SolverOptions::default()
        };
        let alone: Vec<MappedTrajectory> = demos
            .iter()
            .map(|(d, o)| {
                Mapper::new(mm.clone(), Weights::default(), single)
                    .unwrap()
                    .map(d, &spec.for_object(Some(*o)), &mm.anchor())
                    .unwrap()
            })
            .collect();
        let trajs = batch(&sys, &demos, single);
        let (spread, spread_alone) = (
            first_frame_spread(&trajs, &sys),
            first_frame_spread(&alone, &sys),
        );
        println!("{name}: first-frame spread {spread:.3} rad in a batch, {spread_alone:.3} alone");
        assert!(
            spread < FIRST_FRAME_SPREAD_BOUND,
            "{name}: spread {spread} rad"
        );
        // wam_ob4f has a single branch here: both spreads are the same to 1e-3 rad.
        assert!(
            spread <= spread_alone + 0.01,
            "{name}: {spread} vs {spread_alone}"
        );
        let f = |t: &[MappedTrajectory]| {
            let mut v: Vec<f64> = t.iter().map(|t| t.metrics[0].objective).collect();
            v.sort_by(f64::total_cmp);
            (
                v[v.len() / 2],
                v[v.len() - 1],
                t.iter().filter(|t| !t.metrics[0].converged).count(),
            )
        };
        let ((med, max, unconv), (med_a, max_a, unconv_a)) = (f(&trajs), f(&alone));
        println!(
            "   F median / max / unconverged: batch {med:.3e} / {max:.3e} / {unconv}, alone {med_a:.3e} / {max_a:.3e} / {unconv_a}"
        );
        // Consistency costs little accuracy: the median first frame is as good as the
        // multi-start's; the worst one may be a little worse (one branch for all; measured with
        // the scene-keeping registration: pa10_t42 1.713e-2 vs 1.602e-2 and pa10_ihy 1.947e-2 vs
        // 1.823e-2, +7 %; the others within 2 %). (The `converged` flag at the 1e-7 first-frame tolerance differs by a frame
        // or two either way, so it is printed, not compared.)
        assert!(med <= 1.05 * med_a && max <= 1.10 * max_a, "{name}");
    }
}

/// Measured 0.23-0.52 rad on `demos(10, 1)` with the former shoulder-anchored registration
/// (wam_ihy then split into two wrist branches across subjects), 0.21-0.38 rad on every system
/// with the scene-keeping one and each demonstration's object.
const FIRST_FRAME_SPREAD_BOUND: f64 = 0.6;

/// Tuning probe (not a check): per system, the first-frame spread mapped alone vs in a batch,
/// and the ratio of the local (from the reference) to the multi-start first-frame objective.
#[test]
#[ignore]
fn probe_first_frame_reference() {
    let demos = demos_with_objects(25, 1);
    for name in SYSTEMS {
        let sys = system(name);
        let mm = MappingModel::from_system(&sys).unwrap();
        let anchor = mm.anchor();
        let spec = RegistrationSpec::default();
        let alone: Vec<MappedTrajectory> = demos
            .iter()
            .map(|(d, o)| {
                mapper(&sys, Weights::default())
                    .map(d, &spec.for_object(Some(*o)), &anchor)
                    .unwrap()
            })
            .collect();
        let never = SolverOptions {
            first_frame_fallback: 1e300,
            ..SolverOptions::default()
        };
        let local = batch(&sys, &demos, never);
        let with = batch(&sys, &demos, SolverOptions::default());
        let mut ratios: Vec<f64> = local
            .iter()
            .zip(&alone)
            .map(|(l, a)| l.metrics[0].objective / a.metrics[0].objective)
            .collect();
        ratios.sort_by(f64::total_cmp);
        let fell_back = with
            .iter()
            .zip(&local)
            .filter(|(w, l)| w.frame(0) != l.frame(0))
            .count();
        println!(
            "{name}: spread alone {:.3}, batch (no fallback) {:.3}, batch {:.3}; local/multi F ratio min {:.3} median {:.3} max {:.3}; fell back {fell_back}/{}",
            first_frame_spread(&alone, &sys),
            first_frame_spread(&local, &sys),
            first_frame_spread(&with, &sys),
            ratios[0],
            ratios[ratios.len() / 2],
            ratios[ratios.len() - 1],
            demos.len()
        );
        for (j, name) in with[0].joint_names.iter().enumerate() {
            let v: Vec<f64> = with.iter().map(|t| t.frame(0)[j]).collect();
            let r = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                - v.iter().cloned().fold(f64::INFINITY, f64::min);
            if r > 0.1 {
                println!(
                    "   {name} range {r:.3}: {:?}",
                    v.iter()
                        .map(|x| (x * 100.0).round() / 100.0)
                        .collect::<Vec<_>>()
                );
            }
        }
    }
}

#[test]
fn a_frame_that_does_not_converge_is_reported() {
    let demo = &demos(1, 4)[0];
    let sys = system("pa10_ob4f");
    let anchor = MappingModel::from_system(&sys).unwrap().anchor();
    let opts = SolverOptions {
        max_iterations: 1,
        first_frame_max_iterations: 1,
        first_frame_starts: 1,
        priority_max_iterations: 1,
        ..SolverOptions::default()
    };
    let mut m = Mapper::new(
        MappingModel::from_system(&sys).unwrap(),
        Weights::default(),
        opts,
    )
    .unwrap();
    let traj = m.map(demo, &RegistrationSpec::default(), &anchor).unwrap();
    assert!(traj.unconverged().count() > 0);
    // One iteration of the weighted solve and one of the fingertip-priority stage.
    assert!(traj.metrics.iter().all(|m| m.iterations <= 2));
}

#[test]
fn bad_frames_are_rejected_naming_the_frame() {
    let mut demo = demos(1, 2)[0].clone();
    let sys = system("wam_ihy");
    let anchor = MappingModel::from_system(&sys).unwrap().anchor();
    let mut m = mapper(&sys, Weights::default());
    let spec = RegistrationSpec::default();
    assert_eq!(
        m.map(&[], &spec, &anchor).unwrap_err(),
        MappingError::EmptyDemonstration
    );
    let t3 = demo[3].t;
    demo[4].t = t3;
    assert!(matches!(
        m.map(&demo, &spec, &anchor).unwrap_err(),
        MappingError::NonIncreasingTime { frame: 4, .. }
    ));
    demo[4].t = t3 + 1e-3;
    demo[7].fingertips[1].translation.vector.x = f64::NAN;
    assert_eq!(
        m.map(&demo, &spec, &anchor).unwrap_err(),
        MappingError::NonFinite {
            frame: 7,
            field: "fingertips"
        }
    );
}

/// Tuning probe (not a check): iterations and objective gap for a few tolerances.
#[test]
#[ignore]
fn probe_tolerances() {
    let frames = &demos(1, 1)[0];
    let sys = system("wam_ihy");
    let mm = MappingModel::from_system(&sys).unwrap();
    let anchor = mm.anchor();
    let reg = registration_for(frames, &RegistrationSpec::default(), &anchor).unwrap();
    let tight = SolverOptions {
        tolerance: 1e-10,
        first_frame_tolerance: 1e-10,
        max_iterations: 5000,
        ..SolverOptions::default()
    };
    let mut r = Mapper::new(mm.clone(), Weights::default(), tight).unwrap();
    let mut goals = vec![FrameGoals::default(); frames.len()];
    for (f, g) in frames.iter().zip(goals.iter_mut()) {
        r.goals(f, &reg, g);
    }
    let mut refs = vec![r.solve_first(&goals[0], 0.0).objective];
    for k in 1..frames.len() {
        refs.push(
            r.solve_next(&goals[k], 0.0, frames[k].t - frames[k - 1].t)
                .objective,
        );
    }
    for (tol, iters) in [(1e-6, 500), (1e-5, 100), (1e-4, 50), (1e-4, 20), (1e-3, 20)] {
        let o = SolverOptions {
            tolerance: tol,
            max_iterations: iters,
            ..SolverOptions::default()
        };
        let mut m = Mapper::new(mm.clone(), Weights::default(), o).unwrap();
        m.solve_first(&goals[0], 0.0);
        let (mut it, mut gaps, mut nc) = (0, Vec::new(), 0);
        for k in 1..frames.len() {
            let x = m.solve_next(&goals[k], 0.0, frames[k].t - frames[k - 1].t);
            it += x.iterations;
            nc += usize::from(!x.converged);
            gaps.push((x.objective - refs[k]) / refs[k]);
        }
        gaps.sort_by(f64::total_cmp);
        println!(
            "tol {tol:e} cap {iters}: mean iters {:.1}, unconverged {nc}/{}, gap median {:.4} % max {:.4} %",
            it as f64 / (frames.len() - 1) as f64,
            frames.len() - 1,
            100.0 * gaps[gaps.len() / 2],
            100.0 * gaps[gaps.len() - 1]
        );
    }
}

/// At the demonstration's own rate the frames come back (to rounding); at half the rate every
/// second frame does; between frames the points are the linear interpolants.
#[test]
fn resampling_at_the_own_rate_reproduces_the_frames_and_interpolates_between_them() {
    let frames = &demos(1, 5)[0];
    let rate = 1.0 / (frames[1].t - frames[0].t);
    let same = resample_frames(frames, rate);
    assert_eq!(same.len(), frames.len());
    let close = |a: &HumanFrame, b: &HumanFrame| {
        (a.t - b.t).abs() < 1e-9
            && (a.elbow - b.elbow).norm() < 1e-9
            && (a.fingertips[3].translation.vector - b.fingertips[3].translation.vector).norm()
                < 1e-9
            && a.wrist.rotation.angle_to(&b.wrist.rotation) < 1e-9
    };
    assert!(same.iter().zip(frames).all(|(a, b)| close(a, b)));
    let half = resample_frames(frames, rate / 2.0);
    assert_eq!(half.len(), frames.len().div_ceil(2));
    assert!(
        half.iter()
            .zip(frames.iter().step_by(2))
            .all(|(a, b)| close(a, b))
    );
    let double = resample_frames(frames, rate * 2.0);
    assert_eq!(double.len(), 2 * frames.len() - 1);
    let mid = &double[1];
    let want = (frames[0].shoulder.coords + frames[1].shoulder.coords) / 2.0;
    assert!((mid.shoulder.coords - want).norm() < 1e-12);
    assert!(resample_frames(&[], 10.0).is_empty());
}

/// The default study's design at one trial per subject and position (5 × 5 = 25
/// demonstrations, every object at every position across subjects), at the seeding's 30 Hz:
/// frames and each demonstration's object.
fn study(trials: usize) -> Vec<(Vec<HumanFrame>, HumanObject)> {
    let cfg = StudyConfig {
        trials,
        ..StudyConfig::default()
    };
    generate_study(&cfg)
        .unwrap()
        .iter()
        .map(|d| {
            let demo = ingest(d).unwrap();
            (
                resample_frames(&demo.frames, 30.0),
                human_object(&demo.object),
            )
        })
        .collect()
}

fn map_study(
    sys: &System,
    study: &[(Vec<HumanFrame>, HumanObject)],
    spec: &RegistrationSpec,
    weights: Weights,
) -> Vec<MappedTrajectory> {
    map_study_with(sys, study, spec, weights, SolverOptions::default())
}

fn map_study_with(
    sys: &System,
    study: &[(Vec<HumanFrame>, HumanObject)],
    spec: &RegistrationSpec,
    weights: Weights,
    options: SolverOptions,
) -> Vec<MappedTrajectory> {
    let mm = MappingModel::from_system(sys).unwrap();
    let specs: Vec<RegistrationSpec> = study
        .iter()
        .map(|(_, o)| spec.for_object(Some(*o)))
        .collect();
    let items: Vec<BatchItem> = study
        .iter()
        .zip(&specs)
        .map(|((frames, _), registration)| BatchItem {
            frames,
            registration,
        })
        .collect();
    map_batch(
        &mm,
        &mm.anchor(),
        &items,
        weights,
        options,
        2,
        &|_, _| {},
        &AtomicBool::new(false),
    )
    .unwrap()
    .into_iter()
    .map(Result::unwrap)
    .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn quantile95(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((0.95 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1]
}

/// The scene is kept: every registered object rests on the robot's table exactly as the
/// subject's rested on theirs. The reference is independent of the registration code: the
/// height of the human object above the tracker table from the object's own signed distance
/// (`ObjectShape::signed_distance` at the table point under its centre), against parry's exact
/// distance between the registered object's collision shape and the robot's support plane.
#[test]
fn registered_objects_rest_on_the_robot_table_and_a_given_placement_is_met() {
    let study = study(1);
    let sys = system("wam_t42");
    let anchor = MappingModel::from_system(&sys).unwrap().anchor();
    for (frames, object) in &study {
        let spec = RegistrationSpec::default().for_object(Some(*object));
        let reg = registration_for(frames, &spec, &anchor).unwrap();
        let c = object.pose.translation.vector;
        let under = nalgebra::Vector3::new(c.x, c.y, 0.0);
        let human_gap = object
            .shape
            .signed_distance(&(object.pose.inverse() * nalgebra::Point3::from(under)).coords);
        let scene = scene_of(&reg);
        let (o, plane) = (scene.object.unwrap(), scene.support.unwrap());
        let sd = crate::geometry::half_space_distance(o.solid(), o.pose(), &plane.0);
        assert!(
            (sd.distance - human_gap).abs() < 1e-6,
            "object {:?}: {} m above the robot table, {human_gap} m above the subject's",
            object.shape,
            sd.distance
        );
        // Inside the reach, in front of the robot.
        assert!(
            reg.robot_anchor.x > 0.2 && (reg.robot_anchor - anchor.shoulder).norm() < anchor.reach
        );
    }
    // Placements given per request: the seeded objects' documented reachable placements.
    for &(x, y) in &crate::grasp::objects::REACHABLE_PLACEMENTS {
        for (frames, object) in study.iter().take(5) {
            let c = object.pose.translation.vector;
            let p = nalgebra::Point3::new(x, y, c.z);
            let spec = RegistrationSpec::Scene(SceneRegistration {
                placement: Some(p),
                ..SceneRegistration::default()
            })
            .for_object(Some(*object));
            let reg = registration_for(frames, &spec, &anchor).unwrap();
            let got = reg.point(&nalgebra::Point3::from(c));
            assert!((got - p).norm() < 0.01, "{got} vs {p}");
            let placed = reg.object.unwrap().pose.translation.vector;
            assert!((placed - p.coords).norm() < 0.01);
        }
    }
}

/// The claims of issue 16 on the default study (one trial per subject and position) mapped onto
/// each shipped system: no frame below the support plane or inside the object before the last
/// 10 % of the reach (exact parry clearances); humanlike swivel (median difference within 15° of
/// the smallest the joint limits allow, with the default weights, the anthropomorphism-off
/// baseline printed beside it); mean elbow distance within 5 cm of the smallest the joint limits
/// allow; median and p95 fingertip error printed, and on the frames where the robot can put its
/// fingertips the fingertip-priority stage brings them nearer than the single weighted sum.
#[test]
fn default_study_is_mapped_above_the_table_with_humanlike_elbows_on_every_system() {
    let study = study(1);
    let spec = RegistrationSpec::default();
    let mut failures = Vec::new();
    for name in SYSTEMS {
        let sys = system(name);
        let with = map_study(&sys, &study, &spec, Weights::default());
        let base = map_study(
            &sys,
            &study,
            &spec,
            Weights::default().without_anthropomorphism(),
        );
        let (swivel, elbow, bound, tip, tip95) = study_stats(&with);
        let (swivel0, elbow0, bound0, tip0, tip950) = study_stats(&base);
        println!(
            "{name}: swivel diff median {swivel:.1}° (baseline {swivel0:.1}°); elbow distance mean \
             {:.1} mm, bound {:.1} mm (baseline {:.1} / {:.1}); fingertip error median {:.2} mm \
             p95 {:.2} mm (baseline {:.2} / {:.2})",
            elbow * 1e3,
            bound * 1e3,
            elbow0 * 1e3,
            bound0 * 1e3,
            tip * 1e3,
            tip95 * 1e3,
            tip0 * 1e3,
            tip950 * 1e3
        );
        // One branch across subjects and positions: printed, not checked here (measured 0.31-0.52
        // rad on four systems; wam_ob4f 1.13 and pa10_ob4f 0.72 rad, where the study's subjects
        // start from rest poses further apart than the batch test's).
        let spread = first_frame_spread(&with, &sys);
        println!("   first-frame spread over the study {spread:.3} rad");
        let z_min = lowest_elbow_height(&sys);
        let floors = elbow_floors(&sys, &study, &with, z_min);
        let floors0 = elbow_floors(&sys, &study, &base, z_min);
        // The floors are lower bounds: no frame may beat them (a check of the bounds themselves).
        let beaten = floors
            .iter()
            .chain(&floors0)
            .filter(|f| f[1] < f[0] - 1e-6 || f[3] < f[2] - 1e-6)
            .count();
        if beaten > 0 {
            failures.push(format!("{name}: {beaten} frames beat the elbow floors"));
        }
        let stats = |f: &[[f64; 4]]| {
            (
                median(f.iter().map(|f| f[0].to_degrees()).collect()),
                median(f.iter().map(|f| (f[1] - f[0]).to_degrees()).collect()),
                f.iter().map(|f| f[2]).sum::<f64>() / f.len() as f64,
                f.iter().map(|f| f[3] - f[2]).sum::<f64>() / f.len() as f64,
            )
        };
        let (swivel_floor, swivel_excess, elbow_floor, elbow_excess) = stats(&floors);
        let (_, swivel_excess0, _, elbow_excess0) = stats(&floors0);
        println!(
            "   lowest elbow {z_min:.3} m ({} frames): swivel floor median {swivel_floor:.1}°, \
             above it {swivel_excess:.1}° (baseline {swivel_excess0:.1}°); elbow floor mean \
             {:.1} mm, above it {:.1} mm (baseline {:.1} mm)",
            floors.len(),
            elbow_floor * 1e3,
            elbow_excess * 1e3,
            elbow_excess0 * 1e3
        );
        let (worst_support, worst_object) = worst_clearances(&with);
        println!(
            "   smallest clearance: support {:.2} mm, object (first 90 %) {:.2} mm",
            worst_support * 1e3,
            worst_object * 1e3
        );
        let mut fail = |ok: bool, what: String| {
            if !ok {
                failures.push(format!("{name}: {what}"));
            }
        };
        fail(
            worst_support >= 0.0,
            format!("a link {worst_support} m below the support"),
        );
        fail(
            worst_object >= 0.0,
            format!("a link {worst_object} m inside the object"),
        );
        // The targets as the robots' joint limits allow them. Measured against the
        // bare link-length bounds, the swivel difference (55-70°) and elbow distance (14-26 cm
        // over) miss the issue's ≤ 15° and ≤ 5 cm: mounted on their table, the PA10's J2 limit
        // (±94° from vertical) keeps its elbow at or above 0.286 m and the WAM's keeps it above
        // 0.076 m, while a seated subject's elbow hangs near table height, so the humanlike
        // swivel is out of reach for most frames ([`ElbowCircle`]). Above those floors: ≤ 15°
        // swivel (measured 0.0-7.7°, baseline without the terms 17-88°) and ≤ 5 cm elbow
        // distance (measured 0.2-36 mm, baseline 67-249 mm), medians and means over the study.
        fail(
            swivel_excess <= 15.0,
            format!("swivel {swivel_excess}° above its floor"),
        );
        fail(
            elbow_excess <= 0.05,
            format!("elbow {elbow_excess} m above its floor"),
        );
        // And the terms matter: against the baseline without them.
        // (Measured 19-93° lower than the baseline; pa10_ihy the least.)
        fail(
            swivel <= swivel0 - 15.0,
            format!("swivel {swivel}° vs baseline {swivel0}°"),
        );
        fail(
            elbow <= elbow0 - 0.05,
            format!("elbow {elbow} m vs baseline {elbow0} m"),
        );
        // Fingertips ≤ 5 mm (median) where the robot can put them: on the frames a separate
        // fingertip-only solve with the clearance penalty ([`fingertip_reach`], every
        // `REACH_STRIDE`-th frame) gets every tip within 1 mm of its goal. Over all frames the
        // median is 24-32 mm (printed above): the robot hands' finger layouts differ from the
        // subject's hand, and the pads stay 5 mm off the table the subject's fingertips rest on.
        let probe = ReachProbe {
            stride: REACH_STRIDE,
            free: false,
            hand: false,
            full: None,
        };
        // Measured with the fingertip-priority stage on at its measured setting (`K = 1000`;
        // the default, `with` above, is the paper's single weighted sum): the stage must bring
        // the reachable frames' fingertips nearer than the single sum does.
        let prioritised_study = map_study_with(
            &sys,
            &study,
            &spec,
            Weights::default(),
            SolverOptions {
                fingertip_priority: 1e3,
                ..SolverOptions::default()
            },
        );
        let (ps, po) = worst_clearances(&prioritised_study);
        fail(
            ps >= 0.0 && po >= 0.0,
            format!(
                "with fingertip priority a link {ps} m from the support, {po} m from the object"
            ),
        );
        let reach = fingertip_reach(&sys, &study, &prioritised_study, &probe);
        let (mut prioritised, mut weighted, mut frames) = (Vec::new(), Vec::new(), 0);
        let mut at = reach.iter();
        for (traj, one) in prioritised_study.iter().zip(&with) {
            for k in (0..traj.times.len()).step_by(REACH_STRIDE) {
                let r = at.next().expect("one reach per checked frame");
                if r.clear <= 1e-3 {
                    frames += 1;
                    let tips = |m: &FrameMetrics| m.position_error[..m.fingers].to_vec();
                    prioritised.extend(tips(&traj.metrics[k]));
                    weighted.extend(tips(&one.metrics[k]));
                }
            }
        }
        let mm = |v: &[f64], f: fn(Vec<f64>) -> f64| {
            if v.is_empty() {
                f64::NAN
            } else {
                f(v.to_vec()) * 1e3
            }
        };
        println!(
            "   reachable frames {frames} of {}: fingertip error median {:.2} mm, p95 {:.2} mm \
             (single weighted sum {:.2} / {:.2} mm)",
            reach.len(),
            mm(&prioritised, median),
            mm(&prioritised, quantile95),
            mm(&weighted, median),
            mm(&weighted, quantile95),
        );
        if frames >= 5 {
            let (p, w) = (median(prioritised), median(weighted));
            fail(
                p < w,
                format!("reachable-frame fingertip error median {p} m, single weighted sum {w} m"),
            );
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Every how many frames the default-study test checks fingertip reachability (a tight
/// fingertip-only solve from two starts per checked frame).
const REACH_STRIDE: usize = 4;

/// The lowest height the robot's elbow frame reaches within the joint limits of the joints that
/// move it (found by perturbation), on a 2° grid over those joints, and not below the support
/// plane (z = 0: the elbow point lies inside its link's collision shape, which must stay above
/// the table). Independent of the mapping code: plain FK of the system.
pub(super) fn lowest_elbow_height(sys: &System) -> f64 {
    let mm = MappingModel::from_system(sys).unwrap();
    let model = &sys.model;
    let elbow = sys.elbow_frames[0];
    let mut data = Data::new(model);
    let q0 = mm.neutral();
    let height = |q: &[f64], data: &mut Data| {
        forward_kinematics(model, data, q);
        data.frame(elbow).translation.vector.z
    };
    let z0 = height(&q0, &mut data);
    let moving: Vec<usize> = (0..q0.len())
        .filter(|&i| {
            let mut q = q0.clone();
            [-0.4, 0.4].iter().any(|d| {
                q[i] = q0[i] + d;
                forward_kinematics(model, &mut data, &q);
                let p = data.frame(elbow).translation.vector;
                q[i] = q0[i] + d + 0.3;
                forward_kinematics(model, &mut data, &q);
                (data.frame(elbow).translation.vector - p).norm() > 1e-9
            })
        })
        .collect();
    assert!(moving.len() <= 3, "{:?}", moving);
    let grids: Vec<Vec<f64>> = moving
        .iter()
        .map(|&i| {
            let (l, u) = (mm.lower[i].max(-PI), mm.upper[i].min(PI));
            let n = ((u - l) / 2f64.to_radians()).ceil() as usize;
            (0..=n).map(|k| l + (u - l) * k as f64 / n as f64).collect()
        })
        .collect();
    // Every grid point: an odometer over the moving joints.
    let mut lowest = z0;
    let mut q = q0.clone();
    let mut at = vec![0; grids.len()];
    'grid: loop {
        for ((&i, g), &k) in moving.iter().zip(&grids).zip(&at) {
            q[i] = g[k];
        }
        lowest = lowest.min(height(&q, &mut data));
        for (k, g) in at.iter_mut().zip(&grids) {
            *k += 1;
            if *k < g.len() {
                continue 'grid;
            }
            *k = 0;
        }
        break;
    }
    lowest.max(0.0)
}

/// The elbow circle of a frame: where the robot's elbow can be given its shoulder `s`, its wrist
/// `w` and its link lengths, parametrised by the swivel `φ` from the circle's lowest point
/// ([`swivel_angle`]'s convention), and the smallest `|φ|` that keeps the elbow at or above
/// `z_min`: the circle's height is `z(φ) = c_z − r |r̂_z| cos φ` (the perpendicular direction
/// `â × r̂` is horizontal), so the allowed swivels are `|φ| ≥ acos((c_z − z_min) / (r |r̂_z|))`.
/// A necessary condition only: the other joint limits may forbid more. `None` when the wrist is
/// out of the links' reach or the axis is vertical.
pub(super) struct ElbowCircle {
    centre: nalgebra::Point3<f64>,
    radius: f64,
    /// Unit vectors across the axis: towards the lowest point, and `â × r̂`.
    low: nalgebra::Vector3<f64>,
    side: nalgebra::Vector3<f64>,
    /// Smallest allowed `|φ|`, rad.
    edge: f64,
}

impl ElbowCircle {
    pub(super) fn new(
        s: &nalgebra::Point3<f64>,
        w: &nalgebra::Point3<f64>,
        upper: f64,
        fore: f64,
        z_min: f64,
    ) -> Option<Self> {
        let axis = w - s;
        let d = axis.norm();
        let a = axis / d;
        let x = (upper * upper - fore * fore + d * d) / (2.0 * d);
        let radius = (upper * upper - x * x).sqrt();
        let low = -nalgebra::Vector3::z() + a * a.z;
        let down = low.norm();
        if !radius.is_finite() || down < 1e-9 || radius < 1e-9 {
            return None;
        }
        let low = low / down;
        let centre = s + a * x;
        let bound = (centre.z - z_min) / (radius * down);
        let edge = if bound >= 1.0 {
            0.0
        } else {
            bound.max(-1.0).acos()
        };
        Some(Self {
            centre,
            radius,
            low,
            side: a.cross(&low),
            edge,
        })
    }

    /// The smallest swivel difference to the human's `human` swivel the allowed arc permits.
    pub(super) fn swivel_floor(&self, human: f64) -> f64 {
        (self.edge - human.abs()).max(0.0)
    }

    /// The distance from the human elbow `h` to the nearest allowed elbow position.
    fn elbow_floor(&self, h: &nalgebra::Point3<f64>) -> f64 {
        let v = h - self.centre;
        let best = v.dot(&self.side).atan2(v.dot(&self.low));
        let at = |phi: f64| {
            let e = self.centre + self.radius * (phi.cos() * self.low + phi.sin() * self.side);
            (e - h).norm()
        };
        if best.abs() >= self.edge {
            at(best)
        } else {
            at(self.edge).min(at(-self.edge))
        }
    }
}

/// Per frame of `trajs` (mapped from `study`) onto `sys`, at the robot's own shoulder and wrist
/// ([`ElbowCircle`]): (swivel floor, swivel difference, elbow-distance floor, elbow distance), rad
/// and m (frames where the circle is undefined are skipped).
fn elbow_floors(
    sys: &System,
    study: &[(Vec<HumanFrame>, HumanObject)],
    trajs: &[MappedTrajectory],
    z_min: f64,
) -> Vec<[f64; 4]> {
    let mut data = Data::new(&sys.model);
    let mut out = Vec::new();
    for ((frames, _), t) in study.iter().zip(trajs) {
        assert_eq!(frames.len(), t.metrics.len());
        for (k, m) in t.metrics.iter().enumerate() {
            forward_kinematics(&sys.model, &mut data, t.frame(k));
            let p = |f| nalgebra::Point3::from(data.frame(f).translation.vector);
            let (s, e, w) = (
                p(sys.shoulder_frame),
                p(sys.elbow_frames[0]),
                p(sys.wrist_frame),
            );
            let h = t.registration.point(&frames[k].elbow);
            if let Some(c) = ElbowCircle::new(&s, &w, (e - s).norm(), (w - e).norm(), z_min) {
                out.push([
                    c.swivel_floor(m.swivel_human),
                    m.swivel_difference,
                    c.elbow_floor(&h),
                    (e - h).norm(),
                ]);
            }
        }
    }
    out
}

/// Median swivel difference (deg), mean elbow distance and bound, median and p95 fingertip error.
fn study_stats(trajs: &[MappedTrajectory]) -> (f64, f64, f64, f64, f64) {
    let ms = || trajs.iter().flat_map(|t| t.metrics.iter());
    let tips: Vec<f64> = ms()
        .flat_map(|m| m.position_error[..m.fingers].iter().copied())
        .collect();
    let n = ms().count() as f64;
    (
        median(ms().map(|m| m.swivel_difference.to_degrees()).collect()),
        ms().map(|m| m.elbow_distance_mean).sum::<f64>() / n,
        ms().map(|m| m.elbow_bound).sum::<f64>() / n,
        median(tips.clone()),
        quantile95(tips),
    )
}

/// Smallest support clearance over all frames and object clearance over the first 90 % of each
/// demonstration.
fn worst_clearances(trajs: &[MappedTrajectory]) -> (f64, f64) {
    let mut worst_support = f64::INFINITY;
    let mut worst_object = f64::INFINITY;
    for t in trajs {
        let (t0, t1) = (t.times[0], *t.times.last().unwrap());
        for m in &t.metrics {
            assert!(m.support_clearance.is_finite() && m.object_clearance.is_finite());
            worst_support = worst_support.min(m.support_clearance);
            if m.t < t0 + 0.9 * (t1 - t0) {
                worst_object = worst_object.min(m.object_clearance);
            }
        }
    }
    (worst_support, worst_object)
}

/// Tuning probe (not a check): transport scale and anthropomorphism weights on the study.
#[test]
#[ignore]
fn probe_registration_and_weights() {
    let study = study(1);
    for name in SYSTEMS {
        let sys = system(name);
        for scale in [Scale::One, Scale::Auto] {
            let spec = RegistrationSpec::Scene(SceneRegistration {
                transport_scale: scale,
                ..SceneRegistration::default()
            });
            for (elbow, swivel) in [
                (0.0, 0.0),
                (1e-2, 0.0),
                (1e-2, 1e-2),
                (1e-3, 1e-2),
                (1e-2, 1e-1),
            ] {
                let w = Weights {
                    elbow,
                    swivel,
                    ..Weights::default()
                };
                let t = map_study(&sys, &study, &spec, w);
                let (sw, el, b, tip, tip95) = study_stats(&t);
                let (cs, co) = worst_clearances(&t);
                println!(
                    "{name} {scale:?} w_D {elbow:e} w_s {swivel:e}: swivel {sw:.1}°, elbow {:.0}/{:.0} mm, tip {:.1}/{:.1} mm, clear {:.2}/{:.2} mm",
                    el * 1e3,
                    b * 1e3,
                    tip * 1e3,
                    tip95 * 1e3,
                    cs * 1e3,
                    co * 1e3
                );
            }
        }
    }
}

/// A hand-only system (`robots/examples/ihy_hand.toml`: the iHY on a fixed base, its wrist the
/// hand's root) maps a demonstration fingertips-only, relative to the subject's wrist. The check
/// is an invariance the registration must have and the arm registration has not: moving the
/// whole demonstration rigidly (another tracker placement, another reach) changes nothing.
#[test]
fn a_hand_only_system_maps_the_grasp_relative_to_the_wrist() {
    let sys = System::from_file(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/examples/ihy_hand.toml"),
    )
    .unwrap();
    assert!(sys.arm_joints.is_empty() && sys.elbow_frames.is_empty());
    let mm = MappingModel::from_system(&sys).unwrap();
    let anchor = mm.anchor();
    assert!(anchor.fixed_wrist.is_some());
    let demo = &demos(1, 3)[0];
    let moved: Vec<HumanFrame> = {
        let t = Isometry3::from_parts(
            Translation3::new(0.4, -0.3, 0.2),
            UnitQuaternion::from_euler_angles(0.3, -0.5, 1.2),
        );
        demo.iter()
            .map(|f| HumanFrame {
                t: f.t,
                shoulder: t * f.shoulder,
                elbow: t * f.elbow,
                wrist: t * f.wrist,
                fingertips: f.fingertips.map(|p| t * p),
            })
            .collect()
    };
    let spec = RegistrationSpec::default();
    let a = mapper(&sys, Weights::default())
        .map(demo, &spec, &anchor)
        .unwrap();
    let b = mapper(&sys, Weights::default())
        .map(&moved, &spec, &anchor)
        .unwrap();
    let diff = a
        .positions
        .iter()
        .zip(&b.positions)
        .fold(0.0_f64, |m, (x, y)| m.max((x - y).abs()));
    assert!(
        diff < 1e-6,
        "a rigid move of the demonstration changed the hand by {diff} rad"
    );
    // The fingertip goals are the subject's, rigid with the wrist: the distance of each human
    // fingertip to the wrist is the distance of its goal to the robot hand's root.
    let reg = a.registration;
    let root = anchor.fixed_wrist.unwrap().translation.vector;
    for f in demo.iter().step_by(7) {
        for tip in &f.fingertips {
            let (goal, _) = reg.hand_tip(tip, &f.wrist).unwrap();
            let human = (tip.translation.vector - f.wrist.translation.vector).norm();
            let d = (goal.coords - root).norm();
            assert!((d - human).abs() < 1e-9, "{d} vs {human}");
        }
    }
    let unconverged = a.unconverged().count();
    println!(
        "hand-only iHY: {} frames, {unconverged} unconverged, fingertip error median {:.1} mm",
        demo.len(),
        median(
            a.metrics
                .iter()
                .flat_map(|m| m.position_error[..m.fingers].to_vec())
                .collect()
        ) * 1e3
    );
    assert!(unconverged * 10 <= demo.len());
    assert!(a.metrics.iter().all(|m| m.swivel_difference.is_nan()));
    // An explicit transform has nothing to act on.
    let explicit = RegistrationSpec::Explicit {
        transform: Isometry3::identity(),
        scale: 1.0,
    };
    assert!(matches!(
        mapper(&sys, Weights::default()).map(demo, &explicit, &anchor),
        Err(MappingError::InvalidRegistration { .. })
    ));
}

/// A robot shape's exact signed distance to a scene member by a second method: parry's own
/// generic queries (`query::contact` with an unbounded prediction for the sign and depth,
/// `query::distance` when separated) on the shapes posed by a fresh forward kinematics, not the
/// geometry module's kernel. `None`: the member is not in the scene.
fn parry_distance(
    checker: &crate::geometry::CollisionChecker,
    data: &Data,
    shape: usize,
    other: crate::geometry::Target,
) -> Option<f64> {
    use crate::geometry::Target;
    use parry3d_f64::query;
    use parry3d_f64::shape::{HalfSpace, Shape};
    let s = &checker.robot().shapes()[shape];
    let pose = data.frame(s.frame) * s.origin;
    let a: &dyn Shape = s.solid().shape().as_ref();
    // The scene member first: parry 0.25's support-map-then-half-space contact passes the
    // relative pose on uninverted (found here), the half-space-first order is the direct one.
    let signed = |pb: &Isometry3<f64>, b: &dyn Shape| {
        let c = query::contact(pb, b, &pose, a, 1e9).unwrap().unwrap();
        if c.dist > 0.0 {
            query::distance(pb, b, &pose, a).unwrap()
        } else {
            c.dist
        }
    };
    match other {
        Target::Support => {
            let plane = checker.scene().support?;
            let n = plane.normal();
            let at = Isometry3::from_parts(
                Translation3::from(n.into_inner() * plane.offset()),
                UnitQuaternion::identity(),
            );
            Some(signed(&at, &HalfSpace::new(n)))
        }
        Target::Object => {
            let o = checker.scene().object.as_ref()?;
            Some(signed(o.pose(), o.solid().shape().as_ref()))
        }
        _ => None,
    }
}

/// The clearance penalty's fast path (the objective's forward kinematics reused, only support
/// and object pairs visited, bounding spheres posed by FK skipping pairs beyond the margin) and
/// the reported per-frame clearances give the figures of the plain exhaustive computation: every
/// support and object pair of every robot shape, posed by its own forward kinematics, measured
/// by parry's generic queries ([`parry_distance`]). On mapped frames of study demonstrations on
/// all six systems, and on postures perturbed from them (penetrating the table and the object,
/// so the penalty is active: the test insists that it is, often).
#[test]
fn the_fast_exact_clearance_gives_the_exhaustive_parry_figures_on_real_demonstrations() {
    use crate::geometry::{Category, Target};
    use rand::{RngExt, SeedableRng};
    let study = study(1);
    let opts = SolverOptions::default();
    let (w, margin) = (opts.clearance_weight, opts.clearance_margin);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    let (mut postures, mut active) = (0, 0);
    for (n, name) in SYSTEMS.iter().enumerate() {
        let sys = system(name);
        let mm = MappingModel::from_system(&sys).unwrap();
        let anchor = mm.anchor();
        let mut mapper = mapper(&sys, Weights::default());
        let mut kin = Data::new(&sys.model);
        let mut grad = vec![0.0; sys.model.nq()];
        let mut grad_ref = vec![0.0; sys.model.nq()];
        for (frames, object) in study.iter().skip(n * 4).take(2) {
            let spec = RegistrationSpec::default().for_object(Some(*object));
            let traj = mapper.map(frames, &spec, &anchor).unwrap();
            mapper.set_scene(&traj.registration);
            let c = mapper.clearance.as_mut().unwrap();
            let pairs: Vec<(usize, Target, Category)> = (0..c.checker.pairs().len())
                .filter(|&i| !c.checker.is_allowed(i))
                .map(|i| c.checker.pairs()[i])
                .filter(|p| matches!(p.category, Category::Support | Category::Object))
                .map(|p| (p.shape, p.other, p.category))
                .collect();
            assert!(pairs.iter().any(|p| p.2 == Category::Support));
            assert!(pairs.iter().any(|p| p.2 == Category::Object));
            for (k, m) in traj.metrics.iter().enumerate() {
                let q0 = traj.frame(k);
                // The reported clearances: the exhaustive minima per category.
                forward_kinematics(&sys.model, &mut kin, q0);
                for (cat, reported) in [
                    (Category::Support, m.support_clearance),
                    (Category::Object, m.object_clearance),
                ] {
                    let want = pairs
                        .iter()
                        .filter(|p| p.2 == cat)
                        .map(|p| parry_distance(&c.checker, &kin, p.0, p.1).unwrap())
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        (reported - want).abs() < 1e-6,
                        "{name} frame {k}: reported {cat:?} clearance {reported} vs {want}"
                    );
                }
                // The penalty, at the frame and at postures pushed into the table and object.
                for trial in 0..3 {
                    let q: Vec<f64> = q0
                        .iter()
                        .enumerate()
                        .map(|(i, &x)| {
                            let s = if trial == 0 { 0.0 } else { 0.4 };
                            (x + rng.random_range(-s..=s)).clamp(mm.lower[i], mm.upper[i])
                        })
                        .collect();
                    c.object = (k + trial) % 2 == 0;
                    forward_kinematics(&sys.model, &mut kin, &q);
                    // Two exact methods agree to ~1e-7 m (GJK/EPA on cylinders and boxes), so
                    // the comparison allows 1e-6 m per distance.
                    let tol = 1e-6;
                    let (mut want, mut slack) = (0.0, 1e-12);
                    let (mut surely, mut maybe) = (0, 0);
                    for p in &pairs {
                        if p.2 == Category::Object && !c.object {
                            continue;
                        }
                        let d = parry_distance(&c.checker, &kin, p.0, p.1).unwrap();
                        if d < margin {
                            want += w * (margin - d).powi(2);
                            slack += 2.0 * w * (margin - d + tol) * tol;
                        }
                        surely += usize::from(d < margin - tol);
                        maybe += usize::from(d < margin + tol);
                    }
                    grad.fill(0.0);
                    let got = c.penalty(&mut mapper.eval, &q, w, margin, Some(&mut grad));
                    assert!(
                        (got - want).abs() <= slack,
                        "{name} frame {k}: penalty {got} vs exhaustive {want}"
                    );
                    assert!(
                        (surely..=maybe).contains(&c.near.len()),
                        "{name} frame {k}: {} pairs in the margin, exhaustive {surely}..={maybe}",
                        c.near.len()
                    );
                    let within = c.near.len();
                    // Same gradient as the checker's own path (its own forward kinematics,
                    // every pair's bounding spheres): the borrowed placements are the ones at q.
                    grad_ref.fill(0.0);
                    let cats: &[Category] = if c.object {
                        &[Category::Support, Category::Object]
                    } else {
                        &[Category::Support]
                    };
                    let mut data = c.checker.data();
                    let mut near = Vec::new();
                    c.checker
                        .for_each_within_in(&mut data, &q, margin, cats, |i, d| near.push((i, *d)));
                    let mut tmp = vec![0.0; q.len()];
                    for (i, d) in near {
                        tmp.fill(0.0);
                        c.checker.add_distance_gradient(&data, i, &d, &mut tmp);
                        for (g, t) in grad_ref.iter_mut().zip(&tmp) {
                            *g -= 2.0 * w * (margin - d.distance) * t;
                        }
                    }
                    for (a, b) in grad.iter().zip(&grad_ref) {
                        assert!(
                            (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
                            "{name}: {a} vs {b}"
                        );
                    }
                    postures += 1;
                    active += usize::from(within > 0);
                }
            }
        }
    }
    println!("{postures} postures, the penalty active at {active}");
    assert!(active * 5 >= postures, "{active} of {postures}");
}

/// Per frame of a mapped demonstration: the mapping's fingertip errors and the smallest largest
/// fingertip error three separate fingertip-only solves reach (weights: position only; joint
/// limits, couplings and spread order kept; tight tolerance), each from the mapped posture
/// (within 1 rad of it) and from the previous frame's solution, best kept:
/// `free` the whole arm-hand with no other term; `clear` the same with the mapping's clearance
/// penalty (the pads kept 5 mm off the table, out of the object before the grasp); `hand` the
/// hand alone at the mapped arm posture (the achieved wrist).
struct Reach {
    errors: Vec<f64>,
    free: f64,
    clear: f64,
    hand: f64,
    /// The mapping's own objective (its weights, the clearance penalty) solved locally from the
    /// `clear` solve's posture: its fingertip errors, and its objective minus the mapping's
    /// (negative: the mapping stopped in a worse local minimum than the one next to the
    /// reachable posture; positive with tips near: the terms trade the tips away).
    full_errors: Vec<f64>,
    full_gain: f64,
}

/// Which reachability solves [`fingertip_reach`] runs, on every `stride`-th frame of each
/// demonstration (the `clear` solve always).
struct ReachProbe {
    stride: usize,
    free: bool,
    hand: bool,
    /// The mapping's weights, for the `full` solve (skipped: `None`).
    full: Option<Weights>,
}

fn fingertip_reach(
    sys: &System,
    study: &[(Vec<HumanFrame>, HumanObject)],
    trajs: &[MappedTrajectory],
    probe: &ReachProbe,
) -> Vec<Reach> {
    let mm = MappingModel::from_system(sys).unwrap();
    // Single-stage solves: the fingertip-priority stage would only repeat a fingertip-only
    // objective, and the `full` solve is the weighted objective's local minimum.
    let opts = SolverOptions {
        first_frame_tolerance: 1e-10,
        first_frame_max_iterations: 2000,
        first_frame_fallback: 1e300,
        fingertip_priority: 1.0,
        ..SolverOptions::default()
    };
    let only_tips = Weights {
        position: 1.0,
        orientation: 0.0,
        elbow: 0.0,
        swivel: 0.0,
    };
    let mut out = Vec::new();
    let worst = |m: &FrameMetrics| {
        m.position_error[..m.fingers]
            .iter()
            .fold(0.0, |a: f64, &b| a.max(b))
    };
    for ((frames, _), traj) in study.iter().zip(trajs) {
        let mut free = Mapper::new(mm.clone(), only_tips, opts)
            .unwrap()
            .with_geometry(None);
        let mut clear = Mapper::new(mm.clone(), only_tips, opts).unwrap();
        clear.set_scene(&traj.registration);
        let mut hand = Mapper::new(mm.clone(), only_tips, opts)
            .unwrap()
            .with_geometry(None);
        let mut full = Mapper::new(mm.clone(), probe.full.unwrap_or_default(), opts).unwrap();
        full.set_scene(&traj.registration);
        let (t0, t1) = (traj.times[0], *traj.times.last().unwrap());
        let mut goals = FrameGoals::default();
        let mut prev: [Option<Vec<f64>>; 3] = [None, None, None];
        for (k, m) in traj.metrics.iter().enumerate().step_by(probe.stride) {
            free.goals(&frames[k], &traj.registration, &mut goals);
            if let Some(c) = &mut clear.clearance {
                c.object = frames[k].t < t0 + opts.object_free_until * (t1 - t0);
            }
            let q = traj.frame(k);
            for &j in &sys.arm_joints {
                hand.eval.mm.lower[j] = q[j];
                hand.eval.mm.upper[j] = q[j];
            }
            let mut best = [f64::INFINITY; 3];
            let mut clear_q = q.to_vec();
            let solvers = [&mut free, &mut clear, &mut hand];
            let wanted = [probe.free, true, probe.hand];
            for (s, mapper) in solvers.into_iter().enumerate().filter(|(s, _)| wanted[*s]) {
                let mut starts = vec![q.to_vec()];
                if let Some(p) = &prev[s] {
                    let mut p = p.clone();
                    if s == 2 {
                        for &j in &sys.arm_joints {
                            p[j] = q[j];
                        }
                    }
                    starts.push(p);
                }
                let mut best_q = q.to_vec();
                for start in starts {
                    let r = StartReference {
                        q: start,
                        objective: 0.0,
                    };
                    let got = mapper.solve_first_from(&goals, m.t, &r);
                    if worst(&got) < best[s] {
                        best[s] = worst(&got);
                        best_q = mapper.solution().to_vec();
                    }
                }
                if s == 1 {
                    clear_q = best_q.clone();
                }
                prev[s] = Some(best_q);
            }
            let (mut full_errors, mut full_gain) = (Vec::new(), f64::NAN);
            if probe.full.is_some() {
                if let Some(c) = &mut full.clearance {
                    c.object = frames[k].t < t0 + opts.object_free_until * (t1 - t0);
                }
                let f = full.solve_first_from(
                    &goals,
                    m.t,
                    &StartReference {
                        q: clear_q,
                        objective: 0.0,
                    },
                );
                full_errors = f.position_error[..f.fingers].to_vec();
                full_gain = f.objective - m.objective;
            }
            out.push(Reach {
                errors: m.position_error[..m.fingers].to_vec(),
                free: best[0],
                clear: best[1],
                hand: best[2],
                full_errors,
                full_gain,
            });
        }
    }
    out
}

/// Probe (not a check): issue 16's fingertip claim on the default study. A frame is reachable
/// when a separate fingertip-only solve ([`fingertip_reach`]) puts every fingertip within 1 mm
/// of its goal; printed per system: the reachable fractions and the mapping's median / p95
/// fingertip error on those frames, with the default weights and without the
/// anthropomorphism terms, and how far the unreachable frames are.
#[test]
#[ignore]
fn probe_fingertip_reachability() {
    let study = study(1);
    let spec = RegistrationSpec::default();
    let only = std::env::var("PROBE_SYSTEMS").unwrap_or_default();
    for name in SYSTEMS {
        if !only.is_empty() && !only.split(',').any(|s| s == name) {
            continue;
        }
        let sys = system(name);
        // The baseline without the anthropomorphism terms only when asked (it doubles the time).
        let baseline = std::env::var_os("PROBE_BASELINE").is_some();
        // PROBE_W="position,orientation,elbow,swivel" replaces the default weights.
        let chosen = std::env::var("PROBE_W").ok().map(|v| {
            let w: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
            Weights {
                position: w[0],
                orientation: w[1],
                elbow: w[2],
                swivel: w[3],
            }
        });
        let weights = [
            ("default", chosen.unwrap_or_default()),
            (
                "no anthropomorphism",
                Weights::default().without_anthropomorphism(),
            ),
        ];
        for (label, w) in weights.into_iter().take(if baseline { 2 } else { 1 }) {
            // PROBE_OPTS="tolerance,max_iterations,step_scale" replaces the solver's defaults.
            let mut so = SolverOptions::default();
            if let Ok(v) = std::env::var("PROBE_OPTS") {
                let o: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
                so.tolerance = o[0];
                so.max_iterations = o[1] as usize;
                so.step_scale = o[2];
            }
            // PROBE_PRIORITY="K,max_iterations" sets the fingertip-priority stage (K = 1: off).
            if let Ok(v) = std::env::var("PROBE_PRIORITY") {
                let o: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
                so.fingertip_priority = o[0];
                so.priority_max_iterations = o[1] as usize;
            }
            let trajs = map_study_with(&sys, &study, &spec, w, so);
            let floors = elbow_floors(&sys, &study, &trajs, lowest_elbow_height(&sys));
            let (ws, we) = worst_clearances(&trajs);
            {
                // Joint steps against the warm-started solve's bound (2 v_max dt).
                let vmax = sys.model.velocity_limits();
                let (mut worst, mut over, mut total) = (0.0_f64, 0, 0);
                for t in &trajs {
                    for k in 1..t.times.len() {
                        let dt = t.times[k] - t.times[k - 1];
                        let mut r = 0.0_f64;
                        for ((a, b), &v) in t.frame(k).iter().zip(t.frame(k - 1)).zip(vmax) {
                            let v = if v.is_finite() && v > 0.0 { v } else { 3.0 };
                            r = r.max((a - b).abs() / (v * dt));
                        }
                        worst = worst.max(r);
                        total += 1;
                        if r > 2.0 + 1e-9 {
                            over += 1;
                        }
                    }
                }
                println!(
                    "{name} [{label}] joint step / (v_max dt): worst {worst:.2}, over 2 at {over} of {total} steps"
                );
            }
            println!(
                "{name} [{label}] swivel above floor median {:.1}°, elbow above floor mean {:.1} mm; clearance support {:.2} mm object {:.2} mm",
                median(floors.iter().map(|f| (f[1] - f[0]).to_degrees()).collect()),
                1e3 * floors.iter().map(|f| f[3] - f[2]).sum::<f64>() / floors.len() as f64,
                ws * 1e3,
                we * 1e3
            );
            let hand_too = std::env::var_os("PROBE_HAND").is_some();
            let probe = ReachProbe {
                stride: 1,
                free: true,
                hand: hand_too,
                full: Some(w),
            };
            let reach = fingertip_reach(&sys, &study, &trajs, &probe);
            let n = reach.len() as f64;
            for (what, pick) in [
                (
                    "arm-hand, tips only",
                    (|r: &Reach| r.free) as fn(&Reach) -> f64,
                ),
                ("arm-hand + clearance", |r: &Reach| r.clear),
                ("hand at the mapped wrist", |r: &Reach| r.hand),
            ] {
                if !hand_too && what.starts_with("hand") {
                    continue;
                }
                let ok: Vec<&Reach> = reach.iter().filter(|r| pick(r) <= 1e-3).collect();
                let errs: Vec<f64> = ok.iter().flat_map(|r| r.errors.iter().copied()).collect();
                let (med, p95) = if errs.is_empty() {
                    (f64::NAN, f64::NAN)
                } else {
                    (median(errs.clone()), quantile95(errs))
                };
                let best = median(reach.iter().map(pick).collect());
                println!(
                    "{name} [{label}] {what}: reachable {:.1} % of {n} frames; mapping error on them median {:.2} mm, p95 {:.2} mm; solve's worst-tip residual median over all frames {:.2} mm",
                    100.0 * ok.len() as f64 / n,
                    med * 1e3,
                    p95 * 1e3,
                    best * 1e3
                );
                if !ok.is_empty() {
                    let fe: Vec<f64> = ok
                        .iter()
                        .flat_map(|r| r.full_errors.iter().copied())
                        .collect();
                    let lower = ok.iter().filter(|r| r.full_gain < 0.0).count();
                    println!(
                        "  the mapping objective from that solve: tips median {:.2} mm, p95 {:.2} mm; objective below the mapping's at {lower} of {} frames (median gain {:.3e})",
                        median(fe.clone()) * 1e3,
                        quantile95(fe) * 1e3,
                        ok.len(),
                        median(ok.iter().map(|r| r.full_gain).collect())
                    );
                }
            }
            let all: Vec<f64> = reach
                .iter()
                .flat_map(|r| r.errors.iter().copied())
                .collect();
            println!(
                "{name} [{label}] all frames: mapping error median {:.2} mm, p95 {:.2} mm",
                median(all.clone()) * 1e3,
                quantile95(all) * 1e3
            );
        }
    }
}
