//! Bridge workers: the connected ones (live, from the hub) and every one seen before (stored).

use super::{Context, Error};
use crate::bridge::WorkerSnapshot;
use crate::store::executions as repo;

pub use crate::store::executions::BridgeRow;

/// The connected workers and every worker ever seen.
pub async fn list(ctx: &Context) -> Result<(Vec<WorkerSnapshot>, Vec<BridgeRow>), Error> {
    let live = ctx.bridges.workers();
    let known = repo::list_bridges(&ctx.db).await?;
    Ok((live, known))
}
