//! HTTP API: one router per resource, DTOs with utoipa schemas, problem+json errors.
//!
//! # Adding a resource (e.g. `robots`)
//!
//! 1. **Migration.** Add `migrations/000N_<resource>.sql` with your contract number (0002 robots,
//!    0003 demonstrations, 0004 objects+grasps, 0005 mappings, 0006 models+trajectories,
//!    0007 bridges+executions). Never edit an applied migration. Ids are `TEXT` UUIDs,
//!    timestamps `TEXT` from [`crate::store::now`], numeric arrays `BLOB`s from
//!    [`crate::store::blob`]; reference `jobs(id)` if your rows come from a job.
//! 2. **Repository.** `src/store/<resource>.rs` with `sqlx::query`/`query_as` +
//!    `#[derive(sqlx::FromRow)]` rows (never the `query!` macros). Multi-row writes use a
//!    transaction: `let mut tx = store::begin_write(&pool).await?; ...execute(&mut *tx)...; tx.commit().await?`
//!    (`BEGIN IMMEDIATE`: a deferred `pool.begin()` that reads before it writes fails under
//!    concurrent writers).
//! 3. **DTOs and handlers.** `src/api/<resource>.rs`:
//!    ```ignore
//!    use utoipa_axum::{router::OpenApiRouter, routes};
//!    use super::{ApiError, AppState, Json, Path, Problem, Query};
//!
//!    #[derive(serde::Deserialize, utoipa::ToSchema)]
//!    pub struct CreateRobot { pub name: String, pub urdf: String }
//!
//!    pub fn router() -> OpenApiRouter<AppState> {
//!        OpenApiRouter::new()
//!            .routes(routes!(list_robots, create_robot))   // same path, several methods
//!            .routes(routes!(get_robot))
//!    }
//!
//!    #[utoipa::path(post, path = "/v1/robots", tag = "robots", request_body = CreateRobot,
//!        responses((status = 201, body = RobotDto),
//!                  (status = 422, body = Problem, content_type = "application/problem+json")))]
//!    async fn create_robot(State(s): State<AppState>, Json(body): Json<CreateRobot>)
//!        -> Result<(StatusCode, Json<RobotDto>), ApiError> { ... }
//!    ```
//!    Always use [`Json`], [`Path`] and [`Query`] from this module (not axum's): their
//!    rejections are problem+json with the JSONPath of the bad field. Handlers: extract → parse
//!    into domain types → call a use case of [`crate::service`] (numerics, then one
//!    transaction per unit of work) → DTO. New use cases belong in `src/service/`, never here:
//!    the CLI, seeding and the dashboard must be able to call them without this module.
//! 4. **Errors.** Keep one `#[non_exhaustive]` thiserror enum per layer and convert it at the
//!    edge with `impl From<RobotError> for ApiError` in your api file (use cases return
//!    [`crate::service::Error`], rendered by `impl From<service::Error> for ApiError`; never
//!    branch on an `ApiError`'s status or field paths): bad input →
//!    [`ApiError::invalid_field`] / [`ApiError::validation`] (422, JSONPath like
//!    `$.joints[2].position` in each [`FieldError`]), unknown id → [`ApiError::not_found`],
//!    duplicates/state conflicts → [`ApiError::conflict`], bugs → [`ApiError::internal`] (logged,
//!    never leaked). `?` on `sqlx::Error` gives 409 for unique violations and 500 otherwise.
//! 5. **Register** your router in [`openapi_router`] (`.merge(robots::router())`) and add your
//!    tag to [`ApiDoc`]. DTO schemas referenced by `utoipa::path` are collected automatically.
//!    Then regenerate the committed spec: `cargo run -- openapi > openapi/openapi.json`
//!    (the `openapi_document_is_up_to_date` test fails until you do).
//! 6. **Long work** runs as a job, never inline in the handler: validate first, then
//!    `state.jobs.submit("mapping", move |ctx| { ... })` and answer `202 Accepted` with the
//!    [`JobRecord`](crate::jobs::JobRecord) and `Location: /v1/jobs/{id}`. The closure runs on
//!    the blocking pool; its [`JobOutput`](crate::jobs::JobOutput) persists the result in the
//!    transaction that marks the job succeeded. See [`crate::jobs`] for a full example.
//!    Short CPU work (one IK, one grasp) can run inline with
//!    `tokio::task::spawn_blocking(move || ...)`, so it never blocks an async worker.
//! 7. **Shared state.** Need something process-wide? Add a cloneable field (`Arc<...>`) to the
//!    service [`Context`](crate::service::Context) and initialise it in
//!    [`crate::app::App::build`].
//! 8. **Tests.** Black-box tests in `tests/api/<resource>.rs` (add `mod <resource>;` to
//!    `tests/api/main.rs`) using `helpers::spawn_app()`.

pub mod bridges;
pub mod contract;
pub mod demonstrations;
pub mod error;
pub mod executions;
pub mod extract;
pub mod figures;
pub mod grasps;
pub mod health;
pub mod jobs;
pub mod mappings;
pub mod middleware;
pub mod models;
pub mod page;
pub mod plans;
pub mod retarget;
pub mod robots;
pub mod testing;
pub mod verifications;

use axum::Router;
use axum::extract::DefaultBodyLimit;
use axum::http::{Method, Request, Uri};
use axum::response::IntoResponse;
use tower::ServiceBuilder;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::{DefaultOnResponse, TraceLayer};
use tracing::Level;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_swagger_ui::SwaggerUi;

pub use error::{ApiError, FieldError, Problem};
pub use extract::{Json, Path, Query};

/// The answer to a create: `status` (201, or 200 for an idempotent re-upload) with
/// `Location: location` and the stored resource as the body.
pub(crate) fn created<T: serde::Serialize>(
    status: axum::http::StatusCode,
    location: String,
    body: T,
) -> axum::response::Response {
    (
        status,
        [(axum::http::header::LOCATION, location)],
        Json(body),
    )
        .into_response()
}

/// The answer to submitted long work: `202 Accepted` with the job, `Location` the job and, when
/// the work fills a resource that exists already (a pending mapping or model),
/// `Content-Location` that resource.
pub(crate) fn accepted_job(
    job: crate::jobs::JobRecord,
    content_location: Option<String>,
) -> axum::response::Response {
    use axum::http::header;
    let mut res = (
        axum::http::StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/jobs/{}", job.id))],
        Json(job),
    )
        .into_response();
    if let Some(v) = content_location.and_then(|c| axum::http::HeaderValue::try_from(c).ok()) {
        res.headers_mut().insert(header::CONTENT_LOCATION, v);
    }
    res
}

/// The handlers' state is the service context: a handler parses, calls a use case, renders.
pub use crate::service::Context as AppState;

/// The OpenAPI document's static part; paths and schemas come from the routers.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "reachgrasp",
        description = "Humanlike, task-specific reaching and grasping for redundant robot arms \
                       and low-complexity hands. Errors are RFC 7807 `application/problem+json` \
                       documents whose `type` is `urn:reachgrasp:problem:<slug>`."
    ),
    tags(
        (name = "health", description = "Liveness and readiness"),
        (name = "jobs", description = "Long-running computations: status, progress (SSE), cancellation"),
        (name = "robots", description = "Arm-hand systems: library, FK, Jacobians, IK, manipulability"),
        (name = "demonstrations", description = "Human reach-to-grasp demonstrations: upload (JSON or CSV), derived kinematics, synthetic studies"),
        (name = "grasps", description = "Graspable objects and task-specific grasps (paper eq. 10-29)"),
        (name = "mappings", description = "Human demonstrations mapped onto a robot arm-hand system (paper eq. 1-7): joint trajectories and per-frame metrics"),
        (name = "models", description = "Humanlike motion models: PCA manifolds + certified navigation functions (paper eq. 8-9), closed-loop law"),
        (name = "trajectories", description = "Humanlike trajectories generated from a motion model, with Cartesian paths"),
        (name = "executions", description = "Trajectories and closed-loop motions executed by bridge workers"),
        (name = "bridges", description = "Bridge workers: connected robots and the WebSocket protocol"),
        (name = "figures", description = "Figures as SVG (paper Fig. 2-6 and more); 3-D views take azimuth/elevation"),
        (name = "plans", description = "One request from object and task to a humanlike motion ending in a task-specific grasp, and its execution"),
    ),
    components(schemas(Problem, FieldError))
)]
pub struct ApiDoc;

/// Every documented route, with its OpenAPI paths. Register new resources here.
pub fn openapi_router() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(health::router())
        .merge(jobs::router())
        .merge(robots::router())
        .merge(retarget::router())
        .merge(demonstrations::router())
        .merge(grasps::router())
        .merge(mappings::router())
        .merge(models::router())
        .merge(executions::router())
        .merge(bridges::router())
        .merge(plans::router())
        .merge(verifications::router())
        .merge(figures::router())
}

/// The OpenAPI 3.1 document (`/openapi.json`, `reachgrasp openapi`, `openapi/openapi.json`).
pub fn openapi() -> serde_json::Value {
    contract::complete(openapi_router().split_for_parts().1)
}

/// The complete application: documented routes, `/openapi.json`, Swagger UI at `/docs`, the
/// `pages` of another edge (the dashboard; the caller composes them so that this layer does not
/// import its sibling), problem+json fallbacks, and the request layers (request id, tracing,
/// panic catching, timeout, body size and idle limits, problem+json safety net).
pub fn router(state: AppState, pages: Router<AppState>) -> Router {
    let (mut router, api) = openapi_router().split_for_parts();
    let api = contract::complete(api);
    router = router.merge(SwaggerUi::new("/docs").external_url_unchecked("/openapi.json", api));
    router = router.merge(pages);
    if state.config.test_jobs {
        tracing::warn!("TEST-ONLY job routes are enabled (REACHGRASP_TEST_JOBS)");
        router = router.merge(testing::router());
    }
    let layers = ServiceBuilder::new()
        .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
        .layer(
            TraceLayer::new_for_http()
                .make_span_with(|req: &Request<_>| {
                    let request_id = req
                        .headers()
                        .get("x-request-id")
                        .and_then(|v| v.to_str().ok())
                        .unwrap_or("");
                    tracing::info_span!("request", method = %req.method(), uri = %req.uri(),
                                        request_id = %request_id)
                })
                .on_response(DefaultOnResponse::new().level(Level::INFO)),
        )
        .layer(PropagateRequestIdLayer::x_request_id())
        .layer(CatchPanicLayer::custom(
            |_: Box<dyn std::any::Any + Send>| {
                ApiError::internal(anyhow::anyhow!("a request handler panicked")).into_response()
            },
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.config.request_timeout(),
            middleware::timeout,
        ))
        .layer(axum::middleware::from_fn_with_state(
            middleware::BodyLimits {
                max_bytes: state.config.body_limit,
                idle: state.config.body_idle_timeout(),
            },
            middleware::body_limits,
        ))
        .layer(DefaultBodyLimit::max(state.config.body_limit))
        .layer(axum::middleware::map_response(
            middleware::problem_safety_net,
        ));
    router
        .fallback(|uri: Uri| async move { ApiError::route_not_found(uri.path()) })
        .method_not_allowed_fallback(|method: Method, uri: Uri| async move {
            ApiError::method_not_allowed(method.as_str(), uri.path())
        })
        .layer(layers)
        .with_state(state)
}
