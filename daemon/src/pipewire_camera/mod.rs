//! The PipeWire camera: a per-user process that owns the camera's PipeWire
//! nodes, so readers keep their stream while sdid restarts (WirePlumber
//! ends a reader's stream when its target node goes away). sdid starts it
//! on demand and feeds it rendered frames over a socket in
//! `$XDG_RUNTIME_DIR` ([`link`]); `crate::sink::pipewire` is sdid's side.

pub mod launch;
pub mod link;
pub mod nodes;
pub mod server;
