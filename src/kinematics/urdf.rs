//! URDF → [`Model`] conversion, in one place: the maths never sees XML (cf. openrr/k `src/urdf.rs`).
//!
//! Supported: revolute, continuous, prismatic and fixed joints; `<mimic>` folded into the driver
//! (multiplier and offset); position/velocity/effort limits; collision geometry as parry shapes
//! (box, cylinder, capsule, sphere, STL/OBJ meshes), and `<visual>` geometry of the same kinds for
//! drawing only (kinematics and collision checks never read it). Links without inertia or
//! geometry are fine.
//! Everything is validated before the model is built, and every error names the joint or link.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::shape::SharedShape;

use super::error::{KinematicsError, check_finite};
use super::mesh::parse_mesh;
use super::model::{FrameId, JointKind, JointLimits, Mimic, Model, ModelBuilder};

/// URDF texts above this size are refused (the bundled ones are a few kB; big ecosystem
/// descriptions stay well below a megabyte once meshes are external).
pub const MAX_URDF_BYTES: usize = 4 * 1024 * 1024;

/// Where mesh files referenced by a URDF come from.
pub trait MeshSource {
    /// The bytes of `filename` as written in the URDF, or why they cannot be had.
    fn read(&self, filename: &str) -> Result<Vec<u8>, String>;
}

/// For URDF text without files around it: every mesh reference is an error.
pub struct NoMeshes;

impl MeshSource for NoMeshes {
    fn read(&self, _filename: &str) -> Result<Vec<u8>, String> {
        Err("no mesh files are available for this URDF (register primitives, or load from a directory)".into())
    }
}

/// Meshes supplied with the URDF text (uploaded with a registered system), by the filename
/// exactly as the URDF references it.
pub struct MapMeshes(pub std::collections::BTreeMap<String, Vec<u8>>);

impl MeshSource for MapMeshes {
    fn read(&self, filename: &str) -> Result<Vec<u8>, String> {
        self.0.get(filename).cloned().ok_or_else(|| {
            let known: Vec<&str> = self.0.keys().map(String::as_str).collect();
            format!("mesh '{filename}' was not uploaded with the robot (uploaded: {known:?})")
        })
    }
}

/// Meshes relative to the URDF's directory. `package://pkg/rest` and `file://` are resolved by
/// looking for `rest` (then `pkg/rest`) in the URDF directory and its ancestors, which covers the
/// usual ROS package layouts without a ROS installation.
pub struct DirMeshes {
    pub base: PathBuf,
}

impl DirMeshes {
    fn candidates(&self, filename: &str) -> Vec<PathBuf> {
        if let Some(abs) = filename.strip_prefix("file://") {
            return vec![PathBuf::from(abs)];
        }
        if let Some(rest) = filename.strip_prefix("package://") {
            let (pkg, tail) = rest.split_once('/').unwrap_or((rest, ""));
            let mut out = Vec::new();
            for dir in self.base.ancestors().take(4) {
                out.push(dir.join(tail));
                out.push(dir.join(pkg).join(tail));
            }
            return out;
        }
        vec![self.base.join(filename)]
    }
}

impl MeshSource for DirMeshes {
    fn read(&self, filename: &str) -> Result<Vec<u8>, String> {
        let candidates = self.candidates(filename);
        for c in &candidates {
            if c.is_file() {
                return std::fs::read(c).map_err(|e| format!("{}: {e}", c.display()));
            }
        }
        Err(format!(
            "not found (looked at {})",
            candidates
                .iter()
                .map(|c| c.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    }
}

/// Parses URDF text, enforcing the size limit.
pub fn parse_urdf(text: &str) -> Result<urdf_rs::Robot, KinematicsError> {
    if text.len() > MAX_URDF_BYTES {
        return Err(KinematicsError::UrdfTooLarge {
            size: text.len(),
            limit: MAX_URDF_BYTES,
        });
    }
    urdf_rs::read_from_string(text).map_err(|e| KinematicsError::MalformedUrdf {
        message: e.to_string(),
    })
}

/// Loads a standalone model from URDF text.
pub fn model_from_urdf_str(text: &str, meshes: &dyn MeshSource) -> Result<Model, KinematicsError> {
    let robot = parse_urdf(text)?;
    let root = root_link(&robot)?;
    let mut b = ModelBuilder::new(&root);
    append_robot(&mut b, &robot, None, meshes)?;
    b.build()
}

/// Loads a standalone model from a URDF file; meshes resolve relative to it.
pub fn model_from_urdf_file(path: &Path) -> Result<Model, KinematicsError> {
    let text = read_text(path)?;
    model_from_urdf_str(
        &text,
        &DirMeshes {
            base: path.parent().unwrap_or(Path::new(".")).to_path_buf(),
        },
    )
}

pub(crate) fn read_text(path: &Path) -> Result<String, KinematicsError> {
    let meta = std::fs::metadata(path).map_err(|e| KinematicsError::FileUnreadable {
        path: path.display().to_string(),
        reason: e.to_string(),
    })?;
    if meta.len() as usize > MAX_URDF_BYTES {
        return Err(KinematicsError::UrdfTooLarge {
            size: meta.len() as usize,
            limit: MAX_URDF_BYTES,
        });
    }
    std::fs::read_to_string(path).map_err(|e| KinematicsError::FileUnreadable {
        path: path.display().to_string(),
        reason: e.to_string(),
    })
}

/// How a URDF is grafted onto an existing tree: a fixed joint `joint` from `parent` to the URDF's
/// root link, placed at `origin`.
pub struct Attach<'a> {
    pub parent: FrameId,
    pub origin: Isometry3<f64>,
    pub joint: &'a str,
}

/// The single root link of the URDF, after checking link references, parents and cycles.
pub fn root_link(robot: &urdf_rs::Robot) -> Result<String, KinematicsError> {
    let mut links = HashSet::new();
    for l in &robot.links {
        if !links.insert(l.name.as_str()) {
            return Err(KinematicsError::DuplicateFrame {
                name: l.name.clone(),
            });
        }
    }
    let mut joint_names = HashSet::new();
    let mut parent_joint: HashMap<&str, &str> = HashMap::new();
    for j in &robot.joints {
        if !joint_names.insert(j.name.as_str()) {
            return Err(KinematicsError::DuplicateJoint {
                name: j.name.clone(),
            });
        }
        for (role, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains(link.as_str()) {
                return Err(KinematicsError::MissingLink {
                    joint: j.name.clone(),
                    role,
                    link: link.clone(),
                });
            }
        }
        if let Some(first) = parent_joint.insert(j.child.link.as_str(), j.name.as_str()) {
            return Err(KinematicsError::TwoParents {
                link: j.child.link.clone(),
                first: first.to_owned(),
                second: j.name.clone(),
            });
        }
    }
    let roots: Vec<String> = robot
        .links
        .iter()
        .filter(|l| !parent_joint.contains_key(l.name.as_str()))
        .map(|l| l.name.clone())
        .collect();
    match roots.len() {
        0 => Err(KinematicsError::Cycle {
            link: robot
                .links
                .first()
                .map(|l| l.name.clone())
                .unwrap_or_default(),
        }),
        1 => {
            // Every link has one parent and there is one root; any link not reached from the
            // root sits on a cycle.
            let mut children: HashMap<&str, Vec<&str>> = HashMap::new();
            for j in &robot.joints {
                children
                    .entry(j.parent.link.as_str())
                    .or_default()
                    .push(j.child.link.as_str());
            }
            let mut seen = HashSet::new();
            let mut stack = vec![roots[0].as_str()];
            while let Some(l) = stack.pop() {
                if seen.insert(l) {
                    stack.extend(children.get(l).into_iter().flatten());
                }
            }
            if let Some(l) = robot.links.iter().find(|l| !seen.contains(l.name.as_str())) {
                return Err(KinematicsError::Cycle {
                    link: l.name.clone(),
                });
            }
            Ok(roots[0].clone())
        }
        _ => Err(KinematicsError::SeveralRoots { roots }),
    }
}

fn pose(path: impl Fn() -> String, p: &urdf_rs::Pose) -> Result<Isometry3<f64>, KinematicsError> {
    for &v in p.xyz.iter().chain(p.rpy.iter()) {
        check_finite(&path, v)?;
    }
    // URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z, i.e.
    // R = Rz(yaw) Ry(pitch) Rx(roll) — exactly nalgebra's `from_euler_angles`.
    Ok(Isometry3::from_parts(
        Translation3::new(p.xyz[0], p.xyz[1], p.xyz[2]),
        UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]),
    ))
}

/// Adds the links and joints of `robot` to `b`: under `attach`, or (when `None`) assuming `b`'s
/// root frame is the URDF's root link.
pub fn append_robot(
    b: &mut ModelBuilder,
    robot: &urdf_rs::Robot,
    attach: Option<Attach<'_>>,
    meshes: &dyn MeshSource,
) -> Result<(), KinematicsError> {
    let root = root_link(robot)?;
    let root_frame = match attach {
        None => {
            let r = b.root();
            debug_assert_eq!(b.frame_id(&root), Some(r));
            r
        }
        Some(a) => b.add_joint(
            a.joint,
            a.parent,
            &root,
            JointKind::Fixed,
            a.origin,
            JointLimits::unbounded(),
            None,
        )?,
    };
    let links: HashMap<&str, &urdf_rs::Link> =
        robot.links.iter().map(|l| (l.name.as_str(), l)).collect();
    let mut children: HashMap<&str, Vec<&urdf_rs::Joint>> = HashMap::new();
    for j in &robot.joints {
        children.entry(j.parent.link.as_str()).or_default().push(j);
    }
    add_collisions(b, root_frame, links[root.as_str()], meshes)?;
    add_visuals(b, root_frame, links[root.as_str()], meshes);
    // Depth-first in document order, so `q` follows the order a reader of the file expects.
    let mut stack: Vec<(&str, FrameId)> = vec![(root.as_str(), root_frame)];
    while let Some((link, frame)) = stack.pop() {
        let Some(js) = children.get(link) else {
            continue;
        };
        let mut added = Vec::with_capacity(js.len());
        for j in js {
            let child = add_joint(b, j, frame)?;
            add_collisions(b, child, links[j.child.link.as_str()], meshes)?;
            add_visuals(b, child, links[j.child.link.as_str()], meshes);
            added.push((j.child.link.as_str(), child));
        }
        stack.extend(added.into_iter().rev());
    }
    Ok(())
}

fn add_joint(
    b: &mut ModelBuilder,
    j: &urdf_rs::Joint,
    parent: FrameId,
) -> Result<FrameId, KinematicsError> {
    let name = j.name.as_str();
    let origin = pose(|| format!("joint '{name}' origin"), &j.origin)?;
    let axis = || -> Result<Unit<Vector3<f64>>, KinematicsError> {
        let a = Vector3::new(j.axis.xyz[0], j.axis.xyz[1], j.axis.xyz[2]);
        for &v in a.iter() {
            check_finite(|| format!("joint '{name}' axis"), v)?;
        }
        Unit::try_new(a, 1e-9).ok_or(KinematicsError::ZeroAxis {
            joint: name.to_owned(),
        })
    };
    let kind = match j.joint_type {
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        urdf_rs::JointType::Revolute => JointKind::Revolute { axis: axis()? },
        urdf_rs::JointType::Continuous => JointKind::Continuous { axis: axis()? },
        urdf_rs::JointType::Prismatic => JointKind::Prismatic { axis: axis()? },
        ref other => {
            return Err(KinematicsError::UnsupportedJoint {
                joint: name.to_owned(),
                kind: format!("{other:?}").to_lowercase(),
            });
        }
    };
    let l = &j.limit;
    for (field, v) in [("lower limit", l.lower), ("upper limit", l.upper)] {
        // Continuous joints ignore position limits, and URDF 1.2 writes "no limit" as infinity.
        if !matches!(kind, JointKind::Continuous { .. } | JointKind::Fixed) {
            check_finite(|| format!("joint '{name}' {field}"), v)?;
        } else if v.is_nan() {
            return Err(KinematicsError::NonFinite {
                path: format!("joint '{name}' {field}"),
                value: v,
            });
        }
    }
    // Velocity/effort 0 (the URDF default when the attribute is omitted, common on gripper mimic
    // joints) means "not specified", so it becomes unbounded rather than a frozen joint.
    let rate = |field: &str, v: f64| -> Result<f64, KinematicsError> {
        if v.is_nan() {
            return Err(KinematicsError::NonFinite {
                path: format!("joint '{name}' {field}"),
                value: v,
            });
        }
        Ok(if v == 0.0 { f64::INFINITY } else { v })
    };
    let limits = JointLimits::new(
        l.lower,
        l.upper,
        rate("velocity limit", l.velocity)?,
        rate("effort limit", l.effort)?,
    );
    let mimic = j.mimic.as_ref().map(|m| Mimic {
        joint: m.joint.clone(),
        multiplier: m.multiplier.unwrap_or(1.0),
        offset: m.offset.unwrap_or(0.0),
    });
    b.add_joint(name, parent, &j.child.link, kind, origin, limits, mimic)
}

fn add_collisions(
    b: &mut ModelBuilder,
    frame: FrameId,
    link: &urdf_rs::Link,
    meshes: &dyn MeshSource,
) -> Result<(), KinematicsError> {
    for c in &link.collision {
        let (shape, origin) =
            placed_shape(&link.name, "collision", &c.origin, &c.geometry, meshes)?;
        b.add_collision(frame, origin, shape)?;
    }
    Ok(())
}

/// Keeps a link's `<visual>` geometry for drawing. A visual that cannot be built (a mesh file
/// that is missing or malformed, a bad size) is recorded on the model instead of failing the
/// load: drawing-only data must not make a robot stored before it was read unusable, while
/// registration refuses it (see [`Model::visual_errors`]).
fn add_visuals(
    b: &mut ModelBuilder,
    frame: FrameId,
    link: &urdf_rs::Link,
    meshes: &dyn MeshSource,
) {
    for v in &link.visual {
        match placed_shape(&link.name, "visual", &v.origin, &v.geometry, meshes) {
            Ok((shape, origin)) => b.add_visual(frame, origin, shape),
            Err(e) => b.add_visual_error(e),
        }
    }
}

/// A URDF geometry as a parry shape and its placement in the link frame (`role` is
/// `collision` or `visual`, for the messages).
fn placed_shape(
    name: &str,
    role: &str,
    origin: &urdf_rs::Pose,
    geometry: &urdf_rs::Geometry,
    meshes: &dyn MeshSource,
) -> Result<(SharedShape, Isometry3<f64>), KinematicsError> {
    let bad = |reason: String| KinematicsError::BadGeometry {
        link: name.to_owned(),
        reason,
    };
    let origin = pose(|| format!("link '{name}' {role} origin"), origin)?;
    let positive = |what: &str, v: f64| -> Result<f64, KinematicsError> {
        check_finite(|| format!("link '{name}' {role} {what}"), v)?;
        if v <= 0.0 {
            Err(bad(format!("{role} {what} must be positive, got {v}")))
        } else {
            Ok(v)
        }
    };
    // parry's cylinder is along y; URDF cylinders and capsules are along z.
    let y_to_z = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
    Ok(match geometry {
        urdf_rs::Geometry::Box { size } => {
            let s: Vec<f64> = size
                .iter()
                .map(|&v| positive("box size", v))
                .collect::<Result<_, _>>()?;
            (
                SharedShape::cuboid(s[0] / 2.0, s[1] / 2.0, s[2] / 2.0),
                origin,
            )
        }
        urdf_rs::Geometry::Cylinder { radius, length } => {
            let (r, l) = (
                positive("cylinder radius", *radius)?,
                positive("cylinder length", *length)?,
            );
            (SharedShape::cylinder(l / 2.0, r), origin * y_to_z)
        }
        urdf_rs::Geometry::Capsule { radius, length } => {
            let (r, l) = (
                positive("capsule radius", *radius)?,
                positive("capsule length", *length)?,
            );
            (
                SharedShape::capsule(
                    Point3::new(0.0, 0.0, -l / 2.0),
                    Point3::new(0.0, 0.0, l / 2.0),
                    r,
                ),
                origin,
            )
        }
        urdf_rs::Geometry::Sphere { radius } => (
            SharedShape::ball(positive("sphere radius", *radius)?),
            origin,
        ),
        urdf_rs::Geometry::Mesh { filename, scale } => {
            let s = scale.map(|s| s.0).unwrap_or([1.0; 3]);
            for v in s {
                positive("mesh scale", v)?;
            }
            let bytes =
                meshes
                    .read(filename)
                    .map_err(|reason| KinematicsError::MeshUnreadable {
                        link: name.to_owned(),
                        path: filename.clone(),
                        reason,
                    })?;
            let mesh = parse_mesh(filename, &bytes, s).map_err(|reason| {
                KinematicsError::MeshMalformed {
                    link: name.to_owned(),
                    path: filename.clone(),
                    reason,
                }
            })?;
            (SharedShape::new(mesh), origin)
        }
    })
}
