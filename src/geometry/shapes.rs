//! Shape descriptions shared by graspable objects and scene obstacles: primitives and closed
//! triangle meshes (OBJ/STL), validated and turned into parry shapes. Lengths in metres.
//!
//! Frame convention: the axis of cylinders and capsules is the local `z` axis (parry's own
//! primitives use `y`, so a built shape carries a fixed rotation, [`BuiltShape::local_fix`]).

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::shape::{Ball, Capsule, Cuboid, Cylinder, SharedShape, TriMesh, TriMeshFlags};
use serde::{Deserialize, Serialize};

use super::GeometryError;

/// Largest accepted triangle count of an uploaded mesh.
pub const MAX_MESH_TRIANGLES: usize = 100_000;

/// Geometry of an object, in its own frame.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ShapeSpec {
    /// A ball.
    Sphere {
        /// Radius.
        radius: f64,
    },
    /// A cylinder along local `z`, centred on the origin.
    Cylinder {
        /// Radius.
        radius: f64,
        /// Full height.
        height: f64,
    },
    /// A box centred on the origin.
    Box {
        /// Full edge lengths along x, y, z.
        #[schema(min_items = 3, max_items = 3)]
        size: [f64; 3],
    },
    /// A capsule along local `z`: a cylinder of `length` with hemispherical caps.
    Capsule {
        /// Radius.
        radius: f64,
        /// Length of the cylindrical part (total length = length + 2 radius).
        length: f64,
    },
    /// A closed, consistently oriented triangle mesh; it is re-centred on its volume centroid.
    Mesh {
        /// Vertex positions.
        vertices: Vec<[f64; 3]>,
        /// Triangles as vertex indices (counter-clockwise seen from outside).
        triangles: Vec<[u32; 3]>,
    },
}

/// Read through [`ShapeWire`] so that a bad field names its own path (`$.shape.radius`): a
/// derived internally tagged enum is buffered and its errors stop at `$.shape`.
impl<'de> Deserialize<'de> for ShapeSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        crate::wire::tagged(d, "type", "a shape object with a `type`").map(ShapeWire::into)
    }
}

/// [`ShapeSpec`] externally tagged (`{"sphere": {"radius": 0.1}}`), as [`crate::wire::tagged`]
/// reads it.
#[derive(Deserialize)]
#[serde(rename_all = "snake_case")]
enum ShapeWire {
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
        length: f64,
    },
    Mesh {
        #[serde(deserialize_with = "crate::wire::exact")]
        vertices: Vec<[f64; 3]>,
        #[serde(deserialize_with = "crate::wire::exact")]
        triangles: Vec<[u32; 3]>,
    },
}

impl From<ShapeWire> for ShapeSpec {
    fn from(w: ShapeWire) -> Self {
        match w {
            ShapeWire::Sphere { radius } => ShapeSpec::Sphere { radius },
            ShapeWire::Cylinder { radius, height } => ShapeSpec::Cylinder { radius, height },
            ShapeWire::Box { size } => ShapeSpec::Box { size },
            ShapeWire::Capsule { radius, length } => ShapeSpec::Capsule { radius, length },
            ShapeWire::Mesh {
                vertices,
                triangles,
            } => ShapeSpec::Mesh {
                vertices,
                triangles,
            },
        }
    }
}

/// A horizontal-or-not plane the object rests on: points `x` with `normal · x = offset` (world).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SupportPlane {
    /// Unit normal pointing to the free half-space.
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub normal: [f64; 3],
    /// Plane offset along the normal.
    pub offset: f64,
    /// Coulomb friction coefficient of the surface against the object and the links (> 0; a
    /// physics check assumes 0.5, a laminate table, when absent). The geometry ignores it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(exclusive_minimum = 0, maximum = 5)]
    pub friction: Option<f64>,
}

impl SupportPlane {
    /// The horizontal plane `z = height` (normal `+z`).
    pub fn horizontal(height: f64) -> Self {
        SupportPlane {
            normal: [0.0, 0.0, 1.0],
            offset: height,
            friction: None,
        }
    }

    /// Signed height of a world point above the plane.
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        Vector3::from(self.normal).dot(&p.coords) - self.offset
    }
}

/// A validated shape: the parry shape, where it sits in the spec's frame, and a bound on its size.
#[derive(Clone)]
pub struct BuiltShape {
    pub shape: SharedShape,
    /// Pose of the parry shape in the spec's frame (a fixed rotation for `z`-axis primitives).
    pub local_fix: Isometry3<f64>,
    /// Radius of a ball about the spec frame's origin that contains the shape.
    pub bounding_radius: f64,
}

impl std::fmt::Debug for BuiltShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BuiltShape")
            .field("shape", &self.shape.shape_type())
            .field("bounding_radius", &self.bounding_radius)
            .finish()
    }
}

pub(crate) fn positive(field: &str, v: f64) -> Result<(), GeometryError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(GeometryError::InvalidDimension {
            field: field.to_string(),
            value: v,
        })
    }
}

/// Validate a shape spec and build its parry shape; dimension fields are named
/// `{prefix}.radius`, `{prefix}.size[1]`, ... in errors. A mesh is first moved so that its volume
/// centroid is the origin (for objects the origin is `C_G`, eq. 20; obstacles follow the same
/// convention so one spec means one thing).
pub fn build_shape(spec: &mut ShapeSpec, prefix: &str) -> Result<BuiltShape, GeometryError> {
    let y_to_z = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
    let field = |name: &str| format!("{prefix}.{name}");
    let (shape, local_fix, bounding_radius) = match spec {
        ShapeSpec::Sphere { radius } => {
            positive(&field("radius"), *radius)?;
            (
                SharedShape::new(Ball::new(*radius)),
                Isometry3::identity(),
                *radius,
            )
        }
        ShapeSpec::Cylinder { radius, height } => {
            positive(&field("radius"), *radius)?;
            positive(&field("height"), *height)?;
            let r = (radius.powi(2) + (0.5 * *height).powi(2)).sqrt();
            (
                SharedShape::new(Cylinder::new(0.5 * *height, *radius)),
                Isometry3::from_parts(Translation3::identity(), y_to_z),
                r,
            )
        }
        ShapeSpec::Box { size } => {
            for (i, s) in size.iter().enumerate() {
                positive(&field(&format!("size[{i}]")), *s)?;
            }
            let he = Vector3::new(size[0], size[1], size[2]) * 0.5;
            (
                SharedShape::new(Cuboid::new(he)),
                Isometry3::identity(),
                he.norm(),
            )
        }
        ShapeSpec::Capsule { radius, length } => {
            positive(&field("radius"), *radius)?;
            positive(&field("length"), *length)?;
            (
                SharedShape::new(Capsule::new_y(0.5 * *length, *radius)),
                Isometry3::from_parts(Translation3::identity(), y_to_z),
                0.5 * *length + *radius,
            )
        }
        ShapeSpec::Mesh {
            vertices,
            triangles,
        } => {
            let (centroid, r) = check_mesh(vertices, triangles)?;
            for v in vertices.iter_mut() {
                for (x, c) in v.iter_mut().zip(centroid) {
                    *x -= c;
                }
            }
            let pts: Vec<Point3<f64>> = vertices.iter().map(|v| Point3::from(*v)).collect();
            let mesh = TriMesh::with_flags(pts, triangles.clone(), TriMeshFlags::ORIENTED)
                .map_err(|e| GeometryError::MalformedMesh {
                    reason: format!("{e:?}"),
                })?;
            (SharedShape::new(mesh), Isometry3::identity(), r)
        }
    };
    Ok(BuiltShape {
        shape,
        local_fix,
        bounding_radius,
    })
}

/// Check a triangle soup is a closed 2-manifold with consistent orientation.
/// Returns its volume centroid and its bounding radius about that centroid.
fn check_mesh(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
) -> Result<([f64; 3], f64), GeometryError> {
    if triangles.is_empty() || vertices.len() < 4 {
        return Err(GeometryError::MalformedMesh {
            reason: format!(
                "a closed mesh needs at least 4 vertices and 4 triangles, got {} and {}",
                vertices.len(),
                triangles.len()
            ),
        });
    }
    if triangles.len() > MAX_MESH_TRIANGLES {
        return Err(GeometryError::MeshTooLarge {
            triangles: triangles.len(),
            limit: MAX_MESH_TRIANGLES,
        });
    }
    for (i, v) in vertices.iter().enumerate() {
        if v.iter().any(|x| !x.is_finite()) {
            return Err(GeometryError::MalformedMesh {
                reason: format!("vertex {i} is not finite"),
            });
        }
    }
    let nv = vertices.len() as u32;
    // Each directed edge must occur exactly once and its reverse exactly once: closed,
    // edge-manifold and consistently oriented.
    let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(triangles.len() * 3);
    let mut volume6 = 0.0;
    let mut centroid = Vector3::zeros();
    for (t, tri) in triangles.iter().enumerate() {
        if tri.iter().any(|&i| i >= nv) {
            return Err(GeometryError::MalformedMesh {
                reason: format!("triangle {t} references a vertex beyond {}", nv - 1),
            });
        }
        let [a, b, c] = tri.map(|i| Vector3::from(vertices[i as usize]));
        if (b - a).cross(&(c - a)).norm() < 1e-18 {
            return Err(GeometryError::MalformedMesh {
                reason: format!("triangle {t} is degenerate"),
            });
        }
        for k in 0..3 {
            let e = (tri[k], tri[(k + 1) % 3]);
            let count = edges.entry(e).or_insert(0);
            *count += 1;
            if *count > 1 {
                return Err(GeometryError::NonManifoldMesh {
                    reason: format!(
                        "edge ({}, {}) is used twice in the same direction (triangle {t}): \
                         non-manifold or inconsistently oriented",
                        e.0, e.1
                    ),
                });
            }
        }
        // Signed tetrahedron volumes about the origin give the volume centroid.
        let v6 = a.dot(&b.cross(&c));
        volume6 += v6;
        centroid += (a + b + c) * v6;
    }
    for &(i, j) in edges.keys() {
        if !edges.contains_key(&(j, i)) {
            return Err(GeometryError::NonManifoldMesh {
                reason: format!("edge ({i}, {j}) has no opposite edge: the mesh is not closed"),
            });
        }
    }
    if volume6 <= 1e-15 {
        return Err(GeometryError::NonManifoldMesh {
            reason: format!(
                "enclosed volume is {:.3e} m³: triangles must be counter-clockwise seen from outside",
                volume6 / 6.0
            ),
        });
    }
    let centroid = centroid / (4.0 * volume6);
    let radius = vertices
        .iter()
        .map(|v| (Vector3::from(*v) - centroid).norm())
        .fold(0.0, f64::max);
    Ok((centroid.into(), radius))
}

/// Parse a Wavefront OBJ text (`v` and `f` records; polygons fan-triangulated; `v/vt/vn`
/// and negative indices accepted; everything else ignored).
pub fn parse_obj(text: &str) -> Result<ShapeSpec, GeometryError> {
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut v = [0.0; 3];
                for x in v.iter_mut() {
                    *x = it
                        .next()
                        .and_then(|s| s.parse::<f64>().ok())
                        .ok_or_else(|| GeometryError::MalformedMesh {
                            reason: format!("OBJ line {}: bad vertex", ln + 1),
                        })?;
                }
                vertices.push(v);
            }
            Some("f") => {
                let mut idx = Vec::with_capacity(4);
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| GeometryError::MalformedMesh {
                        reason: format!("OBJ line {}: bad face index '{tok}'", ln + 1),
                    })?;
                    let n = vertices.len() as i64;
                    let k = if i > 0 { i - 1 } else { n + i };
                    if i == 0 || k < 0 || k >= n {
                        return Err(GeometryError::MalformedMesh {
                            reason: format!("OBJ line {}: face index {i} out of range", ln + 1),
                        });
                    }
                    idx.push(k as u32);
                }
                if idx.len() < 3 {
                    return Err(GeometryError::MalformedMesh {
                        reason: format!("OBJ line {}: face with fewer than 3 vertices", ln + 1),
                    });
                }
                for k in 1..idx.len() - 1 {
                    triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
                if triangles.len() > MAX_MESH_TRIANGLES {
                    return Err(GeometryError::MeshTooLarge {
                        triangles: triangles.len(),
                        limit: MAX_MESH_TRIANGLES,
                    });
                }
            }
            _ => {}
        }
    }
    Ok(ShapeSpec::Mesh {
        vertices,
        triangles,
    })
}

/// Parse an STL file (binary or ASCII). Coincident vertices are welded (STL stores every
/// triangle's corners separately) so that manifoldness can be checked.
pub fn parse_stl(bytes: &[u8]) -> Result<ShapeSpec, GeometryError> {
    let mut corners: Vec<[f64; 3]> = Vec::new();
    let is_ascii = bytes.starts_with(b"solid")
        && std::str::from_utf8(bytes)
            .is_ok_and(|s| s.contains("facet") || s.trim_end().ends_with("endsolid"));
    if is_ascii {
        let text = std::str::from_utf8(bytes).expect("checked above");
        for (ln, line) in text.lines().enumerate() {
            let mut it = line.split_whitespace();
            if it.next() == Some("vertex") {
                let mut v = [0.0; 3];
                for x in v.iter_mut() {
                    *x = it.next().and_then(|s| s.parse().ok()).ok_or_else(|| {
                        GeometryError::MalformedMesh {
                            reason: format!("STL line {}: bad vertex", ln + 1),
                        }
                    })?;
                }
                corners.push(v);
            }
        }
        if !corners.len().is_multiple_of(3) {
            return Err(GeometryError::MalformedMesh {
                reason: "STL vertex count is not a multiple of 3".into(),
            });
        }
    } else {
        if bytes.len() < 84 {
            return Err(GeometryError::MalformedMesh {
                reason: format!(
                    "binary STL shorter than its 84-byte header ({} bytes)",
                    bytes.len()
                ),
            });
        }
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        if n > MAX_MESH_TRIANGLES {
            return Err(GeometryError::MeshTooLarge {
                triangles: n,
                limit: MAX_MESH_TRIANGLES,
            });
        }
        if bytes.len() != 84 + 50 * n {
            return Err(GeometryError::MalformedMesh {
                reason: format!(
                    "binary STL declares {n} triangles ({} bytes) but has {} bytes",
                    84 + 50 * n,
                    bytes.len()
                ),
            });
        }
        for t in 0..n {
            let base = 84 + 50 * t + 12;
            for c in 0..3 {
                let mut v = [0.0; 3];
                for (k, x) in v.iter_mut().enumerate() {
                    let o = base + 12 * c + 4 * k;
                    *x = f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]])
                        as f64;
                }
                corners.push(v);
            }
        }
    }
    if corners.len() / 3 > MAX_MESH_TRIANGLES {
        return Err(GeometryError::MeshTooLarge {
            triangles: corners.len() / 3,
            limit: MAX_MESH_TRIANGLES,
        });
    }
    let mut index: HashMap<[u64; 3], u32> = HashMap::new();
    let mut vertices = Vec::new();
    let mut triangles = Vec::with_capacity(corners.len() / 3);
    for tri in corners.chunks_exact(3) {
        let mut t = [0u32; 3];
        for (k, v) in tri.iter().enumerate() {
            let key = v.map(f64::to_bits);
            t[k] = *index.entry(key).or_insert_with(|| {
                vertices.push(*v);
                (vertices.len() - 1) as u32
            });
        }
        triangles.push(t);
    }
    Ok(ShapeSpec::Mesh {
        vertices,
        triangles,
    })
}
