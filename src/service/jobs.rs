//! Jobs: listing, reading and cancelling the long work the other use cases submit.

use uuid::Uuid;

use super::{Context, Error};
use crate::jobs::{JobRecord, JobStatus};
use crate::store::jobs::JobFilter;

/// A page of jobs, newest first, optionally of one status and/or kind.
pub async fn list(
    ctx: &Context,
    status: Option<JobStatus>,
    kind: Option<String>,
    limit: u32,
    offset: u32,
) -> Result<Vec<JobRecord>, Error> {
    let filter = JobFilter {
        status,
        kind,
        limit,
        offset,
    };
    Ok(ctx.jobs.list(&filter).await?)
}

pub async fn get(ctx: &Context, id: Uuid) -> Result<JobRecord, Error> {
    Ok(ctx.jobs.get(id).await?)
}

/// Requests cooperative cancellation; returns the job as it stands.
pub async fn cancel(ctx: &Context, id: Uuid) -> Result<JobRecord, Error> {
    Ok(ctx.jobs.cancel(id).await?)
}
