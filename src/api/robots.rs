//! `/v1/robots`: the arm-hand system library (bundled read-only systems from `robots/`, plus
//! registered ones) and its kinematics: FK, Jacobians, IK, manipulability.
//!
//! The use cases are in [`crate::service::robots`]; here they are routed and rendered. Joint
//! vectors always travel with their names (`joint_names` + `positions`) and are checked once
//! against the model ([`crate::kinematics::JointVector`]). Kinematic errors become 422
//! problem+json naming the field and the joint, link or frame.

use std::collections::BTreeMap;

use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, Json, Path, Problem};
use crate::kinematics::{FrameId, JointKind, System, SystemDescriptor};
use crate::service::robots::RobotRow;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_robots, create_robot))
        .routes(routes!(get_robot, delete_robot))
        .routes(routes!(get_robot_urdf))
        .routes(routes!(get_robot_mesh))
        .routes(routes!(robot_fk))
        .routes(routes!(robot_jacobian))
        .routes(routes!(robot_ik))
        .routes(routes!(robot_manipulability))
}

// ------------------------------------------------------------------------------------ errors

use crate::service::robots::{self as service, inf_to_none};
pub use crate::service::robots::{
    DefaultModelDto, IkBatchFile, IkBatchReport, IkBatchStats, IkRequest, IkResponse,
    MAX_IK_BUDGET_MS, SeedDto,
};
pub use crate::service::robots::{
    FkRequest, FkResponse, FramePose, JacobianRequest, JacobianResponse, ManipulabilityRequest,
    ManipulabilityResponse, TaskRows, TransmissionDto,
};

// ------------------------------------------------------------------------------------ DTOs

/// A system in the list.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct RobotSummary {
    pub id: String,
    pub name: String,
    /// Bundled systems come from `robots/` and are read-only.
    pub bundled: bool,
    /// Independent joints, the order of every joint vector of this robot.
    pub joint_names: Vec<String>,
    pub fingers: Vec<String>,
    /// The model plans use when they name none, or why there is none yet.
    pub default_model: DefaultModelDto,
    pub created_at: String,
    pub updated_at: String,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct RobotList {
    pub items: Vec<RobotSummary>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct MimicDto {
    /// The independent joint this one follows.
    pub joint: String,
    pub multiplier: f64,
    pub offset: f64,
}

/// A joint of the model. Limits are `null` where unbounded.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct JointDto {
    pub name: String,
    /// `revolute`, `continuous`, `prismatic` or `fixed`.
    #[serde(rename = "type")]
    pub kind: String,
    pub parent: String,
    pub child: String,
    #[schema(min_items = 3, max_items = 3)]
    pub axis: Option<[f64; 3]>,
    pub lower: Option<f64>,
    pub upper: Option<f64>,
    pub velocity: Option<f64>,
    pub effort: Option<f64>,
    /// Independent coordinate (its index in `joint_names`), or coupled/fixed.
    pub independent: bool,
    pub q_index: Option<usize>,
    /// For coupled joints (eq. 26): value = multiplier * value(joint) + offset, resolved to an
    /// independent joint.
    pub mimic: Option<MimicDto>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct FingerDto {
    pub name: String,
    pub tip_frame: String,
    /// Fingertip contact-sphere radius, metres.
    pub contact_radius: f64,
    /// Independent joints moving this finger.
    pub joints: Vec<String>,
}

/// A system with its joints, fingers and descriptor.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct RobotDetail {
    pub id: String,
    pub name: String,
    pub bundled: bool,
    pub joint_names: Vec<String>,
    pub arm_joints: Vec<String>,
    pub hand_joints: Vec<String>,
    pub joints: Vec<JointDto>,
    pub frames: Vec<String>,
    pub fingers: Vec<FingerDto>,
    pub thumb: String,
    /// Eq. 28: each `[a, b]` requires value(a) <= value(b).
    pub spread_pairs: Vec<[String; 2]>,
    /// Eq. 4: frames whose origins enter the anthropomorphism term.
    pub elbow_frames: Vec<String>,
    pub shoulder_frame: String,
    pub wrist_frame: String,
    /// The descriptor as registered (bundled systems: as in `robots/systems/`, with the URDF
    /// paths).
    pub descriptor: SystemDescriptor,
    /// The model plans use when they name none, or why there is none yet.
    pub default_model: DefaultModelDto,
    pub created_at: String,
    pub updated_at: String,
}

/// Register a system: a descriptor plus either `arm_urdf` + `hand_urdf` (with `descriptor.mount`)
/// or one combined `urdf` (with `descriptor.wrist_frame`). Meshes the URDFs reference in
/// `<collision>` or `<visual>` (STL or OBJ) are uploaded in `meshes`, keyed by the filename
/// exactly as the URDF writes it; a reference to a mesh not uploaded is a 422 naming the link
/// and the file. Visual geometry is only drawn (the dashboard's 3-D viewer); collision checks
/// use the collision geometry.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateRobot {
    /// The system descriptor (same fields as `robots/systems/*.toml`; its URDF path fields are
    /// ignored here, the URDF texts come in `arm_urdf` + `hand_urdf` or `urdf`).
    pub descriptor: SystemDescriptor,
    pub arm_urdf: Option<String>,
    pub hand_urdf: Option<String>,
    pub urdf: Option<String>,
    /// Mesh files by URDF filename (e.g. `package://my_arm/meshes/link1.stl`), at most 64,
    /// each name 1 to 512 bytes of UTF-8; stored with the robot.
    #[serde(default)]
    pub meshes: BTreeMap<String, MeshUpload>,
}

/// Most meshes uploaded with one system.
pub const MAX_MESHES: usize = 64;

/// One uploaded mesh file: STL (ASCII, or binary as base64) or OBJ text.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MeshUpload {
    /// File contents: text, or base64 when `encoding` is `base64`.
    pub data: String,
    /// `text` (default) or `base64`.
    #[serde(default)]
    pub encoding: Option<String>,
}

/// The uploaded meshes as bytes, each error naming its `$.meshes[...]` entry.
fn decode_meshes(
    meshes: &BTreeMap<String, MeshUpload>,
) -> Result<BTreeMap<String, Vec<u8>>, ApiError> {
    if meshes.len() > MAX_MESHES {
        return Err(ApiError::invalid_field(
            "$.meshes",
            format!("at most {MAX_MESHES} meshes, got {}", meshes.len()),
        ));
    }
    let mut out = BTreeMap::new();
    for (name, m) in meshes {
        let path = format!("$.meshes['{name}']");
        if name.is_empty() || name.len() > 512 {
            return Err(ApiError::invalid_field(
                path,
                "a mesh filename must have 1 to 512 bytes",
            ));
        }
        let bytes = match m.encoding.as_deref().unwrap_or("text") {
            "text" => m.data.clone().into_bytes(),
            "base64" => crate::service::decode_base64(&m.data).ok_or_else(|| {
                ApiError::invalid_field(format!("{path}.data"), "not valid base64")
            })?,
            other => {
                return Err(ApiError::invalid_field(
                    format!("{path}.encoding"),
                    format!("must be text or base64, got '{other}'"),
                ));
            }
        };
        out.insert(name.clone(), bytes);
    }
    Ok(out)
}

fn summary(row: &RobotRow, s: &System, default_model: DefaultModelDto) -> RobotSummary {
    RobotSummary {
        id: row.id.clone(),
        name: row.name.clone(),
        bundled: row.bundled,
        joint_names: s.model.joint_names().to_vec(),
        fingers: s.fingers.iter().map(|f| f.name.clone()).collect(),
        default_model,
        created_at: row.created_at.clone(),
        updated_at: row.updated_at.clone(),
    }
}

fn detail(row: &RobotRow, s: &System, default_model: DefaultModelDto) -> RobotDetail {
    let m = &s.model;
    let qn = |k: usize| m.joint_names()[k].clone();
    let joints = m
        .joints()
        .iter()
        .map(|j| {
            let act = j.actuation;
            let independent = act.is_some() && j.mimic.is_none();
            JointDto {
                name: j.name.clone(),
                kind: j.kind.type_name().into(),
                parent: m.frame_name(j.parent).into(),
                child: m.frame_name(j.child).into(),
                axis: j.kind.axis().map(|a| [a.x, a.y, a.z]),
                lower: if matches!(j.kind, JointKind::Fixed) {
                    None
                } else {
                    inf_to_none(j.limits.lower)
                },
                upper: if matches!(j.kind, JointKind::Fixed) {
                    None
                } else {
                    inf_to_none(j.limits.upper)
                },
                velocity: inf_to_none(j.limits.velocity),
                effort: inf_to_none(j.limits.effort),
                independent,
                q_index: if independent {
                    act.map(|a| a.q_index)
                } else {
                    None
                },
                mimic: match (j.mimic.is_some(), act) {
                    (true, Some(a)) => Some(MimicDto {
                        joint: qn(a.q_index),
                        multiplier: a.multiplier,
                        offset: a.offset,
                    }),
                    _ => None,
                },
            }
        })
        .collect();
    RobotDetail {
        id: row.id.clone(),
        name: row.name.clone(),
        bundled: row.bundled,
        joint_names: m.joint_names().to_vec(),
        arm_joints: s.arm_joints.iter().map(|&k| qn(k)).collect(),
        hand_joints: s.hand_joints.iter().map(|&k| qn(k)).collect(),
        joints,
        frames: (0..m.n_frames())
            .map(|i| m.frame_name(FrameId(i)).to_owned())
            .collect(),
        fingers: s
            .fingers
            .iter()
            .map(|f| FingerDto {
                name: f.name.clone(),
                tip_frame: m.frame_name(f.tip).into(),
                contact_radius: f.contact_radius,
                joints: f.joints.iter().map(|&k| qn(k)).collect(),
            })
            .collect(),
        thumb: s.fingers[s.thumb].name.clone(),
        spread_pairs: s
            .spread_pairs
            .iter()
            .map(|p| [p.lower_joint.clone(), p.upper_joint.clone()])
            .collect(),
        elbow_frames: s
            .elbow_frames
            .iter()
            .map(|&f| m.frame_name(f).to_owned())
            .collect(),
        shoulder_frame: m.frame_name(s.shoulder_frame).into(),
        wrist_frame: m.frame_name(s.wrist_frame).into(),
        descriptor: s.descriptor.clone(),
        default_model,
        created_at: row.created_at.clone(),
        updated_at: row.updated_at.clone(),
    }
}

// ------------------------------------------------------------------------------------ handlers

/// List the arm-hand systems.
#[utoipa::path(get, path = "/v1/robots", tag = "robots",
    responses((status = 200, description = "All systems, bundled first", body = RobotList)))]
async fn list_robots(State(state): State<AppState>) -> Result<Json<RobotList>, ApiError> {
    let mut items = Vec::new();
    for (row, s) in service::list(&state).await? {
        let default_model = service::default_model(&state, &row.id).await?;
        items.push(summary(&row, &s, default_model));
    }
    Ok(Json(RobotList { items }))
}

/// One system: joints with limits (independent vs coupled), fingers and fingertip frames.
#[utoipa::path(get, path = "/v1/robots/{id}", tag = "robots",
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "The system", body = RobotDetail),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_robot(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<RobotDetail>, ApiError> {
    let (row, s) = service::get(&state, &id).await?;
    let default_model = service::default_model(&state, &id).await?;
    Ok(Json(detail(&row, &s, default_model)))
}

/// The system as one URDF (arm, mount joint `hand_mount_joint`, hand).
#[utoipa::path(get, path = "/v1/robots/{id}/urdf", tag = "robots",
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "URDF XML", body = String, content_type = "application/xml"),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_robot_urdf(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let text = service::urdf(&state, &id).await?;
    Ok(([(header::CONTENT_TYPE, "application/xml")], text).into_response())
}

/// A mesh uploaded with a registered system, by the filename its URDF names (percent-encode
/// it as one path segment: `package%3A%2F%2Flab%2Fmeshes%2Flink1.stl`), as uploaded (STL or
/// OBJ): what a physics worker needs to build the system's collision shapes.
#[utoipa::path(get, path = "/v1/robots/{id}/meshes/{filename}", tag = "robots",
    params(("id" = String, Path, description = "Robot id"),
           ("filename" = String, Path, description = "The mesh's filename in the URDF, percent-encoded")),
    responses(
        (status = 200, description = "The mesh file", body = Vec<u8>, content_type = "application/octet-stream"),
        (status = 404, description = "Unknown robot or mesh", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_robot_mesh(
    State(state): State<AppState>,
    Path((id, filename)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let data = service::mesh(&state, &id, &filename).await?;
    Ok(([(header::CONTENT_TYPE, "application/octet-stream")], data).into_response())
}

/// Register an arm-hand system (validated; nothing is stored on error).
#[utoipa::path(post, path = "/v1/robots", tag = "robots", request_body = CreateRobot,
    responses(
        (status = 201, description = "Registered", body = RobotDetail),
        (status = 400, description = "Malformed JSON", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid URDF or descriptor; names the field and the joint or link", body = Problem, content_type = "application/problem+json"),
    ))]
async fn create_robot(
    State(state): State<AppState>,
    Json(body): Json<CreateRobot>,
) -> Result<Response, ApiError> {
    let desc = body.descriptor;
    let (arm, hand) = match (body.arm_urdf, body.hand_urdf, body.urdf) {
        (Some(a), Some(h), None) => (a, Some(h)),
        (None, None, Some(c)) => (c, None),
        _ => {
            return Err(ApiError::invalid_field(
                "$.urdf",
                "give either arm_urdf and hand_urdf, or urdf (one combined URDF)",
            ));
        }
    };
    let meshes = decode_meshes(&body.meshes)?;
    let (row, s) = service::register(&state, desc, arm, hand, meshes).await?;
    let id = row.id.clone();
    let default_model = service::default_model(&state, &id).await?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/robots/{id}"),
        detail(&row, &s, default_model),
    ))
}

/// Delete a registered system. Bundled systems are read-only (409); a system still referenced
/// by other resources is refused (409).
#[utoipa::path(delete, path = "/v1/robots/{id}", tag = "robots",
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Bundled or still referenced", body = Problem, content_type = "application/problem+json"),
    ))]
async fn delete_robot(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service::delete(&state, &id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Forward kinematics: world placement of every (or the named) frame.
#[utoipa::path(post, path = "/v1/robots/{id}/fk", tag = "robots", request_body = FkRequest,
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "Frame placements", body = FkResponse),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Bad joint vector or frame", body = Problem, content_type = "application/problem+json"),
    ))]
async fn robot_fk(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<FkRequest>,
) -> Result<Json<FkResponse>, ApiError> {
    Ok(Json(service::fk(&state, &id, &body).await?))
}

/// Geometric Jacobian of a frame point in the world frame (6 × n, linear then angular).
#[utoipa::path(post, path = "/v1/robots/{id}/jacobian", tag = "robots", request_body = JacobianRequest,
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "The Jacobian", body = JacobianResponse),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Bad joint vector, frame or point", body = Problem, content_type = "application/problem+json"),
    ))]
async fn robot_jacobian(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<JacobianRequest>,
) -> Result<Json<JacobianResponse>, ApiError> {
    Ok(Json(service::jacobian(&state, &id, &body).await?))
}

/// Pose inverse kinematics (damped least squares with limits and random restarts). A target
/// the solver cannot reach is still 200, with `success: false` and the best residuals.
#[utoipa::path(post, path = "/v1/robots/{id}/ik", tag = "robots", request_body = IkRequest,
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "Solution or best attempt with residuals", body = IkResponse),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Bad target, seed or options", body = Problem, content_type = "application/problem+json"),
    ))]
async fn robot_ik(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<IkRequest>,
) -> Result<Json<IkResponse>, ApiError> {
    Ok(Json(crate::service::robots::ik(&state, &id, &body).await?))
}

/// Manipulability (eq. 12), velocity/force ellipsoid axes (eq. 10-11) and transmission ratios
/// along task directions (eq. 14-15) of a frame point.
#[utoipa::path(post, path = "/v1/robots/{id}/manipulability", tag = "robots", request_body = ManipulabilityRequest,
    params(("id" = String, Path, description = "Robot id")),
    responses(
        (status = 200, description = "Manipulability analysis", body = ManipulabilityResponse),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Bad joint vector, frame or direction", body = Problem, content_type = "application/problem+json"),
    ))]
async fn robot_manipulability(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<ManipulabilityRequest>,
) -> Result<Json<ManipulabilityResponse>, ApiError> {
    Ok(Json(service::manipulability(&state, &id, &body).await?))
}

// ------------------------------------------------------------------------------------ CLI batch
