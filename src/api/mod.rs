//! HTTP API: one router per resource, DTOs with utoipa schemas, problem+json errors.
