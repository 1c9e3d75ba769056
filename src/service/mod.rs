//! The application layer: one module per use case, between the edges (HTTP handlers in
//! [`crate::api`], the dashboard, the CLI, first-start seeding) and the pure numerics.
//!
//! A use case takes parsed domain inputs and a [`Context`], does its work (numerics off the
//! async runtime, store writes in one transaction per unit of work) and returns domain results
//! or an [`Error`]. It knows nothing of HTTP: the edge renders an [`Error`] as problem+json once
//! ([`crate::api::ApiError`] implements `From<Error>`).
//!
//! Layers, lowest first (a module imports only from its own layer or below; the test
//! `tests/layers.rs` enforces it):
//! 1. numeric core: `kinematics`, `geometry`, `human`, `mapping`, `motion`, `grasp`, `optim`,
//!    `figures` (pure computation, no I/O);
//! 2. `store` (SQLite rows, the robot library) and `shutdown`;
//! 3. `jobs` and `bridge` (the job runner, the bridge hub and its worker protocol);
//! 4. `service` and `config` (this layer);
//! 5. the edges that reach the use cases without HTTP: `dashboard`, `seed`;
//! 6. `api` (HTTP handlers, DTOs, problem+json);
//! 7. the process: `app` (wiring) and the CLI (`main.rs`), which takes from `api` only the
//!    OpenAPI document and the rendering of a plan.

pub mod bridges;
pub mod demonstrations;
pub mod executions;
pub mod figures;
pub mod grasps;
pub mod jobs;
pub mod mappings;
pub mod models;
pub mod plans;
pub mod retarget;
pub mod robots;
pub mod seed;
pub mod status;
pub mod storage;
pub mod trajectories;
pub mod verifications;

use std::fmt;
use std::sync::Arc;

use sqlx::SqlitePool;
use uuid::Uuid;

use crate::bridge::{BridgeError, Hub};
use crate::config::Config;
use crate::jobs::{JobRunner, RunnerError};
use crate::shutdown::Shutdown;
use crate::store::library::{LibraryError, RobotLibrary};

/// The stored grasp and object records the grasp and plan use cases hand out, named here so
/// that the edges render them without naming the store.
pub use crate::store::grasps::{GraspRow, ObjectRow};

/// Everything a use case may need; cheap to clone.
#[derive(Clone, Debug)]
pub struct Context {
    pub db: SqlitePool,
    pub config: Arc<Config>,
    pub jobs: JobRunner,
    /// Loaded arm-hand systems by id.
    pub robots: RobotLibrary,
    /// Connected bridge workers and the execution dispatcher.
    pub bridges: Hub,
    /// Robots whose default model the first-start seeding is still preparing.
    pub seed: seed::SeedStatus,
    /// Resolves when the service starts shutting down (ends long-lived streams).
    pub shutdown: Shutdown,
    /// Admission of the plans, grasps and trajectories requests compute.
    pub compute: ComputeGate,
}

/// Admission of the computations synchronous requests run (plans, grasps, trajectories): at
/// most `permits` at a time, the others waiting in arrival order (tokio's semaphore is fair).
/// Without it every request in flight shares the cores and each takes as long as they all
/// together: at 32 concurrent plans on 2 cores the slower requests finished last (p99 2.2-2.4 s
/// against a median of 1.3 s); in order, a request waits for those that came before it only.
#[derive(Clone, Debug)]
pub struct ComputeGate(Arc<tokio::sync::Semaphore>);

impl ComputeGate {
    pub fn new(permits: usize) -> Self {
        ComputeGate(Arc::new(tokio::sync::Semaphore::new(permits.max(1))))
    }

    /// Waits for a turn; the computation holds the permit until it is dropped.
    pub async fn enter(&self) -> tokio::sync::OwnedSemaphorePermit {
        self.0
            .clone()
            .acquire_owned()
            .await
            .expect("the gate's semaphore is never closed")
    }

    /// Waits for a turn, then runs `work` to its end on its own task, which holds the permit.
    /// A request dropped meanwhile (its client gone, its timeout reached) stops waiting for the
    /// answer, not the computation: the blocking steps `work` awaits run on regardless, so a
    /// permit released with the request let one computation more than the permits run.
    pub async fn run<F>(&self, work: F) -> Result<F::Output, Error>
    where
        F: std::future::Future + Send + 'static,
        F::Output: Send + 'static,
    {
        let turn = self.enter().await;
        tokio::spawn(async move {
            let out = work.await;
            drop(turn);
            out
        })
        .await
        .map_err(Error::internal)
    }

    /// Permits free now (for the tests: a number that is stale as soon as it is read).
    #[cfg(test)]
    fn available(&self) -> usize {
        self.0.available_permits()
    }
}

impl AsRef<Hub> for Context {
    fn as_ref(&self) -> &Hub {
        &self.bridges
    }
}

/// A word a request may give in place of a value: `"auto"` (learn or choose it) where a number
/// is expected, `"current"` (the connected worker's measured state) or `"zero"` (the robot's
/// zero configuration) where a configuration is.
/// Requests carry the word as text, so that an unknown one is quoted back in the 422 that
/// refuses it (and the OpenAPI schemas stay `string`); the use cases parse it here, once, and
/// match on the enum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Keyword {
    Auto,
    Current,
    Zero,
}

impl Keyword {
    pub const fn as_str(self) -> &'static str {
        match self {
            Keyword::Auto => "auto",
            Keyword::Current => "current",
            Keyword::Zero => "zero",
        }
    }

    pub fn parse(s: &str) -> Option<Keyword> {
        [Keyword::Auto, Keyword::Current, Keyword::Zero]
            .into_iter()
            .find(|k| k.as_str() == s)
    }
}

/// One bad input: the field as the request names it (a JSONPath into the request body, e.g.
/// `$.start.positions[2]`, or a parameter name), and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Invalid {
    pub field: String,
    pub message: String,
}

impl Invalid {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Invalid {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// What a use case reports. Each edge renders it once (HTTP: problem+json; CLI: a message).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Bad input; every offending field.
    #[error("{}", summary(.0))]
    Invalid(Vec<Invalid>),
    /// The payload of an execution does not fit its robot (the caller knows where each part
    /// came from).
    #[error("the execution does not fit the robot")]
    Payload(Vec<crate::bridge::PayloadIssue>),
    /// An id the request is about does not exist.
    #[error("{kind} {id} does not exist")]
    NotFound { kind: &'static str, id: String },
    /// The request conflicts with the stored state.
    #[error("{0}")]
    Conflict(String),
    /// Job `job` is still preparing what the request needs.
    #[error("{message}")]
    NotReady { message: String, job: Uuid },
    /// A dependency is down or the service is stopping.
    #[error("{0}")]
    Unavailable(String),
    /// A bug or an unexpected failure below (logged, never detailed to a client).
    #[error(transparent)]
    Internal(anyhow::Error),
}

fn summary(errors: &[Invalid]) -> String {
    match errors {
        [one] => format!("{}: {}", one.field, one.message),
        many => format!("{} fields are invalid", many.len()),
    }
}

impl Error {
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid(vec![Invalid::new(field, message)])
    }

    pub fn not_found(kind: &'static str, id: impl fmt::Display) -> Self {
        Error::NotFound {
            kind,
            id: id.to_string(),
        }
    }

    pub fn internal(cause: impl Into<anyhow::Error>) -> Self {
        Error::Internal(cause.into())
    }
}

/// Whether a storage error is a full database (disk or size cap): the edge answers 507 for it,
/// wherever in an internal error's chain it sits.
pub use crate::store::is_disk_full;

impl From<sqlx::Error> for Error {
    fn from(e: sqlx::Error) -> Self {
        if crate::store::is_unique_violation(&e) {
            Error::Conflict("a resource with the same identity already exists".into())
        } else {
            Error::Internal(e.into())
        }
    }
}

impl From<RunnerError> for Error {
    fn from(e: RunnerError) -> Self {
        match e {
            RunnerError::NotFound(id) => Error::not_found("job", id),
            RunnerError::AlreadyFinished { id, status } => {
                Error::Conflict(format!("job {id} is already {status}"))
            }
            RunnerError::ShuttingDown => Error::Unavailable("the service is shutting down".into()),
            RunnerError::Store(e) => Error::internal(e),
        }
    }
}

impl From<LibraryError> for Error {
    fn from(e: LibraryError) -> Self {
        match e {
            LibraryError::UnknownRobot(id) => Error::not_found("robot", id),
            LibraryError::Store(e) => e.into(),
            other => Error::internal(other),
        }
    }
}

impl From<BridgeError> for Error {
    fn from(e: BridgeError) -> Self {
        match e {
            BridgeError::UnknownRobot(id) => {
                Error::invalid("$.robot", format!("unknown robot '{id}'"))
            }
            BridgeError::InvalidWorkerName(_) => Error::invalid("$.worker", e.to_string()),
            BridgeError::InvalidPayload(issues) => Error::Payload(issues),
            BridgeError::UnknownExecution(id) => Error::not_found("execution", id),
            BridgeError::AlreadyFinished { .. } => Error::Conflict(e.to_string()),
            BridgeError::NoWorker(m) => Error::Conflict(m),
            BridgeError::Store(e) => e.into(),
            other => Error::internal(other),
        }
    }
}

/// Readiness: the database answers a query within `within`.
pub async fn ready(ctx: &Context, within: std::time::Duration) -> Result<(), Error> {
    match tokio::time::timeout(within, crate::store::ping(&ctx.db)).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => {
            tracing::warn!(error = %e, "readiness check failed");
            Err(Error::Unavailable("the database does not answer".into()))
        }
        Err(_) => Err(Error::Unavailable(format!(
            "the database did not answer within {} s",
            within.as_secs()
        ))),
    }
}

/// Standard base64 (RFC 4648) as uploads carry binary files (meshes): whitespace is ignored,
/// and padding may be left off, as clients wrap and trim encoded text.
pub fn decode_base64(s: &str) -> Option<Vec<u8>> {
    use base64::Engine;
    use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
    const LENIENT: GeneralPurpose = GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        GeneralPurposeConfig::new()
            .with_decode_padding_mode(DecodePaddingMode::Indifferent)
            .with_decode_allow_trailing_bits(true),
    );
    let compact: String = s.chars().filter(|c| !c.is_ascii_whitespace()).collect();
    LENIENT.decode(compact).ok()
}

/// A context over a fresh database in `dir` with the bundled robots, for the use cases' tests.
#[cfg(test)]
pub(crate) async fn test_context(dir: &std::path::Path) -> Context {
    let robots_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots");
    let config = Config {
        db: dir.join("test.db"),
        robots: robots_dir.clone(),
        no_seed: true,
        ..Config::default()
    };
    let db = crate::store::connect(&config.db).await.expect("database");
    crate::store::library::sync_bundled(&db, &robots_dir)
        .await
        .expect("bundled robots");
    let jobs = JobRunner::start(db.clone(), 1).await.expect("job runner");
    let robots = RobotLibrary::new(db.clone());
    let (_trigger, shutdown) = Shutdown::new();
    let bridges = Hub::new(
        db.clone(),
        robots.clone(),
        config.bridge_settings("t".into()),
    );
    Context {
        compute: ComputeGate::new(config.request_concurrency()),
        db,
        config: Arc::new(config),
        jobs,
        robots,
        bridges,
        seed: seed::SeedStatus::default(),
        shutdown,
    }
}

#[cfg(test)]
mod tests {
    use super::{ComputeGate, Keyword, decode_base64};
    use std::sync::Arc;

    #[tokio::test]
    async fn the_compute_gate_admits_in_arrival_order_and_no_more_than_its_permits() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::time::Duration;
        // one permit, held: three requests arrive in turn and enter in that order once freed
        let gate = ComputeGate::new(1);
        let held = gate.enter().await;
        let order = Arc::new(std::sync::Mutex::new(Vec::new()));
        let mut waiting = Vec::new();
        for name in ["b", "c", "d"] {
            let (gate, order) = (gate.clone(), order.clone());
            waiting.push(tokio::spawn(async move {
                let _turn = gate.enter().await;
                order.lock().unwrap().push(name);
            }));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(
            order.lock().unwrap().is_empty(),
            "entered past a held permit"
        );
        drop(held);
        for w in waiting {
            w.await.unwrap();
        }
        assert_eq!(*order.lock().unwrap(), ["b", "c", "d"]);
        // two permits: eight computations, never more than two inside at once
        let gate = ComputeGate::new(2);
        let (inside, most) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
        let tasks: Vec<_> = (0..8)
            .map(|_| {
                let (gate, inside, most) = (gate.clone(), inside.clone(), most.clone());
                tokio::spawn(async move {
                    let _turn = gate.enter().await;
                    let now = inside.fetch_add(1, Ordering::SeqCst) + 1;
                    most.fetch_max(now, Ordering::SeqCst);
                    tokio::time::sleep(Duration::from_millis(5)).await;
                    inside.fetch_sub(1, Ordering::SeqCst);
                })
            })
            .collect();
        for t in tasks {
            t.await.unwrap();
        }
        assert_eq!(most.load(Ordering::SeqCst), 2);
    }

    #[tokio::test]
    async fn a_computation_keeps_its_permit_when_its_request_is_dropped() {
        // one permit; a computation that runs until released, its caller dropped once inside
        let gate = ComputeGate::new(1);
        let (inside_tx, inside_rx) = tokio::sync::oneshot::channel::<()>();
        let (release_tx, release_rx) = tokio::sync::oneshot::channel::<()>();
        let (done_tx, done_rx) = tokio::sync::oneshot::channel::<()>();
        let caller = {
            let gate = gate.clone();
            tokio::spawn(async move {
                gate.run(async move {
                    inside_tx.send(()).unwrap();
                    release_rx.await.unwrap();
                    done_tx.send(()).unwrap();
                })
                .await
            })
        };
        inside_rx.await.unwrap();
        caller.abort();
        assert!(caller.await.unwrap_err().is_cancelled());
        // the request is gone, the computation is not: its permit stays taken
        assert_eq!(gate.available(), 0);
        release_tx.send(()).unwrap();
        done_rx.await.unwrap();
        // and is free once the computation ends
        let _next = gate.enter().await;
        assert_eq!(gate.available(), 0);
    }

    #[test]
    fn keywords_parse_from_their_wire_text_and_nothing_else() {
        for k in [Keyword::Auto, Keyword::Current] {
            assert_eq!(Keyword::parse(k.as_str()), Some(k));
        }
        assert_eq!(Keyword::parse("Auto"), None);
        assert_eq!(Keyword::parse(""), None);
    }

    #[test]
    fn base64_decodes_rfc4648_vectors_with_or_without_padding() {
        assert_eq!(decode_base64("").unwrap(), b"");
        assert_eq!(decode_base64("Zg==").unwrap(), b"f");
        assert_eq!(decode_base64("Zg").unwrap(), b"f");
        assert_eq!(decode_base64("Zm9v\nYmFy").unwrap(), b"foobar");
        assert_eq!(decode_base64("Zm9vYg==").unwrap(), b"foob");
        assert!(decode_base64("Zm9v!").is_none());
    }
}
