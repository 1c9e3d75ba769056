//! Cross-cutting HTTP layers: request timeout and the problem+json safety net.

use std::time::Duration;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::header;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::ApiError;
use super::error::PROBLEM_JSON;

/// Answers `503 timeout` (problem+json) when the handler has not produced a response within the
/// configured time. A streaming response (SSE) counts as produced once its headers are ready.
pub async fn timeout(State(limit): State<Duration>, req: Request, next: Next) -> Response {
    match tokio::time::timeout(limit, next.run(req)).await {
        Ok(res) => res,
        Err(_) => ApiError::timeout(limit.as_secs()).into_response(),
    }
}

/// Rewrites any error response that is not already problem+json (axum's own 404/405/413
/// bodies, layers from tower-http, extractors a handler used directly) into problem+json with
/// the original status, headers (e.g. `Allow`) and text as detail.
pub async fn problem_safety_net(res: Response) -> Response {
    let status = res.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return res;
    }
    let is_problem = res
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        // The dashboard's HTML error pages (e.g. an unknown id) are already readable.
        .is_some_and(|v| v.starts_with(PROBLEM_JSON) || v.starts_with("text/html"));
    if is_problem {
        return res;
    }
    let (mut parts, body) = res.into_parts();
    let is_text = parts
        .headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("text/plain"));
    // Error bodies are short; anything longer is cut rather than buffered without bound.
    let detail = match axum::body::to_bytes(body, 16 * 1024).await {
        Ok(bytes) if is_text => String::from_utf8_lossy(&bytes).trim().to_owned(),
        _ => String::new(),
    };
    let problem = ApiError::from_status(status, detail).into_response();
    let (problem_parts, problem_body) = problem.into_parts();
    parts.headers.remove(header::CONTENT_LENGTH);
    for (name, value) in &problem_parts.headers {
        parts.headers.insert(name, value.clone());
    }
    Response::from_parts(parts, Body::new(problem_body))
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::Router;
    use axum::http::StatusCode;
    use axum::routing::get;
    use tower::ServiceExt;

    async fn body_json(res: Response) -> serde_json::Value {
        let bytes = axum::body::to_bytes(res.into_body(), 1 << 16)
            .await
            .unwrap();
        serde_json::from_slice(&bytes).unwrap()
    }

    #[tokio::test]
    async fn a_slow_handler_is_answered_with_a_timeout_problem() {
        let app = Router::new()
            .route(
                "/slow",
                get(|| async {
                    tokio::time::sleep(Duration::from_secs(30)).await;
                    "late"
                }),
            )
            .route("/fast", get(|| async { "ok" }))
            .layer(axum::middleware::from_fn_with_state(
                Duration::from_millis(50),
                timeout,
            ));
        let res = app
            .clone()
            .oneshot(Request::get("/slow").body(Body::empty()).unwrap())
            .await
            .unwrap();
        assert_eq!(res.status(), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(res.headers()[header::CONTENT_TYPE], PROBLEM_JSON);
        assert_eq!(
            body_json(res).await["type"],
            "urn:reachgrasp:problem:timeout"
        );
        let res = app
            .oneshot(Request::get("/fast").body(Body::empty()).unwrap())
            .await
            .unwrap();
        assert_eq!(res.status(), StatusCode::OK);
    }

    #[tokio::test]
    async fn plain_text_errors_are_rewritten_as_problems_keeping_status_and_text() {
        let app = Router::new()
            .route(
                "/teapot",
                get(|| async { (StatusCode::CONFLICT, "already there") }),
            )
            .route("/ok", get(|| async { (StatusCode::CREATED, "made") }))
            .layer(axum::middleware::map_response(problem_safety_net));
        let res = app
            .clone()
            .oneshot(Request::get("/teapot").body(Body::empty()).unwrap())
            .await
            .unwrap();
        assert_eq!(res.status(), StatusCode::CONFLICT);
        assert_eq!(res.headers()[header::CONTENT_TYPE], PROBLEM_JSON);
        let p = body_json(res).await;
        assert_eq!(p["type"], "urn:reachgrasp:problem:conflict");
        assert_eq!(p["detail"], "already there");
        let res = app
            .oneshot(Request::get("/ok").body(Body::empty()).unwrap())
            .await
            .unwrap();
        assert_eq!(res.status(), StatusCode::CREATED);
        assert_ne!(res.headers()[header::CONTENT_TYPE], PROBLEM_JSON);
    }
}
