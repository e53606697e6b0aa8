//! The physically faithful ToF simulator: scene -> wells -> readout -> ADC.
//!
//! Per pixel the wells collect Poisson counts with means
//! I+- = integral of (f | 1 - f)(t) g_i(t) dt (eq. wellmeasurement,
//! eq. poissonstats), clipped at full well; the readout is
//! D = rho * (eta * (N+ - N-) + n_read) (eq. pixeleff, eq. skellamvar) plus
//! the ADC black level and a per-pixel fixed-pattern offset, then quantized
//! and clipped by the ADC. Light uncorrelated with f (ambient, `Constant`
//! sources) splits between the wells by the duty of f: under the 50/50 square
//! wave it cancels in the mean and adds shot noise. Moving scenes are
//! integrated over the exposure so motion inside it (temporal gradients,
//! two-shot ghosting) comes out of the model: per segment of the modulation
//! from the scene's own time average ([`Scene::render_mean`], closed form
//! where it can), else in sub-steps.
//!
//! [`Frame::dn`] holds the ADC code minus the (known, constant) black-level
//! offset; the per-pixel fixed pattern stays in, as on the real sensor: dark
//! frames ([`Simulator::capture_dark`]) measure it for subtraction.
//!
//! Speed: static scenes keep their expected wells and per-pixel readout plan
//! (see [`readout`]) for each recently used illumination, so a frame costs one
//! random draw per bright pixel.

pub mod light_travel;
pub mod poisson;
pub mod readout;
mod run;

pub use run::{
    run_config, SimRun, SimRunError, MAX_AMBIENT_ELECTRONS_PER_US, MAX_DARK_FRAMES,
    MAX_EXPOSURE_US, MAX_FRAMES,
};

use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::frame::Frame;
use crate::image::Image;
use crate::modulation::{Illumination, SourceDrive};
use crate::scene::{Radiance, Scene, SceneSpec};
use crate::sensor::{ParamError, SensorParams};
use readout::ReadoutPlan;

/// Everything needed to build a simulator run.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    pub sensor: SensorParams,
    pub scene: SceneSpec,
    /// Uniform ambient light, electrons per microsecond per pixel.
    pub ambient_electrons_per_us: f64,
    pub seed: u64,
    /// Sub-steps per exposure for moving scenes that cannot integrate
    /// themselves, and point samples for the parts of those that can but
    /// sample (static scenes use one).
    pub substeps: usize,
    /// Light travel time (`light_travel`): where the scene has depth, a
    /// square-wave-modulated source's light arrives delayed by 2 depth / c
    /// and part of it lands in the other well.
    pub light_travel: bool,
}

impl SimConfig {
    pub fn new(sensor: SensorParams, scene: SceneSpec) -> Self {
        Self {
            sensor,
            scene,
            ambient_electrons_per_us: 0.0,
            seed: 0,
            substeps: 16,
            light_travel: true,
        }
    }

    /// Rejects bad sensor parameters, scene parameters, ambient and sub-steps.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.sensor.validate()?;
        self.scene.validate()?;
        let a = self.ambient_electrons_per_us;
        if !(a.is_finite() && a >= 0.0) {
            return Err(ParamError {
                name: "ambient_electrons_per_us",
                value: a,
                allowed: "finite, >= 0",
            });
        }
        if !(1..=4096).contains(&self.substeps) {
            return Err(ParamError {
                name: "substeps",
                value: self.substeps as f64,
                allowed: "1..=4096",
            });
        }
        Ok(())
    }
}

/// Expected well contents of one exposure, electrons: the ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct WellExpectation {
    pub i_plus_electrons: Image<f32>,
    pub i_minus_electrons: Image<f32>,
}

impl WellExpectation {
    fn zeros(width: usize, height: usize) -> Self {
        Self {
            i_plus_electrons: Image::new(width, height),
            i_minus_electrons: Image::new(width, height),
        }
    }
}

/// Expected wells and readout plan for one illumination.
struct CacheEntry {
    /// `None` for a moving scene (recomputed every frame).
    illumination: Option<Illumination>,
    expected: WellExpectation,
    plan: ReadoutPlan,
    plan_valid: bool,
}

/// How many illuminations a static scene keeps precomputed (two-shot
/// alternates two, plus dark frames).
const CACHE_ENTRIES: usize = 3;

/// A simulated sensor looking at a scene.
pub struct Simulator {
    config: SimConfig,
    scene: Box<dyn Scene>,
    rng: SmallRng,
    fixed_pattern_dn: Image<f32>,
    radiance: Radiance,
    /// True once `radiance` holds a static scene's (time-independent) rates.
    radiance_static: bool,
    cache: Vec<CacheEntry>,
    current: usize,
    time_us: f64,
    sequence: u64,
    /// Per-pixel depth of the scene, metres, when light travel is simulated
    /// and the scene has depth.
    depth_m: Option<Image<f32>>,
}

impl Simulator {
    /// Validates the configuration (NaN, negative ambient, bad scene or
    /// sensor parameters are rejected) and builds the scene and the fixed
    /// pattern, both deterministic given the seed.
    pub fn new(config: SimConfig) -> Result<Self, ParamError> {
        config.validate()?;
        let (w, h) = (config.sensor.width, config.sensor.height);
        let scene = config.scene.build(w, h, config.seed);
        // Separate streams: the fixed pattern does not depend on how many
        // noise draws happen, and vice versa.
        let mut fpn_rng = SmallRng::seed_from_u64(config.seed ^ 0x005E_EDF1_ED0F_F5E7);
        let sigma = config.sensor.fixed_pattern_sigma_dn;
        let fixed_pattern_dn = match Normal::new(0.0f32, sigma as f32) {
            Ok(n) if sigma > 0.0 => Image {
                width: w,
                height: h,
                data: (0..w * h).map(|_| n.sample(&mut fpn_rng)).collect(),
            },
            _ => Image::new(w, h),
        };
        let depth_m = if config.light_travel {
            scene.depth_m()
        } else {
            None
        };
        Ok(Self {
            depth_m,
            scene,
            rng: SmallRng::seed_from_u64(config.seed),
            fixed_pattern_dn,
            radiance: Radiance::default(),
            radiance_static: false,
            cache: vec![CacheEntry {
                illumination: None,
                expected: WellExpectation::zeros(w, h),
                plan: ReadoutPlan::default(),
                plan_valid: false,
            }],
            current: 0,
            time_us: 0.0,
            sequence: 0,
            config,
        })
    }

    pub fn params(&self) -> &SensorParams {
        &self.config.sensor
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// True when the scene does not move (one expectation serves every frame).
    pub fn scene_is_static(&self) -> bool {
        self.scene.is_static()
    }

    /// Simulation clock: start of the next exposure, microseconds.
    pub fn time_us(&self) -> f64 {
        self.time_us
    }

    /// The per-pixel fixed-pattern offset, DN (ground truth for dark frames).
    pub fn fixed_pattern_dn(&self) -> &Image<f32> {
        &self.fixed_pattern_dn
    }

    /// Expected well contents of the exposure most recently captured (or
    /// integrated by [`Simulator::expect_wells`]).
    pub fn last_expectation(&self) -> &WellExpectation {
        &self.cache[self.current].expected
    }

    /// Integrates the expected well contents of an exposure starting at
    /// `t0_us` (eq. wellmeasurement); [`Simulator::last_expectation`] then
    /// returns them. Static scenes reuse earlier results for the same
    /// illumination.
    pub fn expect_wells(&mut self, illumination: &Illumination, t0_us: f64) {
        let is_static = self.scene.is_static();
        if is_static {
            if let Some(i) = self
                .cache
                .iter()
                .position(|e| e.illumination.as_ref() == Some(illumination))
            {
                self.current = i;
                return;
            }
            self.current = if self.cache.len() < CACHE_ENTRIES {
                let (w, h) = (self.config.sensor.width, self.config.sensor.height);
                self.cache.push(CacheEntry {
                    illumination: None,
                    expected: WellExpectation::zeros(w, h),
                    plan: ReadoutPlan::default(),
                    plan_valid: false,
                });
                self.cache.len() - 1
            } else {
                // Evict the entry after the current one (round robin).
                (self.current + 1) % CACHE_ENTRIES
            };
        }
        self.integrate(illumination, t0_us, is_static);
        let entry = &mut self.cache[self.current];
        entry.illumination = is_static.then(|| illumination.clone());
        entry.plan_valid = false;
    }

    /// The sub-stepped integration of a moving scene's exposure (a render
    /// at the middle of each of `substeps` steps), whatever the scene can do
    /// in closed form: the reference [`Simulator::expect_wells`] is tested
    /// and benchmarked against.
    pub fn expect_wells_substepped(&mut self, illumination: &Illumination, t0_us: f64) {
        if self.scene.is_static() {
            return self.expect_wells(illumination, t0_us);
        }
        self.integrate_substeps(illumination, t0_us, false);
        self.cache[self.current].plan_valid = false;
    }

    fn integrate(&mut self, illumination: &Illumination, t0_us: f64, is_static: bool) {
        if is_static || !self.integrate_segments(illumination, t0_us) {
            self.integrate_substeps(illumination, t0_us, is_static);
        }
    }

    /// Moving scenes: one mean render per segment of the modulation (f
    /// constant, or a carrier much faster than the scene), from the scene's
    /// own time integration. False if the scene cannot integrate.
    fn integrate_segments(&mut self, illumination: &Illumination, t0_us: f64) -> bool {
        let exposure_us = self.config.sensor.exposure_us;
        let substeps = self.config.substeps.max(1);
        let expected = &mut self.cache[self.current].expected;
        expected.i_plus_electrons.data.fill(0.0);
        expected.i_minus_electrons.data.fill(0.0);
        for seg in &illumination.modulation.segments {
            let (u0, u1) = (seg.start.max(0.0), seg.end.min(1.0));
            if u1 <= u0 {
                continue;
            }
            // As many samples as the sub-steps this segment spans.
            let samples = ((u1 - u0) * substeps as f64).round().max(1.0) as usize;
            let (ta, tb) = (t0_us + u0 * exposure_us, t0_us + u1 * exposure_us);
            if !self.scene.render_mean(ta, tb, samples, &mut self.radiance) {
                return false;
            }
            let duty = seg.duty.clamp(0.0, 1.0);
            accumulate(
                expected,
                &self.radiance,
                illumination,
                duty,
                tb - ta,
                self.config.ambient_electrons_per_us,
                travel(self.depth_m.as_ref(), illumination),
            );
        }
        self.radiance_static = false;
        true
    }

    fn integrate_substeps(&mut self, illumination: &Illumination, t0_us: f64, is_static: bool) {
        let exposure_us = self.config.sensor.exposure_us;
        let steps = if is_static {
            1
        } else {
            self.config.substeps.max(1)
        };
        let dt_us = exposure_us / steps as f64;
        let ambient = self.config.ambient_electrons_per_us;
        let expected = &mut self.cache[self.current].expected;
        expected.i_plus_electrons.data.fill(0.0);
        expected.i_minus_electrons.data.fill(0.0);
        for k in 0..steps {
            let u0 = k as f64 / steps as f64;
            let u1 = (k + 1) as f64 / steps as f64;
            let duty = illumination.modulation.duty_over(u0, u1);
            if !(is_static && self.radiance_static) {
                let t_mid_us = t0_us + (k as f64 + 0.5) * dt_us;
                self.scene.render(t_mid_us, &mut self.radiance);
                self.radiance_static = is_static;
            }
            let delay = travel(self.depth_m.as_ref(), illumination);
            accumulate(
                expected,
                &self.radiance,
                illumination,
                duty,
                dt_us,
                ambient,
                delay,
            );
        }
    }

    /// Captures one frame: integrates the exposure, samples shot and read
    /// noise, digitizes, and advances the clock by one frame period.
    pub fn capture(&mut self, illumination: &Illumination, out: &mut Frame) {
        self.prepare(illumination, out);
        self.sample(out);
    }

    /// Like [`Simulator::capture`], but a moving scene's exposure comes from
    /// [`Simulator::expect_wells_substepped`]: the previous path, kept as
    /// the reference the closed-form motion is benchmarked against.
    pub fn capture_substepped(&mut self, illumination: &Illumination, out: &mut Frame) {
        let (w, h) = (self.config.sensor.width, self.config.sensor.height);
        if out.width() != w || out.height() != h {
            *out = Frame::new(w, h);
        }
        self.expect_wells_substepped(illumination, self.time_us);
        self.sample(out);
    }

    /// Noise, readout and clock advance for the current expectation.
    fn sample(&mut self, out: &mut Frame) {
        let entry = &mut self.cache[self.current];
        if !entry.plan_valid {
            entry.plan.rebuild(
                &self.config.sensor,
                &entry.expected.i_plus_electrons.data,
                &entry.expected.i_minus_electrons.data,
                &self.fixed_pattern_dn.data,
            );
            entry.plan_valid = true;
        }
        entry.plan.sample(&self.config.sensor, &mut self.rng, out);
        self.advance(out);
    }

    /// A dark ("black") frame: both sources off, same exposure and
    /// modulation. It holds the fixed pattern, read noise and, if there is
    /// ambient light, its shot noise (section 4, measurement procedure).
    pub fn capture_dark(&mut self, out: &mut Frame) {
        let dark = Illumination::dark(self.config.sensor.modulation_hz);
        self.capture(&dark, out);
    }

    /// Like [`Simulator::capture`], but samples every pixel literally with
    /// `rand_distr`'s Poisson (two draws) and Normal (one draw), without the
    /// readout plan. Slow; kept as the reference the fast path is checked
    /// and benchmarked against.
    pub fn capture_reference(&mut self, illumination: &Illumination, out: &mut Frame) {
        self.prepare(illumination, out);
        let entry = &self.cache[self.current];
        readout::sample_reference(
            &self.config.sensor,
            &entry.expected.i_plus_electrons,
            &entry.expected.i_minus_electrons,
            &self.fixed_pattern_dn,
            &mut self.rng,
            out,
        );
        self.advance(out);
    }

    fn prepare(&mut self, illumination: &Illumination, out: &mut Frame) {
        let (w, h) = (self.config.sensor.width, self.config.sensor.height);
        if out.width() != w || out.height() != h {
            *out = Frame::new(w, h);
        }
        self.expect_wells(illumination, self.time_us);
    }

    fn advance(&mut self, out: &mut Frame) {
        out.timestamp_us = self.time_us as u64;
        out.sequence = self.sequence;
        self.sequence += 1;
        self.time_us += 1e6 / self.config.sensor.frame_rate_hz;
    }
}

/// The depth map and carrier when light travel applies to `illumination`:
/// a 50/50 square wave over the whole exposure (the delayed-square-wave
/// split of [`light_travel::wrong_well_fraction`] holds for it alone).
fn travel<'a>(
    depth: Option<&'a Image<f32>>,
    illumination: &Illumination,
) -> Option<(&'a Image<f32>, f64)> {
    let m = &illumination.modulation;
    let square =
        matches!(m.segments[..], [seg] if seg.start <= 0.0 && seg.end >= 1.0 && seg.duty == 0.5);
    depth.filter(|_| square).map(|d| (d, m.carrier_hz))
}

/// Adds the wells' share of `dt_us` of the rates in `radiance` (and the
/// uniform ambient) at mean duty `duty` of f (eq. wellmeasurement). With
/// `delay` (depth, carrier), a modulated source's light at a pixel of depth
/// z arrives 2 z / c late and fraction w of it lands in the other well
/// ([`light_travel::delayed_wells`]); unmodulated light is unaffected.
fn accumulate(
    expected: &mut WellExpectation,
    radiance: &Radiance,
    illumination: &Illumination,
    duty: f64,
    dt_us: f64,
    ambient_electrons_per_us: f64,
    delay: Option<(&Image<f32>, f64)>,
) {
    let channels = [
        (radiance.ls1.as_ref(), illumination.ls1),
        (radiance.ls2.as_ref(), illumination.ls2),
        (radiance.ambient.as_ref(), SourceDrive::Constant),
    ];
    let plus = &mut expected.i_plus_electrons.data;
    let minus = &mut expected.i_minus_electrons.data;
    for (rate, drive) in channels {
        let (Some(rate), (fp, fm)) = (rate, drive.well_split(duty)) else {
            continue;
        };
        let (wp, wm) = ((fp * dt_us) as f32, (fm * dt_us) as f32);
        if wp == 0.0 && wm == 0.0 {
            continue;
        }
        match delay.filter(|_| drive != SourceDrive::Constant) {
            Some((depth, carrier_hz)) => {
                let px = plus.iter_mut().zip(minus.iter_mut()).zip(&rate.data);
                for (((p, m), &r), &z) in px.zip(&depth.data) {
                    let w = light_travel::wrong_well_fraction(2.0 * f64::from(z), carrier_hz);
                    let (dp, dm) = light_travel::delayed_wells(f64::from(wp), f64::from(wm), w);
                    *p += dp as f32 * r;
                    *m += dm as f32 * r;
                }
            }
            None => {
                for ((p, m), &r) in plus.iter_mut().zip(minus.iter_mut()).zip(&rate.data) {
                    *p += wp * r;
                    *m += wm * r;
                }
            }
        }
    }
    if ambient_electrons_per_us > 0.0 {
        // Uniform ambient: uncorrelated with f, split by the duty.
        let (fp, fm) = SourceDrive::Constant.well_split(duty);
        let a = ambient_electrons_per_us;
        let (wp, wm) = ((fp * dt_us * a) as f32, (fm * dt_us * a) as f32);
        plus.iter_mut().for_each(|p| *p += wp);
        minus.iter_mut().for_each(|m| *m += wm);
    }
}
