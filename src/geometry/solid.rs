//! The exact signed-distance kernel between two posed shapes, and between a shape and a plane.
//!
//! Every shape is analysed once into a [`Solid`]: a *core* (a point, a segment, a convex
//! support-mapped shape or a triangle mesh) swept by a ball of some radius (balls and capsules
//! are a point and a segment swept by their radius). For convex sets the signed distance of
//! swept shapes is the signed distance of their cores minus both radii, on both sides of zero
//! (the Minkowski sum with a ball adds its radius to every support value), so ball and capsule
//! pairs are closed forms and only genuinely polyhedral or cylindrical pairs go through GJK/EPA.
//!
//! Sign and units: metres; positive = separation distance, negative = penetration depth (the
//! length of the shortest translation that separates two convex shapes). Witness points are
//! world points on each shape's surface; `normal` is the unit direction from the first shape
//! towards the second (moving the second shape along it increases the distance).
//!
//! Meshes: the sign is exact for a closed mesh (a shape wholly inside is found by a containment
//! test of one of its points), positive values are exact distances, and a negative value is a
//! lower bound on the depth (the deepest parry contact over the mesh triangles, or the distance
//! to the surface of a shape wholly inside). A closed mesh that is convex is turned into a
//! convex polyhedron when the solid is built, so its depths are exact too. Mesh queries go
//! through parry's composite-shape traversal, which allocates; primitives do not.

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use parry3d_f64::query::{self, ClosestPoints, epa::EPA, gjk};
use parry3d_f64::shape::{ConvexPolyhedron, Shape, SharedShape, SupportMap};

/// What a shape is, for dispatch (resolved once, so the hot path does no downcasting).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Core {
    /// A ball: its centre, swept by the radius.
    Point,
    /// A capsule: its segment (endpoints in the shape frame), swept by the radius.
    Segment { a: Point3<f64>, b: Point3<f64> },
    /// A convex support-mapped shape (cuboid, cylinder, cone, convex polyhedron, ...).
    Convex,
    /// A triangle mesh (possibly non-convex).
    Mesh,
}

/// A shape analysed for exact queries: the parry shape, its core and sweep radius, and a
/// bounding sphere in the shape frame (the broad phase).
#[derive(Clone)]
pub struct Solid {
    shape: SharedShape,
    pub(crate) core: Core,
    /// Sweep radius of the core (balls, capsules); 0 otherwise.
    pub(crate) radius: f64,
    /// Bounding sphere in the shape frame.
    pub(crate) center: Point3<f64>,
    pub(crate) bound: f64,
    /// A bounding capsule in the shape frame (the broad phase's second test).
    pub(crate) capsule: BoundingCapsule,
}

impl std::fmt::Debug for Solid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Solid")
            .field("shape", &self.shape.shape_type())
            .field("core", &self.core)
            .field("radius", &self.radius)
            .field("bound", &self.bound)
            .finish()
    }
}

/// Volume of a closed, consistently oriented triangle mesh (signed tetrahedra about the origin).
fn mesh_volume(points: &[Point3<f64>], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| points[i as usize].coords);
            a.dot(&b.cross(&c))
        })
        .sum::<f64>()
        / 6.0
}

impl Solid {
    /// Analyse a parry shape. A triangle mesh whose volume equals that of its convex hull (to
    /// 1e-9 relative) is convex and is replaced by the hull, whose depths are exact.
    pub fn new(shape: SharedShape) -> Solid {
        let mut shape = shape;
        if let Some(mesh) = shape.as_trimesh() {
            let v = mesh_volume(mesh.vertices(), mesh.indices());
            if v > 0.0
                && let Some(hull) = ConvexPolyhedron::from_convex_hull(mesh.vertices())
            {
                let hv = hull.mass_properties(1.0).mass();
                if (hv - v).abs() <= 1e-9 * hv.max(v) {
                    shape = SharedShape::new(hull);
                }
            }
        }
        let (core, radius) = if let Some(b) = shape.as_ball() {
            (Core::Point, b.radius)
        } else if let Some(c) = shape.as_capsule() {
            (
                Core::Segment {
                    a: c.segment.a,
                    b: c.segment.b,
                },
                c.radius,
            )
        } else if shape.as_trimesh().is_some() {
            (Core::Mesh, 0.0)
        } else if shape.as_support_map().is_some() {
            (Core::Convex, 0.0)
        } else {
            // Compounds, heightfields and the like go through parry's generic queries.
            (Core::Mesh, 0.0)
        };
        let bs = shape.compute_local_bounding_sphere();
        Solid {
            core,
            radius,
            center: *bs.center(),
            bound: bs.radius(),
            capsule: BoundingCapsule::of(&shape),
            shape,
        }
    }

    /// The parry shape (a convex mesh already replaced by its hull).
    pub fn shape(&self) -> &SharedShape {
        &self.shape
    }

    /// Bounding sphere in the shape frame: centre and radius.
    pub fn bounding_sphere(&self) -> (Point3<f64>, f64) {
        (self.center, self.bound)
    }

    /// True when pairs with another such shape go through GJK/EPA (polyhedra, cylinders, cones),
    /// whose distances are good to 1.5e-7 relative and witness normals to ~1e-3 rad.
    pub fn is_gjk(&self) -> bool {
        self.core == Core::Convex
    }

    /// True when the signed distance is exact on both sides of zero (everything but non-convex
    /// meshes and other composite shapes).
    pub fn is_exact(&self) -> bool {
        self.core != Core::Mesh
    }
}

/// Exact signed distance between two posed shapes (see the module docs for the conventions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignedDistance {
    /// Metres: > 0 separated, < 0 penetrating (depth).
    pub distance: f64,
    /// Witness point on the first shape (world).
    pub point_a: Point3<f64>,
    /// Witness point on the second shape (world).
    pub point_b: Point3<f64>,
    /// Unit direction from the first shape towards the second (world).
    pub normal: Vector3<f64>,
}

/// Reusable buffers of the GJK/EPA queries (EPA keeps its polytope between calls).
pub struct QueryScratch {
    simplex: gjk::VoronoiSimplex,
    epa: super::epa::Epa,
    /// parry's, for what [`super::epa::Epa`] leaves.
    fallback: EPA,
}

impl Default for QueryScratch {
    fn default() -> Self {
        QueryScratch {
            simplex: gjk::VoronoiSimplex::new(),
            epa: super::epa::Epa::default(),
            fallback: EPA::new(),
        }
    }
}

impl std::fmt::Debug for QueryScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("QueryScratch")
    }
}

fn any_perpendicular(v: &Vector3<f64>) -> Vector3<f64> {
    let a = if v.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    v.cross(&a).try_normalize(1e-300).unwrap_or_else(Vector3::z)
}

/// Closest points of segments `[p1, q1]` and `[p2, q2]` (Ericson, Real-Time Collision
/// Detection §5.1.9). Hand-rolled: parry's version returns only locations through a dispatcher
/// enum, and this one is a dozen lines that the closed-form tests check.
fn closest_segment_segment(
    p1: &Point3<f64>,
    q1: &Point3<f64>,
    p2: &Point3<f64>,
    q2: &Point3<f64>,
) -> (Point3<f64>, Point3<f64>) {
    let d1 = q1 - p1;
    let d2 = q2 - p2;
    let r = p1 - p2;
    let a = d1.norm_squared();
    let e = d2.norm_squared();
    let f = d2.dot(&r);
    let eps = 1e-30;
    let (s, t);
    if a <= eps && e <= eps {
        return (*p1, *p2);
    }
    if a <= eps {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(&r);
        if e <= eps {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let mut s0 = if denom > eps * a * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t0 = 0.0;
                s0 = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t0 = 1.0;
                s0 = ((b - c) / a).clamp(0.0, 1.0);
            }
            s = s0;
            t = t0;
        }
    }
    (p1 + d1 * s, p2 + d2 * t)
}

/// A capsule containing a shape, in the shape's frame: a segment and a radius. The broad
/// phase's second test after the bounding sphere: for a long link the sphere reaches half its
/// length sideways, the capsule only its thickness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BoundingCapsule {
    pub a: Point3<f64>,
    pub b: Point3<f64>,
    pub radius: f64,
}

impl BoundingCapsule {
    /// The shape's own for balls, capsules and cylinders; otherwise around the shape's points (a
    /// convex polyhedron's or a mesh's vertices, else the corners of its local AABB, which
    /// contains it): the segment along the longest side of their box, the radius their largest
    /// distance from its line. Every radius a nanometre larger: a bound whatever the rounding.
    fn of(shape: &SharedShape) -> Self {
        let mut c = Self::fitted(shape);
        c.radius += 1e-9;
        c
    }

    fn fitted(shape: &SharedShape) -> Self {
        if let Some(b) = shape.as_ball() {
            let o = Point3::origin();
            return BoundingCapsule {
                a: o,
                b: o,
                radius: b.radius,
            };
        }
        if let Some(c) = shape.as_capsule() {
            return BoundingCapsule {
                a: c.segment.a,
                b: c.segment.b,
                radius: c.radius,
            };
        }
        if let Some(c) = shape.as_cylinder() {
            // parry's cylinders stand on their local y axis
            let h = Vector3::y() * c.half_height;
            return BoundingCapsule {
                a: Point3::from(-h),
                b: Point3::from(h),
                radius: c.radius,
            };
        }
        let points: Vec<Point3<f64>> = if let Some(p) = shape.as_convex_polyhedron() {
            p.points().to_vec()
        } else if let Some(m) = shape.as_trimesh() {
            m.vertices().to_vec()
        } else {
            let aabb = shape.compute_local_aabb();
            let (lo, hi) = (aabb.mins, aabb.maxs);
            (0..8)
                .map(|k| {
                    Point3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    )
                })
                .collect()
        };
        Self::around(&points)
    }

    fn around(points: &[Point3<f64>]) -> Self {
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for p in points {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let axis = (hi - lo).imax();
        let center = Point3::from((lo + hi) / 2.0);
        let (mut t_lo, mut t_hi, mut r2) = (0.0f64, 0.0f64, 0.0f64);
        for p in points {
            let v = p - center;
            let t = v[axis];
            t_lo = t_lo.min(t);
            t_hi = t_hi.max(t);
            r2 = r2.max(v.norm_squared() - t * t);
        }
        let mut e = Vector3::zeros();
        e[axis] = 1.0;
        BoundingCapsule {
            a: center + e * t_lo,
            b: center + e * t_hi,
            radius: r2.max(0.0).sqrt(),
        }
    }

    /// A lower bound on the signed distance between the shapes the two capsules contain, posed
    /// at `pa` and `pb`.
    pub fn gap(&self, pa: &Isometry3<f64>, other: &BoundingCapsule, pb: &Isometry3<f64>) -> f64 {
        let (a0, a1) = (pa * self.a, pa * self.b);
        let (b0, b1) = (pb * other.a, pb * other.b);
        let (x, y) = closest_segment_segment(&a0, &a1, &b0, &b1);
        (y - x).norm() - self.radius - other.radius
    }

    /// A lower bound on the height of the shape posed at `pose` above `plane`.
    pub fn height(&self, pose: &Isometry3<f64>, plane: &HalfSpace) -> f64 {
        plane
            .height(&(pose * self.a))
            .min(plane.height(&(pose * self.b)))
            - self.radius
    }
}

/// A core-to-core result before the sweep radii are applied.
struct CoreDistance {
    distance: f64,
    a: Point3<f64>,
    b: Point3<f64>,
    normal: Vector3<f64>,
}

impl CoreDistance {
    /// From two closest points of disjoint (or touching) cores.
    fn from_points(a: Point3<f64>, b: Point3<f64>, fallback: &Vector3<f64>) -> Self {
        let d = b - a;
        let n = d.norm();
        let normal = if n > 1e-300 {
            d / n
        } else {
            fallback
                .try_normalize(1e-300)
                .unwrap_or_else(|| any_perpendicular(&Vector3::z()))
        };
        CoreDistance {
            distance: n,
            a,
            b,
            normal,
        }
    }
}

/// World endpoints of a segment core, or the point of a point core.
fn core_points(core: &Core, pose: &Isometry3<f64>) -> (Point3<f64>, Point3<f64>) {
    match core {
        Core::Segment { a, b } => (pose * a, pose * b),
        _ => {
            let p = Point3::from(pose.translation.vector);
            (p, p)
        }
    }
}

/// Signed distance from a world point to a convex support-mapped shape (exact projection).
fn point_convex(p: &Point3<f64>, shape: &dyn Shape, pose: &Isometry3<f64>) -> (f64, Point3<f64>) {
    let proj = shape.project_point(pose, p, false);
    let d = (p - proj.point).norm();
    (if proj.is_inside { -d } else { d }, proj.point)
}

/// GJK (EPA when the cores intersect) between two support maps posed in the world.
fn gjk_epa(
    g1: &dyn SupportMap,
    pose1: &Isometry3<f64>,
    g2: &dyn SupportMap,
    pose2: &Isometry3<f64>,
    scratch: &mut QueryScratch,
) -> CoreDistance {
    let pos12 = pose1.inv_mul(pose2);
    let dir = Unit::try_new(pos12.translation.vector, 1e-12).unwrap_or(Vector3::x_axis());
    scratch
        .simplex
        .reset(gjk::CSOPoint::from_shapes(&pos12, g1, g2, &dir));
    let res = gjk::closest_points(&pos12, g1, g2, f64::MAX, true, &mut scratch.simplex);
    let (p1, p2, n) = match res {
        gjk::GJKResult::ClosestPoints(p1, p2, n) => (p1, p2, n),
        gjk::GJKResult::Intersection => {
            let found = scratch
                .epa
                .closest_points(&pos12, g1, g2, &scratch.simplex, super::epa::TOLERANCE)
                .or_else(|| {
                    scratch
                        .fallback
                        .closest_points(&pos12, g1, g2, &scratch.simplex)
                });
            match found {
                Some(r) => r,
                // EPA fails only on degenerate (flat) overlaps: call it touching.
                None => {
                    let p = pose1 * Point3::from(pos12.translation.vector * 0.5);
                    return CoreDistance {
                        distance: 0.0,
                        a: p,
                        b: p,
                        normal: (pose2.translation.vector - pose1.translation.vector)
                            .try_normalize(1e-300)
                            .unwrap_or_else(Vector3::z),
                    };
                }
            }
        }
        gjk::GJKResult::NoIntersection(n) | gjk::GJKResult::Proximity(n) => {
            // Not returned with max_dist = MAX and exact_dist; keep a sane answer.
            let p = pose1 * Point3::origin();
            return CoreDistance {
                distance: f64::MAX,
                a: p,
                b: p,
                normal: pose1 * n.into_inner(),
            };
        }
    };
    let distance = (p2 - p1).dot(&n);
    CoreDistance {
        distance,
        a: pose1 * p1,
        b: pose1 * p2,
        normal: pose1 * n.into_inner(),
    }
}

/// Any non-convex pair: parry's generic queries, plus containment tests so that a shape wholly
/// inside a closed mesh is negative.
fn generic(a: &Solid, pa: &Isometry3<f64>, b: &Solid, pb: &Isometry3<f64>) -> CoreDistance {
    let (sa, sb) = (a.shape.as_ref(), b.shape.as_ref());
    let fallback = pb.translation.vector - pa.translation.vector;
    match query::closest_points(pa, sa, pb, sb, f64::MAX) {
        Ok(ClosestPoints::WithinMargin(p1, p2)) => {
            let mut r = CoreDistance::from_points(p1, p2, &fallback);
            // Wholly inside a closed mesh: no surface crossing, but a point inside.
            let inside = |m: &Solid, pm: &Isometry3<f64>, o: &Solid, po: &Isometry3<f64>| {
                m.core == Core::Mesh
                    && m.shape
                        .as_trimesh()
                        .is_some_and(|t| t.pseudo_normals().is_some())
                    && m.shape.contains_point(pm, &(po * o.center))
            };
            if r.distance > 0.0 && (inside(b, pb, a, pa) || inside(a, pa, b, pb)) {
                r.distance = -r.distance;
                r.normal = -r.normal;
            }
            r
        }
        Ok(ClosestPoints::Intersecting) | Ok(ClosestPoints::Disjoint) | Err(_) => {
            match query::contact(pa, sa, pb, sb, 0.0) {
                Ok(Some(c)) => CoreDistance {
                    distance: c.dist.min(0.0),
                    a: c.point1,
                    b: c.point2,
                    normal: c.normal1.into_inner(),
                },
                _ => {
                    let p = Point3::from((pa.translation.vector + pb.translation.vector) * 0.5);
                    CoreDistance {
                        distance: 0.0,
                        a: p,
                        b: p,
                        normal: fallback.try_normalize(1e-300).unwrap_or_else(Vector3::z),
                    }
                }
            }
        }
    }
}

/// Exact signed distance between `a` at `pa` and `b` at `pb` (world poses of the shapes).
pub fn signed_distance(
    a: &Solid,
    pa: &Isometry3<f64>,
    b: &Solid,
    pb: &Isometry3<f64>,
    scratch: &mut QueryScratch,
) -> SignedDistance {
    let fallback = pb.translation.vector - pa.translation.vector;
    let core = match (&a.core, &b.core) {
        // Whole shapes, radii included.
        (Core::Mesh, _) | (_, Core::Mesh) => {
            let c = generic(a, pa, b, pb);
            return SignedDistance {
                distance: c.distance,
                point_a: c.a,
                point_b: c.b,
                normal: c.normal,
            };
        }
        (Core::Point | Core::Segment { .. }, Core::Point | Core::Segment { .. }) => {
            let (a0, a1) = core_points(&a.core, pa);
            let (b0, b1) = core_points(&b.core, pb);
            let (x, y) = closest_segment_segment(&a0, &a1, &b0, &b1);
            let fb = if (a1 - a0).norm_squared() > 0.0 {
                any_perpendicular(&(a1 - a0))
            } else {
                fallback
            };
            CoreDistance::from_points(x, y, &fb)
        }
        (Core::Point, Core::Convex) => {
            let p = Point3::from(pa.translation.vector);
            let (d, on) = point_convex(&p, b.shape.as_ref(), pb);
            let n = if d < 0.0 { p - on } else { on - p };
            let normal = n
                .try_normalize(1e-300)
                .unwrap_or_else(|| fallback.normalize());
            CoreDistance {
                distance: d,
                a: p,
                b: on,
                normal,
            }
        }
        (Core::Convex, Core::Point) => {
            let p = Point3::from(pb.translation.vector);
            let (d, on) = point_convex(&p, a.shape.as_ref(), pa);
            let n = if d < 0.0 { on - p } else { p - on };
            let normal = n
                .try_normalize(1e-300)
                .unwrap_or_else(|| fallback.normalize());
            CoreDistance {
                distance: d,
                a: on,
                b: p,
                normal,
            }
        }
        (Core::Segment { a: s0, b: s1 }, Core::Convex) => {
            let seg = parry3d_f64::shape::Segment::new(*s0, *s1);
            let g2 = b
                .shape
                .as_support_map()
                .expect("convex core is a support map");
            gjk_epa(&seg, pa, g2, pb, scratch)
        }
        (Core::Convex, Core::Segment { a: s0, b: s1 }) => {
            let seg = parry3d_f64::shape::Segment::new(*s0, *s1);
            let g1 = a
                .shape
                .as_support_map()
                .expect("convex core is a support map");
            gjk_epa(g1, pa, &seg, pb, scratch)
        }
        (Core::Convex, Core::Convex) => {
            let g1 = a
                .shape
                .as_support_map()
                .expect("convex core is a support map");
            let g2 = b
                .shape
                .as_support_map()
                .expect("convex core is a support map");
            gjk_epa(g1, pa, g2, pb, scratch)
        }
    };
    let (ra, rb) = (a.radius, b.radius);
    SignedDistance {
        distance: core.distance - ra - rb,
        point_a: core.a + core.normal * ra,
        point_b: core.b - core.normal * rb,
        normal: core.normal,
    }
}

/// A plane `normal · x = offset` whose lower side (`normal · x < offset`) is solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfSpace {
    /// Unit normal pointing into the free side.
    pub normal: Unit<Vector3<f64>>,
    pub offset: f64,
}

impl HalfSpace {
    /// Signed height of a world point above the plane.
    #[inline]
    pub fn height(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }
}

/// Exact signed distance from a posed shape to the solid half-space: the height of the shape's
/// lowest point (its support point against the normal; the lowest vertex of a mesh). Witness
/// `point_a` on the shape, `point_b` its projection on the plane, `normal` = −plane normal
/// (from the shape towards the solid).
pub fn half_space_distance(s: &Solid, pose: &Isometry3<f64>, plane: &HalfSpace) -> SignedDistance {
    let n = plane.normal.into_inner();
    let lowest = match &s.core {
        Core::Point => Point3::from(pose.translation.vector),
        Core::Segment { a, b } => {
            let (a, b) = (pose * a, pose * b);
            if plane.height(&a) <= plane.height(&b) {
                a
            } else {
                b
            }
        }
        Core::Convex => s
            .shape
            .as_support_map()
            .expect("convex core is a support map")
            .support_point(pose, &-n),
        Core::Mesh => match s.shape.as_trimesh() {
            Some(m) => m
                .vertices()
                .iter()
                .map(|v| pose * v)
                .min_by(|x, y| plane.height(x).total_cmp(&plane.height(y)))
                .unwrap_or_else(|| Point3::from(pose.translation.vector)),
            None => {
                // Other composite shapes: the lowest corner of the world bounding box bounds it.
                let aabb = s.shape.compute_aabb(pose);
                let (lo, hi) = (aabb.mins, aabb.maxs);
                Point3::new(
                    if n.x >= 0.0 { lo.x } else { hi.x },
                    if n.y >= 0.0 { lo.y } else { hi.y },
                    if n.z >= 0.0 { lo.z } else { hi.z },
                )
            }
        },
    };
    let point_a = lowest - n * s.radius;
    let h = plane.height(&point_a);
    SignedDistance {
        distance: h,
        point_a,
        point_b: point_a - n * h,
        normal: -n,
    }
}
