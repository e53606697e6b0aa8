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

/// Declares an enum named by strings: the common derives (comparison, hash,
/// strum's name table with `FromStr`, `Display`, `&'static str`, the list of
/// names, iteration and doc messages), serde through that table, `NAMES`
/// and `name()`. The
/// caller's `#[strum(...)]` sets the spelling and the parse error; the
/// caller's crate depends on `strum`, which the derives name.
#[macro_export]
macro_rules! named_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $name:ident { $($(#[$vmeta:meta])* $variant:ident),+ $(,)? }
    ) => {
        #[derive(
            Debug,
            Clone,
            Copy,
            PartialEq,
            Eq,
            Hash,
            strum::EnumString,
            strum::Display,
            strum::IntoStaticStr,
            strum::VariantNames,
            strum::EnumIter,
            strum::EnumMessage,
        )]
        $(#[$meta])*
        $vis enum $name { $($(#[$vmeta])* $variant),+ }

        $crate::serde_by_name!($name);

        impl $name {
            /// Every name, in declaration order.
            pub const NAMES: &'static [&'static str] =
                <Self as strum::VariantNames>::VARIANTS;

            /// The name, as parsed and shown.
            pub fn name(self) -> &'static str {
                self.into()
            }
        }
    };
}
