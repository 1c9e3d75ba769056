//! Plans in the dashboard (issue 21): the list with the "plan and execute" form, one plan's page
//! linking its grasp, trajectory and execution, and a side-by-side comparison of grasps or plans.
//!
//! A plan is the user's unit of work, so its page gathers what the separate pages show (cost
//! terms, residuals, the trajectory's timing and clearance, the execution's live state) and
//! links each part to its own page for the details.

use axum::extract::{Path, Query, State};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use serde_json::Value;

use super::html::{
    self, PageError, esc, facts, field, figure, form, link, num, short, table, value_facts,
    value_text,
};
use super::pages::{not_firm, readable_grasp_value, task_fields};
use super::resources::{
    execution_fraction, execution_progress, physics_fact, report_facts, safety_fact,
};
use crate::grasp::{GraspResult, ObjectSpec};
use crate::service::Context as AppState;
use crate::service::grasps::GraspSettings;
use crate::service::plans::StoredPlan;
use crate::store::executions as execution_repo;
use crate::store::grasps::{self as grasp_repo, GraspRow};
use crate::store::plans as plan_repo;
use crate::store::robots as robot_repo;

type Page = Result<Response, PageError>;

/// Plans per page of the list.
const PAGE: u32 = 50;
/// Most columns a comparison shows side by side (more would not fit a screen).
const MAX_COMPARED: usize = 4;

/// The viewer page a colleague serves for a plan (3-D scene, motion replay).
fn view_href(id: &str) -> String {
    format!("/ui/view/plans/{id}")
}

/// `[x, y, z] force maximize; …` from the grasp request's task directions (JSON).
fn directions_text(v: &Value) -> String {
    v.as_array()
        .into_iter()
        .flatten()
        .map(|t| {
            let d: Vec<String> = t["direction"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(Value::as_f64)
                .map(|x| num(x, 2))
                .collect();
            format!(
                "[{}] {} {}",
                d.join(", "),
                t["kind"].as_str().unwrap_or(""),
                t["goal"].as_str().unwrap_or("")
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn feasible_text(feasible: bool, reason: Option<&str>) -> String {
    if feasible {
        "<span class=\"ok\">feasible</span>".to_owned()
    } else {
        format!(
            "<span class=\"bad\">infeasible</span>{}",
            reason.map(|r| format!(": {}", esc(r))).unwrap_or_default()
        )
    }
}

/// The start choices, as the JSON the API takes for `start`: `"current"` (the connected
/// worker's measured state) or `"zero"` (the zero configuration of whichever robot is chosen,
/// resolved by the service), so that no robot and start chosen together can disagree. With no
/// worker connected there is no current state, so the zero configuration is preselected (a plan
/// from `"current"` would be refused).
fn start_select(worker_connected: bool) -> String {
    let (current, zero) = if worker_connected {
        (" selected", "")
    } else {
        ("", " selected")
    };
    format!(
        "<div class=\"field\"><label>start</label><select name=\"start\" data-type=\"json\" \
         data-path=\"$.start\"><option value=\"&quot;current&quot;\"{current}>current: where the \
         connected worker is</option><option value=\"&quot;zero&quot;\"{zero}>zero configuration \
         of the robot</option></select><span class=\"field-error\"></span></div>"
    )
}

/// The "plan and execute" form: robot, object, task directions, start, and execution on a
/// connected bridge worker. On success the script opens the new plan's page (the API answers
/// 201 with its location).
async fn plan_form(state: &AppState) -> Result<String, PageError> {
    let robots: Vec<String> = robot_repo::list(&state.db)
        .await?
        .into_iter()
        .map(|r| r.id)
        .collect();
    let objects = grasp_repo::list_objects(&state.db).await?;
    let workers = state.bridges.workers();
    // The robot a worker is connected for is the one a user most likely wants to run.
    let default_robot = workers
        .first()
        .map(|w| w.robot.clone())
        .filter(|r| robots.contains(r))
        .or_else(|| robots.iter().find(|r| *r == "wam_ihy").cloned())
        .or_else(|| robots.first().cloned())
        .unwrap_or_default();
    let robot_opts: String = robots.iter().map(|r| format!("{r}|")).collect();
    let object_opts: String = objects
        .iter()
        .map(|o| format!("{}={}|", o.id, o.name))
        .collect();
    let worker_opts: String = workers
        .iter()
        .map(|w| format!("{n}={n} ({r})|", n = w.name, r = w.robot))
        .collect();
    let connected = if workers.is_empty() {
        "<p class=\"hint\">No bridge worker is connected: plan without executing, or start \
         one (<code>reachgrasp bridge --sim --robot wam_ihy --token …</code>).</p>"
            .to_owned()
    } else {
        String::new()
    };
    let [d0, k0, g0] = task_fields(0, false);
    let [d1, k1, g1] = task_fields(1, true);
    let fields = [
        field(
            "robot",
            "robot",
            "$.robot",
            &format!("select:{robot_opts}"),
            &default_robot,
        ),
        field(
            "object",
            "object_id",
            "$.object_id",
            &format!("select:{object_opts}"),
            objects.first().map(|o| o.id.as_str()).unwrap_or(""),
        ),
        d0,
        k0,
        g0,
        d1,
        k1,
        g1,
        start_select(!workers.is_empty()),
        field(
            "execute",
            "execute",
            "$.execute",
            "bool",
            if workers.is_empty() { "false" } else { "true" },
        ),
        field(
            "verify in physics (grasp trial)",
            "verify",
            "$.verify",
            "bool",
            "false",
        ),
        field(
            "worker",
            "worker",
            "$.worker",
            &format!("select:=any of the robot|{worker_opts}"),
            "",
        ),
        field(
            "mode",
            "mode",
            "$.mode",
            "select:open_loop=open loop (follow the trajectory)|closed_loop=closed loop (the \
             model's control law)",
            "open_loop",
        ),
        field(
            "approach standoff (m)",
            "approach_standoff",
            "$.approach_standoff",
            "float",
            "",
        ),
    ];
    Ok(form(
        "plan-form",
        "Plan and execute",
        "/v1/plans",
        &fields,
        "Plan",
    )
    .replacen(
        "</h2>",
        "</h2><p class=\"hint\">A task-specific grasp of the object, a humanlike motion to it \
         from the start, and, with execute, the motion run on a connected bridge worker; with \
         verify, on a physics worker (grasp_trial), which then lifts and shakes the object. \
         The new plan's page opens when it is stored.</p>",
        1,
    )
    .replacen("<button", &format!("{connected}<button"), 1))
}

#[derive(Debug, Deserialize)]
pub struct ListQuery {
    offset: Option<u32>,
}

pub async fn plans(State(state): State<AppState>, Query(q): Query<ListQuery>) -> Page {
    let offset = q.offset.unwrap_or(0);
    let (rows, total) = plan_repo::list_overview(&state.db, PAGE.into(), offset.into()).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|p| {
            let tasks = p
                .task_directions
                .as_deref()
                .and_then(|t| serde_json::from_str::<Value>(t).ok())
                .map(|t| directions_text(&t))
                .unwrap_or_default();
            let execution = match (&p.execution_id, &p.execution_state) {
                (Some(e), Some(s)) => format!(
                    "{} <span class=\"state state-{s}\">{s}</span>",
                    link(&format!("/ui/executions/{e}"), short(e)),
                    s = esc(s)
                ),
                (Some(e), None) => link(&format!("/ui/executions/{e}"), short(e)),
                _ => "–".into(),
            };
            vec![
                format!(
                    "<input type=\"checkbox\" name=\"plans\" value=\"{}\" \
                     aria-label=\"compare plan {}\">",
                    esc(&p.id),
                    esc(short(&p.id))
                ),
                link(&format!("/ui/plans/{}", p.id), short(&p.id)),
                esc(&p.robot),
                esc(p.object_name.as_deref().unwrap_or("")),
                esc(&tasks),
                feasible_text(p.feasible, p.reason.as_deref()),
                link(&format!("/ui/grasps/{}", p.grasp_id), short(&p.grasp_id)),
                p.trajectory_id
                    .as_deref()
                    .map(|t| {
                        format!(
                            "{} {} s",
                            link(&format!("/ui/trajectories/{t}"), short(t)),
                            p.duration.map(|d| num(d, 2)).unwrap_or_default()
                        )
                    })
                    .unwrap_or_else(|| "–".into()),
                execution,
                format!(
                    "<span class=\"when\">{}</span>",
                    esc(&html::when(&p.created_at))
                ),
            ]
        })
        .collect();
    let pager = html::pager(offset, PAGE, rows.len(), total, "");
    let list = if rows.is_empty() {
        table(&[], &[])
    } else {
        // A plain GET form: the ticked plans become `?plans=A&plans=B`.
        format!(
            "<form class=\"compare-pick\" action=\"/ui/compare\" method=\"get\">{}\
             <p><button type=\"submit\">Compare selected</button> <span class=\"hint\">tick \
             two to {MAX_COMPARED} plans</span></p></form>",
            table(
                &[
                    "",
                    "plan",
                    "robot",
                    "object",
                    "task",
                    "result",
                    "grasp",
                    "trajectory",
                    "execution",
                    "created",
                ],
                &trs,
            )
        )
    };
    let body = format!(
        "<section class=\"forms\">{}</section><p class=\"hint\">Many plans checked in \
         physics at once (<code>POST /v1/verifications</code>): {}.</p>{pager}{list}",
        plan_form(&state).await?,
        link("/ui/verifications", "physics verifications")
    );
    Ok(html::ok("Plans", "/ui/plans", &body))
}

/// The physics verifications, newest first: what each asked, linked to its report.
pub async fn verifications(State(state): State<AppState>, Query(q): Query<ListQuery>) -> Page {
    let offset = q.offset.unwrap_or(0);
    let (rows, total) = crate::service::verifications::list(&state, PAGE, offset).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|v| {
            vec![
                link(&format!("/ui/verifications/{}", v.id), short(&v.id)),
                esc(&v.robots.join(", ")),
                esc(&v.objects.join(", ")),
                v.plans.to_string(),
                link(&format!("/ui/jobs/{}", v.job_id), short(&v.job_id)),
                format!(
                    "<span class=\"when\">{}</span>",
                    esc(&html::when(&v.created_at))
                ),
            ]
        })
        .collect();
    let body = format!(
        "<p class=\"hint\">Each verification plans every combination of its robots, objects, \
         placements and tasks with <code>verify</code> and runs the feasible ones on a physics \
         worker (<code>POST /v1/verifications</code>; a running one is a job).</p>{}{}",
        html::pager(offset, PAGE, rows.len(), total, ""),
        table(
            &[
                "verification",
                "robots",
                "objects",
                "plans",
                "job",
                "created"
            ],
            &trs
        )
    );
    Ok(html::ok("Physics verifications", "/ui/plans", &body))
}

/// A grasp's parts as stored.
struct GraspParts {
    object: ObjectSpec,
    settings: GraspSettings,
    result: GraspResult,
}

fn grasp_parts(g: &GraspRow) -> Result<GraspParts, PageError> {
    Ok(GraspParts {
        object: serde_json::from_str(&g.object).map_err(PageError::internal)?,
        settings: serde_json::from_str(&g.request).map_err(PageError::internal)?,
        result: GraspResult::from_stored(&g.result).map_err(PageError::internal)?,
    })
}

/// `(name, value)` pairs of a JSON object, nested objects as `outer.inner`, in document order.
fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, Value)>) {
    if let Value::Object(map) = v {
        for (k, v) in map {
            let name = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            if v.is_object() {
                flatten(&name, v, out);
            } else {
                out.push((name, v.clone()));
            }
        }
    }
}

fn flat(v: &impl serde::Serialize) -> Result<Vec<(String, Value)>, PageError> {
    let mut out = Vec::new();
    flatten(
        "",
        &serde_json::to_value(v).map_err(PageError::internal)?,
        &mut out,
    );
    Ok(out)
}

/// Named quantities of one section of a grasp's numbers, titled.
type Section = (&'static str, Vec<(String, Value)>);

/// The numbers compared and shown for a grasp, by section: cost terms (eq. 12-22), the
/// optimiser's residuals with the exact check, and the arm and hand ellipsoids (eq. 10-11).
fn grasp_numbers(r: &GraspResult) -> Result<Vec<Section>, PageError> {
    let mut ellipsoids = Vec::new();
    for (part, e) in [("arm", &r.arm_ellipsoids), ("hand", &r.hand_ellipsoids)] {
        ellipsoids.push((
            format!("{part} velocity semi-axes"),
            serde_json::json!(e.velocity_semi_axes),
        ));
        ellipsoids.push((
            format!("{part} force semi-axes"),
            serde_json::json!(e.force_semi_axes),
        ));
        ellipsoids.push((format!("{part} major axis"), serde_json::json!(e.axes[0])));
    }
    let mut residuals = flat(&r.residuals)?;
    residuals.extend(
        flat(&r.exact)?
            .into_iter()
            .map(|(k, v)| (format!("exact.{k}"), v)),
    );
    let readable = |items: Vec<(String, Value)>| -> Vec<(String, Value)> {
        items
            .into_iter()
            .map(|(k, v)| {
                let v = readable_grasp_value(&k, &v);
                (k, v)
            })
            .collect()
    };
    Ok(vec![
        ("Cost terms", labelled(&flat(&r.terms)?)),
        ("Residuals and exact check", labelled(&readable(residuals))),
        ("Ellipsoids", readable(ellipsoids)),
    ])
}

/// The unit of a grasp quantity by its name (the documented units of `Terms`, `Residuals`,
/// `ExactCheck` and `Ellipsoids`), for the labels.
fn unit(name: &str) -> &'static str {
    let leaf = name.rsplit('.').next().unwrap_or(name);
    match leaf {
        "q_dc" => " (m)",
        "q_agp" | "d" => " (m²)",
        "min_limit_margin" => " (rad)",
        "max_pad_angle_deg" => " (°)",
        "max_coupling_error" | "max_spread_violation" => " (rad)",
        _ if leaf.contains("penetration")
            || leaf.contains("distance")
            || leaf.contains("separation") =>
        {
            " (m)"
        }
        _ => "",
    }
}

fn labelled(items: &[(String, Value)]) -> Vec<(String, Value)> {
    items
        .iter()
        .map(|(k, v)| (format!("{k}{}", unit(k)), v.clone()))
        .collect()
}

fn grasp_figure(id: &str, caption: &str) -> String {
    figure(
        &format!("/v1/grasps/{id}/plot.svg"),
        caption,
        true,
        "<label>ellipsoid <select name=\"ellipsoid\"><option value=\"\">auto</option>\
         <option>velocity</option><option>force</option></select></label>",
    )
}

/// The start as asked (`"current"` or a configuration) and, when a motion was generated, the
/// configuration it resolved to.
fn start_text(asked: &Value, stored: &StoredPlan) -> String {
    let resolved = stored
        .trajectory
        .as_ref()
        .map(|t| {
            t.start
                .iter()
                .map(|x| num(*x, 3))
                .collect::<Vec<_>>()
                .join(", ")
        })
        .map(|q| format!(" <span class=\"hint\">(q = {q})</span>"))
        .unwrap_or_default();
    let what = match asked {
        Value::String(s) if s == "current" => "current: where the connected worker was".to_owned(),
        Value::Object(_) => "a configuration".to_owned(),
        other => esc(&other.to_string()),
    };
    format!("{what}{resolved}")
}

pub async fn plan(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let stored = match crate::service::plans::get(&state, &id).await {
        Ok(s) => s,
        Err(crate::service::Error::NotFound { .. }) => {
            return Ok(html::not_found("plan", &id, "/ui/plans", "plans"));
        }
        Err(e) => return Err(e.into()),
    };
    let p = &stored.plan;
    let request: Value = serde_json::from_str(&p.request).map_err(PageError::internal)?;
    let timings: Value = serde_json::from_str(&p.timings).unwrap_or(Value::Null);
    let g = &stored.grasp;
    let parts = grasp_parts(g)?;
    let directions = serde_json::to_value(&parts.settings.task_directions)
        .map(|v| directions_text(&v))
        .unwrap_or_default();
    let object = match &g.object_id {
        Some(o) => link(&format!("/ui/objects/{o}"), &parts.object.name),
        None => format!("{} (inline)", esc(&parts.object.name)),
    };
    let execute = if request["execute"] == true {
        format!(
            "yes, {}{}",
            esc(request["mode"].as_str().unwrap_or("open_loop")),
            request["worker"]
                .as_str()
                .map(|w| format!(" on {}", esc(w)))
                .unwrap_or_default()
        )
    } else {
        "no".to_owned()
    };
    let obstacles = request["obstacles"].as_array().map_or(0, Vec::len);
    let mut rows = vec![
        ("robot", link(&format!("/ui/robots/{}", p.robot), &p.robot)),
        ("object", object),
        ("task", esc(&directions)),
        (
            "quality",
            serde_json::to_value(parts.settings.quality)
                .ok()
                .and_then(|v| v.as_str().map(esc))
                .unwrap_or_default(),
        ),
        ("start", start_text(&request["start"], &stored)),
        ("execute", execute),
        ("obstacles", obstacles.to_string()),
        (
            "model",
            p.model_id
                .as_deref()
                .map(|m| link(&format!("/ui/models/{m}"), short(m)))
                .unwrap_or_else(|| "–".into()),
        ),
        ("result", feasible_text(p.feasible, p.reason.as_deref())),
        (
            "time",
            format!(
                "grasp {} s, trajectory {} s, total {} s",
                num(timings["grasp_s"].as_f64().unwrap_or(f64::NAN), 3),
                num(timings["trajectory_s"].as_f64().unwrap_or(f64::NAN), 3),
                num(timings["total_s"].as_f64().unwrap_or(f64::NAN), 3)
            ),
        ),
        ("created", esc(&p.created_at)),
        (
            "see also",
            format!(
                "<a class=\"view3d\" href=\"{}\">3-D view</a> · {}",
                esc(&view_href(&id)),
                link(&format!("/v1/plans/{id}"), "JSON")
            ),
        ),
    ];
    // grasps the plan found and dropped because no collision-free motion reached them
    if let Some(list) = timings["rejected_grasps"]
        .as_array()
        .filter(|l| !l.is_empty())
    {
        let text: Vec<String> = list
            .iter()
            .map(|r| {
                format!(
                    "seed {}: {}",
                    r["seed"].as_u64().unwrap_or(0),
                    esc(r["reason"].as_str().unwrap_or(""))
                )
            })
            .collect();
        let after = rows
            .iter()
            .position(|(k, _)| *k == "result")
            .map_or(rows.len(), |i| i + 1);
        rows.insert(after, ("grasps dropped", text.join("<br>")));
    }
    let summary = facts(&rows);

    let r = &parts.result;
    let verdict = feasible_text(r.feasible, r.reason.as_deref());
    let mut grasp = format!(
        "<section class=\"part\" id=\"grasp\"><h2>Grasp {}</h2>{}",
        link(&format!("/ui/grasps/{}", g.id), short(&g.id)),
        facts(&[
            (
                "result",
                match not_firm(r) {
                    Some(why) => format!("{verdict}, <span class=\"bad\">not firm</span>: {why}"),
                    None => verdict,
                },
            ),
            (
                "starts",
                format!("{} run, {} feasible", r.starts_used, r.starts_feasible)
            ),
            ("time", format!("{} s", num(r.time_s, 3))),
        ])
    );
    grasp.push_str("<div class=\"split\"><div>");
    for (title, items) in grasp_numbers(r)? {
        grasp.push_str(&format!(
            "<h3>{}</h3>{}",
            esc(title),
            value_facts(items.iter().map(|(k, v)| (k.as_str(), v)))
        ));
    }
    grasp.push_str("</div><div>");
    grasp.push_str(&grasp_figure(
        &g.id,
        "Arm and hand at the grasp, contacts, task direction and ellipsoid",
    ));
    grasp.push_str("</div></div></section>");

    let trajectory = trajectory_section(&stored);
    let execution = execution_section(&state, &stored, request["execute"] == true).await?;

    let body = format!(
        "{summary}{}{grasp}{trajectory}{execution}",
        compare_with(&state, &id).await?
    );
    Ok(html::ok(
        &format!("Plan {}", short(&id)),
        "/ui/plans",
        &body,
    ))
}

/// The plan's motion: its timing and clearance facts beside its figure.
fn trajectory_section(stored: &StoredPlan) -> String {
    let p = &stored.plan;
    match &stored.trajectory {
        Some(t) => format!(
            "<section class=\"part\" id=\"trajectory\"><h2>Trajectory {}</h2><div class=\"split\">\
             <div>{}{}</div><div>{}</div></div></section>",
            link(&format!("/ui/trajectories/{}", t.id), short(&t.id)),
            facts(&[
                ("duration", format!("{} s", num(t.duration, 3))),
                ("points", t.points.len().to_string()),
                (
                    "executed",
                    match (&stored.execution_id, p.feasible) {
                        (Some(e), _) => format!(
                            "queued as {}",
                            link(&format!("/ui/executions/{e}"), short(e))
                        ),
                        (None, true) => "not asked".into(),
                        (None, false) => "never: the plan is infeasible; the motion is kept \
                                          for inspection"
                            .into(),
                    }
                ),
            ]),
            report_facts(&t.summary),
            figure(
                &format!("/v1/trajectories/{}/plot.svg", t.id),
                "Joint positions over time",
                false,
                ""
            ),
        ),
        None => "<section class=\"part\" id=\"trajectory\"><h2>Trajectory</h2><p class=\"empty\">\
                 No motion was generated: the plan stopped at the grasp.</p></section>"
            .to_owned(),
    }
}

/// The plan's execution: a live bar (the script follows its events) beside the planned vs
/// measured figure, or why there is none.
async fn execution_section(
    state: &AppState,
    stored: &StoredPlan,
    asked: bool,
) -> Result<String, PageError> {
    let p = &stored.plan;
    Ok(match &stored.execution_id {
        Some(e) => match execution_repo::get(&state.db, e).await? {
            Some(row) => {
                let view = crate::service::executions::view(state, row);
                let dto = &view.row;
                let fraction = execution_fraction(&view);
                let tracking = view
                    .tracking
                    .as_ref()
                    .map(|t| {
                        format!(
                            "max {}, rms {} rad over {} samples",
                            num(t.max_error, 4),
                            num(t.rms_error, 4),
                            t.samples
                        )
                    })
                    .unwrap_or_else(|| "–".into());
                format!(
                    "<section class=\"part\" id=\"execution\"><h2>{} {}</h2>\
                     <div class=\"split\"><div>{}</div><div>{}</div></div></section>",
                    if stored.verification.is_some() {
                        "Physics verification: execution"
                    } else {
                        "Execution"
                    },
                    link(&format!("/ui/executions/{e}"), short(e)),
                    facts(&[
                        ("state", execution_progress(e, dto.state, fraction)),
                        ("reason", esc(dto.reason.as_deref().unwrap_or("–"))),
                        (
                            "worker",
                            esc(dto
                                .assigned_worker
                                .as_deref()
                                .unwrap_or("(not assigned yet)"))
                        ),
                        ("tracking error", tracking),
                        (
                            "safety filter",
                            safety_fact(&view).unwrap_or_else(|| "–".into())
                        ),
                        (
                            "physics trial",
                            physics_fact(&view).unwrap_or_else(|| match &stored.verification {
                                Some(v) => format!(
                                    "{} m lift, {} s hold, {} shakes: waiting for a physics \
                                     worker's report",
                                    num(v.trial.lift, 3),
                                    num(v.trial.hold_s, 1),
                                    v.trial.shakes
                                ),
                                None => "–".into(),
                            })
                        ),
                        (
                            "penetration in simulation",
                            stored
                                .verification
                                .as_ref()
                                .and_then(|v| v.max_penetration_m.as_ref())
                                .map(|m| {
                                    m.iter()
                                        .map(|(k, d)| format!("{} {} mm", esc(k), num(d * 1e3, 1)))
                                        .collect::<Vec<_>>()
                                        .join(", ")
                                })
                                .unwrap_or_else(|| "–".into())
                        ),
                        ("finished", esc(dto.finished_at.as_deref().unwrap_or("–"))),
                    ]),
                    // `data-execution`: the script reloads this figure when the run ends.
                    figure(
                        &format!("/v1/executions/{e}/plot.svg"),
                        "Planned (dashed) vs measured joint positions over time",
                        false,
                        ""
                    )
                    .replacen(
                        "<figure class=\"plot\"",
                        "<figure class=\"plot\" data-execution",
                        1
                    ),
                )
            }
            None => format!(
                "<section class=\"part\" id=\"execution\"><h2>Execution</h2><p class=\"empty\">\
                 Execution {} has been deleted.</p></section>",
                esc(e)
            ),
        },
        None => format!(
            "<section class=\"part\" id=\"execution\"><h2>Execution</h2><p class=\"empty\">\
             Not executed{}.</p></section>",
            match (asked, p.feasible) {
                (true, false) => ": execution was asked, but an infeasible plan is never queued",
                (false, _) => ": execution was not asked",
                (true, true) => "",
            }
        ),
    })
}

/// A small GET form on a plan's page: compare it with one of the other recent plans.
async fn compare_with(state: &AppState, id: &str) -> Result<String, PageError> {
    let (recent, _) = plan_repo::list_overview(&state.db, 30, 0).await?;
    let opts: String = recent
        .iter()
        .filter(|p| p.id != id)
        .map(|p| {
            format!(
                "<option value=\"{}\">{} · {} · {} · {}</option>",
                esc(&p.id),
                esc(short(&p.id)),
                esc(&p.robot),
                esc(p.object_name.as_deref().unwrap_or("")),
                if p.feasible { "feasible" } else { "infeasible" }
            )
        })
        .collect();
    if opts.is_empty() {
        return Ok(String::new());
    }
    Ok(format!(
        "<form class=\"compare-pick inline\" action=\"/ui/compare\" method=\"get\">\
         <input type=\"hidden\" name=\"plans\" value=\"{}\"><label>Compare with \
         <select name=\"plans\">{opts}</select></label> <button type=\"submit\">Compare\
         </button></form>",
        esc(id)
    ))
}

/// One column of a comparison: a grasp, and the plan it was made for when plans are compared.
struct Column {
    title: String,
    href: String,
    grasp: GraspRow,
    parts: GraspParts,
    plan: Option<StoredPlan>,
}

/// The ids asked for: `?plans=A,B` or `?plans=A&plans=B` (what the list's checkboxes send);
/// the same for `grasps`.
fn compared_ids(pairs: &[(String, String)], key: &str) -> Vec<String> {
    let mut ids: Vec<String> = Vec::new();
    for (k, v) in pairs.iter().filter(|(k, _)| k == key) {
        debug_assert_eq!(k, key);
        for id in v.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            if !ids.iter().any(|i| i == id) {
                ids.push(id.to_owned());
            }
        }
    }
    ids
}

fn compare_form(grasps: &str, plans: &str, problem: &str) -> String {
    format!(
        "<form class=\"compare-pick api-less\" action=\"/ui/compare\" method=\"get\">\
         {problem}<div class=\"field\"><label>plans</label><input name=\"plans\" value=\"{}\" \
         placeholder=\"plan ids, comma-separated\"></div><div class=\"field\"><label>or grasps\
         </label><input name=\"grasps\" value=\"{}\" placeholder=\"grasp ids, comma-separated\">\
         </div><button type=\"submit\">Compare</button></form>",
        esc(plans),
        esc(grasps)
    )
}

/// `/ui/compare?plans=A,B` or `?grasps=A,B`: two to four grasps or plans side by side: cost
/// terms, residuals, ellipsoids and figures (for plans also the motion and its execution).
pub async fn compare(
    State(state): State<AppState>,
    Query(pairs): Query<Vec<(String, String)>>,
) -> Page {
    let plan_ids = compared_ids(&pairs, "plans");
    let grasp_ids = compared_ids(&pairs, "grasps");
    let by_plan = !plan_ids.is_empty();
    let ids = if by_plan { &plan_ids } else { &grasp_ids };
    if ids.len() < 2 || ids.len() > MAX_COMPARED || (by_plan && !grasp_ids.is_empty()) {
        let problem = if pairs.is_empty() {
            String::new()
        } else {
            format!(
                "<p class=\"field-error\">Pick two to {MAX_COMPARED} plans, or two to \
                 {MAX_COMPARED} grasps (got {} plans and {} grasps).</p>",
                plan_ids.len(),
                grasp_ids.len()
            )
        };
        let status = if pairs.is_empty() {
            axum::http::StatusCode::OK
        } else {
            axum::http::StatusCode::UNPROCESSABLE_ENTITY
        };
        let body = format!(
            "{}<p>Or tick plans in {} and press <em>Compare selected</em>.</p>",
            compare_form(&grasp_ids.join(", "), &plan_ids.join(", "), &problem),
            link("/ui/plans", "the plan list")
        );
        return Ok((
            status,
            axum::response::Html(html::page("Compare", "/ui/plans", &body)),
        )
            .into_response());
    }
    let mut columns = Vec::with_capacity(ids.len());
    for id in ids {
        let column = if by_plan {
            let stored = match crate::service::plans::get(&state, id).await {
                Ok(s) => s,
                Err(crate::service::Error::NotFound { .. }) => {
                    return Ok(html::not_found("plan", id, "/ui/plans", "plans"));
                }
                Err(e) => return Err(e.into()),
            };
            Column {
                title: format!("Plan {}", short(id)),
                href: format!("/ui/plans/{id}"),
                grasp: stored.grasp.clone(),
                parts: grasp_parts(&stored.grasp)?,
                plan: Some(stored),
            }
        } else {
            let Some(g) = grasp_repo::get_grasp(&state.db, id).await? else {
                return Ok(html::not_found("grasp", id, "/ui/grasps", "grasps"));
            };
            Column {
                title: format!("Grasp {}", short(id)),
                href: format!("/ui/grasps/{id}"),
                parts: grasp_parts(&g)?,
                grasp: g,
                plan: None,
            }
        };
        columns.push(column);
    }
    let mut headers: Vec<String> = vec![String::new()];
    headers.extend(columns.iter().map(|c| c.title.clone()));
    let two = columns.len() == 2;
    if two {
        headers.push("difference (2 − 1)".into());
    }
    let header_refs: Vec<&str> = headers.iter().map(String::as_str).collect();

    // What was asked and what came out.
    let mut about: Vec<Vec<String>> = vec![
        row("", columns.iter().map(|c| link(&c.href, &c.title))),
        row("robot", columns.iter().map(|c| esc(&c.grasp.robot))),
        row("object", columns.iter().map(|c| esc(&c.parts.object.name))),
        row(
            "task",
            columns.iter().map(|c| {
                esc(&serde_json::to_value(&c.parts.settings.task_directions)
                    .map(|v| directions_text(&v))
                    .unwrap_or_default())
            }),
        ),
        row(
            "grasp",
            columns.iter().map(|c| {
                format!(
                    "{} {}",
                    link(&format!("/ui/grasps/{}", c.grasp.id), short(&c.grasp.id)),
                    feasible_text(c.parts.result.feasible, c.parts.result.reason.as_deref())
                )
            }),
        ),
    ];
    if by_plan {
        about.push(row(
            "plan",
            columns.iter().map(|c| {
                let p = &c.plan.as_ref().expect("a plan column").plan;
                feasible_text(p.feasible, p.reason.as_deref())
            }),
        ));
    }
    for r in &mut about {
        if two {
            r.push(String::new());
        }
    }
    let mut body = table(&header_refs, &about).replacen("<table>", "<table class=\"compare\">", 1);

    // The numbers, one row per quantity, so differences read across.
    let numbers: Vec<Vec<Section>> = columns
        .iter()
        .map(|c| grasp_numbers(&c.parts.result))
        .collect::<Result<_, _>>()?;
    for (s, (title, _)) in numbers[0].iter().enumerate() {
        let mut names: Vec<&str> = Vec::new();
        for n in &numbers {
            for (k, _) in &n[s].1 {
                if !names.contains(&k.as_str()) {
                    names.push(k);
                }
            }
        }
        let rows: Vec<Vec<String>> = names
            .iter()
            .map(|name| {
                let values: Vec<Option<&Value>> = numbers
                    .iter()
                    .map(|n| n[s].1.iter().find(|(k, _)| k == name).map(|(_, v)| v))
                    .collect();
                let mut r = row(
                    name,
                    values
                        .iter()
                        .map(|v| v.map(value_text).unwrap_or_else(|| "–".into())),
                );
                if two {
                    r.push(
                        match (
                            values[0].and_then(Value::as_f64),
                            values[1].and_then(Value::as_f64),
                        ) {
                            (Some(a), Some(b)) => num(b - a, 5),
                            _ => String::new(),
                        },
                    );
                }
                r
            })
            .collect();
        body.push_str(&format!(
            "<h2>{}</h2>{}",
            esc(title),
            table(&header_refs, &rows).replacen("<table>", "<table class=\"compare\">", 1)
        ));
    }
    if by_plan {
        let rows = vec![
            row(
                "duration (s)",
                columns.iter().map(|c| {
                    plan_of(c)
                        .trajectory
                        .as_ref()
                        .map(|t| num(t.duration, 3))
                        .unwrap_or_else(|| "–".into())
                }),
            ),
            row(
                "execution",
                columns.iter().map(|c| match &plan_of(c).execution_id {
                    Some(e) => link(&format!("/ui/executions/{e}"), short(e)),
                    None => "–".into(),
                }),
            ),
        ];
        let rows: Vec<Vec<String>> = rows
            .into_iter()
            .map(|mut r| {
                if two {
                    r.push(String::new());
                }
                r
            })
            .collect();
        body.push_str(&format!(
            "<h2>Motion</h2>{}",
            table(&header_refs, &rows).replacen("<table>", "<table class=\"compare\">", 1)
        ));
    }

    // Figures side by side.
    let cols = columns.len();
    let mut figs = format!("<h2>Grasps</h2><div class=\"side-by-side cols-{cols}\">");
    for c in &columns {
        figs.push_str(&format!(
            "<div><h3>{}</h3>{}</div>",
            link(&c.href, &c.title),
            grasp_figure(&c.grasp.id, &format!("{} at the grasp", c.title))
        ));
    }
    figs.push_str("</div>");
    if by_plan {
        figs.push_str(&format!(
            "<h2>Motions</h2><div class=\"side-by-side cols-{cols}\">"
        ));
        for c in &columns {
            let p = plan_of(c);
            figs.push_str("<div>");
            match &p.trajectory {
                Some(t) => figs.push_str(&figure(
                    &format!("/v1/trajectories/{}/plot.svg", t.id),
                    &format!("{}: joint positions over time", c.title),
                    false,
                    "",
                )),
                None => figs.push_str("<p class=\"empty\">No motion was generated.</p>"),
            }
            if let Some(e) = &p.execution_id {
                figs.push_str(&figure(
                    &format!("/v1/executions/{e}/plot.svg"),
                    &format!("{}: planned vs measured", c.title),
                    false,
                    "",
                ));
            }
            figs.push_str("</div>");
        }
        figs.push_str("</div>");
    }
    body.push_str(&figs);
    let what = if by_plan { "plans" } else { "grasps" };
    Ok(html::ok(
        &format!("Compare {} {what}", columns.len()),
        "/ui/plans",
        &body,
    ))
}

fn plan_of(c: &Column) -> &StoredPlan {
    c.plan.as_ref().expect("a plan column")
}

fn row(name: &str, cells: impl Iterator<Item = String>) -> Vec<String> {
    let mut r = vec![format!("<b>{}</b>", esc(name))];
    r.extend(cells);
    r
}

/// A batch verification (`GET /v1/verifications/{id}`): held per system and object, then every
/// combination with its plan and verdict.
pub async fn verification(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let v = match crate::service::verifications::get(&state, &id).await {
        Ok(v) => v,
        Err(crate::service::Error::NotFound { .. }) => {
            return Ok(html::not_found(
                "verification",
                &id,
                "/ui/verifications",
                "verifications",
            ));
        }
        Err(e) => return Err(e.into()),
    };
    let count_row = |c: &crate::service::verifications::VerificationCounts| {
        vec![
            esc(&c.robot),
            esc(&c.object),
            c.plans.to_string(),
            c.feasible.to_string(),
            format!("<strong>{}</strong>", c.held),
            c.unverified.to_string(),
        ]
    };
    let mut counts: Vec<Vec<String>> = v.table.iter().map(count_row).collect();
    counts.push(count_row(&v.total));
    let items: Vec<Vec<String>> = v
        .items
        .iter()
        .map(|it| {
            let i = &it.item;
            let verdict = match (&it.verification, &i.error) {
                (_, Some(e)) => format!("not planned: {}", esc(e)),
                (Some(x), None) => match x.held {
                    Some(h) => format!(
                        "{} (lift {} m, slip {} mm)",
                        if h { "held" } else { "not held" },
                        num(x.object_lift_m.unwrap_or(0.0), 3),
                        num(x.slip_m.unwrap_or(0.0) * 1e3, 1)
                    ),
                    None => format!(
                        "<span class=\"state state-{s}\">{s}</span> {}",
                        esc(x.reason.as_deref().unwrap_or("")),
                        s = esc(&x.state)
                    ),
                },
                (None, None) => match (it.feasible, &it.reason) {
                    (Some(false), Some(r)) => format!("infeasible: {}", esc(r)),
                    (None, _) => "plan deleted".into(),
                    _ => "–".into(),
                },
            };
            vec![
                esc(&i.robot),
                link(&format!("/ui/objects/{}", i.object_id), &i.object),
                i.placement
                    .map(|p| format!("({}, {})", num(p.x, 3), num(p.y, 3)))
                    .unwrap_or_else(|| "as stored".into()),
                v.tasks
                    .get(i.task)
                    .and_then(|t| serde_json::to_value(t).ok())
                    .map(|t| esc(&directions_text(&t)))
                    .unwrap_or_else(|| i.task.to_string()),
                i.plan_id
                    .as_deref()
                    .map(|p| link(&format!("/ui/plans/{p}"), short(p)))
                    .unwrap_or_else(|| "–".into()),
                verdict,
            ]
        })
        .collect();
    let body = format!(
        "<section class=\"part\"><h2>Held in physics</h2><p class=\"hint\">Every combination \
         planned with verify and run on its robot's physics worker (job {}, {}); \
         <em>unverified</em>: feasible plans whose execution is still waiting or ended without \
         a trial verdict (the motion did not arrive).</p>{}</section>\
         <section class=\"part\"><h2>Combinations</h2>{}</section>",
        link(&format!("/ui/jobs/{}", v.job_id), short(&v.job_id)),
        esc(&html::when(&v.created_at)),
        table(
            &["robot", "object", "plans", "feasible", "held", "unverified"],
            &counts
        ),
        table(
            &["robot", "object", "placement", "task", "plan", "verdict"],
            &items
        ),
    );
    Ok(html::ok(
        &format!("Verification {}", short(&id)),
        "/ui/plans",
        &body,
    ))
}
