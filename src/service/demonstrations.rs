//! Demonstrations: the synthetic study generator as a job.

use uuid::Uuid;

use super::{Context, Error};
use crate::human::{self, HumanError, StudyConfig};
use crate::jobs::{JobContext, JobError, JobOutput, JobRecord, ResultRef};
use crate::store::demonstrations as repo;
use crate::store::now;

/// A demonstration error: bad input at the field it names, or a bug for unreadable storage.
pub fn human_error(e: HumanError) -> Error {
    match e {
        HumanError::MalformedStorage { .. } => Error::internal(e),
        e => {
            let path = e.path();
            let path = if path.is_empty() {
                "$".to_string()
            } else {
                format!("$.{path}")
            };
            Error::invalid(path, e.to_string())
        }
    }
}

/// Checks the study parameters and submits the study as a job. Each demonstration goes
/// through the same ingest path as uploads and is labelled synthetic; its `external_id` is
/// derived from the seed and the trial, so repeating a study stores nothing twice.
pub async fn submit_study(ctx: &Context, cfg: StudyConfig) -> Result<JobRecord, Error> {
    cfg.validate().map_err(|e| match e {
        HumanError::InvalidParameter {
            field,
            reason,
            value,
        } => Error::invalid(format!("$.{field}"), format!("{reason} (got {value})")),
        e => human_error(e),
    })?;
    Ok(ctx
        .jobs
        .submit("synthetic_demonstrations", move |ctx: JobContext| {
            run_study(&ctx, &cfg)
        })
        .await?)
}

fn run_study(ctx: &JobContext, cfg: &StudyConfig) -> Result<JobOutput, JobError> {
    let trials = cfg.trials();
    let n = trials.len();
    let mut demos = Vec::with_capacity(n);
    for (i, spec) in trials.iter().enumerate() {
        ctx.check_cancelled()?;
        let input = human::synth::generate_trial(spec, cfg.seed).map_err(JobError::failed)?;
        demos.push(human::ingest(&input).map_err(JobError::failed)?);
        ctx.progress((i + 1) as f64 / n as f64, format!("trial {} of {n}", i + 1));
    }
    Ok(JobOutput::persist_with(move |job_id, tx| {
        Box::pin(async move {
            let created_at = now();
            let (mut first, mut stored) = (None, 0usize);
            for demo in &demos {
                let ext = demo.labels.external_id.as_deref().unwrap_or_default();
                if let Some(row) = repo::get_by_external_id(tx, ext).await? {
                    first.get_or_insert(row.id);
                    continue;
                }
                let id = Uuid::new_v4().to_string();
                repo::insert(tx, &id, Some(&job_id.to_string()), demo, &created_at).await?;
                first.get_or_insert(id);
                stored += 1;
            }
            tracing::info!(stored, total = demos.len(), "synthetic study stored");
            let first = first.ok_or_else(|| anyhow::anyhow!("the study produced nothing"))?;
            Ok(ResultRef::new("demonstrations", first))
        })
    })
    .with_message(format!(
        "{n} demonstrations generated; new ones are listed by GET /v1/demonstrations?job_id={}, \
         all synthetic ones by ?synthetic=true",
        ctx.id()
    )))
}
