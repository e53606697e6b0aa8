//! Where a session-bus sdid is found: the session bus of the environment, or
//! the private bus `sdid --session` starts (and announces in a file) when
//! there is none.

use std::path::PathBuf;

/// Where `sdid --session` writes the address of a private bus it started,
/// so `sdictl --session` finds it.
pub fn private_bus_file() -> PathBuf {
    let dir = std::env::var_os("XDG_RUNTIME_DIR")
        .map(PathBuf::from)
        .filter(|d| d.is_dir())
        .unwrap_or_else(|| PathBuf::from("/tmp"));
    dir.join(format!("sdid-session-bus-{}", nix::unistd::getuid()))
}

/// The session bus address from the environment or `$XDG_RUNTIME_DIR/bus`.
pub fn session_address() -> Option<String> {
    if let Some(a) = std::env::var("DBUS_SESSION_BUS_ADDRESS")
        .ok()
        .filter(|a| !a.is_empty())
    {
        return Some(a);
    }
    let rt = std::env::var_os("XDG_RUNTIME_DIR")?;
    let sock = PathBuf::from(rt).join("bus");
    sock.exists()
        .then(|| format!("unix:path={}", sock.display()))
}

/// The address a client uses for a session-bus sdid: the session bus, else
/// the private bus sdid announced.
pub fn session_or_private_address() -> Option<String> {
    session_address().or_else(|| {
        std::fs::read_to_string(private_bus_file())
            .ok()
            .map(|s| s.trim().to_owned())
            .filter(|s| !s.is_empty())
    })
}
