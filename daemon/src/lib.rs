//! Library side of sdid: the parts integration tests drive directly.
//!
//! The hardware backend lives under `backend/opt8241/`; until the daemon's
//! `backend` module declares it, it is mounted here by path.

pub mod light;
#[path = "backend/opt8241/mod.rs"]
pub mod opt8241;
