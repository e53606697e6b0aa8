//! Scene parameters set by name (`--scene-param key=value`): every field of
//! a [`SceneSpec`] but its kind and source placement, the scene's defaults
//! for the rest. Done through the spec's own serde form, so the keys are
//! the field names and there is no second list of them to keep in step.

use super::SceneSpec;
use crate::sensor::ParamError;

/// Why a scene parameter was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneParamError {
    #[error("scene parameter '{0}': expected key=value")]
    Syntax(String),
    #[error("scene {scene} has no parameter '{key}'; its parameters: {keys}")]
    UnknownKey {
        scene: &'static str,
        key: String,
        keys: String,
    },
    #[error("scene parameter {key}: '{value}' is not {want}")]
    BadValue {
        key: String,
        value: String,
        want: &'static str,
    },
    #[error("scene parameter {0}")]
    OutOfRange(#[from] ParamError),
}

/// Keys that select the scene rather than parameterize it.
const FIXED: [&str; 2] = ["kind", "placement"];

impl SceneSpec {
    /// The names of this scene's parameters (with their current values).
    pub fn params(&self) -> Vec<(String, String)> {
        match toml::Value::try_from(self) {
            Ok(toml::Value::Table(t)) => t
                .into_iter()
                .filter(|(k, _)| !FIXED.contains(&k.as_str()))
                .map(|(k, v)| (k, v.to_string()))
                .collect(),
            _ => Vec::new(),
        }
    }

    /// This scene with `key=value` settings applied in order, validated.
    pub fn with_params<S: AsRef<str>>(&self, settings: &[S]) -> Result<Self, SceneParamError> {
        let Ok(toml::Value::Table(mut table)) = toml::Value::try_from(self) else {
            return Err(SceneParamError::Syntax("scene not representable".into()));
        };
        let keys = || {
            self.params()
                .into_iter()
                .map(|(k, v)| format!("{k} (default {v})"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for setting in settings {
            let setting = setting.as_ref();
            let (key, value) = setting
                .split_once('=')
                .map(|(k, v)| (k.trim(), v.trim()))
                .filter(|(k, v)| !k.is_empty() && !v.is_empty())
                .ok_or_else(|| SceneParamError::Syntax(setting.to_owned()))?;
            let bad = |want| SceneParamError::BadValue {
                key: key.to_owned(),
                value: value.to_owned(),
                want,
            };
            let slot = table
                .get_mut(key)
                .filter(|_| !FIXED.contains(&key))
                .ok_or_else(|| SceneParamError::UnknownKey {
                    scene: self.name(),
                    key: key.to_owned(),
                    keys: keys(),
                })?;
            *slot = match slot {
                toml::Value::Float(_) => value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .map(toml::Value::Float)
                    .ok_or_else(|| bad("a finite number"))?,
                toml::Value::Integer(_) => value
                    .parse::<u32>()
                    .map(|v| toml::Value::Integer(i64::from(v)))
                    .map_err(|_| bad("a whole number from 0 to 4294967295"))?,
                _ => return Err(bad("settable")),
            };
        }
        let spec: SceneSpec = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| SceneParamError::Syntax(e.to_string()))?;
        spec.validate()?;
        Ok(spec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneId;

    #[test]
    fn defaults_stay_and_named_parameters_change() {
        let d = SceneSpec::from_name("depth-edge").unwrap();
        assert_eq!(d.with_params::<&str>(&[]).unwrap(), d);
        let s = d.with_params(&["source_spacing_mm=250"]).unwrap();
        match s {
            SceneSpec::DepthEdge {
                source_spacing_mm,
                source_electrons_per_us,
                ..
            } => {
                assert_eq!(source_spacing_mm, 250.0);
                assert_eq!(source_electrons_per_us, 12.0);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(s.name(), "depth-edge");
        let f = SceneSpec::from_name("fan-pellets")
            .unwrap()
            .with_params(&["fan_rpm = 300", "pellets=3"])
            .unwrap();
        assert!(matches!(f, SceneSpec::FanPellets { fan_rpm, pellets: 3, .. } if fan_rpm == 300.0));
        let b = SceneSpec::from_name("birefringent")
            .unwrap()
            .with_params(&["displacement_px=2.5"])
            .unwrap();
        assert!(
            matches!(b, SceneSpec::Birefringent { displacement_px, .. } if displacement_px == 2.5)
        );
    }

    #[test]
    fn every_scene_lists_its_parameters_and_refuses_bad_ones() {
        for name in SceneId::NAMES {
            let s = SceneSpec::from_name(name).unwrap();
            assert!(!s.params().is_empty(), "{name}");
            let e = s.with_params(&["no_such=1"]).unwrap_err();
            assert!(matches!(e, SceneParamError::UnknownKey { .. }), "{e}");
            assert!(s.with_params(&["kind=flat-field"]).is_err());
            for (k, _) in s.params() {
                for v in ["nan", "inf", "-inf", "1e9", "x", ""] {
                    let setting = format!("{k}={v}");
                    assert!(s.with_params(&[&setting]).is_err(), "{setting} on {name}");
                }
            }
        }
        let f = SceneSpec::from_name("flat-field").unwrap();
        assert!(f.with_params(&["ls1_electrons_per_us=-1"]).is_err());
        assert!(f.with_params(&["ls1_electrons_per_us=0"]).is_ok());
        let p = SceneSpec::from_name("fan-pellets").unwrap();
        assert!(p.with_params(&["pellets=-1"]).is_err());
        assert!(p.with_params(&["pellets=2.5"]).is_err());
        let d = SceneSpec::from_name("depth-edge").unwrap();
        assert!(d.with_params(&["placement=vertical"]).is_err());
        assert!(matches!(
            d.with_params(&["source_spacing_mm"]),
            Err(SceneParamError::Syntax(_))
        ));
    }
}
