//! `GET /v1/robots/{id}/retarget`: online retargeting of hand keypoint streams over a
//! WebSocket (issue 22; session in [`crate::service::retarget`]).

use std::time::Instant;

use axum::extract::State;
use axum::extract::ws::{
    Message, WebSocket, WebSocketUpgrade, rejection::WebSocketUpgradeRejection,
};
use axum::response::{IntoResponse, Response};
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, Path, Problem, Query};
use crate::service::retarget::{
    self as service, ForwardStatus, KeypointFrameMsg, RetargetFrameError, RetargetJoints,
    RetargetQuery, RetargetReady, Session,
};

/// The stream's message schemas (no HTTP operation carries them).
#[derive(OpenApi)]
#[openapi(components(schemas(
    KeypointFrameMsg,
    RetargetReady,
    RetargetJoints,
    RetargetFrameError,
    ForwardStatus,
    crate::bridge::StreamSend
)))]
struct StreamDoc;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(StreamDoc::openapi()).routes(routes!(retarget))
}

/// Largest frame message read, bytes (a frame with all optional fields is under 2 KiB).
const MAX_MESSAGE: usize = 64 << 10;

/// Retarget a live hand keypoint stream onto this robot (WebSocket upgrade).
///
/// Options are query parameters, checked before the upgrade (422 naming the parameter, 404 for
/// an unknown robot). The service first sends `ready` (`RetargetReady`: joint order, fingers,
/// whether frames need an elbow and shoulder). Then each text message the client sends is one
/// keypoint frame (`KeypointFrameMsg`: `t`, the 21 MANO / MediaPipe points, optionally the wrist
/// orientation, elbow and shoulder) and gets exactly one answer, in order: `joints`
/// (`RetargetJoints`: the robot's joint values, arm and hand, with each fingertip's error, the
/// elbow swivel difference and the server-side latency) or `error` (`RetargetFrameError`: the
/// frame is refused, the stream stays open and unchanged). The first frame is solved from
/// several starts, later ones warm-started from the previous solution.
///
/// Teleoperation: with `forward=true` the session also starts a streaming execution on an idle
/// connected bridge worker of the robot with the `streaming` capability (409 when there is
/// none); each answer's `q` goes to it as a setpoint and the answer says what became of it
/// (`forward`: sent, skipped, closed; the robot's measured joints). Closing the stream ends the
/// execution (`succeeded`); cancelling the execution stops the robot while the stream goes on
/// retargeting. A worker brakes to a stop when the setpoints pause for `hold_after_s`.
#[utoipa::path(get, path = "/v1/robots/{id}/retarget", tag = "robots",
    params(("id" = String, Path, description = "Robot id"), RetargetQuery),
    responses(
        (status = 101, description = "Switching protocols: the retargeting stream"),
        (status = 400, description = "Not a WebSocket upgrade request", body = Problem,
         content_type = "application/problem+json"),
        (status = 404, description = "Unknown robot", body = Problem,
         content_type = "application/problem+json"),
        (status = 409, description = "forward=true and no idle worker of the robot with the \
         streaming capability is connected", body = Problem,
         content_type = "application/problem+json"),
        (status = 422, description = "A bad option (the query parameter named)", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn retarget(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(query): Query<RetargetQuery>,
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Response {
    let mut session = match service::open(&state, &id, &query).await {
        Ok(s) => s,
        Err(e) => return ApiError::from(e).into_response(),
    };
    let ws = match ws {
        Ok(ws) => ws,
        Err(e) => {
            return ApiError::bad_request(format!("expected a WebSocket upgrade: {e}"))
                .into_response();
        }
    };
    if let Err(e) = session.forward(&state, &query).await {
        return ApiError::from(e).into_response();
    }
    let shutdown = state.shutdown.clone();
    ws.max_message_size(MAX_MESSAGE)
        .max_frame_size(MAX_MESSAGE)
        .on_upgrade(move |socket| serve(socket, session, shutdown))
}

async fn serve(mut socket: WebSocket, mut session: Session, shutdown: crate::shutdown::Shutdown) {
    let ready = serde_json::to_string(&session.ready()).expect("serialisable");
    if socket.send(Message::Text(ready.into())).await.is_err() {
        session.close().await;
        return;
    }
    loop {
        let msg = tokio::select! {
            m = socket.recv() => m,
            () = shutdown.wait() => {
                session.close().await;
                let _ = socket.send(Message::Close(None)).await;
                return;
            }
        };
        let arrived = Instant::now();
        let reply = match msg {
            Some(Ok(Message::Text(text))) => session.message(text.as_str(), arrived).await,
            Some(Ok(Message::Binary(_))) => serde_json::to_string(&RetargetFrameError::new(
                None,
                400,
                "frames are JSON text messages".into(),
                None,
            ))
            .expect("serialisable"),
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
            Some(Ok(Message::Close(_))) | None | Some(Err(_)) => {
                session.close().await;
                return;
            }
        };
        if socket.send(Message::Text(reply.into())).await.is_err() || !session.alive() {
            session.close().await;
            return;
        }
    }
}
