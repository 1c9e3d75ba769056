//! The scene in the robot base frame: the object to grasp, the support plane it rests on (the
//! half-space below it is solid) and further obstacles, each a named shape with a pose.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::shape::SharedShape;
use serde::{Deserialize, Serialize};

use super::GeometryError;
use super::shapes::{ShapeSpec, SupportPlane, build_shape};
use super::solid::{HalfSpace, Solid};

/// An obstacle as a client sends it: a shape (mesh origin = volume centroid, cylinder and capsule
/// axes along local `z`) and its pose in the robot base frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ObstacleSpec {
    /// Name used in reports ("which link meets which obstacle").
    #[schema(min_length = 1)]
    pub name: String,
    /// Geometry.
    pub shape: ShapeSpec,
    /// Position of the shape's origin in the robot base frame, metres (within ±1000 m).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub position: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]` (normalised on validation).
    #[serde(default = "identity_quaternion")]
    #[schema(min_items = 4, max_items = 4)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub orientation: [f64; 4],
}

fn identity_quaternion() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}

/// A validated pose from a position and a `[w, x, y, z]` quaternion; fields named under `prefix`.
pub fn pose_from_parts(
    prefix: &str,
    position: &[f64; 3],
    orientation: &[f64; 4],
) -> Result<Isometry3<f64>, GeometryError> {
    for (i, v) in position.iter().enumerate() {
        if !v.is_finite() {
            return Err(GeometryError::NonFinite {
                field: format!("{prefix}position[{i}]"),
            });
        }
    }
    let q = orientation;
    let qn = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if !qn.is_finite() || qn < 1e-9 {
        return Err(GeometryError::NonFinite {
            field: format!("{prefix}orientation"),
        });
    }
    let rot = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
    Ok(Isometry3::from_parts(
        Translation3::from(Vector3::from(*position)),
        rot,
    ))
}

/// A named shape placed in the world (robot base frame).
#[derive(Clone, Debug)]
pub struct SceneShape {
    pub name: String,
    pub(crate) solid: Solid,
    /// World pose of the parry shape.
    pub(crate) pose: Isometry3<f64>,
    /// World centre of the bounding sphere.
    pub(crate) center: Point3<f64>,
}

impl SceneShape {
    /// A parry shape at a world pose (the pose of the parry shape itself, e.g.
    /// `grasp::Object::shape()`).
    pub fn new(name: impl Into<String>, shape: SharedShape, pose: Isometry3<f64>) -> SceneShape {
        let solid = Solid::new(shape);
        let center = pose * solid.center;
        SceneShape {
            name: name.into(),
            solid,
            pose,
            center,
        }
    }

    /// Validate an obstacle spec (fields named under `prefix`, e.g. `"obstacles[2]."`) and place it.
    pub fn from_spec(spec: &ObstacleSpec, prefix: &str) -> Result<SceneShape, GeometryError> {
        let pose = pose_from_parts(prefix, &spec.position, &spec.orientation)?;
        let mut shape = spec.shape.clone();
        let built = build_shape(&mut shape, &format!("{prefix}shape"))?;
        Ok(SceneShape::new(
            spec.name.clone(),
            built.shape,
            pose * built.local_fix,
        ))
    }

    pub fn solid(&self) -> &Solid {
        &self.solid
    }

    /// World pose of the parry shape.
    pub fn pose(&self) -> &Isometry3<f64> {
        &self.pose
    }

    /// World bounding sphere: centre and radius.
    pub fn bounding_sphere(&self) -> (Point3<f64>, f64) {
        (self.center, self.solid.bound)
    }
}

/// A support plane: points `x` with `normal · x = offset`; the side below is solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane(pub(crate) HalfSpace);

impl Plane {
    /// From a (not necessarily unit) normal pointing into the free side and an offset along it.
    pub fn new(normal: Vector3<f64>, offset: f64) -> Result<Plane, GeometryError> {
        let nn = normal.norm();
        if !nn.is_finite() || nn < 1e-9 || !offset.is_finite() {
            return Err(GeometryError::NonFinite {
                field: "support".into(),
            });
        }
        Ok(Plane(HalfSpace {
            normal: Unit::new_unchecked(normal / nn),
            offset: offset / nn,
        }))
    }

    /// The horizontal plane `z = height`.
    pub fn horizontal(height: f64) -> Plane {
        Plane(HalfSpace {
            normal: Vector3::z_axis(),
            offset: height,
        })
    }

    pub fn normal(&self) -> Unit<Vector3<f64>> {
        self.0.normal
    }

    pub fn offset(&self) -> f64 {
        self.0.offset
    }

    /// Signed height of a world point above the plane.
    pub fn height(&self, p: &Point3<f64>) -> f64 {
        self.0.height(p)
    }
}

impl TryFrom<&SupportPlane> for Plane {
    type Error = GeometryError;
    fn try_from(s: &SupportPlane) -> Result<Plane, GeometryError> {
        Plane::new(Vector3::from(s.normal), s.offset)
    }
}

/// Everything the robot must not run into, in its base frame.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The object to grasp (its contacts with the fingertip pads may be allowed in the closing
    /// phase).
    pub object: Option<SceneShape>,
    /// The surface the object rests on; the half-space below it is solid.
    pub support: Option<Plane>,
    pub obstacles: Vec<SceneShape>,
}

impl Scene {
    /// An empty scene (self-collision only).
    pub fn new() -> Scene {
        Scene::default()
    }

    pub fn with_object(mut self, object: SceneShape) -> Scene {
        self.object = Some(object);
        self
    }

    pub fn with_support(mut self, support: Plane) -> Scene {
        self.support = Some(support);
        self
    }

    pub fn with_obstacle(mut self, obstacle: SceneShape) -> Scene {
        self.obstacles.push(obstacle);
        self
    }

    /// Validates obstacle specs (fields named `{prefix}[i].…`, e.g. `"$.obstacles"`) and adds them.
    pub fn with_obstacle_specs(
        mut self,
        specs: &[ObstacleSpec],
        prefix: &str,
    ) -> Result<Scene, GeometryError> {
        for (i, s) in specs.iter().enumerate() {
            self.obstacles
                .push(SceneShape::from_spec(s, &format!("{prefix}[{i}]."))?);
        }
        Ok(self)
    }
}
