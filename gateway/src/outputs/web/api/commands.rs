//! `POST /api/captures`: a manual capture asked through the API, the same command as
//! the command register 11 (`command.manual_capture`) gives, with the client as its
//! origin. Off unless `outputs.web.allow_commands`.
//!
//! Guarded against other sites' pages: only `Content-Type: application/json` is
//! taken (a cross-site form cannot send it, and a script on another site needs a
//! CORS preflight, which this server never grants), and the `Host` check of every
//! route applies (DNS rebinding). The body is at most [`MAX_COMMAND_BODY`] bytes.

use std::net::SocketAddr;
use std::ops::RangeInclusive;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::{ConnectInfo, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::{Extension, Json};
use serde::Deserialize;

use super::ApiError;
use crate::outputs::web::shared::WebState;
use crate::state::commands::{Command, CommandOrigin, CommandRefused};

/// Largest body of `POST /api/captures`, bytes.
pub(crate) const MAX_COMMAND_BODY: usize = 1024;
/// Seconds a manual capture may span, as the command register takes them.
pub(crate) const CAPTURE_SECONDS: RangeInclusive<u16> = 1..=255;
/// Seconds when the request gives none (the command register's 0).
pub(crate) const CAPTURE_SECONDS_DEFAULT: u16 = 10;

/// The body: `{"subject": "F1", "seconds": 10}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaptureRequest {
    /// A driveline's or a tandem mill's name.
    subject: String,
    /// 1..=255 s; [`CAPTURE_SECONDS_DEFAULT`] when absent.
    seconds: Option<serde_json::Value>,
}

fn refused(status: StatusCode, message: String) -> ApiError {
    ApiError { status, message }
}

/// The command channel and the body of a command request: 403 without
/// `outputs.web.allow_commands`, 415 without a JSON content type, 413 for a body over
/// [`MAX_COMMAND_BODY`] bytes.
async fn command_body(
    state: &WebState,
    headers: &HeaderMap,
    body: Body,
) -> Result<(crate::state::commands::CommandSender, axum::body::Bytes), ApiError> {
    let Some(commands) = state.commands.get().filter(|_| state.allow_commands) else {
        return Err(refused(
            StatusCode::FORBIDDEN,
            "this page takes no commands (outputs.web.allow_commands = false)".into(),
        ));
    };
    let json = headers
        .get(header::CONTENT_TYPE)
        .and_then(|value| value.to_str().ok())
        .and_then(|value| value.split(';').next())
        .is_some_and(|media| media.trim().eq_ignore_ascii_case("application/json"));
    if !json {
        return Err(refused(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "Content-Type must be application/json".into(),
        ));
    }
    let bytes = axum::body::to_bytes(body, MAX_COMMAND_BODY)
        .await
        .map_err(|_| {
            refused(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("the body is over {MAX_COMMAND_BODY} bytes"),
            )
        })?;
    Ok((commands.clone(), bytes))
}

/// The body of a fatigue reset: `{"component": "spindle top"}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FatigueResetRequest {
    /// The component's name (`drivelines[].fatigue.components[].name`).
    component: String,
}

/// `POST /api/drivelines/{name}/fatigue/reset` with `{"component": NAME}`: start the
/// component's life used at 0 (it was replaced), the same command as
/// `command.reset_fatigue`, with the client as its origin (202 when the analysis has
/// it; the history records it). Authorised as `POST /api/captures` is (403, 415, 413
/// as there); 404 for an unknown driveline, 400 for a body that is no such object or
/// a component the driveline's ledger does not have, 503 when the analysis is busy or
/// stopped.
pub(crate) async fn reset_fatigue(
    State(state): State<Arc<WebState>>,
    axum::extract::Path(name): axum::extract::Path<String>,
    Extension(ConnectInfo(peer)): Extension<ConnectInfo<SocketAddr>>,
    headers: HeaderMap,
    body: Body,
) -> Result<(StatusCode, Json<serde_json::Value>), ApiError> {
    let (commands, bytes) = command_body(&state, &headers, body).await?;
    let Some(driveline) = state.drivelines.iter().position(|d| d.name == name) else {
        return Err(refused(
            StatusCode::NOT_FOUND,
            format!("no driveline \"{}\"", name.escape_default()),
        ));
    };
    let request: FatigueResetRequest = serde_json::from_slice(&bytes).map_err(|error| {
        ApiError::bad(format!("the body must be {{\"component\": NAME}}: {error}"))
    })?;
    let components = &state.drivelines[driveline].fatigue_components;
    let Some(component) = components.iter().position(|c| *c == request.component) else {
        return Err(ApiError::bad(format!(
            "component: driveline \"{}\" has no fatigue component \"{}\" (known: {})",
            name.escape_default(),
            request.component.escape_default(),
            if components.is_empty() {
                "none: no drivelines[].fatigue".to_owned()
            } else {
                components.join(", ")
            }
        )));
    };
    commands
        .send(Command::ResetFatigue {
            driveline,
            component,
            origin: CommandOrigin::Web(peer),
        })
        .map_err(|error: CommandRefused| {
            refused(StatusCode::SERVICE_UNAVAILABLE, error.to_string())
        })?;
    tracing::info!(%peer, driveline = %name, component = %request.component, "fatigue reset asked through the web API");
    Ok((
        StatusCode::ACCEPTED,
        Json(serde_json::json!({
            "accepted": true,
            "driveline": name,
            "component": request.component,
        })),
    ))
}

/// `POST /api/captures` with `{"subject": NAME, "seconds": S}`: keep the next S
/// seconds of driveline NAME's torque, or of every stand of tandem mill NAME, as a
/// capture of kind `manual` (202 when the analysis has the command; the capture is
/// in the history once the span has passed). 403 without `outputs.web.allow_commands`,
/// 415 without a JSON content type, 413 for a body over [`MAX_COMMAND_BODY`] bytes,
/// 400 for a body that is no such object, an unknown subject or seconds out of
/// range, 409 without a history or with `history.captures = false`, 503 when the analysis is busy or stopped.
pub(crate) async fn request_capture(
    State(state): State<Arc<WebState>>,
    Extension(ConnectInfo(peer)): Extension<ConnectInfo<SocketAddr>>,
    headers: HeaderMap,
    body: Body,
) -> Result<(StatusCode, Json<serde_json::Value>), ApiError> {
    let (commands, bytes) = command_body(&state, &headers, body).await?;
    let request: CaptureRequest = serde_json::from_slice(&bytes).map_err(|error| {
        ApiError::bad(format!(
            "the body must be {{\"subject\": NAME, \"seconds\": S}}: {error}"
        ))
    })?;
    let seconds = match &request.seconds {
        None => CAPTURE_SECONDS_DEFAULT,
        Some(value) => value
            .as_u64()
            .and_then(|s| u16::try_from(s).ok())
            .filter(|s| CAPTURE_SECONDS.contains(s))
            .ok_or_else(|| {
                ApiError::bad(format!(
                    "seconds: {value} is not allowed (must be an integer in {}..={})",
                    CAPTURE_SECONDS.start(),
                    CAPTURE_SECONDS.end()
                ))
            })?,
    };
    let origin = CommandOrigin::Web(peer);
    let subject = request.subject;
    let command = if let Some(driveline) = state.drivelines.iter().position(|d| d.name == subject) {
        Command::CaptureTorque {
            driveline,
            seconds,
            origin,
        }
    } else if let Some(mill) = state.tandem_mills.iter().position(|(m, _)| *m == subject) {
        Command::CaptureStands {
            mill,
            seconds,
            origin,
        }
    } else {
        let known: Vec<&str> = state
            .drivelines
            .iter()
            .map(|d| d.name.as_str())
            .chain(state.tandem_mills.iter().map(|(m, _)| m.as_str()))
            .collect();
        return Err(ApiError::bad(format!(
            "subject: no driveline or tandem mill \"{}\" (known: {})",
            subject.escape_default(),
            known.join(", ")
        )));
    };
    if state.history.is_none() {
        return Err(refused(
            StatusCode::CONFLICT,
            "no history configured: captures are not kept (add [history])".into(),
        ));
    }
    if !state.captures_kept {
        return Err(refused(
            StatusCode::CONFLICT,
            "captures are not kept (history.captures = false)".into(),
        ));
    }
    commands.send(command).map_err(|error: CommandRefused| {
        refused(StatusCode::SERVICE_UNAVAILABLE, error.to_string())
    })?;
    let logged = crate::lock(&state.command_log).occurred(tokio::time::Instant::now());
    if let Some(suppressed) = logged {
        tracing::info!(%peer, subject, seconds, suppressed, "manual capture asked through the web API");
    }
    Ok((
        StatusCode::ACCEPTED,
        Json(serde_json::json!({
            "accepted": true,
            "kind": "manual",
            "subject": subject,
            "seconds": seconds,
        })),
    ))
}
