//! `sdi-pipewire-camera SPEC` (or `--system-feed [PATH]`, fed by the system
//! service: every feed socket in the directory PATH, `/run/sdi` by
//! default, or the socket PATH): the per-user process
//! that owns SDI's PipeWire camera nodes (one camera's: [`Spec`]'s
//! serial names them), so readers keep their stream while sdid restarts
//! (WirePlumber ends a reader's stream when its target node goes away). sdid
//! starts it when it is installed beside sdid and feeds it rendered frames
//! over the socket protocol of `sdi-camera-link`; `sdid`'s
//! `sink/pipewire.rs` is the other side.
//!
//! [`Spec`]: sdi_camera_link::Spec
//!
//! It is its own program, not a mode of sdid, so that sdid builds and runs on
//! machines without libpipewire: only this crate links it.

mod feeds;
mod logging;
mod nodes;
mod server;

use std::process::ExitCode;

use sdi_camera_link::SYSTEM_RUNTIME_DIR;

fn main() -> ExitCode {
    logging::init();
    let mut args = std::env::args_os().skip(1);
    let first = args.next();
    if first.as_deref() == Some(sdi_camera_link::SYSTEM_FEED_FLAG.as_ref()) {
        return match args.next().map(std::path::PathBuf::from) {
            Some(dir) if dir.is_dir() => feeds::main(&dir),
            Some(socket) => server::main_system_feed(socket),
            None => feeds::main(SYSTEM_RUNTIME_DIR.as_ref()),
        };
    }
    server::main(first)
}
