//! Pages of the motion pipeline's resources: mappings, models, trajectories, bridges,
//! executions, with the forms that start the next step (train, plan, execute).

use axum::extract::{Path, Query, State};
use serde::Deserialize;

use super::html::{
    self, PageError, esc, facts, field, figure, form, link, num, progress, short, table,
};
use crate::bridge::Mode;
use crate::service::Context as AppState;
use crate::store::executions::{self as execution_repo, ExecutionState};
use crate::store::grasps as grasp_repo;
use crate::store::mappings as mapping_repo;
use crate::store::models as model_repo;
use crate::store::trajectories as trajectory_repo;

type Page = Result<axum::response::Response, PageError>;

fn pretty(json: &str) -> String {
    serde_json::from_str::<serde_json::Value>(json)
        .and_then(|v| serde_json::to_string_pretty(&v))
        .unwrap_or_else(|_| json.to_owned())
}

/// A live progress bar for an execution (the script follows its Server-Sent Events).
pub(super) fn execution_progress(id: &str, state: ExecutionState, fraction: f64) -> String {
    progress(id, state.as_str(), fraction)
        .replacen(
            "class=\"job-status\"",
            "class=\"job-status exec-status\"",
            1,
        )
        .replacen("data-job=", "data-execution=", 1)
}

/// How far an execution is, 0 to 1: all of it once it succeeded, else as far as its latest
/// feedback says.
pub(super) fn execution_fraction(view: &crate::service::executions::ExecutionView) -> f64 {
    match (&view.last_feedback, view.row.state) {
        (_, ExecutionState::Succeeded) => 1.0,
        (Some(f), _) => f.progress,
        _ => 0.0,
    }
}

/// The safety filter's account of a closed-loop execution with a scene (its worker's
/// `result`): the closest pair and when, the smallest barrier, how often the filter acted.
pub(super) fn safety_fact(view: &crate::service::executions::ExecutionView) -> Option<String> {
    let s = view.tracking.as_ref()?.safety.as_ref()?;
    let mm = |x: Option<f64>| x.map_or_else(|| "–".to_owned(), |v| format!("{:.1} mm", v * 1e3));
    let pair = match (&s.link, &s.other) {
        (Some(l), Some(o)) => format!(
            " ({} / {}{})",
            esc(l),
            esc(o),
            s.time_s
                .map_or_else(String::new, |t| format!(", at {t:.2} s"))
        ),
        _ => String::new(),
    };
    Some(format!(
        "closest {}{pair}; smallest barrier {}; filtered {} of {} periods",
        mm(s.min_distance_m),
        mm(s.min_barrier_m),
        s.filtered_periods,
        s.periods
    ))
}

/// A physics worker's grasp trial, as one line: held or not, lift, slip, grip, force.
pub(super) fn physics_fact(view: &crate::service::executions::ExecutionView) -> Option<String> {
    let p = view.tracking.as_ref()?.physics.as_ref()?;
    let Some(t) = &p.trial else {
        return Some(format!("{}: no grasp trial", esc(&p.engine)));
    };
    let grip = match (t.grip, &t.grip_raised_in) {
        (Some(g), Some(phase)) => format!("; grip {g:.2} of the limit, raised in {}", esc(phase)),
        (Some(g), None) => format!("; grip {g:.2} of the limit"),
        _ => String::new(),
    };
    let force = t
        .contact_force_total_mean_n
        .map_or_else(String::new, |f| format!("; contact force {f:.1} N"));
    Some(format!(
        "{}: {} (lifted {:.3} m, slip {:.1} mm{grip}{force})",
        esc(&p.engine),
        if t.held { "held" } else { "not held" },
        t.object_lift_m,
        t.slip_m * 1e3,
    ))
}

fn train_form(robot: &str, mapping: &str) -> String {
    form(
        "train-form",
        "Train a motion model",
        "/v1/models",
        &[
            field("robot", "robot", "$.robot", "text", robot),
            field("mappings (ids)", "mappings", "$.mappings", "list", mapping),
            field(
                "variance threshold",
                "variance_threshold",
                "$.variance_threshold",
                "float",
                "",
            ),
            field("held-out folds", "held_out", "$.held_out", "bool", "false"),
        ],
        "Train",
    )
}

async fn trajectory_form(state: &AppState, model: &str, robot: &str) -> Result<String, PageError> {
    let system = state.robots.system(robot).await?;
    let m = &system.model;
    let neutral: Vec<String> = m.neutral().iter().map(|v| num(*v, 4)).collect();
    let grasps = grasp_repo::list_grasps(&state.db, 200).await?;
    let opts: String = grasps
        .iter()
        .filter(|g| g.robot == robot && g.feasible)
        .map(|g| format!("{}={} ({})|", g.id, short(&g.id), g.created_at))
        .collect();
    Ok(form(
        "trajectory-form",
        "Plan a trajectory to a grasp",
        "/v1/trajectories",
        &[
            field("model", "model", "$.model", "text", model),
            field(
                "start joints",
                "start.joint_names",
                "$.start.joint_names",
                "list",
                &m.joint_names().join(", "),
            ),
            field(
                "start positions",
                "start.positions",
                "$.start.positions",
                "vec",
                &neutral.join(", "),
            ),
            field(
                "goal grasp",
                "goal.grasp",
                "$.goal.grasp",
                &format!("select:{opts}"),
                "",
            ),
            field("rate (Hz)", "rate", "$.rate", "float", "100"),
        ],
        "Plan",
    ))
}

fn execute_form(state: &AppState, robot: &str, trajectory: &str) -> String {
    let workers: String = state
        .bridges
        .workers()
        .iter()
        .filter(|w| w.robot == robot)
        .map(|w| format!("{}|", w.name))
        .collect();
    form(
        "execute-form",
        "Execute on a connected worker",
        "/v1/executions",
        &[
            field("robot", "robot", "$.robot", "text", robot),
            field("mode", "mode", "$.mode", "select:open_loop", "open_loop"),
            field(
                "trajectory",
                "trajectory_id",
                "$.trajectory_id",
                "text",
                trajectory,
            ),
            field(
                "worker (empty: any)",
                "worker",
                "$.worker",
                &format!("select:=any|{workers}"),
                "",
            ),
        ],
        "Execute",
    )
}

#[derive(Debug, Deserialize)]
pub struct PageQuery {
    offset: Option<u32>,
}

pub async fn mappings(State(state): State<AppState>, Query(q): Query<PageQuery>) -> Page {
    let offset = q.offset.unwrap_or(0);
    let (rows, total) =
        mapping_repo::list_mappings(&state.db, 100, i64::from(offset), None, None).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|m| {
            vec![
                link(&format!("/ui/mappings/{}", m.id), short(&m.id)),
                esc(&m.robot),
                esc(&m.status),
                link(&format!("/ui/jobs/{}", m.job_id), "job"),
                esc(&m.created_at),
            ]
        })
        .collect();
    let body = format!(
        "<p class=\"pager\">{total} mappings</p>{}",
        table(&["mapping", "robot", "status", "job", "created"], &trs)
    );
    Ok(html::ok("Mappings", "/ui/mappings", &body))
}

#[derive(Debug, Deserialize)]
pub struct MappingQuery {
    demo: Option<usize>,
}

pub async fn mapping(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<MappingQuery>,
) -> Page {
    let Some(m) = mapping_repo::get_mapping(&state.db, &id).await? else {
        return Ok(html::not_found("mapping", &id, "/ui/mappings", "mappings"));
    };
    let (demos, total) = mapping_repo::list_demos(&state.db, &id, None, 200, 0).await?;
    let demo = q.demo.unwrap_or(0);
    let trs: Vec<Vec<String>> = demos
        .iter()
        .map(|d| {
            vec![
                link(
                    &format!("/ui/mappings/{id}?demo={}", d.position),
                    &d.position.to_string(),
                ),
                link(
                    &format!("/ui/demonstrations/{}", d.demonstration_id),
                    short(&d.demonstration_id),
                ),
                esc(&d.subject_id),
                esc(&d.object_name),
                d.position_index.to_string(),
                d.trial.to_string(),
                d.frame_count.to_string(),
            ]
        })
        .collect();
    let fig = if m.status == "succeeded" && total > 0 {
        figure(
            &format!("/v1/mappings/{id}/plot.svg?demo={demo}"),
            &format!("Fig. 2: human vs robot fingertip and elbow paths (demonstration {demo})"),
            true,
            "<label>postures <input name=\"postures\" type=\"number\" min=\"0\" max=\"10\" \
             value=\"3\"></label>",
        )
    } else {
        format!(
            "<p>The mapping is {}; {}</p>",
            esc(&m.status),
            progress(&m.job_id, &m.status, 0.0)
        )
    };
    let body = format!(
        "{}{fig}<h2>Mapped demonstrations ({total})</h2>{}{}<h2>Request</h2><pre>{}</pre>\
         <h2>Summary</h2><pre>{}</pre>",
        facts(&[
            ("robot", link(&format!("/ui/robots/{}", m.robot), &m.robot)),
            ("status", esc(&m.status)),
            ("job", link(&format!("/ui/jobs/{}", m.job_id), &m.job_id)),
            ("created", esc(&m.created_at)),
            (
                "3-D view",
                link(
                    &format!("/ui/view/mappings/{id}?demo={demo}"),
                    "human and robot side by side"
                )
            ),
            ("API", link(&format!("/v1/mappings/{id}"), "JSON")),
        ]),
        table(
            &[
                "#",
                "demonstration",
                "subject",
                "object",
                "position",
                "trial",
                "frames"
            ],
            &trs
        ),
        if m.status == "succeeded" {
            train_form(&m.robot, &id)
        } else {
            String::new()
        },
        esc(&pretty(&m.request)),
        esc(&m.summary.as_deref().map(pretty).unwrap_or_default()),
    );
    Ok(html::ok(
        &format!("Mapping {}", short(&id)),
        "/ui/mappings",
        &body,
    ))
}

pub async fn models(State(state): State<AppState>, Query(q): Query<PageQuery>) -> Page {
    let (rows, total) =
        model_repo::list_models(&state.db, None, 100, q.offset.unwrap_or(0)).await?;
    // The model plans use when none is named, per robot on this page.
    let mut defaults = std::collections::BTreeMap::new();
    for m in &rows {
        if !defaults.contains_key(&m.robot) {
            let d = model_repo::default_model_for(&state.db, &m.robot).await?;
            defaults.insert(m.robot.clone(), d.map(|d| d.id));
        }
    }
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|m| {
            let is_default = defaults.get(&m.robot).and_then(|d| d.as_deref()) == Some(&m.id);
            vec![
                link(&format!("/ui/models/{}", m.id), short(&m.id)),
                esc(&m.robot),
                esc(&m.status),
                if is_default {
                    "default".into()
                } else {
                    String::new()
                },
                link(&format!("/ui/jobs/{}", m.job_id), "job"),
                esc(&m.created_at),
            ]
        })
        .collect();
    let body = format!(
        "<p class=\"pager\">{total} models; a robot's default is what its plans use when none \
         is named</p>{}",
        table(
            &["model", "robot", "status", "plans use", "job", "created"],
            &trs
        )
    );
    Ok(html::ok("Models", "/ui/models", &body))
}

pub async fn model(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(m) = model_repo::get_model(&state.db, &id).await? else {
        return Ok(html::not_found("model", &id, "/ui/models", "models"));
    };
    let report: Option<serde_json::Value> = m
        .report
        .as_deref()
        .and_then(|r| serde_json::from_str(r).ok());
    let is_default = model_repo::default_model_for(&state.db, &m.robot)
        .await?
        .is_some_and(|d| d.id == m.id);
    let mut items = vec![
        ("robot", link(&format!("/ui/robots/{}", m.robot), &m.robot)),
        ("status", esc(&m.status)),
        (
            "default",
            if is_default {
                "yes: plans of this robot use it when none is named".into()
            } else {
                "no".into()
            },
        ),
        ("job", link(&format!("/ui/jobs/{}", m.job_id), &m.job_id)),
    ];
    let mut manifolds = Vec::new();
    if let Some(r) = &report {
        items.push((
            "training demonstrations",
            r["training_demonstrations"].to_string(),
        ));
        for g in r["manifolds"].as_array().into_iter().flatten() {
            manifolds.push(vec![
                esc(g["group"].as_str().unwrap_or("")),
                g["components"].to_string(),
                num(
                    g["cumulative_explained_variance"]
                        .as_f64()
                        .unwrap_or(f64::NAN),
                    3,
                ),
                num(g["train_alignment"].as_f64().unwrap_or(f64::NAN), 3),
                certificate_cell(&g["certificate"]),
            ]);
        }
        if let Some(o) = r["held_out"]["overall"].as_object() {
            items.push((
                "held-out deviation (NF / joint line)",
                format!(
                    "{} / {} (ratio {})",
                    num(o["nf"].as_f64().unwrap_or(f64::NAN), 4),
                    num(o["joint_line"].as_f64().unwrap_or(f64::NAN), 4),
                    num(o["ratio_to_joint_line"].as_f64().unwrap_or(f64::NAN), 3)
                ),
            ));
            if let (Some(dmp), Some(promp)) = (o["dmp"].as_f64(), o["promp"].as_f64()) {
                items.push((
                    "held-out deviation (DMP / ProMP)",
                    format!("{} / {}", num(dmp, 4), num(promp, 4)),
                ));
            }
        }
    }
    items.push(("API", link(&format!("/v1/models/{id}"), "JSON")));
    let trained = m.status == "succeeded";
    let fig = if trained {
        figure(
            &format!("/v1/models/{id}/plot.svg"),
            "Explained variance; demonstrated vs generated paths in PCA space",
            false,
            "",
        )
    } else {
        format!(
            "<p>Training is {}: {}</p>",
            esc(&m.status),
            progress(&m.job_id, &m.status, 0.0)
        )
    };
    let plan = if trained {
        trajectory_form(&state, &id, &m.robot).await?
    } else {
        String::new()
    };
    let body = format!(
        "{}{fig}<h2>Manifolds</h2>{}{plan}<h2>Request</h2><pre>{}</pre>",
        facts(&items),
        table(
            &[
                "group",
                "components",
                "cumulative variance",
                "flow alignment",
                "convergence certificate"
            ],
            &manifolds
        ),
        esc(&pretty(&m.request)),
    );
    Ok(html::ok(
        &format!("Model {}", short(&id)),
        "/ui/models",
        &body,
    ))
}

pub async fn trajectories(State(state): State<AppState>, Query(q): Query<PageQuery>) -> Page {
    let (rows, total) =
        trajectory_repo::list_trajectories(&state.db, None, 100, q.offset.unwrap_or(0)).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|t| {
            vec![
                link(&format!("/ui/trajectories/{}", t.id), short(&t.id)),
                esc(&t.robot),
                t.model_id
                    .as_deref()
                    .map(|m| link(&format!("/ui/models/{m}"), short(m)))
                    .unwrap_or_default(),
                num(t.duration, 3),
                esc(&t.created_at),
            ]
        })
        .collect();
    let body = format!(
        "<p class=\"pager\">{total} trajectories</p>{}",
        table(
            &["trajectory", "robot", "model", "duration (s)", "created"],
            &trs
        )
    );
    Ok(html::ok("Trajectories", "/ui/trajectories", &body))
}

/// What a lab checks before it runs a trajectory, from its stored report: timing against the
/// learned duration and the limits, the exact clearance (closest pair, per kind), what the
/// avoidance moved, how the end meets the grasp, and the approach and workspace-entry segments
/// with their notes. Empty for a summary that is not a trajectory report.
pub(super) fn report_facts(summary: &str) -> String {
    use crate::grasp::ClearanceHit;
    use crate::service::trajectories::TrajectoryReportDto;
    let Ok(r) = serde_json::from_str::<TrajectoryReportDto>(summary) else {
        return String::new();
    };
    let hit = |h: &Option<ClearanceHit>| {
        h.as_ref().map_or("–".to_owned(), |h| {
            format!(
                "{} mm: {} – {} at {} s",
                num(1e3 * h.distance_m, 1),
                esc(&h.link),
                esc(&h.other),
                num(h.time_s, 2)
            )
        })
    };
    let mut items = vec![
        (
            "duration",
            format!(
                "{} s (learned {} s; velocity and acceleration alone allow {} s)",
                num(r.duration, 2),
                num(r.learned_duration, 2),
                r.time_optimal_duration.map_or("–".into(), |t| num(t, 2))
            ),
        ),
        (
            "limit use",
            format!(
                "velocity {}, acceleration {}, jerk {}",
                num(r.max_velocity_ratio, 2),
                num(r.max_acceleration_ratio, 2),
                r.max_jerk_ratio.map_or("–".into(), |j| num(j, 2))
            ),
        ),
    ];
    if let Some(c) = &r.clearance {
        items.push((
            "collision-free",
            format!(
                "{} (exact, URDF collision shapes; contact up to {} mm{})",
                if c.collision_free {
                    "yes"
                } else {
                    "<strong>no</strong>"
                },
                num(1e3 * c.contact_tolerance_m, 1),
                if c.complete { "" } else { "; check incomplete" }
            ),
        ));
        items.push(("closest", hit(&c.closest)));
        items.push(("object", hit(&c.object)));
        items.push(("support", hit(&c.support)));
        if c.obstacle.is_some() {
            items.push(("obstacles", hit(&c.obstacle)));
        }
        items.push(("between links", hit(&c.self_collision)));
        items.push(("closing press", hit(&c.closing_contact)));
    }
    if let Some(a) = &r.avoidance {
        items.push((
            "avoidance",
            format!(
                "{} of {} rounds, points below target {} → {}, moved at most {} rad",
                a.rounds,
                a.max_rounds,
                a.below_target_before,
                a.below_target_after,
                num(a.max_displacement_rad, 3)
            ),
        ));
    }
    if let Some(a) = &r.arrival {
        items.push((
            "arrival",
            if a.from_inside == 0 {
                "every link touching the object or the table at the goal arrives from outside"
                    .to_owned()
            } else {
                format!(
                    "{} link(s) did not approach the goal from outside; end turned by up to {} \
                     rad, overshoot past the goal {} → {} mm",
                    a.from_inside,
                    num(a.max_change_rad, 3),
                    num(1e3 * a.overshoot_before_m, 2),
                    num(1e3 * a.overshoot_after_m, 2)
                )
            },
        ));
    }
    if let Some(a) = &r.approach {
        items.push(("approach", esc(&a.note)));
    }
    if let Some(e) = &r.workspace_entry {
        items.push(("workspace entry", esc(&e.note)));
    }
    format!("<h2>Timing and clearance</h2>{}", facts(&items))
}

pub async fn trajectory(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(t) = trajectory_repo::get_trajectory(&state.db, &id).await? else {
        return Ok(html::not_found(
            "trajectory",
            &id,
            "/ui/trajectories",
            "trajectories",
        ));
    };
    let body = format!(
        "{}{}{}{}<h2>Summary</h2><pre>{}</pre>",
        facts(&[
            ("robot", link(&format!("/ui/robots/{}", t.robot), &t.robot)),
            (
                "model",
                t.model_id
                    .as_deref()
                    .map(|m| link(&format!("/ui/models/{m}"), m))
                    .unwrap_or_default()
            ),
            ("duration", format!("{} s", num(t.duration, 3))),
            ("points", t.points.len().to_string()),
            ("joints", esc(&t.joint_names.join(", "))),
            (
                "3-D view",
                link(&format!("/ui/view/trajectories/{id}"), "play it back")
            ),
            ("API", link(&format!("/v1/trajectories/{id}"), "JSON")),
        ]),
        figure(
            &format!("/v1/trajectories/{id}/plot.svg"),
            "Joint positions over time",
            false,
            ""
        ),
        report_facts(&t.summary),
        execute_form(&state, &t.robot, &id),
        esc(&pretty(&t.summary)),
    );
    Ok(html::ok(
        &format!("Trajectory {}", short(&id)),
        "/ui/trajectories",
        &body,
    ))
}

/// What a worker's capabilities let it run, in words.
fn capability_words(caps: &[crate::bridge::protocol::Capability]) -> String {
    use crate::bridge::protocol::Capability as C;
    caps.iter()
        .map(|c| match c {
            C::OpenLoop => "open loop",
            C::ClosedLoop => "closed loop",
            C::SafetyFilter => "safety filter",
            C::PathFollowing => "path following",
            C::Streaming => "teleoperation (streaming)",
            C::GraspTrial => "grasp trial (physics)",
        })
        .collect::<Vec<_>>()
        .join(", ")
}

pub async fn bridges(State(state): State<AppState>) -> Page {
    let live = state.bridges.workers();
    let known = execution_repo::list_bridges(&state.db).await?;
    let mut trs: Vec<Vec<String>> = live
        .iter()
        .map(|w| {
            vec![
                esc(&w.name),
                esc(&w.robot),
                if w.execution_id.is_some() {
                    "connected, busy"
                } else {
                    "connected, idle"
                }
                .into(),
                w.execution_id
                    .as_deref()
                    .map(|e| link(&format!("/ui/executions/{e}"), short(e)))
                    .unwrap_or_default(),
                capability_words(&w.capabilities),
                esc(&w.connected_at),
            ]
        })
        .collect();
    for r in known
        .iter()
        .filter(|r| live.iter().all(|w| w.name != r.name))
    {
        trs.push(vec![
            esc(&r.name),
            esc(&r.robot),
            "disconnected".into(),
            String::new(),
            serde_json::from_str::<Vec<crate::bridge::protocol::Capability>>(&r.capabilities)
                .map(|c| capability_words(&c))
                .unwrap_or_default(),
            esc(&r.last_seen_at),
        ]);
    }
    let body = format!(
        "{}<p>Start a simulated worker with <code>reachgrasp bridge --sim</code>. A worker that \
         can stream is teleoperated from a keypoint stream: \
         <code>GET /v1/robots/{{id}}/retarget?forward=true</code> (README, Retargeting keypoint \
         streams).</p>",
        table(
            &[
                "worker",
                "robot",
                "status",
                "execution",
                "runs",
                "connected / last seen"
            ],
            &trs
        )
    );
    Ok(html::ok("Bridges", "/ui/bridges", &body))
}

pub async fn executions(State(state): State<AppState>, Query(q): Query<PageQuery>) -> Page {
    let rows = execution_repo::list(&state.db, None, None, 100, q.offset.unwrap_or(0)).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|e| {
            vec![
                link(&format!("/ui/executions/{}", e.id), short(&e.id)),
                esc(&e.robot),
                esc(e.mode.as_str()),
                execution_progress(
                    &e.id,
                    e.state,
                    if e.state == ExecutionState::Succeeded {
                        1.0
                    } else {
                        0.0
                    },
                ),
                esc(e.assigned_worker.as_deref().unwrap_or("")),
                esc(&e.created_at),
            ]
        })
        .collect();
    let body = table(
        &[
            "execution",
            "robot",
            "mode",
            "progress",
            "worker",
            "created",
        ],
        &trs,
    );
    Ok(html::ok("Executions", "/ui/executions", &body))
}

pub async fn execution(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(row) = execution_repo::get(&state.db, &id).await? else {
        return Ok(html::not_found(
            "execution",
            &id,
            "/ui/executions",
            "executions",
        ));
    };
    let view = crate::service::executions::view(&state, row);
    let mode = view.row.mode;
    let dto = &view.row;
    let fraction = execution_fraction(&view);
    let tracking = view
        .tracking
        .as_ref()
        .map(|t| {
            format!(
                "{} samples, max {}, rms {}",
                t.samples,
                num(t.max_error, 4),
                num(t.rms_error, 4)
            )
        })
        .unwrap_or_default();
    let source = match dto.kind.as_str() {
        "trajectory" => link(
            &format!("/ui/trajectories/{}", dto.source_id),
            &dto.source_id,
        ),
        "model" => link(&format!("/ui/models/{}", dto.source_id), &dto.source_id),
        _ => esc(&dto.source_id),
    };
    let safety = safety_fact(&view);
    let body = format!(
        "{}{}",
        facts(&[
            ("robot", esc(&dto.robot)),
            (
                "mode",
                esc(serde_json::to_value(mode)
                    .ok()
                    .and_then(|v| v.as_str().map(str::to_owned))
                    .as_deref()
                    .unwrap_or(""))
            ),
            ("source", source),
            ("progress", execution_progress(&id, dto.state, fraction)),
            ("reason", esc(dto.reason.as_deref().unwrap_or(""))),
            (
                "worker",
                esc(dto.assigned_worker.as_deref().unwrap_or("(not assigned)"))
            ),
            ("tracking error", tracking),
            ("safety filter", safety.unwrap_or_else(|| "–".into())),
            (
                "physics trial",
                physics_fact(&view).unwrap_or_else(|| "–".into())
            ),
            (
                "measured history",
                format!(
                    "{} samples ({})",
                    view.feedback_samples,
                    link(&format!("/v1/executions/{id}/feedback"), "JSON")
                )
            ),
            ("created", esc(&dto.created_at)),
            ("finished", esc(dto.finished_at.as_deref().unwrap_or(""))),
            (
                "3-D view",
                link(&format!("/ui/view/executions/{id}"), "live robot pose")
            ),
            ("API", link(&format!("/v1/executions/{id}"), "JSON")),
        ]),
        figure(
            &format!("/v1/executions/{id}/plot.svg"),
            if mode == Mode::ClosedLoop {
                "Measured joint positions over time, against the law's path (dashed) where it \
                 runs one (a bare law has no planned trajectory)"
            } else {
                "Planned (dashed) vs measured joint positions over time"
            },
            false,
            ""
        )
        .replacen(
            "<figure class=\"plot\"",
            "<figure class=\"plot\" data-execution",
            1
        ),
    );
    Ok(html::ok(
        &format!("Execution {}", short(&id)),
        "/ui/executions",
        &body,
    ))
}

/// A manifold's certificate in words: whether it holds, which theorem, and how much of the
/// fitted field it kept.
fn certificate_cell(c: &serde_json::Value) -> String {
    let theorem = match c["kind"].as_str() {
        Some("no_critical_point") => "no critical point but the goal (γ may rise)",
        _ => "γ strictly decreasing",
    };
    format!(
        "{}: {theorem}; field kept × {}",
        if c["holds"].as_bool() == Some(true) {
            "holds"
        } else {
            "does not hold"
        },
        num(c["shrink"].as_f64().unwrap_or(f64::NAN), 2)
    )
}
