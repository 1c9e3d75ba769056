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
        .is_some_and(|v| v.starts_with(PROBLEM_JSON));
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
