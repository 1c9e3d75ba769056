//! Process wiring: logging, store, job runner, listener, graceful shutdown.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::Context;
use axum::serve::ListenerExt;
use tokio::net::TcpListener;

use crate::api;
use crate::config::Config;
use crate::jobs::JobRunner;
use crate::service;
use crate::shutdown::{Shutdown, ShutdownTrigger};
use crate::store;
use crate::store::library::{self, RobotLibrary};

/// Installs the global tracing subscriber (text or JSON lines on stdout). Call once.
pub fn init_tracing(log: &str, json: bool) -> anyhow::Result<()> {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_new(log)
        .with_context(|| format!("invalid log filter {log:?} (--log, REACHGRASP_LOG)"))?;
    // Colour codes only for a person at a terminal: a log file or a pipe gets plain text.
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stdout().is_terminal());
    let result = if json {
        builder.json().flatten_event(true).try_init()
    } else {
        builder.try_init()
    };
    result.map_err(|e| anyhow::anyhow!("cannot install the log subscriber: {e}"))
}

/// A built, bound application ready to serve.
pub struct App {
    listener: TcpListener,
    state: service::Context,
    trigger: ShutdownTrigger,
}

impl App {
    /// Opens the database (creating it, applying migrations), recovers interrupted jobs, and
    /// binds the listener (port 0 picks a free port; see [`App::local_addr`]).
    pub async fn build(config: Config) -> anyhow::Result<App> {
        let db = store::connect_capped(&config.db, config.db_max_bytes)
            .await
            .with_context(|| format!("cannot open the database {}", config.db.display()))?;
        let jobs = JobRunner::start(db.clone(), config.job_concurrency()).await?;
        if !config.robots.is_dir() {
            // Robots can also be registered over the API, so a missing folder is not fatal.
            tracing::warn!(robots = %config.robots.display(), "robots folder not found; starting without bundled robots");
        } else {
            library::sync_bundled(&db, &config.robots)
                .await
                .context("cannot synchronise the bundled robots")?;
        }
        let listener = TcpListener::bind(config.bind)
            .await
            .with_context(|| format!("cannot listen on {} (REACHGRASP_BIND)", config.bind))?;
        let (trigger, shutdown) = Shutdown::new();
        let recovered = store::executions::recover_interrupted(&db)
            .await
            .context("cannot recover interrupted executions")?;
        if recovered > 0 {
            tracing::warn!(
                count = recovered,
                "executions left running by the previous process marked interrupted"
            );
        }
        let token = match &config.bridge_token {
            Some(t) if !t.trim().is_empty() => t.trim().to_owned(),
            _ => {
                let t = uuid::Uuid::new_v4().simple().to_string();
                tracing::warn!(token = %t, "no bridge token configured (REACHGRASP_BRIDGE_TOKEN); bridge workers must present this generated one");
                t
            }
        };
        let robots = RobotLibrary::new(db.clone());
        let bridges =
            crate::bridge::Hub::new(db.clone(), robots.clone(), config.bridge_settings(token));
        bridges.spawn_dispatcher(shutdown.clone());
        let state = service::Context {
            compute: service::ComputeGate::new(config.request_concurrency()),
            bridges,
            db,
            config: Arc::new(config),
            jobs,
            robots,
            seed: crate::service::seed::SeedStatus::default(),
            shutdown,
        };
        crate::seed::start(&state)
            .await
            .context("cannot start first-start seeding")?;
        Ok(App {
            listener,
            state,
            trigger,
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> SocketAddr {
        self.listener
            .local_addr()
            .expect("a bound TCP listener has an address")
    }

    pub fn state(&self) -> &service::Context {
        &self.state
    }

    /// Serves until `signal` resolves, then stops accepting connections, lets in-flight requests
    /// finish (ending SSE streams), asks running jobs to stop, and closes the database. Each of
    /// the two waits is bounded by the configured shutdown grace.
    pub async fn run_until(
        self,
        signal: impl Future<Output = ()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let App {
            listener,
            state,
            trigger,
        } = self;
        let addr = listener.local_addr()?;
        tracing::info!(%addr, "listening");
        let grace = state.config.shutdown_grace();
        let shutdown = state.shutdown.clone();
        let router = api::router(state.clone(), crate::dashboard::router());
        // Retention sweep and WAL checkpoint, every maintenance interval until shutdown.
        tokio::spawn(service::storage::run_maintenance(state.clone()));
        // Small frames (bridge `execute`/`cancel`, SSE events) must not wait for delayed ACKs:
        // with Nagle's algorithm on they sit ~40 ms on loopback.
        let listener = listener.tap_io(|tcp| {
            if let Err(e) = tcp.set_nodelay(true) {
                tracing::debug!(error = %e, "cannot set TCP_NODELAY");
            }
        });
        let server = axum::serve(listener, router).with_graceful_shutdown({
            let shutdown = shutdown.clone();
            async move { shutdown.wait().await }
        });
        let mut server = std::pin::pin!(server.into_future());
        tokio::select! {
            result = &mut server => result?,
            () = signal => {
                tracing::info!("shutting down: finishing in-flight requests");
                trigger.trigger();
                if tokio::time::timeout(grace, &mut server).await.is_err() {
                    tracing::warn!("in-flight requests did not finish within the grace period");
                }
            }
        }
        state.jobs.shutdown(grace).await;
        state.db.close().await;
        tracing::info!("stopped");
        Ok(())
    }
}

/// The next delivery of `signal`, or never without one.
#[cfg(unix)]
async fn recv(signal: Option<&mut tokio::signal::unix::Signal>) {
    match signal {
        Some(s) => {
            s.recv().await;
        }
        None => std::future::pending::<()>().await,
    }
}

/// Resolves on SIGINT (Ctrl-C) or SIGTERM.
///
/// The handlers are installed when this is *called*, not when the future is first polled: the
/// service logs "listening" and can answer requests on other worker threads before its
/// main task polls the signal, and on a loaded machine a SIGTERM sent in that window (after a
/// client saw the service up) used to kill the process with the default action instead of
/// stopping it gracefully. Call it inside the runtime.
pub fn shutdown_signal() -> impl Future<Output = ()> + Send + 'static {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let listen = |kind: SignalKind, name: &'static str| match signal(kind) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::error!(error = %e, "cannot listen for {name}");
                None
            }
        };
        let mut interrupt = listen(SignalKind::interrupt(), "SIGINT");
        let mut terminate = listen(SignalKind::terminate(), "SIGTERM");
        async move {
            tokio::select! {
                () = recv(interrupt.as_mut()) => {},
                () = recv(terminate.as_mut()) => {},
            }
        }
    }
    #[cfg(not(unix))]
    async {
        if let Err(e) = tokio::signal::ctrl_c().await {
            tracing::error!(error = %e, "cannot listen for Ctrl-C");
            std::future::pending::<()>().await;
        }
    }
}
