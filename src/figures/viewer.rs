//! The 3-D viewer's scene: what the dashboard's WebGL page draws, computed here so that the
//! browser draws the service's own geometry and kinematics and only composes transforms.
//!
//! A [`ViewScene`] holds the static shapes (every link's URDF collision shapes, and its visual
//! shapes where the URDF has them, in its link frame; object, support plane and obstacles in
//! the world; a grasp's contacts and ellipsoids) and the motion sampled at a fixed rate: per
//! frame, the world pose of every link from [`forward_kinematics`] at the joint positions
//! linearly interpolated from the track. Shapes are described in parry's own frames (cylinders
//! and capsules along local `y`, which is also three.js's convention), so a shape's pose is
//! exactly the pose the collision checks use.
//!
//! Units and conventions: robot base frame, metres, `z` up; a pose is `[x, y, z, qw, qx, qy,
//! qz]`. Numbers are rounded to 10 µm and 1e-5 (the JSON of a 20-second trajectory stays well
//! under a megabyte; far below what a screen can show).

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::shape::SharedShape;
use serde::Serialize;

use super::FigureError;
use super::scene::hand_frames;
use crate::geometry::{ShapeSpec, SupportPlane, build_shape};
use crate::grasp::{Contact, Ellipsoids};
use crate::human::HumanFrame;
use crate::kinematics::{Data, FrameId, Model, System, forward_kinematics};
use crate::mapping::Registration;

/// Default sampling rate of the motion, frames per second.
pub const VIEW_FPS: f64 = 30.0;
/// Most frames in one scene: longer motions are sampled more sparsely.
pub const MAX_VIEW_FRAMES: usize = 3600;

/// A joint-space motion: `positions` row-major, one row of `joint_names.len()` values per time.
#[derive(Debug, Clone, Copy)]
pub struct Track<'a> {
    pub joint_names: &'a [String],
    /// Strictly increasing seconds (any origin; the scene's clock starts at the first).
    pub times: &'a [f64],
    pub positions: &'a [f64],
}

/// A shape's geometry in its own frame, parry's conventions.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ViewGeometry {
    Sphere {
        radius: f64,
    },
    /// Centred on the origin; full edge lengths.
    Box {
        size: [f64; 3],
    },
    /// Along local `y`, centred; full height.
    Cylinder {
        radius: f64,
        height: f64,
    },
    /// Along local `y`, centred; `length` of the cylindrical part.
    Capsule {
        radius: f64,
        length: f64,
    },
    /// Triangles (flat `xyz` vertex list, flat index triples).
    Mesh {
        vertices: Vec<f32>,
        indices: Vec<u32>,
    },
}

/// A placed shape: for link shapes the pose is in the link frame, otherwise in the world.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewShape {
    pub name: String,
    pub geometry: ViewGeometry,
    pub pose: [f64; 7],
}

/// A robot link that carries collision or visual shapes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewLink {
    pub name: String,
    /// A hand joint moves it (drawn in the hand colour).
    pub hand: bool,
    /// The URDF collision shapes (what the collision checks use), in the link frame.
    pub shapes: Vec<ViewShape>,
    /// The URDF visual shapes where the robot has them, in the link frame (drawing only).
    pub visuals: Vec<ViewShape>,
}

/// A grasp's contact on the object surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewContact {
    pub finger: String,
    pub point: [f64; 3],
    pub normal: [f64; 3],
}

/// An arm ellipsoid (eq. 10-11) at the grasp frame of the grasp configuration, scaled so that
/// its largest semi-axis is 0.15 m (only its shape and directions carry meaning).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewEllipsoid {
    /// `velocity` or `force`.
    pub kind: String,
    pub center: [f64; 3],
    /// Unit axis directions (world).
    pub axes: [[f64; 3]; 3],
    pub semi_axes: [f64; 3],
}

/// The sampled motion: `times[k]` seconds from the start, `links[k]` the poses of every
/// [`ViewLink`] (7 values each, link order).
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct ViewFrames {
    pub fps: f64,
    pub times: Vec<f64>,
    pub links: Vec<Vec<f64>>,
}

/// The demonstrator's arm and hand, registered into the robot base frame (Fig. 2): `points`
/// names the tracked points, `segments` joins them, `frames[k]` holds their positions (3 values
/// each) at `ViewFrames::times[k]`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewHuman {
    pub points: Vec<String>,
    pub segments: Vec<[usize; 2]>,
    pub frames: Vec<Vec<f64>>,
}

/// Everything the viewer draws.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewScene {
    pub title: String,
    pub robot: String,
    /// The track's joint order (live poses are requested in it).
    pub joint_names: Vec<String>,
    pub links: Vec<ViewLink>,
    pub object: Option<ViewShape>,
    pub support: Option<SupportPlane>,
    pub obstacles: Vec<ViewShape>,
    pub contacts: Vec<ViewContact>,
    pub ellipsoids: Vec<ViewEllipsoid>,
    pub frames: ViewFrames,
    pub human: Option<ViewHuman>,
    /// A sphere holding the robot over the whole motion and the scene's shapes (camera framing).
    pub center: [f64; 3],
    pub radius: f64,
}

/// A grasp to show: the configuration (model joint names and values), its contacts and arm
/// ellipsoids.
#[derive(Debug, Clone, Copy)]
pub struct ViewGrasp<'a> {
    pub joints: &'a [(String, f64)],
    pub contacts: &'a [Contact],
    pub ellipsoids: &'a Ellipsoids,
}

/// What a scene is built from; everything but the system is optional.
#[derive(Debug, Clone, Copy)]
pub struct ViewInput<'a> {
    pub title: &'a str,
    pub robot: &'a str,
    pub system: &'a System,
    pub track: Option<Track<'a>>,
    /// Object shape (object frame: centroid, `z`-axis primitives) and its world pose.
    pub object: Option<(&'a ShapeSpec, &'a Isometry3<f64>)>,
    pub support: Option<SupportPlane>,
    /// Obstacles: name, shape, world pose of the shape's frame.
    pub obstacles: &'a [(String, ShapeSpec, Isometry3<f64>)],
    pub grasp: Option<ViewGrasp<'a>>,
    /// The demonstration a mapping was computed from, and its registration.
    pub human: Option<(&'a [HumanFrame], &'a Registration)>,
    /// Frames per second (default [`VIEW_FPS`]).
    pub fps: Option<f64>,
}

fn r5(v: f64) -> f64 {
    (v * 1e5).round() / 1e5
}

fn pose7(p: &Isometry3<f64>) -> [f64; 7] {
    let t = p.translation.vector;
    let q = p.rotation.quaternion();
    [
        r5(t.x),
        r5(t.y),
        r5(t.z),
        r5(q.w),
        r5(q.i),
        r5(q.j),
        r5(q.k),
    ]
}

fn p3(p: &Point3<f64>) -> [f64; 3] {
    [r5(p.x), r5(p.y), r5(p.z)]
}

/// A parry shape as viewer geometry, with the placement that geometry needs within the shape's
/// frame (identity except for capsules on an arbitrary segment).
fn geometry_of(shape: &SharedShape) -> (ViewGeometry, Isometry3<f64>) {
    let id = Isometry3::identity();
    if let Some(b) = shape.as_ball() {
        return (ViewGeometry::Sphere { radius: b.radius }, id);
    }
    if let Some(c) = shape.as_cuboid() {
        let h = c.half_extents;
        return (
            ViewGeometry::Box {
                size: [2.0 * h.x, 2.0 * h.y, 2.0 * h.z],
            },
            id,
        );
    }
    if let Some(c) = shape.as_cylinder() {
        return (
            ViewGeometry::Cylinder {
                radius: c.radius,
                height: 2.0 * c.half_height,
            },
            id,
        );
    }
    if let Some(c) = shape.as_capsule() {
        let (a, b) = (c.segment.a, c.segment.b);
        let axis = b - a;
        let rot = UnitQuaternion::rotation_between(&Vector3::y(), &axis)
            .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.0));
        let mid = nalgebra::center(&a, &b);
        return (
            ViewGeometry::Capsule {
                radius: c.radius,
                length: axis.norm(),
            },
            Isometry3::from_parts(Translation3::from(mid.coords), rot),
        );
    }
    let mesh = |pts: &[Point3<f64>], tris: &[[u32; 3]]| ViewGeometry::Mesh {
        vertices: pts
            .iter()
            .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect(),
        indices: tris.iter().flatten().copied().collect(),
    };
    if let Some(m) = shape.as_trimesh() {
        return (mesh(m.vertices(), m.indices()), id);
    }
    if let Some(c) = shape.as_convex_polyhedron() {
        let (pts, tris) = c.to_trimesh();
        return (mesh(&pts, &tris), id);
    }
    // Any other parry shape is drawn as its bounding box: visibly a box, never missing.
    let aabb = shape.compute_local_aabb();
    let he = aabb.half_extents();
    (
        ViewGeometry::Box {
            size: [2.0 * he.x, 2.0 * he.y, 2.0 * he.z],
        },
        Isometry3::from_parts(
            Translation3::from(aabb.center().coords),
            UnitQuaternion::identity(),
        ),
    )
}

/// A shape spec placed at `pose` (its own frame), in parry's frames.
fn placed_spec(
    name: &str,
    spec: &ShapeSpec,
    pose: &Isometry3<f64>,
) -> Result<ViewShape, FigureError> {
    let mut spec = spec.clone();
    let built = build_shape(&mut spec, name).map_err(|e| FigureError::Empty {
        what: format!("a drawable {name}: {e}"),
    })?;
    let (geometry, fix) = geometry_of(&built.shape);
    Ok(ViewShape {
        name: name.to_owned(),
        geometry,
        pose: pose7(&(pose * built.local_fix * fix)),
    })
}

/// The links with collision or visual shapes (collision shapes first, in first-shape order),
/// with their frames.
fn view_links(system: &System) -> (Vec<ViewLink>, Vec<FrameId>) {
    let model = &system.model;
    let is_hand = hand_frames(model, &system.hand_joints);
    let mut links: Vec<ViewLink> = Vec::new();
    let mut frames: Vec<FrameId> = Vec::new();
    let mut link_of = |frame: FrameId, links: &mut Vec<ViewLink>| -> usize {
        match frames.iter().position(|f| *f == frame) {
            Some(k) => k,
            None => {
                frames.push(frame);
                links.push(ViewLink {
                    name: model.frame_name(frame).to_owned(),
                    hand: is_hand[frame.0],
                    shapes: Vec::new(),
                    visuals: Vec::new(),
                });
                links.len() - 1
            }
        }
    };
    let placed = |name: String, shape: &SharedShape, origin: &Isometry3<f64>| {
        let (geometry, fix) = geometry_of(shape);
        ViewShape {
            name,
            geometry,
            pose: pose7(&(origin * fix)),
        }
    };
    for (i, c) in model.collisions().iter().enumerate() {
        let k = link_of(c.frame, &mut links);
        let name = format!("{} #{i}", links[k].name);
        links[k].shapes.push(placed(name, &c.shape, &c.origin));
    }
    for (i, v) in model.visuals().iter().enumerate() {
        let k = link_of(v.frame, &mut links);
        let name = format!("{} visual #{i}", links[k].name);
        links[k].visuals.push(placed(name, &v.shape, &v.origin));
    }
    (links, frames)
}

/// Index `i` with `times[i] <= t < times[i + 1]` (clamped) and the fraction between them.
fn locate(times: &[f64], t: f64) -> (usize, f64) {
    let n = times.len();
    if n < 2 || t <= times[0] {
        return (0, 0.0);
    }
    if t >= times[n - 1] {
        return (n - 2, 1.0);
    }
    let i = times.partition_point(|&x| x <= t) - 1;
    let span = times[i + 1] - times[i];
    let s = if span > 0.0 {
        (t - times[i]) / span
    } else {
        0.0
    };
    (i, s)
}

/// The sample times: from the first time to the last at `fps` (fewer when that would exceed
/// [`MAX_VIEW_FRAMES`]), the last time always included.
fn sample_times(t0: f64, t1: f64, fps: f64) -> (f64, Vec<f64>) {
    let span = (t1 - t0).max(0.0);
    let fps = fps.min((MAX_VIEW_FRAMES - 1) as f64 / span.max(1e-9));
    let n = (span * fps).floor() as usize;
    let mut times: Vec<f64> = (0..=n).map(|k| k as f64 / fps).collect();
    if span - times[n] > 1e-9 {
        times.push(span);
    }
    (fps, times)
}

/// Joint positions of the model (`q`, independent joints) at `t` on `track` (track joints the
/// model lacks are ignored; model joints the track lacks keep their value in `q`).
fn set_q_at(track: &Track<'_>, columns: &[Option<usize>], t: f64, q: &mut [f64]) {
    let n = track.joint_names.len();
    let (i, s) = locate(track.times, t);
    let row = |k: usize| &track.positions[k * n..(k + 1) * n];
    let a = row(i);
    let b = if track.times.len() > 1 { row(i + 1) } else { a };
    for ((col, va), vb) in columns.iter().zip(a).zip(b) {
        if let Some(c) = col {
            q[*c] = va + s * (vb - va);
        }
    }
}

/// Track columns → model `q` indices.
fn columns_of(model: &Model, joint_names: &[String]) -> Vec<Option<usize>> {
    let by_name: HashMap<&str, usize> = model
        .joint_names()
        .iter()
        .enumerate()
        .map(|(k, n)| (n.as_str(), k))
        .collect();
    joint_names
        .iter()
        .map(|n| by_name.get(n.as_str()).copied())
        .collect()
}

fn check_track(track: &Track<'_>) -> Result<(), FigureError> {
    let n = track.joint_names.len();
    if track.times.is_empty() || track.positions.len() != n * track.times.len() {
        return Err(FigureError::Empty {
            what: "the motion (no samples, or rows that do not match its joints)".into(),
        });
    }
    if track
        .positions
        .iter()
        .chain(track.times)
        .any(|v| !v.is_finite())
    {
        return Err(FigureError::Empty {
            what: "a finite motion".into(),
        });
    }
    Ok(())
}

/// World poses (7 values per link, link order) of the links `frames` at configuration `q`.
pub fn link_poses(
    model: &Model,
    data: &mut Data,
    frames: &[FrameId],
    q: &[f64],
    out: &mut Vec<f64>,
) {
    forward_kinematics(model, data, q);
    out.clear();
    for f in frames {
        out.extend_from_slice(&pose7(data.frame(*f)));
    }
}

/// The link poses of `system` for named joint positions (missing joints at the neutral
/// configuration, unknown names ignored): the live view's pose of a measured state.
pub fn pose_of(
    system: &System,
    joint_names: &[String],
    positions: &[f64],
) -> Result<Vec<f64>, FigureError> {
    if joint_names.len() != positions.len() {
        return Err(FigureError::WrongLength {
            param: "positions",
            expected: joint_names.len(),
            got: positions.len(),
        });
    }
    let times = [0.0];
    let track = Track {
        joint_names,
        times: &times,
        positions,
    };
    check_track(&track)?;
    let model = &system.model;
    let (_, frames) = view_links(system);
    let mut q = model.neutral();
    set_q_at(&track, &columns_of(model, joint_names), 0.0, &mut q);
    let mut data = Data::new(model);
    let mut out = Vec::with_capacity(7 * frames.len());
    link_poses(model, &mut data, &frames, &q, &mut out);
    Ok(out)
}

const HUMAN_POINTS: [&str; 8] = [
    "shoulder",
    "elbow",
    "wrist",
    "thumb tip",
    "index tip",
    "middle tip",
    "ring tip",
    "little tip",
];

/// The registered human points of the frame at `t` (nearest frame in time: the tracker runs
/// at ~240 Hz, far above the viewer's rate).
fn human_points(human: &[HumanFrame], reg: &Registration, t: f64) -> Vec<f64> {
    let k = human.partition_point(|f| f.t < t).min(human.len() - 1);
    let k = if k > 0 && (human[k - 1].t - t).abs() < (human[k].t - t).abs() {
        k - 1
    } else {
        k
    };
    let f = &human[k];
    let wrist = Point3::from(f.wrist.translation.vector);
    let mut out = Vec::with_capacity(3 * HUMAN_POINTS.len());
    out.extend(p3(&reg.point(&f.shoulder)));
    out.extend(p3(&reg.point(&f.elbow)));
    out.extend(p3(&reg.point(&wrist)));
    for tip in &f.fingertips {
        out.extend(p3(
            &reg.hand_point(&Point3::from(tip.translation.vector), &wrist)
        ));
    }
    out
}

/// Builds the scene: static shapes, then the motion sampled at `fps` with FK per frame.
pub fn view_scene(input: &ViewInput<'_>) -> Result<ViewScene, FigureError> {
    let system = input.system;
    let model = &system.model;
    let fps = input.fps.unwrap_or(VIEW_FPS);
    if !(fps.is_finite() && (1.0..=120.0).contains(&fps)) {
        return Err(FigureError::OutOfRange {
            param: "fps",
            value: fps,
            min: 1.0,
            max: 120.0,
        });
    }
    let (links, link_frames) = view_links(system);
    let mut data = Data::new(model);
    let mut q = model.neutral();

    let mut scene = ViewScene {
        title: input.title.to_owned(),
        robot: input.robot.to_owned(),
        joint_names: model.joint_names().to_vec(),
        links,
        object: None,
        support: input.support,
        obstacles: Vec::new(),
        contacts: Vec::new(),
        ellipsoids: Vec::new(),
        frames: ViewFrames::default(),
        human: None,
        center: [0.0; 3],
        radius: 1.0,
    };
    if let Some((spec, pose)) = input.object {
        scene.object = Some(placed_spec("object", spec, pose)?);
    }
    for (name, spec, pose) in input.obstacles {
        scene.obstacles.push(placed_spec(name, spec, pose)?);
    }
    if let Some(g) = &input.grasp {
        scene.contacts = g
            .contacts
            .iter()
            .map(|c| ViewContact {
                finger: c.finger.clone(),
                point: c.point.map(r5),
                normal: c.normal.map(r5),
            })
            .collect();
        let mut qg = model.neutral();
        for (name, v) in g.joints {
            if let Some(k) = model.q_index(name) {
                qg[k] = *v;
            }
        }
        forward_kinematics(model, &mut data, &qg);
        let c = data.frame(system.wrist_frame).translation.vector;
        let e = g.ellipsoids;
        for (kind, semi) in [
            ("velocity", e.velocity_semi_axes),
            ("force", e.force_semi_axes),
        ] {
            let largest = semi.iter().copied().fold(0.0_f64, f64::max);
            if largest.is_finite() && largest > 0.0 {
                scene.ellipsoids.push(ViewEllipsoid {
                    kind: kind.into(),
                    center: [r5(c.x), r5(c.y), r5(c.z)],
                    axes: e.axes.map(|a| a.map(r5)),
                    semi_axes: semi.map(|v| r5(0.15 * v / largest)),
                });
            }
        }
    }

    // The motion: a track, else the grasp configuration, else the neutral posture.
    let mut frames = ViewFrames {
        fps,
        ..ViewFrames::default()
    };
    let mut pose = Vec::with_capacity(7 * link_frames.len());
    match &input.track {
        Some(track) => {
            check_track(track)?;
            scene.joint_names = track.joint_names.to_vec();
            let columns = columns_of(model, track.joint_names);
            let t0 = track.times[0];
            let (fps, times) = sample_times(t0, track.times[track.times.len() - 1], fps);
            frames.fps = r5(fps);
            for &t in &times {
                set_q_at(track, &columns, t0 + t, &mut q);
                link_poses(model, &mut data, &link_frames, &q, &mut pose);
                frames.links.push(pose.clone());
            }
            if let Some((human, reg)) = input.human.filter(|(h, _)| !h.is_empty()) {
                scene.human = Some(ViewHuman {
                    points: HUMAN_POINTS.iter().map(|s| (*s).to_owned()).collect(),
                    segments: vec![[0, 1], [1, 2], [2, 3], [2, 4], [2, 5], [2, 6], [2, 7]],
                    frames: times
                        .iter()
                        .map(|&t| human_points(human, reg, t0 + t))
                        .collect(),
                });
            }
            frames.times = times.into_iter().map(r5).collect();
        }
        None => {
            if let Some(g) = &input.grasp {
                for (name, v) in g.joints {
                    if let Some(k) = model.q_index(name) {
                        q[k] = *v;
                    }
                }
            }
            link_poses(model, &mut data, &link_frames, &q, &mut pose);
            frames.times.push(0.0);
            frames.links.push(pose.clone());
        }
    }
    scene.frames = frames;
    let (center, radius) = framing(&scene);
    scene.center = center;
    scene.radius = radius;
    Ok(scene)
}

/// Centre and radius of a sphere around every link origin over the motion, the object, the
/// obstacles and the human points (each shape counted by its position plus a margin).
fn framing(scene: &ViewScene) -> ([f64; 3], f64) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    let mut add = |p: Vector3<f64>| {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    };
    for f in &scene.frames.links {
        for l in f.chunks_exact(7) {
            add(Vector3::new(l[0], l[1], l[2]));
        }
    }
    for s in scene.object.iter().chain(&scene.obstacles) {
        add(Vector3::new(s.pose[0], s.pose[1], s.pose[2]));
    }
    if let Some(h) = &scene.human {
        for f in &h.frames {
            for p in f.chunks_exact(3) {
                add(Vector3::new(p[0], p[1], p[2]));
            }
        }
    }
    if lo.x > hi.x {
        return ([0.0; 3], 1.0);
    }
    let c = (lo + hi) / 2.0;
    let r = ((hi - lo).norm() / 2.0 + 0.15).max(0.3);
    ([r5(c.x), r5(c.y), r5(c.z)], r5(r))
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;
    use std::sync::OnceLock;

    use nalgebra::{Quaternion, Translation3};

    use super::*;
    use crate::geometry::RobotGeometry;

    fn system() -> &'static System {
        static S: OnceLock<System> = OnceLock::new();
        S.get_or_init(|| {
            let path =
                PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml");
            System::from_file(&path).expect("bundled system loads")
        })
    }

    fn iso(p: &[f64]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(p[0], p[1], p[2]),
            UnitQuaternion::from_quaternion(Quaternion::new(p[3], p[4], p[5], p[6])),
        )
    }

    /// A smooth motion of every joint from neutral, `secs` long at 100 Hz.
    fn motion(secs: f64) -> (Vec<String>, Vec<f64>, Vec<f64>) {
        let m = &system().model;
        let names = m.joint_names().to_vec();
        let neutral = m.neutral();
        let n = (secs * 100.0).round() as usize;
        let times: Vec<f64> = (0..=n).map(|k| k as f64 / 100.0).collect();
        let mut pos = Vec::new();
        for &t in &times {
            for (j, q0) in neutral.iter().enumerate() {
                let (lo, hi) = (m.lower_limits()[j], m.upper_limits()[j]);
                let amp = 0.3 * (hi - lo).min(2.0);
                pos.push((q0 + amp * (0.7 * t + j as f64).sin()).clamp(lo, hi));
            }
        }
        (names, times, pos)
    }

    fn input<'a>(track: Option<Track<'a>>) -> ViewInput<'a> {
        ViewInput {
            title: "test",
            robot: "wam_ihy",
            system: system(),
            track,
            object: None,
            support: None,
            obstacles: &[],
            grasp: None,
            human: None,
            fps: None,
        }
    }

    #[test]
    fn a_frames_link_poses_are_the_forward_kinematics_of_the_motion_at_that_time() {
        let (names, times, pos) = motion(2.0);
        let track = Track {
            joint_names: &names,
            times: &times,
            positions: &pos,
        };
        let scene = view_scene(&input(Some(track))).unwrap();
        let model = &system().model;
        let mut data = Data::new(model);
        let nq = names.len();
        // Frame 3 is at 0.1 s = track sample 10; frame 4 (0.1333 s) lies between samples 13
        // and 14 and must be the FK of the linear interpolation between them.
        for (frame, q) in [
            (3, pos[10 * nq..11 * nq].to_vec()),
            (4, {
                let s = (4.0 / 30.0 - 0.13) / 0.01;
                (0..nq)
                    .map(|j| pos[13 * nq + j] + s * (pos[14 * nq + j] - pos[13 * nq + j]))
                    .collect()
            }),
        ] {
            forward_kinematics(model, &mut data, &q);
            for (k, link) in scene.links.iter().enumerate() {
                let f = model.frame_id(&link.name).unwrap();
                let got = iso(&scene.frames.links[frame][7 * k..7 * k + 7]);
                let want = data.frame(f);
                assert!(
                    (got.translation.vector - want.translation.vector).norm() < 2e-5,
                    "{} at frame {frame}",
                    link.name
                );
                assert!(
                    got.rotation.angle_to(&want.rotation) < 1e-4,
                    "{}",
                    link.name
                );
            }
        }
    }

    #[test]
    fn link_pose_times_shape_pose_is_where_the_collision_checks_put_each_shape() {
        let (names, times, pos) = motion(1.0);
        let track = Track {
            joint_names: &names,
            times: &times,
            positions: &pos,
        };
        let scene = view_scene(&input(Some(track))).unwrap();
        let geometry = RobotGeometry::from_system(system());
        let model = &system().model;
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, &pos[30 * names.len()..31 * names.len()]);
        let mut poses = vec![Isometry3::identity(); geometry.shapes().len()];
        geometry.pose_shapes(&data, &mut poses);
        let mut checked = 0;
        for (shape, want) in geometry.shapes().iter().zip(&poses) {
            let k = scene
                .links
                .iter()
                .position(|l| l.name == shape.link)
                .unwrap();
            let link = iso(&scene.frames.links[9][7 * k..7 * k + 7]);
            // Capsules carry the segment's placement in their pose; compare the others exactly.
            let candidates: Vec<Isometry3<f64>> = scene.links[k]
                .shapes
                .iter()
                .filter(|s| !matches!(s.geometry, ViewGeometry::Capsule { .. }))
                .map(|s| link * iso(&s.pose))
                .collect();
            if candidates.is_empty() {
                continue;
            }
            let best = candidates
                .iter()
                .map(|c| (c.translation.vector - want.translation.vector).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(best < 5e-5, "{}: {best}", shape.link);
            checked += 1;
        }
        assert!(checked >= 8, "only {checked} shapes compared");
    }

    #[test]
    fn twenty_seconds_at_thirty_frames_per_second_is_601_frames_ending_at_the_end() {
        let (names, times, pos) = motion(20.0);
        let track = Track {
            joint_names: &names,
            times: &times,
            positions: &pos,
        };
        let scene = view_scene(&input(Some(track))).unwrap();
        assert_eq!(scene.frames.times.len(), 601);
        assert_eq!(scene.frames.links.len(), 601);
        assert_eq!(*scene.frames.times.last().unwrap(), 20.0);
        assert!(
            scene
                .frames
                .links
                .iter()
                .all(|f| f.len() == 7 * scene.links.len())
        );
        // Not a still picture: the hand moves.
        let (a, b) = (&scene.frames.links[0], &scene.frames.links[300]);
        let last = 7 * (scene.links.len() - 1);
        assert!((a[last] - b[last]).abs() + (a[last + 1] - b[last + 1]).abs() > 1e-3);
    }

    #[test]
    fn a_z_axis_cylinder_object_is_drawn_with_its_axis_along_the_objects_z() {
        let spec = ShapeSpec::Cylinder {
            radius: 0.03,
            height: 0.2,
        };
        let pose = Isometry3::from_parts(
            Translation3::new(0.5, 0.1, 0.2),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.4),
        );
        let scene = view_scene(&ViewInput {
            object: Some((&spec, &pose)),
            ..input(None)
        })
        .unwrap();
        let o = scene.object.unwrap();
        assert_eq!(
            o.geometry,
            ViewGeometry::Cylinder {
                radius: 0.03,
                height: 0.2
            }
        );
        // three.js cylinders, like parry's, run along local y.
        let drawn_axis = iso(&o.pose).rotation * Vector3::y();
        assert!((drawn_axis - pose.rotation * Vector3::z()).norm() < 1e-4);
        assert_eq!(scene.frames.times, vec![0.0]);
    }

    #[test]
    fn a_live_pose_equals_the_scene_frame_at_the_same_joint_values() {
        let (names, times, pos) = motion(1.0);
        let track = Track {
            joint_names: &names,
            times: &times,
            positions: &pos,
        };
        let scene = view_scene(&input(Some(track))).unwrap();
        let got = pose_of(system(), &names, &pos[..names.len()]).unwrap();
        assert_eq!(got, scene.frames.links[0]);
        assert!(pose_of(system(), &names, &pos[..2]).is_err());
    }

    #[test]
    fn a_motion_whose_rows_do_not_match_its_joints_is_refused() {
        let names = vec!["wam_j1".to_owned()];
        let track = Track {
            joint_names: &names,
            times: &[0.0, 1.0],
            positions: &[0.0],
        };
        assert!(view_scene(&input(Some(track))).is_err());
    }
}
