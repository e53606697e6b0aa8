//! The settings a client changes (`sdictl set NAME VALUE`): one table of
//! their names, the property each shows in and the method that sets it.

use std::num::ParseFloatError;

use strum::IntoEnumIterator;

use crate::{Camera1Proxy, SdiError};

/// A setting that changes the picture; its name is the kebab-case variant
/// (`exposure-us`), its property the PascalCase one (`ExposureUs`), its
/// method `Set` and the property (`SetExposureUs`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, strum::Display, strum::IntoStaticStr, strum::EnumIter,
)]
#[strum(serialize_all = "kebab-case")]
pub enum Setting {
    Mode,
    ExposureUs,
    FrameRate,
    ModulationHz,
    Colormap,
    Range,
}

/// What a setting's value is: a number, or a name sdid checks (a mode, a
/// colormap).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SettingKind {
    Number,
    Name,
}

/// A name that is no setting, or a value that is not a number.
#[derive(Debug, thiserror::Error)]
pub enum SettingError {
    #[error("'{0}' cannot be set; settable: {names}", names = Setting::names().join(", "))]
    Unknown(String),
    #[error("{setting}: '{value}' is not a number")]
    NotANumber {
        setting: Setting,
        value: String,
        #[source]
        source: ParseFloatError,
    },
}

/// A setting with its new value, ready to send.
#[derive(Debug, Clone, PartialEq)]
pub enum Change {
    Mode(String),
    ExposureUs(f64),
    FrameRate(f64),
    ModulationHz(f64),
    Colormap(String),
    Range(f64),
}

impl Setting {
    /// Every setting, in the table's order.
    pub fn all() -> impl Iterator<Item = Setting> {
        Setting::iter()
    }

    /// Every setting's name, in the table's order.
    pub fn names() -> Vec<&'static str> {
        Setting::all().map(<&'static str>::from).collect()
    }

    /// The setting a person names: `exposure-us`, `exposure_us` or
    /// `ExposureUs`; `frame-rate-hz` as sdid's flag spells it.
    pub fn from_user(name: &str) -> Result<Self, SettingError> {
        let wanted = squash(name);
        Setting::iter()
            .find(|s| squash(s.property_name()) == wanted)
            .or_else(|| (wanted == "frameratehz").then_some(Setting::FrameRate))
            .ok_or_else(|| SettingError::Unknown(name.to_owned()))
    }

    /// The D-Bus property that shows the setting.
    pub fn property_name(self) -> &'static str {
        match self {
            Setting::Mode => "Mode",
            Setting::ExposureUs => "ExposureUs",
            Setting::FrameRate => "FrameRate",
            Setting::ModulationHz => "ModulationHz",
            Setting::Colormap => "Colormap",
            Setting::Range => "Range",
        }
    }

    /// What a person reads beside the setting's control: what it is, with
    /// its unit (`exposure (us)`).
    pub fn label(self) -> &'static str {
        match self {
            Setting::Mode => "mode",
            Setting::ExposureUs => "exposure (us)",
            Setting::FrameRate => "frame rate (Hz)",
            Setting::ModulationHz => "modulation (Hz)",
            Setting::Colormap => "colormap",
            Setting::Range => "range (DN, 0 auto)",
        }
    }

    /// Whether the value is a number or a name ([`change`](Self::change)
    /// parses it so).
    pub fn kind(self) -> SettingKind {
        match self {
            Setting::Mode | Setting::Colormap => SettingKind::Name,
            Setting::ExposureUs | Setting::FrameRate | Setting::ModulationHz | Setting::Range => {
                SettingKind::Number
            }
        }
    }

    /// `value` as this setting's type: a name for the mode and colormap
    /// (sdid checks it), a number for the rest.
    pub fn change(self, value: &str) -> Result<Change, SettingError> {
        let number = || {
            value
                .parse::<f64>()
                .map_err(|source| SettingError::NotANumber {
                    setting: self,
                    value: value.to_owned(),
                    source,
                })
        };
        Ok(match self {
            Setting::Mode => Change::Mode(value.to_owned()),
            Setting::Colormap => Change::Colormap(value.to_owned()),
            Setting::ExposureUs => Change::ExposureUs(number()?),
            Setting::FrameRate => Change::FrameRate(number()?),
            Setting::ModulationHz => Change::ModulationHz(number()?),
            Setting::Range => Change::Range(number()?),
        })
    }
}

impl Change {
    /// Sends the change; (sequence, timestamp_us) of the first frame under it.
    pub async fn send(&self, camera: &Camera1Proxy<'_>) -> Result<(u64, u64), SdiError> {
        match self {
            Change::Mode(name) => camera.set_mode(name).await,
            Change::ExposureUs(us) => camera.set_exposure_us(*us).await,
            Change::FrameRate(hz) => camera.set_frame_rate(*hz).await,
            Change::ModulationHz(hz) => camera.set_modulation_hz(*hz).await,
            Change::Colormap(name) => camera.set_colormap(name).await,
            Change::Range(dn) => camera.set_range(*dn).await,
        }
    }
}

/// Lower case without `-` and `_`: the spellings a person uses compare equal.
fn squash(name: &str) -> String {
    name.chars()
        .filter(|c| !matches!(c, '-' | '_'))
        .map(|c| c.to_ascii_lowercase())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_spelling_names_one_setting() {
        for s in Setting::iter() {
            let kebab = s.to_string();
            assert_eq!(Setting::from_user(&kebab).unwrap(), s);
            assert_eq!(Setting::from_user(&kebab.replace('-', "_")).unwrap(), s);
            assert_eq!(Setting::from_user(s.property_name()).unwrap(), s);
        }
        assert_eq!(
            Setting::from_user("frame-rate-hz").unwrap(),
            Setting::FrameRate
        );
        let e = Setting::from_user("width").unwrap_err().to_string();
        assert!(e.contains("exposure-us, frame-rate"), "{e}");
    }

    #[test]
    fn numbers_parse_and_names_pass() {
        assert_eq!(Setting::Range.change("0").unwrap(), Change::Range(0.0));
        assert_eq!(
            Setting::Mode.change("raw").unwrap(),
            Change::Mode("raw".into())
        );
        let e = Setting::ExposureUs.change("fast").unwrap_err().to_string();
        assert_eq!(e, "exposure-us: 'fast' is not a number");
    }

    /// `kind` says what `change` parses: a number setting refuses a word, a
    /// name setting passes it on; every setting has a label.
    #[test]
    fn the_kind_is_what_change_parses() {
        for s in Setting::iter() {
            assert!(!s.label().is_empty(), "{s}");
            let word = s.change("fast");
            match s.kind() {
                SettingKind::Number => {
                    assert!(word.is_err(), "{s}");
                    assert!(s.change("2.5").is_ok(), "{s}");
                }
                SettingKind::Name => assert!(word.is_ok(), "{s}"),
            }
        }
    }

    /// Each setting's property and `Set` method exist in the proxy.
    #[test]
    fn each_setting_has_its_property_and_setter() {
        let members = crate::proxy::members();
        for s in Setting::iter() {
            for name in [
                s.property_name().to_owned(),
                format!("Set{}", s.property_name()),
            ] {
                assert!(members.iter().any(|m| m.name == name), "{name}");
            }
        }
    }
}
