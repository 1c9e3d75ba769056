//! Bounded storage (issue 20): deleting plans and trajectories with what they own, and the
//! periodic maintenance (retention sweep, WAL checkpoint). The rules of ownership are in
//! [`crate::store::retention`].

use super::{Context, Error};
use crate::store::retention::{self, Deletion, Swept};

fn outcome(kind: &'static str, id: &str, done: Deletion) -> Result<(), Error> {
    match done {
        Deletion::Deleted => Ok(()),
        Deletion::NotFound => Err(Error::not_found(kind, id)),
        Deletion::InUse(why) => Err(Error::Conflict(why)),
    }
}

/// Deletes plan `id` with its grasp, trajectory and execution (with its feedback); 409 while
/// its execution is queued or running.
pub async fn delete_plan(ctx: &Context, id: &str) -> Result<(), Error> {
    outcome("plan", id, retention::delete_plan(&ctx.db, id).await?)
}

/// Deletes trajectory `id`; 409 while a plan owns it or an unfinished execution follows it.
pub async fn delete_trajectory(ctx: &Context, id: &str) -> Result<(), Error> {
    outcome(
        "trajectory",
        id,
        retention::delete_trajectory(&ctx.db, id).await?,
    )
}

/// One maintenance run: the retention sweep of the configured policy, then a WAL checkpoint
/// that truncates the WAL.
pub async fn maintain(ctx: &Context) -> Result<Swept, Error> {
    let swept = retention::sweep(&ctx.db, &ctx.config.retention()).await?;
    if swept.total() > 0 {
        tracing::info!(
            plans = swept.plans,
            trajectories = swept.trajectories,
            executions = swept.executions,
            "retention: expired rows deleted"
        );
    }
    let (busy, log, done) = retention::checkpoint(&ctx.db).await?;
    tracing::debug!(busy, log, done, "WAL checkpoint");
    Ok(swept)
}

/// Runs [`maintain`] every configured interval until the service stops. A failed run (e.g. a
/// full disk) is logged and retried at the next interval.
pub async fn run_maintenance(ctx: Context) {
    let mut tick = tokio::time::interval(ctx.config.maintenance_interval());
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            () = ctx.shutdown.wait() => return,
        }
        if let Err(e) = maintain(&ctx).await {
            tracing::warn!(error = %e, "storage maintenance failed; retrying at the next interval");
        }
    }
}
