//! The loop as a whole: a source that pauses or stays silent, against a
//! sink that notes what it was given and when.

use super::{Command, FrameLoop, FrameMark};
use crate::backend::sim::SimBackend;
use crate::backend::{Backend, BackendError, CaptureSettings};
use crate::monotonic::monotonic_now_us;
use crate::out_frame::OutFrame;
use crate::sink::output::Output;
use crate::sink::{Sink, SinkError, SinkInfo};
use sdi_core::display::DisplayMap;
use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::sensor::{SensorParams, SensorPreset};
use sdi_core::Frame;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The simulator, failing the capture attempts marked in `fails` (a
/// source that pauses) and taking `first_capture` over its first frame;
/// or, when `silent`, a device with its own frame clock that never
/// sends a frame nor fails ([`BackendError::NotYet`] after a short slice).
struct Scripted {
    sim: SimBackend,
    fails: Vec<bool>,
    attempt: usize,
    first_capture: Option<Duration>,
    silent: bool,
}

impl Backend for Scripted {
    fn kind(&self) -> crate::backend::BackendName {
        self.sim.kind()
    }
    fn device(&self) -> String {
        self.sim.device()
    }
    fn sensor(&self) -> &SensorParams {
        self.sim.sensor()
    }
    fn settings(&self) -> CaptureSettings {
        self.sim.settings()
    }
    fn configure(&mut self, s: &CaptureSettings) -> Result<(), BackendError> {
        self.sim.configure(s)
    }
    fn paced_rate_hz(&self) -> Option<f64> {
        self.sim.paced_rate_hz().filter(|_| !self.silent)
    }
    fn capture(&mut self, ill: &Illumination, frame: &mut Frame) -> Result<(), BackendError> {
        if self.silent {
            std::thread::sleep(Duration::from_millis(10));
            return Err(BackendError::NotYet);
        }
        self.attempt += 1;
        if self.fails.get(self.attempt - 1).copied().unwrap_or(false) {
            return Err(BackendError::Unavailable("paused".into()));
        }
        if let Some(took) = self.first_capture.take() {
            std::thread::sleep(took);
        }
        self.sim.capture(ill, frame)
    }
}

/// What a sink was given: (is the card, timestamp, CLOCK_MONOTONIC at the write).
type Written = Arc<Mutex<Vec<(bool, u64, u64)>>>;

struct Seen(Written);

impl Sink for Seen {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: crate::sink::SinkKindName::Y4m,
            device: String::new(),
            format: String::new(),
            width: 0,
            height: 0,
        }
    }
    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
        let now_us = monotonic_now_us();
        self.0
            .lock()
            .unwrap()
            .push((false, frame.output.timestamp_us, now_us));
        Ok(())
    }
    fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), SinkError> {
        let now_us = monotonic_now_us();
        self.0.lock().unwrap().push((true, timestamp_us, now_us));
        Ok(())
    }
}

/// A 16x8 simulator at 200 Hz.
fn sim(mode: ModeId) -> SimBackend {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = 16;
    p.height = 8;
    p.frame_rate_hz = 200.0;
    SimBackend::new(p, mode, 1, None).unwrap()
}

/// The frame loop over `backend`, running on its own thread, and what
/// its sink is given.
fn spawn_loop(
    backend: Scripted,
    mode: ModeId,
) -> (
    std::sync::mpsc::Sender<Command>,
    std::thread::JoinHandle<Option<crate::recorder::RecordingWriter>>,
    Written,
) {
    let written = Written::default();
    let output = Output::spawn(Box::new(Seen(written.clone()))).unwrap();
    let (stats_tx, _stats) = tokio::sync::watch::channel(Default::default());
    let (cal_tx, _cal) = tokio::sync::watch::channel(Default::default());
    let fl = FrameLoop::new(
        Box::new(backend),
        mode,
        DisplayMap::default(),
        output,
        stats_tx,
        cal_tx,
    );
    let (tx, rx) = std::sync::mpsc::channel();
    (tx, std::thread::spawn(move || fl.run(rx)), written)
}

/// Runs the frame loop in `mode` over a source that fails the attempts
/// marked in `fails` until the sink has `writes` writes; returns them.
fn published(mode: ModeId, fails: Vec<bool>, writes: usize) -> Vec<(bool, u64, u64)> {
    let backend = Scripted {
        sim: sim(mode),
        fails,
        attempt: 0,
        // A slow first capture: later frames must not be dated from it.
        first_capture: Some(Duration::from_millis(40)),
        silent: false,
    };
    let (tx, t, written) = spawn_loop(backend, mode);
    let t0 = Instant::now();
    while written.lock().unwrap().len() < writes && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    tx.send(Command::Shutdown).unwrap();
    t.join().unwrap();
    let w = written.lock().unwrap().clone();
    assert!(w.len() >= writes, "{} of {writes} writes: {w:?}", w.len());
    w
}

/// A source that sends nothing yet has not failed (the board within
/// its 2 s frame wait) answers a setting change as a stalled one does,
/// with the next frame's number, without a "no signal" card.
#[test]
fn a_silent_source_answers_setting_changes_without_a_card() {
    let backend = Scripted {
        sim: sim(ModeId::Raw),
        fails: Vec::new(),
        attempt: 0,
        first_capture: None,
        silent: true,
    };
    let (tx, t, written) = spawn_loop(backend, ModeId::Raw);
    let (reply, mark) = tokio::sync::oneshot::channel();
    tx.send(Command::SetDisplay(DisplayMap::default(), reply))
        .unwrap();
    let mark = mark.blocking_recv().expect("the call is answered");
    assert_eq!(
        mark,
        FrameMark {
            sequence: 1,
            timestamp_us: 0
        }
    );
    let (reply, snapshot) = tokio::sync::oneshot::channel();
    tx.send(Command::Snapshot(reply)).unwrap();
    assert!(snapshot.blocking_recv().expect("answered").is_none());
    tx.send(Command::Shutdown).unwrap();
    t.join().unwrap();
    assert!(written.lock().unwrap().is_empty(), "{written:?}");
}

/// Every stamp strictly after the one before, none later than the
/// moment the sink wrote it, cards and frames both where expected.
fn assert_one_clock(w: &[(bool, u64, u64)]) {
    for (i, pair) in w.windows(2).enumerate() {
        assert!(
            pair[1].1 > pair[0].1,
            "stamp {} not after {}: {w:?}",
            i + 1,
            i
        );
    }
    for (i, &(card, stamp, now)) in w.iter().enumerate() {
        assert!(
            stamp <= now,
            "write {i} (card {card}) stamped {} us in the future",
            stamp - now
        );
    }
    assert!(w[0].0, "the start-up card comes first: {w:?}");
    let after_pause = w.iter().skip(1).skip_while(|x| !x.0).skip_while(|x| x.0);
    assert!(after_pause.count() >= 2, "frames after the pause: {w:?}");
}

#[test]
fn no_signal_and_frames_share_one_clock_never_in_the_future() {
    // A card at start-up, frames, a pause of two attempts (two cards),
    // frames again; in two-shot the pause falls inside a pair.
    let mut fails = vec![true, false, false, false, false, true, true];
    fails.resize(40, false);
    for mode in [ModeId::Raw, ModeId::TwoShot] {
        let w = published(mode, fails.clone(), 12);
        assert_one_clock(&w);
    }
}

/// The mode travels with the frame: a snapshot taken right after a mode
/// change, before the new mode's first output, is the old mode's frame
/// and says so (it was labelled with the mode asked for at the time of
/// the snapshot). Either order of the two calls is checked by the
/// sequence numbers: frames before the change's mark are the old mode's.
#[test]
fn a_snapshot_carries_the_mode_of_its_frame() {
    let backend = Scripted {
        sim: sim(ModeId::Raw),
        fails: Vec::new(),
        attempt: 0,
        first_capture: None,
        silent: false,
    };
    let (tx, t, written) = spawn_loop(backend, ModeId::Raw);
    let t0 = Instant::now();
    while written.lock().unwrap().len() < 3 && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    for mode in [ModeId::DepthEdge, ModeId::Raw, ModeId::DepthEdge] {
        let (reply, mark) = tokio::sync::oneshot::channel();
        tx.send(Command::SetMode(mode, reply)).unwrap();
        let (reply, snapshot) = tokio::sync::oneshot::channel();
        tx.send(Command::Snapshot(reply)).unwrap();
        let mark = mark.blocking_recv().expect("the mode change is answered");
        let snap = snapshot
            .blocking_recv()
            .expect("answered")
            .expect("a frame");
        let before = snap.output.sequence < mark.sequence;
        assert_eq!(
            snap.mode == mode,
            !before,
            "snapshot of frame {} in {:?}; the change to {mode:?} took effect at frame {}",
            snap.output.sequence,
            snap.mode,
            mark.sequence
        );
    }
    tx.send(Command::Shutdown).unwrap();
    t.join().unwrap();
}
