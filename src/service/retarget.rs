//! Online retargeting of hand keypoint streams (issue 22): the session behind
//! `GET /v1/robots/{id}/retarget` (a WebSocket). The numerics are [`crate::mapping::retarget`];
//! this module resolves the robot, reads the wire messages and measures each frame's latency.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Point3, Quaternion, UnitQuaternion};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::{Context, Error};
use crate::human::keypoints::{KEYPOINT_COUNT, KEYPOINT_NAMES, KeypointFrame};
use crate::human::{Handedness, HumanError};
use crate::kinematics::System;
use crate::mapping::{
    MappingModel, RetargetError, RetargetOptions, RetargetStep, Retargeter, SolverOptions, Weights,
};

/// Stream settings, as query parameters of the upgrade request.
#[derive(Debug, Clone, Default, Deserialize, Serialize, ToSchema, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct RetargetQuery {
    /// `right` (default) or `left`: which hand the keypoints are.
    #[serde(default)]
    pub handedness: Handedness,
    /// First-order low-pass on the output joint values, Hz (default: off).
    #[param(minimum = 0.01, maximum = 1000.0)]
    pub cutoff_hz: Option<f64>,
    /// Output joint speed bound as a multiple of each joint's URDF velocity limit (default:
    /// off; the solver's own per-frame step box of 2 × the limit still applies).
    #[param(minimum = 0.01, maximum = 10.0)]
    pub speed_scale: Option<f64>,
    /// Fingertips relative to the wrist scaled by this (default 1: unscaled).
    #[param(minimum = 0.1, maximum = 10.0)]
    pub hand_scale: Option<f64>,
    /// Arm systems: the subject's stature, m, for the arm's transport scale (default 1.72).
    #[param(minimum = 1.0, maximum = 2.3)]
    pub stature_m: Option<f64>,
    /// Arm systems: where the first frame's wrist lands, robot base frame, `x,y,z` in metres
    /// (default: the scaled human reach above the robot's support).
    #[param(
        pattern = r"^-?[0-9]{1,2}(\.[0-9]{1,9})?,-?[0-9]{1,2}(\.[0-9]{1,9})?,-?[0-9]{1,2}(\.[0-9]{1,9})?$"
    )]
    pub placement: Option<String>,
    /// Weight of the fingertip orientation term (eq. 2-3) against the positions (default
    /// 1e-4, the mappings' tie-break). Keypoints give a fingertip's roll only as an estimate;
    /// 0 follows the fingertip positions alone (on reachable targets: median 0.02 mm instead of
    /// 0.4 mm).
    #[param(minimum = 0.0, maximum = 1.0)]
    pub orientation_weight: Option<f64>,
    /// Teleoperation: forward every answer's `q` as a setpoint to a connected bridge worker of
    /// this robot with the `streaming` capability, as one streaming execution that ends when
    /// the stream does (default false). 409 before the upgrade when no such worker is idle.
    pub forward: Option<bool>,
    /// With `forward`: this worker only (default: any idle one).
    pub worker: Option<String>,
    /// With `forward`: the worker brakes to a stop when no setpoint arrived for this long, s
    /// (default 0.2).
    #[param(minimum = 0.01, maximum = 10.0)]
    pub hold_after_s: Option<f64>,
}

impl RetargetQuery {
    /// The numerics' options; every bad value named by its query parameter.
    pub fn options(&self) -> Result<RetargetOptions, Error> {
        let mut issues = Vec::new();
        let mut range = |field: &str, v: Option<f64>, lo: f64, hi: f64| {
            if let Some(x) = v
                && !(x.is_finite() && (lo..=hi).contains(&x))
            {
                issues.push(super::Invalid::new(
                    format!("$.{field}"),
                    format!("must be a number in [{lo}, {hi}], got {x}"),
                ));
            }
        };
        range("cutoff_hz", self.cutoff_hz, 0.01, 1000.0);
        range("speed_scale", self.speed_scale, 0.01, 10.0);
        range("hand_scale", self.hand_scale, 0.1, 10.0);
        range("stature_m", self.stature_m, 1.0, 2.3);
        range("orientation_weight", self.orientation_weight, 0.0, 1.0);
        range("hold_after_s", self.hold_after_s, 0.01, 10.0);
        if self.forward != Some(true) {
            for (field, given) in [
                ("worker", self.worker.is_some()),
                ("hold_after_s", self.hold_after_s.is_some()),
            ] {
                if given {
                    issues.push(super::Invalid::new(
                        format!("$.{field}"),
                        "only applies with forward=true (teleoperation)",
                    ));
                }
            }
        }
        if let Some(w) = &self.worker
            && let Err(e) = crate::bridge::WorkerName::parse(w)
        {
            issues.push(super::Invalid::new("$.worker", e.to_string()));
        }
        let placement = match &self.placement {
            None => None,
            Some(text) => {
                let v: Vec<Option<f64>> = text
                    .split(',')
                    .map(|s| s.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
                    .collect();
                match v.as_slice() {
                    [Some(x), Some(y), Some(z)] => Some(Point3::new(*x, *y, *z)),
                    _ => {
                        issues.push(super::Invalid::new(
                            "$.placement",
                            format!("must be three finite numbers `x,y,z` in metres, got `{text}`"),
                        ));
                        None
                    }
                }
            }
        };
        if !issues.is_empty() {
            return Err(Error::Invalid(issues));
        }
        let d = RetargetOptions::default();
        Ok(RetargetOptions {
            handedness: self.handedness,
            cutoff_hz: self.cutoff_hz,
            speed_scale: self.speed_scale,
            hand_scale: self.hand_scale.unwrap_or(d.hand_scale),
            placement,
            stature_m: self.stature_m.unwrap_or(d.stature_m),
            weights: Weights {
                orientation: self.orientation_weight.unwrap_or(d.weights.orientation),
                ..d.weights
            },
            solver: SolverOptions::default(),
        })
    }
}

/// One keypoint frame, as a client sends it (a WebSocket text message).
#[derive(Debug, Clone, Deserialize, Serialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct KeypointFrameMsg {
    /// Client's frame number, echoed in the answer (default: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// Frame time, s, strictly increasing along the stream.
    pub t: f64,
    /// The 21 hand keypoints `[x, y, z]` (m) in the MANO / MediaPipe order: wrist; thumb CMC,
    /// MCP, IP, tip; index, middle, ring, little MCP, PIP, DIP, tip.
    #[schema(min_items = 21, max_items = 21)]
    pub points: Vec<Vec<f64>>,
    /// The wrist frame `[w, x, y, z]` (`x` towards the middle-finger MCP, `z` the palmar
    /// normal), when the tracking gives it; otherwise it is derived from the palm keypoints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrist_orientation: Option<Vec<f64>>,
    /// Elbow and shoulder centres `[x, y, z]`: required by arm systems, unused by a hand on a
    /// fixed base.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elbow: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shoulder: Option<Vec<f64>>,
}

impl KeypointFrameMsg {
    /// The wire form of a frame (what a client sends; [`parse_frame`] reads it back).
    pub fn new(frame: &KeypointFrame, seq: Option<u64>) -> Self {
        let xyz = |p: &Point3<f64>| vec![p.x, p.y, p.z];
        Self {
            seq,
            t: frame.t,
            points: frame.points.iter().map(xyz).collect(),
            wrist_orientation: frame.wrist_orientation.map(|q| vec![q.w, q.i, q.j, q.k]),
            elbow: frame.elbow.as_ref().map(xyz),
            shoulder: frame.shoulder.as_ref().map(xyz),
        }
    }
}

/// The first message of a session: what the answers will hold.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RetargetReady {
    /// Always `ready`.
    #[serde(rename = "type")]
    pub kind: String,
    pub robot: String,
    /// Order of `q` in every answer (the independent joints).
    pub joint_names: Vec<String>,
    /// Robot fingers, order of `fingertip_error_m`.
    pub fingers: Vec<String>,
    /// A hand on a fixed base: frames need no elbow or shoulder.
    pub hand_only: bool,
    /// The keypoint order frames must follow.
    pub keypoints: Vec<String>,
    /// With `forward=true`: the streaming execution the answers' `q` drive
    /// (`GET /v1/executions/{id}`) and the worker running it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub execution_id: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub worker: Option<String>,
    /// With `forward=true`: the answers start at the robot's measured posture (the worker's
    /// latest heartbeat) and move from there to the retargeted one within `speed_scale` and
    /// `cutoff_hz` (without either, the second answer is already the retargeted posture).
    #[serde(default)]
    pub starts_from_robot: bool,
}

/// With `forward=true`: what became of an answer's `q` on the robot.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ForwardStatus {
    /// `sent` (queued to the worker), `skipped` (the worker reads slower than the stream: this
    /// setpoint was dropped, it follows the next) or `closed` (the execution is over:
    /// cancelled, or the worker left; frames are still retargeted, nothing is forwarded).
    pub setpoint: crate::bridge::StreamSend,
    /// The robot's latest measured joint values (worker feedback, `joint_names` order), rad or m.
    pub measured: Option<Vec<f64>>,
    /// Largest joint deviation of the robot from its latest setpoint at that feedback, rad.
    pub tracking_error: Option<f64>,
}

/// The answer to one frame.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RetargetJoints {
    /// Always `joints`.
    #[serde(rename = "type")]
    pub kind: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// Accepted frames before this one.
    pub index: usize,
    pub t: f64,
    /// Joint values, rad or m, in `joint_names` order (after the low-pass and speed bound).
    pub q: Vec<f64>,
    /// Distance of each robot fingertip from its goal at `q`, m.
    pub fingertip_error_m: Vec<f64>,
    /// Elbow swivel difference human vs robot, rad (arm systems; null for a hand).
    pub swivel_difference: Option<f64>,
    pub converged: bool,
    pub iterations: usize,
    /// Whether the low-pass or the speed bound moved `q` off the solution.
    pub filtered: bool,
    /// Time from the frame's arrival to this answer, µs (parse, solve, filter, forward; not
    /// the few microseconds of writing the answer itself).
    pub latency_us: f64,
    /// With `forward=true`: the setpoint's fate and the robot's measured state.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub forward: Option<ForwardStatus>,
}

/// A refused frame: the stream stays open and unchanged.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RetargetFrameError {
    /// Always `error`.
    #[serde(rename = "type")]
    pub kind: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seq: Option<u64>,
    /// HTTP-like status: 422 for a frame that does not validate, 400 for a message that is not
    /// a frame.
    pub status: u16,
    pub title: String,
    pub detail: String,
    /// JSONPath of the offending field (`$.points[8]`), when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

impl RetargetFrameError {
    pub fn new(seq: Option<u64>, status: u16, detail: String, field: Option<String>) -> Self {
        Self {
            kind: "error".into(),
            seq,
            status,
            title: if status == 422 {
                "Invalid frame".into()
            } else {
                "Bad message".into()
            },
            detail,
            field,
        }
    }
}

/// An open stream.
pub struct Session {
    robot: String,
    system: Arc<System>,
    retargeter: Option<Retargeter>,
    /// Teleoperation: the streaming execution the answers drive.
    stream: Option<crate::bridge::StreamHandle>,
    starts_from_robot: bool,
}

/// Opens a stream onto robot `id` (404 unknown robot, 422 bad options).
pub async fn open(ctx: &Context, id: &str, query: &RetargetQuery) -> Result<Session, Error> {
    let options = query.options()?;
    let system = super::robots::system(ctx, id).await?;
    let mm = MappingModel::from_system(&system).map_err(|e| Error::invalid("$", e.to_string()))?;
    let retargeter = tokio::task::spawn_blocking(move || Retargeter::new(mm, options))
        .await
        .map_err(|e| Error::internal(anyhow::anyhow!("retargeter task failed: {e}")))?
        .map_err(|e| match e {
            RetargetError::InvalidOption { field, value } => {
                Error::invalid(format!("$.{field}"), format!("invalid value {value}"))
            }
            e => Error::invalid("$.placement", e.to_string()),
        })?;
    Ok(Session {
        robot: id.to_string(),
        system,
        retargeter: Some(retargeter),
        stream: None,
        starts_from_robot: false,
    })
}

impl Session {
    pub fn ready(&self) -> RetargetReady {
        let r = self
            .retargeter
            .as_ref()
            .expect("a session holds its retargeter");
        RetargetReady {
            kind: "ready".into(),
            robot: self.robot.clone(),
            joint_names: r.joint_names().to_vec(),
            fingers: self.system.fingers.iter().map(|f| f.name.clone()).collect(),
            hand_only: !r.needs_arm(),
            keypoints: KEYPOINT_NAMES.iter().map(|s| s.to_string()).collect(),
            execution_id: self.stream.as_ref().map(|s| s.id().to_owned()),
            worker: self.stream.as_ref().map(|s| s.worker().to_owned()),
            starts_from_robot: self.starts_from_robot,
        }
    }

    /// With `forward=true` in `query`: starts the streaming execution the answers will drive
    /// (409 when no idle worker of the robot can take it). Called once the request is known
    /// to be a WebSocket upgrade, so that a refused upgrade starts nothing.
    pub async fn forward(&mut self, ctx: &Context, query: &RetargetQuery) -> Result<(), Error> {
        if query.forward != Some(true) {
            return Ok(());
        }
        let worker = query
            .worker
            .as_deref()
            .map(crate::bridge::WorkerName::parse)
            .transpose()?;
        let payload = crate::bridge::ExecutionPayload::Stream {
            source: "retarget".into(),
            joint_names: self.system.model.joint_names().to_vec(),
            hold_after_s: query
                .hold_after_s
                .unwrap_or(crate::store::payload::DEFAULT_HOLD_AFTER),
        };
        let stream = ctx
            .bridges
            .open_stream(&self.robot, worker.as_ref(), payload)
            .await
            .map_err(|e| match e {
                crate::bridge::BridgeError::InvalidPayload(issues) => Error::Invalid(
                    issues
                        .into_iter()
                        .map(|i| super::Invalid::new(format!("$.{}", i.at), i.message))
                        .collect(),
                ),
                e => e.into(),
            })?;
        // The answers start where the robot stands and lead it to the operator's posture at
        // the stream's speed bound, instead of sending it a far first setpoint.
        if let (Some(q), Some(r)) = (stream.measured(), self.retargeter.as_mut()) {
            self.starts_from_robot = r.start_from(&q);
        }
        self.stream = Some(stream);
        Ok(())
    }

    /// Ends the streaming execution, if any (the worker stops; the execution succeeds).
    pub async fn close(&mut self) {
        if let Some(s) = self.stream.take() {
            s.end().await;
        }
    }

    /// Answers one text message (a frame), `arrived` when it was read off the socket. The solve
    /// runs on the blocking pool (the first frame's multi-start takes milliseconds).
    pub async fn message(&mut self, text: &str, arrived: Instant) -> String {
        let mut de = serde_json::Deserializer::from_str(text);
        let msg: KeypointFrameMsg = match serde_path_to_error::deserialize(&mut de) {
            Ok(m) => m,
            Err(e) => {
                let (path, detail) = crate::wire::locate(&e);
                let e = RetargetFrameError::new(None, 400, detail, Some(path));
                return serde_json::to_string(&e).expect("serialisable");
            }
        };
        let seq = msg.seq;
        let frame = match parse_frame(&msg) {
            Ok(f) => f,
            Err((field, detail)) => {
                let e = RetargetFrameError::new(seq, 422, detail, Some(field));
                return serde_json::to_string(&e).expect("serialisable");
            }
        };
        let mut r = self.retargeter.take().expect("one message at a time");
        let (r, result) = match tokio::task::spawn_blocking(move || {
            let res = r.push(&frame);
            let q = r.output().to_vec();
            (r, res.map(|s| (s, q)))
        })
        .await
        {
            Ok(v) => v,
            Err(e) => {
                // The solver panicked: the session cannot go on from a known state.
                tracing::error!(error = %e, "retargeting task failed");
                let e = RetargetFrameError::new(seq, 500, "internal error".into(), None);
                return serde_json::to_string(&e).expect("serialisable");
            }
        };
        self.retargeter = Some(r);
        match result {
            Ok((step, q)) => {
                let forward = self.stream.as_mut().map(|s| {
                    let setpoint = s.send(frame.t, &q);
                    let fb = s.feedback();
                    ForwardStatus {
                        setpoint,
                        measured: fb.as_ref().map(|f| f.positions.clone()),
                        tracking_error: fb.map(|f| f.tracking_error),
                    }
                });
                answer(seq, &frame, step, q, arrived, forward)
            }
            Err(e) => {
                let field = e.field();
                let field = (!field.is_empty()).then(|| format!("$.{field}"));
                let e = RetargetFrameError::new(seq, 422, e.to_string(), field);
                serde_json::to_string(&e).expect("serialisable")
            }
        }
    }

    /// Whether the solver state is intact (false only after a panic in the solver).
    pub fn alive(&self) -> bool {
        self.retargeter.is_some()
    }
}

fn answer(
    seq: Option<u64>,
    frame: &KeypointFrame,
    step: RetargetStep,
    q: Vec<f64>,
    arrived: Instant,
    forward: Option<ForwardStatus>,
) -> String {
    let m = &step.metrics;
    let out = RetargetJoints {
        kind: "joints".into(),
        seq,
        index: step.index,
        t: frame.t,
        q,
        fingertip_error_m: step.output_error[..m.fingers].to_vec(),
        swivel_difference: m
            .swivel_difference
            .is_finite()
            .then_some(m.swivel_difference),
        converged: m.converged,
        iterations: m.iterations,
        filtered: step.filtered,
        latency_us: arrived.elapsed().as_secs_f64() * 1e6,
        forward,
    };
    serde_json::to_string(&out).expect("serialisable")
}

/// A wire frame to the numerics' frame; errors are `(JSONPath, message)`.
pub fn parse_frame(msg: &KeypointFrameMsg) -> Result<KeypointFrame, (String, String)> {
    if msg.points.len() != KEYPOINT_COUNT {
        return Err((
            "$.points".into(),
            format!(
                "expected {KEYPOINT_COUNT} keypoints (MANO / MediaPipe order), got {}",
                msg.points.len()
            ),
        ));
    }
    let point = |v: &[f64], path: String| -> Result<Point3<f64>, (String, String)> {
        match v {
            [x, y, z] => Ok(Point3::new(*x, *y, *z)),
            _ => Err((path, format!("expected [x, y, z], got {} values", v.len()))),
        }
    };
    let mut points = [Point3::origin(); KEYPOINT_COUNT];
    for (k, p) in msg.points.iter().enumerate() {
        points[k] = point(p, format!("$.points[{k}]"))?;
    }
    let wrist_orientation = match &msg.wrist_orientation {
        None => None,
        Some(q) => match q.as_slice() {
            [w, x, y, z] => {
                let quat = Quaternion::new(*w, *x, *y, *z);
                let n = quat.norm();
                if !(n.is_finite() && n > crate::human::demo::MIN_QUATERNION_NORM) {
                    return Err((
                        "$.wrist_orientation".into(),
                        format!("quaternion norm {n} cannot be normalised"),
                    ));
                }
                Some(UnitQuaternion::from_quaternion(quat))
            }
            _ => {
                return Err((
                    "$.wrist_orientation".into(),
                    format!("expected [w, x, y, z], got {} values", q.len()),
                ));
            }
        },
    };
    let elbow = msg
        .elbow
        .as_deref()
        .map(|v| point(v, "$.elbow".into()))
        .transpose()?;
    let shoulder = msg
        .shoulder
        .as_deref()
        .map(|v| point(v, "$.shoulder".into()))
        .transpose()?;
    let frame = KeypointFrame {
        t: msg.t,
        points,
        wrist_orientation,
        elbow,
        shoulder,
    };
    crate::human::keypoints::validate(&frame, "frame", 0)
        .map_err(|e| (frame_path(&e), frame_detail(&e)))?;
    Ok(frame)
}

/// The message of a frame's validation error, without the stream and sample a recording's
/// error names (the frame is the whole document here).
fn frame_detail(e: &HumanError) -> String {
    match e {
        HumanError::NonFinite { field, value, .. } => format!("`{field}` is not finite ({value})"),
        HumanError::PositionOutOfRange {
            field,
            distance,
            limit,
            ..
        } => format!("`{field}` is {distance:.3} m from the origin (limit {limit} m)"),
        e => e.to_string(),
    }
}

/// `$.points[8]` for a keypoint error (its field names the keypoint), `$.elbow`, `$.t`.
fn frame_path(e: &HumanError) -> String {
    let field = e.field().unwrap_or("");
    let base = field.split(' ').next().unwrap_or(field);
    // `points[8] (index_tip)[1]` -> `points[8]`; `elbow[2]` -> `elbow`.
    let base = if base.starts_with("points") {
        base.to_string()
    } else {
        base.split('[').next().unwrap_or(base).to_string()
    };
    format!("$.{base}")
}

/// What [`replay`] measured over a recorded stream.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReplayReport {
    pub robot: String,
    pub joint_names: Vec<String>,
    pub frames: usize,
    /// Warm-started frames per second on this thread (the first frame's multi-start excluded).
    pub frames_per_s: f64,
    /// The first frame (the multi-start), µs.
    pub first_frame_us: f64,
    /// Per warm-started frame, µs: median, p95, p99, max.
    pub latency_us: [f64; 4],
    /// Robot fingertips' distance from their goals (the keypoints' assignment), m: median,
    /// p95, max over every finger and frame.
    pub goal_error_m: [f64; 3],
    /// The same from the given `targets`, when the file has them (m: median, p95, max).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_error_m: Option<[f64; 3]>,
    /// The joint values of every frame, `joint_names` order.
    pub q: Vec<Vec<f64>>,
}

/// A recorded stream file: an array of frames, or `{frames, targets?}` where `targets` are, per
/// frame, the robot fingertip positions the frame is meant to reach (robot base frame, finger
/// order), as `cargo bench --bench retarget` writes with `RETARGET_DUMP`.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum RecordedStream {
    Frames(Vec<KeypointFrameMsg>),
    WithTargets {
        frames: Vec<KeypointFrameMsg>,
        #[serde(default)]
        targets: Option<Vec<Vec<[f64; 3]>>>,
    },
}

fn spread(mut v: Vec<f64>) -> [f64; 3] {
    if v.is_empty() {
        return [f64::NAN; 3];
    }
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    [at(0.5), at(0.95), v[v.len() - 1]]
}

/// Retargets a recorded stream frame by frame on this thread, as the WebSocket session does,
/// timing every frame (the comparison harness of issue 22: `reachgrasp retarget`). A frame that
/// does not validate is an error naming it.
pub fn replay(
    robot: &str,
    system: &System,
    stream: &RecordedStream,
    options: RetargetOptions,
) -> Result<ReplayReport, Error> {
    let (msgs, targets) = match stream {
        RecordedStream::Frames(f) => (f, None),
        RecordedStream::WithTargets { frames, targets } => (frames, targets.as_ref()),
    };
    if let Some(t) = targets
        && t.len() != msgs.len()
    {
        return Err(Error::invalid(
            "$.targets",
            format!("{} target rows for {} frames", t.len(), msgs.len()),
        ));
    }
    let frames: Vec<KeypointFrame> = msgs
        .iter()
        .enumerate()
        .map(|(k, m)| {
            parse_frame(m).map_err(|(field, detail)| {
                Error::invalid(field.replacen('$', &format!("$.frames[{k}]"), 1), detail)
            })
        })
        .collect::<Result<_, _>>()?;
    let mm = MappingModel::from_system(system).map_err(|e| Error::invalid("$", e.to_string()))?;
    let mut r = Retargeter::new(mm, options).map_err(|e| Error::invalid("$", e.to_string()))?;
    let model = &system.model;
    let mut data = crate::kinematics::Data::new(model);
    let (mut lat, mut goal_err, mut target_err) = (Vec::new(), Vec::new(), Vec::new());
    let mut q = Vec::with_capacity(frames.len());
    let mut first_frame_us = f64::NAN;
    let mut warm = 0.0;
    for (k, f) in frames.iter().enumerate() {
        let t0 = Instant::now();
        let step = r.push(f).map_err(|e| {
            let field = e.field();
            Error::invalid(format!("$.frames[{k}].{field}"), e.to_string())
        })?;
        let us = t0.elapsed().as_secs_f64() * 1e6;
        if k == 0 {
            first_frame_us = us;
        } else {
            warm += us;
            lat.push(us);
        }
        goal_err.extend_from_slice(&step.output_error[..step.metrics.fingers]);
        if let Some(t) = targets {
            crate::kinematics::forward_kinematics(model, &mut data, r.output());
            for (finger, p) in system.fingers.iter().zip(&t[k]) {
                let x = data.frame(finger.tip).translation.vector;
                target_err.push((x - nalgebra::Vector3::from(*p)).norm());
            }
        }
        q.push(r.output().to_vec());
    }
    let latency = {
        let s = spread(lat.clone());
        lat.sort_by(f64::total_cmp);
        let p99 = lat
            .get(((lat.len().max(1) - 1) as f64 * 0.99).round() as usize)
            .copied()
            .unwrap_or(f64::NAN);
        [s[0], s[1], p99, s[2]]
    };
    Ok(ReplayReport {
        robot: robot.to_string(),
        joint_names: r.joint_names().to_vec(),
        frames: frames.len(),
        frames_per_s: lat.len() as f64 / (warm * 1e-6),
        first_frame_us,
        latency_us: latency,
        goal_error_m: spread(goal_err),
        target_error_m: targets.map(|_| spread(target_err)),
        q,
    })
}
