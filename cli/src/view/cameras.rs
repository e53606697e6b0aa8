//! The page's camera picker: the cameras sdid serves
//! ([`sdi_api::cameras`]), and the switch to another. A switch moves the
//! page's calls and its frame stream to the camera chosen, and a lost
//! connection comes back to that camera.

use std::sync::Arc;

use axum::extract::State;
use axum::Json;
use sdi_api::cameras;
use serde::Deserialize;
use serde_json::json;

use super::controls::{bus_text, Controls, PageError, Reply};
use crate::exit::CliError;

/// Every camera (serial, backend, mode, device) and the page's.
pub async fn list(State(c): State<Arc<Controls>>) -> Reply {
    let (listed, current) = c
        .bus
        .call(|cam| async move {
            let listed = cameras::list(cam.inner().connection()).await?;
            Ok((listed, cam.serial().await?))
        })
        .await?;
    let rows: Vec<_> = listed
        .iter()
        .map(|l| json!({"serial": l.serial, "backend": l.backend, "mode": l.mode, "device": l.device}))
        .collect();
    Ok(Json(json!({"cameras": rows, "current": current})))
}

#[derive(Deserialize)]
pub struct ChooseRequest {
    serial: String,
}

/// Moves the page to the camera of `serial`.
pub async fn choose(State(c): State<Arc<Controls>>, Json(r): Json<ChooseRequest>) -> Reply {
    let serial = bus_text("the serial", &r.serial)?.to_owned();
    let wanted = serial.clone();
    let proxy = c
        .bus
        .call(|cam| async move {
            crate::online::cameras::chosen(cam.inner().connection(), Some(&wanted)).await
        })
        .await
        .map_err(PageError::from)?;
    let stream = super::frames::open(&proxy).await?;
    let (done, switched) = tokio::sync::oneshot::channel();
    c.next_stream
        .send((stream, done))
        .await
        .map_err(|_| CliError::Runtime("the frame pump has stopped".into()))?;
    // From here on, the page sees only the chosen camera's frames.
    let _ = switched.await;
    if let Ok(mut chosen) = c.camera.lock() {
        *chosen = Some(serial.clone());
    }
    c.bus.replace(proxy).await;
    Ok(Json(json!({ "serial": serial })))
}
