//! TEST-ONLY job kind, reachable over HTTP only when `REACHGRASP_TEST_JOBS=1` (`--test-jobs`):
//! a job that sleeps in bounded steps, so tests (including the SIGKILL crash-recovery test,
//! which drives a real process) can observe progress, queueing and cancellation. It computes
//! nothing and must never be enabled in a deployment.

use std::time::Duration;

use super::{JobContext, JobError, JobOutput};

/// The kind recorded for sleep jobs.
pub const SLEEP_KIND: &str = "test.sleep";
/// Upper bounds that keep a test job finite.
pub const MAX_STEPS: u32 = 10_000;
pub const MAX_STEP_MS: u64 = 1_000;

/// A job of `steps` sleeps of `step_ms` each, reporting progress after every step and checking
/// cancellation before every step. With `fail_at = Some(k)`, step `k` fails with a message.
pub fn sleep_job(
    steps: u32,
    step_ms: u64,
    fail_at: Option<u32>,
) -> impl FnOnce(JobContext) -> Result<JobOutput, JobError> + Send + 'static {
    let steps = steps.min(MAX_STEPS);
    let step = Duration::from_millis(step_ms.min(MAX_STEP_MS));
    move |ctx: JobContext| {
        for i in 0..steps {
            ctx.check_cancelled()?;
            if fail_at == Some(i) {
                return Err(JobError::Failed(format!(
                    "test job failed at step {i} as asked"
                )));
            }
            std::thread::sleep(step);
            ctx.progress(
                f64::from(i + 1) / f64::from(steps),
                format!("step {} of {steps}", i + 1),
            );
        }
        Ok(JobOutput::empty().with_message(format!("slept {steps} steps")))
    }
}
