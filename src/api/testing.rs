//! TEST-ONLY routes, merged only when `REACHGRASP_TEST_JOBS=1` (`--test-jobs`) and absent from
//! the OpenAPI document. They let black-box tests start a job that only sleeps.

use axum::Router;
use axum::extract::State;
use axum::response::Response;
use axum::routing::post;
use serde::Deserialize;

use super::{ApiError, AppState, FieldError, Json};
use crate::jobs::testing::{MAX_STEP_MS, MAX_STEPS, SLEEP_KIND, sleep_job};

pub fn router() -> Router<AppState> {
    Router::new().route("/v1/_test/jobs/sleep", post(submit_sleep))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SleepRequest {
    steps: u32,
    step_ms: u64,
    #[serde(default)]
    fail_at: Option<u32>,
}

async fn submit_sleep(
    State(state): State<AppState>,
    Json(req): Json<SleepRequest>,
) -> Result<Response, ApiError> {
    let mut errors = Vec::new();
    if req.steps == 0 || req.steps > MAX_STEPS {
        errors.push(FieldError::new(
            "$.steps",
            format!("must be 1..={MAX_STEPS}"),
        ));
    }
    if req.step_ms > MAX_STEP_MS {
        errors.push(FieldError::new(
            "$.step_ms",
            format!("must be at most {MAX_STEP_MS}"),
        ));
    }
    if !errors.is_empty() {
        return Err(ApiError::validation(errors));
    }
    let job = state
        .jobs
        .submit(SLEEP_KIND, sleep_job(req.steps, req.step_ms, req.fail_at))
        .await?;
    Ok(super::accepted_job(job, None))
}
