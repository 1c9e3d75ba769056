//! Extractors whose rejections are [`ApiError`]s (problem+json), replacing axum's plain-text
//! ones. Handlers use these instead of `axum::Json`, `axum::extract::{Path, Query}`.

use axum::body::Bytes;
use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::error::{ApiError, FieldError};

/// JSON body (request) or JSON response; malformed input becomes problem+json with the JSONPath
/// of the offending field.
#[derive(Debug, Clone, Copy, Default)]
pub struct Json<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for Json<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, ApiError> {
        if !json_content_type(req.headers()) {
            return Err(missing_json_content_type());
        }
        let bytes = Bytes::from_request(req, state)
            .await
            .map_err(|e| ApiError::from(JsonRejection::from(e)))?;
        match axum::Json::<T>::from_bytes(&bytes) {
            Ok(axum::Json(value)) => Ok(Json(value)),
            Err(JsonRejection::JsonSyntaxError(e)) => Err(shape_error::<T>(&bytes)
                .unwrap_or_else(|| JsonRejection::JsonSyntaxError(e).into())),
            Err(rejection) => Err(rejection.into()),
        }
    }
}

/// What axum's own `Json` accepts: `application/json` or `application/*+json`, any parameters.
fn json_content_type(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<mime::Mime>().ok())
        .is_some_and(|m| {
            m.type_() == "application"
                && (m.subtype() == "json" || m.suffix().is_some_and(|s| s == "json"))
        })
}

fn missing_json_content_type() -> ApiError {
    ApiError::unsupported_media_type("expected a body with `Content-Type: application/json`")
}

/// The 422 of a body that is valid JSON but which the JSON reader refused as a syntax error
/// while reading it as `T`: a wrong type for a plain enum (serde_json's "expected value") or
/// an array longer than a fixed size ("trailing characters") are its own syntax errors, though
/// the request is well-formed. Read from a parsed `Value`, the same mistakes are data errors
/// at their field's path. `None` when the body is not valid JSON after all.
fn shape_error<T: DeserializeOwned>(bytes: &[u8]) -> Option<ApiError> {
    let value: serde_json::Value = serde_json::from_slice(bytes).ok()?;
    let e = serde_path_to_error::deserialize::<_, T>(value).err()?;
    Some(ApiError::validation(vec![field_error(&e)]))
}

impl<T: Serialize> IntoResponse for Json<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

/// Path parameters; a parameter that does not parse (e.g. a malformed UUID) is a 400.
#[derive(Debug, Clone, Copy, Default, FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct Path<T>(pub T);

/// Query string; a bad parameter is a 400 naming it.
#[derive(Debug, Clone, Copy, Default, FromRequestParts)]
#[from_request(via(axum::extract::Query), rejection(ApiError))]
pub struct Query<T>(pub T);

type PathError = serde_path_to_error::Error<serde_json::Error>;

/// Finds the serde_path_to_error cause axum keeps inside its JSON rejections.
fn path_error<'a>(e: &'a (dyn std::error::Error + 'static)) -> Option<&'a PathError> {
    let mut cur: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(err) = cur {
        if let Some(p) = err.downcast_ref::<PathError>() {
            return Some(p);
        }
        cur = err.source();
    }
    None
}

/// The offending field and message of a serde error, naming a missing field itself rather than
/// its parent object.
fn field_error(e: &PathError) -> FieldError {
    let (path, message) = locate(e);
    FieldError::new(path, message)
}

pub(crate) use crate::wire::locate;

impl From<JsonRejection> for ApiError {
    fn from(rejection: JsonRejection) -> Self {
        match rejection {
            JsonRejection::JsonDataError(e) => match path_error(&e) {
                Some(p) => ApiError::validation(vec![field_error(p)]),
                None => ApiError::validation(vec![FieldError::new("$", e.body_text())]),
            },
            JsonRejection::JsonSyntaxError(e) => {
                let errors = path_error(&e)
                    .map(|p| vec![field_error(p)])
                    .unwrap_or_default();
                let detail = match path_error(&e) {
                    Some(p) => format!("the body is not valid JSON: {}", p.inner()),
                    None => format!("the body is not valid JSON: {}", e.body_text()),
                };
                ApiError::malformed_json(detail, errors)
            }
            JsonRejection::MissingJsonContentType(_) => missing_json_content_type(),
            JsonRejection::BytesRejection(e) => {
                if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
                    ApiError::payload_too_large(
                        "the request body exceeds the configured limit (REACHGRASP_BODY_LIMIT)",
                    )
                } else {
                    ApiError::bad_request(format!(
                        "cannot read the request body: {}",
                        e.body_text()
                    ))
                }
            }
            other => ApiError::bad_request(other.body_text()),
        }
    }
}

impl From<PathRejection> for ApiError {
    fn from(rejection: PathRejection) -> Self {
        use axum::extract::path::ErrorKind;
        match rejection {
            PathRejection::FailedToDeserializePathParams(e) => match e.kind() {
                ErrorKind::ParseErrorAtKey {
                    key,
                    value,
                    expected_type,
                } => ApiError::invalid_parameter(
                    key.clone(),
                    format!("cannot parse {value:?} as {expected_type}"),
                ),
                ErrorKind::DeserializeError {
                    key,
                    value,
                    message,
                } => ApiError::invalid_parameter(
                    key.clone(),
                    format!("cannot parse {value:?}: {message}"),
                ),
                ErrorKind::InvalidUtf8InPathParam { key } => {
                    ApiError::invalid_parameter(key.clone(), "is not valid UTF-8")
                }
                _ => ApiError::invalid_parameter("path", e.body_text()),
            },
            other => ApiError::internal(anyhow::anyhow!("path extraction failed: {other}")),
        }
    }
}

impl From<QueryRejection> for ApiError {
    fn from(rejection: QueryRejection) -> Self {
        match rejection {
            QueryRejection::FailedToDeserializeQueryString(e) => {
                // serde_urlencoded names the parameter in its message but has no path API.
                let text = e.body_text();
                let message = text
                    .strip_prefix("Failed to deserialize query string: ")
                    .unwrap_or(&text);
                // Messages look like "limit: invalid digit found in string".
                match message.split_once(": ") {
                    Some((name, rest))
                        if !name.is_empty()
                            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') =>
                    {
                        ApiError::invalid_parameter(name, rest)
                    }
                    _ => ApiError::invalid_parameter("query", message),
                }
            }
            other => ApiError::bad_request(other.body_text()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[allow(dead_code)]
    struct Inner {
        x: f64,
        name: String,
    }

    #[derive(Debug, serde::Deserialize)]
    #[allow(dead_code)]
    struct Outer {
        items: Vec<Inner>,
    }

    fn err(body: &str) -> ApiError {
        ApiError::from(axum::Json::<Outer>::from_bytes(body.as_bytes()).unwrap_err())
    }

    #[test]
    fn wrong_types_name_the_json_path_of_the_field() {
        let e = err(r#"{"items": [{"x": 1, "name": "a"}, {"x": "oops", "name": "b"}]}"#);
        assert_eq!(e.status(), axum::http::StatusCode::UNPROCESSABLE_ENTITY);
        assert_eq!(e.errors()[0].path, "$.items[1].x");
        assert!(
            e.errors()[0].message.contains("invalid type"),
            "{:?}",
            e.errors()
        );
    }

    #[test]
    fn missing_fields_are_named_themselves() {
        let e = err(r#"{"items": [{"x": 1}]}"#);
        assert_eq!(e.slug(), "validation");
        assert_eq!(e.errors()[0].path, "$.items[0].name");
        let e = err(r#"{}"#);
        assert_eq!(e.errors()[0].path, "$.items");
    }

    #[test]
    fn syntax_errors_are_malformed_json() {
        let e = err(r#"{"items": [ "#);
        assert_eq!(e.status(), axum::http::StatusCode::BAD_REQUEST);
        assert_eq!(e.slug(), "malformed-json");
    }
}
