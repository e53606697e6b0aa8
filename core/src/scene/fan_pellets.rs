//! Temporal-gradient scene (section 5.4, Figs. tempgrad_fan and teaser b): a
//! rotating fan on the left, white pellets falling and bouncing on the floor
//! on the right, lit only by ambient light (no active source).
//!
//! Everything moves in closed form as a function of time, so the simulator's
//! integration of eq. wellmeasurement with the single-transition pattern
//! produces the gradient: an edge that arrives during the exposure (leading
//! edge) is brighter late, landing in I+, a trailing edge in I-. Edges are
//! anti-aliased (coverage from the signed distance in pixels). The fan's
//! time average is exact (`render_mean`); pellets are sampled.

use multiversion::multiversion;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::{Radiance, Scene};
use crate::image::Image;

/// Standard gravity, metres per second squared.
const GRAVITY_M_PER_S2: f32 = 9.81;
/// Fraction of the speed a pellet keeps at each bounce.
const RESTITUTION: f32 = 0.6;
/// Pellets restart their drop every this many seconds.
const DROP_PERIOD_S: f32 = 1.5;
/// Number of blades and the fraction of each angular period a blade covers.
const BLADES: usize = 5;
const BLADE_FRACTION: f32 = 0.4;
/// Rate of the lit floor relative to the objects.
const FLOOR_FRACTION: f32 = 0.25;

/// Scene parameters (see `SceneSpec::FanPellets`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FanPelletsParams {
    pub background_electrons_per_us: f32,
    pub object_electrons_per_us: f32,
    pub fan_rpm: f32,
    pub pellets: usize,
}

#[derive(Debug, Clone, Copy)]
struct Pellet {
    x_px: f32,
    drop_height_px: f32,
    phase_s: f32,
    /// Lies still on the floor.
    resting: bool,
}

/// A fan pixel: its index, radius and angle in units of blade periods.
#[derive(Debug, Clone, Copy)]
struct FanPixel {
    index: usize,
    radius_px: f32,
    turns: f32,
}

pub struct FanPellets {
    width: usize,
    height: usize,
    params: FanPelletsParams,
    /// Static part (wall and floor), electrons per microsecond.
    base: Vec<f32>,
    fan_pixels: Vec<FanPixel>,
    fan_centre_px: (f32, f32),
    fan_radius_px: f32,
    hub_radius_px: f32,
    floor_y_px: f32,
    pellet_radius_px: f32,
    gravity_px_per_s2: f32,
    pellets: Vec<Pellet>,
    /// Per fan pixel (same order as `fan_pixels`), for [`Scene::render_mean`].
    blades: FanBlades,
    /// Scratch for the pellets' time-averaged coverage, one per pixel.
    pellet_now: Vec<f32>,
    pellet_sum: Vec<f32>,
    pellet_boxes: Vec<PelletBox>,
}

/// Fan pixels as plain arrays, so the closed-form blade average vectorizes.
#[derive(Default)]
struct FanBlades {
    /// Runs of consecutive frame indices: (first index, first fan pixel, length).
    rows: Vec<(usize, usize, usize)>,
    turns: Vec<f32>,
    /// Arc length of one blade period at this radius, pixels per turn.
    px_per_turn: Vec<f32>,
    rim: Vec<f32>,
    hub: Vec<f32>,
    /// Fan pixels whose coverage is not rim * blade or hub alone (the edge
    /// of the hub, or radii under 2 px): averaged from point samples.
    sampled: Vec<usize>,
}

/// Pixel box a pellet touched: x0, x1, y0, y1 (exclusive ends).
type PelletBox = [usize; 4];

impl FanPellets {
    pub fn new(width: usize, height: usize, params: FanPelletsParams, seed: u64) -> Self {
        let (w, h) = (width as f32, height as f32);
        let floor_y_px = 0.92 * h;
        let pixels_per_m = 2.0 * h;
        let pellet_radius_px = (0.02 * h).max(1.5);
        let mut rng = SmallRng::seed_from_u64(seed ^ 0x00FA_4BE1_1E75);
        let pellets = (0..params.pellets)
            .map(|i| Pellet {
                x_px: rng.random_range(0.6..0.95) * w,
                drop_height_px: rng.random_range(0.3..0.8) * floor_y_px,
                phase_s: rng.random_range(0.0..DROP_PERIOD_S),
                resting: i % 4 == 3,
            })
            .collect();
        let mut s = Self {
            width,
            height,
            params,
            base: Vec::new(),
            fan_pixels: Vec::new(),
            fan_centre_px: (0.3 * w, 0.45 * h),
            fan_radius_px: 0.38 * h,
            hub_radius_px: 0.07 * h,
            floor_y_px,
            pellet_radius_px,
            gravity_px_per_s2: GRAVITY_M_PER_S2 * pixels_per_m,
            pellets,
            blades: FanBlades::default(),
            pellet_now: Vec::new(),
            pellet_sum: Vec::new(),
            pellet_boxes: Vec::new(),
        };
        s.base = (0..width * height)
            .map(|i| s.static_rate((i % width) as f32 + 0.5, (i / width) as f32 + 0.5))
            .collect();
        s.fan_pixels = (0..width * height)
            .filter_map(|i| {
                let (x, y) = ((i % width) as f32 + 0.5, (i / width) as f32 + 0.5);
                let (dx, dy) = (x - s.fan_centre_px.0, y - s.fan_centre_px.1);
                let radius_px = (dx * dx + dy * dy).sqrt();
                (radius_px < s.fan_radius_px + 1.0).then(|| FanPixel {
                    index: i,
                    radius_px,
                    turns: dy.atan2(dx) / std::f32::consts::TAU * BLADES as f32,
                })
            })
            .collect();
        s.blades = s.fan_blades();
        s
    }

    fn fan_blades(&self) -> FanBlades {
        let mut b = FanBlades::default();
        for (j, f) in self.fan_pixels.iter().enumerate() {
            match b.rows.last_mut() {
                Some((first, _, len)) if *first + *len == f.index => *len += 1,
                _ => b.rows.push((f.index, j, 1)),
            }
            let px_per_turn = std::f32::consts::TAU / BLADES as f32 * f.radius_px;
            let hub = (self.hub_radius_px - f.radius_px + 0.5).clamp(0.0, 1.0);
            b.turns.push(f.turns);
            b.px_per_turn.push(px_per_turn);
            b.rim
                .push((self.fan_radius_px - f.radius_px + 0.5).clamp(0.0, 1.0));
            b.hub.push(hub);
            // The closed form needs ramps shorter than half a blade (2.5 px per turn).
            if hub < 1.0 && (hub > 0.0 || px_per_turn < 2.5) {
                b.sampled.push(j);
            }
        }
        b
    }

    /// Blade rotation at `t_us`, in blade periods (fraction in [0, 1)).
    fn rotation(&self, t_us: f64) -> f64 {
        (t_us * 1e-6 * self.params.fan_rpm as f64 / 60.0 * BLADES as f64).fract()
    }

    fn static_rate(&self, _x: f32, y: f32) -> f32 {
        let p = &self.params;
        let floor = (y - self.floor_y_px + 0.5).clamp(0.0, 1.0);
        p.background_electrons_per_us
            + floor * FLOOR_FRACTION * (p.object_electrons_per_us - p.background_electrons_per_us)
    }

    /// Fan coverage in [0, 1] of a pixel at radius `radius_px` and angle
    /// `turns` (blade periods) at time `t_us`; blades turn clockwise on screen.
    fn fan_coverage(&self, radius_px: f32, turns: f32, t_us: f64) -> f32 {
        let rotation = (t_us * 1e-6 * self.params.fan_rpm as f64 / 60.0 * BLADES as f64).fract();
        let phase = (turns - rotation as f32).rem_euclid(1.0);
        let inside = phase < BLADE_FRACTION;
        let d_turns = if inside {
            phase.min(BLADE_FRACTION - phase)
        } else {
            -(phase - BLADE_FRACTION).min(1.0 - phase)
        };
        let arc_px = d_turns * std::f32::consts::TAU / BLADES as f32 * radius_px;
        let blade = (arc_px + 0.5).clamp(0.0, 1.0);
        let hub = (self.hub_radius_px - radius_px + 0.5).clamp(0.0, 1.0);
        let rim = (self.fan_radius_px - radius_px + 0.5).clamp(0.0, 1.0);
        (blade * rim).max(hub)
    }

    /// Centre of pellet `i` at time `t_us`, pixels, and its vertical speed
    /// (pixels per second, positive downwards).
    pub fn pellet_state(&self, i: usize, t_us: f64) -> (f32, f32, f32) {
        let p = self.pellets[i];
        let rest_y = self.floor_y_px - self.pellet_radius_px;
        if p.resting {
            return (p.x_px, rest_y, 0.0);
        }
        let g = self.gravity_px_per_s2;
        let tau = ((t_us * 1e-6) as f32 + p.phase_s).rem_euclid(DROP_PERIOD_S);
        let t_fall = (2.0 * p.drop_height_px / g).sqrt();
        if tau < t_fall {
            return (
                p.x_px,
                rest_y - p.drop_height_px + 0.5 * g * tau * tau,
                g * tau,
            );
        }
        let (mut t0, mut v) = (t_fall, g * t_fall * RESTITUTION);
        loop {
            let flight = 2.0 * v / g;
            if flight < 1e-3 {
                return (p.x_px, rest_y, 0.0);
            }
            if tau < t0 + flight {
                let dt = tau - t0;
                return (p.x_px, rest_y - (v * dt - 0.5 * g * dt * dt), g * dt - v);
            }
            t0 += flight;
            v *= RESTITUTION;
        }
    }

    pub fn pellet_count(&self) -> usize {
        self.pellets.len()
    }

    /// Photoelectron rate at pixel (x, y) at time `t_us`, electrons per
    /// microsecond: what `render` writes, pixel by pixel.
    pub fn rate_at(&self, x: usize, y: usize, t_us: f64) -> f32 {
        let i = y * self.width + x;
        let mut coverage = 0.0f32;
        let (xc, yc) = (x as f32 + 0.5, y as f32 + 0.5);
        let (dx, dy) = (xc - self.fan_centre_px.0, yc - self.fan_centre_px.1);
        let r = (dx * dx + dy * dy).sqrt();
        if r < self.fan_radius_px + 1.0 {
            let turns = dy.atan2(dx) / std::f32::consts::TAU * BLADES as f32;
            coverage = self.fan_coverage(r, turns, t_us);
        }
        for k in 0..self.pellets.len() {
            let (px, py, _) = self.pellet_state(k, t_us);
            coverage = coverage.max(disc_coverage(x, y, px, py, self.pellet_radius_px));
        }
        self.mix(self.base[i], coverage)
    }

    /// `out` as ambient light only, holding the still background; the
    /// ambient image is reused when it has the size.
    fn background_into<'a>(&self, out: &'a mut Radiance) -> &'a mut Image<f32> {
        out.ls1 = None;
        out.ls2 = None;
        let img = super::reuse(out.ambient.take(), self.width, self.height);
        let buf = out.ambient.insert(img);
        buf.data.copy_from_slice(&self.base);
        buf
    }

    #[inline]
    fn mix(&self, base: f32, coverage: f32) -> f32 {
        base + coverage * (self.params.object_electrons_per_us - base)
    }
}

impl FanPellets {
    /// Pellet coverage averaged over the sample times, merged into `out`
    /// like [`Scene::render`] merges it at one instant.
    fn pellets_mean(&mut self, samples: usize, sample_t: &dyn Fn(usize) -> f64, out: &mut [f32]) {
        let (w, h, r) = (self.width, self.height, self.pellet_radius_px);
        self.pellet_now.resize(w * h, 0.0);
        self.pellet_sum.resize(w * h, 0.0);
        self.pellet_boxes.clear();
        for j in 0..samples {
            let t_us = sample_t(j);
            let first_box = self.pellet_boxes.len();
            for k in 0..self.pellets.len() {
                let (px, py, _) = self.pellet_state(k, t_us);
                let [x0, x1, y0, y1] = pellet_box(px, py, r, w, h);
                for y in y0..y1 {
                    for x in x0..x1 {
                        let c = &mut self.pellet_now[y * w + x];
                        *c = c.max(disc_coverage(x, y, px, py, r));
                    }
                }
                self.pellet_boxes.push([x0, x1, y0, y1]);
            }
            // Add this instant's coverage (the max over pellets) once per pixel.
            for &[x0, x1, y0, y1] in &self.pellet_boxes[first_box..] {
                for y in y0..y1 {
                    let now = &mut self.pellet_now[y * w + x0..y * w + x1];
                    let sum = &mut self.pellet_sum[y * w + x0..y * w + x1];
                    for (s, c) in sum.iter_mut().zip(now) {
                        *s += std::mem::take(c);
                    }
                }
            }
        }
        let inv = 1.0 / samples as f32;
        let obj = self.params.object_electrons_per_us;
        for &[x0, x1, y0, y1] in &self.pellet_boxes {
            for y in y0..y1 {
                let i = y * w + x0..y * w + x1;
                let sum = &mut self.pellet_sum[i.clone()];
                for ((o, s), &b) in out[i.clone()].iter_mut().zip(sum).zip(&self.base[i]) {
                    let c = std::mem::take(s) * inv;
                    *o = o.max(b + c * (obj - b));
                }
            }
        }
    }
}

/// Mean rate over the interval for one run of fan pixels (see
/// [`Scene::render_mean`] for FanPellets): blade coverage from the
/// antiderivative of the trapezoid, times the rim, at least the hub.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
/// Pixels [x0, x1) x [y0, y1) a pellet at (px, py) of radius `r` can
/// touch, clipped to the `w` x `h` image.
fn pellet_box(px: f32, py: f32, r: f32, w: usize, h: usize) -> [usize; 4] {
    let x0 = (px - r - 1.0).floor().max(0.0) as usize;
    let y0 = (py - r - 1.0).floor().max(0.0) as usize;
    let x1 = ((px + r + 1.0).ceil() as usize).min(w);
    let y1 = ((py + r + 1.0).ceil() as usize).min(h);
    [x0, x1, y0, y1]
}

/// Fraction of pixel (x, y) a disc at (px, py) of radius `r` covers,
/// anti-aliased over one pixel from its edge.
#[inline]
fn disc_coverage(x: usize, y: usize, px: f32, py: f32, r: f32) -> f32 {
    let (xc, yc) = (x as f32 + 0.5, y as f32 + 0.5);
    let d = ((xc - px).powi(2) + (yc - py).powi(2)).sqrt();
    (r - d + 0.5).clamp(0.0, 1.0)
}

fn blade_row(
    out: &mut [f32],
    base: &[f32],
    (turns, px_per_turn): (&[f32], &[f32]),
    (rim, hub): (&[f32], &[f32]),
    (rot0, span, obj): (f32, f32, f32),
) {
    let n = out.len();
    let (base, turns, px_per_turn, rim, hub) = (
        &base[..n],
        &turns[..n],
        &px_per_turn[..n],
        &rim[..n],
        &hub[..n],
    );
    let point = span.abs() < 1e-4;
    for i in 0..n {
        let k = px_per_turn[i];
        let phi0 = turns[i] - rot0;
        let blade = if point {
            blade_at(phi0 - 0.5 * span, k)
        } else {
            (blade_integral(phi0, k) - blade_integral(phi0 - span, k)) / span
        };
        let c = (rim[i] * blade).max(hub[i]);
        out[i] = base[i] + c * (obj - base[i]);
    }
}

/// Blade coverage at phase `phi` (turns), `k` pixels per turn: the
/// anti-aliased distance to the nearest blade edge, as in `fan_coverage`.
#[inline(always)]
fn blade_at(phi: f32, k: f32) -> f32 {
    let phase = phi - phi.floor();
    let d_turns = if phase < BLADE_FRACTION {
        phase.min(BLADE_FRACTION - phase)
    } else {
        -(phase - BLADE_FRACTION).min(1.0 - phase)
    };
    (d_turns * k + 0.5).clamp(0.0, 1.0)
}

/// An antiderivative of [`blade_at`] in `phi` (exact for k >= 2.5 px per
/// turn, i.e. ramps inside their half blade): each whole period adds the
/// blade fraction; inside one, the signed distance d to the edge gives
/// `ramp(d)`, the integral of clamp(k d + 1/2, 0, 1).
#[inline(always)]
fn blade_integral(phi: f32, k: f32) -> f32 {
    let periods = phi.floor();
    let phase = phi - periods;
    let half = 0.5 / k;
    // ramp(s) = 0 below -half, k/2 (s + half)^2 across the edge, s above.
    let ramp = |s: f32| {
        let q = (s + half).clamp(0.0, 2.0 * half);
        0.5 * k * q * q + (s - half).max(0.0)
    };
    let f = BLADE_FRACTION;
    let within = if phase <= 0.5 * f {
        ramp(phase)
    } else if phase <= 0.5 * (1.0 + f) {
        f - ramp(f - phase)
    } else {
        f + ramp(phase - 1.0)
    };
    periods * f + within
}

impl Scene for FanPellets {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn is_static(&self) -> bool {
        false
    }

    /// Closed-form time average of the fan (the blade coverage is a
    /// periodic trapezoid in the blade phase, which moves linearly in time:
    /// its antiderivative gives the exact mean) plus the mean of `samples`
    /// point renders for the pellets (ballistic, with bounces) and the hub edge.
    fn render_mean(&mut self, t0_us: f64, t1_us: f64, samples: usize, out: &mut Radiance) -> bool {
        let buf = self.background_into(out);
        let samples = samples.max(1);
        let sample_t = |j: usize| t0_us + (j as f64 + 0.5) / samples as f64 * (t1_us - t0_us);
        // Blade phase phi = turns - rotation(t) falls by `span` turns.
        let rot0 = self.rotation(t0_us) as f32;
        let span =
            ((t1_us - t0_us) * 1e-6 * self.params.fan_rpm as f64 / 60.0 * BLADES as f64) as f32;
        let obj = self.params.object_electrons_per_us;
        let b = &self.blades;
        for &(first, j0, len) in &b.rows {
            let row = &mut buf.data[first..first + len];
            let base = &self.base[first..first + len];
            let range = j0..j0 + len;
            blade_row(
                row,
                base,
                (&b.turns[range.clone()], &b.px_per_turn[range.clone()]),
                (&b.rim[range.clone()], &b.hub[range]),
                (rot0, span, obj),
            );
        }
        for &j in &b.sampled {
            let f = self.fan_pixels[j];
            let mean = (0..samples)
                .map(|k| self.fan_coverage(f.radius_px, f.turns, sample_t(k)))
                .sum::<f32>()
                / samples as f32;
            buf.data[f.index] = self.mix(self.base[f.index], mean);
        }
        self.pellets_mean(samples, &sample_t, &mut buf.data);
        true
    }

    fn render(&self, t_us: f64, out: &mut Radiance) {
        let (w, h) = (self.width, self.height);
        let buf = self.background_into(out);
        for f in &self.fan_pixels {
            let c = self.fan_coverage(f.radius_px, f.turns, t_us);
            buf.data[f.index] = self.mix(self.base[f.index], c);
        }
        let r = self.pellet_radius_px;
        for k in 0..self.pellets.len() {
            let (px, py, _) = self.pellet_state(k, t_us);
            let [x0, x1, y0, y1] = pellet_box(px, py, r, w, h);
            for y in y0..y1 {
                for x in x0..x1 {
                    let c = disc_coverage(x, y, px, py, r);
                    let i = y * w + x;
                    let current = buf.data[i];
                    buf.data[i] = current.max(self.mix(self.base[i], c));
                }
            }
        }
    }
}
