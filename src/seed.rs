//! First start: make an empty database immediately useful (issue 10).
//!
//! When a bundled system has no trained model, a background task generates the default
//! synthetic study, maps it onto every such system and trains each one's default model. It does
//! so as a client of the service's own API (in-process requests through the router, no
//! network): every step is an ordinary job with progress in `/v1/jobs` and the dashboard, goes
//! through the same validation, and stores exactly what a user making the same calls would. A
//! crash midway leaves finished steps stored and unfinished ones `failed: interrupted`; the
//! next start repeats only what is still missing (the study's demonstrations have deterministic
//! external ids, so they are not duplicated).
//!
//! While a system's model is being prepared, [`SeedStatus::pending_job`] names the job to
//! watch, so requests that need the default model answer 503 with it instead of an error.

use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use axum::Router;
use axum::body::Body;
use axum::http::{Method, Request, StatusCode, header};
use serde_json::{Value, json};
use tower::ServiceExt;
use uuid::Uuid;

use crate::jobs::JobStatus;
use crate::service::Context as AppState;
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
    // One router for every in-process request of this run (building it mounts Swagger UI).
    let router = crate::api::router(state.clone(), Router::new());
    let study = submit_study(&router).await?;
    for r in &missing {
        state.seed.set(r, study);
    }
    tracing::info!(robots = ?missing, job = %study, "seeding: generating the default synthetic study, then mapping and training");
    let state = state.clone();
    tokio::spawn(async move {
        let started = Instant::now();
        match run(&state, &router, study, &missing).await {
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

async fn run(
    state: &AppState,
    router: &Router,
    study: Uuid,
    robots: &[String],
) -> anyhow::Result<()> {
    wait(state, study, "synthetic study").await?;
    let demos =
        store::demonstrations::ids_by_external_prefix(&state.db, &format!("synth-{STUDY_SEED}-"))
            .await?;
    if demos.is_empty() {
        bail!("the synthetic study stored no demonstrations");
    }
    let mut tasks = tokio::task::JoinSet::new();
    for r in robots {
        let (state, router, robot, demos) =
            (state.clone(), router.clone(), r.clone(), demos.clone());
        tasks.spawn(async move {
            let r = seed_robot(&state, &router, &robot, demos).await;
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

async fn seed_robot(
    state: &AppState,
    router: &Router,
    robot: &str,
    demos: Vec<String>,
) -> anyhow::Result<()> {
    let (job, mapping) = submit(
        router,
        "/v1/mappings",
        json!({"robot": robot, "demonstrations": demos, "output_rate_hz": MAPPING_RATE_HZ}),
    )
    .await?;
    state.seed.set(robot, job);
    tracing::info!(robot, %job, "seeding: mapping the study");
    wait(state, job, "mapping").await?;
    let mapping = mapping.context("the mapping answer has no Content-Location")?;
    let (job, model) = submit(
        router,
        "/v1/models",
        json!({"robot": robot, "mappings": [mapping], "held_out": false, "default": true}),
    )
    .await?;
    state.seed.set(robot, job);
    tracing::info!(robot, %job, "seeding: training the default model");
    wait(state, job, "training").await?;
    tracing::info!(
        robot,
        model = model.as_deref().unwrap_or("?"),
        "seeding: default model ready"
    );
    Ok(())
}

async fn submit_study(router: &Router) -> anyhow::Result<Uuid> {
    Ok(submit(
        router,
        "/v1/demonstrations/synthetic",
        json!({"seed": STUDY_SEED}),
    )
    .await?
    .0)
}

/// POSTs `body` to a job-creating route in-process; returns the job id (`Location`) and the
/// resource id the job fills (`Content-Location`), if given.
async fn submit(
    router: &Router,
    path: &str,
    body: Value,
) -> anyhow::Result<(Uuid, Option<String>)> {
    let request = Request::builder()
        .method(Method::POST)
        .uri(path)
        .header(header::CONTENT_TYPE, "application/json")
        .body(Body::from(body.to_string()))?;
    let response = router
        .clone()
        .oneshot(request)
        .await
        .expect("the router is infallible");
    let (parts, body) = response.into_parts();
    let status = parts.status;
    let header_value = |name| {
        parts
            .headers
            .get(name)
            .and_then(|v| v.to_str().ok())
            .map(str::to_owned)
    };
    let job = header_value(header::LOCATION);
    let resource = header_value(header::CONTENT_LOCATION);
    if status != StatusCode::ACCEPTED {
        let bytes = axum::body::to_bytes(body, 64 * 1024)
            .await
            .unwrap_or_default();
        bail!(
            "POST {path} answered {status}: {}",
            String::from_utf8_lossy(&bytes)
        );
    }
    let job = job
        .as_deref()
        .and_then(|l| l.strip_prefix("/v1/jobs/"))
        .and_then(|id| id.parse().ok())
        .with_context(|| format!("POST {path}: no job Location"))?;
    let resource = resource.and_then(|l| l.rsplit('/').next().map(str::to_owned));
    Ok((job, resource))
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
