//! Clap value parsers over the same types and ranges, so a command-line
//! override is parsed once, at the edge, exactly as the file's key is.

use std::str::FromStr;

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use sdi_core::sensor::capture_range::CaptureRange;
use strum::{EnumMessage, IntoEnumIterator};

/// A choice among an enum's names (its other spellings, such as "gray", are
/// accepted as aliases); `--help` lists the names.
pub fn choice<T>() -> impl TypedValueParser<Value = T>
where
    T: IntoEnumIterator + EnumMessage + Into<&'static str> + FromStr + Clone,
    T: Send + Sync + 'static,
    <T as FromStr>::Err: std::fmt::Display,
{
    let values = T::iter().map(|v| {
        let aliases = v.get_serializations();
        let name: &'static str = v.into();
        PossibleValue::new(name).aliases(aliases.iter().copied().filter(move |a| *a != name))
    });
    PossibleValuesParser::new(values).try_map(|s| s.parse::<T>().map_err(|e| e.to_string()))
}

/// A number within `range` (the same range the file and D-Bus use).
pub fn in_range(range: CaptureRange) -> impl Fn(&str) -> Result<f64, String> + Clone {
    move |s| {
        let v: f64 = s.parse().map_err(|e| format!("'{s}': {e}"))?;
        range.check(v).map_err(|e| e.to_string())
    }
}
