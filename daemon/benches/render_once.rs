//! Side-by-side benchmark, one run, one core: the rendering `--sink auto`
//! does per frame with the module loaded and the PipeWire camera running
//! (the loopback view, YUYV 640x480, and data node, Y16 at the sensor
//! size; the camera's view and data node, the same pictures) against one
//! sink's, when each sink renders for itself (before `OutFrame`) and when
//! the frame renders each picture once for both (`OutFrame`). Every path
//! starts from a fresh `OutFrame` (a copy of the output), as the frame
//! loop's does.
//!
//! `cargo bench -p sdi-daemon --bench render_once`
//! Times are the thread's CPU time (CLOCK_THREAD_CPUTIME_ID), the median
//! over alternating rounds of the three paths, so all see the same machine.

use std::time::Duration;

use nix::time::{clock_gettime, ClockId};
use sdi_core::display::DisplayMap;
use sdi_core::mode::{ModeId, ModeOutput, SeparatedChannels};
use sdi_core::view::{PixelFormat, ViewRenderer};
use sdi_core::Image;
use sdi_daemon::out_frame::OutFrame;

/// The board's sensor size.
const W: usize = 320;
const H: usize = 240;
const ROUNDS: usize = 15;
const PER_ROUND: usize = 40;

fn thread_cpu() -> Duration {
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(Duration::from)
        .unwrap_or_default()
}

/// One sink's renderers: view and data node.
struct SinkRenderers {
    view: ViewRenderer,
    data: ViewRenderer,
}

impl SinkRenderers {
    fn new() -> Self {
        Self {
            view: ViewRenderer::new(640, 480, PixelFormat::Yuyv),
            data: ViewRenderer::new(W, H, PixelFormat::Y16),
        }
    }

    /// What a sink did before: render both pictures itself.
    fn alone(&mut self, f: &OutFrame) -> usize {
        let v = self
            .view
            .render(&f.output, &f.display)
            .map_or(0, <[u8]>::len);
        v + self
            .data
            .render_signed_dn(&f.output.signed_dn)
            .map_or(0, <[u8]>::len)
    }

    /// What a sink does now: ask the frame.
    fn shared(&mut self, f: &OutFrame) -> usize {
        let v = f.view(&mut self.view).map_or(0, |b| b.len());
        v + f.signed_dn(&mut self.data).map_or(0, |b| b.len())
    }
}

fn output(separation: bool) -> ModeOutput {
    let mut out = ModeOutput::new(W, H);
    let img = |k: f32| Image {
        width: W,
        height: H,
        data: (0..W * H)
            .map(|i| ((i % W) as f32 - 160.0) * k + (i / W) as f32)
            .collect(),
    };
    out.signed_dn = img(3.0);
    if separation {
        out.channels = Some(SeparatedChannels {
            i_plus_electrons: img(5.0),
            i_minus_electrons: img(-2.0),
            i_plus_se_electrons: img(0.1),
            i_minus_se_electrons: img(0.1),
        });
    }
    out
}

/// Mean CPU ms per frame of `f` over one round.
fn round(mut f: impl FnMut() -> usize) -> f64 {
    let c0 = thread_cpu();
    let mut bytes = 0;
    for _ in 0..PER_ROUND {
        bytes += f();
    }
    std::hint::black_box(bytes);
    (thread_cpu() - c0).as_secs_f64() * 1e3 / PER_ROUND as f64
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    println!(
        "{:<34} {:>10} {:>12} {:>12} {:>8} {:>8}",
        "output (320x240 -> 640x480 YUYV + Y16)",
        "one sink",
        "two, alone",
        "two, shared",
        "alone/1",
        "shared/1"
    );
    for (name, mode, separation) in [
        ("signed image (depth-edge)", ModeId::DepthEdge, false),
        ("separated channels (separation)", ModeId::Separation, true),
    ] {
        let out = output(separation);
        let frame = || OutFrame::new(out.clone(), mode, DisplayMap::default());
        let (mut a, mut b, mut c) = (
            SinkRenderers::new(),
            SinkRenderers::new(),
            SinkRenderers::new(),
        );
        let mut d = SinkRenderers::new();
        let (mut one, mut alone, mut shared) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..ROUNDS {
            one.push(round(|| a.alone(&frame())));
            alone.push(round(|| {
                let f = frame();
                a.alone(&f) + b.alone(&f)
            }));
            shared.push(round(|| {
                let f = frame();
                c.shared(&f) + d.shared(&f)
            }));
        }
        let (one, alone, shared) = (median(one), median(alone), median(shared));
        println!(
            "{name:<34} {one:>8.3}ms {alone:>10.3}ms {shared:>10.3}ms {:>7.2}x {:>7.2}x",
            alone / one,
            shared / one
        );
    }
}
