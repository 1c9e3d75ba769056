//! Figures as SVG (`GET /v1/<resource>/{id}/plot.svg`): thin handlers that load the stored data
//! and call the pure builders of [`crate::figures`]. View angles are query parameters, checked
//! before anything is drawn (out of range: 400 problem+json naming the parameter).

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::grasps::GraspSettingsDto;
use super::{ApiError, AppState, Path, Problem, Query};
use crate::figures::{self, EllipsoidKind, Figure, FigureError, GraspInput, View};
use crate::grasp::{GraspResult, ObjectSpec};
use crate::human::unpack_frames;
use crate::store::{blob, demonstrations as demo_repo, grasps as grasp_repo};

pub const SVG: &str = "image/svg+xml";

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(robot_plot))
        .routes(routes!(demonstration_plot))
        .routes(routes!(grasp_plot))
}

impl From<FigureError> for ApiError {
    fn from(e: FigureError) -> Self {
        match &e {
            FigureError::OutOfRange { param, .. } | FigureError::WrongLength { param, .. } => {
                ApiError::invalid_parameter(*param, e.to_string())
            }
            FigureError::Empty { .. } => ApiError::conflict(e.to_string()),
            _ => ApiError::internal(anyhow::Error::new(e)),
        }
    }
}

/// An SVG document response.
pub fn svg(fig: Figure) -> Response {
    (
        [
            (header::CONTENT_TYPE, SVG),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        fig.svg,
    )
        .into_response()
}

/// Runs a figure builder off the async workers (FK and drawing are CPU work).
pub async fn render<F>(f: F) -> Result<Response, ApiError>
where
    F: FnOnce() -> Result<Figure, ApiError> + Send + 'static,
{
    let fig = tokio::task::spawn_blocking(f)
        .await
        .map_err(ApiError::internal)??;
    Ok(svg(fig))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PostureQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    pub elevation: Option<f64>,
    /// Independent joint values, comma-separated, in the robot's joint order (default: the
    /// neutral configuration). Each must be within its joint limits.
    pub q: Option<String>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ViewQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    pub elevation: Option<f64>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct GraspPlotQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    pub elevation: Option<f64>,
    /// `velocity` or `force` (default: the kind of the first task direction, else velocity).
    pub ellipsoid: Option<String>,
}

/// Parses `q=0.1,0.2,...` and checks each value against the joint limits.
pub fn parse_q(model: &crate::kinematics::Model, text: Option<&str>) -> Result<Vec<f64>, ApiError> {
    let Some(text) = text else {
        return Ok(model.neutral());
    };
    let mut q = Vec::with_capacity(model.nq());
    for (i, s) in text.split(',').enumerate() {
        let v: f64 = s.trim().parse().map_err(|_| {
            ApiError::invalid_parameter("q", format!("q[{i}] = {s:?} is not a number"))
        })?;
        q.push(v);
    }
    if q.len() != model.nq() {
        return Err(ApiError::invalid_parameter(
            "q",
            format!(
                "must hold {} comma-separated values ({}), got {}",
                model.nq(),
                model.joint_names().join(", "),
                q.len()
            ),
        ));
    }
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    for (i, v) in q.iter().enumerate() {
        if !v.is_finite() || *v < lo[i] || *v > hi[i] {
            return Err(ApiError::invalid_parameter(
                "q",
                format!(
                    "q[{i}] ({}) = {v} is outside its limits [{}, {}]",
                    model.joint_names()[i],
                    lo[i],
                    hi[i]
                ),
            ));
        }
    }
    Ok(q)
}

/// The arm and hand links of a robot at a configuration (forward kinematics).
#[utoipa::path(get, path = "/v1/robots/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Robot id"), PostureQuery),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 400, description = "View angle or joint value out of range", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown robot", body = Problem, content_type = "application/problem+json"),
    ))]
async fn robot_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<PostureQuery>,
) -> Result<Response, ApiError> {
    let view = View::new(q.azimuth, q.elevation)?;
    let system = super::robots::system(&state, &id).await?;
    let config = parse_q(&system.model, q.q.as_deref())?;
    render(move || {
        let scene = figures::posture_scene(&system, &config)?;
        Ok(figures::render_scene(&scene, view)?)
    })
    .await
}

/// Wrist speed and grip aperture over time.
#[utoipa::path(get, path = "/v1/demonstrations/{id}/plot.svg", tag = "figures",
    params(("id" = Uuid, Path, description = "Demonstration id")),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 404, description = "Unknown demonstration", body = Problem, content_type = "application/problem+json"),
    ))]
async fn demonstration_plot(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Response, ApiError> {
    let id = id.to_string();
    let (title, frames) = load_demonstration(&state, &id).await?;
    render(move || Ok(figures::demonstration_figure(&title, &frames)?)).await
}

/// A stored demonstration's title and derived frames.
pub async fn load_demonstration(
    state: &AppState,
    id: &str,
) -> Result<(String, Vec<crate::human::HumanFrame>), ApiError> {
    let row = demo_repo::get(&state.db, id)
        .await?
        .ok_or_else(|| ApiError::not_found("demonstration", id))?;
    let bytes = demo_repo::frames(&state.db, id)
        .await?
        .ok_or_else(|| ApiError::not_found("demonstration", id))?;
    let array =
        blob::decode::<f64>(&bytes).map_err(|e| ApiError::internal(anyhow::Error::new(e)))?;
    let (frames, _) = unpack_frames(&array.data)?;
    let subject = row.subject()?.id;
    let object = row.object()?.name;
    let title = format!(
        "{subject} reaching for the {object} (position {}, trial {})",
        row.position_index, row.trial
    );
    Ok((title, frames))
}

/// Fig. 3-6: the arm and hand at the grasp, the object, the contact points, the task
/// directions and the arm's velocity or force ellipsoid at the grasp frame.
#[utoipa::path(get, path = "/v1/grasps/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Grasp id"), GraspPlotQuery),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 400, description = "View angle out of range or unknown ellipsoid", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown grasp", body = Problem, content_type = "application/problem+json"),
    ))]
async fn grasp_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<GraspPlotQuery>,
) -> Result<Response, ApiError> {
    let view = View::new(q.azimuth, q.elevation)?;
    let ellipsoid = match q.ellipsoid.as_deref() {
        None => None,
        Some("velocity") => Some(EllipsoidKind::Velocity),
        Some("force") => Some(EllipsoidKind::Force),
        Some(other) => {
            return Err(ApiError::invalid_parameter(
                "ellipsoid",
                format!("must be velocity or force, got {other:?}"),
            ));
        }
    };
    let row = grasp_repo::get_grasp(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("grasp", &id))?;
    let object: ObjectSpec = serde_json::from_str(&row.object).map_err(ApiError::internal)?;
    let settings: GraspSettingsDto =
        serde_json::from_str(&row.request).map_err(ApiError::internal)?;
    let result: GraspResult = serde_json::from_str(&row.result).map_err(ApiError::internal)?;
    let robots = state.config.robots.clone();
    render(move || {
        let system = super::grasps::load_system(&robots, &row.robot)?;
        let dirs: Vec<([f64; 3], _)> = settings
            .task_directions
            .iter()
            .map(|t| {
                let d = nalgebra::Vector3::from(t.direction);
                let n = d.norm().max(1e-12);
                ((d / n).into(), t.kind)
            })
            .collect();
        let scene = figures::grasp_scene(&GraspInput {
            system: &system,
            result: &result,
            object: &object,
            task_directions: &dirs,
            ellipsoid,
        })?;
        Ok(figures::render_scene(&scene, view)?)
    })
    .await
}
