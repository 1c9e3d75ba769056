//! `GET /healthz` (the process answers), `GET /readyz` (the database answers) and
//! `GET /v1/status` (seeding progress, default models, jobs, workers).

use std::time::Duration;

use axum::extract::State;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, Json, Problem};
use crate::service::status::StatusDto;

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// `ok` or `ready`.
    pub status: String,
    /// Service version.
    pub version: String,
}

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(healthz))
        .routes(routes!(readyz))
        .routes(routes!(status))
}

/// The service at a glance: first-start seeding's progress, each robot's default model (trained
/// since when, being seeded, or missing), jobs by state and connected bridge workers.
#[utoipa::path(get, path = "/v1/status", tag = "health",
    responses((status = 200, description = "The service's state", body = StatusDto)))]
async fn status(State(state): State<AppState>) -> Result<Json<StatusDto>, ApiError> {
    Ok(Json(crate::service::status::status(&state).await?))
}

/// Liveness: the process is up and serving requests.
#[utoipa::path(get, path = "/healthz", tag = "health",
    responses((status = 200, description = "The process is alive", body = Health)))]
async fn healthz() -> Json<Health> {
    Json(Health {
        status: "ok".to_owned(),
        version: env!("CARGO_PKG_VERSION").to_owned(),
    })
}

/// Readiness: the database answers a query within two seconds.
#[utoipa::path(get, path = "/readyz", tag = "health",
    responses(
        (status = 200, description = "Ready to serve", body = Health),
        (status = 503, description = "The database does not answer", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn readyz(State(state): State<AppState>) -> Result<Json<Health>, ApiError> {
    crate::service::ready(&state, Duration::from_secs(2)).await?;
    Ok(Json(Health {
        status: "ready".to_owned(),
        version: env!("CARGO_PKG_VERSION").to_owned(),
    }))
}
