//! Figures are well-formed SVG holding the expected series (parsed back with roxmltree).

use std::path::PathBuf;
use std::sync::OnceLock;

use super::*;
use crate::grasp::objects::seeded_object;
use crate::grasp::{GraspRequest, HandArm, Object, QualityMeasure, Transmission, plan_grasp};
use crate::human::{self, HumanFrame, StudyConfig};
use crate::kinematics::System;
use crate::mapping::{FrameMetrics, MAX_FINGERS, MappedTrajectory, Registration};
use crate::motion::TrajectoryPoint;

fn system() -> &'static System {
    static S: OnceLock<System> = OnceLock::new();
    S.get_or_init(|| {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml");
        System::from_file(&path).expect("bundled system loads")
    })
}

fn demo_frames() -> &'static [HumanFrame] {
    static F: OnceLock<Vec<HumanFrame>> = OnceLock::new();
    F.get_or_init(|| {
        let cfg = StudyConfig {
            subjects: 1,
            positions: 1,
            trials: 1,
            ..StudyConfig::default()
        };
        let spec = &cfg.trials()[0];
        let input = human::synth::generate_trial(spec, cfg.seed).expect("synthetic trial");
        human::ingest(&input).expect("ingest").frames
    })
}

/// Parses the SVG and returns its polylines as (stroke colour, point count).
fn polylines(svg: &str) -> Vec<(String, usize)> {
    let doc = roxmltree::Document::parse(svg).expect("well-formed SVG");
    assert_eq!(doc.root_element().tag_name().name(), "svg");
    doc.descendants()
        .filter(|n| n.has_tag_name("polyline"))
        .map(|n| {
            let stroke = n.attribute("stroke").unwrap_or_default().to_uppercase();
            let points = n.attribute("points").unwrap_or_default();
            (stroke, points.split_whitespace().count())
        })
        .collect()
}

fn count_tag(svg: &str, tag: &str, fill: &str) -> usize {
    let doc = roxmltree::Document::parse(svg).expect("well-formed SVG");
    doc.descendants()
        .filter(|n| {
            n.has_tag_name(tag)
                && n.attribute("fill").map(str::to_uppercase).as_deref() == Some(fill)
        })
        .count()
}

fn color_of(fig: &Figure, name: &str) -> String {
    fig.series
        .iter()
        .find(|s| s.name == name)
        .unwrap_or_else(|| panic!("series {name:?} missing from {:?}", fig.series))
        .color
        .clone()
}

#[test]
fn view_is_range_checked() {
    assert!(View::new(None, None).is_ok());
    assert!(View::new(Some(180.0), Some(-90.0)).is_ok());
    for (az, el, param) in [
        (Some(181.0), None, "azimuth"),
        (Some(f64::NAN), None, "azimuth"),
        (None, Some(90.5), "elevation"),
        (None, Some(f64::INFINITY), "elevation"),
    ] {
        match View::new(az, el) {
            Err(FigureError::OutOfRange { param: p, .. }) => assert_eq!(p, param),
            other => panic!("{az:?} {el:?}: {other:?}"),
        }
    }
}

#[test]
fn posture_draws_every_moving_link_and_each_fingertip() {
    let sys = system();
    let q = sys.model.neutral();
    let scene = posture_scene(sys, &q).unwrap();
    let fig = render_scene(&scene, View::default()).unwrap();
    let lines = polylines(&fig.svg);
    let arm = color_of(&fig, "arm links");
    let hand = color_of(&fig, "hand links");
    let drawn = lines
        .iter()
        .filter(|(c, n)| (*c == arm || *c == hand) && *n == 2)
        .count();
    // One 2-point polyline per link of the scene, plus one per legend entry for each colour.
    assert_eq!(drawn, scene.lines.len() + 2);
    assert!(scene.lines.iter().any(|l| l.name == "hand links"));
    let tips = count_tag(&fig.svg, "circle", &color_of(&fig, "fingertips"));
    assert_eq!(
        tips,
        sys.fingers.len() + 1,
        "one marker per fingertip + legend"
    );
    // The wrong number of joint values is an error, not a panic.
    assert!(matches!(
        posture_scene(sys, &q[1..]),
        Err(FigureError::WrongLength { .. })
    ));
}

#[test]
fn view_angle_changes_the_projection_only() {
    let sys = system();
    let scene = posture_scene(sys, &sys.model.neutral()).unwrap();
    let a = render_scene(&scene, View::new(Some(0.0), Some(10.0)).unwrap()).unwrap();
    let b = render_scene(&scene, View::new(Some(90.0), Some(10.0)).unwrap()).unwrap();
    assert_ne!(a.svg, b.svg);
    assert_eq!(polylines(&a.svg).len(), polylines(&b.svg).len());
    assert_eq!(a.series, b.series);
}

#[test]
fn demonstration_has_speed_and_aperture_over_every_frame() {
    let frames = demo_frames();
    let fig = demonstration_figure("demo", frames).unwrap();
    let lines = polylines(&fig.svg);
    for name in ["wrist speed", "grip aperture"] {
        let c = color_of(&fig, name);
        assert!(
            lines.iter().any(|(s, n)| *s == c && *n == frames.len()),
            "{name}: no polyline of {} points",
            frames.len()
        );
    }
    assert!(matches!(
        demonstration_figure("x", &frames[..2]),
        Err(FigureError::Empty { .. })
    ));
}

fn mapped(sys: &System, frames: usize) -> MappedTrajectory {
    let m = &sys.model;
    let nq = m.nq();
    let (lo, hi) = (m.lower_limits(), m.upper_limits());
    let mut positions = Vec::with_capacity(frames * nq);
    for k in 0..frames {
        let s = k as f64 / (frames - 1) as f64;
        for j in 0..nq {
            let mid = if lo[j].is_finite() && hi[j].is_finite() {
                0.5 * (lo[j] + hi[j])
            } else {
                0.0
            };
            positions.push(mid + 0.3 * s * (j as f64 * 0.7).sin());
        }
    }
    let metric = FrameMetrics {
        t: 0.0,
        fingers: sys.fingers.len(),
        position_error: [0.0; MAX_FINGERS],
        orientation_error: [0.0; MAX_FINGERS],
        elbow_distance: 0.0,
        elbow_distance_mean: 0.0,
        objective: 0.0,
        iterations: 1,
        converged: true,
        swivel_human: f64::NAN,
        swivel_robot: f64::NAN,
        swivel_difference: f64::NAN,
        elbow_bound: f64::NAN,
        support_clearance: f64::NAN,
        object_clearance: f64::NAN,
    };
    MappedTrajectory {
        joint_names: m.joint_names().to_vec(),
        times: (0..frames).map(|k| k as f64 * 0.01).collect(),
        positions,
        metrics: vec![metric; frames],
        registration: Registration::identity(),
    }
}

#[test]
fn mapping_has_one_path_per_human_and_robot_fingertip() {
    let sys = system();
    let human = demo_frames();
    let traj = mapped(sys, 25);
    let input = MappingInput {
        system: sys,
        human,
        trajectory: &traj,
        postures: 3,
    };
    let scene = mapping_scene(&input).unwrap();
    let fig = render_scene(&scene, View::default()).unwrap();
    let lines = polylines(&fig.svg);
    let paths_of = |name: &str, len: usize| {
        let c = color_of(&fig, name);
        lines.iter().filter(|(s, n)| *s == c && *n == len).count()
    };
    for f in ["thumb", "index", "middle", "ring", "little"] {
        assert_eq!(paths_of(&format!("human {f} tip"), human.len()), 1, "{f}");
    }
    assert_eq!(paths_of("human elbow", human.len()), 1);
    for f in &sys.fingers {
        assert_eq!(
            paths_of(&format!("robot {} tip", f.name), 25),
            1,
            "{}",
            f.name
        );
    }
    assert_eq!(paths_of("robot elbow", 25), 1);
    // Three postures' links: every posture link is a 2-point polyline in the posture colour.
    let postures = scene
        .lines
        .iter()
        .filter(|l| l.name == "robot postures")
        .count();
    assert!(postures >= 3 && postures % 3 == 0, "{postures}");
    let too_many = MappingInput {
        postures: 11,
        ..input
    };
    assert!(matches!(
        mapping_scene(&too_many),
        Err(FigureError::OutOfRange {
            param: "postures",
            ..
        })
    ));
}

#[test]
fn grasp_shows_links_object_contacts_direction_and_ellipsoid() {
    let sys = HandArm::from_system(system()).unwrap();
    let spec = seeded_object("ball", 0.5, 0.0, 0.0).unwrap();
    let mut req = GraspRequest::new(
        Object::new(spec.clone()).unwrap(),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    req.starts = 1;
    let result = plan_grasp(&sys, &req).unwrap();
    let dirs = [([0.0, 0.0, 1.0], Transmission::Force)];
    let input = GraspInput {
        system: &sys,
        result: &result,
        object: &spec,
        task_directions: &dirs,
        ellipsoid: None,
    };
    let scene = grasp_scene(&input).unwrap();
    let fig = render_scene(&scene, View::default()).unwrap();
    let names: Vec<&str> = fig.series.iter().map(|s| s.name.as_str()).collect();
    for n in [
        "arm links",
        "hand links",
        "object",
        "contacts",
        "task direction",
        "force ellipsoid",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    let lines = polylines(&fig.svg);
    // A sphere is three great circles; the ellipsoid three principal ellipses.
    let obj = color_of(&fig, "object");
    assert_eq!(
        lines.iter().filter(|(c, n)| *c == obj && *n == 37).count(),
        3
    );
    let ell = color_of(&fig, "force ellipsoid");
    assert_eq!(
        lines.iter().filter(|(c, n)| *c == ell && *n == 49).count(),
        3
    );
    let contacts = count_tag(&fig.svg, "circle", &color_of(&fig, "contacts"));
    assert_eq!(contacts, result.contacts.len() + 1);
    let velocity = grasp_scene(&GraspInput {
        ellipsoid: Some(EllipsoidKind::Velocity),
        ..input
    })
    .unwrap();
    assert!(
        velocity
            .lines
            .iter()
            .any(|l| l.name == "velocity ellipsoid")
    );
}

fn ramp(n: usize, joints: usize) -> Vec<TrajectoryPoint> {
    (0..n)
        .map(|k| {
            let t = k as f64 * 0.05;
            TrajectoryPoint {
                t,
                positions: (0..joints).map(|j| (t + j as f64).sin()).collect(),
                velocities: vec![0.0; joints],
                accelerations: vec![0.0; joints],
            }
        })
        .collect()
}

#[test]
fn trajectory_has_one_line_per_joint() {
    let names: Vec<String> = (1..=7).map(|j| format!("j{j}")).collect();
    let pts = ramp(40, 7);
    let fig = trajectory_figure("t", &names, &pts).unwrap();
    let lines = polylines(&fig.svg);
    for n in &names {
        let c = color_of(&fig, n);
        assert!(lines.iter().any(|(s, k)| *s == c && *k == 40), "{n}");
    }
    assert!(matches!(
        trajectory_figure("t", &names[..6], &pts),
        Err(FigureError::WrongLength { .. })
    ));
}

#[test]
fn execution_pairs_planned_and_measured_per_joint() {
    let names: Vec<String> = vec!["a".into(), "b".into()];
    let planned = ramp(30, 2);
    let measured: Vec<ExecutionSample> = planned
        .iter()
        .map(|p| ExecutionSample {
            t: p.t + 0.01,
            positions: p.positions.iter().map(|x| x + 0.01).collect(),
        })
        .collect();
    let fig = execution_figure("e", &names, &planned, &measured).unwrap();
    let lines = polylines(&fig.svg);
    for n in &names {
        let c = color_of(&fig, &format!("{n} measured"));
        assert_eq!(c, color_of(&fig, &format!("{n} planned")));
        assert!(
            lines.iter().any(|(s, k)| *s == c && *k == 30),
            "{n} measured"
        );
    }
    assert!(execution_figure("e", &names, &[], &[]).is_err());
}

#[test]
fn a_closed_loop_execution_draws_measured_lines_only_and_long_ones_thinned() {
    let names: Vec<String> = vec!["a".into(), "b".into(), "c".into()];
    // a bounded history at its largest (4000 samples), and around the drawing limit
    for (n, drawn) in [(4000, 1000), (999, 999), (1001, 1000)] {
        let measured: Vec<ExecutionSample> = (0..n)
            .map(|k| ExecutionSample {
                t: k as f64 * 0.05,
                positions: (0..3).map(|j| (k as f64 * 0.01 + j as f64).sin()).collect(),
            })
            .collect();
        let fig = execution_figure("e", &names, &[], &measured).unwrap();
        assert!(fig.series.iter().all(|s| s.name.ends_with(" measured")));
        assert_eq!(fig.series.len(), names.len());
        let lines = polylines(&fig.svg);
        for name in &names {
            let c = color_of(&fig, &format!("{name} measured"));
            let k = lines.iter().filter(|(s, k)| *s == c && *k > 2).count();
            assert_eq!(k, 1, "{name}: one measured line");
            assert!(
                lines.iter().any(|(s, k)| *s == c && *k == drawn),
                "{name}: {n} samples drawn as {drawn} points"
            );
        }
        assert!(drawn <= super::series::MAX_DRAWN);
    }
}

#[test]
fn model_has_bars_per_component_and_both_path_kinds() {
    let ev = [0.6, 0.2, 0.1];
    let paths = vec![
        PcaPath {
            generated: false,
            points: (0..20).map(|k| (k as f64, (k as f64).sqrt())).collect(),
        },
        PcaPath {
            generated: true,
            points: (0..20)
                .map(|k| (k as f64, (k as f64).sqrt() + 0.1))
                .collect(),
        },
    ];
    let fig = model_figure("m", &ev, &paths).unwrap();
    let bars = count_tag(&fig.svg, "rect", &color_of(&fig, "explained variance"));
    assert_eq!(bars, ev.len());
    let lines = polylines(&fig.svg);
    for n in ["demonstrated", "generated"] {
        let c = color_of(&fig, n);
        assert!(lines.iter().any(|(s, k)| *s == c && *k == 20), "{n}");
    }
    assert!(model_figure("m", &[], &paths).is_err());
}
