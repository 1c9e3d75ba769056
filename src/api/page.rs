//! One page envelope for every list endpoint, and the extractor that reads its query
//! parameters, so all lists page alike: `limit` (1 to 500, default 50) and `offset` (default 0)
//! are defaulted and range-checked here once, and echoed in the answer.
//!
//! A list's query struct still names `limit` and `offset` (their descriptions differ per
//! resource in the OpenAPI document); [`Listing`] reads them.

use std::borrow::Cow;

use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Schema};
use utoipa::openapi::{Ref, RefOr};
use utoipa::{PartialSchema, ToSchema};

use super::{ApiError, Query};

/// Largest page a list endpoint returns.
pub const MAX_PAGE: u32 = 500;
/// Page size when the client names none.
pub const DEFAULT_PAGE: u32 = 50;
/// Largest `offset` accepted (the documented `int32` range; larger is a 400).
pub const MAX_OFFSET: u32 = i32::MAX as u32;

/// Refuses an `offset` above [`MAX_OFFSET`] (400 naming it).
pub fn check_offset(offset: u32) -> Result<u32, ApiError> {
    if offset > MAX_OFFSET {
        return Err(ApiError::invalid_parameter(
            "offset",
            format!("must be between 0 and {MAX_OFFSET}, got {offset}"),
        ));
    }
    Ok(offset)
}

/// Which page a client asked for, checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PageRequest {
    pub limit: u32,
    pub offset: u32,
}

impl PageRequest {
    /// This page of `items`; `total` counts every match where the list knows it.
    pub fn of<T>(self, items: Vec<T>, total: Option<i64>) -> Page<T> {
        Page {
            items,
            total,
            limit: self.limit,
            offset: self.offset,
        }
    }
}

#[derive(Deserialize)]
struct RawPage {
    limit: Option<u32>,
    offset: Option<u32>,
}

/// A list endpoint's query: the resource's own parameters `Q` and the checked page.
#[derive(Debug)]
pub struct Listing<Q>(pub Q, pub PageRequest);

impl<Q, S> FromRequestParts<S> for Listing<Q>
where
    Q: DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let Query(q) = Query::<Q>::from_request_parts(parts, state).await?;
        let Query(raw) = Query::<RawPage>::from_request_parts(parts, state).await?;
        let limit = raw.limit.unwrap_or(DEFAULT_PAGE);
        if !(1..=MAX_PAGE).contains(&limit) {
            return Err(ApiError::invalid_parameter(
                "limit",
                format!("must be between 1 and {MAX_PAGE}, got {limit}"),
            ));
        }
        let offset = check_offset(raw.offset.unwrap_or(0))?;
        Ok(Listing(q, PageRequest { limit, offset }))
    }
}

/// One page of a list, newest first: `{items, total?, limit, offset}`.
#[derive(Debug, Serialize, Deserialize)]
pub struct Page<T> {
    pub items: Vec<T>,
    /// Every match, where the list counts them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub total: Option<i64>,
    pub limit: u32,
    pub offset: u32,
}

/// An item type that is listed in pages: the name its page has in the OpenAPI document.
pub trait Listed: ToSchema {
    /// Schema name of a page of these, e.g. `PlanList`.
    const PAGE: &'static str;
    /// The page schema's description.
    const DESCRIPTION: Option<&'static str> = None;
    /// Whether the page carries `total`.
    const COUNTED: bool = true;
}

impl<T: Listed> PartialSchema for Page<T> {
    fn schema() -> RefOr<Schema> {
        let mut object = ObjectBuilder::new()
            .description(T::DESCRIPTION)
            .property(
                "items",
                ArrayBuilder::new().items(Ref::from_schema_name(T::name())),
            )
            .required("items");
        if T::COUNTED {
            object = object.property("total", i64::schema()).required("total");
        }
        object = object
            .property("limit", u32::schema())
            .required("limit")
            .property("offset", u32::schema())
            .required("offset");
        RefOr::T(Schema::Object(object.build()))
    }
}

impl<T: Listed> ToSchema for Page<T> {
    fn name() -> Cow<'static, str> {
        Cow::Borrowed(T::PAGE)
    }

    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        schemas.push((T::name().into_owned(), T::schema()));
        T::schemas(schemas);
    }
}
