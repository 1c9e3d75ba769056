//! Demonstrations: upload (ingest, idempotent by external id), list, get, derived frames,
//! delete, and the synthetic study generator as a job.

use uuid::Uuid;

use super::{Context, Error};
use crate::human::{
    self, Demonstration, DemonstrationInput, HumanError, HumanFrame, StudyConfig, unpack_frames,
};
use crate::jobs::{JobContext, JobError, JobOutput, JobRecord, ResultRef};
use crate::store::demonstrations::{self as repo, Deleted};
use crate::store::{blob, is_unique_violation, now};

pub use crate::store::demonstrations::{DemonstrationFilter, DemonstrationRow};

fn not_found(id: &str) -> Error {
    Error::not_found("demonstration", id)
}

/// Ingests and stores a demonstration. With an `external_id` already stored, nothing is
/// stored and the stored record comes back with `false` (not created), but only for a valid
/// upload: the ingest validates first, so that a bad body is the same 422 whether or not its
/// id is known.
pub async fn upload(
    ctx: &Context,
    input: DemonstrationInput,
) -> Result<(DemonstrationRow, bool), Error> {
    let demo = ingest_blocking(input).await?;
    if let Some(ext) = &demo.labels.external_id {
        let mut conn = ctx.db.acquire().await?;
        if let Some(row) = repo::get_by_external_id(&mut conn, ext).await? {
            return Ok((row, false));
        }
    }
    let id = Uuid::new_v4().to_string();
    let mut tx = crate::store::begin_write(&ctx.db).await?;
    match repo::insert(&mut tx, &id, None, &demo, &now()).await {
        Ok(()) => tx.commit().await?,
        Err(e) if is_unique_violation(&e) => {
            // A concurrent upload with the same external id won the race: return its record.
            drop(tx);
            let ext = demo.labels.external_id.as_deref().unwrap_or_default();
            let mut conn = ctx.db.acquire().await?;
            let row = repo::get_by_external_id(&mut conn, ext)
                .await?
                .ok_or_else(|| {
                    Error::Conflict("a demonstration with this id already exists".into())
                })?;
            return Ok((row, false));
        }
        Err(e) => return Err(e.into()),
    }
    Ok((get(ctx, &id).await?, true))
}

async fn ingest_blocking(input: DemonstrationInput) -> Result<Demonstration, Error> {
    tokio::task::spawn_blocking(move || human::ingest(&input))
        .await
        .map_err(|e| Error::internal(anyhow::anyhow!("ingest task failed: {e}")))?
        .map_err(human_error)
}

/// A page of demonstrations, newest first, and how many match the filter.
pub async fn list(
    ctx: &Context,
    filter: &DemonstrationFilter,
) -> Result<(Vec<DemonstrationRow>, i64), Error> {
    Ok(repo::list(&ctx.db, filter).await?)
}

pub async fn get(ctx: &Context, id: &str) -> Result<DemonstrationRow, Error> {
    repo::get(&ctx.db, id).await?.ok_or_else(|| not_found(id))
}

/// A demonstration with its derived frames and their resampled glove angles.
pub async fn frames(
    ctx: &Context,
    id: &str,
) -> Result<(DemonstrationRow, Vec<HumanFrame>, Vec<[f64; 22]>), Error> {
    let row = get(ctx, id).await?;
    let bytes = repo::frames(&ctx.db, id)
        .await?
        .ok_or_else(|| not_found(id))?;
    let array = blob::decode::<f64>(&bytes).map_err(Error::internal)?;
    let (frames, glove) = unpack_frames(&array.data).map_err(human_error)?;
    Ok((row, frames, glove))
}

/// Deletes a demonstration; while mappings use it that is a conflict unless `cascade`, which
/// deletes them too.
pub async fn delete(ctx: &Context, id: &str, cascade: bool) -> Result<(), Error> {
    match repo::delete(&ctx.db, id, cascade).await? {
        Deleted::Yes { .. } => Ok(()),
        Deleted::NotFound => Err(not_found(id)),
        Deleted::InUse { mappings } => Err(Error::Conflict(format!(
            "demonstration {id} is used by mapping(s) {}; delete them first or pass cascade=true",
            mappings.join(", ")
        ))),
    }
}

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
