//! 3-D scenes: robot postures (links from FK), grasps (Fig. 3-6) and mappings (Fig. 2).

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use plotters::prelude::*;

use super::{Figure, FigureError, PALETTE, SIZE, SeriesInfo, View, hex, render_err};
use crate::grasp::objects::{ObjectSpec, ShapeSpec};
use crate::grasp::{GraspResult, HandArm, Transmission};
use crate::human::HumanFrame;
use crate::kinematics::{Data, FrameId, Model, System, forward_kinematics};
use crate::mapping::{MappedTrajectory, Registration};

const ARM: RGBColor = RGBColor(70, 70, 80);
const HAND: RGBColor = RGBColor(31, 119, 180);
const OBJECT: RGBColor = RGBColor(150, 110, 60);
const CONTACT: RGBColor = RGBColor(214, 39, 40);
const TASK: RGBColor = RGBColor(44, 160, 44);
const ELLIPSOID: RGBColor = RGBColor(148, 103, 189);
const HUMAN_ELBOW: RGBColor = RGBColor(255, 190, 0);
const ROBOT_ELBOW: RGBColor = RGBColor(120, 0, 0);

/// A world-frame polyline (robot base frame, metres).
#[derive(Debug, Clone)]
pub struct Polyline {
    /// Legend name; polylines sharing a name share one legend entry.
    pub name: String,
    pub color: RGBColor,
    pub width: u32,
    pub points: Vec<Point3<f64>>,
}

/// A world-frame point marker.
#[derive(Debug, Clone)]
pub struct Marker {
    pub name: String,
    pub color: RGBColor,
    pub radius: u32,
    pub point: Point3<f64>,
}

/// Geometry of a 3-D figure, before projection.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    pub title: String,
    pub lines: Vec<Polyline>,
    pub markers: Vec<Marker>,
}

impl Scene {
    fn line(&mut self, name: &str, color: RGBColor, width: u32, points: Vec<Point3<f64>>) {
        if points.len() >= 2 {
            self.lines.push(Polyline {
                name: name.to_owned(),
                color,
                width,
                points,
            });
        }
    }

    fn marker(&mut self, name: &str, color: RGBColor, radius: u32, point: Point3<f64>) {
        self.markers.push(Marker {
            name: name.to_owned(),
            color,
            radius,
            point,
        });
    }

    /// Centre and half-width of the cube holding every point (equal axis scales, so shapes
    /// are not distorted).
    fn bounds(&self) -> Option<(Point3<f64>, f64)> {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        let all = self
            .lines
            .iter()
            .flat_map(|l| l.points.iter())
            .chain(self.markers.iter().map(|m| &m.point));
        for p in all.filter(|p| p.coords.iter().all(|x| x.is_finite())) {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        if lo.x > hi.x {
            return None;
        }
        let half = ((hi - lo).max() * 0.55).max(0.05);
        Some((Point3::from((lo + hi) * 0.5), half))
    }
}

/// Draws a scene with equal axis scales. World `z` (up) is the chart's vertical axis.
pub fn render_scene(scene: &Scene, view: View) -> Result<Figure, FigureError> {
    let (c, h) = scene.bounds().ok_or_else(|| FigureError::Empty {
        what: scene.title.clone(),
    })?;
    let mut svg = String::new();
    let mut series = Vec::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(render_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(&scene.title, ("sans-serif", 20))
            .margin(10)
            // Chart axes: X = world x, Y (vertical) = world z, Z = world y.
            .build_cartesian_3d(c.x - h..c.x + h, c.z - h..c.z + h, c.y - h..c.y + h)
            .map_err(render_err)?;
        chart.with_projection(|mut p| {
            p.yaw = view.azimuth_deg.to_radians();
            p.pitch = view.elevation_deg.to_radians();
            p.scale = 0.85;
            p.into_matrix()
        });
        chart
            .configure_axes()
            .light_grid_style(RGBColor(235, 235, 235))
            .max_light_lines(2)
            .label_style(("sans-serif", 11))
            .x_labels(5)
            .y_labels(5)
            .z_labels(5)
            .draw()
            .map_err(render_err)?;
        let to3 = |p: &Point3<f64>| (p.x, p.z, p.y);
        for l in &scene.lines {
            let style = ShapeStyle::from(&l.color).stroke_width(l.width);
            let anno = chart
                .draw_series(LineSeries::new(l.points.iter().map(to3), style))
                .map_err(render_err)?;
            if !series.iter().any(|s: &SeriesInfo| s.name == l.name) {
                series.push(SeriesInfo {
                    name: l.name.clone(),
                    color: hex(l.color),
                });
                let color = l.color;
                anno.label(l.name.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(3))
                });
            }
        }
        for m in &scene.markers {
            let anno = chart
                .draw_series(std::iter::once(Circle::new(
                    to3(&m.point),
                    m.radius,
                    m.color.filled(),
                )))
                .map_err(render_err)?;
            if !series.iter().any(|s: &SeriesInfo| s.name == m.name) {
                series.push(SeriesInfo {
                    name: m.name.clone(),
                    color: hex(m.color),
                });
                let color = m.color;
                anno.label(m.name.clone())
                    .legend(move |(x, y)| Circle::new((x + 9, y), 4, color.filled()));
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 12))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .draw()
            .map_err(render_err)?;
        root.present().map_err(render_err)?;
    }
    Ok(Figure { svg, series })
}

/// For every frame, whether a hand joint moves it (hand links are drawn in the hand colour).
pub(super) fn hand_frames(model: &Model, hand_joints: &[usize]) -> Vec<bool> {
    (0..model.n_frames())
        .map(|f| {
            model
                .supporting_q(FrameId(f))
                .iter()
                .any(|k| hand_joints.contains(k))
        })
        .collect()
}

/// One polyline per link (parent origin to child origin) of the posture in `data`.
fn add_links(
    scene: &mut Scene,
    model: &Model,
    data: &Data,
    is_hand: &[bool],
    names: (&str, &str),
    colors: (RGBColor, RGBColor),
) {
    for (f, &hand) in is_hand.iter().enumerate().take(model.n_frames()) {
        let id = FrameId(f);
        let Some(parent) = model.frame_parent(id) else {
            continue;
        };
        let a = Point3::from(data.frame(parent).translation.vector);
        let b = Point3::from(data.frame(id).translation.vector);
        // Fixed frames at their parent's origin add nothing visible.
        if (a - b).norm() < 1e-6 {
            continue;
        }
        let (name, color, width) = if hand {
            (names.1, colors.1, 2)
        } else {
            (names.0, colors.0, 4)
        };
        scene.line(name, color, width, vec![a, b]);
    }
}

fn check_q(model: &Model, q: &[f64]) -> Result<(), FigureError> {
    if q.len() != model.nq() {
        return Err(FigureError::WrongLength {
            param: "q",
            expected: model.nq(),
            got: q.len(),
        });
    }
    Ok(())
}

/// The arm and hand links of `system` at configuration `q` (independent joints, model order),
/// with the fingertip contact spheres' centres marked.
pub fn posture_scene(system: &System, q: &[f64]) -> Result<Scene, FigureError> {
    let model = &system.model;
    check_q(model, q)?;
    let mut data = Data::new(model);
    forward_kinematics(model, &mut data, q);
    let mut scene = Scene {
        title: format!("{} posture", system.name),
        ..Scene::default()
    };
    let is_hand = hand_frames(model, &system.hand_joints);
    add_links(
        &mut scene,
        model,
        &data,
        &is_hand,
        ("arm links", "hand links"),
        (ARM, HAND),
    );
    for f in &system.fingers {
        let p = Point3::from(data.frame(f.tip).translation.vector);
        scene.marker("fingertips", CONTACT, 4, p);
    }
    Ok(scene)
}

/// Which ellipsoid of a grasp figure to draw at the grasp frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EllipsoidKind {
    Velocity,
    Force,
}

/// Everything a grasp figure shows.
pub struct GraspInput<'a> {
    pub system: &'a HandArm,
    pub result: &'a GraspResult,
    pub object: &'a ObjectSpec,
    /// Unit task directions with their kind (world frame).
    pub task_directions: &'a [([f64; 3], Transmission)],
    /// `None`: the kind of the first task direction, velocity without one.
    pub ellipsoid: Option<EllipsoidKind>,
}

/// Fig. 3-6: arm and hand links at the grasp, the object, contact points, the task directions
/// and the arm's velocity or force ellipsoid (eq. 10-11) at the grasp frame.
pub fn grasp_scene(input: &GraspInput<'_>) -> Result<Scene, FigureError> {
    let sys = input.system;
    let model = &sys.model;
    let mut q = model.neutral();
    for j in input.result.q_arm.iter().chain(&input.result.q_hand) {
        if let Some(k) = model.q_index(&j.name) {
            q[k] = j.value;
        }
    }
    let mut data = Data::new(model);
    forward_kinematics(model, &mut data, &q);
    let mut scene = Scene {
        title: format!(
            "{} grasping {}{}",
            sys.name,
            input.object.name,
            if input.result.feasible {
                ""
            } else {
                " (infeasible)"
            }
        ),
        ..Scene::default()
    };
    let is_hand = hand_frames(model, &sys.hand_joints);
    add_links(
        &mut scene,
        model,
        &data,
        &is_hand,
        ("arm links", "hand links"),
        (ARM, HAND),
    );
    for line in object_wireframe(input.object) {
        scene.line("object", OBJECT, 1, line);
    }
    for c in &input.result.contacts {
        scene.marker("contacts", CONTACT, 5, Point3::from(c.point));
    }
    let palm = Point3::from(data.frame(sys.palm).translation.vector);
    let kind = input
        .ellipsoid
        .unwrap_or(match input.task_directions.first() {
            Some((_, Transmission::Force)) => EllipsoidKind::Force,
            _ => EllipsoidKind::Velocity,
        });
    let e = &input.result.arm_ellipsoids;
    let (name, semi) = match kind {
        EllipsoidKind::Velocity => ("velocity ellipsoid", e.velocity_semi_axes),
        EllipsoidKind::Force => ("force ellipsoid", e.force_semi_axes),
    };
    // Only the shape matters in the figure: the largest semi-axis is drawn 0.15 m long.
    let largest = semi.iter().copied().fold(0.0_f64, f64::max);
    if largest.is_finite() && largest > 0.0 {
        let s = semi.map(|v| 0.15 * v / largest);
        let ax = e.axes.map(Vector3::from);
        for (i, j) in [(0, 1), (1, 2), (0, 2)] {
            let ring = (0..=48)
                .map(|k| {
                    let t = std::f64::consts::TAU * f64::from(k) / 48.0;
                    palm + ax[i] * (s[i] * t.cos()) + ax[j] * (s[j] * t.sin())
                })
                .collect();
            scene.line(name, ELLIPSOID, 1, ring);
        }
    }
    for (d, _) in input.task_directions {
        let tip = palm + Vector3::from(*d) * 0.2;
        scene.line("task direction", TASK, 3, vec![palm, tip]);
        scene.marker("task direction", TASK, 4, tip);
    }
    Ok(scene)
}

/// Edges of an object's shape in the world, as polylines (meshes: every triangle, at most
/// about 1500 of them, so a figure stays small and fast).
pub fn object_wireframe(o: &ObjectSpec) -> Vec<Vec<Point3<f64>>> {
    let [w, x, y, z] = o.orientation;
    let pose = Isometry3::from_parts(
        Translation3::from(Vector3::from(o.position)),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    );
    let circle = |r: f64, zc: f64, plane: usize| -> Vec<Point3<f64>> {
        (0..=36)
            .map(|k| {
                let t = std::f64::consts::TAU * f64::from(k) / 36.0;
                let (a, b) = (r * t.cos(), r * t.sin());
                match plane {
                    0 => Point3::new(a, b, zc),
                    1 => Point3::new(a, zc, b),
                    _ => Point3::new(zc, a, b),
                }
            })
            .collect()
    };
    let local: Vec<Vec<Point3<f64>>> = match &o.shape {
        ShapeSpec::Sphere { radius } => (0..3).map(|p| circle(*radius, 0.0, p)).collect(),
        ShapeSpec::Cylinder { radius, height } => {
            let h = height / 2.0;
            let mut v = vec![circle(*radius, -h, 0), circle(*radius, h, 0)];
            for k in 0..4 {
                let t = std::f64::consts::FRAC_PI_2 * f64::from(k);
                let (a, b) = (radius * t.cos(), radius * t.sin());
                v.push(vec![Point3::new(a, b, -h), Point3::new(a, b, h)]);
            }
            v
        }
        ShapeSpec::Capsule { radius, length } => {
            let h = length / 2.0;
            let mut v = vec![circle(*radius, -h, 0), circle(*radius, h, 0)];
            for k in 0..4 {
                let t = std::f64::consts::FRAC_PI_2 * f64::from(k);
                let (a, b) = (radius * t.cos(), radius * t.sin());
                v.push(vec![Point3::new(a, b, -h), Point3::new(a, b, h)]);
            }
            // Cap outlines in the xz and yz planes.
            for plane in 0..2 {
                for (z0, sign) in [(h, 1.0), (-h, -1.0)] {
                    v.push(
                        (0..=18)
                            .map(|k| {
                                let t = std::f64::consts::PI * f64::from(k) / 18.0;
                                let (a, b) = (radius * t.cos(), z0 + sign * radius * t.sin());
                                if plane == 0 {
                                    Point3::new(a, 0.0, b)
                                } else {
                                    Point3::new(0.0, a, b)
                                }
                            })
                            .collect(),
                    );
                }
            }
            v
        }
        ShapeSpec::Box { size } => {
            let h = Vector3::from(*size) / 2.0;
            let corner = |i: u8| {
                Point3::new(
                    if i & 1 == 0 { -h.x } else { h.x },
                    if i & 2 == 0 { -h.y } else { h.y },
                    if i & 4 == 0 { -h.z } else { h.z },
                )
            };
            let mut v = Vec::with_capacity(12);
            for a in 0u8..8 {
                for bit in [1u8, 2, 4] {
                    if a & bit == 0 {
                        v.push(vec![corner(a), corner(a | bit)]);
                    }
                }
            }
            v
        }
        ShapeSpec::Mesh {
            vertices,
            triangles,
        } => {
            let stride = triangles.len().div_ceil(1500).max(1);
            triangles
                .iter()
                .step_by(stride)
                .filter_map(|t| {
                    let p = |i: u32| vertices.get(i as usize).map(|v| Point3::from(*v));
                    Some(vec![p(t[0])?, p(t[1])?, p(t[2])?, p(t[0])?])
                })
                .collect()
        }
    };
    local
        .into_iter()
        .map(|l| l.iter().map(|p| pose * p).collect())
        .collect()
}

/// Everything a mapping figure (Fig. 2) shows for one mapped demonstration.
pub struct MappingInput<'a> {
    pub system: &'a System,
    /// The demonstration's frames (tracker frame).
    pub human: &'a [HumanFrame],
    /// Robot joint trajectory and the registration used to map it.
    pub trajectory: &'a MappedTrajectory,
    /// Robot postures drawn along the way (start and end included), 0 to 10.
    pub postures: usize,
}

const HUMAN_FINGERS: [&str; 5] = ["thumb", "index", "middle", "ring", "little"];

/// The mapping's stored metrics in one line (issue 16): median / p95 fingertip error, mean elbow
/// distance and its link-length bound, median swivel difference, smallest exact clearances.
pub fn metrics_caption(ms: &[crate::mapping::FrameMetrics]) -> String {
    let sorted = |mut v: Vec<f64>| {
        v.retain(|x| x.is_finite());
        v.sort_by(f64::total_cmp);
        v
    };
    let at = |v: &[f64], q: f64| {
        if v.is_empty() {
            f64::NAN
        } else {
            v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1]
        }
    };
    let tips = sorted(
        ms.iter()
            .flat_map(|m| m.position_error[..m.fingers].iter().copied())
            .collect(),
    );
    let swivel = sorted(ms.iter().map(|m| m.swivel_difference).collect());
    let mean = |f: &dyn Fn(&crate::mapping::FrameMetrics) -> f64| {
        let v = sorted(ms.iter().map(f).collect());
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let min = |f: &dyn Fn(&crate::mapping::FrameMetrics) -> f64| {
        sorted(ms.iter().map(f).collect())
            .first()
            .copied()
            .unwrap_or(f64::NAN)
    };
    format!(
        "tip error median {:.1} mm, p95 {:.1} mm; elbow distance {:.0} mm (bound {:.0} mm); \
         swivel diff median {:.0}°; clearance support {:.1} mm, object {:.1} mm",
        at(&tips, 0.5) * 1e3,
        at(&tips, 0.95) * 1e3,
        mean(&|m| m.elbow_distance_mean) * 1e3,
        mean(&|m| m.elbow_bound) * 1e3,
        at(&swivel, 0.5).to_degrees(),
        min(&|m| m.support_clearance) * 1e3,
        min(&|m| m.object_clearance) * 1e3,
    )
}

/// Fig. 2: the human fingertip and elbow paths (registered into the robot base frame) against
/// the robot fingertip and elbow paths, with a few robot postures along the motion, the human
/// arm at the same instants, the registered object and table, and the mapping's metrics.
pub fn mapping_scene(input: &MappingInput<'_>) -> Result<Scene, FigureError> {
    if input.postures > 10 {
        return Err(FigureError::OutOfRange {
            param: "postures",
            value: input.postures as f64,
            min: 0.0,
            max: 10.0,
        });
    }
    let sys = input.system;
    let model = &sys.model;
    let traj = input.trajectory;
    let frames = traj.times.len();
    if frames == 0 || traj.positions.len() != frames * traj.nq() {
        return Err(FigureError::Empty {
            what: "the mapped trajectory".into(),
        });
    }
    // Trajectory columns -> model q indices, resolved once.
    let by_name: HashMap<&str, usize> = model
        .joint_names()
        .iter()
        .enumerate()
        .map(|(k, n)| (n.as_str(), k))
        .collect();
    let columns: Vec<Option<usize>> = traj
        .joint_names
        .iter()
        .map(|n| by_name.get(n.as_str()).copied())
        .collect();
    let reg: &Registration = &traj.registration;
    let mut scene = Scene {
        title: format!(
            "{}: human vs robot fingertip and elbow paths; {}",
            sys.name,
            metrics_caption(&traj.metrics)
        ),
        ..Scene::default()
    };
    // The scene the mapping registered: the object on its placement and the robot's table.
    if let Some(o) = &reg.object {
        let c = o.pose.translation.vector;
        let q = o.pose.rotation.quaternion();
        let spec = ObjectSpec {
            name: "object".into(),
            shape: crate::mapping::shape_spec(&o.shape),
            position: [c.x, c.y, c.z],
            orientation: [q.w, q.i, q.j, q.k],
            support: None,
            mass: None,
            friction: None,
        };
        for l in object_wireframe(&spec) {
            scene.line("object", OBJECT, 1, l);
        }
        if let Some(h) = reg.support {
            // A 0.3 m square of the table around the object (the plane's trace).
            let (x, y, z) = (c.x, c.y, h);
            let d = 0.15;
            scene.line(
                "support plane",
                RGBColor(150, 150, 150),
                1,
                vec![
                    Point3::new(x - d, y - d, z),
                    Point3::new(x + d, y - d, z),
                    Point3::new(x + d, y + d, z),
                    Point3::new(x - d, y + d, z),
                    Point3::new(x - d, y - d, z),
                ],
            );
        }
    }
    let human_color = |i: usize| PALETTE[(i + 1) % PALETTE.len()];
    for (i, name) in HUMAN_FINGERS.iter().enumerate() {
        let path = input
            .human
            .iter()
            .map(|f| {
                reg.hand_point(
                    &Point3::from(f.fingertips[i].translation.vector),
                    &Point3::from(f.wrist.translation.vector),
                )
            })
            .collect();
        scene.line(&format!("human {name} tip"), human_color(i), 1, path);
    }
    let elbow = input.human.iter().map(|f| reg.point(&f.elbow)).collect();
    scene.line("human elbow", HUMAN_ELBOW, 2, elbow);
    // The human arm (shoulder, elbow, wrist) at the drawn postures: the swivel to compare.
    let drawn = |k: usize, n: usize, frames: usize| match n {
        0 => false,
        1 => k == frames - 1,
        n => (0..n).any(|j| j * (frames - 1) / (n - 1) == k),
    };
    for (k, f) in input.human.iter().enumerate() {
        if drawn(k, input.postures, input.human.len()) {
            scene.line(
                "human arm",
                HUMAN_ELBOW,
                1,
                vec![
                    reg.point(&f.shoulder),
                    reg.point(&f.elbow),
                    reg.point(&Point3::from(f.wrist.translation.vector)),
                ],
            );
        }
    }

    let mut data = Data::new(model);
    let mut q = model.neutral();
    let mut tips: Vec<Vec<Point3<f64>>> = vec![Vec::with_capacity(frames); sys.fingers.len()];
    let mut robot_elbow = Vec::with_capacity(frames);
    let posture_at: Vec<usize> = match input.postures {
        0 => Vec::new(),
        1 => vec![frames - 1],
        n => (0..n).map(|k| k * (frames - 1) / (n - 1)).collect(),
    };
    let is_hand = hand_frames(model, &sys.hand_joints);
    for k in 0..frames {
        for (v, col) in traj.frame(k).iter().zip(&columns) {
            if let Some(c) = col {
                q[*c] = *v;
            }
        }
        forward_kinematics(model, &mut data, &q);
        for (f, path) in sys.fingers.iter().zip(tips.iter_mut()) {
            path.push(Point3::from(data.frame(f.tip).translation.vector));
        }
        if let Some(e) = sys.elbow_frames.first() {
            robot_elbow.push(Point3::from(data.frame(*e).translation.vector));
        }
        if posture_at.contains(&k) {
            add_links(
                &mut scene,
                model,
                &data,
                &is_hand,
                ("robot postures", "robot postures"),
                (RGBColor(160, 160, 170), RGBColor(160, 160, 170)),
            );
        }
    }
    for (f, path) in sys.fingers.iter().zip(tips) {
        scene.line(
            &format!("robot {} tip", f.name),
            RGBColor(20, 20, 20),
            2,
            path,
        );
    }
    scene.line("robot elbow", ROBOT_ELBOW, 3, robot_elbow);
    // Distinguish robot fingertip paths by colour too (black plus the palette's dark tones).
    let dark = [
        RGBColor(0, 0, 0),
        RGBColor(0, 70, 140),
        RGBColor(0, 100, 0),
        RGBColor(90, 40, 130),
        RGBColor(100, 50, 20),
    ];
    let mut i = 0;
    for l in scene.lines.iter_mut() {
        if l.name.starts_with("robot ") && l.name.ends_with(" tip") {
            l.color = dark[i % dark.len()];
            i += 1;
        }
    }
    Ok(scene)
}
