//! `/v1/bridges`: connected bridge workers, and the WebSocket they connect to
//! (`/v1/bridges/connect`, protocol in [`crate::bridge::protocol`]).

use axum::extract::State;
use axum::extract::ws::{WebSocketUpgrade, rejection::WebSocketUpgradeRejection};
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::{OpenApi, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, Json, Problem};
use crate::bridge::WorkerSnapshot;
use crate::bridge::protocol::{
    self, Cancel, Capability, ErrorCode, ErrorReply, Execute, ExecutionPayload, ExecutionResult,
    Feedback, Heartbeat, Hello, Outcome, ServiceMessage, TrajectoryPointSchema, Welcome,
    WorkerMessage,
};

/// The protocol's message schemas (referenced by no HTTP operation, listed for worker authors).
#[derive(OpenApi)]
#[openapi(components(schemas(
    WorkerMessage,
    ServiceMessage,
    Hello,
    Heartbeat,
    Feedback,
    ExecutionResult,
    Outcome,
    Welcome,
    Execute,
    Cancel,
    ErrorReply,
    ErrorCode,
    Capability,
    ExecutionPayload,
    TrajectoryPointSchema,
)))]
struct ProtocolDoc;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ProtocolDoc::openapi())
        .routes(routes!(list_bridges))
        .routes(routes!(connect))
}

/// A bridge worker: connected now, or seen before.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct BridgeDto {
    pub name: String,
    pub robot: String,
    pub connected: bool,
    /// `idle`, `busy` (running an execution) or `disconnected`.
    pub status: String,
    /// Live connection details (None when disconnected).
    pub connection: Option<WorkerSnapshot>,
    pub first_seen_at: String,
    pub last_connected_at: String,
    /// Last contact recorded in the database (hello or disconnect).
    pub last_seen_at: String,
}

/// Bridge workers.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct BridgeList {
    pub items: Vec<BridgeDto>,
    /// The protocol version this service speaks.
    pub protocol_version: u32,
}

/// Bridge workers: connected ones with their robot, last heartbeat and current execution
/// (busy/idle), then the ones seen before that are not connected.
#[utoipa::path(get, path = "/v1/bridges", tag = "bridges",
    responses((status = 200, description = "Workers, connected first", body = BridgeList)))]
async fn list_bridges(State(state): State<AppState>) -> Result<Json<BridgeList>, ApiError> {
    let (live, known) = crate::service::bridges::list(&state).await?;
    let mut items: Vec<BridgeDto> = Vec::with_capacity(known.len().max(live.len()));
    for w in &live {
        let row = known.iter().find(|r| r.name == w.name);
        items.push(BridgeDto {
            name: w.name.clone(),
            robot: w.robot.clone(),
            connected: true,
            status: if w.execution_id.is_some() {
                "busy"
            } else {
                "idle"
            }
            .into(),
            connection: Some(w.clone()),
            first_seen_at: row.map_or_else(|| w.connected_at.clone(), |r| r.first_seen_at.clone()),
            last_connected_at: w.connected_at.clone(),
            last_seen_at: row.map_or_else(|| w.connected_at.clone(), |r| r.last_seen_at.clone()),
        });
    }
    for r in known {
        if live.iter().all(|w| w.name != r.name) {
            items.push(BridgeDto {
                name: r.name,
                robot: r.robot,
                connected: false,
                status: "disconnected".into(),
                connection: None,
                first_seen_at: r.first_seen_at,
                last_connected_at: r.last_connected_at,
                last_seen_at: r.last_seen_at,
            });
        }
    }
    Ok(Json(BridgeList {
        items,
        protocol_version: protocol::PROTOCOL_VERSION,
    }))
}

/// The bridge workers' WebSocket (upgrade).
///
/// Present `Authorization: Bearer <token>` (the service's `REACHGRASP_BRIDGE_TOKEN`); a
/// missing or wrong token is refused with 401 before the upgrade. Then JSON text frames: the
/// worker sends `hello` first (protocol version, worker name, robot system id, its joint names
/// in model order, capabilities) and gets `welcome` or a fatal `error`; afterwards it sends
/// `heartbeat`s, and `feedback` and one `result` per `execute` it receives; the service may
/// send `cancel`. Message schemas: `WorkerMessage`, `ServiceMessage`. Frames above 64 KiB, bad
/// JSON, unknown types and feedback for an execution the worker does not hold get an `error`
/// reply; 20 of them close the connection.
#[utoipa::path(get, path = "/v1/bridges/connect", tag = "bridges",
    params(("authorization" = String, Header, description = "`Bearer <bridge token>`")),
    responses(
        (status = 101, description = "Switching protocols: the WebSocket session"),
        (status = 400, description = "Not a WebSocket upgrade request", body = Problem,
         content_type = "application/problem+json"),
        (status = 401, description = "Missing or wrong token", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn connect(
    State(state): State<AppState>,
    headers: HeaderMap,
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Response {
    let auth = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    if !state.bridges.authorized(auth) {
        return ApiError::unauthorized(
            "bridge workers must present `Authorization: Bearer <token>` with the service's bridge token",
        )
        .into_response();
    }
    let ws = match ws {
        Ok(ws) => ws,
        Err(e) => {
            return ApiError::bad_request(format!("expected a WebSocket upgrade: {e}"))
                .into_response();
        }
    };
    let hub = state.bridges.clone();
    // Frames up to 1 MiB are read (and answered with an `oversized` error when above the
    // protocol's 64 KiB); larger ones end the connection.
    ws.max_message_size(1 << 20)
        .max_frame_size(1 << 20)
        .on_upgrade(move |socket| hub.serve(state.shutdown.clone(), socket))
}
