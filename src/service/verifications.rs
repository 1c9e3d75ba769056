//! Physics verification of many plans at once (issue 24 §3 item 6): a job over robots ×
//! objects × placements × task sets that plans each combination with `verify: true`, waits for
//! the physics worker's verdict, and stores which plan answered which combination;
//! `GET /v1/verifications/{id}` reads the verdicts from the plans' executions and tabulates
//! them per system and object.
//!
//! Each robot's plans run one after another (the robots side by side): a physics worker puts
//! the robot back where it started after each trial (`--reset start`), so every plan starts
//! where the worker is, and the start check of the next plan sees that state rather than the
//! end of a queued grasp.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use sqlx::Row;
use utoipa::ToSchema;

use super::grasps::{GraspIn, ObjectIn, TaskDirectionIn};
use super::plans::{PlanIn, StartIn, Verification};
use super::{Context, Error, Invalid};
use crate::bridge::protocol::Capability;
use crate::bridge::{RequestedMode, TrialSpec};
use crate::grasp::{Goal, ObjectSpec, Transmission};
use crate::jobs::{JobContext, JobError, JobOutput, JobRecord};
use crate::store::jobs::ResultRef;

/// Most plans one verification may make.
pub const MAX_PLANS: usize = 200;

/// Robots × objects × placements × task sets to plan with `verify: true`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"robots": ["wam_t42", "pa10_t42"], "objects": ["ball", "bottle"],
                          "placements": [{"x": 0.5, "y": 0.0}, {"x": 0.55, "y": 0.15}]}))]
pub struct VerificationIn {
    /// Robot systems, 1 to 8 ids (one listed twice counts once); each needs a connected worker
    /// with the `grasp_trial` capability when the request is made (409 otherwise).
    #[schema(min_items = 1, max_items = 8)]
    pub robots: Vec<String>,
    /// Objects, 1 to 16 (one listed twice counts once): stored ids or seeded names, each with
    /// a `mass` and a `friction`.
    #[schema(min_items = 1, max_items = 16)]
    pub objects: Vec<String>,
    /// Where to put each object: its centroid's `x`, `y` in the robot base frame, m (its
    /// height, orientation and support kept), at most 8. Default: where each object is stored.
    /// A placement out of reach makes infeasible plans, not a refused request.
    #[serde(default)]
    #[schema(max_items = 8)]
    pub placements: Vec<Placement>,
    /// Task sets, at most 8, each the `task_directions` of a plan (an empty set: a grasp with
    /// no task, as a plan without `task_directions`). Default: one set, the force along +z
    /// maximised (lift the object).
    #[serde(default)]
    #[schema(max_items = 8)]
    pub tasks: Vec<Vec<TaskDirectionIn>>,
    /// Start of every motion, as a plan's `start` (default `"zero"`).
    pub start: Option<StartIn>,
    /// Execution mode of every plan (default `open_loop`).
    pub mode: Option<RequestedMode>,
    /// The grasp trial (default 0.1 m lift, 2 s hold, 2 shakes).
    pub trial: Option<TrialSpec>,
}

/// Where an object's centroid goes on its support (robot base frame, m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    pub x: f64,
    pub y: f64,
}

/// One combination and the plan that answered it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct VerificationItem {
    pub robot: String,
    /// The object's name and id.
    pub object: String,
    pub object_id: String,
    /// The placement used (absent: the object where it is stored).
    pub placement: Option<Placement>,
    /// Index into the request's task sets.
    pub task: usize,
    /// The plan (absent when the plan request itself was refused: `error`).
    pub plan_id: Option<String>,
    /// Why no plan was made (a refused request, e.g. a start far from the worker).
    pub error: Option<String>,
}

/// A combination with its verdict as it stands.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct VerifiedItem {
    #[serde(flatten)]
    pub item: VerificationItem,
    /// The plan found a feasible grasp and a collision-free motion (absent: no plan, or the
    /// plan was deleted since).
    pub feasible: Option<bool>,
    /// Why the plan is infeasible.
    pub reason: Option<String>,
    /// The physics check of a feasible plan.
    pub verification: Option<Verification>,
}

/// Counts of one system and object.
#[derive(Debug, Clone, Default, Serialize, Deserialize, ToSchema)]
pub struct VerificationCounts {
    pub robot: String,
    pub object: String,
    /// Combinations.
    pub plans: usize,
    /// Feasible plans.
    pub feasible: usize,
    /// Plans whose object was held in the trial.
    pub held: usize,
    /// Feasible plans not verified (yet): still queued or running, or their execution ended
    /// without a trial verdict.
    pub unverified: usize,
}

/// A verification: every combination with its verdict, and the table per system and object.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct VerificationReport {
    pub id: String,
    /// The job that made the plans.
    pub job_id: String,
    pub created_at: String,
    /// The task sets the items' `task` indexes.
    pub tasks: Vec<Vec<TaskDirectionIn>>,
    pub items: Vec<VerifiedItem>,
    /// Per system and object, in request order.
    pub table: Vec<VerificationCounts>,
    /// Over all combinations.
    pub total: VerificationCounts,
}

/// The force along +z maximised: a lift.
fn lift_task() -> Vec<TaskDirectionIn> {
    vec![TaskDirectionIn {
        direction: [0.0, 0.0, 1.0],
        kind: Transmission::Force,
        goal: Goal::Maximize,
    }]
}

/// A plan's object: the stored one, moved to `placement`.
fn placed(spec: &ObjectSpec, placement: Option<Placement>) -> ObjectIn {
    let mut position = spec.position;
    if let Some(Placement { x, y }) = placement {
        position[0] = x;
        position[1] = y;
    }
    ObjectIn {
        name: spec.name.clone(),
        shape: Some(spec.shape.clone()),
        mesh: None,
        position,
        orientation: Some(spec.orientation),
        support: spec.support,
        mass: spec.mass,
        friction: spec.friction,
    }
}

/// Validates the request (422 naming the field) and submits the job.
pub async fn submit(ctx: &Context, body: &VerificationIn) -> Result<JobRecord, Error> {
    let mut errors = Vec::new();
    let mut count = |path: &str, n: usize, lo: usize, hi: usize| {
        if !(lo..=hi).contains(&n) {
            errors.push(Invalid::new(
                path,
                format!("must hold {lo} to {hi} items, got {n}"),
            ));
        }
    };
    count("$.robots", body.robots.len(), 1, 8);
    count("$.objects", body.objects.len(), 1, 16);
    count("$.placements", body.placements.len(), 0, 8);
    count("$.tasks", body.tasks.len(), 0, 8);
    if !errors.is_empty() {
        return Err(Error::Invalid(errors));
    }
    let tasks = if body.tasks.is_empty() {
        vec![lift_task()]
    } else {
        body.tasks.clone()
    };
    for (i, t) in tasks.iter().enumerate() {
        super::grasps::check_task_directions(&format!("$.tasks[{i}]"), t)?;
    }
    if let Some(t) = &body.trial
        && let Some((field, why)) = t.invalid_field()
    {
        return Err(Error::invalid(format!("$.trial.{field}"), why));
    }
    // (the paths name the request's own positions; a repeat is skipped)
    let once = |list: &[String]| -> Vec<(usize, String)> {
        let mut seen = Vec::new();
        for (i, a) in list.iter().enumerate() {
            if !seen.iter().any(|(_, b)| b == a) {
                seen.push((i, a.clone()));
            }
        }
        seen
    };
    let robots = once(&body.robots);
    let workers = ctx.bridges.workers();
    for (i, robot) in &robots {
        let path = format!("$.robots[{i}]");
        super::robots::robot_field(ctx, robot, &path).await?;
        if !workers
            .iter()
            .any(|w| w.robot == *robot && w.can(Capability::GraspTrial))
        {
            // (the request is sound; the service's state is not ready for it)
            return Err(Error::Conflict(format!(
                "{path}: no worker with the grasp_trial capability is connected for robot \
                 '{robot}': start a physics worker (workers/mujoco/run-worker --robot {robot} \
                 --url … --token …) and ask again"
            )));
        }
    }
    let mut objects = Vec::with_capacity(body.objects.len());
    for (i, id) in &once(&body.objects) {
        let path = format!("$.objects[{i}]");
        let (oid, object) = super::grasps::stored_object(ctx, &path, id).await?;
        if let Some((field, meaning)) = object.spec().missing_physics() {
            return Err(Error::invalid(
                path,
                format!(
                    "object '{id}' has no {field}: a physics check needs {meaning}; store it \
                     again with \"{field}\" (POST /v1/objects)"
                ),
            ));
        }
        objects.push((oid, object.spec().clone()));
    }
    let placements: Vec<Option<Placement>> = if body.placements.is_empty() {
        vec![None]
    } else {
        body.placements.iter().copied().map(Some).collect()
    };
    let total = robots.len() * objects.len() * placements.len() * tasks.len();
    if total > MAX_PLANS {
        return Err(Error::invalid(
            "$",
            format!(
                "{total} combinations (robots × objects × placements × tasks); at most \
                 {MAX_PLANS} per verification"
            ),
        ));
    }
    // Every combination, grouped by robot (each robot's run one after another).
    let mut plans: Vec<Vec<(VerificationItem, PlanIn)>> = Vec::new();
    for (_, robot) in &robots {
        let mut mine = Vec::new();
        for (oid, spec) in &objects {
            for &placement in &placements {
                for (k, task) in tasks.iter().enumerate() {
                    let item = VerificationItem {
                        robot: robot.clone(),
                        object: spec.name.clone(),
                        object_id: oid.clone(),
                        placement,
                        task: k,
                        plan_id: None,
                        error: None,
                    };
                    let plan = PlanIn {
                        grasp: GraspIn {
                            robot: robot.clone(),
                            object_id: None,
                            object: Some(placed(spec, placement)),
                            task_directions: task.clone(),
                            quality: None,
                            weights: None,
                            starts: None,
                            max_starts: None,
                            seed: None,
                            elbow_reference: None,
                        },
                        start: body.start.clone().unwrap_or(StartIn::Word("zero".into())),
                        model: None,
                        duration: None,
                        rate: None,
                        execute: false,
                        verify: true,
                        trial: body.trial,
                        mode: body.mode,
                        worker: None,
                        obstacles: Vec::new(),
                        approach_standoff: None,
                    };
                    mine.push((item, plan));
                }
            }
        }
        plans.push(mine);
    }
    let request = serde_json::to_string(body).map_err(Error::internal)?;
    // A verification mostly waits for physics workers: it runs on the runtime and takes no job
    // slot (its plans pass the compute gate as any request's do).
    let jobs = ctx.jobs.clone();
    let ctx = ctx.clone();
    Ok(jobs
        .submit_waiting("verification", move |job| {
            Box::pin(async move {
                let items = run(&ctx, &job, plans, total).await?;
                let made = items.iter().filter(|i| i.plan_id.is_some()).count();
                Ok(JobOutput::persist_with(move |job_id, tx| {
                    Box::pin(async move {
                        let id = uuid::Uuid::new_v4().to_string();
                        sqlx::query(
                            "INSERT INTO verifications (id, job_id, request, items, created_at) \
                         VALUES (?, ?, ?, ?, ?)",
                        )
                        .bind(&id)
                        .bind(job_id.to_string())
                        .bind(&request)
                        .bind(serde_json::to_string(&items)?)
                        .bind(crate::store::now())
                        .execute(&mut **tx)
                        .await?;
                        Ok(ResultRef::new("verifications", id))
                    })
                })
                .with_message(format!("{made} of {total} plans made and run")))
            })
        })
        .await?)
}

/// Plans and waits for every combination, each robot's in order, the robots side by side.
async fn run(
    ctx: &Context,
    job: &JobContext,
    plans: Vec<Vec<(VerificationItem, PlanIn)>>,
    total: usize,
) -> Result<Vec<VerificationItem>, JobError> {
    let done = AtomicUsize::new(0);
    let per_robot = plans.into_iter().map(|mine| {
        let done = &done;
        async move {
            let mut out = Vec::with_capacity(mine.len());
            for (mut item, plan) in mine {
                if job.is_cancelled() {
                    break;
                }
                match super::plans::plan(ctx, &plan).await {
                    Ok(p) => {
                        item.plan_id = Some(p.stored.plan.id.clone());
                        if let Some(e) = &p.stored.execution_id {
                            wait(ctx, job, e).await;
                        }
                    }
                    Err(e) => item.error = Some(e.to_string()),
                }
                out.push(item);
                let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                job.progress(
                    n as f64 / total as f64,
                    format!("{n} of {total} plans verified"),
                );
            }
            out
        }
    });
    let items: Vec<VerificationItem> = futures::future::join_all(per_robot)
        .await
        .into_iter()
        .flatten()
        .collect();
    job.check_cancelled()?;
    Ok(items)
}

/// Until execution `id` has ended (a cancelled job cancels it).
async fn wait(ctx: &Context, job: &JobContext, id: &str) {
    let finished = ctx.bridges.wait_final(id);
    tokio::pin!(finished);
    loop {
        tokio::select! {
            _ = &mut finished => return,
            () = tokio::time::sleep(Duration::from_millis(250)) => {
                if job.is_cancelled() {
                    let _ = ctx.bridges.cancel(id).await;
                    return;
                }
            }
        }
    }
}

/// A verification in a listing: what was asked, without the verdicts.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct VerificationSummary {
    pub id: String,
    pub job_id: String,
    pub robots: Vec<String>,
    pub objects: Vec<String>,
    /// Combinations planned.
    pub plans: usize,
    pub created_at: String,
}

/// Verifications, newest first, with how many there are.
pub async fn list(
    ctx: &Context,
    limit: u32,
    offset: u32,
) -> Result<(Vec<VerificationSummary>, i64), Error> {
    let rows = sqlx::query(
        "SELECT id, job_id, request, items, created_at FROM verifications \
         ORDER BY created_at DESC, id LIMIT ? OFFSET ?",
    )
    .bind(i64::from(limit))
    .bind(i64::from(offset))
    .fetch_all(&ctx.db)
    .await?;
    let total: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM verifications")
        .fetch_one(&ctx.db)
        .await?;
    let mut out = Vec::with_capacity(rows.len());
    for row in rows {
        let request: VerificationIn =
            serde_json::from_str(row.get::<&str, _>("request")).map_err(Error::internal)?;
        let items: Vec<VerificationItem> =
            serde_json::from_str(row.get::<&str, _>("items")).map_err(Error::internal)?;
        out.push(VerificationSummary {
            id: row.get("id"),
            job_id: row.get("job_id"),
            robots: request.robots,
            objects: request.objects,
            plans: items.len(),
            created_at: row.get("created_at"),
        });
    }
    Ok((out, total))
}

/// Deletes verification `id`'s report (its plans stay).
pub async fn delete(ctx: &Context, id: &str) -> Result<(), Error> {
    let gone = sqlx::query("DELETE FROM verifications WHERE id = ?")
        .bind(id)
        .execute(&ctx.db)
        .await?
        .rows_affected();
    if gone == 0 {
        return Err(Error::not_found("verification", id));
    }
    Ok(())
}

/// Verification `id` with every combination's verdict as it stands.
pub async fn get(ctx: &Context, id: &str) -> Result<VerificationReport, Error> {
    let row =
        sqlx::query("SELECT job_id, request, items, created_at FROM verifications WHERE id = ?")
            .bind(id)
            .fetch_optional(&ctx.db)
            .await?
            .ok_or_else(|| Error::not_found("verification", id))?;
    let items: Vec<VerificationItem> =
        serde_json::from_str(row.get::<&str, _>("items")).map_err(Error::internal)?;
    let request: VerificationIn =
        serde_json::from_str(row.get::<&str, _>("request")).map_err(Error::internal)?;
    let tasks = if request.tasks.is_empty() {
        vec![lift_task()]
    } else {
        request.tasks
    };
    // (two queries for all items: their plans, then those plans' executions)
    let plan_ids: Vec<&str> = items.iter().filter_map(|i| i.plan_id.as_deref()).collect();
    let mut plans: HashMap<String, crate::store::plans::PlanRow> =
        crate::store::plans::get_many(&ctx.db, &plan_ids)
            .await?
            .into_iter()
            .map(|p| (p.id.clone(), p))
            .collect();
    let execution_ids: Vec<&str> = plans
        .values()
        .filter_map(|p| p.execution_id.as_deref())
        .collect();
    let mut checks: HashMap<String, Verification> =
        crate::store::executions::get_many_with_trial(&ctx.db, &execution_ids)
            .await?
            .into_iter()
            .filter_map(|(row, trial)| {
                let check = Verification::of_stored(&row, trial)?;
                Some((row.id, check))
            })
            .collect();
    let mut out = Vec::with_capacity(items.len());
    for item in items {
        let plan = item.plan_id.as_deref().and_then(|p| plans.remove(p));
        let verification = plan
            .as_ref()
            .and_then(|p| p.execution_id.as_deref())
            .and_then(|e| checks.remove(e));
        out.push(VerifiedItem {
            feasible: plan.as_ref().map(|p| p.feasible),
            reason: plan.and_then(|p| p.reason),
            verification,
            item,
        });
    }
    let mut table: Vec<VerificationCounts> = Vec::new();
    let mut total = VerificationCounts {
        robot: "all".into(),
        object: "all".into(),
        ..VerificationCounts::default()
    };
    let mut at = BTreeMap::new();
    for v in &out {
        let key = (v.item.robot.clone(), v.item.object_id.clone());
        let i = *at.entry(key).or_insert_with(|| {
            table.push(VerificationCounts {
                robot: v.item.robot.clone(),
                object: v.item.object.clone(),
                ..VerificationCounts::default()
            });
            table.len() - 1
        });
        for c in [&mut table[i], &mut total] {
            c.plans += 1;
            if v.feasible == Some(true) {
                c.feasible += 1;
                match v.verification.as_ref().and_then(|x| x.held) {
                    Some(true) => c.held += 1,
                    Some(false) => {}
                    None => c.unverified += 1,
                }
            }
        }
    }
    Ok(VerificationReport {
        id: id.to_owned(),
        job_id: row.get("job_id"),
        created_at: row.get("created_at"),
        tasks,
        items: out,
        table,
        total,
    })
}
