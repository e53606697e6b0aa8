//! `sdictl monitor`: the Stats property as it changes, one line each.

use futures_util::StreamExt;
use sdi_api::Camera1Proxy;
use serde_json::Value as Json;

use super::wire_json;
use crate::exit::CliError;
use crate::stdout::outln;

pub async fn run(
    camera: &Camera1Proxy<'_>,
    count: Option<u64>,
    json: bool,
) -> Result<(), CliError> {
    let mut stream = camera.receive_stats_changed().await;
    let mut n = 0u64;
    if !json {
        outln!(
            "{:>10} {:>8} {:>12} {:>12} {:>8}",
            "frames",
            "fps",
            "latency_us",
            "max_us",
            "dropped"
        )?;
    }
    while let Some(change) = stream.next().await {
        let s = change.get().await?;
        if json {
            outln!("{}", Json::Object(wire_json::object(&s)?))?;
        } else {
            outln!(
                "{:>10} {:>8.2} {:>12.0} {:>12.0} {:>8}",
                s.frames,
                s.fps,
                s.latency_us,
                s.latency_max_us,
                s.dropped_view + s.dropped_recording
            )?;
        }
        n += 1;
        if count.is_some_and(|c| n >= c) {
            break;
        }
    }
    Ok(())
}
