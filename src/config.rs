//! Typed configuration, layered: built-in defaults < environment (`REACHGRASP_*`) < flags.
//!
//! The same struct is parsed by the CLI (`reachgrasp [serve] --flags`, each flag with an
//! environment variable) and built in code by tests ([`Config::default`] equals the documented
//! defaults). The offline sub-commands take only what they read: [`Sources`] (where robots are
//! found) and, for the bridge worker, [`Logging`].

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Default bind address.
pub const DEFAULT_BIND: &str = "127.0.0.1:8080";
/// Default database file.
pub const DEFAULT_DB: &str = "./data/reachgrasp.db";
/// Default robots folder.
pub const DEFAULT_ROBOTS: &str = "./robots";
/// Default log filter.
pub const DEFAULT_LOG: &str = "info";
/// Default request body limit: 32 MiB (URDFs, meshes and demonstrations can be large).
pub const DEFAULT_BODY_LIMIT: usize = 32 * 1024 * 1024;
/// Default request timeout in seconds (long work belongs in jobs, not requests).
pub const DEFAULT_REQUEST_TIMEOUT_SECS: u64 = 60;
/// Default time a request body may stall between two received chunks, in milliseconds, before
/// the request is answered with 408 (independent of the request timeout).
pub const DEFAULT_BODY_IDLE_TIMEOUT_MS: u64 = 10_000;
/// Default retention: the newest plans (with what they own), trajectories and finished
/// executions kept of each kind; older ones are deleted by the periodic maintenance.
pub const DEFAULT_RETENTION_MAX_COUNT: u64 = 1000;
/// Default seconds between two maintenance runs (retention sweep, WAL checkpoint).
pub const DEFAULT_MAINTENANCE_INTERVAL_SECS: u64 = 60;
/// Default graceful-shutdown grace period in seconds.
pub const DEFAULT_SHUTDOWN_GRACE_SECS: u64 = 10;

/// Default time a queued execution waits for a compatible worker (s).
pub const DEFAULT_BRIDGE_QUEUE_TIMEOUT_SECS: u64 = 600;
/// Default bridge heartbeat interval (ms).
pub const DEFAULT_BRIDGE_HEARTBEAT_MS: u64 = 1000;

/// The help section of the flags only the HTTP service reads.
const SERVICE_OPTIONS: &str = "Service options";

const DB_HELP: &str = "SQLite database file; the file and its folder are created if missing";
/// The `--robots` help, shared by the service and the offline sub-commands.
pub const ROBOTS_HELP: &str =
    "Folder of robot descriptions (`arms/`, `hands/`, `systems/`); may be empty or missing";
const LOG_HELP: &str =
    "Log filter in `tracing` EnvFilter syntax, e.g. `info` or `reachgrasp=debug,tower_http=info`";
const LOG_JSON_HELP: &str = "Log one JSON object per line instead of human-readable text";

/// Where an offline sub-command finds robots: the bundled descriptions and the service's
/// database (robots registered over the API).
#[derive(Debug, Clone, clap::Args)]
pub struct Sources {
    #[arg(long, env = "REACHGRASP_DB", default_value = DEFAULT_DB, help = DB_HELP)]
    pub db: PathBuf,
    #[arg(long, env = "REACHGRASP_ROBOTS", default_value = DEFAULT_ROBOTS, help = ROBOTS_HELP)]
    pub robots: PathBuf,
}

/// Log options of a long-running sub-command (the bridge worker).
#[derive(Debug, Clone, clap::Args)]
pub struct Logging {
    #[arg(long, env = "REACHGRASP_LOG", default_value = DEFAULT_LOG, help = LOG_HELP)]
    pub log: String,
    #[arg(long, env = "REACHGRASP_LOG_JSON", help = LOG_JSON_HELP,
          value_parser = clap::builder::BoolishValueParser::new())]
    pub log_json: bool,
}

/// Service configuration.
#[derive(Debug, Clone, clap::Args)]
pub struct Config {
    /// Address to listen on (`0.0.0.0:8080` in the container; port 0 picks a free port).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_BIND", default_value = DEFAULT_BIND)]
    pub bind: SocketAddr,

    #[arg(long, env = "REACHGRASP_DB", default_value = DEFAULT_DB, help = DB_HELP)]
    pub db: PathBuf,

    #[arg(long, env = "REACHGRASP_ROBOTS", default_value = DEFAULT_ROBOTS, help = ROBOTS_HELP)]
    pub robots: PathBuf,

    #[arg(long, env = "REACHGRASP_LOG", default_value = DEFAULT_LOG, help = LOG_HELP)]
    pub log: String,

    #[arg(long, env = "REACHGRASP_LOG_JSON", help = LOG_JSON_HELP,
          value_parser = clap::builder::BoolishValueParser::new())]
    pub log_json: bool,

    /// Largest accepted request body in bytes (larger bodies get 413).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_BODY_LIMIT", default_value_t = DEFAULT_BODY_LIMIT)]
    pub body_limit: usize,

    /// Milliseconds a request body may stall (no bytes arriving) before the request is
    /// answered with 408; a declared `Content-Length` over the body limit is 413 at once.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_BODY_IDLE_TIMEOUT_MS", default_value_t = DEFAULT_BODY_IDLE_TIMEOUT_MS,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub body_idle_timeout_ms: u64,

    /// Seconds a request may take before it is answered with 503 (jobs are not affected).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_REQUEST_TIMEOUT", default_value_t = DEFAULT_REQUEST_TIMEOUT_SECS,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub request_timeout_secs: u64,

    /// Retention: keep at most this many plans (each with its grasp, trajectory and finished
    /// execution), trajectories no plan owns, and finished executions no plan owns, the newest
    /// of each; 0 keeps all. Nothing a queued or running execution needs is ever deleted.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_RETENTION_MAX_COUNT", default_value_t = DEFAULT_RETENTION_MAX_COUNT,
          )]
    pub retention_max_count: u64,

    /// Retention: delete plans, trajectories and finished executions older than this many
    /// hours (as for the count); 0 (default) keeps them whatever their age.
    #[arg(help_heading = SERVICE_OPTIONS,
        long,
        env = "REACHGRASP_RETENTION_MAX_AGE_HOURS",
        default_value_t = 0,
    )]
    pub retention_max_age_hours: u64,

    /// Seconds between two maintenance runs: the retention sweep, then a WAL checkpoint
    /// (`PRAGMA wal_checkpoint(TRUNCATE)`).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_MAINTENANCE_INTERVAL", default_value_t = DEFAULT_MAINTENANCE_INTERVAL_SECS,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub maintenance_interval_secs: u64,

    /// Largest size of the database file in bytes (`PRAGMA max_page_count`); a write beyond it
    /// is refused with 507 and changes nothing, as on a full disk. Default: no cap.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_DB_MAX_BYTES")]
    pub db_max_bytes: Option<u64>,

    /// Computing jobs (training, mappings, grasp batches) running at once; further ones wait
    /// queued. A verification, which mostly waits for physics workers, takes no slot. Default:
    /// the number of CPUs.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_JOB_CONCURRENCY",
          value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub job_concurrency: Option<u64>,

    /// Plans, grasps and trajectories that requests compute at once; further ones wait in
    /// arrival order. Default: the number of CPUs.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_REQUEST_CONCURRENCY",
          value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub request_concurrency: Option<u64>,

    /// Seconds to wait at shutdown for in-flight requests and jobs before exiting.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_SHUTDOWN_GRACE", default_value_t = DEFAULT_SHUTDOWN_GRACE_SECS,
          )]
    pub shutdown_grace_secs: u64,

    /// Token bridge workers present (`Authorization: Bearer <token>`) on
    /// `/v1/bridges/connect`. When unset, a random token is generated at start and logged once.
    #[arg(help_heading = SERVICE_OPTIONS,
        long,
        env = "REACHGRASP_BRIDGE_TOKEN",
        hide_env_values = true
    )]
    pub bridge_token: Option<String>,

    /// Seconds a queued execution waits while no compatible worker is connected before it
    /// fails with `no worker` (0: wait forever).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_BRIDGE_QUEUE_TIMEOUT", default_value_t = DEFAULT_BRIDGE_QUEUE_TIMEOUT_SECS,
          )]
    pub bridge_queue_timeout_secs: u64,

    /// Milliseconds between worker heartbeats (told to workers in `welcome`); a worker silent
    /// for 5 intervals is disconnected.
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_BRIDGE_HEARTBEAT_MS", default_value_t = DEFAULT_BRIDGE_HEARTBEAT_MS,
          value_parser = clap::value_parser!(u64).range(10..=60_000))]
    pub bridge_heartbeat_ms: u64,

    /// Skip first-start seeding (generating the default synthetic study, mapping it for every
    /// bundled system and training each system's default model when one is missing).
    #[arg(help_heading = SERVICE_OPTIONS, long, env = "REACHGRASP_NO_SEED",
          value_parser = clap::builder::BoolishValueParser::new())]
    pub no_seed: bool,

    /// TEST ONLY: expose `POST /v1/_test/jobs/sleep` (a job that only sleeps). Never enable in a
    /// deployment.
    #[arg(long, env = "REACHGRASP_TEST_JOBS", hide = true,
          value_parser = clap::builder::BoolishValueParser::new())]
    pub test_jobs: bool,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            bind: DEFAULT_BIND.parse().expect("valid default bind address"),
            db: PathBuf::from(DEFAULT_DB),
            robots: PathBuf::from(DEFAULT_ROBOTS),
            log: DEFAULT_LOG.to_owned(),
            log_json: false,
            body_limit: DEFAULT_BODY_LIMIT,
            body_idle_timeout_ms: DEFAULT_BODY_IDLE_TIMEOUT_MS,
            request_timeout_secs: DEFAULT_REQUEST_TIMEOUT_SECS,
            retention_max_count: DEFAULT_RETENTION_MAX_COUNT,
            retention_max_age_hours: 0,
            maintenance_interval_secs: DEFAULT_MAINTENANCE_INTERVAL_SECS,
            db_max_bytes: None,
            job_concurrency: None,
            request_concurrency: None,
            shutdown_grace_secs: DEFAULT_SHUTDOWN_GRACE_SECS,
            bridge_token: None,
            bridge_queue_timeout_secs: DEFAULT_BRIDGE_QUEUE_TIMEOUT_SECS,
            bridge_heartbeat_ms: DEFAULT_BRIDGE_HEARTBEAT_MS,
            no_seed: false,
            test_jobs: false,
        }
    }
}

impl Config {
    pub fn request_timeout(&self) -> Duration {
        Duration::from_secs(self.request_timeout_secs)
    }

    /// The retention policy of the periodic maintenance.
    pub fn retention(&self) -> crate::store::retention::Policy {
        crate::store::retention::Policy {
            max_age: (self.retention_max_age_hours > 0)
                .then(|| Duration::from_secs(self.retention_max_age_hours.saturating_mul(3600))),
            max_count: (self.retention_max_count > 0).then_some(self.retention_max_count),
        }
    }

    pub fn maintenance_interval(&self) -> Duration {
        Duration::from_secs(self.maintenance_interval_secs)
    }

    /// How long a request body may stall between chunks (see `body_idle_timeout_ms`).
    pub fn body_idle_timeout(&self) -> Duration {
        Duration::from_millis(self.body_idle_timeout_ms)
    }

    /// The bridge hub's settings; `token` is the resolved token (configured or generated).
    pub fn bridge_settings(&self, token: String) -> crate::bridge::HubSettings {
        let interval = Duration::from_millis(self.bridge_heartbeat_ms);
        crate::bridge::HubSettings {
            token,
            heartbeat_interval: interval,
            heartbeat_timeout: interval * 5,
            queue_timeout: (self.bridge_queue_timeout_secs > 0)
                .then(|| Duration::from_secs(self.bridge_queue_timeout_secs)),
        }
    }

    pub fn shutdown_grace(&self) -> Duration {
        Duration::from_secs(self.shutdown_grace_secs)
    }

    /// The effective job concurrency (configured, else the number of CPUs).
    pub fn job_concurrency(&self) -> usize {
        self.job_concurrency.map_or_else(cpus, |n| n as usize)
    }

    /// The effective request concurrency (configured, else the number of CPUs).
    pub fn request_concurrency(&self) -> usize {
        self.request_concurrency.map_or_else(cpus, |n| n as usize)
    }
}

fn cpus() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        config: Config,
    }

    fn parse(args: &[&str]) -> Result<Config, clap::Error> {
        Cli::try_parse_from(std::iter::once("reachgrasp").chain(args.iter().copied()))
            .map(|c| c.config)
    }

    #[test]
    fn flags_override_defaults_and_are_checked() {
        let c = parse(&[
            "--bind",
            "0.0.0.0:9000",
            "--db",
            "/tmp/x.db",
            "--job-concurrency",
            "3",
            "--request-concurrency",
            "5",
            "--body-limit",
            "1024",
            "--body-idle-timeout-ms",
            "250",
        ])
        .unwrap();
        assert_eq!(c.bind.port(), 9000);
        assert_eq!(c.db, PathBuf::from("/tmp/x.db"));
        assert_eq!(c.job_concurrency(), 3);
        assert_eq!(c.request_concurrency(), 5);
        assert_eq!(c.body_limit, 1024);
        assert_eq!(c.body_idle_timeout(), Duration::from_millis(250));
        assert!(parse(&["--body-idle-timeout-ms", "0"]).is_err());
        assert!(parse(&["--bind", "not-an-address"]).is_err());
        assert!(parse(&["--job-concurrency", "0"]).is_err());
        assert!(parse(&["--request-concurrency", "0"]).is_err());
        assert!(parse(&["--request-timeout-secs", "0"]).is_err());
    }

    #[test]
    fn the_default_struct_equals_the_documented_cli_defaults() {
        // Only meaningful without REACHGRASP_* in the environment (as in CI).
        if std::env::vars().any(|(k, _)| k.starts_with("REACHGRASP_")) {
            return;
        }
        let parsed = parse(&[]).unwrap();
        let default = Config::default();
        assert_eq!(format!("{parsed:?}"), format!("{default:?}"));
        assert!(default.job_concurrency() >= 1);
    }
}
