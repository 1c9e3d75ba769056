//! The dashboard's pages: lists, detail pages with figures and numbers, action forms.

use axum::extract::{Path, Query, State};
use axum::response::Response;
use serde::Deserialize;
use uuid::Uuid;

use super::html::{
    self, PageError, esc, facts, field, figure, form, link, num, progress, short, table,
    value_facts,
};
use crate::grasp::{GraspResult, ObjectSpec, ShapeSpec};
use crate::jobs::JobRecord;
use crate::service::Context as AppState;
use crate::service::grasps::GraspSettings;
use crate::service::robots::DefaultModelState;
use crate::store::demonstrations::{self as demo_repo, DemonstrationFilter};
use crate::store::grasps as grasp_repo;
use crate::store::jobs::JobFilter;
use crate::store::robots as robot_repo;

type Page = Result<Response, PageError>;

fn job_link(j: &JobRecord) -> String {
    link(&format!("/ui/jobs/{}", j.id), &j.id.to_string()[..8])
}

/// Where a finished job's result is shown.
pub fn result_href(j: &JobRecord) -> Option<String> {
    let r = j.result.as_ref()?;
    Some(match r.resource.as_str() {
        // A study stores many demonstrations; show them all.
        "demonstrations" => format!("/ui/demonstrations?job_id={}", j.id),
        "grasps/batches" => r.href.clone(),
        other => format!("/ui/{other}/{}", r.id),
    })
}

/// What the result link says: the resource and its short id, so that six model jobs in a row
/// are six different links.
fn result_text(j: &JobRecord) -> String {
    match &j.result {
        Some(r) if r.resource == "demonstrations" => "demonstrations".into(),
        Some(r) if r.resource == "grasps/batches" => format!("grasp batch {}", short(&r.id)),
        Some(r) => format!(
            "{} {}",
            r.resource.strip_suffix('s').unwrap_or(&r.resource),
            short(&r.id)
        ),
        None => "result".into(),
    }
}

fn jobs_table(jobs: &[JobRecord]) -> String {
    let rows: Vec<Vec<String>> = jobs
        .iter()
        .map(|j| {
            vec![
                job_link(j),
                esc(&j.kind),
                progress(&j.id.to_string(), j.status.as_str(), j.progress.fraction),
                result_href(j)
                    .map(|h| link(&h, &result_text(j)))
                    .unwrap_or_default(),
                esc(&j.created_at),
            ]
        })
        .collect();
    table(&["job", "kind", "progress", "result", "created"], &rows)
}

fn shape_name(s: &ShapeSpec) -> String {
    match s {
        ShapeSpec::Sphere { radius } => format!("sphere r={}", num(*radius, 3)),
        ShapeSpec::Cylinder { radius, height } => {
            format!("cylinder r={} h={}", num(*radius, 3), num(*height, 3))
        }
        ShapeSpec::Box { size } => format!(
            "box {}×{}×{}",
            num(size[0], 3),
            num(size[1], 3),
            num(size[2], 3)
        ),
        ShapeSpec::Capsule { radius, length } => {
            format!("capsule r={} l={}", num(*radius, 3), num(*length, 3))
        }
        ShapeSpec::Mesh { triangles, .. } => format!("mesh, {} triangles", triangles.len()),
    }
}

fn synthetic_form() -> String {
    form(
        "synthetic-form",
        "Generate a synthetic study",
        "/v1/demonstrations/synthetic",
        &[
            field("subjects", "subjects", "$.subjects", "int", "1"),
            field("object positions", "positions", "$.positions", "int", "1"),
            field("trials per position", "trials", "$.trials", "int", "2"),
            field("seed", "seed", "$.seed", "int", "1"),
            field("sensor noise", "noise", "$.noise", "bool", "true"),
        ],
        "Generate",
    )
}

async fn map_form(state: &AppState, job_id: &str) -> Result<String, PageError> {
    let robots = robot_repo::list(&state.db).await?;
    let robot_opts: String = robots.iter().map(|r| format!("{}|", r.id)).collect();
    Ok(form(
        "map-form",
        "Map demonstrations onto a robot",
        "/v1/mappings",
        &[
            field(
                "robot",
                "robot",
                "$.robot",
                &format!("select:{robot_opts}"),
                "wam_ihy",
            ),
            field(
                "demonstrations of study job",
                "demonstrations.job_id",
                "$.demonstrations.job_id",
                "text",
                job_id,
            ),
            field(
                "output rate (Hz)",
                "output_rate_hz",
                "$.output_rate_hz",
                "float",
                "30",
            ),
        ],
        "Map",
    ))
}

/// The inputs of task direction `i` of a grasp or plan body (direction, transmission, goal);
/// an `optional` one starts empty and is left out of the body unless filled in.
pub(super) fn task_fields(i: usize, optional: bool) -> [String; 3] {
    let (label, direction, none) = if optional {
        (format!("task direction {} (optional)", i + 1), "", "=–|")
    } else if i == 0 {
        ("task direction (x, y, z)".to_owned(), "0, 0, 1", "")
    } else {
        (format!("task direction {}", i + 1), "0, 0, 1", "")
    };
    let default = |v: &'static str| if optional { "" } else { v };
    [
        field(
            &label,
            &format!("task_directions.{i}.direction"),
            &format!("$.task_directions[{i}].direction"),
            "vec",
            direction,
        ),
        field(
            "transmission",
            &format!("task_directions.{i}.kind"),
            &format!("$.task_directions[{i}].kind"),
            &format!("select:{none}force|velocity"),
            default("force"),
        ),
        field(
            "goal",
            &format!("task_directions.{i}.goal"),
            &format!("$.task_directions[{i}].goal"),
            &format!("select:{none}maximize|minimize"),
            default("maximize"),
        ),
    ]
}

async fn grasp_form(state: &AppState, object: Option<&str>) -> Result<String, PageError> {
    let robots = robot_repo::list(&state.db).await?;
    let robot_opts: String = robots.iter().map(|r| format!("{}|", r.id)).collect();
    let objects = grasp_repo::list_objects(&state.db).await?;
    let object_opts: String = objects
        .iter()
        .map(|o| format!("{}={}|", o.id, o.name))
        .collect();
    let selected = object
        .map(str::to_owned)
        .or_else(|| objects.first().map(|o| o.id.clone()))
        .unwrap_or_default();
    let default_robot = robots
        .iter()
        .find(|r| r.id == "wam_ihy")
        .or(robots.first())
        .map(|r| r.id.clone())
        .unwrap_or_default();
    Ok(form(
        "grasp-form",
        "Request a task-specific grasp",
        "/v1/grasps",
        &[
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
                &selected,
            ),
            task_fields(0, false).concat(),
            field("starts (1-64)", "starts", "$.starts", "int", "2"),
            field("seed", "seed", "$.seed", "int", "0"),
        ],
        "Plan the grasp",
    ))
}

pub async fn home(State(state): State<AppState>) -> Page {
    let robots = robot_repo::list(&state.db).await?;
    let objects = grasp_repo::list_objects(&state.db).await?;
    let (_, demos) = demo_repo::list(
        &state.db,
        &DemonstrationFilter {
            subject: None,
            object: None,
            synthetic: None,
            job_id: None,
            limit: 1,
            offset: 0,
        },
    )
    .await?;
    // the count alone (the overview read up to 1000 whole grasps to count them)
    let grasps = grasp_repo::count_grasps(&state.db).await?;
    let jobs = state
        .jobs
        .list(&JobFilter {
            status: None,
            kind: None,
            limit: 10,
            offset: 0,
        })
        .await?;
    let (_, mappings) = crate::store::mappings::list_mappings(&state.db, 1, 0, None, None).await?;
    let (_, models) = crate::store::models::list_models(&state.db, None, 1, 0).await?;
    let (_, trajectories) =
        crate::store::trajectories::list_trajectories(&state.db, None, 1, 0).await?;
    let (_, plans) = crate::store::plans::list(&state.db, None, 1, 0).await?;
    let cards = [
        ("/ui/plans", "plans", plans),
        ("/ui/robots", "robots", robots.len() as i64),
        ("/ui/objects", "objects", objects.len() as i64),
        ("/ui/demonstrations", "demonstrations", demos),
        ("/ui/mappings", "mappings", mappings),
        ("/ui/models", "models", models),
        ("/ui/grasps", "grasps", grasps),
        ("/ui/trajectories", "trajectories", trajectories),
        (
            "/ui/bridges",
            "connected workers",
            state.bridges.workers().len() as i64,
        ),
    ]
    .iter()
    .map(|(href, label, n)| {
        format!("<a class=\"card\" href=\"{href}\"><span class=\"count\">{n}</span> {label}</a>")
    })
    .collect::<String>();
    let body = format!(
        "{}<section class=\"cards\">{cards}</section>\
         <section class=\"forms\">{}{}{}</section>\
         <section><h2>Recent jobs</h2>{}</section>",
        status_section(&crate::service::status::status(&state).await?),
        synthetic_form(),
        map_form(&state, "").await?,
        grasp_form(&state, None).await?,
        jobs_table(&jobs),
    );
    Ok(html::ok("Overview", "/", &body))
}

/// The overview's first lines: is first-start seeding still preparing models (with a live bar
/// per robot), and which robot can plan without naming a model, since when.
fn status_section(st: &crate::service::status::StatusDto) -> String {
    use crate::service::status::SeedingState;
    let seeding = match st.seeding.state {
        SeedingState::Running => format!(
            "First-start seeding is preparing the default models: {} of {} bundled robots \
             ready. Plans for the others answer 503 until their model is trained.",
            st.seeding.trained, st.seeding.bundled
        ),
        SeedingState::Done => format!(
            "Every bundled robot ({}) has a default model.",
            st.seeding.bundled
        ),
        SeedingState::Disabled => format!(
            "First-start seeding is off (--no-seed): {} of {} bundled robots have a default \
             model; train one with POST /v1/models.",
            st.seeding.trained, st.seeding.bundled
        ),
        SeedingState::Incomplete => format!(
            "Seeding ended with {} of {} bundled robots ready: see the failed jobs below.",
            st.seeding.trained, st.seeding.bundled
        ),
    };
    let mut rows = String::new();
    for r in &st.robots {
        let model = &r.default_model;
        let cell = match model.state {
            DefaultModelState::Trained => format!(
                "<a href=\"/ui/models/{id}\">trained</a> since {at} UTC",
                id = esc(model.id.as_deref().unwrap_or("")),
                at = esc(&html::when(model.trained_at.as_deref().unwrap_or(""))),
            ),
            DefaultModelState::Seeding => {
                let step = st.seeding.pending.iter().find(|p| p.robot == r.id);
                match step {
                    Some(p) => format!(
                        "seeding: {} {}",
                        esc(&p.kind),
                        html::progress(&p.job_id, p.status.as_str(), p.fraction)
                    ),
                    None => "seeding".to_owned(),
                }
            }
            DefaultModelState::None => "none".to_owned(),
        };
        rows.push_str(&format!(
            "<tr><td><a href=\"/ui/robots/{id}\">{id}</a></td><td>{cell}</td></tr>",
            id = esc(&r.id)
        ));
    }
    format!(
        "<section class=\"status\" data-seeding=\"{state}\"><h2>Status</h2><p>{seeding} \
         {workers} bridge worker(s) connected; jobs: {queued} queued, {running} running, \
         {failed} failed.</p><table><thead><tr><th>robot</th><th>default model</th></tr>\
         </thead><tbody>{rows}</tbody></table></section>",
        state = serde_json::to_value(st.seeding.state)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default(),
        workers = st.workers,
        queued = st.jobs.queued,
        running = st.jobs.running,
        failed = st.jobs.failed,
    )
}

pub async fn robots(State(state): State<AppState>) -> Page {
    let rows = robot_repo::list(&state.db).await?;
    let mut cards = String::new();
    for r in &rows {
        let s = state.robots.system(&r.id).await?;
        // whether a plan can use this robot without naming a model yet
        let model = match crate::service::robots::default_model(&state, &r.id)
            .await?
            .state
        {
            DefaultModelState::Trained => "model trained",
            DefaultModelState::Seeding => "model being trained (first start)",
            DefaultModelState::None => "no model yet",
        };
        cards.push_str(&format!(
            "<a class=\"thumb\" href=\"/ui/robots/{id}\"><img loading=\"lazy\" \
             src=\"/v1/robots/{id}/plot.svg\" alt=\"{id} posture\" width=\"400\" height=\"300\">\
             <span><b>{id}</b> · {} joints · {} fingers{} · {model}</span></a>",
            s.model.nq(),
            s.fingers.len(),
            if r.bundled { " · bundled" } else { "" },
            id = esc(&r.id),
        ));
    }
    let body = if rows.is_empty() {
        "<p class=\"empty\">No robots registered.</p>".to_owned()
    } else {
        format!("<section class=\"thumbs\">{cards}</section>")
    };
    Ok(html::ok("Robots", "/ui/robots", &body))
}

pub async fn robot(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    if robot_repo::get(&state.db, &id).await?.is_none() {
        return Ok(html::not_found("robot", &id, "/ui/robots", "robots"));
    }
    let s = state.robots.system(&id).await?;
    let m = &s.model;
    let names = m.joint_names();
    let rows: Vec<Vec<String>> = (0..m.nq())
        .map(|k| {
            let role = if s.hand_joints.contains(&k) {
                "hand"
            } else {
                "arm"
            };
            vec![
                esc(&names[k]),
                role.into(),
                num(m.lower_limits()[k], 3),
                num(m.upper_limits()[k], 3),
                num(m.velocity_limits()[k], 2),
            ]
        })
        .collect();
    let fingers: Vec<String> = s
        .fingers
        .iter()
        .map(|f| {
            format!(
                "{} (tip {}, contact r={} m)",
                esc(&f.name),
                esc(m.frame_name(f.tip)),
                num(f.contact_radius, 3)
            )
        })
        .collect();
    let neutral: Vec<String> = m.neutral().iter().map(|v| num(*v, 3)).collect();
    let q_control = format!(
        "<label>q <input name=\"q\" size=\"40\" placeholder=\"{}\" title=\"comma-separated \
         joint values, model order\"></label>",
        esc(&neutral.join(","))
    );
    let body = format!(
        "{}{}<h2>Joints</h2>{}",
        facts(&[
            ("independent joints", m.nq().to_string()),
            ("arm joints", s.arm_joints.len().to_string()),
            ("hand joints", s.hand_joints.len().to_string()),
            ("fingers", fingers.join("<br>")),
            (
                "thumb",
                esc(&s.fingers[s.thumb.min(s.fingers.len().saturating_sub(1))].name)
            ),
            ("API", link(&format!("/v1/robots/{id}"), "JSON")),
        ]),
        figure(
            &format!("/v1/robots/{id}/plot.svg"),
            "Posture (forward kinematics)",
            true,
            &q_control
        ),
        table(&["joint", "part", "lower", "upper", "max velocity"], &rows),
    );
    Ok(html::ok(&format!("Robot {id}"), "/ui/robots", &body))
}

pub async fn objects(State(state): State<AppState>) -> Page {
    let rows = grasp_repo::list_objects(&state.db).await?;
    let rows: Vec<Vec<String>> = rows
        .iter()
        .map(|o| {
            let spec: Option<ObjectSpec> = serde_json::from_str(&o.spec).ok();
            vec![
                link(&format!("/ui/objects/{}", o.id), &o.name),
                spec.as_ref()
                    .map(|s| esc(&shape_name(&s.shape)))
                    .unwrap_or_default(),
                spec.as_ref()
                    .map(|s| s.position.map(|v| num(v, 3)).join(", "))
                    .unwrap_or_default(),
                if o.seeded { "seeded" } else { "uploaded" }.into(),
            ]
        })
        .collect();
    let body = table(&["object", "shape", "position (m)", "origin"], &rows);
    Ok(html::ok("Objects", "/ui/objects", &body))
}

pub async fn object(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(row) = grasp_repo::get_object(&state.db, &id).await? else {
        return Ok(html::not_found("object", &id, "/ui/objects", "objects"));
    };
    let spec: ObjectSpec = serde_json::from_str(&row.spec).map_err(PageError::internal)?;
    let pretty = serde_json::to_string_pretty(&spec).map_err(PageError::internal)?;
    let body = format!(
        "{}{}<h2>Specification</h2><pre>{}</pre>",
        facts(&[
            ("shape", esc(&shape_name(&spec.shape))),
            ("position (m)", spec.position.map(|v| num(v, 3)).join(", ")),
            (
                "orientation [w,x,y,z]",
                spec.orientation.map(|v| num(v, 3)).join(", ")
            ),
            ("API", link(&format!("/v1/objects/{id}"), "JSON")),
        ]),
        grasp_form(&state, Some(&row.id)).await?,
        esc(&pretty)
    );
    Ok(html::ok(
        &format!("Object {}", row.name),
        "/ui/objects",
        &body,
    ))
}

#[derive(Debug, Deserialize)]
pub struct DemoListQuery {
    job_id: Option<Uuid>,
    offset: Option<u32>,
}

pub async fn demonstrations(State(state): State<AppState>, Query(q): Query<DemoListQuery>) -> Page {
    let limit = 50;
    let offset = q.offset.unwrap_or(0);
    let (rows, total) = demo_repo::list(
        &state.db,
        &DemonstrationFilter {
            subject: None,
            object: None,
            synthetic: None,
            job_id: q.job_id.map(|j| j.to_string()),
            limit,
            offset,
        },
    )
    .await?;
    let mut trs = Vec::with_capacity(rows.len());
    for r in &rows {
        let summary = r.summary()?;
        trs.push(vec![
            link(
                &format!("/ui/demonstrations/{}", r.id),
                &r.id[..8.min(r.id.len())],
            ),
            esc(&r.subject_id),
            esc(&r.object_name),
            esc(&r.task),
            r.position_index.to_string(),
            r.trial.to_string(),
            r.frame_count.to_string(),
            num(summary.duration_s, 2),
            if r.synthetic { "synthetic" } else { "recorded" }.into(),
        ]);
    }
    let filter = q.job_id.map(|j| format!("&job_id={j}")).unwrap_or_default();
    let pager = html::pager(offset, limit, rows.len(), total, &filter);
    let heading = match q.job_id {
        Some(j) => format!(
            "<p>From job {}</p>",
            link(&format!("/ui/jobs/{j}"), &j.to_string())
        ),
        None => String::new(),
    };
    let job = q.job_id.map(|j| j.to_string()).unwrap_or_default();
    let body = format!(
        "{heading}{}{pager}<section class=\"forms\">{}{}</section>",
        table(
            &[
                "id",
                "subject",
                "object",
                "task",
                "position",
                "trial",
                "frames",
                "duration (s)",
                "source"
            ],
            &trs
        ),
        map_form(&state, &job).await?,
        synthetic_form(),
    );
    Ok(html::ok("Demonstrations", "/ui/demonstrations", &body))
}

pub async fn demonstration(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(r) = demo_repo::get(&state.db, &id).await? else {
        return Ok(html::not_found(
            "demonstration",
            &id,
            "/ui/demonstrations",
            "demonstrations",
        ));
    };
    let s = r.summary()?;
    let subject = r.subject()?;
    let body = format!(
        "{}{}",
        facts(&[
            (
                "subject",
                format!(
                    "{} (stature {} m, hand {} × {} m)",
                    esc(&subject.id),
                    num(subject.stature_m, 2),
                    num(subject.hand_length_m, 3),
                    num(subject.hand_breadth_m, 3)
                )
            ),
            ("object", esc(&r.object_name)),
            ("task", esc(&r.task)),
            (
                "position / trial",
                format!("{} / {}", r.position_index, r.trial)
            ),
            (
                "frames",
                format!("{} at {} Hz", s.frames, num(s.rate_hz, 1))
            ),
            ("duration", format!("{} s", num(s.duration_s, 3))),
            (
                "raw samples",
                match s.source {
                    crate::human::Source::TrackerGlove => format!(
                        "tracker {} ({} Hz), glove {} ({} Hz)",
                        s.tracker_samples,
                        num(s.tracker_rate_hz, 1),
                        s.glove_samples,
                        num(s.glove_rate_hz, 1)
                    ),
                    crate::human::Source::Keypoints => format!(
                        "hand keypoints {} ({} Hz){}",
                        s.tracker_samples,
                        num(s.tracker_rate_hz, 1),
                        if s.arm {
                            ", with elbow and shoulder"
                        } else {
                            ", the hand alone: maps onto a hand on a fixed base only"
                        }
                    ),
                }
            ),
            (
                "source",
                format!(
                    "{} ({})",
                    if r.synthetic { "synthetic" } else { "recorded" },
                    match s.source {
                        crate::human::Source::TrackerGlove => "tracker + glove",
                        crate::human::Source::Keypoints => "hand keypoints",
                    }
                )
            ),
            (
                "API",
                link(
                    &format!("/v1/demonstrations/{id}/frames?every=10"),
                    "frames (JSON)"
                )
            ),
        ]),
        figure(
            &format!("/v1/demonstrations/{id}/plot.svg"),
            "Wrist speed and grip aperture",
            false,
            ""
        ),
    );
    Ok(html::ok(
        &format!("Demonstration {}", &id[..8.min(id.len())]),
        "/ui/demonstrations",
        &body,
    ))
}

pub async fn grasps(State(state): State<AppState>) -> Page {
    let rows = grasp_repo::list_grasps(&state.db, 200).await?;
    let trs: Vec<Vec<String>> = rows
        .iter()
        .map(|g| {
            let object: Option<ObjectSpec> = serde_json::from_str(&g.object).ok();
            let result = GraspResult::from_stored(&g.result).ok();
            vec![
                format!(
                    "<input type=\"checkbox\" name=\"grasps\" value=\"{}\" \
                     aria-label=\"compare grasp\">",
                    esc(&g.id)
                ),
                link(&format!("/ui/grasps/{}", g.id), &g.id[..8.min(g.id.len())]),
                esc(&g.robot),
                object.map(|o| esc(&o.name)).unwrap_or_default(),
                if g.feasible { "feasible" } else { "infeasible" }.into(),
                result.map(|r| num(r.terms.cost, 4)).unwrap_or_default(),
                esc(&g.created_at),
            ]
        })
        .collect();
    // Ticked grasps open side by side (`/ui/compare?grasps=A&grasps=B`).
    let body = format!(
        "<form class=\"compare-pick\" action=\"/ui/compare\" method=\"get\">{}{}</form>{}",
        table(
            &["", "grasp", "robot", "object", "result", "cost", "created"],
            &trs
        ),
        if trs.is_empty() {
            ""
        } else {
            "<p><button type=\"submit\">Compare selected</button></p>"
        },
        grasp_form(&state, None).await?
    );
    Ok(html::ok("Grasps", "/ui/grasps", &body))
}

/// The fields of JSON objects, in order, as one facts list.
fn object_facts(objects: &[&serde_json::Value]) -> String {
    let items: Vec<(&str, serde_json::Value)> = objects
        .iter()
        .filter_map(|v| v.as_object())
        .flatten()
        .map(|(k, v)| (k.as_str(), readable_grasp_value(k, v)))
        .collect();
    value_facts(items.iter().map(|(k, v)| (*k, v)))
}

/// A grasp quantity as a reader should see it: the API keeps JSON finite with sentinels, which
/// the pages say in words: `max_spread_violation` is -10 when the hand has no spread-order pair
/// (eq. 28 has no rows), and an ellipsoid semi-axis is capped at 1e6 where the hand cannot move
/// or resist along that axis at all.
pub(super) fn readable_grasp_value(key: &str, v: &serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    if key.ends_with("max_spread_violation") && v.as_f64().is_some_and(|x| x <= -10.0) {
        return Value::String("none: the hand has no spread-order pair".into());
    }
    if (key.contains("semi-axes") || key.contains("semi_axes"))
        && let Value::Array(a) = v
    {
        return Value::Array(
            a.iter()
                .map(|x| match x.as_f64() {
                    Some(x) if x >= 1e6 => Value::String("unbounded".into()),
                    _ => x.clone(),
                })
                .collect(),
        );
    }
    v.clone()
}

pub async fn grasp(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(g) = grasp_repo::get_grasp(&state.db, &id).await? else {
        return Ok(html::not_found("grasp", &id, "/ui/grasps", "grasps"));
    };
    let object: ObjectSpec = serde_json::from_str(&g.object).map_err(PageError::internal)?;
    let settings: GraspSettings = serde_json::from_str(&g.request).map_err(PageError::internal)?;
    let result = GraspResult::from_stored(&g.result).map_err(PageError::internal)?;
    let terms = serde_json::to_value(&result.terms).map_err(PageError::internal)?;
    let residuals = serde_json::to_value(&result.residuals).map_err(PageError::internal)?;
    let term_facts = object_facts(&[&terms, &residuals]);
    // The exact check decides `feasible`: penetrations and separations on the URDF shapes, the
    // pads' distance and angle, the contacts' opposition.
    let exact = serde_json::to_value(&result.exact).map_err(PageError::internal)?;
    let exact_facts = object_facts(&[&exact]);
    let joints: Vec<Vec<String>> = result
        .q_arm
        .iter()
        .map(|j| vec![esc(&j.name), "arm".into(), num(j.value, 4)])
        .chain(
            result
                .q_hand
                .iter()
                .map(|j| vec![esc(&j.name), "hand".into(), num(j.value, 4)]),
        )
        .collect();
    let contacts: Vec<Vec<String>> = result
        .contacts
        .iter()
        .map(|c| {
            vec![
                esc(&c.finger),
                c.point.map(|v| num(v, 4)).join(", "),
                c.normal.map(|v| num(v, 3)).join(", "),
                num(c.surface_distance * 1000.0, 2),
                num(c.pad_angle_deg, 1),
            ]
        })
        .collect();
    let dirs: Vec<String> = settings
        .task_directions
        .iter()
        .map(|t| {
            format!(
                "[{}] {:?} {:?}",
                t.direction.map(|v| num(v, 2)).join(", "),
                t.kind,
                t.goal
            )
            .to_lowercase()
        })
        .collect();
    let ellipsoid = "<label>ellipsoid <select name=\"ellipsoid\"><option value=\"\">auto\
                     </option><option>velocity</option><option>force</option></select></label>";
    let body = format!(
        "{}{}<h2>Cost terms and residuals</h2>{}<h2>Exact check</h2>{}<h2>Joint values</h2>{}\
         <h2>Contacts</h2>{}",
        facts(&[
            ("robot", esc(&g.robot)),
            (
                "object",
                match &g.object_id {
                    Some(o) => link(&format!("/ui/objects/{o}"), &object.name),
                    None => esc(&object.name),
                }
            ),
            (
                "feasible",
                if result.feasible {
                    "yes".to_owned()
                } else {
                    format!("no: {}", esc(result.reason.as_deref().unwrap_or("")))
                }
            ),
            (
                "firm",
                match not_firm(&result) {
                    Some(why) => format!("no: {why}"),
                    None if result.feasible => "yes".to_owned(),
                    None => "—".to_owned(),
                },
            ),
            ("task directions", esc(&dirs.join("; "))),
            (
                "fingers on the object",
                if result.idle_fingers.is_empty() {
                    "all".to_owned()
                } else {
                    format!(
                        "{} ({} kept off it)",
                        result.contacts.len(),
                        esc(&result.idle_fingers.join(", "))
                    )
                }
            ),
            (
                "starts",
                format!(
                    "{} run, {} feasible",
                    result.starts_used, result.starts_feasible
                )
            ),
            ("time", format!("{} s", num(result.time_s, 3))),
            ("API", link(&format!("/v1/grasps/{id}"), "JSON")),
        ]),
        figure(
            &format!("/v1/grasps/{id}/plot.svg"),
            "Arm and hand at the grasp, object, contacts, task direction and ellipsoid",
            true,
            ellipsoid
        ),
        term_facts,
        exact_facts,
        table(&["joint", "part", "value (rad)"], &joints),
        table(
            &[
                "finger",
                "point (m)",
                "normal",
                "surface distance (mm)",
                "pad angle (°)"
            ],
            &contacts
        ),
    );
    Ok(html::ok(
        &format!("Grasp {}", &id[..8.min(id.len())]),
        "/ui/grasps",
        &body,
    ))
}

pub async fn jobs(State(state): State<AppState>) -> Page {
    let jobs = state
        .jobs
        .list(&JobFilter {
            status: None,
            kind: None,
            limit: 100,
            offset: 0,
        })
        .await?;
    Ok(html::ok("Jobs", "/ui/jobs", &jobs_table(&jobs)))
}

pub async fn job(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Ok(uuid) = id.parse::<Uuid>() else {
        return Ok(html::not_found("job", &id, "/ui/jobs", "jobs"));
    };
    let j = match state.jobs.get(uuid).await {
        Ok(j) => j,
        Err(crate::jobs::RunnerError::NotFound(_)) => {
            return Ok(html::not_found("job", &id, "/ui/jobs", "jobs"));
        }
        Err(e) => return Err(e.into()),
    };
    let body = format!(
        "{}{}",
        facts(&[
            ("kind", esc(&j.kind)),
            (
                "progress",
                progress(&j.id.to_string(), j.status.as_str(), j.progress.fraction)
            ),
            ("message", esc(j.progress.message.as_deref().unwrap_or(""))),
            (
                "error",
                j.error
                    .as_ref()
                    .map(|e| format!("{}: {}", esc(&e.reason), esc(&e.message)))
                    .unwrap_or_default()
            ),
            (
                "result",
                result_href(&j)
                    .map(|h| link(&h, "open"))
                    .unwrap_or_default()
            ),
            ("created", esc(&j.created_at)),
            ("finished", esc(j.finished_at.as_deref().unwrap_or(""))),
            ("API", link(&format!("/v1/jobs/{id}"), "JSON")),
        ]),
        "",
    );
    Ok(html::ok(&format!("Job {}", &id[..8]), "/ui/jobs", &body))
}

/// Why a feasible grasp is not firm (`exact.firm` false: its contact normals cannot balance),
/// for the pages: the closing hand is likely to squeeze the object out (none of those held in
/// the physics surveys). `None` for a firm or an infeasible grasp.
pub(super) fn not_firm(r: &GraspResult) -> Option<String> {
    (r.feasible && !r.exact.firm).then(|| {
        format!(
            "the contact normals cannot balance (normal balance {} &gt; 0.12), so the closing \
             hand is likely to squeeze the object out",
            num(r.exact.normal_balance, 2)
        )
    })
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::readable_grasp_value;

    /// The sentinels the grasp optimiser writes (`optimizer.rs`: the spread violation floored at
    /// -10, a semi-axis capped at 1e6) read as words; every other value, including a real
    /// violation and finite semi-axes, is left as it is.
    #[test]
    fn grasp_sentinels_read_as_words_and_nothing_else_changes() {
        assert_eq!(
            readable_grasp_value("max_spread_violation", &json!(-10.0)),
            json!("none: the hand has no spread-order pair")
        );
        assert_eq!(
            readable_grasp_value("max_spread_violation", &json!(-0.02)),
            json!(-0.02)
        );
        assert_eq!(
            readable_grasp_value("hand force semi-axes", &json!([10.6, 69.1, 1e6])),
            json!([10.6, 69.1, "unbounded"])
        );
        assert_eq!(
            readable_grasp_value("arm force semi-axes", &json!([2.1, 2.8, 3.2])),
            json!([2.1, 2.8, 3.2])
        );
        assert_eq!(readable_grasp_value("cost", &json!(-10.0)), json!(-10.0));
    }
}
