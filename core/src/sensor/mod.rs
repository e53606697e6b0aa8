//! The ToF pixel: parameters, presets and the Skellam mixing matrix H (section 3).

mod params;
mod presets;
mod skellam;

pub(crate) use params::check;
pub use params::{ParamError, SensorParams};
pub use presets::SensorPreset;
pub use skellam::SkellamMixing;
