//! The physically faithful ToF simulator: scene -> wells -> readout -> ADC.
//!
//! Per pixel the wells collect Poisson counts with means
//! I+- = integral of (f | 1 - f)(t) g_i(t) dt (eq. wellmeasurement), clipped at
//! full well; the readout is D = rho * (eta * (N+ - N-) + n_read) (eq. pixeleff)
//! plus black level and fixed-pattern offset, then quantized and clipped by the
//! ADC. Moving scenes are integrated in sub-steps so motion inside one
//! exposure (temporal gradients, two-shot ghosting) comes out of the model.

use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, Poisson};

use crate::frame::Frame;
use crate::image::Image;
use crate::modulation::{Illumination, SourceDrive};
use crate::scene::{Radiance, Scene, SceneSpec};
use crate::sensor::{ParamError, SensorParams};

/// Everything needed to build a simulator run.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    pub sensor: SensorParams,
    pub scene: SceneSpec,
    /// Uniform ambient light, electrons per microsecond per pixel.
    pub ambient_electrons_per_us: f64,
    pub seed: u64,
    /// Integration sub-steps per exposure for moving scenes (static scenes use one).
    pub substeps: usize,
}

impl SimConfig {
    pub fn new(sensor: SensorParams, scene: SceneSpec) -> Self {
        Self {
            sensor,
            scene,
            ambient_electrons_per_us: 0.0,
            seed: 0,
            substeps: 16,
        }
    }
}

/// Expected well contents of one exposure, electrons: the ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct WellExpectation {
    pub i_plus_electrons: Image<f32>,
    pub i_minus_electrons: Image<f32>,
}

/// A simulated sensor looking at a scene.
pub struct Simulator {
    config: SimConfig,
    scene: Box<dyn Scene>,
    rng: SmallRng,
    fixed_pattern_dn: Image<f32>,
    radiance: Radiance,
    expected: WellExpectation,
    time_us: f64,
    sequence: u64,
}

impl Simulator {
    pub fn new(config: SimConfig) -> Result<Self, ParamError> {
        config.sensor.validate()?;
        let a = config.ambient_electrons_per_us;
        if !(a.is_finite() && a >= 0.0) {
            return Err(ParamError {
                name: "ambient_electrons_per_us",
                value: a,
                allowed: ">= 0",
            });
        }
        let (w, h) = (config.sensor.width, config.sensor.height);
        let scene = config.scene.build(w, h, config.seed);
        let mut rng = SmallRng::seed_from_u64(config.seed);
        let sigma = config.sensor.fixed_pattern_sigma_dn;
        let fixed_pattern_dn = match Normal::new(0.0f32, sigma as f32) {
            Ok(n) if sigma > 0.0 => Image {
                width: w,
                height: h,
                data: (0..w * h).map(|_| n.sample(&mut rng)).collect(),
            },
            _ => Image::new(w, h),
        };
        Ok(Self {
            scene,
            rng,
            fixed_pattern_dn,
            radiance: Radiance::default(),
            expected: WellExpectation {
                i_plus_electrons: Image::new(w, h),
                i_minus_electrons: Image::new(w, h),
            },
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

    /// Simulation clock: start of the next exposure, microseconds.
    pub fn time_us(&self) -> f64 {
        self.time_us
    }

    /// Expected well contents of the exposure most recently captured.
    pub fn last_expectation(&self) -> &WellExpectation {
        &self.expected
    }

    /// Integrates the expected well contents of an exposure starting at `t0_us`.
    pub fn expect_wells(&mut self, illumination: &Illumination, t0_us: f64) {
        let exposure_us = self.config.sensor.exposure_us;
        let steps = if self.scene.is_static() {
            1
        } else {
            self.config.substeps.max(1)
        };
        let dt_us = exposure_us / steps as f64;
        self.expected.i_plus_electrons.data.fill(0.0);
        self.expected.i_minus_electrons.data.fill(0.0);
        let ambient = self.config.ambient_electrons_per_us as f32;
        for k in 0..steps {
            let u0 = k as f64 / steps as f64;
            let u1 = (k + 1) as f64 / steps as f64;
            let duty = illumination.modulation.duty_over(u0, u1);
            let t_mid_us = t0_us + (k as f64 + 0.5) * dt_us;
            self.scene.render(t_mid_us, &mut self.radiance);
            let channels = [
                (self.radiance.ls1.as_ref(), illumination.ls1),
                (self.radiance.ls2.as_ref(), illumination.ls2),
                (self.radiance.ambient.as_ref(), SourceDrive::Constant),
            ];
            for (rate, drive) in channels {
                let (Some(rate), (fp, fm)) = (rate, drive.well_split(duty)) else {
                    continue;
                };
                let (wp, wm) = ((fp * dt_us) as f32, (fm * dt_us) as f32);
                if wp == 0.0 && wm == 0.0 {
                    continue;
                }
                let plus = &mut self.expected.i_plus_electrons.data;
                let minus = &mut self.expected.i_minus_electrons.data;
                for ((p, m), &r) in plus.iter_mut().zip(minus.iter_mut()).zip(&rate.data) {
                    *p += wp * r;
                    *m += wm * r;
                }
            }
            if ambient > 0.0 {
                let (fp, fm) = SourceDrive::Constant.well_split(duty);
                let (wp, wm) = ((fp * dt_us) as f32 * ambient, (fm * dt_us) as f32 * ambient);
                for p in &mut self.expected.i_plus_electrons.data {
                    *p += wp;
                }
                for m in &mut self.expected.i_minus_electrons.data {
                    *m += wm;
                }
            }
        }
    }

    /// Captures one frame: integrates the exposure, samples shot and read
    /// noise, digitizes, and advances the clock by one frame period.
    pub fn capture(&mut self, illumination: &Illumination, out: &mut Frame) {
        let p = &self.config.sensor;
        let (w, h) = (p.width, p.height);
        if out.width() != w || out.height() != h {
            *out = Frame::new(w, h);
        }
        let t0_us = self.time_us;
        self.expect_wells(illumination, t0_us);
        let p = &self.config.sensor;
        let rho = p.conversion_gain_dn_per_electron;
        let eta = p.demodulation_contrast;
        let full_well = p.full_well_electrons;
        let (lo, hi) = p.adc_range_dn();
        let read = Normal::new(0.0, p.read_noise_electrons).ok();
        let offset = p.adc_offset_dn;
        for i in 0..w * h {
            let np = poisson(&mut self.rng, self.expected.i_plus_electrons.data[i] as f64);
            let nm = poisson(
                &mut self.rng,
                self.expected.i_minus_electrons.data[i] as f64,
            );
            let (np, nm) = (np.min(full_well), nm.min(full_well));
            let well_full = np >= full_well || nm >= full_well;
            let n_read = read.map_or(0.0, |n| n.sample(&mut self.rng));
            let d =
                rho * (eta * (np - nm) + n_read) + offset + self.fixed_pattern_dn.data[i] as f64;
            let code = d.round();
            let clipped = code < lo || code > hi;
            out.dn.data[i] = code.clamp(lo, hi) as f32;
            out.saturated.data[i] = u8::from(well_full || clipped);
        }
        out.timestamp_us = t0_us as u64;
        out.sequence = self.sequence;
        self.sequence += 1;
        self.time_us += 1e6 / p.frame_rate_hz;
    }
}

fn poisson(rng: &mut SmallRng, mean: f64) -> f64 {
    if mean <= 0.0 || !mean.is_finite() {
        return 0.0;
    }
    match Poisson::new(mean) {
        Ok(d) => d.sample(rng),
        // Beyond the sampler's range the Poisson is Gaussian to far below a DN.
        Err(_) => mean.round(),
    }
}
