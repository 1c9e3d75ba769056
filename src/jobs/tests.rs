//! Unit tests of the job runner against a temporary SQLite database.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use super::*;

async fn setup(concurrency: usize) -> (JobRunner, SqlitePool, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let pool = store::connect(&dir.path().join("jobs.db")).await.unwrap();
    let runner = JobRunner::start(pool.clone(), concurrency).await.unwrap();
    (runner, pool, dir)
}

/// Polls until the job satisfies `done` (bounded: 10 s).
async fn wait_for(runner: &JobRunner, id: Uuid, done: impl Fn(&JobRecord) -> bool) -> JobRecord {
    for _ in 0..1000 {
        let r = runner.get(id).await.unwrap();
        if done(&r) {
            return r;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("job {id} did not reach the expected state in 10 s");
}

async fn wait_final(runner: &JobRunner, id: Uuid) -> JobRecord {
    wait_for(runner, id, |r| r.status.is_final()).await
}

/// A gate blocking jobs until opened (each wait bounded so a failing test cannot hang).
#[derive(Clone, Default)]
struct Gate(Arc<(Mutex<bool>, Condvar)>);

impl Gate {
    fn open(&self) {
        *self.0.0.lock().unwrap() = true;
        self.0.1.notify_all();
    }
    fn wait(&self) {
        let (lock, cv) = &*self.0;
        let guard = lock.lock().unwrap();
        let _ = cv
            .wait_timeout_while(guard, Duration::from_secs(10), |open| !*open)
            .unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn progress_is_visible_live_and_the_job_succeeds_with_full_progress() {
    let (runner, _pool, _dir) = setup(2).await;
    let gate = Gate::default();
    let g = gate.clone();
    let job = runner
        .submit("unit", move |ctx| {
            ctx.progress(0.25, "quarter");
            g.wait();
            ctx.progress(f64::NAN, "nan keeps the fraction");
            ctx.progress(7.0, "clamped");
            Ok(JobOutput::empty())
        })
        .await
        .unwrap();
    assert_eq!(job.status, JobStatus::Queued);
    let mut rx = runner.subscribe(job.id).expect("live job");
    // The live view shows progress at once; the store within the persist interval.
    let seen = async {
        loop {
            if rx.borrow_and_update().progress.fraction == 0.25 {
                break;
            }
            rx.changed().await.unwrap();
        }
    };
    tokio::time::timeout(Duration::from_secs(10), seen)
        .await
        .unwrap();
    let stored = wait_for(&runner, job.id, |r| r.progress.fraction == 0.25).await;
    assert_eq!(stored.status, JobStatus::Running);
    assert_eq!(stored.progress.message.as_deref(), Some("quarter"));
    assert!(stored.started_at.is_some());
    gate.open();
    let done = wait_final(&runner, job.id).await;
    assert_eq!(done.status, JobStatus::Succeeded);
    assert_eq!(done.progress.fraction, 1.0);
    assert_eq!(done.progress.message.as_deref(), Some("clamped"));
    assert!(done.error.is_none() && done.result.is_none());
    assert!(done.finished_at.is_some());
    // The live receiver ends on the final record.
    let last = async {
        loop {
            if rx.borrow_and_update().status.is_final() {
                return rx.borrow().clone();
            }
            if rx.changed().await.is_err() {
                return rx.borrow().clone();
            }
        }
    };
    let last = tokio::time::timeout(Duration::from_secs(10), last)
        .await
        .unwrap();
    assert_eq!(last, done);
    // Once settled, the job is no longer live (read from the store instead).
    for _ in 0..1000 {
        if runner.subscribe(job.id).is_none() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("a finished job stayed live");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_result_is_stored_in_the_same_transaction_as_the_success() {
    let (runner, pool, _dir) = setup(1).await;
    sqlx::query(
        "CREATE TABLE results (id TEXT PRIMARY KEY, job_id TEXT REFERENCES jobs(id), data BLOB)",
    )
    .execute(&pool)
    .await
    .unwrap();
    let job = runner
        .submit("unit", |_ctx| {
            let data = store::blob::encode(&[2], &[1.0f64, 2.0]).unwrap();
            Ok(JobOutput::persist_with(move |job_id, tx| {
                Box::pin(async move {
                    let id = Uuid::new_v4();
                    sqlx::query("INSERT INTO results (id, job_id, data) VALUES (?, ?, ?)")
                        .bind(id.to_string())
                        .bind(job_id.to_string())
                        .bind(data)
                        .execute(&mut **tx)
                        .await?;
                    Ok(ResultRef::new("results", id))
                })
            }))
        })
        .await
        .unwrap();
    let done = wait_final(&runner, job.id).await;
    assert_eq!(done.status, JobStatus::Succeeded);
    let result = done.result.expect("result reference");
    assert_eq!(result.resource, "results");
    assert_eq!(result.href, format!("/v1/results/{}", result.id));
    let (job_id, data): (String, Vec<u8>) =
        sqlx::query_as("SELECT job_id, data FROM results WHERE id = ?")
            .bind(&result.id)
            .fetch_one(&pool)
            .await
            .unwrap();
    assert_eq!(job_id, job.id.to_string());
    assert_eq!(
        store::blob::decode::<f64>(&data).unwrap().data,
        vec![1.0, 2.0]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_persist_step_rolls_back_its_rows_and_fails_the_job() {
    let (runner, pool, _dir) = setup(1).await;
    sqlx::query("CREATE TABLE results (id TEXT PRIMARY KEY)")
        .execute(&pool)
        .await
        .unwrap();
    let job = runner
        .submit("unit", |_ctx| {
            Ok(JobOutput::persist_with(|_job_id, tx| {
                Box::pin(async move {
                    sqlx::query("INSERT INTO results (id) VALUES ('partial')")
                        .execute(&mut **tx)
                        .await?;
                    anyhow::bail!("disk full (simulated)")
                })
            }))
        })
        .await
        .unwrap();
    let done = wait_final(&runner, job.id).await;
    assert_eq!(done.status, JobStatus::Failed);
    let failure = done.error.unwrap();
    assert_eq!(failure.reason, "internal");
    assert!(
        !failure.message.contains("disk full"),
        "causes are logged, not shown"
    );
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM results")
        .fetch_one(&pool)
        .await
        .unwrap();
    assert_eq!(n, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failures_and_panics_are_recorded_with_their_reason() {
    let (runner, _pool, _dir) = setup(2).await;
    let failed = runner
        .submit("unit", |_ctx| {
            Err(JobError::failed("solver diverged at frame 12"))
        })
        .await
        .unwrap();
    let panicked = runner
        .submit("unit", |_ctx| -> Result<JobOutput, JobError> {
            panic!("index out of bounds (simulated)")
        })
        .await
        .unwrap();
    let internal = runner
        .submit("unit", |_ctx| {
            Err(JobError::Internal("secret detail".into()))
        })
        .await
        .unwrap();
    let f = wait_final(&runner, failed.id).await;
    assert_eq!(f.status, JobStatus::Failed);
    assert_eq!(
        f.error,
        Some(JobFailure {
            reason: "failed".into(),
            message: "solver diverged at frame 12".into()
        })
    );
    for id in [panicked.id, internal.id] {
        let r = wait_final(&runner, id).await;
        assert_eq!(r.status, JobStatus::Failed);
        let e = r.error.unwrap();
        assert_eq!(e.reason, "internal");
        assert!(!e.message.contains("secret") && !e.message.contains("simulated"));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_running_job_stops_cooperatively_when_cancelled() {
    let (runner, _pool, _dir) = setup(1).await;
    let saw_cancel = Arc::new(AtomicBool::new(false));
    let saw = saw_cancel.clone();
    let job = runner
        .submit("unit", move |ctx| {
            for i in 0..1000 {
                if ctx.is_cancelled() {
                    saw.store(true, Ordering::SeqCst);
                }
                ctx.check_cancelled()?;
                ctx.progress(f64::from(i) / 1000.0, "working");
                std::thread::sleep(Duration::from_millis(10));
            }
            Ok(JobOutput::empty())
        })
        .await
        .unwrap();
    wait_for(&runner, job.id, |r| r.status == JobStatus::Running).await;
    let r = runner.cancel(job.id).await.unwrap();
    assert!(r.cancel_requested);
    let done = wait_final(&runner, job.id).await;
    assert_eq!(done.status, JobStatus::Cancelled);
    assert!(done.cancel_requested);
    assert!(done.error.is_none());
    assert!(saw_cancel.load(Ordering::SeqCst));
    // A finished job cannot be cancelled again.
    assert!(matches!(
        runner.cancel(job.id).await,
        Err(RunnerError::AlreadyFinished {
            status: JobStatus::Cancelled,
            ..
        })
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn excess_jobs_queue_and_all_run_within_the_concurrency_limit() {
    let (runner, _pool, _dir) = setup(2).await;
    let gate = Gate::default();
    let running = Arc::new(AtomicUsize::new(0));
    let peak = Arc::new(AtomicUsize::new(0));
    let mut ids = Vec::new();
    for _ in 0..5 {
        let (g, running, peak) = (gate.clone(), running.clone(), peak.clone());
        let job = runner
            .submit("unit", move |_ctx| {
                let now = running.fetch_add(1, Ordering::SeqCst) + 1;
                peak.fetch_max(now, Ordering::SeqCst);
                g.wait();
                running.fetch_sub(1, Ordering::SeqCst);
                Ok(JobOutput::empty())
            })
            .await
            .unwrap();
        ids.push(job.id);
    }
    // Two run, three wait queued; nothing is dropped.
    for _ in 0..1000 {
        if running.load(Ordering::SeqCst) == 2 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(running.load(Ordering::SeqCst), 2);
    let filter = store::jobs::JobFilter {
        limit: 10,
        ..Default::default()
    };
    let count = |s: JobStatus, all: &[JobRecord]| all.iter().filter(|r| r.status == s).count();
    let all = runner.list(&filter).await.unwrap();
    assert_eq!(count(JobStatus::Queued, &all), 3);
    gate.open();
    for id in ids {
        assert_eq!(wait_final(&runner, id).await.status, JobStatus::Succeeded);
    }
    assert_eq!(peak.load(Ordering::SeqCst), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_queued_job_cancelled_before_it_starts_never_runs() {
    let (runner, _pool, _dir) = setup(1).await;
    let gate = Gate::default();
    let g = gate.clone();
    let blocker = runner
        .submit("unit", move |_ctx| {
            g.wait();
            Ok(JobOutput::empty())
        })
        .await
        .unwrap();
    let ran = Arc::new(AtomicBool::new(false));
    let r = ran.clone();
    let queued = runner
        .submit("unit", move |_ctx| {
            r.store(true, Ordering::SeqCst);
            Ok(JobOutput::empty())
        })
        .await
        .unwrap();
    wait_for(&runner, blocker.id, |r| r.status == JobStatus::Running).await;
    runner.cancel(queued.id).await.unwrap();
    // Cancelled while the only permit is still held: it does not wait for a permit.
    let done = wait_final(&runner, queued.id).await;
    assert_eq!(done.status, JobStatus::Cancelled);
    assert!(done.started_at.is_none());
    gate.open();
    wait_final(&runner, blocker.id).await;
    assert!(!ran.load(Ordering::SeqCst));
}

#[tokio::test]
async fn jobs_left_running_or_queued_by_a_previous_process_become_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    let pool = store::connect(&dir.path().join("jobs.db")).await.unwrap();
    let now = store::now();
    let ids: Vec<Uuid> = (0..3).map(|_| Uuid::new_v4()).collect();
    let ids_by_name = |name: &str| ids[usize::from(name.as_bytes()[0] - b'a')];
    for (id, status) in [("a", "running"), ("b", "queued"), ("c", "succeeded")] {
        sqlx::query("INSERT INTO jobs (id, kind, status, created_at) VALUES (?, 'x', ?, ?)")
            .bind(ids_by_name(id).to_string())
            .bind(status)
            .bind(&now)
            .execute(&pool)
            .await
            .unwrap();
    }
    let runner = JobRunner::start(pool.clone(), 1).await.unwrap();
    let get = |id: &str| runner.get(ids_by_name(id));
    for id in ["a", "b"] {
        let r = get(id).await.unwrap();
        assert_eq!(r.status, JobStatus::Failed);
        assert_eq!(r.error.unwrap().reason, "interrupted");
        assert!(r.finished_at.is_some());
    }
    let c = get("c").await.unwrap();
    assert_eq!(c.status, JobStatus::Succeeded);
    assert!(c.error.is_none());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_interrupts_running_jobs_and_refuses_new_ones() {
    let (runner, _pool, _dir) = setup(1).await;
    let job = runner
        .submit("unit", testing::sleep_job(1000, 10, None))
        .await
        .unwrap();
    let queued = runner
        .submit("unit", testing::sleep_job(1, 1, None))
        .await
        .unwrap();
    wait_for(&runner, job.id, |r| r.status == JobStatus::Running).await;
    runner.shutdown(Duration::from_secs(10)).await;
    for id in [job.id, queued.id] {
        let r = runner.get(id).await.unwrap();
        assert_eq!(r.status, JobStatus::Failed);
        assert_eq!(r.error.unwrap().reason, "interrupted");
    }
    assert!(matches!(
        runner.submit("unit", testing::sleep_job(1, 1, None)).await,
        Err(RunnerError::ShuttingDown)
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_waiting_job_takes_no_job_slot_and_is_recorded_like_any_job() {
    // one slot; a waiting job holds on until released, and a computing job runs meanwhile
    let (runner, _pool, _dir) = setup(1).await;
    let (release, released) = tokio::sync::oneshot::channel::<()>();
    let waiting = runner
        .submit_waiting("unit.wait", move |ctx| {
            Box::pin(async move {
                ctx.progress(0.5, "waiting for a worker");
                released
                    .await
                    .map_err(|_| JobError::Failed("never released".into()))?;
                Ok(JobOutput::empty().with_message("released"))
            })
        })
        .await
        .unwrap();
    let live = wait_for(&runner, waiting.id, |r| r.progress.fraction == 0.5).await;
    assert_eq!(live.status, JobStatus::Running);
    let computing = runner
        .submit("unit", |_ctx| {
            Ok(JobOutput::empty().with_message("computed"))
        })
        .await
        .unwrap();
    let done = wait_final(&runner, computing.id).await;
    assert_eq!(done.status, JobStatus::Succeeded, "{done:?}");
    assert_eq!(
        runner.get(waiting.id).await.unwrap().status,
        JobStatus::Running,
        "the computing job ran beside the waiting one"
    );
    release.send(()).unwrap();
    let finished = wait_final(&runner, waiting.id).await;
    assert_eq!(finished.status, JobStatus::Succeeded, "{finished:?}");
    assert_eq!(finished.progress.message.as_deref(), Some("released"));
    // and it is cancelled like any job
    let (_keep, never) = tokio::sync::oneshot::channel::<()>();
    let stuck = runner
        .submit_waiting("unit.wait", move |ctx| {
            Box::pin(async move {
                tokio::select! {
                    _ = never => Ok(JobOutput::empty()),
                    () = async {
                        while !ctx.is_cancelled() {
                            tokio::time::sleep(Duration::from_millis(5)).await;
                        }
                    } => Err(JobError::Cancelled),
                }
            })
        })
        .await
        .unwrap();
    wait_for(&runner, stuck.id, |r| r.status == JobStatus::Running).await;
    runner.cancel(stuck.id).await.unwrap();
    assert_eq!(
        wait_final(&runner, stuck.id).await.status,
        JobStatus::Cancelled
    );
}
