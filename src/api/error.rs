//! RFC 7807 problem+json errors: the one error type every handler returns.

use std::borrow::Cow;
use std::fmt;

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::jobs::RunnerError;
use crate::service::executions::PayloadPaths;

/// Media type of every error response.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// Prefix of every problem `type` URI; the suffix is a stable slug listed in [`ApiError`].
pub const PROBLEM_TYPE_PREFIX: &str = "urn:reachgrasp:problem:";

/// One bad field: where it is and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FieldError {
    /// JSONPath of the field in the request body (`$.joints[2].position`), or the name of the
    /// path/query parameter (`id`, `limit`).
    pub path: String,
    pub message: String,
}

impl FieldError {
    pub fn new(path: impl Into<String>, message: impl Into<String>) -> Self {
        FieldError {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// An RFC 7807 problem document (`application/problem+json`).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Problem {
    /// Stable URI naming the kind of problem, `urn:reachgrasp:problem:<slug>`.
    #[serde(rename = "type")]
    pub type_uri: String,
    /// Short summary of the problem kind (the same for every occurrence).
    pub title: String,
    /// HTTP status code.
    pub status: u16,
    /// What went wrong in this occurrence.
    pub detail: String,
    /// For validation problems: every offending field.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub errors: Vec<FieldError>,
    /// For `not-ready`: the job preparing what the request needs (`GET /v1/jobs/{job_id}`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job_id: Option<String>,
}

/// The error every handler returns; it renders as problem+json.
///
/// Stable problem slugs (`type` is `urn:reachgrasp:problem:<slug>`):
///
/// | slug | status | use |
/// |---|---|---|
/// | `malformed-json` | 400 | the body is not valid JSON |
/// | `invalid-parameter` | 400 | a path or query parameter cannot be parsed |
/// | `bad-request` | 400 | another malformed request |
/// | `not-found` | 404 | unknown resource id or route |
/// | `method-not-allowed` | 405 | the route exists, the method does not |
/// | `conflict` | 409 | the request conflicts with the resource's state |
/// | `unauthorized` | 401 | missing or wrong credentials (bridge workers' token) |
/// | `payload-too-large` | 413 | body above the configured limit (a declared `Content-Length` is checked before reading) |
/// | `body-timeout` | 408 | the request body stalled longer than the configured idle time |
/// | `unsupported-media-type` | 415 | body is not `application/json` |
/// | `validation` | 422 | well-formed JSON with bad values (see `errors`) |
/// | `unavailable` | 503 | dependency down, shutting down |
/// | `not-ready` | 503 | a job (see `job_id`) is still preparing what the request needs |
/// | `timeout` | 503 | the request took longer than the configured timeout |
/// | `insufficient-storage` | 507 | the database is full (disk or `REACHGRASP_DB_MAX_BYTES`); nothing was stored |
/// | `internal` | 500 | a bug; logged, never detailed to the client |
#[derive(Debug)]
pub struct ApiError {
    status: StatusCode,
    slug: &'static str,
    title: &'static str,
    detail: Cow<'static, str>,
    errors: Vec<FieldError>,
    job_id: Option<String>,
    /// The logged cause of an internal error (never sent).
    source: Option<anyhow::Error>,
}

impl ApiError {
    fn new(
        status: StatusCode,
        slug: &'static str,
        title: &'static str,
        detail: impl Into<Cow<'static, str>>,
    ) -> Self {
        ApiError {
            status,
            slug,
            title,
            detail: detail.into(),
            errors: Vec::new(),
            job_id: None,
            source: None,
        }
    }

    /// 422: well-formed input with bad values; `errors` names every offending field.
    pub fn validation(errors: Vec<FieldError>) -> Self {
        let detail = match errors.as_slice() {
            [one] => format!("{}: {}", one.path, one.message),
            many => format!("{} fields are invalid", many.len()),
        };
        let mut e = ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "validation",
            "Invalid request",
            detail,
        );
        e.errors = errors;
        e
    }

    /// 422 for one field, e.g. `ApiError::invalid_field("$.q[3]", "must be finite, got NaN")`.
    pub fn invalid_field(path: impl Into<String>, message: impl Into<String>) -> Self {
        ApiError::validation(vec![FieldError::new(path, message)])
    }

    /// 400: the body is not JSON (syntax error or truncated).
    pub fn malformed_json(detail: impl Into<Cow<'static, str>>, errors: Vec<FieldError>) -> Self {
        let mut e = ApiError::new(
            StatusCode::BAD_REQUEST,
            "malformed-json",
            "Malformed JSON",
            detail,
        );
        e.errors = errors;
        e
    }

    /// 400: a path or query parameter could not be parsed.
    pub fn invalid_parameter(name: impl Into<String>, message: impl Into<String>) -> Self {
        let errors = vec![FieldError::new(name, message)];
        let mut e = ApiError::new(
            StatusCode::BAD_REQUEST,
            "invalid-parameter",
            "Invalid parameter",
            format!("{}: {}", errors[0].path, errors[0].message),
        );
        e.errors = errors;
        e
    }

    /// 400 for any other malformed request.
    pub fn bad_request(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            "bad-request",
            "Bad request",
            detail,
        )
    }

    /// 404 for an unknown id: `ApiError::not_found("job", id)`.
    pub fn not_found(resource: &str, id: impl fmt::Display) -> Self {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "not-found",
            "Not found",
            format!("{resource} {id} does not exist"),
        )
    }

    /// 404 for an unknown route.
    pub fn route_not_found(path: &str) -> Self {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "not-found",
            "Not found",
            format!("no route for {path}"),
        )
    }

    /// 405.
    pub fn method_not_allowed(method: &str, path: &str) -> Self {
        ApiError::new(
            StatusCode::METHOD_NOT_ALLOWED,
            "method-not-allowed",
            "Method not allowed",
            format!("{path} does not accept {method}"),
        )
    }

    /// 409: the request conflicts with the current state (duplicate name, finished job, ...).
    pub fn conflict(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(StatusCode::CONFLICT, "conflict", "Conflict", detail)
    }

    /// 413.
    pub fn payload_too_large(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "payload-too-large",
            "Payload too large",
            detail,
        )
    }

    /// 408: the client stopped sending its request body for longer than `idle`.
    pub fn body_timeout(idle: std::time::Duration) -> Self {
        ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            "body-timeout",
            "Request body timed out",
            format!(
                "no part of the request body arrived for {} ms (REACHGRASP_BODY_IDLE_TIMEOUT_MS); \
                 send the whole body promptly",
                idle.as_millis()
            ),
        )
    }

    /// 415.
    pub fn unsupported_media_type(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported-media-type",
            "Unsupported media type",
            detail,
        )
    }

    /// 401: missing or wrong credentials (the bridge workers' token).
    pub fn unauthorized(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "Unauthorized",
            detail,
        )
    }

    /// 503: a dependency is down or the service is stopping.
    pub fn unavailable(detail: impl Into<Cow<'static, str>>) -> Self {
        ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "unavailable",
            "Service unavailable",
            detail,
        )
    }

    /// 503: job `job` is still preparing what the request needs (e.g. a default model during
    /// first-start seeding); retry once it has finished.
    pub fn not_ready(detail: impl Into<Cow<'static, str>>, job: impl fmt::Display) -> Self {
        let mut e = ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "not-ready",
            "Not ready yet",
            detail,
        );
        e.job_id = Some(job.to_string());
        e
    }

    /// 503: the request exceeded the configured timeout.
    pub fn timeout(seconds: u64) -> Self {
        ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "timeout",
            "Request timed out",
            format!("the request did not complete within {seconds} s; submit long work as a job"),
        )
    }

    /// 507: the database (its disk, or its configured size cap) is full; nothing was stored.
    pub fn insufficient_storage() -> Self {
        ApiError::new(
            StatusCode::INSUFFICIENT_STORAGE,
            "insufficient-storage",
            "Insufficient storage",
            "the database is full (its disk, or REACHGRASP_DB_MAX_BYTES): nothing was stored \
             and nothing stored was changed; free space, delete plans or trajectories \
             (DELETE /v1/plans/{id}, DELETE /v1/trajectories/{id}) or lower the retention, \
             then retry",
        )
    }

    /// 500: logs `cause` in full; the client sees only that an internal error happened. A
    /// cause that is a full database (SQLITE_FULL, anywhere in its chain) is a 507 instead.
    pub fn internal(cause: impl Into<anyhow::Error>) -> Self {
        let cause = cause.into();
        if cause.chain().any(|e| {
            e.downcast_ref::<sqlx::Error>()
                .is_some_and(crate::service::is_disk_full)
        }) {
            tracing::warn!(error = %cause, "the database is full");
            return ApiError::insufficient_storage();
        }
        let mut e = ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal",
            "Internal error",
            "internal error; see the server logs (x-request-id header names the request)",
        );
        e.source = Some(cause);
        e
    }

    /// A problem for an error response produced outside our handlers (see the safety-net
    /// middleware), keyed by its status.
    pub(crate) fn from_status(status: StatusCode, detail: String) -> Self {
        let (slug, title) = match status.as_u16() {
            400 => ("bad-request", "Bad request"),
            404 => ("not-found", "Not found"),
            405 => ("method-not-allowed", "Method not allowed"),
            408 | 503 if detail.contains("timed out") => ("timeout", "Request timed out"),
            409 => ("conflict", "Conflict"),
            413 => ("payload-too-large", "Payload too large"),
            415 => ("unsupported-media-type", "Unsupported media type"),
            422 => ("validation", "Invalid request"),
            500 => return ApiError::internal(anyhow::anyhow!("{detail}")),
            503 => ("unavailable", "Service unavailable"),
            _ => ("http-error", "HTTP error"),
        };
        let detail = if detail.is_empty() {
            status.canonical_reason().unwrap_or("error").to_owned()
        } else {
            detail
        };
        ApiError::new(status, slug, title, detail)
    }

    pub fn status(&self) -> StatusCode {
        self.status
    }

    /// The stable slug of the problem `type`.
    pub fn slug(&self) -> &'static str {
        self.slug
    }

    pub fn detail(&self) -> &str {
        &self.detail
    }

    pub fn errors(&self) -> &[FieldError] {
        &self.errors
    }

    /// The problem document this error renders as.
    pub fn to_problem(&self) -> Problem {
        Problem {
            type_uri: format!("{PROBLEM_TYPE_PREFIX}{}", self.slug),
            title: self.title.to_owned(),
            status: self.status.as_u16(),
            detail: self.detail.to_string(),
            errors: self.errors.clone(),
            job_id: self.job_id.clone(),
        }
    }
}

impl fmt::Display for ApiError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({}): {}", self.title, self.status, self.detail)
    }
}

impl std::error::Error for ApiError {}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        if let Some(source) = &self.source {
            tracing::error!(error = ?source, "internal error");
        } else if self.status.is_server_error() {
            tracing::warn!(status = %self.status, detail = %self.detail, "request failed");
        }
        let body = serde_json::to_vec(&self.to_problem()).expect("a problem always serializes");
        let mut res = (self.status, body).into_response();
        res.headers_mut()
            .insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        res
    }
}

impl From<sqlx::Error> for ApiError {
    fn from(e: sqlx::Error) -> Self {
        crate::service::Error::from(e).into()
    }
}

impl From<crate::service::Error> for ApiError {
    fn from(e: crate::service::Error) -> Self {
        use crate::service::Error as E;
        match e {
            E::Invalid(fields) => ApiError::validation(
                fields
                    .into_iter()
                    .map(|f| FieldError::new(f.field, f.message))
                    .collect(),
            ),
            E::Payload(issues) => ApiError::validation(
                PayloadPaths::default()
                    .invalid(&issues)
                    .into_iter()
                    .map(|f| FieldError::new(f.field, f.message))
                    .collect(),
            ),
            E::NotFound { kind, id } => ApiError::not_found(kind, id),
            E::Conflict(m) => ApiError::conflict(m),
            E::NotReady { message, job } => ApiError::not_ready(message, job),
            E::Unavailable(m) => ApiError::unavailable(m),
            E::Internal(cause) => ApiError::internal(cause),
        }
    }
}

impl From<crate::bridge::BridgeError> for ApiError {
    fn from(e: crate::bridge::BridgeError) -> Self {
        crate::service::Error::from(e).into()
    }
}

impl From<RunnerError> for ApiError {
    fn from(e: RunnerError) -> Self {
        match e {
            RunnerError::NotFound(id) => ApiError::not_found("job", id),
            RunnerError::AlreadyFinished { id, status } => {
                ApiError::conflict(format!("job {id} is already {status}"))
            }
            RunnerError::ShuttingDown => ApiError::unavailable("the service is shutting down"),
            RunnerError::Store(e) => ApiError::internal(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_problems_list_fields_and_summarise_them() {
        let one = ApiError::invalid_field("$.q[3]", "must be finite");
        assert_eq!(one.status(), StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(one.detail(), "$.q[3]: must be finite");
        let p = one.to_problem();
        assert_eq!(p.type_uri, "urn:reachgrasp:problem:validation");
        assert_eq!(p.errors, vec![FieldError::new("$.q[3]", "must be finite")]);
        let two = ApiError::validation(vec![FieldError::new("a", "x"), FieldError::new("b", "y")]);
        assert_eq!(two.detail(), "2 fields are invalid");
    }

    #[test]
    fn internal_errors_never_carry_their_cause_in_the_document() {
        let e = ApiError::internal(anyhow::anyhow!("secret connection string"));
        let json = serde_json::to_string(&e.to_problem()).unwrap();
        assert!(!json.contains("secret"));
        assert!(!json.contains("errors"));
        assert_eq!(e.status(), StatusCode::INTERNAL_SERVER_ERROR);
    }
}
