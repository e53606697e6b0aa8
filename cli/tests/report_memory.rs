//! `report separation` streams its frames: peak memory does not grow with
//! `--max-frames` (it kept every frame, ~0.4 MB each at 320x240, and
//! aborted at 10^9). Its own test binary, so the children's peak RSS is
//! only these runs'.

mod common;
use common::{scratch, sdictl, stderr};

/// Peak RSS of every child waited for so far, KiB (Linux ru_maxrss).
fn children_max_rss_kib() -> i64 {
    nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_CHILDREN)
        .unwrap()
        .max_rss()
}

#[test]
fn peak_memory_is_flat_in_the_frame_count() {
    let dir = scratch("report-memory", "rss");
    let mut peaks = Vec::new();
    for n in ["20", "400"] {
        let o = sdictl(&[
            "report",
            "separation",
            "--scene",
            "flat-field",
            "--max-frames",
            n,
            "--out",
            dir.join(n).to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        peaks.push(children_max_rss_kib());
    }
    // 380 more frames kept would be ~145 MB; streaming adds nothing.
    let grown_mib = (peaks[1] - peaks[0]) as f64 / 1024.0;
    assert!(
        grown_mib < 20.0,
        "peak RSS {peaks:?} KiB: grew {grown_mib:.1} MiB"
    );
}
