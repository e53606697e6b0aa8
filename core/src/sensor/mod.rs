//! The ToF pixel: parameters, presets and the Skellam mixing matrix H (section 3).

pub mod description;
mod params;
mod presets;
mod skellam;

pub use description::{mixing_with_adc, SensorDescription};
pub(crate) use params::check;
pub use params::{ParamError, SensorParams, FRAME_RATE_RANGE_HZ};
pub use presets::SensorPreset;
pub use skellam::SkellamMixing;
