//! Dashboard: server-rendered HTML pages at `GET /` and `/ui/...`, with the stylesheet and script
//! embedded in the binary (`include_str!`; no CDN, no build step).
//!
//! Pages read the store directly and link to the figures of the API (`/v1/.../plot.svg`). The script
//! (`assets/dashboard/app.js`) does three things: submits the action forms as JSON to the API and
//! shows each problem+json field error next to the input whose `data-path` matches the error's
//! JSONPath; follows job progress over Server-Sent Events (`/v1/jobs/{id}/events`) with a
//! progress bar; and re-requests a figure when its view sliders move.
//!
//! The 3-D viewer (`/ui/view/...`, [`viewer`]) adds `assets/dashboard/viewer.js` and three.js
//! (vendored from npm, `assets/dashboard/vendor/`) and dashboard-internal JSON routes (its
//! scenes and live poses), which are not part of the OpenAPI document.

mod html;
mod pages;
mod plans;
mod resources;
mod viewer;

use axum::Router;
use axum::http::header;
use axum::response::{IntoResponse, Redirect};
use axum::routing::get;

use crate::service::Context as AppState;

pub use html::esc;

const STYLE: &str = include_str!("../../assets/dashboard/style.css");
const SCRIPT: &str = include_str!("../../assets/dashboard/app.js");
const FAVICON: &[u8] = include_bytes!("../../assets/dashboard/favicon.svg");

/// The dashboard routes (not part of the OpenAPI document).
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/", get(pages::home))
        // The pages live under /ui/…; its bare prefix is where a user looks for the overview.
        .route("/ui", get(|| async { Redirect::permanent("/") }))
        .route("/ui/", get(|| async { Redirect::permanent("/") }))
        // Any other path under /ui/ is a page that does not exist: say so in HTML.
        .route(
            "/ui/{*rest}",
            get(|uri: axum::http::Uri| async move { html::no_such_page(uri.path()) }),
        )
        .route("/assets/style.css", get(style))
        .route("/assets/app.js", get(script))
        .route("/favicon.ico", get(favicon))
        .route("/ui/robots", get(pages::robots))
        .route("/ui/robots/{id}", get(pages::robot))
        .route("/ui/objects", get(pages::objects))
        .route("/ui/objects/{id}", get(pages::object))
        .route("/ui/demonstrations", get(pages::demonstrations))
        .route("/ui/demonstrations/{id}", get(pages::demonstration))
        .route("/ui/grasps", get(pages::grasps))
        .route("/ui/grasps/{id}", get(pages::grasp))
        .route("/ui/mappings", get(resources::mappings))
        .route("/ui/mappings/{id}", get(resources::mapping))
        .route("/ui/models", get(resources::models))
        .route("/ui/models/{id}", get(resources::model))
        .route("/ui/trajectories", get(resources::trajectories))
        .route("/ui/trajectories/{id}", get(resources::trajectory))
        .route("/ui/bridges", get(resources::bridges))
        .route("/ui/executions", get(resources::executions))
        .route("/ui/executions/{id}", get(resources::execution))
        .route("/ui/jobs", get(pages::jobs))
        .route("/ui/jobs/{id}", get(pages::job))
        .route("/ui/plans", get(plans::plans))
        .route("/ui/plans/{id}", get(plans::plan))
        .route("/ui/verifications", get(plans::verifications))
        .route("/ui/verifications/{id}", get(plans::verification))
        .route("/ui/compare", get(plans::compare))
        .merge(viewer::router())
}

async fn style() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/css; charset=utf-8"),
            (header::CACHE_CONTROL, "max-age=300"),
        ],
        STYLE,
    )
}

async fn script() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/javascript; charset=utf-8"),
            (header::CACHE_CONTROL, "max-age=300"),
        ],
        SCRIPT,
    )
}

async fn favicon() -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "image/svg+xml"),
            (header::CACHE_CONTROL, "max-age=86400"),
        ],
        FAVICON,
    )
}
