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

use super::{ApiError, AppState, Path, Problem, Query};
use crate::figures::{
    self, EllipsoidKind, ExecutionSample, Figure, FigureError, GraspInput, MappingInput, PcaPath,
    View,
};
use crate::motion::TrajectoryOptions;
use crate::service::figures as service;

pub const SVG: &str = "image/svg+xml";

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(robot_plot))
        .routes(routes!(demonstration_plot))
        .routes(routes!(grasp_plot))
        .routes(routes!(mapping_plot))
        .routes(routes!(model_plot))
        .routes(routes!(trajectory_plot))
        .routes(routes!(execution_plot))
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
    #[param(minimum = -180, maximum = 180)]
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    #[param(minimum = -90, maximum = 90)]
    pub elevation: Option<f64>,
    /// Independent joint values, comma-separated, in the robot's joint order (default: the
    /// neutral configuration). Each must be within its joint limits. How many values and
    /// their limits depend on the robot (`GET /v1/robots/{id}`), so the schema states only
    /// the form: comma-separated decimal numbers.
    #[param(
        pattern = r"^ *[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][-+]?[0-9]+)? *(, *[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][-+]?[0-9]+)? *)*$"
    )]
    pub q: Option<String>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ViewQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    #[param(minimum = -180, maximum = 180)]
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    #[param(minimum = -90, maximum = 90)]
    pub elevation: Option<f64>,
}

/// The values of `ellipsoid` (documentation only: the handler reads the string and answers 400
/// naming the parameter for any other value).
#[derive(utoipa::ToSchema)]
#[schema(rename_all = "snake_case")]
#[allow(dead_code)]
pub enum EllipsoidParam {
    Velocity,
    Force,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct GraspPlotQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    #[param(minimum = -180, maximum = 180)]
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    #[param(minimum = -90, maximum = 90)]
    pub elevation: Option<f64>,
    /// `velocity` or `force` (default: the kind of the first task direction, else velocity).
    #[param(value_type = Option<EllipsoidParam>, inline)]
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
    let system = crate::service::robots::system(&state, &id).await?;
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
        (status = 409, description = "The demonstration has too few frames to plot", body = Problem, content_type = "application/problem+json"),
    ))]
async fn demonstration_plot(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Response, ApiError> {
    let id = id.to_string();
    let (title, frames) = service::demonstration(&state, &id).await?;
    render(move || Ok(figures::demonstration_figure(&title, &frames)?)).await
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
    let service::StoredGrasp {
        robot,
        object,
        settings,
        result,
    } = service::grasp(&state, &id).await?;
    let robots = state.config.robots.clone();
    render(move || {
        let system = crate::service::grasps::load_system(&robots, &robot)?;
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

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct MappingPlotQuery {
    /// Camera azimuth about the vertical axis, degrees, -180 to 180 (default 35).
    #[param(minimum = -180, maximum = 180)]
    pub azimuth: Option<f64>,
    /// Camera elevation, degrees, -90 to 90 (default 20).
    #[param(minimum = -90, maximum = 90)]
    pub elevation: Option<f64>,
    /// Which mapped demonstration, 0-based in the mapping's order (default 0); a mapping holds
    /// at most [`crate::service::mappings::MAX_DEMONSTRATIONS`] (500).
    #[param(minimum = 0, maximum = 499)]
    pub demo: Option<usize>,
    /// Robot postures drawn along the motion, 0 to 10 (default 3).
    #[param(minimum = 0, maximum = 10)]
    pub postures: Option<usize>,
}

/// Fig. 2: human fingertip and elbow paths (registered into the robot base frame) against the
/// robot's fingertip and elbow paths, with a few robot postures along the way.
#[utoipa::path(get, path = "/v1/mappings/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Mapping id"), MappingPlotQuery),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 400, description = "View angle, demonstration index or posture count out of range", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown mapping", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The mapping has not succeeded", body = Problem, content_type = "application/problem+json"),
    ))]
async fn mapping_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<MappingPlotQuery>,
) -> Result<Response, ApiError> {
    let view = View::new(q.azimuth, q.elevation)?;
    let postures = q.postures.unwrap_or(3);
    if postures > 10 {
        return Err(ApiError::invalid_parameter(
            "postures",
            format!("must be between 0 and 10, got {postures}"),
        ));
    }
    let index = q.demo.unwrap_or(0);
    let service::MappedDemoFigure {
        system,
        human,
        demo,
    } = service::mapping(&state, &id, index)
        .await?
        .map_err(|total| {
            ApiError::invalid_parameter(
                "demo",
                format!("must be between 0 and {}, got {index}", (total - 1).max(0)),
            )
        })?;
    render(move || {
        let scene = figures::mapping_scene(&MappingInput {
            system: &system,
            human: &human,
            trajectory: &demo.trajectory,
            postures,
        })?;
        Ok(figures::render_scene(&scene, view)?)
    })
    .await
}

/// Most demonstrated (and as many generated) paths drawn in a model figure.
const MODEL_PATHS: usize = 10;

/// Explained variance per principal component of the arm manifold, and demonstrated vs
/// generated paths in the plane of its first two components.
#[utoipa::path(get, path = "/v1/models/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Model id")),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 404, description = "Unknown model", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The model is not trained", body = Problem, content_type = "application/problem+json"),
    ))]
async fn model_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let (robot, model, demos) = service::model(&state, &id, MODEL_PATHS).await?;
    let title = format!("model {} ({})", &id[..8.min(id.len())], robot);
    render(move || {
        let Some(arm) = model.manifolds.first() else {
            return Err(FigureError::Empty {
                what: "the model".into(),
            }
            .into());
        };
        let n = model.n_joints;
        let d = arm.pca.d();
        let mut q = vec![0.0; arm.joints.len()];
        let mut y = vec![0.0; d.max(2)];
        let mut project = |row: &[f64]| {
            for (qi, &j) in q.iter_mut().zip(&arm.joints) {
                *qi = row[j];
            }
            arm.pca.project(&q, &mut y);
            (y[0], if d > 1 { y[1] } else { 0.0 })
        };
        let mut paths = Vec::new();
        for demo in &demos {
            let t = &demo.trajectory;
            if t.nq() != n || t.times.is_empty() {
                continue;
            }
            let rows: Vec<&[f64]> = (0..t.times.len()).map(|k| t.frame(k)).collect();
            paths.push(PcaPath {
                generated: false,
                points: rows.iter().map(|r| project(r)).collect(),
            });
            let (start, goal) = (rows[0], rows[rows.len() - 1]);
            // A start or goal outside the model's regions is refused; that demo has no twin.
            if let Ok(p) = model.path_positions(start, goal, &TrajectoryOptions::default()) {
                paths.push(PcaPath {
                    generated: true,
                    points: p.chunks_exact(n).map(&mut project).collect(),
                });
            }
        }
        let ev: Vec<f64> = arm
            .pca
            .all_explained_variance
            .iter()
            .take(10)
            .copied()
            .collect();
        let title = format!("{title}: arm manifold, {d} components kept");
        Ok(figures::model_figure(&title, &ev, &paths)?)
    })
    .await
}

/// Joint positions over time.
#[utoipa::path(get, path = "/v1/trajectories/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Trajectory id")),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 404, description = "Unknown trajectory", body = Problem, content_type = "application/problem+json"),
    ))]
async fn trajectory_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let t = crate::service::trajectories::get(&state, &id).await?;
    let title = format!(
        "trajectory {} ({}, {:.2} s)",
        &id[..8.min(id.len())],
        t.robot,
        t.duration
    );
    render(move || {
        Ok(figures::trajectory_figure(
            &title,
            &t.joint_names,
            &t.points,
        )?)
    })
    .await
}

/// Planned (dashed) vs measured joint positions over time: the planned trajectory (open loop)
/// and the execution's measured state history (`GET /v1/executions/{id}/feedback`). A
/// closed-loop execution has no planned trajectory; its figure shows the measured positions only
/// and says so in its title.
#[utoipa::path(get, path = "/v1/executions/{id}/plot.svg", tag = "figures",
    params(("id" = String, Path, description = "Execution id")),
    responses(
        (status = 200, description = "SVG figure", body = String, content_type = "image/svg+xml"),
        (status = 404, description = "Unknown execution", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Nothing planned or measured yet", body = Problem, content_type = "application/problem+json"),
    ))]
async fn execution_plot(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let (row, joint_names, planned, history) = service::execution(&state, &id).await?;
    let short = &id[..8.min(id.len())];
    let mode = row.mode.as_str().replace('_', " ");
    let title = if planned.is_empty() {
        // The title is the figure's legend for this: the series are all measured.
        format!(
            "execution {short} ({}): {mode}, measured only (no planned trajectory)",
            row.state
        )
    } else if history.is_empty() {
        format!(
            "execution {short} ({}, {mode}, {}): planned only, nothing measured yet",
            row.robot, row.state
        )
    } else {
        format!(
            "execution {short} ({}, {mode}, {}): planned (dashed) vs measured",
            row.robot, row.state
        )
    };
    render(move || {
        let measured: Vec<ExecutionSample> = history
            .samples()
            .map(|s| ExecutionSample {
                t: s.t,
                positions: s.positions.to_vec(),
            })
            .collect();
        Ok(figures::execution_figure(
            &title,
            &joint_names,
            &planned,
            &measured,
        )?)
    })
    .await
}
