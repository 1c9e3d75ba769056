//! Cross-cutting HTTP layers: request timeout, request-body limits and the problem+json
//! safety net.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use axum::body::Bytes;
use futures::{Stream, StreamExt};

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

/// The request-body limits, separate from the request timeout.
#[derive(Debug, Clone, Copy)]
pub struct BodyLimits {
    /// Largest accepted body in bytes.
    pub max_bytes: usize,
    /// Longest pause between two chunks of a body (and before its first one).
    pub idle: Duration,
}

/// The error a stalled body yields to whatever reads it.
#[derive(Debug, thiserror::Error)]
#[error("the request body stalled for {0:?}")]
struct BodyStalled(Duration);

/// Enforces [`BodyLimits`] before and while a handler reads the body:
///
/// - a declared `Content-Length` above the limit is answered `413` at once, without reading
///   a byte of the body (the connection is closed after the answer);
/// - a body that stops arriving for longer than the idle time makes the read fail, and the
///   request is answered `408` (whatever the handler made of the failed read), with the
///   connection closed. A stall is never a 5xx and never waits for the request timeout.
///
/// Chunked bodies without a declared length are still cut at the limit by axum's
/// `DefaultBodyLimit` (413 from the extractor).
pub async fn body_limits(State(limits): State<BodyLimits>, req: Request, next: Next) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    if let Some(n) = declared
        && n > limits.max_bytes as u64
    {
        return close_after(
            ApiError::payload_too_large(format!(
                "the declared body of {n} bytes exceeds the limit of {} bytes \
                 (REACHGRASP_BODY_LIMIT)",
                limits.max_bytes
            ))
            .into_response(),
        );
    }
    let has_body =
        declared.is_some_and(|n| n > 0) || req.headers().contains_key(header::TRANSFER_ENCODING);
    if !has_body {
        return next.run(req).await;
    }
    let stalled = Arc::new(AtomicBool::new(false));
    let (parts, body) = req.into_parts();
    let body = Body::from_stream(idle_guarded(body, limits.idle, stalled.clone()));
    let res = next.run(Request::from_parts(parts, body)).await;
    if stalled.load(Ordering::SeqCst) {
        return close_after(ApiError::body_timeout(limits.idle).into_response());
    }
    res
}

/// Marks `res` as the last answer on its connection (the rest of the body is never read).
fn close_after(mut res: Response) -> Response {
    res.headers_mut().insert(
        header::CONNECTION,
        axum::http::HeaderValue::from_static("close"),
    );
    res
}

/// The chunks of `body`, failing (and setting `stalled`) when the next one takes longer
/// than `idle` to arrive.
fn idle_guarded(
    body: Body,
    idle: Duration,
    stalled: Arc<AtomicBool>,
) -> impl Stream<Item = Result<Bytes, axum::BoxError>> + Send + 'static {
    futures::stream::unfold(Some(body.into_data_stream()), move |state| {
        let stalled = stalled.clone();
        async move {
            let mut chunks = state?;
            match tokio::time::timeout(idle, chunks.next()).await {
                Ok(Some(Ok(bytes))) => Some((Ok(bytes), Some(chunks))),
                Ok(Some(Err(e))) => Some((Err(e.into()), None)),
                Ok(None) => None,
                Err(_) => {
                    stalled.store(true, Ordering::SeqCst);
                    Some((Err(BodyStalled(idle).into()), None))
                }
            }
        }
    })
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
