//! Enums named by strings have one table each: strum's derives (`EnumString`,
//! `Display`, `VariantNames`) built from the variant names; serde goes through
//! that same table with [`serde_by_name!`](crate::serde_by_name), so a config
//! file, a command line and a D-Bus call accept exactly the same names.

/// Implements `Serialize` (the `Display` name) and `Deserialize` (through
/// `FromStr`, its error as the message) for a type named by strings.
#[macro_export]
macro_rules! serde_by_name {
    ($t:ty) => {
        impl $crate::named::serde::Serialize for $t {
            fn serialize<S: $crate::named::serde::Serializer>(
                &self,
                s: S,
            ) -> Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }
        impl<'de> $crate::named::serde::Deserialize<'de> for $t {
            fn deserialize<D: $crate::named::serde::Deserializer<'de>>(
                d: D,
            ) -> Result<Self, D::Error> {
                let s = <String as $crate::named::serde::Deserialize>::deserialize(d)?;
                s.parse().map_err($crate::named::serde::de::Error::custom)
            }
        }
    };
}

#[doc(hidden)]
pub use serde;
