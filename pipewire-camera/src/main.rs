//! `sdi-pipewire-camera SPEC` (or `--system-feed [PATH]`, fed by the system
//! service): the per-user process that owns SDI's PipeWire
//! camera nodes, so readers keep their stream while sdid restarts
//! (WirePlumber ends a reader's stream when its target node goes away). sdid
//! starts it when it is installed beside sdid and feeds it rendered frames
//! over the socket protocol of `sdi-camera-link`; `sdid`'s
//! `sink/pipewire.rs` is the other side.
//!
//! It is its own program, not a mode of sdid, so that sdid builds and runs on
//! machines without libpipewire: only this crate links it.

mod logging;
mod nodes;
mod server;

use std::process::ExitCode;

fn main() -> ExitCode {
    logging::init();
    let mut args = std::env::args_os().skip(1);
    let first = args.next();
    if first.as_deref() == Some(sdi_camera_link::SYSTEM_FEED_FLAG.as_ref()) {
        let path = args
            .next()
            .map(Into::into)
            .unwrap_or_else(sdi_camera_link::system_feed_path);
        return server::main_system_feed(path);
    }
    server::main(first)
}
