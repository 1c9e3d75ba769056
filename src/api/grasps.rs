//! `/v1/objects` (graspable objects, seeded with everyday objects) and `/v1/grasps`
//! (task-specific grasps, paper eq. 10-29; batches as jobs).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, FieldError, Json, Path, Problem, robots};
use crate::grasp::objects::{ObjectSpec, ShapeSpec, SupportPlane, parse_obj, parse_stl};
use crate::grasp::{
    Goal, GoalRegion, GraspError, GraspRequest, GraspResult, HandArm, Object, QualityMeasure,
    TaskDirection, Transmission, Weights, plan_grasp,
};
use crate::jobs::{JobError, JobOutput, JobRecord, ResultRef};
use crate::kinematics::System;
use crate::store::grasps as repo;

/// Most grasps in one batch request.
pub const MAX_BATCH: usize = 200;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_objects, create_object))
        .routes(routes!(get_object, delete_object))
        .routes(routes!(create_grasp))
        .routes(routes!(get_grasp))
        .routes(routes!(create_batch))
        .routes(routes!(get_batch))
}

// ---------------------------------------------------------------------------------------------
// DTOs

/// An uploaded mesh: Wavefront OBJ text, or STL (ASCII text, or binary as base64).
#[derive(Debug, Clone, Deserialize, ToSchema)]
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
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct ObjectIn {
    pub name: String,
    pub shape: Option<ShapeSpec>,
    pub mesh: Option<MeshIn>,
    /// Centroid position (m, robot base frame).
    pub position: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]` (default identity).
    pub orientation: Option<[f64; 4]>,
    /// Support plane the object rests on (optional).
    pub support: Option<SupportPlane>,
}

/// A stored object.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ObjectDto {
    pub id: String,
    pub name: String,
    /// True for the everyday objects present from the start.
    pub seeded: bool,
    pub spec: ObjectSpec,
    pub created_at: String,
}

/// A task direction (world frame; normalised by the service).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TaskDirectionIn {
    pub direction: [f64; 3],
    pub kind: Transmission,
    pub goal: Goal,
}

/// The object of a grasp request: a stored object's id, or an inline description.
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct GraspIn {
    /// Robot (arm-hand system) id: a bundled system such as `wam_ihy`, or the id of one registered
    /// with `POST /v1/robots`.
    pub robot: String,
    /// Id of a stored object (give this or `object`).
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
    /// Starts of the multi-start search, 1 to 64 (default 4).
    pub starts: Option<usize>,
    /// Seed of the start perturbations (default 0).
    pub seed: Option<u64>,
    /// Human elbow reference for the anthropomorphism term D (m, world).
    pub elbow_reference: Option<[f64; 3]>,
}

/// A batch: the same robot and task settings over many objects or placements.
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct GraspBatchIn {
    /// Robot id (bundled or registered), as in `POST /v1/grasps`.
    pub robot: String,
    /// Each item is an object id or an inline object (e.g. the same shape at several poses).
    pub items: Vec<BatchItemIn>,
    #[serde(default)]
    pub task_directions: Vec<TaskDirectionIn>,
    pub quality: Option<QualityMeasure>,
    pub weights: Option<Weights>,
    pub starts: Option<usize>,
    pub seed: Option<u64>,
}

/// One batch item.
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct BatchItemIn {
    pub object_id: Option<String>,
    pub object: Option<ObjectIn>,
}

/// A stored grasp.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GraspDto {
    pub id: String,
    pub robot: String,
    pub object_id: Option<String>,
    /// The object as used.
    pub object: ObjectSpec,
    /// The task settings as used.
    pub request: GraspSettingsDto,
    pub result: GraspResult,
    pub batch_id: Option<String>,
    pub created_at: String,
}

/// Task settings echoed with a grasp.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GraspSettingsDto {
    pub task_directions: Vec<TaskDirectionIn>,
    pub quality: QualityMeasure,
    pub weights: Weights,
    pub starts: usize,
    pub seed: u64,
    pub elbow_reference: Option<[f64; 3]>,
}

/// A finished batch.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GraspBatchDto {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub count: i64,
    pub feasible: i64,
    /// Grasp ids in item order (`GET /v1/grasps/{id}`).
    pub grasps: Vec<String>,
    pub created_at: String,
}

// ---------------------------------------------------------------------------------------------
// Parsing (bad input never reaches the numerics)

fn grasp_error(prefix: &str, e: GraspError) -> ApiError {
    let path = match &e {
        GraspError::InvalidDimension { field, .. } | GraspError::NonFinite { field } => {
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
    ApiError::invalid_field(path, e.to_string())
}

/// Standard base64 (RFC 4648) decoding; hand-rolled because it is the only use in the service.
pub(crate) fn decode_base64(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    for c in s.bytes().filter(|c| !c.is_ascii_whitespace()) {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            b'=' => break,
            _ => return None,
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    Some(out)
}

fn parse_object(prefix: &str, o: &ObjectIn) -> Result<Object, ApiError> {
    if o.name.trim().is_empty() {
        return Err(ApiError::invalid_field(
            format!("{prefix}.name"),
            "must not be empty",
        ));
    }
    let shape = match (&o.shape, &o.mesh) {
        (Some(s), None) => s.clone(),
        (None, Some(m)) => {
            let bytes = match m.encoding.as_deref().unwrap_or("text") {
                "text" => m.data.as_bytes().to_vec(),
                "base64" => decode_base64(&m.data).ok_or_else(|| {
                    ApiError::invalid_field(format!("{prefix}.mesh.data"), "invalid base64")
                })?,
                other => {
                    return Err(ApiError::invalid_field(
                        format!("{prefix}.mesh.encoding"),
                        format!("unknown encoding '{other}' (text or base64)"),
                    ));
                }
            };
            match m.format.as_str() {
                "obj" => {
                    let text = std::str::from_utf8(&bytes).map_err(|_| {
                        ApiError::invalid_field(
                            format!("{prefix}.mesh.data"),
                            "OBJ data is not UTF-8 text",
                        )
                    })?;
                    parse_obj(text).map_err(|e| grasp_error(prefix, e))?
                }
                "stl" => parse_stl(&bytes).map_err(|e| grasp_error(prefix, e))?,
                other => {
                    return Err(ApiError::invalid_field(
                        format!("{prefix}.mesh.format"),
                        format!("unknown mesh format '{other}' (obj or stl)"),
                    ));
                }
            }
        }
        _ => {
            return Err(ApiError::invalid_field(
                format!("{prefix}.shape"),
                "give exactly one of shape and mesh",
            ));
        }
    };
    Object::new(ObjectSpec {
        name: o.name.clone(),
        shape,
        position: o.position,
        orientation: o.orientation.unwrap_or([1.0, 0.0, 0.0, 0.0]),
        support: o.support,
    })
    .map_err(|e| grasp_error(prefix, e))
}

fn object_dto(row: repo::ObjectRow) -> Result<ObjectDto, ApiError> {
    let spec: ObjectSpec = serde_json::from_str(&row.spec).map_err(ApiError::internal)?;
    Ok(ObjectDto {
        id: row.id,
        name: row.name,
        seeded: row.seeded,
        spec,
        created_at: row.created_at,
    })
}

/// Grasp views of the systems, by robot id, with the loaded system they were built from: a view
/// is rebuilt only when [`robots::system`] hands out a different system (the robot's row
/// changed), since building one samples every link's collision spheres.
type ViewCache = Mutex<HashMap<String, (Arc<System>, Arc<HandArm>)>>;

fn view_cache() -> &'static ViewCache {
    static CACHE: OnceLock<ViewCache> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(HashMap::new()))
}

fn hand_arm_of(key: &str, sys: &Arc<System>) -> Result<Arc<HandArm>, ApiError> {
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
async fn robot_view(state: &AppState, robot: &str) -> Result<Arc<HandArm>, ApiError> {
    let sys = robots::robot_field(state, robot, "$.robot").await?;
    let key = robot.to_owned();
    tokio::task::spawn_blocking(move || hand_arm_of(&key, &sys))
        .await
        .map_err(ApiError::internal)?
}

/// Resolve a bundled system by file name to its grasp view, for the offline CLI (no database);
/// blocking (file I/O + parsing).
pub fn load_system(robots: &std::path::Path, name: &str) -> Result<Arc<HandArm>, ApiError> {
    let valid = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|c| c.is_ascii_alphanumeric() || c == b'_' || c == b'-');
    let path = robots.join("systems").join(format!("{name}.toml"));
    if !valid || !path.is_file() {
        return Err(ApiError::invalid_field(
            "$.robot",
            format!("unknown robot '{name}'"),
        ));
    }
    let sys =
        System::from_file(&path).map_err(|e| ApiError::invalid_field("$.robot", e.to_string()))?;
    Ok(Arc::new(
        HandArm::from_system(&sys).map_err(|e| grasp_error("$.robot", e))?,
    ))
}

struct Settings {
    task: Vec<TaskDirection>,
    dto: GraspSettingsDto,
}

fn parse_settings(
    task_directions: &[TaskDirectionIn],
    quality: Option<QualityMeasure>,
    weights: Option<Weights>,
    starts: Option<usize>,
    seed: Option<u64>,
    elbow_reference: Option<[f64; 3]>,
) -> Result<Settings, ApiError> {
    let mut errors = Vec::new();
    let mut task = Vec::new();
    for (i, t) in task_directions.iter().enumerate() {
        let d = Vector3::from(t.direction);
        let n = d.norm();
        if !n.is_finite() || n < 1e-9 {
            errors.push(FieldError::new(
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
            errors.push(FieldError::new(
                format!("$.weights.{name}"),
                format!("must be finite and non-negative, got {v}"),
            ));
        }
    }
    let starts = starts.unwrap_or(4);
    if !(1..=64).contains(&starts) {
        errors.push(FieldError::new(
            "$.starts",
            format!("must be between 1 and 64, got {starts}"),
        ));
    }
    if let Some(e) = elbow_reference
        && e.iter().any(|x| !x.is_finite())
    {
        errors.push(FieldError::new("$.elbow_reference", "must be finite"));
    }
    if !errors.is_empty() {
        return Err(ApiError::validation(errors));
    }
    Ok(Settings {
        task,
        dto: GraspSettingsDto {
            task_directions: task_directions.to_vec(),
            quality: quality.unwrap_or(QualityMeasure::CentroidDistance),
            weights,
            starts,
            seed: seed.unwrap_or(0),
            elbow_reference,
        },
    })
}

fn make_request(object: Object, s: &Settings) -> GraspRequest {
    let mut req = GraspRequest::new(object, s.task.clone(), s.dto.quality);
    req.weights = s.dto.weights;
    req.starts = s.dto.starts;
    req.seed = s.dto.seed;
    req.elbow_reference = s.dto.elbow_reference.map(Point3::from);
    req
}

async fn resolve_object(
    state: &AppState,
    prefix: &str,
    id: &Option<String>,
    inline: &Option<ObjectIn>,
) -> Result<(Option<String>, Object), ApiError> {
    match (id, inline) {
        (Some(id), None) => {
            let row = repo::get_object(&state.db, id).await?.ok_or_else(|| {
                ApiError::invalid_field(
                    format!("{prefix}object_id"),
                    format!("unknown object '{id}'"),
                )
            })?;
            let dto = object_dto(row)?;
            let obj = Object::new(dto.spec).map_err(ApiError::internal)?;
            Ok((Some(dto.id), obj))
        }
        (None, Some(o)) => Ok((None, parse_object(&format!("{prefix}object"), o)?)),
        _ => Err(ApiError::invalid_field(
            format!("{prefix}object_id"),
            "give exactly one of object_id and object",
        )),
    }
}

fn new_grasp(
    robot: &str,
    object_id: Option<String>,
    obj: &Object,
    s: &GraspSettingsDto,
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

pub(crate) fn grasp_dto(row: repo::GraspRow) -> Result<GraspDto, ApiError> {
    Ok(GraspDto {
        id: row.id,
        robot: row.robot,
        object_id: row.object_id,
        object: serde_json::from_str(&row.object).map_err(ApiError::internal)?,
        request: serde_json::from_str(&row.request).map_err(ApiError::internal)?,
        result: serde_json::from_str(&row.result).map_err(ApiError::internal)?,
        batch_id: row.batch_id,
        created_at: row.created_at,
    })
}

// ---------------------------------------------------------------------------------------------
// Handlers

/// List objects (the seeded everyday objects first).
#[utoipa::path(get, path = "/v1/objects", tag = "grasps",
    responses((status = 200, description = "OK", body = Vec<ObjectDto>)))]
async fn list_objects(State(state): State<AppState>) -> Result<Json<Vec<ObjectDto>>, ApiError> {
    let rows = repo::list_objects(&state.db).await?;
    Ok(Json(
        rows.into_iter().map(object_dto).collect::<Result<_, _>>()?,
    ))
}

/// Register an object: a primitive (sphere, cylinder, box, capsule) or a closed triangle mesh.
#[utoipa::path(post, path = "/v1/objects", tag = "grasps", request_body = ObjectIn,
    responses((status = 201, description = "Created", body = ObjectDto),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_object(
    State(state): State<AppState>,
    Json(body): Json<ObjectIn>,
) -> Result<Response, ApiError> {
    let obj = tokio::task::spawn_blocking(move || parse_object("$", &body))
        .await
        .map_err(ApiError::internal)??;
    let spec = serde_json::to_string(obj.spec()).map_err(ApiError::internal)?;
    let row = repo::insert_object(&state.db, &obj.spec().name, &spec).await?;
    let dto = object_dto(row)?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/objects/{}", dto.id),
        dto,
    ))
}

/// One object.
#[utoipa::path(get, path = "/v1/objects/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Object id")),
    responses((status = 200, description = "OK", body = ObjectDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_object(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ObjectDto>, ApiError> {
    let row = repo::get_object(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("object", &id))?;
    Ok(Json(object_dto(row)?))
}

/// Delete an object (grasps computed for it keep their own copy).
#[utoipa::path(delete, path = "/v1/objects/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Object id")),
    responses((status = 204, description = "Deleted"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn delete_object(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    if repo::delete_object(&state.db, &id).await? {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(ApiError::not_found("object", &id))
    }
}

/// Compute a task-specific arm configuration and robust grasp (eq. 22-29) and store it. An
/// infeasible request (object out of reach, too large) is a stored result with
/// `feasible: false` and a reason.
#[utoipa::path(post, path = "/v1/grasps", tag = "grasps", request_body = GraspIn,
    responses((status = 201, description = "Created", body = GraspDto),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_grasp(
    State(state): State<AppState>,
    Json(body): Json<GraspIn>,
) -> Result<Response, ApiError> {
    let (new, _) = compute_grasp(&state, &body, &[]).await?;
    let out = store_grasp(&state, &new).await?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/grasps/{}", out.id),
        out,
    ))
}

/// Computes one grasp, ready to store (the work of `POST /v1/grasps`, shared with `/v1/plans`,
/// which stores it only once the rest of the plan has been checked).
///
/// With a motion model's goal `regions` (a plan's), every start begins at their centre and the
/// grasp must lie inside them ([`crate::grasp::GraspRequest::goal_regions`]).
pub(crate) async fn compute_grasp(
    state: &AppState,
    body: &GraspIn,
    regions: &[super::models::NamedGoalRegion],
) -> Result<(repo::NewGrasp, GraspResult), ApiError> {
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        body.starts,
        body.seed,
        body.elbow_reference,
    )?;
    let (object_id, object) = resolve_object(state, "$.", &body.object_id, &body.object).await?;
    let sys = robot_view(state, &body.robot).await?;
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
                    ApiError::invalid_field(
                        "$.model",
                        format!("the model's joints are not all joints of '{}'", body.robot),
                    )
                })
        })
        .collect::<Result<_, _>>()?;
    // The regions' centre: mean + W c per group.
    let arm_seed = (!goal_regions.is_empty()).then(|| {
        let mut q = sys.model.neutral();
        for g in &goal_regions {
            let d = g.center.len();
            for (gi, &j) in g.joints.iter().enumerate() {
                q[j] = g.mean[gi]
                    + (0..d)
                        .map(|i| g.components[gi * d + i] * g.center[i])
                        .sum::<f64>();
            }
        }
        q
    });
    let (result, object) = tokio::task::spawn_blocking(move || {
        let mut req = make_request(object.clone(), &settings);
        req.arm_seed = arm_seed;
        req.goal_regions = goal_regions;
        let r = plan_grasp(&sys, &req).map_err(|e| grasp_error("$", e))?;
        Ok::<_, ApiError>(((r, settings.dto), object))
    })
    .await
    .map_err(ApiError::internal)??;
    let (result, dto) = result;
    Ok((
        new_grasp(&body.robot, object_id, &object, &dto, &result),
        result,
    ))
}

/// Stores a grasp from [`compute_grasp`].
pub(crate) async fn store_grasp(
    state: &AppState,
    new: &repo::NewGrasp,
) -> Result<GraspDto, ApiError> {
    grasp_dto(repo::insert_grasp(&state.db, new).await?)
}

/// One stored grasp.
#[utoipa::path(get, path = "/v1/grasps/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Grasp id")),
    responses((status = 200, description = "OK", body = GraspDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_grasp(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<GraspDto>, ApiError> {
    let row = repo::get_grasp(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("grasp", &id))?;
    Ok(Json(grasp_dto(row)?))
}

/// Compute many grasps (objects or placements) as a job; the result is a batch
/// (`GET /v1/grasps/batches/{id}`).
#[utoipa::path(post, path = "/v1/grasps/batch", tag = "grasps", request_body = GraspBatchIn,
    responses((status = 202, description = "Accepted: the job, to follow at its Location", body = JobRecord),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_batch(
    State(state): State<AppState>,
    Json(body): Json<GraspBatchIn>,
) -> Result<Response, ApiError> {
    if body.items.is_empty() || body.items.len() > MAX_BATCH {
        return Err(ApiError::invalid_field(
            "$.items",
            format!("must hold 1 to {MAX_BATCH} items, got {}", body.items.len()),
        ));
    }
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        body.starts,
        body.seed,
        None,
    )?;
    let mut objects = Vec::with_capacity(body.items.len());
    for (i, it) in body.items.iter().enumerate() {
        objects.push(
            resolve_object(&state, &format!("$.items[{i}]."), &it.object_id, &it.object).await?,
        );
    }
    let robot = body.robot.clone();
    let sys = robot_view(&state, &robot).await?;
    // Checked once before the job exists, so a bad quality measure is a 422, not a failed job.
    if let Some((_, o)) = objects.first() {
        make_request(o.clone(), &settings)
            .validate(&sys)
            .map_err(|e| grasp_error("$", e))?;
    }
    let job = state
        .jobs
        .submit("grasp_batch", move |ctx| {
            let n = objects.len();
            let mut rows = Vec::with_capacity(n);
            for (i, (oid, obj)) in objects.into_iter().enumerate() {
                ctx.check_cancelled()?;
                let r = plan_grasp(&sys, &make_request(obj.clone(), &settings))
                    .map_err(JobError::failed)?;
                rows.push(new_grasp(&robot, oid, &obj, &settings.dto, &r));
                ctx.progress((i + 1) as f64 / n as f64, format!("grasp {} of {n}", i + 1));
            }
            Ok(JobOutput::persist_with(move |job_id, tx| {
                Box::pin(async move {
                    let id = repo::insert_batch(tx, &job_id.to_string(), &robot, &rows).await?;
                    Ok(ResultRef::new("grasps/batches", id))
                })
            }))
        })
        .await?;
    Ok(super::accepted_job(job, None))
}

/// A finished batch: counts and grasp ids in item order.
#[utoipa::path(get, path = "/v1/grasps/batches/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Batch id")),
    responses((status = 200, description = "OK", body = GraspBatchDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_batch(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<GraspBatchDto>, ApiError> {
    let (b, grasps) = repo::get_batch(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("grasp batch", &id))?;
    Ok(Json(GraspBatchDto {
        id: b.id,
        job_id: b.job_id,
        robot: b.robot,
        count: b.count,
        feasible: b.feasible,
        grasps,
        created_at: b.created_at,
    }))
}

/// The offline path of the `reachgrasp grasp` command: the `POST /v1/grasps` body, where
/// `object_id` names a seeded object (`ball`, `bottle`, `kitchen_timer`, `pencil`,
/// `sunglasses`, placed 0.5 m in front of the robot on a table at z = 0). Blocking.
pub fn grasp_offline(robots: &std::path::Path, body: &GraspIn) -> Result<GraspResult, ApiError> {
    let settings = parse_settings(
        &body.task_directions,
        body.quality,
        body.weights,
        body.starts,
        body.seed,
        body.elbow_reference,
    )?;
    let object = match (&body.object_id, &body.object) {
        (Some(name), None) => {
            let spec =
                crate::grasp::objects::seeded_object(name, 0.5, 0.0, 0.0).ok_or_else(|| {
                    ApiError::invalid_field(
                        "$.object_id",
                        format!("unknown seeded object '{name}'"),
                    )
                })?;
            Object::new(spec).map_err(ApiError::internal)?
        }
        (None, Some(o)) => parse_object("$.object", o)?,
        _ => {
            return Err(ApiError::invalid_field(
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
    use super::decode_base64;

    #[test]
    fn base64_decodes_rfc4648_vectors() {
        assert_eq!(decode_base64("").unwrap(), b"");
        assert_eq!(decode_base64("Zg==").unwrap(), b"f");
        assert_eq!(decode_base64("Zm9vYmFy").unwrap(), b"foobar");
        assert_eq!(decode_base64("Zm9vYg==").unwrap(), b"foob");
        assert!(decode_base64("Zm9v!").is_none());
    }
}
