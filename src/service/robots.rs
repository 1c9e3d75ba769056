//! Robots: resolving the arm-hand systems of the library as every use case does, and the
//! inverse kinematics of one (the API's `/v1/robots/{id}/ik` and `reachgrasp ik`).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use nalgebra::{Isometry3, Matrix6xX, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{Context, Error, Invalid};
use crate::kinematics::{
    self, Data, FrameId, IkOptions, IkSolver, IkTarget, JointVector, KinematicsError, MapMeshes,
    System, SystemDescriptor, forward_kinematics, frame_jacobian,
};
use crate::store::library::{LibraryError, system_from_stored};
use crate::store::robots as repo;

pub use crate::store::robots::RobotRow;

// ------------------------------------------------------------------------------------ kinematics

/// Every system with its stored row, bundled first.
pub async fn list(ctx: &Context) -> Result<Vec<(repo::RobotRow, Arc<System>)>, Error> {
    let rows = repo::list(&ctx.db).await?;
    let mut out = Vec::with_capacity(rows.len());
    for row in rows {
        let s = ctx.robots.load_cached(row.clone()).await?;
        out.push((row, s));
    }
    Ok(out)
}

/// A registered or bundled system with its stored row (`id` a path parameter).
pub async fn get(ctx: &Context, id: &str) -> Result<(repo::RobotRow, Arc<System>), Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("robot", id))?;
    let s = ctx.robots.load_cached(row.clone()).await?;
    Ok((row, s))
}

/// The system as one URDF (arm, mount joint `hand_mount_joint`, hand).
pub async fn urdf(ctx: &Context, id: &str) -> Result<String, Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("robot", id))?;
    match &row.hand_urdf {
        None => Ok(row.arm_urdf.clone()),
        Some(hand) => combined_urdf(&row, hand).map_err(Error::internal),
    }
}

/// A mesh uploaded with system `id`, by the filename its URDF gives (404 for an unknown robot
/// or file).
pub async fn mesh(ctx: &Context, id: &str, filename: &str) -> Result<Vec<u8>, Error> {
    repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("robot", id))?;
    repo::mesh(&ctx.db, id, filename)
        .await?
        .ok_or_else(|| Error::not_found("mesh", format!("{filename} of robot {id}")))
}

/// Forward kinematics of robot `id`: world placement of every (or the named) frame.
pub async fn fk(ctx: &Context, id: &str, body: &FkRequest) -> Result<FkResponse, Error> {
    let s = system(ctx, id).await?;
    let q = joint_vector(&s.model, &body.joint_names, &body.positions, "$")?;
    let frames: Vec<FrameId> = match &body.frames {
        None => (0..s.model.n_frames()).map(FrameId).collect(),
        Some(names) => names
            .iter()
            .enumerate()
            .map(|(i, n)| frame_of(&s, n, &format!("$.frames[{i}]")))
            .collect::<Result<_, _>>()?,
    };
    let mut data = Data::new(&s.model);
    forward_kinematics(&s.model, &mut data, q.as_slice());
    let frames = frames
        .into_iter()
        .map(|f| {
            let x = data.frame(f);
            let r = x.rotation;
            FramePose {
                name: s.model.frame_name(f).to_owned(),
                position: x.translation.vector.into(),
                orientation: [r.w, r.i, r.j, r.k],
            }
        })
        .collect();
    Ok(FkResponse { frames })
}

/// The geometric Jacobian of a frame point of robot `id`, world frame (linear then angular).
pub async fn jacobian(
    ctx: &Context,
    id: &str,
    body: &JacobianRequest,
) -> Result<JacobianResponse, Error> {
    let s = system(ctx, id).await?;
    let q = joint_vector(&s.model, &body.joint_names, &body.positions, "$")?;
    let frame = frame_of(&s, &body.frame, "$.frame")?;
    let point = body.point.unwrap_or([0.0; 3]);
    finite_array(&point, "$.point")?;
    let mut data = Data::new(&s.model);
    forward_kinematics(&s.model, &mut data, q.as_slice());
    let mut j = Matrix6xX::zeros(s.model.nq());
    frame_jacobian(&s.model, &data, frame, &Vector3::from(point), &mut j);
    let rows = (0..6).map(|r| j.row(r).iter().copied().collect()).collect();
    Ok(JacobianResponse {
        frame: body.frame.clone(),
        joint_names: s.model.joint_names().to_vec(),
        rows,
    })
}

/// Manipulability (eq. 12), ellipsoid axes (eq. 10-11) and transmission ratios along task
/// directions (eq. 14-15) of a frame point of robot `id`.
pub async fn manipulability(
    ctx: &Context,
    id: &str,
    body: &ManipulabilityRequest,
) -> Result<ManipulabilityResponse, Error> {
    use kinematics::manipulability as mm;
    let s = system(ctx, id).await?;
    let q = joint_vector(&s.model, &body.joint_names, &body.positions, "$")?;
    let frame = frame_of(&s, &body.frame, "$.frame")?;
    let point = body.point.unwrap_or([0.0; 3]);
    finite_array(&point, "$.point")?;
    let task = body.task.unwrap_or(TaskRows::Linear);
    let dim = if task == TaskRows::Full { 6 } else { 3 };
    let mut errors = Vec::new();
    for (i, d) in body.directions.iter().enumerate() {
        if d.len() != dim {
            errors.push(Invalid::new(
                format!("$.directions[{i}]"),
                format!("needs {dim} components for task {task:?}, got {}", d.len()),
            ));
        } else if d.iter().any(|x| !x.is_finite()) {
            errors.push(Invalid::new(
                format!("$.directions[{i}]"),
                "components must be finite",
            ));
        } else if d.iter().map(|x| x * x).sum::<f64>() < 1e-18 {
            errors.push(Invalid::new(
                format!("$.directions[{i}]"),
                "must not be the zero vector",
            ));
        }
    }
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    let mut data = Data::new(&s.model);
    forward_kinematics(&s.model, &mut data, q.as_slice());
    let mut j = Matrix6xX::zeros(s.model.nq());
    frame_jacobian(&s.model, &data, frame, &Vector3::from(point), &mut j);
    let unit = |d: &[f64]| {
        let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
        d.iter().map(|x| x / n).collect::<Vec<f64>>()
    };
    let out = match task {
        TaskRows::Full => {
            let e = mm::velocity_ellipsoid(&j);
            let transmission = body
                .directions
                .iter()
                .map(|d| {
                    let v = Vector6::from_column_slice(&unit(d));
                    TransmissionDto {
                        direction: v.iter().copied().collect(),
                        force_ratio: inf_to_none(mm::force_transmission_ratio(&j, &v)),
                        velocity_ratio: mm::velocity_transmission_ratio(&j, &v),
                    }
                })
                .collect();
            ManipulabilityResponse {
                manipulability: mm::manipulability(&j),
                semi_axes: e.semi_axes.iter().copied().collect(),
                axes: (0..6)
                    .map(|k| e.directions.column(k).iter().copied().collect())
                    .collect(),
                transmission,
            }
        }
        TaskRows::Linear | TaskRows::Angular => {
            let block = j.fixed_rows::<3>(if task == TaskRows::Linear { 0 } else { 3 });
            let e = mm::velocity_ellipsoid(&block);
            let transmission = body
                .directions
                .iter()
                .map(|d| {
                    let v = Vector3::from_column_slice(&unit(d));
                    TransmissionDto {
                        direction: v.iter().copied().collect(),
                        force_ratio: inf_to_none(mm::force_transmission_ratio(&block, &v)),
                        velocity_ratio: mm::velocity_transmission_ratio(&block, &v),
                    }
                })
                .collect();
            ManipulabilityResponse {
                manipulability: mm::manipulability(&block),
                semi_axes: e.semi_axes.iter().copied().collect(),
                axes: (0..3)
                    .map(|k| e.directions.column(k).iter().copied().collect())
                    .collect(),
                transmission,
            }
        }
    };
    Ok(out)
}

fn joint_vector(
    model: &kinematics::Model,
    names: &[String],
    positions: &[f64],
    base: &str,
) -> Result<JointVector, Error> {
    JointVector::from_named(model, names, positions).map_err(|e| {
        let field = match e {
            KinematicsError::UnknownJoint { .. }
            | KinematicsError::RepeatedJoint { .. }
            | KinematicsError::MissingJoint { .. } => "joint_names",
            _ => "positions",
        };
        Error::invalid(format!("{base}.{field}"), e.to_string())
    })
}

/// A limit as JSON: `null` where unbounded.
pub fn inf_to_none(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct FkRequest {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
    /// Frames to report (default: every frame).
    pub frames: Option<Vec<String>>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct FramePose {
    pub name: String,
    /// Metres, world (robot base) frame.
    #[schema(min_items = 3, max_items = 3)]
    pub position: [f64; 3],
    /// `[w, x, y, z]`.
    #[schema(min_items = 4, max_items = 4)]
    pub orientation: [f64; 4],
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct FkResponse {
    pub frames: Vec<FramePose>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct JacobianRequest {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
    pub frame: String,
    /// Point rigidly attached to the frame, in frame coordinates (default the origin); each
    /// coordinate within ±1000 m.
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub point: Option<[f64; 3]>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct JacobianResponse {
    pub frame: String,
    /// Column order.
    pub joint_names: Vec<String>,
    /// 6 rows in the world frame: linear velocity of the point (3), then angular velocity (3).
    /// Coupled joints are folded into their drivers' columns.
    pub rows: Vec<Vec<f64>>,
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum TaskRows {
    /// Linear and angular velocity (6-D).
    Full,
    /// Linear velocity of the point only (3-D).
    Linear,
    /// Angular velocity only (3-D).
    Angular,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ManipulabilityRequest {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
    pub frame: String,
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub point: Option<[f64; 3]>,
    /// Rows of the Jacobian to analyse (default `linear`).
    pub task: Option<TaskRows>,
    /// Task directions (3 or 6 components to match `task`) for the transmission ratios.
    #[serde(default)]
    pub directions: Vec<Vec<f64>>,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TransmissionDto {
    /// The unit direction used.
    pub direction: Vec<f64>,
    /// Eq. 14; `null` when unbounded (the arm cannot move along the direction).
    pub force_ratio: Option<f64>,
    /// Eq. 15.
    pub velocity_ratio: f64,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ManipulabilityResponse {
    /// Eq. 12: sqrt(det(J Jᵀ)).
    pub manipulability: f64,
    /// Velocity-ellipsoid semi-axes (eq. 10), longest first; the force ellipsoid's are their
    /// reciprocals.
    pub semi_axes: Vec<f64>,
    /// Unit axis directions matching `semi_axes`.
    pub axes: Vec<Vec<f64>>,
    pub transmission: Vec<TransmissionDto>,
}

fn combined_urdf(row: &repo::RobotRow, hand: &str) -> anyhow::Result<String> {
    let desc: SystemDescriptor = serde_json::from_str(&row.descriptor)?;
    let mount = desc
        .mount
        .ok_or_else(|| anyhow::anyhow!("stored system without mount"))?;
    let mut arm = urdf_rs::read_from_string(&row.arm_urdf)?;
    let hand = urdf_rs::read_from_string(hand)?;
    let hand_root = kinematics::urdf::root_link(&hand)?;
    arm.joints.push(urdf_rs::Joint {
        name: "hand_mount_joint".into(),
        joint_type: urdf_rs::JointType::Fixed,
        origin: urdf_rs::Pose {
            xyz: urdf_rs::Vec3(mount.xyz),
            rpy: urdf_rs::Vec3(mount.rpy),
        },
        parent: urdf_rs::LinkName {
            link: mount.parent_frame,
        },
        child: urdf_rs::LinkName { link: hand_root },
        axis: urdf_rs::Axis::default(),
        limit: urdf_rs::JointLimit::default(),
        calibration: None,
        dynamics: None,
        mimic: None,
        safety_controller: None,
    });
    arm.name = row.name.clone();
    arm.links.extend(hand.links);
    arm.joints.extend(hand.joints);
    arm.materials.extend(hand.materials);
    Ok(urdf_rs::write_to_string(&arm)?)
}

/// Longest IK time budget a request may ask for.
pub const MAX_IK_BUDGET_MS: f64 = 2000.0;

/// Largest IK residual weight.
pub const MAX_IK_WEIGHT: f64 = 1e6;

/// The loaded system `id` (a path parameter: unknown is "not found").
pub async fn system(ctx: &Context, id: &str) -> Result<Arc<System>, Error> {
    Ok(ctx.robots.system(id).await?)
}

/// Whether a plan may leave out `model` for this robot now, and which model it would use.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DefaultModelDto {
    /// `trained`: plans without `model` use `id`; `seeding`: first-start seeding is training it
    /// (watch `job_id`; plans answer 503 `not-ready` meanwhile); `none`: train one
    /// (`POST /v1/models`) or name one in each plan.
    pub state: DefaultModelState,
    pub id: Option<String>,
    /// `trained`: when its training finished (RFC 3339 UTC).
    pub trained_at: Option<String>,
    pub job_id: Option<String>,
}

/// Whether a robot's default model is trained, being trained by first-start seeding, or missing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum DefaultModelState {
    Trained,
    Seeding,
    None,
}

/// The robot's default model as a plan would resolve it.
pub async fn default_model(ctx: &Context, robot: &str) -> Result<DefaultModelDto, Error> {
    let Some(row) = crate::store::models::default_model_for(&ctx.db, robot).await? else {
        let (state, job_id) = match ctx.seed.pending_job(robot) {
            Some(job) => (DefaultModelState::Seeding, Some(job.to_string())),
            None => (DefaultModelState::None, None),
        };
        return Ok(DefaultModelDto {
            state,
            id: None,
            trained_at: None,
            job_id,
        });
    };
    let trained_at = match row.job_id.parse() {
        Ok(job) => crate::store::jobs::get(&ctx.db, job)
            .await?
            .and_then(|j| j.finished_at),
        Err(_) => None,
    };
    Ok(DefaultModelDto {
        state: DefaultModelState::Trained,
        id: Some(row.id),
        trained_at: trained_at.or(Some(row.created_at)),
        job_id: None,
    })
}

/// The system of a robot named in a request body: an unknown id is bad input at `field`.
pub async fn robot_field(ctx: &Context, id: &str, field: &str) -> Result<Arc<System>, Error> {
    match ctx.robots.system(id).await {
        Err(LibraryError::UnknownRobot(_)) => {
            let known: Vec<String> = repo::list(&ctx.db)
                .await?
                .into_iter()
                .map(|r| r.id)
                .collect();
            Err(unknown_robot(field, id, &known))
        }
        other => Ok(other?),
    }
}

/// The one "unknown robot" field error, naming the robots there are.
pub fn unknown_robot(field: &str, id: &str, known: &[String]) -> Error {
    let known = if known.is_empty() {
        "none is registered yet".to_owned()
    } else {
        format!("known robots: {}", known.join(", "))
    };
    Error::invalid(field, format!("unknown robot '{id}' ({known})"))
}

// ------------------------------------------------------------------------------------ library

/// Registers an arm-hand system: builds it once to validate (the same path that loads it
/// later; nothing is stored on error), then stores it with its meshes.
pub async fn register(
    ctx: &Context,
    desc: SystemDescriptor,
    arm: String,
    hand: Option<String>,
    meshes: BTreeMap<String, Vec<u8>>,
) -> Result<(repo::RobotRow, Arc<System>), Error> {
    let desc_json = serde_json::to_string(&desc).map_err(Error::internal)?;
    let probe = repo::RobotRow {
        id: String::new(),
        name: desc.name.clone(),
        bundled: false,
        descriptor: desc_json.clone(),
        arm_urdf: arm.clone(),
        hand_urdf: hand.clone(),
        created_at: String::new(),
        updated_at: String::new(),
    };
    let source = MapMeshes(meshes);
    let (built, source) = tokio::task::spawn_blocking(move || {
        // A visual the loader had to leave out (it tolerates them, so that a stored robot keeps
        // loading) is refused here like a collision shape would be: the user is still there
        // to upload the missing file.
        let built = system_from_stored(&probe, &source)
            .and_then(|s| match s.model.visual_errors().first() {
                Some(e) => Err(e.clone()),
                None => Ok(s),
            })
            .map_err(|e| {
                let which = urdf_field_of(&e, &probe.arm_urdf, probe.hand_urdf.as_deref());
                kin_error(e, which)
            });
        (built, source)
    })
    .await
    .map_err(Error::internal)?;
    let system = built?;
    let meshes: Vec<(String, Vec<u8>)> = source.0.into_iter().collect();
    let id = uuid::Uuid::new_v4().to_string();
    let row = repo::insert_with_meshes(
        &ctx.db,
        &repo::NewRobot {
            id: &id,
            name: &desc.name,
            bundled: false,
            descriptor: &desc_json,
            arm_urdf: &arm,
            hand_urdf: hand.as_deref(),
        },
        &meshes,
    )
    .await?;
    let s = Arc::new(system);
    ctx.robots.remember(&id, &row.updated_at, s.clone());
    Ok((row, s))
}

/// Deletes a registered system. Bundled systems are read-only; a system still referenced by
/// other resources is refused.
pub async fn delete(ctx: &Context, id: &str) -> Result<(), Error> {
    let row = repo::get(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("robot", id))?;
    if row.bundled {
        return Err(Error::Conflict(format!(
            "robot {id} is bundled (from robots/) and read-only"
        )));
    }
    if crate::store::grasps::robot_in_use(&ctx.db, id).await? {
        return Err(Error::Conflict(format!(
            "robot {id} is still referenced by stored grasps; it cannot be deleted"
        )));
    }
    match repo::delete(&ctx.db, id).await {
        Ok(true) => {
            ctx.robots.forget(id);
            Ok(())
        }
        Ok(false) => Err(Error::not_found("robot", id)),
        Err(e) if crate::store::is_foreign_key_violation(&e) => Err(Error::Conflict(format!(
            "robot {id} is still referenced by other resources; delete those first"
        ))),
        Err(e) => Err(e.into()),
    }
}

/// The JSONPath a kinematics error belongs to, given where the URDF text came from.
fn kin_error(e: KinematicsError, urdf_field: &str) -> Error {
    use KinematicsError as E;
    let path = match &e {
        E::Descriptor { field, .. }
        | E::UnknownFrame { field, .. }
        | E::UnknownJointInDescriptor { field, .. } => {
            format!("$.descriptor.{field}")
        }
        E::NonFinite { path, .. } if path.starts_with("mount") || path.starts_with("fingers") => {
            format!("$.descriptor.{}", path.split(' ').next().unwrap_or(path))
        }
        E::WrongLength { .. } | E::NonFiniteJointValue { .. } => "$.positions".into(),
        E::UnknownJoint { .. } | E::RepeatedJoint { .. } | E::MissingJoint { .. } => {
            "$.joint_names".into()
        }
        _ => urdf_field.into(),
    };
    Error::invalid(path, e.to_string())
}

/// Which URDF text a loader error is about: a text that does not parse, or the one whose link
/// and joint names the message quotes (the hand's names when it does); default the arm.
fn urdf_field_of(e: &KinematicsError, arm: &str, hand: Option<&str>) -> &'static str {
    let Some(hand) = hand else { return "$.urdf" };
    if matches!(
        e,
        KinematicsError::MalformedUrdf { .. } | KinematicsError::UrdfTooLarge { .. }
    ) {
        return if kinematics::urdf::parse_urdf(arm).is_ok() {
            "$.hand_urdf"
        } else {
            "$.arm_urdf"
        };
    }
    let msg = e.to_string();
    let Ok(h) = kinematics::urdf::parse_urdf(hand) else {
        return "$.hand_urdf";
    };
    let quoted = |n: &str| msg.contains(&format!("'{n}'"));
    if h.links.iter().any(|l| quoted(&l.name)) || h.joints.iter().any(|j| quoted(&j.name)) {
        "$.hand_urdf"
    } else {
        "$.arm_urdf"
    }
}

pub fn frame_of(system: &System, name: &str, path: &str) -> Result<FrameId, Error> {
    system
        .model
        .frame_id(name)
        .ok_or_else(|| Error::invalid(path, format!("frame '{name}' does not exist in this robot")))
}

pub fn finite_array<const N: usize>(v: &[f64; N], path: &str) -> Result<(), Error> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(Error::invalid(
            format!("{path}[{i}]"),
            "must be a finite number",
        )),
        None => Ok(()),
    }
}

/// Largest coordinate of an IK target or point (m): far beyond any arm, and small enough that
/// every residual stays finite (a target at 1e305 m made the errors infinite, which JSON cannot
/// carry).
pub const MAX_TARGET_COORDINATE: f64 = 1e3;

/// Finite, and every coordinate within ±[`MAX_TARGET_COORDINATE`].
fn within_reach_of_any_robot(v: &[f64; 3], path: &str) -> Result<(), Error> {
    finite_array(v, path)?;
    match v.iter().position(|x| x.abs() > MAX_TARGET_COORDINATE) {
        Some(i) => Err(Error::invalid(
            format!("{path}[{i}]"),
            format!("must be within ±{MAX_TARGET_COORDINATE} m, got {}", v[i]),
        )),
        None => Ok(()),
    }
}

/// Unit quaternion from `[w, x, y, z]` (normalised; zero norm rejected).
pub fn quaternion(q: &[f64; 4], path: &str) -> Result<UnitQuaternion<f64>, Error> {
    finite_array(q, path)?;
    let quat = Quaternion::new(q[0], q[1], q[2], q[3]);
    if quat.norm() < 1e-9 {
        return Err(Error::invalid(
            path,
            "quaternion [w, x, y, z] must not be zero",
        ));
    }
    Ok(UnitQuaternion::from_quaternion(quat))
}

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SeedDto {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct IkRequest {
    /// Frame to place (default: the wrist frame, where the hand mounts).
    pub frame: Option<String>,
    /// Point rigidly attached to the frame, in frame coordinates (default the origin).
    #[schema(min_items = 3, max_items = 3)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub point: Option<[f64; 3]>,
    /// Target position of the point, metres, world frame; each coordinate within ±1000 m.
    #[schema(min_items = 3, max_items = 3)]
    #[serde(deserialize_with = "crate::wire::exact")]
    pub position: [f64; 3],
    /// Target orientation `[w, x, y, z]`; omit for a position-only target.
    #[schema(min_items = 4, max_items = 4)]
    #[serde(default, deserialize_with = "crate::wire::exact")]
    pub orientation: Option<[f64; 4]>,
    /// Start configuration (default: mid-range); joints not named keep mid-range values.
    pub seed: Option<SeedDto>,
    /// Weight of the position residual, 0 to 1e6; it and `orientation_weight` cannot both be 0.
    #[schema(minimum = 0, maximum = 1e6)]
    pub position_weight: Option<f64>,
    /// Weight of the orientation residual, 0 to 1e6; above 0 only with an `orientation` target.
    #[schema(minimum = 0, maximum = 1e6)]
    pub orientation_weight: Option<f64>,
    #[schema(minimum = 0)]
    pub position_tolerance: Option<f64>,
    #[schema(minimum = 0)]
    pub orientation_tolerance: Option<f64>,
    /// The solver's CPU-time budget in ms (default 5, at most 2000): time the thread is
    /// descheduled is not charged, and the wall time of one solve is capped at 4 × the budget.
    #[schema(minimum = 0, maximum = 2000)]
    pub time_budget_ms: Option<f64>,
    /// Most random restarts, 0 to 100000.
    #[schema(maximum = 100000)]
    pub max_restarts: Option<usize>,
    /// Seed of the random restarts (default 0): the same request gives the same answer.
    pub random_seed: Option<u64>,
}

/// The IK outcome. An unreachable target is `success: false` with the best residuals.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct IkResponse {
    pub success: bool,
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
    pub position_error: f64,
    pub orientation_error: f64,
    pub iterations: usize,
    pub restarts: usize,
    pub elapsed_ms: f64,
}

/// Validates an IK request into a target, seed and options.
pub fn parse_ik(
    s: &System,
    body: &IkRequest,
    base: &str,
) -> Result<(IkTarget, Vec<f64>, IkOptions, u64), Error> {
    let frame = match &body.frame {
        Some(n) => frame_of(s, n, &format!("{base}.frame"))?,
        None => s.wrist_frame,
    };
    let point = body.point.unwrap_or([0.0; 3]);
    within_reach_of_any_robot(&point, &format!("{base}.point"))?;
    within_reach_of_any_robot(&body.position, &format!("{base}.position"))?;
    let rotation = match &body.orientation {
        Some(q) => quaternion(q, &format!("{base}.orientation"))?,
        None => UnitQuaternion::identity(),
    };
    let mut opts = IkOptions::default();
    if body.orientation.is_none() {
        opts.orientation_weight = 0.0;
    }
    let nonneg = |v: Option<f64>, name: &str, dflt: f64| -> Result<f64, Error> {
        match v {
            None => Ok(dflt),
            Some(x) if x.is_finite() && x >= 0.0 => Ok(x),
            Some(x) => Err(Error::invalid(
                format!("{base}.{name}"),
                format!("must be a finite number >= 0, got {x}"),
            )),
        }
    };
    opts.position_weight = nonneg(
        body.position_weight,
        "position_weight",
        opts.position_weight,
    )?;
    opts.orientation_weight = nonneg(
        body.orientation_weight,
        "orientation_weight",
        opts.orientation_weight,
    )?;
    // Weights near f64::MAX overflow the weighted residuals (NaN errors were answered as null).
    for (name, w) in [
        ("position_weight", opts.position_weight),
        ("orientation_weight", opts.orientation_weight),
    ] {
        if w > MAX_IK_WEIGHT {
            return Err(Error::invalid(
                format!("{base}.{name}"),
                format!("at most {MAX_IK_WEIGHT:e}, got {w}"),
            ));
        }
    }
    if body.orientation.is_none() && opts.orientation_weight > 0.0 {
        return Err(Error::invalid(
            format!("{base}.orientation_weight"),
            "needs an orientation target",
        ));
    }
    if opts.position_weight == 0.0 && opts.orientation_weight == 0.0 {
        return Err(Error::invalid(
            format!("{base}.position_weight"),
            "position and orientation weights cannot both be 0",
        ));
    }
    opts.position_tolerance = nonneg(
        body.position_tolerance,
        "position_tolerance",
        opts.position_tolerance,
    )?;
    opts.orientation_tolerance = nonneg(
        body.orientation_tolerance,
        "orientation_tolerance",
        opts.orientation_tolerance,
    )?;
    let budget = nonneg(body.time_budget_ms, "time_budget_ms", 5.0)?;
    if budget > MAX_IK_BUDGET_MS {
        return Err(Error::invalid(
            format!("{base}.time_budget_ms"),
            format!("at most {MAX_IK_BUDGET_MS} ms"),
        ));
    }
    opts.time_budget = Duration::from_secs_f64(budget / 1000.0);
    if let Some(r) = body.max_restarts {
        if r > 100_000 {
            return Err(Error::invalid(
                format!("{base}.max_restarts"),
                "at most 100000",
            ));
        }
        opts.max_restarts = r;
    }
    let neutral = s.model.neutral();
    let seed = match &body.seed {
        None => neutral,
        Some(sd) => JointVector::from_named_with_defaults(
            &s.model,
            &sd.joint_names,
            &sd.positions,
            Some(&neutral),
        )
        .map_err(|e| {
            let f = if matches!(
                e,
                KinematicsError::NonFiniteJointValue { .. } | KinematicsError::WrongLength { .. }
            ) {
                "positions"
            } else {
                "joint_names"
            };
            Error::invalid(format!("{base}.seed.{f}"), e.to_string())
        })?
        .into_vec(),
    };
    let target = IkTarget {
        frame,
        point_in_frame: Vector3::from(point),
        pose: Isometry3::from_parts(Translation3::from(Vector3::from(body.position)), rotation),
    };
    Ok((target, seed, opts, body.random_seed.unwrap_or(0)))
}

/// One IK request for robot `id`, solved off the async runtime.
pub async fn ik(ctx: &Context, id: &str, body: &IkRequest) -> Result<IkResponse, Error> {
    let s = system(ctx, id).await?;
    let (target, seed, opts, rseed) = parse_ik(&s, body, "$")?;
    tokio::task::spawn_blocking(move || solve_ik(&s, &target, &seed, &opts, rseed))
        .await
        .map_err(Error::internal)
}

/// One IK solve, as the API and the CLI report it.
pub fn solve_ik(
    s: &System,
    target: &IkTarget,
    seed: &[f64],
    opts: &IkOptions,
    random_seed: u64,
) -> IkResponse {
    let mut rng = ChaCha8Rng::seed_from_u64(random_seed);
    let r = IkSolver::new(&s.model).solve(&s.model, target, seed, opts, &mut rng);
    IkResponse {
        success: r.success,
        joint_names: s.model.joint_names().to_vec(),
        positions: r.q,
        position_error: r.position_error,
        orientation_error: r.orientation_error,
        iterations: r.iterations,
        restarts: r.restarts,
        elapsed_ms: r.elapsed.as_secs_f64() * 1000.0,
    }
}

/// `reachgrasp ik --targets` input: a list of IK requests, or `{"targets": [...]}`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub enum IkBatchFile {
    List(Vec<IkRequest>),
    Wrapped { targets: Vec<IkRequest> },
}

#[derive(Debug, Serialize, Deserialize)]
pub struct IkBatchStats {
    pub count: usize,
    pub solved: usize,
    pub success_rate: f64,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
}

#[derive(Debug, Serialize, Deserialize)]
pub struct IkBatchReport {
    pub robot: String,
    pub solutions: Vec<IkResponse>,
    pub stats: IkBatchStats,
}

/// Solves every target with the one IK use case's solver; target `i` without `random_seed` uses seed `i`.
/// Validation errors name the target (`$[3].orientation`).
pub fn ik_batch(robot: &str, s: &System, file: IkBatchFile) -> Result<IkBatchReport, Error> {
    let targets = match file {
        IkBatchFile::List(t) | IkBatchFile::Wrapped { targets: t } => t,
    };
    let mut solutions = Vec::with_capacity(targets.len());
    for (i, t) in targets.iter().enumerate() {
        let (target, seed, opts, rseed) = parse_ik(s, t, &format!("$[{i}]"))?;
        let rseed = if t.random_seed.is_some() {
            rseed
        } else {
            i as u64
        };
        solutions.push(solve_ik(s, &target, &seed, &opts, rseed));
    }
    let mut times: Vec<f64> = solutions.iter().map(|r| r.elapsed_ms).collect();
    times.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        if times.is_empty() {
            0.0
        } else {
            times[((times.len() - 1) as f64 * p).round() as usize]
        }
    };
    let solved = solutions.iter().filter(|r| r.success).count();
    let count = solutions.len();
    Ok(IkBatchReport {
        robot: robot.to_owned(),
        stats: IkBatchStats {
            count,
            solved,
            success_rate: if count == 0 {
                0.0
            } else {
                solved as f64 / count as f64
            },
            median_ms: pct(0.5),
            p95_ms: pct(0.95),
            max_ms: times.last().copied().unwrap_or(0.0),
        },
        solutions,
    })
}
