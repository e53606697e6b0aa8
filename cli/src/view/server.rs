//! The local web server: routes, the embedded page, and the WebSocket that
//! carries each frame with its statistics to the page.
//!
//! A frame message is binary: a little-endian `u32` length, that many bytes
//! of JSON (header, histogram, probe, region, and the images' names and
//! sizes), then the images' RGBA bytes in the order the JSON lists them.
//! The page sends JSON text back: `{"probe": [x, y]}` or
//! `{"region": [x, y, width, height]}`.

use std::sync::Arc;

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::response::{Html, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Deserialize;
use serde_json::json;
use tokio::sync::watch;

use super::analysis::{Histogram, Probe, Region, HISTOGRAM_BINS};
use super::cameras;
use super::connections::{self, Limits};
use super::controls::{self, Controls};
use super::frames::LiveFrame;
use super::security::{self, Guard};

const INDEX_HTML: &str = include_str!("assets/index.html");
const APP_JS: &str = include_str!("assets/app.js");

/// Everything a route needs.
#[derive(Clone)]
pub struct App {
    pub controls: Arc<Controls>,
    pub frames: watch::Receiver<Option<Arc<LiveFrame>>>,
}

/// The router, every route behind the guard, then the body's timeout.
pub fn router(app: App, guard: Guard, limits: Limits) -> Router {
    let api = Router::new()
        .route("/api/status", get(controls::status))
        .route("/api/set", post(controls::set))
        .route("/api/snapshot", post(controls::snapshot))
        .route("/api/record", post(controls::record))
        .route("/api/calibrate", post(controls::calibrate))
        .route("/api/cameras", get(cameras::list))
        .route("/api/camera", post(cameras::choose))
        .with_state(app.controls.clone());
    Router::new()
        .route("/", get(index))
        .route("/ws", get(ws))
        .with_state(app)
        .merge(api)
        .layer(axum::middleware::from_fn_with_state(
            limits,
            connections::read_body,
        ))
        .layer(axum::middleware::from_fn_with_state(guard, security::check))
}

/// The page with its script inline: one request. It holds no secret and
/// reads nothing of sdid's, so it needs no token (it arrives in the URL's
/// fragment, which the browser keeps to itself); everything else does.
async fn index() -> Html<String> {
    Html(INDEX_HTML.replace("/*APP_JS*/", APP_JS))
}

async fn ws(upgrade: WebSocketUpgrade, State(app): State<App>) -> Response {
    upgrade.on_upgrade(move |socket| watch_frames(socket, app.frames))
}

/// What the page asks of the statistics.
#[derive(Deserialize)]
struct PageRequest {
    probe: Option<[usize; 2]>,
    region: Option<[usize; 4]>,
}

/// Sends every new frame until the page goes away; a frame that arrives
/// while one is being sent replaces the older one (the watch channel).
async fn watch_frames(mut socket: WebSocket, mut frames: watch::Receiver<Option<Arc<LiveFrame>>>) {
    let mut probe: Option<Probe> = None;
    let mut region: Option<Region> = None;
    loop {
        tokio::select! {
            changed = frames.changed() => {
                if changed.is_err() {
                    return;
                }
                let frame = frames.borrow_and_update().clone();
                let Some(frame) = frame else { continue };
                let msg = encode(&frame, &mut probe, &mut region);
                if socket.send(Message::Binary(msg.into())).await.is_err() {
                    return;
                }
            }
            msg = socket.recv() => {
                let Some(Ok(msg)) = msg else { return };
                let Message::Text(text) = msg else { continue };
                if let Ok(req) = serde_json::from_str::<PageRequest>(text.as_str()) {
                    if let Some([x, y]) = req.probe {
                        probe = Some(Probe::new(x, y));
                    }
                    if let Some([x, y, w, h]) = req.region {
                        region = Some(Region::new(x, y, w, h));
                    }
                }
            }
        }
    }
}

/// One frame message (see the module doc).
fn encode(frame: &LiveFrame, probe: &mut Option<Probe>, region: &mut Option<Region>) -> Vec<u8> {
    let h = &frame.header;
    let (w, ht) = (h.width as usize, h.height as usize);
    if let Some(p) = probe.as_mut() {
        p.push(&frame.dn, w);
    }
    if let Some(r) = region.as_mut() {
        r.push(&frame.dn, w, ht);
    }
    let saturated = frame
        .flags
        .iter()
        .filter(|&&f| f & sdi_core::PixelFlags::SATURATED.bits() != 0)
        .count();
    let mut images = vec![("view", &frame.view_rgba)];
    if let Some((plus, minus)) = &frame.channels_rgba {
        images.push(("i_plus", plus));
        images.push(("i_minus", minus));
    }
    let meta = json!({
        "sequence": h.sequence,
        "timestamp_us": h.timestamp_us,
        "width": w,
        "height": ht,
        "mode": h.mode,
        "colormap": h.colormap,
        "max_abs_dn": h.max_abs_dn,
        "dropped": h.dropped,
        "saturated": saturated,
        "channels_se_electrons": frame.channels_se_electrons,
        "histogram": Histogram::of(&frame.dn, HISTOGRAM_BINS),
        "probe": probe,
        "region": region.as_ref().map(|r| json!({
            "rect": [r.x0, r.y0, r.width, r.height],
            "report": r.report(),
        })),
        "images": images.iter().map(|(name, _)| json!({"name": name, "width": w, "height": ht})).collect::<Vec<_>>(),
    })
    .to_string();
    let rgba_bytes: usize = images.iter().map(|(_, b)| b.len()).sum();
    let mut out = Vec::with_capacity(4 + meta.len() + rgba_bytes);
    out.extend_from_slice(&(meta.len() as u32).to_le_bytes());
    out.extend_from_slice(meta.as_bytes());
    for (_, bytes) in images {
        out.extend_from_slice(bytes);
    }
    out
}
