//! The service at a glance (`GET /v1/status`, the dashboard's overview): whether first-start
//! seeding is still preparing the bundled robots' default models and how far it is, which robot
//! can plan without naming a model (and since when), the job queue and the connected workers.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::robots::{DefaultModelDto, DefaultModelState, default_model};
use super::{Context, Error};
use crate::store;
use crate::store::jobs::JobStatus;

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct StatusDto {
    /// Service version.
    pub version: String,
    pub seeding: SeedingDto,
    /// Every robot (bundled first) with its default model.
    pub robots: Vec<RobotStatusDto>,
    pub jobs: JobCountsDto,
    /// Bridge workers connected now.
    pub workers: usize,
}

/// First-start seeding: the default synthetic study mapped onto every bundled robot without a
/// model, and each one's default model trained from it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct SeedingDto {
    pub state: SeedingState,
    /// Bundled robots.
    pub bundled: usize,
    /// Bundled robots with a trained default model.
    pub trained: usize,
    /// `running`: the step each robot still waits for.
    pub pending: Vec<SeedStepDto>,
}

/// `disabled` (`--no-seed`), `running`, `done` (every bundled robot has a default model) or
/// `incomplete` (seeding ended and some bundled robot has none: see its failed job in
/// `/v1/jobs`, or train one with `POST /v1/models`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum SeedingState {
    Disabled,
    Running,
    Done,
    Incomplete,
}

/// The seeding job a robot waits for.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct SeedStepDto {
    pub robot: String,
    pub job_id: String,
    /// The job's kind: `synthetic_demonstrations`, `mapping` or `model`.
    pub kind: String,
    pub status: JobStatus,
    /// Completed fraction of that job, 0 to 1.
    pub fraction: f64,
    pub message: Option<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RobotStatusDto {
    pub id: String,
    pub name: String,
    pub bundled: bool,
    pub default_model: DefaultModelDto,
}

/// Jobs by state.
#[derive(Debug, Clone, Default, Serialize, Deserialize, ToSchema)]
pub struct JobCountsDto {
    pub queued: i64,
    pub running: i64,
    pub succeeded: i64,
    pub failed: i64,
    pub cancelled: i64,
}

pub async fn status(ctx: &Context) -> Result<StatusDto, Error> {
    let mut robots = Vec::new();
    let mut pending = Vec::new();
    for row in store::robots::list(&ctx.db).await? {
        let model = default_model(ctx, &row.id).await?;
        if let (DefaultModelState::Seeding, Some(job)) = (model.state, &model.job_id) {
            let record = match job.parse() {
                Ok(id) => store::jobs::get(&ctx.db, id).await?,
                Err(_) => None,
            };
            if let Some(j) = record {
                pending.push(SeedStepDto {
                    robot: row.id.clone(),
                    job_id: job.clone(),
                    kind: j.kind,
                    status: j.status,
                    fraction: j.progress.fraction,
                    message: j.progress.message,
                });
            }
        }
        robots.push(RobotStatusDto {
            id: row.id,
            name: row.name,
            bundled: row.bundled,
            default_model: model,
        });
    }
    let bundled = robots.iter().filter(|r| r.bundled).count();
    let trained = robots
        .iter()
        .filter(|r| r.bundled && r.default_model.state == DefaultModelState::Trained)
        .count();
    let running = robots
        .iter()
        .any(|r| r.default_model.state == DefaultModelState::Seeding);
    let state = if running {
        SeedingState::Running
    } else if trained == bundled {
        SeedingState::Done
    } else if ctx.config.no_seed {
        SeedingState::Disabled
    } else {
        SeedingState::Incomplete
    };
    let mut jobs = JobCountsDto::default();
    for (s, n) in store::jobs::count_by_status(&ctx.db).await? {
        *match s {
            JobStatus::Queued => &mut jobs.queued,
            JobStatus::Running => &mut jobs.running,
            JobStatus::Succeeded => &mut jobs.succeeded,
            JobStatus::Failed => &mut jobs.failed,
            JobStatus::Cancelled => &mut jobs.cancelled,
        } = n;
    }
    Ok(StatusDto {
        version: env!("CARGO_PKG_VERSION").to_owned(),
        seeding: SeedingDto {
            state,
            bundled,
            trained,
            pending,
        },
        robots,
        jobs,
        workers: ctx.bridges.workers().len(),
    })
}
