//! The OpenAPI document states what the server enforces (issue 20, item 3).
//!
//! The routers' `utoipa::path` attributes document each operation's own answers. What every
//! operation can also answer comes from the layers around the handlers and from the
//! extractors, the same for all of them, so it is added here once rather than repeated in each
//! attribute (and cannot be forgotten in a new one):
//!
//! - `400` (malformed JSON, an unparsable path or query parameter) where a body or parameter
//!   is read; `404` where the path names a resource; `408`, `413`, `415` and `422` where a JSON
//!   body is read (body idle time, body limit, content type, field validation);
//! - `503` everywhere (shutting down, request timeout), `507` on writes (the database is full);
//! - the paging parameters' enforced ranges (`limit` 1 to [`MAX_PAGE`], `offset` 0 to
//!   [`MAX_OFFSET`]);
//! - the event stream of `GET /v1/jobs/{id}/events` as `text/event-stream` whose schema is one
//!   event (`event`, `data`, `id`, `retry`) with `data` the job as JSON (`contentSchema`),
//!   instead of claiming each event is a `JobRecord`.

use serde_json::{Value, json};

use super::page::{MAX_OFFSET, MAX_PAGE};

fn problem(description: &str) -> Value {
    json!({
        "description": description,
        "content": {
            "application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}
        }
    })
}

/// `N` of "1 to N" in a parameter's description.
fn documented_max(description: &str) -> Option<u64> {
    let rest = &description[description.find("1 to ")? + 5..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// Adds `status` with `description` unless the operation documents it already.
fn add(responses: &mut serde_json::Map<String, Value>, status: &str, description: &str) {
    responses
        .entry(status.to_owned())
        .or_insert_with(|| problem(description));
}

/// The document with what every operation can answer and the enforced parameter ranges.
pub fn complete(doc: utoipa::openapi::OpenApi) -> utoipa::openapi::OpenApi {
    let mut v = serde_json::to_value(&doc).expect("an OpenAPI document serializes");
    let Some(paths) = v.get_mut("paths").and_then(Value::as_object_mut) else {
        return doc;
    };
    for (path, item) in paths.iter_mut() {
        let Some(item) = item.as_object_mut() else {
            continue;
        };
        for (method, op) in item.iter_mut() {
            if !matches!(
                method.as_str(),
                "get" | "post" | "put" | "patch" | "delete" | "head" | "options"
            ) {
                continue;
            }
            complete_operation(path, method, op);
        }
    }
    serde_json::from_value(v).unwrap_or(doc)
}

fn complete_operation(path: &str, method: &str, op: &mut Value) {
    let body = op.get("requestBody").cloned();
    let json_body = body
        .as_ref()
        .and_then(|b| b.get("content"))
        .is_some_and(|c| c.get("application/json").is_some());
    if let Some(params) = op.get_mut("parameters").and_then(Value::as_array_mut) {
        for p in params.iter_mut() {
            let in_query = p.get("in").and_then(Value::as_str) == Some("query");
            let description = p.get("description").and_then(Value::as_str).unwrap_or("");
            let range = match p.get("name").and_then(Value::as_str) {
                // Each page size documents its own range ("Page size, 1 to 500"); the
                // handlers enforce exactly that range (tests/api/openapi.rs checks it).
                Some("limit") if in_query => Some((
                    1,
                    documented_max(description).unwrap_or(u64::from(MAX_PAGE)),
                )),
                Some("offset") if in_query => Some((0, u64::from(MAX_OFFSET))),
                _ => None,
            };
            if let (Some((lo, hi)), Some(schema)) = (range, p.get_mut("schema")) {
                schema["minimum"] = json!(lo);
                schema["maximum"] = json!(hi);
            }
        }
    }
    let has_params = op
        .get("parameters")
        .and_then(Value::as_array)
        .is_some_and(|p| !p.is_empty());
    let Some(responses) = op.get_mut("responses").and_then(Value::as_object_mut) else {
        return;
    };
    if has_params || body.is_some() {
        add(
            responses,
            "400",
            "Bad request: malformed JSON, or a path or query parameter that does not parse \
             (problem+json naming it)",
        );
    }
    if path.contains('{') {
        add(responses, "404", "No such resource (problem+json)");
    }
    if body.is_some() {
        add(
            responses,
            "408",
            "The request body stalled longer than the body idle time (problem+json)",
        );
        add(
            responses,
            "413",
            "The request body is larger than the body limit (problem+json)",
        );
        add(
            responses,
            "415",
            "The request body does not have the documented content type (problem+json)",
        );
    }
    if json_body {
        add(
            responses,
            "422",
            "Invalid request: well-formed JSON with bad values (problem+json naming each field)",
        );
    }
    add(
        responses,
        "503",
        "Service unavailable: shutting down, a dependency down, or the request took longer than \
         the request timeout (problem+json)",
    );
    if matches!(method, "post" | "put" | "patch" | "delete") {
        add(
            responses,
            "507",
            "Insufficient storage: the database is full; nothing was stored (problem+json)",
        );
    }
    // Server-Sent Events: the schema describes one event (what a conformance checker
    // validates each parsed event against), whose `data` is the documented JSON.
    if let Some(ok) = responses.get_mut("200")
        && let Some(stream) = ok
            .get_mut("content")
            .and_then(|c| c.get_mut("text/event-stream"))
    {
        let data = stream.pointer("/schema/$ref").cloned();
        let mut data_schema = json!({
            "type": "string",
            "contentMediaType": "application/json",
            "description": "The event's JSON payload",
        });
        if let Some(r) = data {
            data_schema["contentSchema"] = json!({"$ref": r});
        }
        stream["schema"] = json!({
            "type": "object",
            "description": "One Server-Sent Event: its name and, in `data`, the JSON it carries",
            "properties": {
                "event": {"type": "string"},
                "data": data_schema,
                "id": {"type": "string"},
                "retry": {"type": "integer", "minimum": 0},
            },
        });
    }
}
