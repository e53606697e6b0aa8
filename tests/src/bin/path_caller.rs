//! `path_caller BUS_ADDRESS`: one client of sdid's path methods for
//! `tests/tests/vm_plain/path_races.rs`, run as the unprivileged attacker. Reads
//! one path per line from stdin, calls `Snapshot(path)` (what `sdictl
//! snapshot --by-path` sends) and answers each line with `ok` or `refused
//! ERROR` on stdout. One connection for every attempt, so an attempt costs
//! a D-Bus call, not a process start (which dominates under the VM's TCG).

use std::io::{BufRead, Write};

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let Some(address) = std::env::args().nth(1) else {
        eprintln!("usage: path_caller BUS_ADDRESS");
        std::process::exit(2);
    };
    let connected = match zbus::connection::Builder::address(address.as_str()) {
        Ok(b) => b.build().await,
        Err(e) => Err(e),
    };
    let conn = connected.unwrap_or_else(|e| {
        eprintln!("path_caller: connect to {address}: {e}");
        std::process::exit(3);
    });
    let camera = zbus::Proxy::new(
        &conn,
        "org.sdi.Daemon",
        "/org/sdi/Camera0",
        "org.sdi.Camera1",
    )
    .await
    .unwrap_or_else(|e| {
        eprintln!("path_caller: proxy: {e}");
        std::process::exit(3);
    });
    // stdin is read between calls only: blocking reads are fine on this
    // single-threaded runtime.
    let mut out = std::io::stdout().lock();
    for line in std::io::stdin().lock().lines().map_while(Result::ok) {
        let reply = match camera.call_method("Snapshot", &(line.as_str(),)).await {
            Ok(_) => "ok".to_owned(),
            Err(e) => format!("refused {}", e.to_string().replace('\n', " ")),
        };
        if writeln!(out, "{reply}").and_then(|()| out.flush()).is_err() {
            return;
        }
    }
}
