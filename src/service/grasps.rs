//! Grasps: task-specific arm configurations and robust grasps of an object (paper eq. 10-29),
//! one at a time, in batches (a job), or offline for the CLI; and the objects they grasp.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{Context, Error, Invalid};
use crate::grasp::objects::{
    MAX_OBJECT_EXTENT, ObjectSpec, ShapeSpec, SupportPlane, parse_obj, parse_stl,
};
use crate::grasp::{
    DEFAULT_MAX_STARTS, Goal, GoalRegion, GraspError, GraspRequest, GraspResult, HandArm, Object,
    QualityMeasure, TaskDirection, Transmission, Weights, plan_grasp,
};
use crate::jobs::{JobError, JobOutput, JobRecord, ResultRef};
use crate::kinematics::System;
use crate::store::grasps as repo;

/// Most grasps in one batch request.
pub const MAX_BATCH: usize = 200;

// ---------------------------------------------------------------------------------------------
// Inputs (the request bodies of `/v1/objects` and `/v1/grasps`, and the CLI's request files)

/// An uploaded mesh: Wavefront OBJ text, or STL (ASCII text, or binary as base64).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MeshIn {
    /// `obj` or `stl`.
    pub format: String,
    /// File contents: text, or base64 when `encoding` is `base64`.
    pub data: String,
    /// `text` (default) or `base64`.
    #[serde(default)]
    pub encoding: Option<String>,
}

/// An object description. Give `shape` (a primitive or explicit mesh) or `mesh` (a file).
/// Example: a 5 cm cube standing on the robot's table (no `support`: the table, `z = 0`).
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"name": "cube", "shape": {"type": "box", "size": [0.05, 0.05, 0.05]},
                          "position": [0.5, 0.0, 0.025]}))]
pub struct ObjectIn {
    /// A name with at least one non-blank character.
    #[schema(min_length = 1, pattern = r"\S")]
    pub name: String,
    pub shape: Option<ShapeSpec>,
    pub mesh: Option<MeshIn>,
    /// Centroid position (m, robot base frame).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub position: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]` (default identity).
    #[schema(min_items = 4, max_items = 4)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub orientation: Option<[f64; 4]>,
    /// Support plane the object rests on. Default: the table the robot stands at (the plane
    /// `z = 0`, normal `+z`) when the object is on or above it (its lowest point at most 2 mm
    /// below); none for an object reaching further below (held or mounted elsewhere).
    pub support: Option<SupportPlane>,
    /// Mass, kg (> 0, at most 50): needed only to verify a grasp in physics (a plan's
    /// `verify`).
    #[schema(exclusive_minimum = 0, maximum = 50)]
    pub mass: Option<f64>,
    /// Coulomb friction coefficient against the hand's pads (> 0, at most 5): needed, like
    /// `mass`, only for a physics check.
    #[schema(exclusive_minimum = 0, maximum = 5)]
    pub friction: Option<f64>,
}

/// A task direction (world frame; normalised by the service).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TaskDirectionIn {
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub direction: [f64; 3],
    pub kind: Transmission,
    pub goal: Goal,
}

/// The object of a grasp request: a stored object's id, or an inline description.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GraspIn {
    /// Robot (arm-hand system) id: a bundled system such as `wam_ihy`, or the id of one registered
    /// with `POST /v1/robots`.
    #[schema(min_length = 1)]
    pub robot: String,
    /// Id of a stored object, or the name of a seeded one (`ball`, `bottle`, `kitchen_timer`,
    /// `pencil`, `sunglasses`); give this or `object`.
    pub object_id: Option<String>,
    /// Inline object (give this or `object_id`).
    pub object: Option<ObjectIn>,
    /// Task directions for TC (arm) and GC (hand).
    #[serde(default)]
    pub task_directions: Vec<TaskDirectionIn>,
    /// Grasp quality measure (default `centroid_distance`).
    pub quality: Option<QualityMeasure>,
    /// Weights of eq. 22 (defaults: tc 1, gc 0, q 1, d 1).
    pub weights: Option<Weights>,
    /// Starts of the multi-start search, 1 to 64 (default 4): its first round.
    #[schema(minimum = 1, maximum = 64)]
    pub starts: Option<usize>,
    /// While no start is exactly feasible (and firm), further rounds double the starts run, up
    /// to this many in all: `starts` to 64 (default 64).
    #[schema(minimum = 1, maximum = 64)]
    pub max_starts: Option<usize>,
    /// Seed of the start perturbations (default 0).
    pub seed: Option<u64>,
    /// Human elbow reference for the anthropomorphism term D (m, world).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub elbow_reference: Option<[f64; 3]>,
}

/// A batch: the same robot and task settings over many objects or placements.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GraspBatchIn {
    /// Robot id (bundled or registered), as in `POST /v1/grasps`.
    #[schema(min_length = 1)]
    pub robot: String,
    /// Each item is an object id or an inline object (e.g. the same shape at several poses),
    /// 1 to [`MAX_BATCH`] items.
    #[schema(min_items = 1, max_items = 200)]
    pub items: Vec<BatchItemIn>,
    #[serde(default)]
    pub task_directions: Vec<TaskDirectionIn>,
    pub quality: Option<QualityMeasure>,
    pub weights: Option<Weights>,
    /// Starts of the multi-start search, 1 to 64 (default 4).
    #[schema(minimum = 1, maximum = 64)]
    pub starts: Option<usize>,
    /// At most this many starts in all, as in `POST /v1/grasps`.
    #[schema(minimum = 1, maximum = 64)]
    pub max_starts: Option<usize>,
    pub seed: Option<u64>,
}

/// One batch item.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BatchItemIn {
    pub object_id: Option<String>,
    pub object: Option<ObjectIn>,
}

/// Task settings echoed with a grasp.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[schema(as = GraspSettingsDto)]
pub struct GraspSettings {
    pub task_directions: Vec<TaskDirectionIn>,
    pub quality: QualityMeasure,
    pub weights: Weights,
    pub starts: usize,
    /// Grasps stored before start rounds existed ran `starts` only.
    #[serde(default)]
    pub max_starts: usize,
    pub seed: u64,
    #[schema(min_items = 3, max_items = 3)]
    pub elbow_reference: Option<[f64; 3]>,
}

// ---------------------------------------------------------------------------------------------
// Parsing (bad input never reaches the numerics)

fn grasp_error(prefix: &str, e: GraspError) -> Error {
    let path = match &e {
        GraspError::InvalidDimension { field, .. }
        | GraspError::NonFinite { field }
        | GraspError::ZeroVector { field } => {
            format!("{prefix}.{field}")
        }
        GraspError::MalformedMesh { .. }
        | GraspError::NonManifoldMesh { .. }
        | GraspError::MeshTooLarge { .. } => {
            format!("{prefix}.mesh")
        }
        GraspError::InvalidDirection { index } => format!("$.task_directions[{index}].direction"),
        GraspError::InvalidWeight { field, .. } => format!("$.weights.{field}"),
        GraspError::UnusableQuality { .. } => "$.quality".to_owned(),
        GraspError::InvalidParameter { field, .. } => format!("$.{field}"),
    };
    Error::invalid(path, e.to_string())
}

/// The request field a mesh problem's `reason` is about, below the mesh: the triangle or vertex
/// it names (`triangles[3]`, `vertices[7]`), else the triangle list as a whole.
fn mesh_item(reason: &str) -> String {
    let index_after = |word: &str| {
        reason.match_indices(word).find_map(|(i, _)| {
            let digits: String = reason[i + word.len()..]
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            digits.parse::<usize>().ok()
        })
    };
    if let Some(t) = index_after("triangle ") {
        format!("triangles[{t}]")
    } else if let Some(v) = index_after("vertex ") {
        format!("vertices[{v}]")
    } else {
        "triangles".to_owned()
    }
}

/// An object's validation error at the field of the request it is about. `explicit_shape`:
/// the geometry came in `shape` (a primitive or an explicit mesh), not as an uploaded `mesh`
/// file; mesh problems then name the triangle or vertex in `shape`, while an uploaded file's
/// are about `mesh` (the file, whose text the message cites).
fn object_error(prefix: &str, explicit_shape: bool, e: GraspError) -> Error {
    match &e {
        GraspError::MalformedMesh { .. }
        | GraspError::NonManifoldMesh { .. }
        | GraspError::MeshTooLarge { .. }
            if !explicit_shape =>
        {
            Error::invalid(format!("{prefix}.mesh"), e.to_string())
        }
        GraspError::MalformedMesh { reason } | GraspError::NonManifoldMesh { reason } => {
            Error::invalid(
                format!("{prefix}.shape.{}", mesh_item(reason)),
                e.to_string(),
            )
        }
        GraspError::MeshTooLarge { .. } => {
            Error::invalid(format!("{prefix}.shape.triangles"), e.to_string())
        }
        // The whole object's size (`Object::new`'s extent check), not one length.
        GraspError::InvalidDimension { field, value } if field == "shape" => Error::invalid(
            format!("{prefix}.shape"),
            format!(
                "out of range: the object is {value} m across (bounding-box diagonal); \
                 the largest accepted is {MAX_OBJECT_EXTENT} m"
            ),
        ),
        _ => grasp_error(prefix, e),
    }
}

/// Refuses, at its own field, a single length or coordinate that alone makes the object larger
/// than any accepted object (e.g. a radius of 1e308, which `Object::new` would only see as an
/// infinite extent of the whole shape).
fn check_shape_ranges(prefix: &str, shape: &ShapeSpec) -> Result<(), Error> {
    // (field, value, extent the value alone gives the object)
    let mut lengths: Vec<(String, f64, f64)> = Vec::new();
    match shape {
        ShapeSpec::Sphere { radius } => lengths.push(("radius".into(), *radius, 2.0 * radius)),
        ShapeSpec::Cylinder { radius, height } => {
            lengths.push(("radius".into(), *radius, 2.0 * radius));
            lengths.push(("height".into(), *height, *height));
        }
        ShapeSpec::Box { size } => {
            for (i, s) in size.iter().enumerate() {
                lengths.push((format!("size[{i}]"), *s, *s));
            }
        }
        ShapeSpec::Capsule { radius, length } => {
            lengths.push(("radius".into(), *radius, 2.0 * radius));
            lengths.push(("length".into(), *length, *length));
        }
        ShapeSpec::Mesh { vertices, .. } => {
            // Coordinates this large overflow the mesh checks' products; no object has them.
            for (i, v) in vertices.iter().enumerate() {
                if let Some(x) = v.iter().find(|x| x.abs() > 1e6) {
                    return Err(Error::invalid(
                        format!("{prefix}.shape.vertices[{i}]"),
                        format!("out of range: coordinate {x} m (at most 1e6 m in magnitude)"),
                    ));
                }
            }
        }
    }
    for (name, value, extent) in lengths {
        if value > 0.0 && extent > MAX_OBJECT_EXTENT {
            return Err(Error::invalid(
                format!("{prefix}.shape.{name}"),
                format!(
                    "out of range: {value} m makes the object larger than the largest accepted \
                     ({MAX_OBJECT_EXTENT} m across)"
                ),
            ));
        }
    }
    Ok(())
}

fn parse_object(prefix: &str, o: &ObjectIn) -> Result<Object, Error> {
    if o.name.trim().is_empty() {
        return Err(Error::invalid(
            format!("{prefix}.name"),
            "must not be empty",
        ));
    }
    let shape = match (&o.shape, &o.mesh) {
        (Some(s), None) => s.clone(),
        (None, Some(m)) => {
            let bytes = match m.encoding.as_deref().unwrap_or("text") {
                "text" => m.data.as_bytes().to_vec(),
                "base64" => super::decode_base64(&m.data).ok_or_else(|| {
                    Error::invalid(format!("{prefix}.mesh.data"), "invalid base64")
                })?,
                other => {
                    return Err(Error::invalid(
                        format!("{prefix}.mesh.encoding"),
                        format!("unknown encoding '{other}' (text or base64)"),
                    ));
                }
            };
            match m.format.as_str() {
                "obj" => {
                    let text = std::str::from_utf8(&bytes).map_err(|_| {
                        Error::invalid(format!("{prefix}.mesh.data"), "OBJ data is not UTF-8 text")
                    })?;
                    parse_obj(text).map_err(|e| object_error(prefix, false, e))?
                }
                "stl" => parse_stl(&bytes).map_err(|e| object_error(prefix, false, e))?,
                other => {
                    return Err(Error::invalid(
                        format!("{prefix}.mesh.format"),
                        format!("unknown mesh format '{other}' (obj or stl)"),
                    ));
                }
            }
        }
        _ => {
            return Err(Error::invalid(
                format!("{prefix}.shape"),
                "give exactly one of shape and mesh",
            ));
        }
    };
    let explicit_shape = o.shape.is_some();
    if explicit_shape {
        check_shape_ranges(prefix, &shape)?;
    }
    let spec = ObjectSpec {
        name: o.name.clone(),
        shape,
        position: o.position,
        orientation: o.orientation.unwrap_or([1.0, 0.0, 0.0, 0.0]),
        support: o.support,
        mass: o.mass,
        friction: o.friction,
    };
    let object = Object::new(spec.clone()).map_err(|e| object_error(prefix, explicit_shape, e))?;
    // Without a stated support, an object standing on or above the robot's own table rests on
    // it: left unsupported, the grasp optimiser happily puts a fingertip under a cube.
    if spec.support.is_none() && object.lowest_z() >= -DEFAULT_SUPPORT_TOLERANCE_M {
        return Object::new(ObjectSpec {
            support: Some(SupportPlane::horizontal(DEFAULT_TABLE_Z_M)),
            ..spec
        })
        .map_err(|e| object_error(prefix, explicit_shape, e));
    }
    Ok(object)
}

/// The table the bundled systems stand at: the plane `z = 0` of the robot base frame.
pub const DEFAULT_TABLE_Z_M: f64 = 0.0;
/// An object reaching at most this far below that table still rests on it (rounding in a
/// lab's measured position); one reaching further is held or mounted elsewhere and gets no
/// default support.
pub const DEFAULT_SUPPORT_TOLERANCE_M: f64 = 0.002;

/// Grasp views of the systems, by robot id, with the loaded system they were built from: a view
/// is rebuilt only when [`super::robots::system`] hands out a different system (the robot's row
/// changed), since building one samples every link's collision spheres.
type ViewCache = Mutex<HashMap<String, (Arc<System>, Arc<HandArm>)>>;

fn view_cache() -> &'static ViewCache {
    static CACHE: OnceLock<ViewCache> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(HashMap::new()))
}

fn hand_arm_of(key: &str, sys: &Arc<System>) -> Result<Arc<HandArm>, Error> {
    if let Some((s, v)) = view_cache().lock().expect("cache lock").get(key)
        && Arc::ptr_eq(s, sys)
    {
        return Ok(v.clone());
    }
    let view = Arc::new(HandArm::from_system(sys).map_err(|e| grasp_error("$.robot", e))?);
    view_cache()
        .lock()
        .expect("cache lock")
        .insert(key.to_owned(), (sys.clone(), view.clone()));
    Ok(view)
}

/// A grasp request's robot: any system of the robots store (bundled or registered), resolved
/// like every other resource does; an unknown id in the body is a 422 naming `$.robot`.
pub(super) async fn robot_view(ctx: &Context, robot: &str) -> Result<Arc<HandArm>, Error> {
    let sys = super::robots::robot_field(ctx, robot, "$.robot").await?;
    let key = robot.to_owned();
    tokio::task::spawn_blocking(move || hand_arm_of(&key, &sys))
        .await
        .map_err(Error::internal)?
}

/// Resolve a bundled system by file name to its grasp view, for the offline CLI (no database);
/// blocking (file I/O + parsing).
pub fn load_system(robots: &std::path::Path, name: &str) -> Result<Arc<HandArm>, Error> {
    let valid = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|c| c.is_ascii_alphanumeric() || c == b'_' || c == b'-');
    let path = robots.join("systems").join(format!("{name}.toml"));
    if !valid || !path.is_file() {
        return Err(Error::invalid("$.robot", format!("unknown robot '{name}'")));
    }
    let sys = System::from_file(&path).map_err(|e| Error::invalid("$.robot", e.to_string()))?;
    Ok(Arc::new(
        HandArm::from_system(&sys).map_err(|e| grasp_error("$.robot", e))?,
    ))
}

#[derive(Clone)]
struct Settings {
    task: Vec<TaskDirection>,
    dto: GraspSettings,
}

fn parse_settings(
    task_directions: &[TaskDirectionIn],
    quality: Option<QualityMeasure>,
    weights: Option<Weights>,
    (starts, max_starts): (Option<usize>, Option<usize>),
    seed: Option<u64>,
    elbow_reference: Option<[f64; 3]>,
) -> Result<Settings, Error> {
    let mut errors = Vec::new();
    let mut task = Vec::new();
    for (i, t) in task_directions.iter().enumerate() {
        let d = Vector3::from(t.direction);
        let n = d.norm();
        if !n.is_finite() || n < 1e-9 {
            errors.push(Invalid::new(
                format!("$.task_directions[{i}].direction"),
                "must be a finite non-zero vector",
            ));
        } else {
            task.push(TaskDirection {
                direction: d / n,
                kind: t.kind,
                goal: t.goal,
            });
        }
    }
    let weights = weights.unwrap_or_default();
    for (name, v) in [
        ("tc", weights.tc),
        ("gc", weights.gc),
        ("q", weights.q),
        ("d", weights.d),
    ] {
        if !v.is_finite() || v < 0.0 {
            errors.push(Invalid::new(
                format!("$.weights.{name}"),
                format!("must be finite and non-negative, got {v}"),
            ));
        }
    }
    let starts = starts.unwrap_or(4);
    if !(1..=64).contains(&starts) {
        errors.push(Invalid::new(
            "$.starts",
            format!("must be between 1 and 64, got {starts}"),
        ));
    }
    let max_starts = max_starts.unwrap_or(DEFAULT_MAX_STARTS.max(starts));
    if !(starts..=64).contains(&max_starts) {
        errors.push(Invalid::new(
            "$.max_starts",
            format!("must be between starts ({starts}) and 64, got {max_starts}"),
        ));
    }
    if let Some(e) = elbow_reference
        && e.iter().any(|x| !x.is_finite())
    {
        errors.push(Invalid::new("$.elbow_reference", "must be finite"));
    }
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    Ok(Settings {
        task,
        dto: GraspSettings {
            task_directions: task_directions.to_vec(),
            quality: quality.unwrap_or(QualityMeasure::CentroidDistance),
            weights,
            starts,
            max_starts,
            seed: seed.unwrap_or(0),
            elbow_reference,
        },
    })
}

fn make_request(object: Object, s: &Settings) -> GraspRequest {
    let mut req = GraspRequest::new(object, s.task.clone(), s.dto.quality);
    req.weights = s.dto.weights;
    req.starts = s.dto.starts;
    // Stored settings from before start rounds (`max_starts` 0) mean one round.
    req.max_starts = s.dto.max_starts.max(s.dto.starts);
    req.seed = s.dto.seed;
    req.elbow_reference = s.dto.elbow_reference.map(Point3::from);
    req
}

/// Checks a task set as a grasp request's `task_directions`, its problems named under `path`
/// (e.g. `$.tasks[2]`) instead.
pub fn check_task_directions(path: &str, tasks: &[TaskDirectionIn]) -> Result<(), Error> {
    parse_settings(tasks, None, None, (None, None), None, None)
        .map(|_| ())
        .map_err(|e| match e {
            Error::Invalid(v) => Error::Invalid(
                v.into_iter()
                    .map(|i| Invalid {
                        field: i.field.replacen("$.task_directions", path, 1),
                        message: i.message,
                    })
                    .collect(),
            ),
            other => other,
        })
}

/// A stored object by id, or a seeded one by name, validated, with its id; a 422 at `path`
/// (listing the seeded names) when there is none.
pub async fn stored_object(ctx: &Context, path: &str, id: &str) -> Result<(String, Object), Error> {
    let row = match repo::get_object(&ctx.db, id).await? {
        Some(row) => row,
        None => match repo::get_seeded_object(&ctx.db, id).await? {
            Some(row) => row,
            None => {
                let names = repo::seeded_object_names(&ctx.db).await?;
                return Err(Error::invalid(
                    path,
                    format!(
                        "unknown object '{id}': give an id from GET /v1/objects or a seeded \
                         object's name ({})",
                        names.join(", ")
                    ),
                ));
            }
        },
    };
    let spec: ObjectSpec = serde_json::from_str(&row.spec).map_err(Error::internal)?;
    Ok((row.id, Object::new(spec).map_err(Error::internal)?))
}

async fn resolve_object(
    ctx: &Context,
    prefix: &str,
    id: &Option<String>,
    inline: &Option<ObjectIn>,
) -> Result<(Option<String>, Object), Error> {
    match (id, inline) {
        (Some(id), None) => {
            let (id, obj) = stored_object(ctx, &format!("{prefix}object_id"), id).await?;
            Ok((Some(id), obj))
        }
        (None, Some(o)) => Ok((None, parse_object(&format!("{prefix}object"), o)?)),
        _ => Err(Error::invalid(
            format!("{prefix}object_id"),
            "give exactly one of object_id and object",
        )),
    }
}

fn new_grasp(
    robot: &str,
    object_id: Option<String>,
    obj: &Object,
    s: &GraspSettings,
    r: &GraspResult,
) -> repo::NewGrasp {
    repo::NewGrasp {
        robot: robot.to_owned(),
        object_id,
        object: serde_json::to_string(obj.spec()).expect("serialisable"),
        request: serde_json::to_string(s).expect("serialisable"),
        result: serde_json::to_string(r).expect("serialisable"),
        feasible: r.feasible,
    }
}

/// Computes one grasp, ready to store (shared with [`super::plans`], which stores it only once
/// the rest of the plan has been checked).
///
/// With a motion model's goal `regions` (a plan's), every start begins at their centre and the
/// grasp must lie inside them ([`crate::grasp::GraspRequest::goal_regions`]).
/// A computed grasp's scene: the system and the object (with its support), for checking the
/// motion that reaches it.
#[derive(Clone)]
pub struct GraspScene {
    pub sys: Arc<HandArm>,
    /// `None`: a trajectory to a configuration, checked against its obstacles only.
    pub object: Option<Object>,
}

/// The scene of stored grasp `id`: its system and its object as it was computed (`None`: no such
/// grasp).
pub async fn stored_scene(ctx: &Context, id: &str) -> Result<Option<GraspScene>, Error> {
    let Some(row) = repo::get_grasp(&ctx.db, id).await? else {
        return Ok(None);
    };
    let spec: ObjectSpec = serde_json::from_str(&row.object).map_err(Error::internal)?;
    let object = Object::new(spec).map_err(|e| Error::internal(anyhow::anyhow!("{e}")))?;
    let sys = robot_view(ctx, &row.robot).await?;
    Ok(Some(GraspScene {
        sys,
        object: Some(object),
    }))
}

pub async fn compute(
    ctx: &Context,
    body: &GraspIn,
    regions: &[super::models::NamedGoalRegion],
) -> Result<(repo::NewGrasp, GraspResult, GraspScene), Error> {
    prepare(ctx, body).await?.compute(regions).await
}

/// A grasp request checked and resolved once: its settings, its object (with the stored id)
/// and the system. A plan searches with several seeds on one.
pub struct Prepared {
    robot: String,
    settings: Settings,
    object_id: Option<String>,
    object: Object,
    sys: Arc<HandArm>,
}

/// Checks `body` (settings, then object, then robot) and resolves its object and system.
pub async fn prepare(ctx: &Context, body: &GraspIn) -> Result<Prepared, Error> {
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        (body.starts, body.max_starts),
        body.seed,
        body.elbow_reference,
    )?;
    let (object_id, object) = resolve_object(ctx, "$.", &body.object_id, &body.object).await?;
    let sys = robot_view(ctx, &body.robot).await?;
    Ok(Prepared {
        robot: body.robot.clone(),
        settings,
        object_id,
        object,
        sys,
    })
}

impl Prepared {
    /// The object the grasp is for.
    pub fn object(&self) -> &Object {
        &self.object
    }

    /// Asks for start seed `seed` from now on.
    pub fn with_seed(&mut self, seed: u64) {
        self.settings.dto.seed = seed;
    }

    /// Computes the grasp inside the model's goal `regions` (none: anywhere).
    pub async fn compute(
        &self,
        regions: &[super::models::NamedGoalRegion],
    ) -> Result<(repo::NewGrasp, GraspResult, GraspScene), Error> {
        let (robot, settings, object, sys) = (
            &self.robot,
            self.settings.clone(),
            self.object.clone(),
            self.sys.clone(),
        );
        let names = sys.model.joint_names();
        let index = |n: &String| names.iter().position(|m| m == n);
        let goal_regions: Vec<GoalRegion> = regions
            .iter()
            .map(|r| {
                let joints = r.joints.iter().map(index).collect::<Option<Vec<usize>>>();
                joints
                    .map(|joints| GoalRegion {
                        name: r.group.clone(),
                        joints,
                        mean: r.mean.clone(),
                        components: r.components.clone(),
                        center: r.center.clone(),
                        radius: r.radius,
                    })
                    .ok_or_else(|| {
                        Error::invalid(
                            "$.model",
                            format!("the model's joints are not all joints of '{robot}'"),
                        )
                    })
            })
            .collect::<Result<_, _>>()?;
        // The regions' centre.
        let arm_seed = (!goal_regions.is_empty()).then(|| {
            let mut q = sys.model.neutral();
            for g in &goal_regions {
                for (&j, v) in g.joints.iter().zip(g.centre()) {
                    q[j] = v;
                }
            }
            q
        });
        let view = sys.clone();
        let (result, object) = tokio::task::spawn_blocking(move || {
            let mut req = make_request(object.clone(), &settings);
            req.arm_seed = arm_seed;
            req.goal_regions = goal_regions;
            let r = plan_grasp(&sys, &req).map_err(|e| grasp_error("$", e))?;
            Ok::<_, Error>(((r, settings.dto), object))
        })
        .await
        .map_err(Error::internal)??;
        let (result, dto) = result;
        Ok((
            new_grasp(robot, self.object_id.clone(), &object, &dto, &result),
            result,
            GraspScene {
                sys: view,
                object: Some(object),
            },
        ))
    }
}

/// The stored objects, the seeded everyday objects first.
pub async fn objects(ctx: &Context) -> Result<Vec<repo::ObjectRow>, Error> {
    Ok(repo::list_objects(&ctx.db).await?)
}

/// Stored object `id`.
pub async fn object(ctx: &Context, id: &str) -> Result<repo::ObjectRow, Error> {
    repo::get_object(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("object", id))
}

/// Deletes object `id` (grasps computed for it keep their own copy).
pub async fn delete_object(ctx: &Context, id: &str) -> Result<(), Error> {
    if repo::delete_object(&ctx.db, id).await? {
        Ok(())
    } else {
        Err(Error::not_found("object", id))
    }
}

/// Stored grasp `id`.
pub async fn get(ctx: &Context, id: &str) -> Result<repo::GraspRow, Error> {
    repo::get_grasp(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("grasp", id))
}

/// Finished batch `id` with its grasp ids in item order.
pub async fn batch(ctx: &Context, id: &str) -> Result<(repo::BatchRow, Vec<String>), Error> {
    repo::get_batch(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("grasp batch", id))
}

/// Computes and stores one grasp. An infeasible request (object out of reach, too large) is a
/// stored result with `feasible: false` and a reason.
pub async fn create(ctx: &Context, body: &GraspIn) -> Result<repo::GraspRow, Error> {
    let (c, b) = (ctx.clone(), body.clone());
    let (new, _, _) = ctx
        .compute
        .run(async move { compute(&c, &b, &[]).await })
        .await??;
    Ok(repo::insert_grasp(&ctx.db, &new).await?)
}

/// Validates and stores an object.
pub async fn create_object(ctx: &Context, body: ObjectIn) -> Result<repo::ObjectRow, Error> {
    let obj = tokio::task::spawn_blocking(move || parse_object("$", &body))
        .await
        .map_err(Error::internal)??;
    let spec = serde_json::to_string(obj.spec()).map_err(Error::internal)?;
    Ok(repo::insert_object(&ctx.db, &obj.spec().name, &spec).await?)
}

/// Validates a batch and submits it as a job whose result is the stored batch.
pub async fn submit_batch(ctx: &Context, body: &GraspBatchIn) -> Result<JobRecord, Error> {
    if body.items.is_empty() || body.items.len() > MAX_BATCH {
        return Err(Error::invalid(
            "$.items",
            format!("must hold 1 to {MAX_BATCH} items, got {}", body.items.len()),
        ));
    }
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        (body.starts, body.max_starts),
        body.seed,
        None,
    )?;
    let mut objects = Vec::with_capacity(body.items.len());
    for (i, it) in body.items.iter().enumerate() {
        objects
            .push(resolve_object(ctx, &format!("$.items[{i}]."), &it.object_id, &it.object).await?);
    }
    let robot = body.robot.clone();
    let sys = robot_view(ctx, &robot).await?;
    // Checked once before the job exists, so a bad quality measure is a 422, not a failed job.
    if let Some((_, o)) = objects.first() {
        make_request(o.clone(), &settings)
            .validate(&sys)
            .map_err(|e| grasp_error("$", e))?;
    }
    Ok(ctx
        .jobs
        .submit("grasp_batch", move |job| {
            let n = objects.len();
            let mut rows = Vec::with_capacity(n);
            for (i, (oid, obj)) in objects.into_iter().enumerate() {
                job.check_cancelled()?;
                let r = plan_grasp(&sys, &make_request(obj.clone(), &settings))
                    .map_err(JobError::failed)?;
                rows.push(new_grasp(&robot, oid, &obj, &settings.dto, &r));
                job.progress((i + 1) as f64 / n as f64, format!("grasp {} of {n}", i + 1));
            }
            Ok(JobOutput::persist_with(move |job_id, tx| {
                Box::pin(async move {
                    let id = repo::insert_batch(tx, &job_id.to_string(), &robot, &rows).await?;
                    Ok(ResultRef::new("grasps/batches", id))
                })
            }))
        })
        .await?)
}

/// The offline path of the `reachgrasp grasp` command: the `POST /v1/grasps` body, where
/// `object_id` names a seeded object (`ball`, `bottle`, `kitchen_timer`, `pencil`,
/// `sunglasses`, placed 0.5 m in front of the robot on a table at z = 0). Blocking.
pub fn offline(robots: &std::path::Path, body: &GraspIn) -> Result<GraspResult, Error> {
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        (body.starts, body.max_starts),
        body.seed,
        body.elbow_reference,
    )?;
    let object = match (&body.object_id, &body.object) {
        (Some(name), None) => {
            let spec =
                crate::grasp::objects::seeded_object(name, 0.5, 0.0, 0.0).ok_or_else(|| {
                    Error::invalid("$.object_id", format!("unknown seeded object '{name}'"))
                })?;
            Object::new(spec).map_err(Error::internal)?
        }
        (None, Some(o)) => parse_object("$.object", o)?,
        _ => {
            return Err(Error::invalid(
                "$.object_id",
                "give exactly one of object_id and object",
            ));
        }
    };
    let sys = load_system(robots, &body.robot)?;
    plan_grasp(&sys, &make_request(object, &settings)).map_err(|e| grasp_error("$", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(shape: serde_json::Value) -> ObjectIn {
        serde_json::from_value(serde_json::json!({
            "name": "thing", "shape": shape, "position": [0.5, 0.0, 0.1]
        }))
        .unwrap()
    }

    fn field_of(r: Result<Object, Error>) -> (String, String) {
        match r {
            Err(Error::Invalid(fields)) => (fields[0].field.clone(), fields[0].message.clone()),
            other => panic!("expected a validation error, got {other:?}"),
        }
    }

    #[test]
    fn a_huge_length_is_refused_at_its_own_field_as_out_of_range() {
        let (path, message) = field_of(parse_object(
            "$.object",
            &object(serde_json::json!({"type": "sphere", "radius": 1e308})),
        ));
        assert_eq!(path, "$.object.shape.radius");
        assert!(message.contains("out of range"), "{message}");
        assert!(!message.contains("inf"), "{message}");
        let (path, _) = field_of(parse_object(
            "$",
            &object(serde_json::json!({"type": "box", "size": [0.1, 3.0, 0.1]})),
        ));
        assert_eq!(path, "$.shape.size[1]");
        // Each length fits, the whole does not: the shape is named.
        let (path, message) = field_of(parse_object(
            "$",
            &object(serde_json::json!({"type": "box", "size": [1.5, 1.5, 1.5]})),
        ));
        assert_eq!(path, "$.shape");
        assert!(message.contains("across"), "{message}");
    }

    #[test]
    fn mesh_problems_name_the_triangle_in_the_request() {
        let vertices = [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.0, 0.1, 0.0],
            [0.0, 0.0, 0.1],
        ];
        // A closed tetrahedron whose triangle 2 points past the vertices.
        let bad = serde_json::json!({"type": "mesh", "vertices": vertices,
            "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 9], [1, 2, 3]]});
        let (path, message) = field_of(parse_object("$", &object(bad)));
        assert_eq!(path, "$.shape.triangles[2]", "{message}");
        // The same edge twice in one direction (triangle 1 repeats triangle 0's edges).
        let twice = serde_json::json!({"type": "mesh", "vertices": vertices,
            "triangles": [[0, 2, 1], [0, 2, 1], [0, 3, 2], [1, 2, 3]]});
        let (path, message) = field_of(parse_object("$.object", &object(twice)));
        assert_eq!(path, "$.object.shape.triangles[1]", "{message}");
        assert_eq!(
            mesh_item("edge (1, 2) has no opposite edge: the mesh is not closed"),
            "triangles"
        );
        assert_eq!(mesh_item("vertex 7 is not finite"), "vertices[7]");
    }
}
