//! `/v1/demonstrations`: upload (JSON or multipart CSV), list, inspect, derived frames, delete,
//! and the synthetic study generator as a job.

use axum::extract::{FromRequest, Multipart, Request, State};
use axum::http::{StatusCode, header};
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem, Query};
use crate::human::{
    self, DemonstrationInput, GloveCalibration, GloveStream, HumanError, IngestSummary,
    KeypointStream, Labels, ObjectSpec, StudyConfig, Subject, SyncOptions, TrackerStream,
};
use crate::jobs::JobRecord;
use crate::service::demonstrations::{self as service, DemonstrationFilter, DemonstrationRow};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_demonstrations, create_demonstration))
        .routes(routes!(generate_synthetic))
        .routes(routes!(get_demonstration, delete_demonstration))
        .routes(routes!(get_frames))
}

impl From<HumanError> for ApiError {
    fn from(e: HumanError) -> Self {
        service::human_error(e).into()
    }
}

/// A demonstration upload (canonical JSON; see `reachgrasp::human::demo` for every field).
/// Every nested object refuses unknown fields (a 422 naming e.g. `$.subject.heigth`).
/// Beyond the schema, the server checks what relates fields or samples to each other (a 422
/// naming the stream, sample and field): every stream column has as many rows as its `t`,
/// timestamps strictly increase with gaps of at most `sync.max_gap_s`, the two streams overlap
/// for at least two frames at `sync.rate_hz`, tracker positions lie within 3 m of its origin,
/// quaternions are not zero, and calibrated glove angles are within ±π.
///
/// A keypoint recording (camera, headset, motion-capture suit) gives `keypoints` instead of
/// `tracker` and `glove`: the 21 MANO / MediaPipe hand points per sample, optionally the elbow
/// and shoulder (without them it maps only onto a hand on a fixed base) and the wrist
/// orientation; it is resampled at `sync.rate_hz` on its own
/// clock (`sync.glove_offset_s` does not apply) and becomes the same derived frames.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DemonstrationUpload {
    pub subject: Subject,
    pub object: ObjectSpec,
    pub labels: Labels,
    /// Positions in metres, orientations `[w, x, y, z]`. Required without `keypoints`.
    #[serde(default)]
    pub tracker: Option<TrackerStream>,
    /// `{t, angles: [[22 radians]]}` or `{t, raw: [[22]], calibration: {gain: [22], offset: [22]}}`.
    /// Required without `keypoints`.
    #[serde(default)]
    pub glove: Option<GloveStream>,
    /// A keypoint recording instead of `tracker` and `glove`.
    #[serde(default)]
    pub keypoints: Option<KeypointStream>,
    /// Default `{glove_offset_s: 0, rate_hz: 120, max_gap_s: 0.1}`.
    #[serde(default)]
    pub sync: SyncOptions,
}

impl TryFrom<DemonstrationUpload> for DemonstrationInput {
    type Error = ApiError;
    fn try_from(u: DemonstrationUpload) -> Result<Self, ApiError> {
        let (tracker, glove) = match (u.tracker, u.glove, &u.keypoints) {
            (Some(t), Some(g), None) => (t, g),
            (None, None, Some(_)) => Default::default(),
            (_, _, Some(_)) => {
                return Err(ApiError::invalid_field(
                    "$.keypoints",
                    "a demonstration is a tracker + glove recording or a keypoint recording, \
                     not both: leave out `tracker` and `glove` with `keypoints`",
                ));
            }
            (t, _, None) => {
                let field = if t.is_none() { "$.tracker" } else { "$.glove" };
                return Err(ApiError::invalid_field(
                    field,
                    "missing: give `tracker` and `glove`, or `keypoints`",
                ));
            }
        };
        Ok(DemonstrationInput {
            subject: u.subject,
            object: u.object,
            labels: u.labels,
            tracker,
            glove,
            keypoints: u.keypoints,
            sync: u.sync,
        })
    }
}

/// Multipart form of an upload: a JSON `meta` part and one CSV file per stream.
#[derive(Debug, ToSchema)]
#[allow(dead_code)] // documents the form; the handler reads the parts directly
pub struct DemonstrationForm {
    /// JSON: `{subject, object, labels, sync?, calibration?}`; with a `calibration` the glove CSV
    /// holds raw sensor values.
    #[schema(value_type = FormMeta)]
    meta: String,
    /// CSV `t,shoulder_x,shoulder_y,shoulder_z,elbow_x,...,wrist_z,qw,qx,qy,qz` (with `glove`,
    /// or `keypoints` instead of both).
    #[schema(content_media_type = "text/csv")]
    tracker: Option<String>,
    /// CSV `t` and the 22 glove channel names (radians, or raw values with a calibration).
    #[schema(content_media_type = "text/csv")]
    glove: Option<String>,
    /// Instead of `tracker` and `glove`: a keypoint recording, CSV `t`, `<keypoint>_x,_y,_z` for
    /// the 21 keypoints (`wrist`, `thumb_cmc`, ..., `little_tip`), optionally `elbow_x..z` with
    /// `shoulder_x..z`, and `wrist_qw,wrist_qx,wrist_qy,wrist_qz`.
    #[schema(content_media_type = "text/csv")]
    keypoints: Option<String>,
}

/// The `meta` part of a multipart upload: the upload's fields other than its streams, and the
/// glove calibration when the glove CSV holds raw values. Unknown fields are refused (a 422
/// naming e.g. `meta.subject.heigth`).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = DemonstrationMeta)]
pub struct FormMeta {
    pub subject: Subject,
    pub object: ObjectSpec,
    pub labels: Labels,
    /// Default `{glove_offset_s: 0, rate_hz: 120, max_gap_s: 0.1}`.
    #[serde(default)]
    pub sync: SyncOptions,
    /// Present exactly when the glove CSV holds raw sensor values.
    #[serde(default)]
    pub calibration: Option<GloveCalibration>,
}

/// The `meta` part read with the path of a bad field (`meta.subject.heigth`), as a JSON body's
/// errors name theirs.
fn read_meta(text: &str) -> Result<FormMeta, ApiError> {
    let mut de = serde_json::Deserializer::from_str(text);
    let meta: FormMeta = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        if e.inner().is_syntax() || e.inner().is_eof() {
            let path = match e.path().to_string() {
                p if p == "." => "meta".to_owned(),
                p => format!("meta.{p}"),
            };
            return ApiError::invalid_field(path, format!("invalid JSON: {}", e.inner()));
        }
        // The part's own fields below `meta`, as a JSON body's below `$`.
        let (path, message) = super::extract::locate(&e);
        ApiError::invalid_field(format!("meta{}", &path[1..]), message)
    })?;
    de.end()
        .map_err(|e| ApiError::invalid_field("meta", format!("invalid JSON: {e}")))?;
    Ok(meta)
}

/// Key figures of an ingested demonstration.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct SummaryDto {
    /// Time of the first frame on the tracker clock, s.
    pub start_s: f64,
    pub duration_s: f64,
    pub frames: usize,
    /// Common resampling rate, Hz.
    pub rate_hz: f64,
    pub tracker_samples: usize,
    pub glove_samples: usize,
    /// Mean raw stream rates, Hz.
    pub tracker_rate_hz: f64,
    pub glove_rate_hz: f64,
    /// `tracker_glove` or `keypoints` (then `tracker_*` are the keypoint samples, and frames
    /// have no glove angles).
    pub source: human::Source,
    /// Whether the frames carry the elbow and shoulder (false: the hand alone, which maps only
    /// onto a hand on a fixed base).
    pub arm: bool,
}

impl From<IngestSummary> for SummaryDto {
    fn from(s: IngestSummary) -> Self {
        SummaryDto {
            start_s: s.start_s,
            duration_s: s.duration_s,
            frames: s.frames,
            rate_hz: s.rate_hz,
            tracker_samples: s.tracker_samples,
            glove_samples: s.glove_samples,
            tracker_rate_hz: s.tracker_rate_hz,
            glove_rate_hz: s.glove_rate_hz,
            source: s.source,
            arm: s.arm,
        }
    }
}

/// A stored demonstration (without its frames; see `frames_href`).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DemonstrationDto {
    pub id: String,
    pub external_id: Option<String>,
    /// The synthetic-study job that produced it, if any.
    pub job_id: Option<String>,
    pub subject: Subject,
    pub object: ObjectSpec,
    pub task: String,
    pub position_index: u32,
    pub trial: u32,
    pub synthetic: bool,
    pub summary: SummaryDto,
    pub created_at: String,
    pub frames_href: String,
}

impl TryFrom<&DemonstrationRow> for DemonstrationDto {
    type Error = ApiError;
    fn try_from(r: &DemonstrationRow) -> Result<Self, ApiError> {
        Ok(DemonstrationDto {
            id: r.id.clone(),
            external_id: r.external_id.clone(),
            job_id: r.job_id.clone(),
            subject: r.subject()?,
            object: r.object()?,
            task: r.task.clone(),
            position_index: r.position_index as u32,
            trial: r.trial as u32,
            synthetic: r.synthetic,
            summary: r.summary()?.into(),
            created_at: r.created_at.clone(),
            frames_href: format!("/v1/demonstrations/{}/frames", r.id),
        })
    }
}

impl Listed for DemonstrationDto {
    const PAGE: &'static str = "DemonstrationList";
    const DESCRIPTION: Option<&'static str> = Some("A page of demonstrations, newest first.");
}

/// A page of demonstrations, newest first.
pub type DemonstrationList = Page<DemonstrationDto>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    /// Only this subject id.
    pub subject: Option<String>,
    /// Only this object name (`ball`, `bottle`, ...).
    pub object: Option<String>,
    /// Only synthetic (`true`) or only recorded (`false`) demonstrations.
    pub synthetic: Option<bool>,
    /// Only those produced by this synthetic-study job.
    pub job_id: Option<Uuid>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Demonstrations to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

/// A pose: position (m) and orientation quaternion `[w, x, y, z]`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PoseDto {
    #[schema(min_items = 3, max_items = 3)]
    pub position: [f64; 3],
    #[schema(min_items = 4, max_items = 4)]
    pub orientation: [f64; 4],
}

impl PoseDto {
    fn new(p: &nalgebra::Isometry3<f64>) -> Self {
        let q = p.rotation.quaternion();
        let v = p.translation.vector;
        PoseDto {
            position: [v.x, v.y, v.z],
            orientation: [q.w, q.i, q.j, q.k],
        }
    }
}

/// Derived human kinematics of one frame, tracker frame, metres.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FrameDto {
    pub t: f64,
    #[schema(min_items = 3, max_items = 3)]
    pub shoulder: [f64; 3],
    #[schema(min_items = 3, max_items = 3)]
    pub elbow: [f64; 3],
    pub wrist: PoseDto,
    /// Thumb, index, middle, ring, little: tip position and distal-phalanx frame
    /// (`x` along the phalanx, `z` palmar).
    pub fingertips: Vec<PoseDto>,
    /// The 22 resampled glove angles (radians), channel order of the glove format.
    pub glove: Vec<f64>,
}

/// The derived frames of a demonstration.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct FramesDto {
    pub id: String,
    /// Rate of the returned frames (the stored rate divided by `every`), Hz.
    pub rate_hz: f64,
    pub every: u32,
    /// Channel names of `glove`.
    pub glove_channels: Vec<String>,
    pub frames: Vec<FrameDto>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct FramesQuery {
    /// Keep every n-th frame (decimation), 1 to 1000 (default 1).
    #[param(minimum = 1, maximum = 1000)]
    pub every: Option<u32>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct DeleteQuery {
    /// Also delete the mappings that use the demonstration (default false: 409 while in use).
    pub cascade: Option<bool>,
}

/// Synthetic study request; every field is optional (the defaults reproduce the paper's design:
/// 5 subjects × 5 positions × 10 trials, objects counterbalanced over positions).
///
/// Read as the [`StudyConfig`] itself (see the `Deserialize` impl below): a flattened field
/// would lose the path of a bad value (`{"subjects": "five"}` was reported at `$`).
#[derive(Debug, ToSchema)]
pub struct SyntheticRequest {
    /// `{seed: 1, subjects: 5, positions: 5, trials: 10, objects: ["ball", "bottle",
    /// "kitchen_timer", "pencil", "sunglasses"], full_factorial: false, noise: true,
    /// rate_hz: 120}`.
    #[serde(flatten)]
    #[schema(value_type = Object)]
    pub config: StudyConfig,
}

/// Read as the study's own object, so that errors keep their field paths; only an object is a
/// study (a derived struct would also take a JSON array of its fields in order).
impl<'de> Deserialize<'de> for SyntheticRequest {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Study;
        impl<'de> serde::de::Visitor<'de> for Study {
            type Value = StudyConfig;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a study object")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<StudyConfig, A::Error> {
                StudyConfig::deserialize(serde::de::value::MapAccessDeserializer::new(map))
            }
        }
        d.deserialize_map(Study)
            .map(|config| SyntheticRequest { config })
    }
}

fn created(dto: DemonstrationDto, status: StatusCode) -> Response {
    super::created(status, format!("/v1/demonstrations/{}", dto.id), dto)
}

async fn read_form(mut form: Multipart) -> Result<DemonstrationInput, ApiError> {
    let (mut meta, mut tracker, mut glove, mut keypoints) = (None, None, None, None);
    while let Some(field) = form
        .next_field()
        .await
        .map_err(|e| ApiError::bad_request(format!("malformed multipart body: {e}")))?
    {
        let name = field.name().unwrap_or_default().to_string();
        let text = field
            .text()
            .await
            .map_err(|e| ApiError::bad_request(format!("multipart part `{name}`: {e}")))?;
        match name.as_str() {
            "meta" => meta = Some(text),
            "tracker" => tracker = Some(text),
            "glove" => glove = Some(text),
            "keypoints" => keypoints = Some(text),
            _ => {}
        }
    }
    let missing = |part: &str| {
        ApiError::invalid_field(part, format!("the multipart part `{part}` is missing"))
    };
    let meta = read_meta(&meta.ok_or_else(|| missing("meta"))?)?;
    if let Some(text) = keypoints {
        if tracker.is_some() || glove.is_some() {
            return Err(ApiError::invalid_field(
                "keypoints",
                "a demonstration is a tracker + glove recording or a keypoint recording, not \
                 both: send the `keypoints` part without `tracker` and `glove`",
            ));
        }
        return Ok(DemonstrationInput {
            subject: meta.subject,
            object: meta.object,
            labels: meta.labels,
            tracker: TrackerStream::default(),
            glove: GloveStream::default(),
            keypoints: Some(human::csv::parse_keypoint_csv(&text)?),
            sync: meta.sync,
        });
    }
    let tracker = human::csv::parse_tracker_csv(&tracker.ok_or_else(|| missing("tracker"))?)?;
    let glove =
        human::csv::parse_glove_csv(&glove.ok_or_else(|| missing("glove"))?, meta.calibration)?;
    Ok(DemonstrationInput {
        subject: meta.subject,
        object: meta.object,
        labels: meta.labels,
        tracker,
        glove,
        keypoints: None,
        sync: meta.sync,
    })
}

/// Upload a demonstration (JSON, or multipart with `meta` JSON plus `tracker` and `glove` CSV
/// files). The streams are validated, put on one clock, resampled and the human kinematics
/// derived; bad input is a 422 naming the stream, sample index and field, and nothing is stored.
/// Re-uploading with the same `labels.external_id` returns the existing record with 200.
#[utoipa::path(post, path = "/v1/demonstrations", tag = "demonstrations",
    request_body(content(
        (DemonstrationUpload = "application/json"),
        (DemonstrationForm = "multipart/form-data"),
    )),
    responses(
        (status = 201, description = "Stored; `Location` names it", body = DemonstrationDto),
        (status = 200, description = "Already stored under this `external_id`", body = DemonstrationDto),
        (status = 400, description = "Malformed body", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "Body over the size limit", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Neither JSON nor multipart", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid streams or metadata", body = Problem, content_type = "application/problem+json"),
    ))]
async fn create_demonstration(
    State(state): State<AppState>,
    req: Request,
) -> Result<Response, ApiError> {
    let is_multipart = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("multipart/form-data"));
    let input: DemonstrationInput = if is_multipart {
        let form = Multipart::from_request(req, &state)
            .await
            .map_err(|e| ApiError::bad_request(format!("malformed multipart body: {e}")))?;
        read_form(form).await?
    } else {
        Json::<DemonstrationUpload>::from_request(req, &state)
            .await?
            .0
            .try_into()?
    };
    let (row, new) = service::upload(&state, input).await?;
    let status = if new {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    Ok(created(DemonstrationDto::try_from(&row)?, status))
}

/// List demonstrations, newest first, filtered by subject, object, synthetic flag or job.
#[utoipa::path(get, path = "/v1/demonstrations", tag = "demonstrations", params(ListQuery),
    responses(
        (status = 200, description = "A page of demonstrations", body = DemonstrationList),
        (status = 400, description = "Bad query parameter", body = Problem, content_type = "application/problem+json"),
    ))]
async fn list_demonstrations(
    State(state): State<AppState>,
    Listing(q, page): Listing<ListQuery>,
) -> Result<Json<DemonstrationList>, ApiError> {
    let filter = DemonstrationFilter {
        subject: q.subject,
        object: q.object,
        synthetic: q.synthetic,
        job_id: q.job_id.map(|j| j.to_string()),
        limit: page.limit,
        offset: page.offset,
    };
    let (rows, total) = service::list(&state, &filter).await?;
    let items = rows
        .iter()
        .map(DemonstrationDto::try_from)
        .collect::<Result<_, _>>()?;
    Ok(Json(page.of(items, Some(total))))
}

/// One demonstration: metadata and ingest summary.
#[utoipa::path(get, path = "/v1/demonstrations/{id}", tag = "demonstrations",
    params(("id" = Uuid, Path, description = "Demonstration id")),
    responses(
        (status = 200, description = "The demonstration", body = DemonstrationDto),
        (status = 400, description = "Malformed id", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown demonstration", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_demonstration(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Json<DemonstrationDto>, ApiError> {
    let row = service::get(&state, &id.to_string()).await?;
    Ok(Json(DemonstrationDto::try_from(&row)?))
}

/// The derived kinematics of every frame (or of every n-th frame).
#[utoipa::path(get, path = "/v1/demonstrations/{id}/frames", tag = "demonstrations",
    params(("id" = Uuid, Path, description = "Demonstration id"), FramesQuery),
    responses(
        (status = 200, description = "Derived frames", body = FramesDto),
        (status = 400, description = "Bad parameter", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown demonstration", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_frames(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
    Query(q): Query<FramesQuery>,
) -> Result<Json<FramesDto>, ApiError> {
    let every = q.every.unwrap_or(1);
    if !(1..=1000).contains(&every) {
        return Err(ApiError::invalid_parameter(
            "every",
            format!("must be between 1 and 1000, got {every}"),
        ));
    }
    let id = id.to_string();
    let (row, frames, glove) = service::frames(&state, &id).await?;
    let summary = row.summary()?;
    let frames = frames
        .iter()
        .zip(&glove)
        .step_by(every as usize)
        .map(|(f, g)| FrameDto {
            t: f.t,
            shoulder: f.shoulder.coords.into(),
            elbow: f.elbow.coords.into(),
            wrist: PoseDto::new(&f.wrist),
            fingertips: f.fingertips.iter().map(PoseDto::new).collect(),
            // A keypoint recording has no glove angles (stored as NaN).
            glove: if g.iter().all(|a| a.is_finite()) {
                g.to_vec()
            } else {
                Vec::new()
            },
        })
        .collect();
    Ok(Json(FramesDto {
        id,
        rate_hz: summary.rate_hz / f64::from(every),
        every,
        glove_channels: human::GLOVE_CHANNELS
            .iter()
            .map(|c| c.to_string())
            .collect(),
        frames,
    }))
}

/// Delete a demonstration. While a mapping uses it the answer is 409, unless `cascade=true`,
/// which deletes those mappings too.
#[utoipa::path(delete, path = "/v1/demonstrations/{id}", tag = "demonstrations",
    params(("id" = Uuid, Path, description = "Demonstration id"), DeleteQuery),
    responses(
        (status = 204, description = "Deleted"),
        (status = 404, description = "Unknown demonstration", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Used by a mapping", body = Problem, content_type = "application/problem+json"),
    ))]
async fn delete_demonstration(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
    Query(q): Query<DeleteQuery>,
) -> Result<StatusCode, ApiError> {
    service::delete(&state, &id.to_string(), q.cascade.unwrap_or(false)).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Generate a synthetic study as a job (202). Each demonstration goes through the same ingest
/// path as uploads and is labelled synthetic; its `external_id` is derived from the seed and the
/// trial, so repeating a request stores nothing twice. List the result with
/// `GET /v1/demonstrations?job_id={job}`.
#[utoipa::path(post, path = "/v1/demonstrations/synthetic", tag = "demonstrations",
    request_body = SyntheticRequest,
    responses(
        (status = 202, description = "Job accepted; `Location` names it", body = JobRecord),
        (status = 422, description = "Invalid study parameters", body = Problem, content_type = "application/problem+json"),
    ))]
async fn generate_synthetic(
    State(state): State<AppState>,
    Json(req): Json<SyntheticRequest>,
) -> Result<Response, ApiError> {
    let job = service::submit_study(&state, req.config).await?;
    Ok(super::accepted_job(job, None))
}
