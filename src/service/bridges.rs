//! Bridge workers: the connected ones (live, from the hub) and every one seen before (stored).

use super::{Context, Error};
use crate::bridge::protocol::Capability;
use crate::bridge::{ExecutionPayload, WorkerSnapshot};
use crate::store::executions as repo;

pub use crate::store::executions::BridgeRow;

/// The connected workers and every worker ever seen.
pub async fn list(ctx: &Context) -> Result<(Vec<WorkerSnapshot>, Vec<BridgeRow>), Error> {
    let live = ctx.bridges.workers();
    let known = repo::list_bridges(&ctx.db).await?;
    Ok((live, known))
}

/// Where a connected worker will be when an execution queued now starts.
#[derive(Debug, Clone)]
pub struct ExpectedState {
    pub worker: String,
    /// Its joint names (the robot's, in model order) and the positions.
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
    /// `None`: its measured state (nothing runs or waits before); `Some(id)`: the end of
    /// execution `id`, which runs or is queued before (a worker stays where an execution ends).
    pub after: Option<String>,
    /// The start tolerance the worker announced (or the default).
    pub tolerance: f64,
}

impl ExpectedState {
    /// Largest joint deviation of `q` (in `names` order) from this state, and the joint where
    /// it is; `None` when the names are not this robot's.
    pub fn deviation(&self, names: &[String], q: &[f64]) -> Option<(f64, usize)> {
        if names.len() != self.joint_names.len() || q.len() != names.len() {
            return None;
        }
        let mut worst = (0.0, 0);
        for (name, &x) in names.iter().zip(q) {
            let i = self.joint_names.iter().position(|n| n == name)?;
            let d = (x - self.positions[i]).abs();
            if d > worst.0 {
                worst = (d, i);
            }
        }
        Some(worst)
    }

    /// Where this state comes from, for messages.
    pub fn source(&self) -> String {
        match &self.after {
            None => format!("worker '{}' is (its measured state)", self.worker),
            Some(id) => format!(
                "worker '{}' will be after execution {id}, which runs or waits before this one",
                self.worker
            ),
        }
    }
}

/// The connected workers of `robot` (only `worker` when named) with the capabilities `needs`
/// that report their state, by name, each with where it will be when an execution queued now
/// starts.
pub async fn expected_states(
    ctx: &Context,
    robot: &str,
    worker: Option<&str>,
    needs: &[Capability],
) -> Result<Vec<ExpectedState>, Error> {
    let mut live: Vec<WorkerSnapshot> = ctx
        .bridges
        .workers()
        .into_iter()
        .filter(|w| w.robot == robot && !w.positions.is_empty())
        .filter(|w| worker.is_none_or(|n| n == w.name))
        .filter(|w| needs.iter().all(|&c| w.can(c)))
        .collect();
    live.sort_by(|a, b| a.name.cmp(&b.name));
    let mut out = Vec::with_capacity(live.len());
    for w in live {
        let tolerance = w.tolerance();
        let pending = repo::last_pending(&ctx.db, robot, &w.name).await?;
        let (positions, after) = match pending {
            Some((id, ExecutionPayload::Trajectory { points, .. })) if !points.is_empty() => {
                (points[points.len() - 1].positions.clone(), Some(id))
            }
            Some((id, ExecutionPayload::Model { goal, .. })) => (goal, Some(id)),
            _ => (w.positions, None),
        };
        if positions.len() != w.joint_names.len() {
            continue;
        }
        out.push(ExpectedState {
            worker: w.name,
            joint_names: w.joint_names,
            positions,
            after,
            tolerance,
        });
    }
    Ok(out)
}

/// For an execution that starts at `q` (joint `names`): the connected worker with the
/// capabilities `needs` it should run on (the named one, else the nearest), or a 422 at `path`
/// when even that one will be farther than its start tolerance from `q`. `Ok(None)`: no such
/// worker of the robot is connected and reporting its state, so nothing can be checked now (the
/// worker checks when it starts).
pub async fn check_start(
    ctx: &Context,
    robot: &str,
    (worker, needs): (Option<&str>, &[Capability]),
    names: &[String],
    q: &[f64],
    path: &str,
) -> Result<Option<String>, Error> {
    let states = expected_states(ctx, robot, worker, needs).await?;
    let nearest = states
        .iter()
        .filter_map(|s| s.deviation(names, q).map(|d| (d, s)))
        .min_by(|a, b| a.0.0.total_cmp(&b.0.0));
    let Some(((d, at), state)) = nearest else {
        return Ok(None);
    };
    if d <= state.tolerance {
        return Ok(Some(state.worker.clone()));
    }
    let joint = &state.joint_names[at];
    let here = names
        .iter()
        .position(|n| n == joint)
        .map_or(f64::NAN, |i| q[i]);
    Err(Error::invalid(
        path,
        format!(
            "the motion starts {d:.3} rad from where {} ({joint}: {here:.3} here, {:.3} there), \
             beyond its start tolerance of {} rad; plan with \"start\": \"current\" or move the \
             robot there first",
            state.source(),
            state.positions[at],
            state.tolerance
        ),
    ))
}
