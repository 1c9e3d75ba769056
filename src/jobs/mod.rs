//! Job runner: blocking CPU work off the async runtime, progress, cancellation.
//!
//! # Running long work as a job
//!
//! ```ignore
//! use reachgrasp::jobs::{JobContext, JobError, JobOutput, ResultRef};
//!
//! // In a handler (state: AppState): parse and validate everything first, so bad input is a
//! // 4xx before any job exists. Move owned, validated inputs into the closure.
//! let job = state.jobs.submit("mapping", move |ctx: JobContext| {
//!     let mut rows = Vec::with_capacity(frames.len());
//!     for (i, frame) in frames.iter().enumerate() {
//!         ctx.check_cancelled()?;                       // cooperative cancellation
//!         rows.push(solve_frame(&model, frame).map_err(JobError::failed)?);
//!         ctx.progress((i + 1) as f64 / frames.len() as f64, format!("frame {}", i + 1));
//!     }
//!     // Nothing touches the database inside the closure (it runs on a blocking thread);
//!     // the persist step runs afterwards on the runtime, inside the transaction that also
//!     // marks the job `succeeded` and stores the returned result reference.
//!     Ok(JobOutput::persist_with(move |job_id, tx| Box::pin(async move {
//!         let id = uuid::Uuid::new_v4();
//!         sqlx::query("INSERT INTO mappings (id, job_id, q) VALUES (?, ?, ?)")
//!             .bind(id.to_string()).bind(job_id.to_string())
//!             .bind(reachgrasp::store::blob::encode_matrix(&q_matrix))
//!             .execute(&mut **tx).await?;
//!         Ok(ResultRef::new("mappings", id))           // -> result.href = /v1/mappings/{id}
//!     })))
//! }).await?;
//! // Answer `202 Accepted` with the job (`Location: /v1/jobs/{id}`).
//! ```
//!
//! * The closure runs on tokio's blocking pool (`spawn_blocking`, inside the job's tracing span),
//!   at most `job_concurrency` at a time (a semaphore); further jobs wait `queued`, none are dropped.
//!   It runs inside the runner's [`crate::parallel::Pool`] of `job_concurrency` threads, so the
//!   parallel maps of all running jobs share those threads.
//! * [`JobContext::progress`] is cheap (an in-memory update seen at once by SSE subscribers); the
//!   database copy is written at most every [`PROGRESS_PERSIST_INTERVAL`].
//! * Return [`JobError::Cancelled`] (e.g. via `ctx.check_cancelled()?`) when cancellation is seen;
//!   [`JobError::Failed`] carries a message for the user; [`JobError::Internal`] is logged and
//!   shown only as "internal error". A panic is caught and recorded as `failed` / `internal`.
//! * The persist step ([`PersistResult`]) gets the job id and a transaction; if it fails, the
//!   transaction rolls back (no partial result rows) and the job is `failed` / `internal`.
//! * A job that mostly waits (a verification waits for physics workers) is submitted with
//!   [`JobRunner::submit_waiting`]: its future runs on the runtime, at once and outside the
//!   `job_concurrency` slots and their threads, which are for computation (the plans it makes
//!   pass the service's compute gate like any request's). Progress, cancellation, the persist
//!   step and the records are the same.
//! * At start ([`JobRunner::start`]) any job left `queued` or `running` by a previous process is
//!   marked `failed` with reason `interrupted`. On graceful shutdown, running jobs are asked to
//!   stop and recorded the same way.

pub mod testing;

use std::collections::HashMap;
use std::fmt;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures::future::BoxFuture;
use sqlx::{Sqlite, SqlitePool, Transaction};
use tokio::sync::{Notify, Semaphore, watch};
use tracing::Instrument;
use uuid::Uuid;

use crate::store;
// The job records are stored rows; they live with their table so that the store needs no
// type of the runner.
pub(crate) use crate::store::jobs::Finish;
pub use crate::store::jobs::{JobFailure, JobProgress, JobRecord, JobStatus, ResultRef};

/// How often the progress of a running job is copied to the database (SSE sees every update).
pub const PROGRESS_PERSIST_INTERVAL: Duration = Duration::from_millis(500);

/// How a job's closure ends without output.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JobError {
    /// The job saw a cancellation request and stopped.
    #[error("cancelled")]
    Cancelled,
    /// The computation failed for a reason the user should see.
    #[error("{0}")]
    Failed(String),
    /// A bug or an environment failure: logged in full, reported as "internal error".
    #[error("internal: {0}")]
    Internal(String),
}

impl JobError {
    /// A user-facing failure from any displayable domain error.
    pub fn failed(err: impl fmt::Display) -> Self {
        JobError::Failed(err.to_string())
    }
}

/// Stores a job's result inside the transaction that marks the job `succeeded`.
pub trait PersistResult: Send + 'static {
    /// Writes the result rows and returns where they are. `job_id` is the running job.
    fn persist<'c>(
        self: Box<Self>,
        job_id: Uuid,
        tx: &'c mut Transaction<'static, Sqlite>,
    ) -> BoxFuture<'c, anyhow::Result<ResultRef>>;
}

struct PersistFn<F>(F);

impl<F> PersistResult for PersistFn<F>
where
    F: for<'c> FnOnce(
            Uuid,
            &'c mut Transaction<'static, Sqlite>,
        ) -> BoxFuture<'c, anyhow::Result<ResultRef>>
        + Send
        + 'static,
{
    fn persist<'c>(
        self: Box<Self>,
        job_id: Uuid,
        tx: &'c mut Transaction<'static, Sqlite>,
    ) -> BoxFuture<'c, anyhow::Result<ResultRef>> {
        (self.0)(job_id, tx)
    }
}

/// What a successful job closure returns.
pub struct JobOutput {
    persist: Option<Box<dyn PersistResult>>,
    message: Option<String>,
}

impl JobOutput {
    /// Success with no stored result.
    pub fn empty() -> Self {
        JobOutput {
            persist: None,
            message: None,
        }
    }

    /// Success whose result is stored by `p` (see [`PersistResult`]).
    pub fn persist(p: impl PersistResult) -> Self {
        JobOutput {
            persist: Some(Box::new(p)),
            message: None,
        }
    }

    /// Success whose result is stored by the closure `f(job_id, tx)`, returning
    /// `Box::pin(async move { ...; Ok(ResultRef::new("mappings", id)) })`.
    pub fn persist_with<F>(f: F) -> Self
    where
        F: for<'c> FnOnce(
                Uuid,
                &'c mut Transaction<'static, Sqlite>,
            ) -> BoxFuture<'c, anyhow::Result<ResultRef>>
            + Send
            + 'static,
    {
        JobOutput::persist(PersistFn(f))
    }

    /// The final progress message (default "done").
    pub fn with_message(mut self, message: impl Into<String>) -> Self {
        self.message = Some(message.into());
        self
    }
}

const NOT_CANCELLED: u8 = 0;
const CANCEL_BY_USER: u8 = 1;
const CANCEL_BY_SHUTDOWN: u8 = 2;

/// Cancellation state shared by the API, the driver task and the blocking closure.
struct CancelState {
    why: AtomicU8,
    notify: Notify,
}

impl CancelState {
    fn new() -> Self {
        CancelState {
            why: AtomicU8::new(NOT_CANCELLED),
            notify: Notify::new(),
        }
    }

    fn get(&self) -> u8 {
        self.why.load(Ordering::Acquire)
    }

    fn request(&self, why: u8) {
        // The first reason wins: a user cancel followed by a shutdown stays a user cancel.
        let _ = self
            .why
            .compare_exchange(NOT_CANCELLED, why, Ordering::AcqRel, Ordering::Acquire);
        self.notify.notify_waiters();
    }

    async fn requested(&self) {
        loop {
            let notified = self.notify.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if self.get() != NOT_CANCELLED {
                return;
            }
            notified.await;
        }
    }
}

/// Handed to a job's closure: progress reporting and cancellation checks.
pub struct JobContext {
    id: Uuid,
    cancel: Arc<CancelState>,
    events: watch::Sender<JobRecord>,
}

impl JobContext {
    pub fn id(&self) -> Uuid {
        self.id
    }

    /// Reports progress: `fraction` is clamped to [0, 1]; a NaN fraction keeps the previous one.
    pub fn progress(&self, fraction: f64, message: impl Into<String>) {
        let message = message.into();
        self.events.send_modify(|r| {
            if !fraction.is_nan() {
                r.progress.fraction = fraction.clamp(0.0, 1.0);
            }
            r.progress.message = Some(message);
        });
    }

    /// True once a cancellation (by a user or by shutdown) was requested.
    pub fn is_cancelled(&self) -> bool {
        self.cancel.get() != NOT_CANCELLED
    }

    /// `Err(JobError::Cancelled)` once a cancellation was requested, for use with `?`.
    pub fn check_cancelled(&self) -> Result<(), JobError> {
        if self.is_cancelled() {
            Err(JobError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Errors of the runner's operations.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunnerError {
    #[error("job {0} not found")]
    NotFound(Uuid),
    #[error("job {id} is already {status}")]
    AlreadyFinished { id: Uuid, status: JobStatus },
    #[error("the service is shutting down")]
    ShuttingDown,
    #[error("database error: {0}")]
    Store(#[from] sqlx::Error),
}

struct Live {
    cancel: Arc<CancelState>,
    events: watch::Sender<JobRecord>,
}

struct Inner {
    pool: SqlitePool,
    /// The threads every job's parallel maps run on (as many as jobs may run at once).
    workers: crate::parallel::Pool,
    permits: Arc<Semaphore>,
    concurrency: usize,
    live: Mutex<HashMap<Uuid, Live>>,
    drained: Notify,
    shutting_down: AtomicBool,
}

/// Runs jobs; cheap to clone (shared state).
#[derive(Clone)]
pub struct JobRunner {
    inner: Arc<Inner>,
}

impl fmt::Debug for JobRunner {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("JobRunner")
            .field("concurrency", &self.inner.concurrency)
            .finish_non_exhaustive()
    }
}

impl JobRunner {
    /// Marks jobs a previous process left `queued`/`running` as `failed: interrupted`, then
    /// returns a runner that runs at most `concurrency` (at least 1) jobs at a time.
    pub async fn start(pool: SqlitePool, concurrency: usize) -> Result<Self, sqlx::Error> {
        let recovered = store::jobs::mark_interrupted(&pool, &store::now()).await?;
        if recovered > 0 {
            tracing::warn!(
                recovered,
                "jobs of a previous process marked failed: interrupted"
            );
        }
        let concurrency = concurrency.max(1);
        Ok(JobRunner {
            inner: Arc::new(Inner {
                pool,
                workers: crate::parallel::Pool::new(concurrency),
                permits: Arc::new(Semaphore::new(concurrency)),
                concurrency,
                live: Mutex::new(HashMap::new()),
                drained: Notify::new(),
                shutting_down: AtomicBool::new(false),
            }),
        })
    }

    /// The configured number of jobs that may run at once.
    pub fn concurrency(&self) -> usize {
        self.inner.concurrency
    }

    /// The threads the jobs' parallel maps run on.
    pub fn workers(&self) -> &crate::parallel::Pool {
        &self.inner.workers
    }

    /// Persists a new `queued` job of `kind` and schedules `work` on the blocking pool.
    pub async fn submit<F>(&self, kind: &str, work: F) -> Result<JobRecord, RunnerError>
    where
        F: FnOnce(JobContext) -> Result<JobOutput, JobError> + Send + 'static,
    {
        self.enqueue(kind, Work::Blocking(Box::new(work))).await
    }

    /// Persists a new job of `kind` whose work waits more than it computes (see the module
    /// docs): `work`'s future starts at once on the runtime and takes no job slot.
    pub async fn submit_waiting<F>(&self, kind: &str, work: F) -> Result<JobRecord, RunnerError>
    where
        F: FnOnce(JobContext) -> BoxFuture<'static, Result<JobOutput, JobError>> + Send + 'static,
    {
        self.enqueue(kind, Work::Waiting(Box::new(work))).await
    }

    async fn enqueue(&self, kind: &str, work: Work) -> Result<JobRecord, RunnerError> {
        if self.inner.shutting_down.load(Ordering::Acquire) {
            return Err(RunnerError::ShuttingDown);
        }
        let permit: PermitFuture = match &work {
            Work::Blocking(_) => {
                // Take a place in the semaphore's FIFO queue now (the first poll registers the
                // waiter), so jobs start in submission order whatever order their tasks are
                // scheduled in.
                let slots = self.inner.permits.clone();
                let mut permit: PermitFuture =
                    Box::pin(async move { slots.acquire_owned().await.map(Some) });
                match futures::poll!(permit.as_mut()) {
                    std::task::Poll::Ready(p) => Box::pin(std::future::ready(p)),
                    std::task::Poll::Pending => permit,
                }
            }
            Work::Waiting(_) => Box::pin(std::future::ready(Ok(None))),
        };
        let record = JobRecord {
            id: Uuid::new_v4(),
            kind: kind.to_owned(),
            status: JobStatus::Queued,
            progress: JobProgress {
                fraction: 0.0,
                message: None,
            },
            error: None,
            result: None,
            cancel_requested: false,
            created_at: store::now(),
            started_at: None,
            finished_at: None,
        };
        store::jobs::insert(&self.inner.pool, &record).await?;
        let cancel = Arc::new(CancelState::new());
        let (events, _) = watch::channel(record.clone());
        self.inner.live.lock().expect("live jobs lock").insert(
            record.id,
            Live {
                cancel: cancel.clone(),
                events: events.clone(),
            },
        );
        let span = tracing::info_span!("job", id = %record.id, kind = %record.kind);
        let inner = self.inner.clone();
        tokio::spawn(drive(inner, record.id, permit, work, cancel, events).instrument(span));
        Ok(record)
    }

    /// The job as stored.
    pub async fn get(&self, id: Uuid) -> Result<JobRecord, RunnerError> {
        store::jobs::get(&self.inner.pool, id)
            .await?
            .ok_or(RunnerError::NotFound(id))
    }

    /// Jobs, newest first.
    pub async fn list(
        &self,
        filter: &store::jobs::JobFilter,
    ) -> Result<Vec<JobRecord>, RunnerError> {
        Ok(store::jobs::list(&self.inner.pool, filter).await?)
    }

    /// Requests cooperative cancellation. A queued job is cancelled before it starts; a running
    /// job stops at its next `check_cancelled`. Finished jobs cannot be cancelled.
    pub async fn cancel(&self, id: Uuid) -> Result<JobRecord, RunnerError> {
        let record = self.get(id).await?;
        if record.status.is_final() {
            return Err(RunnerError::AlreadyFinished {
                id,
                status: record.status,
            });
        }
        let live = self
            .inner
            .live
            .lock()
            .expect("live jobs lock")
            .get(&id)
            .map(|l| (l.cancel.clone(), l.events.clone()));
        match live {
            Some((cancel, events)) => {
                store::jobs::set_cancel_requested(&self.inner.pool, id).await?;
                events.send_modify(|r| r.cancel_requested = true);
                cancel.request(CANCEL_BY_USER);
                Ok(events.borrow().clone())
            }
            None => {
                // Not driven by this process (it finished meanwhile, or a stale row): settle it
                // in the database only if it is still unfinished.
                store::jobs::finish(&self.inner.pool, id, &Finish::cancelled(), &store::now())
                    .await?;
                let record = self.get(id).await?;
                if record.status == JobStatus::Cancelled {
                    Ok(record)
                } else {
                    Err(RunnerError::AlreadyFinished {
                        id,
                        status: record.status,
                    })
                }
            }
        }
    }

    /// Live updates of a job driven by this process; `None` once it has finished (read it from
    /// the store instead). The receiver's last value is always the final record.
    pub fn subscribe(&self, id: Uuid) -> Option<watch::Receiver<JobRecord>> {
        self.inner
            .live
            .lock()
            .expect("live jobs lock")
            .get(&id)
            .map(|l| l.events.subscribe())
    }

    /// Refuses new jobs, asks every live job to stop, and waits up to `grace` for them to be
    /// recorded (`failed: interrupted`, unless they finish first). Jobs still running after
    /// `grace` are recovered as interrupted at the next start.
    pub async fn shutdown(&self, grace: Duration) {
        self.inner.shutting_down.store(true, Ordering::Release);
        let wait = async {
            loop {
                let drained = self.inner.drained.notified();
                tokio::pin!(drained);
                drained.as_mut().enable();
                {
                    let live = self.inner.live.lock().expect("live jobs lock");
                    if live.is_empty() {
                        return;
                    }
                    for l in live.values() {
                        l.cancel.request(CANCEL_BY_SHUTDOWN);
                    }
                }
                drained.await;
            }
        };
        if tokio::time::timeout(grace, wait).await.is_err() {
            tracing::warn!(
                "jobs still running at shutdown; they will be marked interrupted at the next start"
            );
        }
    }
}

const INTERNAL_MESSAGE: &str = "internal error; see the server logs";

/// A job slot once granted (`None`: a waiting job, which takes none).
type PermitFuture = std::pin::Pin<
    Box<
        dyn std::future::Future<
                Output = Result<
                    Option<tokio::sync::OwnedSemaphorePermit>,
                    tokio::sync::AcquireError,
                >,
            > + Send,
    >,
>;

/// What a job runs: a closure on the blocking pool, in a job slot, or a future that mostly
/// waits, on the runtime.
enum Work {
    Blocking(Box<dyn FnOnce(JobContext) -> Result<JobOutput, JobError> + Send>),
    Waiting(Box<dyn FnOnce(JobContext) -> BoxFuture<'static, Result<JobOutput, JobError>> + Send>),
}

async fn drive(
    inner: Arc<Inner>,
    id: Uuid,
    permit: PermitFuture,
    work: Work,
    cancel: Arc<CancelState>,
    events: watch::Sender<JobRecord>,
) {
    let pool = inner.pool.clone();
    let workers = inner.workers.clone();
    let permit = tokio::select! {
        permit = permit => permit.ok(),
        () = cancel.requested() => None,
    };
    let finish = match permit {
        // Closed semaphore cannot happen (never closed); treat like a cancel before start.
        None => {
            if cancel.get() == CANCEL_BY_SHUTDOWN {
                Finish::interrupted()
            } else {
                Finish::cancelled()
            }
        }
        Some(_permit) => run(&pool, &workers, id, work, &cancel, &events).await,
    };
    if let Err(e) = store::jobs::finish(&pool, id, &finish, &store::now()).await {
        tracing::error!(error = %e, "cannot record the end of a job");
    }
    settle(&inner, id, &events).await;
}

/// Publishes the stored final record to subscribers and forgets the live job.
async fn settle(inner: &Inner, id: Uuid, events: &watch::Sender<JobRecord>) {
    match store::jobs::get(&inner.pool, id).await {
        Ok(Some(record)) => {
            events.send_replace(record);
        }
        Ok(None) => tracing::error!("a live job vanished from the store"),
        Err(e) => tracing::error!(error = %e, "cannot read back a finished job"),
    }
    inner.live.lock().expect("live jobs lock").remove(&id);
    inner.drained.notify_waiters();
}

async fn run(
    pool: &SqlitePool,
    workers: &crate::parallel::Pool,
    id: Uuid,
    work: Work,
    cancel: &Arc<CancelState>,
    events: &watch::Sender<JobRecord>,
) -> Finish {
    if cancel.get() != NOT_CANCELLED {
        return if cancel.get() == CANCEL_BY_SHUTDOWN {
            Finish::interrupted()
        } else {
            Finish::cancelled()
        };
    }
    let started = store::now();
    if let Err(e) = store::jobs::mark_running(pool, id, &started).await {
        tracing::error!(error = %e, "cannot record the start of a job");
    }
    events.send_modify(|r| {
        r.status = JobStatus::Running;
        r.started_at = Some(started);
    });
    tracing::info!("job started");

    let ctx = JobContext {
        id,
        cancel: cancel.clone(),
        events: events.clone(),
    };
    let span = tracing::Span::current();
    let workers = workers.clone();
    let mut handle = match work {
        Work::Blocking(work) => {
            tokio::task::spawn_blocking(move || workers.install(|| span.in_scope(|| work(ctx))))
        }
        Work::Waiting(work) => tokio::spawn(work(ctx).instrument(span)),
    };
    let mut persisted = events.borrow().progress.clone();
    let mut tick = tokio::time::interval(PROGRESS_PERSIST_INTERVAL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let joined = loop {
        tokio::select! {
            joined = &mut handle => break joined,
            _ = tick.tick() => {
                let now = events.borrow().progress.clone();
                if now != persisted {
                    if let Err(e) = store::jobs::set_progress(pool, id, &now).await {
                        tracing::warn!(error = %e, "cannot store job progress");
                    }
                    persisted = now;
                }
            }
        }
    };

    match joined {
        Ok(Ok(output)) => match complete(pool, id, output, events).await {
            Ok(()) => {
                tracing::info!("job succeeded");
                // `complete` already committed the final state; writing it again is a no-op
                // because `finish` only touches unfinished jobs.
                Finish {
                    status: JobStatus::Succeeded,
                    reason: None,
                    message: None,
                }
            }
            Err(e) => {
                tracing::error!(error = ?e, "cannot store the result of a job");
                Finish::failed("internal", INTERNAL_MESSAGE)
            }
        },
        Ok(Err(JobError::Cancelled)) => {
            if cancel.get() == CANCEL_BY_SHUTDOWN {
                tracing::warn!("job interrupted by shutdown");
                Finish::interrupted()
            } else {
                tracing::info!("job cancelled");
                Finish::cancelled()
            }
        }
        Ok(Err(JobError::Failed(message))) => {
            tracing::info!(%message, "job failed");
            Finish::failed("failed", message)
        }
        Ok(Err(JobError::Internal(message))) => {
            tracing::error!(%message, "job failed with an internal error");
            Finish::failed("internal", INTERNAL_MESSAGE)
        }
        Err(join) => {
            tracing::error!(error = %join, "job panicked");
            Finish::failed("internal", INTERNAL_MESSAGE)
        }
    }
}

/// Stores the result (if any) and marks the job succeeded, in one transaction.
async fn complete(
    pool: &SqlitePool,
    id: Uuid,
    output: JobOutput,
    events: &watch::Sender<JobRecord>,
) -> anyhow::Result<()> {
    let mut tx = store::begin_write(pool).await?;
    let result = match output.persist {
        Some(p) => Some(p.persist(id, &mut tx).await?),
        None => None,
    };
    let message = output
        .message
        .or_else(|| events.borrow().progress.message.clone())
        .unwrap_or_else(|| "done".to_owned());
    store::jobs::succeed(&mut tx, id, result.as_ref(), &message, &store::now()).await?;
    tx.commit().await?;
    Ok(())
}

#[cfg(test)]
mod tests;
