//! Graspable objects: primitives and closed triangle meshes as parry shapes with a pose, resting
//! on an optional support plane (DESIGN §5). Lengths in metres.
//!
//! Object frame convention: the object's origin is its geometric centroid `C_G` (eq. 20); the
//! axis of cylinders and capsules is the local `z` axis (parry's own primitives use `y`, so the
//! parry pose carries a fixed rotation).

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::shape::SharedShape;
use serde::{Deserialize, Serialize};

use super::GraspError;
use crate::geometry;
pub use crate::geometry::{MAX_MESH_TRIANGLES, ShapeSpec, SupportPlane};

/// Largest accepted object extent (bounding-box diagonal), metres: a hand-held object.
pub const MAX_OBJECT_EXTENT: f64 = 2.0;

/// An object description as sent by a client or stored: shape, pose, optional support plane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ObjectSpec {
    /// Display name.
    pub name: String,
    /// Geometry.
    pub shape: ShapeSpec,
    /// Position of the centroid in the world (robot base) frame.
    pub position: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]` (normalised on validation).
    pub orientation: [f64; 4],
    /// Optional support surface; links must stay above it (eq. 29).
    pub support: Option<SupportPlane>,
    /// Mass, kg (> 0, at most [`MAX_OBJECT_MASS`]). The geometry ignores it; a physics check of
    /// a grasp (a plan's `verify`) needs it and refuses an object without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(exclusive_minimum = 0, maximum = 50)]
    pub mass: Option<f64>,
    /// Coulomb friction coefficient of the object's surface against the hand's pads (> 0, at
    /// most [`MAX_FRICTION`]); needed, like `mass`, for a physics check.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(exclusive_minimum = 0, maximum = 5)]
    pub friction: Option<f64>,
}

/// Heaviest accepted object, kg: a hand-held object (the bundled hands lift well under 5 kg).
pub const MAX_OBJECT_MASS: f64 = 50.0;

/// Largest accepted Coulomb coefficient (rubber on rubber is about 1-2).
pub const MAX_FRICTION: f64 = 5.0;

/// A mass or friction coefficient that is finite, positive and at most `max`.
pub(crate) fn physical(field: &str, v: Option<f64>, max: f64) -> Result<(), GraspError> {
    match v {
        Some(x) if !x.is_finite() => Err(GraspError::NonFinite {
            field: field.into(),
        }),
        Some(x) if x <= 0.0 || x > max => Err(GraspError::InvalidDimension {
            field: field.into(),
            value: x,
        }),
        _ => Ok(()),
    }
}

impl ObjectSpec {
    /// The first property a physics check needs that this object lacks, with what it is:
    /// `("mass", …)` or `("friction", …)`; `None` when it has both.
    pub fn missing_physics(&self) -> Option<(&'static str, &'static str)> {
        if self.mass.is_none() {
            Some(("mass", "its mass in kg"))
        } else if self.friction.is_none() {
            Some((
                "friction",
                "its Coulomb friction coefficient against the hand",
            ))
        } else {
            None
        }
    }
}

/// A validated object ready for distance queries.
#[derive(Clone)]
pub struct Object {
    spec: ObjectSpec,
    pose: Isometry3<f64>,
    parry_pose: Isometry3<f64>,
    shape: SharedShape,
    /// Half of the largest extent: a bound used by heuristics (seeding, reach checks).
    bounding_radius: f64,
}

impl std::fmt::Debug for Object {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Object").field("spec", &self.spec).finish()
    }
}

/// Result of a surface query at a world point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceQuery {
    /// Signed distance to the surface: positive outside, negative inside.
    pub signed_distance: f64,
    /// Closest surface point (world).
    pub point: Point3<f64>,
    /// Outward unit normal there: the gradient of the signed distance at the query point.
    pub normal: Vector3<f64>,
}

impl Object {
    /// Validate a spec and build the parry shape.
    pub fn new(spec: ObjectSpec) -> Result<Self, GraspError> {
        let mut spec = spec;
        for (i, v) in spec.position.iter().enumerate() {
            if !v.is_finite() {
                return Err(GraspError::NonFinite {
                    field: format!("position[{i}]"),
                });
            }
        }
        let q = spec.orientation;
        let qn = (q.iter().map(|x| x * x).sum::<f64>()).sqrt();
        if !qn.is_finite() {
            return Err(GraspError::NonFinite {
                field: "orientation".into(),
            });
        }
        if qn < 1e-9 {
            return Err(GraspError::ZeroVector {
                field: "orientation".into(),
            });
        }
        let rot =
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
        spec.orientation = [rot.w, rot.i, rot.j, rot.k];
        let pose = Isometry3::from_parts(Translation3::from(Vector3::from(spec.position)), rot);
        let geometry::BuiltShape {
            shape,
            local_fix,
            bounding_radius,
        } = geometry::build_shape(&mut spec.shape, "shape")?;
        if 2.0 * bounding_radius > MAX_OBJECT_EXTENT {
            return Err(GraspError::InvalidDimension {
                field: "shape".into(),
                value: 2.0 * bounding_radius,
            });
        }
        physical("mass", spec.mass, MAX_OBJECT_MASS)?;
        physical("friction", spec.friction, MAX_FRICTION)?;
        if let Some(plane) = &mut spec.support {
            physical("support.friction", plane.friction, MAX_FRICTION)?;
            let n = Vector3::from(plane.normal);
            let nn = n.norm();
            if !nn.is_finite() || !plane.offset.is_finite() {
                return Err(GraspError::NonFinite {
                    field: "support".into(),
                });
            }
            if nn < 1e-9 {
                return Err(GraspError::ZeroVector {
                    field: "support.normal".into(),
                });
            }
            plane.normal = (n / nn).into();
            plane.offset /= nn;
        }
        Ok(Object {
            parry_pose: pose * local_fix,
            pose,
            shape,
            bounding_radius,
            spec,
        })
    }

    /// The validated spec (orientation normalised, meshes re-centred).
    pub fn spec(&self) -> &ObjectSpec {
        &self.spec
    }

    /// World pose of the object frame.
    pub fn pose(&self) -> &Isometry3<f64> {
        &self.pose
    }

    /// Geometric centroid `C_G` in the world (eq. 20).
    pub fn centroid(&self) -> Point3<f64> {
        Point3::from(self.pose.translation.vector)
    }

    /// Radius of a ball around the centroid containing the object.
    pub fn bounding_radius(&self) -> f64 {
        self.bounding_radius
    }

    /// The support plane, if any.
    pub fn support(&self) -> Option<&SupportPlane> {
        self.spec.support.as_ref()
    }

    /// Lowest world `z` of the object (of its exact shape's bounding box at its pose).
    pub fn lowest_z(&self) -> f64 {
        self.shape.compute_aabb(&self.parry_pose).mins.z
    }

    /// The parry shape and its world pose.
    pub fn shape(&self) -> (&SharedShape, &Isometry3<f64>) {
        (&self.shape, &self.parry_pose)
    }

    /// Signed distance, closest point and outward normal at a world point (parry projection).
    pub fn query(&self, p: &Point3<f64>) -> SurfaceQuery {
        let proj = self.shape.project_point(&self.parry_pose, p, false);
        let diff = p - proj.point;
        let d = diff.norm();
        // A boundary projection of a mesh does not say inside/outside; the solid containment
        // test (pseudo-normals of the oriented mesh) does.
        let inside = if self.shape.as_trimesh().is_some() {
            self.shape.contains_point(&self.parry_pose, p)
        } else {
            proj.is_inside
        };
        let sign = if inside { -1.0 } else { 1.0 };
        let normal = if d > 1e-12 {
            diff * (sign / d)
        } else {
            // On the surface the projection gives no direction; the centroid ray is a
            // well-defined outward fallback for the (star-shaped) objects handled here.
            (p - self.centroid())
                .try_normalize(1e-12)
                .unwrap_or_else(Vector3::z)
        };
        SurfaceQuery {
            signed_distance: sign * d,
            point: proj.point,
            normal,
        }
    }
}

/// Parse a Wavefront OBJ text (see [`geometry::parse_obj`]).
pub fn parse_obj(text: &str) -> Result<ShapeSpec, GraspError> {
    Ok(geometry::parse_obj(text)?)
}

/// Parse an STL file, binary or ASCII (see [`geometry::parse_stl`]).
pub fn parse_stl(bytes: &[u8]) -> Result<ShapeSpec, GraspError> {
    Ok(geometry::parse_stl(bytes)?)
}

/// Height of the lowest point of a shape along `z` in its own frame when upright (used to seat
/// seeded objects on a table).
fn half_height(shape: &ShapeSpec) -> f64 {
    match shape {
        ShapeSpec::Sphere { radius } => *radius,
        ShapeSpec::Cylinder { height, .. } => 0.5 * height,
        ShapeSpec::Box { size } => 0.5 * size[2],
        ShapeSpec::Capsule { radius, .. } => *radius,
        ShapeSpec::Mesh { vertices, .. } => vertices.iter().map(|v| -v[2]).fold(0.0, f64::max),
    }
}

/// The everyday objects of the paper's study (Fig. 7 and the spherical object of Figs. 3-6)
/// as simple shapes, with dimensions of common items.
pub fn seeded_shapes() -> Vec<(&'static str, ShapeSpec, [f64; 4])> {
    let upright = [1.0, 0.0, 0.0, 0.0];
    // Lying along the world y axis: rotate local z onto y (−90° about x).
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let lying = [h, -h, 0.0, 0.0];
    vec![
        // Soft ball (tennis-ball size, 6.6 cm).
        ("ball", ShapeSpec::Sphere { radius: 0.033 }, upright),
        // 0.5 l bottle: 6.5 cm diameter, 20 cm tall.
        (
            "bottle",
            ShapeSpec::Cylinder {
                radius: 0.0325,
                height: 0.20,
            },
            upright,
        ),
        // Round plastic kitchen timer: 6.5 cm diameter, 5 cm tall.
        (
            "kitchen_timer",
            ShapeSpec::Cylinder {
                radius: 0.0325,
                height: 0.05,
            },
            upright,
        ),
        // Pencil: 8 mm diameter, 17 cm long, lying on the table.
        (
            "pencil",
            ShapeSpec::Capsule {
                radius: 0.004,
                length: 0.17,
            },
            lying,
        ),
        // Folded sunglasses: 14 x 4.5 x 3.5 cm.
        (
            "sunglasses",
            ShapeSpec::Box {
                size: [0.045, 0.14, 0.035],
            },
            upright,
        ),
    ]
}

/// Mass (kg) and friction coefficient against rubber-padded fingers of a seeded object: common
/// items of the stated size. Ball: a tennis ball (57 g, felt, 0.8); bottle: a full 0.5 l PET
/// bottle (0.52 kg); kitchen timer: a plastic timer (0.1 kg); pencil: a wooden pencil (6 g);
/// folded sunglasses, plastic frame (30 g); 0.6 for smooth plastic and painted wood on rubber
/// (handbook ranges 0.5-1.0). Migration 0013 writes the same values into the stored objects.
pub fn seeded_properties(name: &str) -> Option<(f64, f64)> {
    match name {
        "ball" => Some((0.057, 0.8)),
        "bottle" => Some((0.52, 0.6)),
        "kitchen_timer" => Some((0.10, 0.6)),
        "pencil" => Some((0.006, 0.6)),
        "sunglasses" => Some((0.030, 0.6)),
        _ => None,
    }
}

/// Friction coefficient of the seeded objects' table (laminate) against objects and links.
pub const TABLE_FRICTION: f64 = 0.5;

/// Documented reachable placements `(x, y)` of the seeded objects on a table at `z = 0` in the
/// robot base frame (the shipped systems stand on that plane): in front of the shoulder, 0.45 to
/// 0.55 m out, up to 0.2 m to either side. Used by the claim tests and `benches/grasp.rs`.
pub const REACHABLE_PLACEMENTS: [(f64, f64); 3] = [(0.5, 0.0), (0.55, 0.15), (0.45, -0.2)];

/// A seeded object resting on a horizontal table of height `table_z`, its centroid above `(x, y)`.
pub fn seeded_object(name: &str, x: f64, y: f64, table_z: f64) -> Option<ObjectSpec> {
    seeded_shapes()
        .into_iter()
        .find(|(n, _, _)| *n == name)
        .map(|(n, shape, q)| {
            let rot =
                UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]));
            // Lowest point along world z of the rotated shape.
            let lowest = match (&shape, q == [1.0, 0.0, 0.0, 0.0]) {
                (_, true) => half_height(&shape),
                (ShapeSpec::Capsule { radius, .. }, false) => *radius,
                (ShapeSpec::Cylinder { radius, .. }, false) => *radius,
                _ => {
                    let _ = rot;
                    half_height(&shape)
                }
            };
            let (mass, friction) = seeded_properties(n).unzip();
            ObjectSpec {
                name: n.to_string(),
                shape,
                position: [x, y, table_z + lowest],
                orientation: q,
                support: Some(SupportPlane {
                    friction: Some(TABLE_FRICTION),
                    ..SupportPlane::horizontal(table_z)
                }),
                mass,
                friction,
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(shape: ShapeSpec) -> ObjectSpec {
        ObjectSpec {
            name: "t".into(),
            shape,
            position: [0.5, 0.1, 0.2],
            orientation: [1.0, 0.0, 0.0, 0.0],
            support: None,
            mass: None,
            friction: None,
        }
    }

    const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
        f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

    #[test]
    fn sphere_and_cylinder_signed_distances_match_closed_forms() {
        let s = Object::new(spec(ShapeSpec::Sphere { radius: 0.05 })).unwrap();
        let p = Point3::new(0.5, 0.1, 0.3);
        let q = s.query(&p);
        assert!((q.signed_distance - 0.05).abs() < 1e-12);
        assert!((q.normal - Vector3::z()).norm() < 1e-12);
        let inside = s.query(&Point3::new(0.52, 0.1, 0.2));
        assert!((inside.signed_distance + 0.03).abs() < 1e-12);
        assert!((inside.normal - Vector3::x()).norm() < 1e-12);
        // Cylinder axis is local z: a point beside it is radial, a point above meets the cap.
        let c = Object::new(spec(ShapeSpec::Cylinder {
            radius: 0.03,
            height: 0.2,
        }))
        .unwrap();
        let side = c.query(&Point3::new(0.5, 0.15, 0.25));
        assert!((side.signed_distance - 0.02).abs() < 1e-12, "{side:?}");
        let top = c.query(&Point3::new(0.5, 0.1, 0.35));
        assert!((top.signed_distance - 0.05).abs() < 1e-12, "{top:?}");
        assert!((top.normal - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn signed_distance_gradient_is_the_normal() {
        let objs = [
            ShapeSpec::Box {
                size: [0.1, 0.2, 0.05],
            },
            ShapeSpec::Capsule {
                radius: 0.01,
                length: 0.1,
            },
            parse_obj(CUBE_OBJ).unwrap(),
        ];
        for shape in objs {
            let mut sp = spec(shape);
            sp.orientation = [0.9, 0.1, -0.3, 0.2];
            let o = Object::new(sp).unwrap();
            let p = Point3::new(0.61, 0.23, 0.27);
            let q = o.query(&p);
            let h = 1e-6;
            for a in 0..3 {
                let mut pp = p;
                let mut pm = p;
                pp[a] += h;
                pm[a] -= h;
                let fd = (o.query(&pp).signed_distance - o.query(&pm).signed_distance) / (2.0 * h);
                assert!(
                    (fd - q.normal[a]).abs() < 1e-5,
                    "{:?} {a}: {fd} vs {}",
                    o.spec().shape,
                    q.normal[a]
                );
            }
        }
    }

    #[test]
    fn non_positive_and_non_finite_dimensions_are_rejected_by_field() {
        let e = Object::new(spec(ShapeSpec::Sphere { radius: 0.0 })).unwrap_err();
        assert_eq!(
            e,
            GraspError::InvalidDimension {
                field: "shape.radius".into(),
                value: 0.0
            }
        );
        let e = Object::new(spec(ShapeSpec::Box {
            size: [0.1, -0.2, 0.1],
        }))
        .unwrap_err();
        assert!(
            matches!(e, GraspError::InvalidDimension { ref field, .. } if field == "shape.size[1]")
        );
        let e = Object::new(spec(ShapeSpec::Cylinder {
            radius: 0.1,
            height: f64::NAN,
        }))
        .unwrap_err();
        assert!(
            matches!(e, GraspError::InvalidDimension { ref field, .. } if field == "shape.height")
        );
        let mut s = spec(ShapeSpec::Sphere { radius: 0.1 });
        s.position[1] = f64::INFINITY;
        assert!(matches!(Object::new(s), Err(GraspError::NonFinite { .. })));
        // A zero quaternion or support normal is named as such, not as "not finite".
        let mut s = spec(ShapeSpec::Sphere { radius: 0.1 });
        s.orientation = [0.0; 4];
        assert_eq!(
            Object::new(s).unwrap_err().to_string(),
            "orientation must not be the zero vector"
        );
        let mut s = spec(ShapeSpec::Sphere { radius: 0.1 });
        s.support = Some(SupportPlane {
            normal: [0.0; 3],
            offset: 0.0,
            friction: None,
        });
        assert_eq!(
            Object::new(s).unwrap_err().to_string(),
            "support.normal must not be the zero vector"
        );
    }

    #[test]
    fn meshes_are_parsed_checked_and_recentred() {
        let o = Object::new(spec(parse_obj(CUBE_OBJ).unwrap())).unwrap();
        // Unit cube re-centred: the centroid is the object position, faces 0.5 away.
        let q = o.query(&Point3::new(0.5, 0.1, 0.2));
        assert!((q.signed_distance + 0.5).abs() < 1e-9, "{q:?}");
        // Missing face: not closed.
        let open: String = CUBE_OBJ.lines().take(13).collect::<Vec<_>>().join("\n");
        assert!(matches!(
            Object::new(spec(parse_obj(&open).unwrap())),
            Err(GraspError::NonManifoldMesh { .. })
        ));
        // All faces flipped: closed but inside out.
        let flipped = CUBE_OBJ.replace("f 1 4 3 2", "f 2 3 4 1");
        assert!(matches!(
            Object::new(spec(parse_obj(&flipped).unwrap())),
            Err(GraspError::NonManifoldMesh { .. })
        ));
        assert!(matches!(
            parse_obj("v 0 0 x\n"),
            Err(GraspError::MalformedMesh { .. })
        ));
        assert!(matches!(
            parse_obj("v 0 0 0\nf 1 2 3\n"),
            Err(GraspError::MalformedMesh { .. })
        ));
        // Binary STL of the same cube welds back to 8 vertices.
        let ShapeSpec::Mesh {
            vertices,
            triangles,
        } = parse_obj(CUBE_OBJ).unwrap()
        else {
            unreachable!()
        };
        let mut stl = vec![0u8; 80];
        stl.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
        for t in &triangles {
            stl.extend_from_slice(&[0u8; 12]);
            for &i in t {
                for x in vertices[i as usize] {
                    stl.extend_from_slice(&(x as f32).to_le_bytes());
                }
            }
            stl.extend_from_slice(&[0u8; 2]);
        }
        let ShapeSpec::Mesh {
            vertices: v2,
            triangles: t2,
        } = parse_stl(&stl).unwrap()
        else {
            unreachable!()
        };
        assert_eq!((v2.len(), t2.len()), (8, 12));
        assert!(
            Object::new(spec(ShapeSpec::Mesh {
                vertices: v2,
                triangles: t2
            }))
            .is_ok()
        );
        assert!(matches!(
            parse_stl(&stl[..100]),
            Err(GraspError::MalformedMesh { .. })
        ));
        let mut huge = vec![0u8; 80];
        huge.extend_from_slice(&(10_000_000u32).to_le_bytes());
        assert!(matches!(
            parse_stl(&huge),
            Err(GraspError::MeshTooLarge { .. })
        ));
    }

    #[test]
    fn seeded_objects_rest_on_their_table() {
        for (name, _, _) in seeded_shapes() {
            let o = Object::new(seeded_object(name, 0.6, 0.0, 0.1).unwrap()).unwrap();
            // The lowest surface point touches the plane: a point 1 mm under the centroid's
            // footprint on the table is within 1 mm of the object.
            let plane = o.support().unwrap();
            let c = o.centroid();
            let below = Point3::new(c.x, c.y, plane.offset - 0.001);
            assert!(
                (o.query(&below).signed_distance - 0.001).abs() < 1e-9,
                "{name}"
            );
        }
    }
}
