//! HTTP control and monitoring (its own port): health, status, Prometheus metrics, the latest
//! screen and camera images, calibration replay, run-time settings and a small live
//! dashboard. Images come from [`super::views`] (made at most once per frame, at a low
//! priority), never from the runtime's workers.

use super::Shared;
use super::frames::Control;
use super::views::{FrameGate, Get, View};
use crate::stimulator::calibration::Curve;
use axum::Router;
use axum::body::Bytes;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use serde_json::json;
use std::sync::Arc;
use tokio::net::TcpListener;

const DASHBOARD: &str = include_str!("dashboard.html");

pub async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    let mut stop = shared.shutdown.clone();
    let app = Router::new()
        .route("/", get(|| async { Html(DASHBOARD) }))
        .route("/health", get(|| async { "ok\n" }))
        .route("/status", get(status))
        .route("/metrics", get(metrics))
        .route("/frame/latest.png", get(frame_png))
        .route("/frame/view.png", get(frame_view))
        .route("/camera/latest.png", get(camera_png))
        .route("/camera/view.png", get(camera_view))
        .route(
            "/calibration",
            axum::routing::put(put_calibration).get(get_calibration),
        )
        .route("/config", get(get_config).put(put_config))
        .layer(axum::middleware::from_fn_with_state(
            shared.clone(),
            between_frames,
        ))
        .with_state(shared);
    let r = axum::serve(listener, app)
        .with_graceful_shutdown(async move {
            let _ = stop.changed().await;
        })
        .await;
    if let Err(e) = r {
        tracing::error!("HTTP server: {e}");
    }
}

/// Every request is answered between frames ([`super::views::FrameGate`]): it waits while a
/// frame is in flight (at most 250 ms), so that watchers never take from the frame loop.
async fn between_frames(
    State(s): State<Arc<Shared>>,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    s.views.gate.idle().await;
    next.run(req).await
}

/// An image's bytes sent in slices, each between frames: a few megabytes copied through
/// the kernel to 16 watchers would otherwise take the frames' CPU. The whole body defers to
/// the frames for at most [`FrameGate::MAX_WAIT`], then goes at its low priority.
fn between_frames_body(png: Bytes, gate: Arc<FrameGate>) -> axum::body::Body {
    const SLICE: usize = 256 << 10;
    let until = std::time::Instant::now() + FrameGate::MAX_WAIT;
    let slices = futures_util::stream::unfold(png, move |mut rest| {
        let gate = gate.clone();
        async move {
            if rest.is_empty() {
                return None;
            }
            gate.idle_before(until).await;
            let slice = rest.split_to(SLICE.min(rest.len()));
            Some((Ok::<_, std::convert::Infallible>(slice), rest))
        }
    });
    axum::body::Body::from_stream(slices)
}

async fn status(State(s): State<Arc<Shared>>) -> Response {
    let (fps, [p50, p99, max], recent) = s.stats.summary();
    let scene = s.scene();
    let (id, sha) = s
        .calibration
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    let latest = s
        .latest
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .as_ref()
        .map(|l| l.frame_id);
    // How far the DEM horizon's cache is filled (frames over uncomputed texels pay for them).
    let horizon = scene
        .config
        .scene
        .body
        .relief
        .as_ref()
        .and_then(|r| r.dem_horizon.as_ref())
        .map(|h| json!({"computed_texels": h.computed_texels(), "texels": h.texels()}));
    let last_frame = s
        .last_frame
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    // Fixed settings, or the budget and what the planner chose for the latest frame.
    let fidelity = match &scene.config.fidelity {
        None => json!({"mode": "fixed"}),
        Some(f) => json!({
            "mode": "budget",
            "budget": f.budget,
            "last_frame": last_frame.as_ref().and_then(|l| {
                l.plan.as_ref().map(|p| json!({"frame_id": l.frame_id, "plan": p}))
            }),
        }),
    };
    let (images_made, captures_made) = s.views.made();
    // What a camera_frame holds: the bands' planes in this order, or the raw mosaic.
    let det = &scene.config.scene.camera.detector;
    let camera = json!({
        "bands": det.bands.iter().map(|b| b.name.as_str()).collect::<Vec<_>>(),
        "mosaic": match det.layout {
            crate::detector::Layout::Bayer(order) => Some(order.name()),
            crate::detector::Layout::Planes => None,
        },
    });
    let access = json!({
        "token": s.access.requires_token(),
        "insecure": s.access.insecure(),
        "scene_dirs": s.access.scene_dirs(),
    });
    axum::Json(json!({
        "access": access,
        "fidelity": fidelity,
        "fps": fps,
        "latency_ms": {"p50": p50, "p99": p99, "max": max},
        "recent_latency_ms": recent,
        "frames_presented": s.stats.frames_presented.get(),
        "poses_received": s.stats.poses_received.get(),
        "drops": s.stats.poses_dropped.get(),
        "protocol_errors": s.stats.protocol_errors.get(),
        "render_failures": s.stats.render_failures.get(),
        "undelivered_messages": s.stats.undelivered.get(),
        "clients": s.stats.clients.get(),
        "calibration": {"id": id, "sha256": sha},
        "config": {"source": scene.label, "sha256": scene.sha256},
        "runtime": s.runtime(),
        "presenter": s.presenter,
        "camera": camera,
        "latest_frame_id": latest,
        "dem_horizon": horizon,
        "last_frame": last_frame,
        "recording": s.recorder.as_ref().map(|r| r.health()),
        "views": {
            "images_made": images_made,
            "camera_captures": captures_made,
            "served_during_frames": s.views.gate.ran_out(),
        },
    }))
    .into_response()
}

async fn metrics(State(s): State<Arc<Shared>>) -> Response {
    let mut text = String::new();
    match prometheus_client::encoding::text::encode(&mut text, &s.stats.registry) {
        Ok(()) => (
            [(
                header::CONTENT_TYPE,
                "application/openmetrics-text; version=1.0.0; charset=utf-8",
            )],
            text,
        )
            .into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

fn no_frame() -> Response {
    (StatusCode::NOT_FOUND, "no frame presented yet\n").into_response()
}

/// The latest screen, its DN codes in a 16-bit PNG.
async fn frame_png(State(s): State<Arc<Shared>>) -> Response {
    view(&s, View::ScreenCodes).await
}

/// The latest screen scaled for viewing (8-bit RGB; clipped pixels red; the scale in the
/// `X-Optistim-*` headers).
async fn frame_view(State(s): State<Arc<Shared>>) -> Response {
    view(&s, View::ScreenView).await
}

/// The simulated camera's image of the latest screen, in its DN.
async fn camera_png(State(s): State<Arc<Shared>>) -> Response {
    view(&s, View::CameraDn).await
}

/// The simulated camera's image scaled for viewing (saturated pixels red).
async fn camera_view(State(s): State<Arc<Shared>>) -> Response {
    view(&s, View::CameraView).await
}

/// A view of the latest presented frame, from the image cache ([`super::views`]): made at
/// most once per frame, by a worker at a lower priority than the frame thread.
async fn view(s: &Shared, which: View) -> Response {
    let Some(latest) = s.latest.lock().unwrap_or_else(|e| e.into_inner()).clone() else {
        return no_frame();
    };
    let scene = s.scene();
    if which.is_camera() && scene.camera.is_none() {
        return (StatusCode::NOT_FOUND, "no simulated camera\n").into_response();
    }
    let bits = scene
        .config
        .stimulator
        .as_ref()
        .map_or(16, |st| st.screen_bits);
    let answer = match s.views.get(which, latest, bits, scene.camera) {
        Get::Ready(a) => a,
        Get::Wait(rx) => rx
            .await
            .unwrap_or_else(|_| Err("the image worker stopped".into())),
    };
    match answer {
        Ok(img) => {
            let mut headers = vec![
                (header::CONTENT_TYPE, "image/png".to_string()),
                (header::CACHE_CONTROL, "no-store".to_string()),
                (
                    header::HeaderName::from_static("x-optistim-frame-id"),
                    img.frame_id.to_string(),
                ),
            ];
            if let Some(sc) = img.scale {
                for (name, v) in [
                    ("x-optistim-white-dn", sc.white_dn.to_string()),
                    ("x-optistim-clip-dn", sc.clip_dn.to_string()),
                    ("x-optistim-clipped-px", sc.clipped_px.to_string()),
                ] {
                    headers.push((header::HeaderName::from_static(name), v));
                }
            }
            let mut r = between_frames_body(img.png.clone(), s.views.gate.clone()).into_response();
            headers.push((header::CONTENT_LENGTH, img.png.len().to_string()));
            for (k, v) in headers {
                if let Ok(v) = header::HeaderValue::from_str(&v) {
                    r.headers_mut().insert(k, v);
                }
            }
            r
        }
        Err(e) if e == super::views::BUSY => (StatusCode::SERVICE_UNAVAILABLE, e).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e).into_response(),
    }
}

async fn get_calibration(State(s): State<Arc<Shared>>) -> Response {
    let (id, sha) = s
        .calibration
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    axum::Json(json!({"id": id, "sha256": sha})).into_response()
}

/// A mutating call's refusal when the daemon has an access token and the request does not
/// carry it (`Authorization: Bearer TOKEN`, compared in constant time).
fn unauthorized(s: &Shared, headers: &HeaderMap) -> Option<Response> {
    let given = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    if s.access.bearer_ok(given) {
        return None;
    }
    Some(
        (
            StatusCode::UNAUTHORIZED,
            [(header::WWW_AUTHENTICATE, "Bearer")],
            "this daemon asks for its access token: Authorization: Bearer TOKEN\n",
        )
            .into_response(),
    )
}

/// Replays an uploaded curve (the CSV of `calibration/README.md`). A curve that does not
/// validate is refused with the reason, and the active one stays.
async fn put_calibration(
    State(s): State<Arc<Shared>>,
    headers: HeaderMap,
    body: Bytes,
) -> Response {
    if let Some(refused) = unauthorized(&s, &headers) {
        return refused;
    }
    let scene = s.scene();
    let interp = (scene.config.stimulator.as_ref())
        .map(|st| st.interp)
        .unwrap_or_default();
    let detector = &scene.config.scene.camera.detector;
    let parsed = Curve::parse(&body, "uploaded", "PUT /calibration", interp).and_then(|c| {
        // A camera of several bands needs a colour curve with the cross-talk of each band.
        if detector.bands.len() > 1 {
            crate::stimulator::colour::Crosstalk::for_camera(&c, detector).map_err(|e| {
                crate::stimulator::calibration::CalibrationError::Bad {
                    file: "PUT /calibration".into(),
                    line: 0,
                    message: e.to_string(),
                }
            })?;
        }
        Ok(c)
    });
    let curve = match parsed {
        // Named by its content hash.
        Ok(mut c) => {
            c.id = format!("uploaded-{}", &c.sha256[..12]);
            Arc::new(c)
        }
        Err(e) => {
            return (
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("curve refused, the active one stays: {e}\n"),
            )
                .into_response();
        }
    };
    let (tx, rx) = std::sync::mpsc::channel();
    s.intake.control(Control::Replay(curve.clone(), tx));
    let answer = tokio::task::spawn_blocking(move || {
        rx.recv_timeout(std::time::Duration::from_secs(30))
            .map_err(|_| "the frame thread did not answer".to_string())
            .and_then(|r| r)
    })
    .await
    .unwrap_or_else(|e| Err(e.to_string()));
    match answer {
        Ok(()) => {
            tracing::info!(id = %curve.id, sha256 = %curve.sha256, "calibration replayed");
            axum::Json(json!({"id": curve.id, "sha256": curve.sha256})).into_response()
        }
        Err(e) => (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("curve not applied: {e}\n"),
        )
            .into_response(),
    }
}

async fn get_config(State(s): State<Arc<Shared>>) -> Response {
    axum::Json(s.runtime()).into_response()
}

async fn put_config(State(s): State<Arc<Shared>>, headers: HeaderMap, body: Bytes) -> Response {
    if let Some(refused) = unauthorized(&s, &headers) {
        return refused;
    }
    let patch: Result<super::RuntimePatch, _> = serde_json::from_slice(&body);
    // A new scene is loaded and built on the blocking pool.
    let applied = tokio::task::spawn_blocking(move || {
        patch.map_err(|e| e.to_string()).and_then(|p| s.apply(p))
    })
    .await
    .unwrap_or_else(|e| Err(e.to_string()));
    match applied {
        Ok(r) => axum::Json(r).into_response(),
        Err(e) => (
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("config refused: {e}\n"),
        )
            .into_response(),
    }
}
