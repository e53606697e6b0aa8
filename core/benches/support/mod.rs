//! What the side-by-side benches share: the thread's CPU time, per-call
//! timing, and running a Python reference script from `benches/`. Each
//! bench uses part of it.
#![allow(dead_code)]

use std::process::Command;
use std::time::{Duration, Instant};

use nix::time::{clock_gettime, ClockId};

/// CPU time consumed by this thread so far (CLOCK_THREAD_CPUTIME_ID):
/// waiting for a core does not count.
pub fn thread_cpu() -> Duration {
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(Duration::from)
        .unwrap_or_default()
}

/// (median wall ms, mean CPU ms) per call over `reps` calls, after one call
/// that warms caches and tables.
pub fn time_ms(reps: usize, mut run: impl FnMut()) -> (f64, f64) {
    run();
    let c0 = thread_cpu();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            run();
            t0.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let cpu = (thread_cpu() - c0).as_secs_f64() * 1e3 / reps as f64;
    t.sort_by(f64::total_cmp);
    (t[reps / 2], cpu)
}

/// The standard output of `/usr/bin/python3 benches/<script> args`; None,
/// said on stderr, without Python (the `column` then stays empty). A failed
/// script's stderr is printed and what it wrote is still returned.
pub fn python(script: &str, args: &[String], column: &str) -> Option<String> {
    let path = format!("{}/benches/{script}", env!("CARGO_MANIFEST_DIR"));
    let Ok(o) = Command::new("/usr/bin/python3")
        .arg(path)
        .args(args)
        .output()
    else {
        eprintln!("no /usr/bin/python3: {column} column left empty");
        return None;
    };
    if !o.status.success() {
        eprintln!("{script} failed: {}", String::from_utf8_lossy(&o.stderr));
    }
    Some(String::from_utf8_lossy(&o.stdout).into_owned())
}
