//! First start: make an empty database immediately useful (issue 10).
//!
//! When a bundled system has no trained model, a background task generates the default
//! synthetic study, maps it onto every such system and trains each one's default model. It
//! calls the same use cases as the API's handlers ([`crate::service`]): every step is an
//! ordinary job with progress in `/v1/jobs` and the dashboard, goes through the same
//! validation, and stores exactly what a user making the same requests would. A
//! crash midway leaves finished steps stored and unfinished ones `failed: interrupted`; the
//! next start repeats only what is still missing (the study's demonstrations have deterministic
//! external ids, so they are not duplicated).
//!
//! While a system's model is being prepared, [`SeedStatus::pending_job`] names the job to
//! watch, so requests that need the default model answer 503 with it instead of an error.

use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use uuid::Uuid;

use crate::human::StudyConfig;
use crate::jobs::JobStatus;
use crate::service::Context as AppState;
use crate::service::mappings::{MappingIn, SelectionIn};
use crate::service::models::CreateModel;
use crate::service::{self, demonstrations};
use crate::store;

/// Seed of the default synthetic study (the paper's design: 5 subjects × 5 positions × 10
/// trials).
pub const STUDY_SEED: u64 = 1;
/// Rate of the mapped trajectories the default models learn from (Hz). Reach-to-grasp motion
/// has no content above a few Hz; 30 Hz keeps seeding fast without losing shape.
pub const MAPPING_RATE_HZ: f64 = 30.0;
/// Longest a seeding step may take before the task gives up on it (a bound, not a target).
const STEP_TIMEOUT: Duration = Duration::from_secs(30 * 60);

/// Starts seeding in the background when some bundled system lacks a model (no-op when
/// `--no-seed` is set). Returns once the task is spawned and the status is filled in, so a
/// request right after start already sees the pending job.
pub async fn start(state: &AppState) -> anyhow::Result<()> {
    if state.config.no_seed {
        return Ok(());
    }
    let missing = robots_missing_a_model(state).await?;
    if missing.is_empty() {
        tracing::info!("seeding: every bundled system has a default model");
        return Ok(());
    }
    let study = submit_study(state).await?;
    for r in &missing {
        state.seed.set(r, study);
    }
    tracing::info!(robots = ?missing, job = %study, "seeding: generating the default synthetic study, then mapping and training");
    let state = state.clone();
    tokio::spawn(async move {
        let started = Instant::now();
        match run(&state, study, &missing).await {
            Ok(()) => tracing::info!(
                seconds = started.elapsed().as_secs_f64(),
                "seeding: finished; every bundled system has a default model"
            ),
            Err(e) => tracing::error!(error = format!("{e:#}"), "seeding stopped"),
        }
        for r in &missing {
            state.seed.clear(r);
        }
    });
    Ok(())
}

async fn robots_missing_a_model(state: &AppState) -> anyhow::Result<Vec<String>> {
    let mut missing = Vec::new();
    for r in store::robots::list(&state.db).await? {
        if r.bundled
            && store::models::default_model_for(&state.db, &r.id)
                .await?
                .is_none()
        {
            missing.push(r.id);
        }
    }
    Ok(missing)
}

async fn run(state: &AppState, study: Uuid, robots: &[String]) -> anyhow::Result<()> {
    wait(state, study, "synthetic study").await?;
    let demos =
        store::demonstrations::ids_by_external_prefix(&state.db, &format!("synth-{STUDY_SEED}-"))
            .await?;
    if demos.is_empty() {
        bail!("the synthetic study stored no demonstrations");
    }
    let mut tasks = tokio::task::JoinSet::new();
    for r in robots {
        let (state, robot, demos) = (state.clone(), r.clone(), demos.clone());
        tasks.spawn(async move {
            let r = seed_robot(&state, &robot, demos).await;
            state.seed.clear(&robot);
            r.with_context(|| format!("seeding {robot}"))
        });
    }
    let mut first_error = None;
    while let Some(joined) = tasks.join_next().await {
        match joined {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                tracing::error!(error = format!("{e:#}"), "seeding: a system failed");
                first_error.get_or_insert(e);
            }
            Err(e) => {
                first_error.get_or_insert(e.into());
            }
        }
    }
    first_error.map_or(Ok(()), Err)
}

async fn seed_robot(state: &AppState, robot: &str, demos: Vec<String>) -> anyhow::Result<()> {
    let request = MappingIn {
        robot: robot.to_owned(),
        demonstrations: SelectionIn::Ids(demos),
        weights: Default::default(),
        registration: Default::default(),
        output_rate_hz: Some(MAPPING_RATE_HZ),
    };
    let (job, mapping) = service::mappings::submit(state, &request)
        .await
        .map_err(|e| step_failed("mapping", e))?;
    let job = job.id;
    state.seed.set(robot, job);
    tracing::info!(robot, %job, "seeding: mapping the study");
    wait(state, job, "mapping").await?;
    let request = CreateModel {
        robot: robot.to_owned(),
        mappings: vec![mapping],
        components: None,
        variance_threshold: None,
        spline_intervals: None,
        regularisation: None,
        k: None,
        held_out: Some(false),
        residual_profile: None,
        profile_ridge: None,
        certificate: None,
        acceleration_limit: None,
        jerk_limit: None,
        control: None,
        default: true,
    };
    let (job, model) = service::models::train_model(state, &request)
        .await
        .map_err(|e| step_failed("training", e))?;
    let job = job.id;
    state.seed.set(robot, job);
    tracing::info!(robot, %job, "seeding: training the default model");
    wait(state, job, "training").await?;
    tracing::info!(
        robot,
        model = %model,
        "seeding: default model ready"
    );
    Ok(())
}

async fn submit_study(state: &AppState) -> anyhow::Result<Uuid> {
    let config = StudyConfig {
        seed: STUDY_SEED,
        ..StudyConfig::default()
    };
    let job = demonstrations::submit_study(state, config)
        .await
        .map_err(|e| step_failed("synthetic study", e))?;
    Ok(job.id)
}

/// A step the service refused: its error, which names the offending field if any.
fn step_failed(what: &str, e: service::Error) -> anyhow::Error {
    let detail = match &e {
        service::Error::Invalid(fields) => fields
            .iter()
            .map(|f| format!("{}: {}", f.field, f.message))
            .collect::<Vec<_>>()
            .join("; "),
        other => other.to_string(),
    };
    anyhow::anyhow!("submitting the {what} failed: {detail}")
}

/// Waits for a job to end; an error unless it succeeded.
async fn wait(state: &AppState, id: Uuid, what: &str) -> anyhow::Result<()> {
    let finished = async {
        if let Some(mut rx) = state.jobs.subscribe(id) {
            while !rx.borrow().status.is_final() {
                if rx.changed().await.is_err() {
                    break;
                }
            }
        }
        state.jobs.get(id).await
    };
    let job = tokio::time::timeout(STEP_TIMEOUT, finished)
        .await
        .with_context(|| format!("the {what} job {id} did not finish in time"))?
        .with_context(|| format!("cannot read the {what} job {id}"))?;
    match job.status {
        JobStatus::Succeeded => Ok(()),
        other => bail!(
            "the {what} job {id} ended {other}: {}",
            job.error.map(|e| e.message).unwrap_or_default()
        ),
    }
}
