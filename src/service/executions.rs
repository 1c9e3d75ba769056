//! Executions: queueing a checked payload for a bridge worker of the robot.

use super::{Context, Error};
use crate::bridge::protocol::Feedback;
use crate::bridge::{ExecutionPayload, Mode, TrackingSummary, WorkerName};
use crate::store::executions::{self as repo, ExecutionRow};

/// Checks `payload` against the robot and queues it; returns the execution id.
pub async fn enqueue(
    ctx: &Context,
    robot: &str,
    mode: Mode,
    payload: ExecutionPayload,
    worker: Option<WorkerName>,
) -> Result<String, Error> {
    Ok(ctx.bridges.enqueue(robot, mode, payload, worker).await?)
}

/// An execution as it stands: its row, with the live feedback and tracking of the bridge hub
/// while it runs, else the stored ones.
#[derive(Debug, Clone)]
pub struct ExecutionView {
    pub row: ExecutionRow,
    pub last_feedback: Option<Feedback>,
    pub tracking: Option<TrackingSummary>,
    pub feedback_samples: u64,
}

pub fn view(ctx: &Context, row: ExecutionRow) -> ExecutionView {
    let live = (row.state == repo::ExecutionState::Running)
        .then(|| ctx.bridges.live(&row.id))
        .flatten();
    let (last_feedback, tracking, feedback_samples) = match live {
        Some((fb, tr, n)) => (fb, Some(tr), n as u64),
        None => (
            row.last_feedback
                .as_deref()
                .and_then(|s| serde_json::from_str::<Option<Feedback>>(s).ok())
                .flatten(),
            row.tracking
                .as_deref()
                .and_then(|s| serde_json::from_str(s).ok()),
            row.feedback_samples.max(0) as u64,
        ),
    };
    ExecutionView {
        row,
        last_feedback,
        tracking,
        feedback_samples,
    }
}
