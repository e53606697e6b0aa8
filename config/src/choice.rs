//! Every choice among known names in `sdid.toml` and on `sdid`'s command line,
//! as an enum with one name table (strum's, kebab-case); serde reads and
//! writes the same names ([`sdi_core::named_enum!`]). Choices that are
//! science (`mode`, `scene`, `colormap`) are sdi-core's own enums.

/// A name that is none of a setting's choices.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {setting} '{given}': use {}", allowed.join(", "))]
pub struct UnknownName {
    /// The setting, as in `sdid.toml` (`backend`, `[lights] driver`).
    pub setting: &'static str,
    pub given: String,
    pub allowed: &'static [&'static str],
}

/// Declares a choice enum ([`sdi_core::named_enum!`], kebab-case names, a
/// default) with an [`UnknownName`] error naming `$setting`.
macro_rules! choice {
    (
        $(#[$meta:meta])*
        $setting:literal,
        pub enum $name:ident { $($(#[$vmeta:meta])* $variant:ident),+ $(,)? }
    ) => {
        sdi_core::named_enum! {
            $(#[$meta])*
            #[derive(Default)]
            #[strum(serialize_all = "kebab-case", parse_err_ty = UnknownName, parse_err_fn = $name::unknown)]
            pub enum $name { $($(#[$vmeta])* $variant),+ }
        }

        impl $name {
            fn unknown(given: &str) -> UnknownName {
                UnknownName {
                    setting: $setting,
                    given: given.to_owned(),
                    allowed: Self::NAMES,
                }
            }
        }
    };
}

choice! {
    /// `backend`: where frames come from.
    "backend",
    pub enum BackendKind {
        /// The board when one is attached, else the simulator.
        #[default]
        Auto,
        /// The simulator.
        Sim,
        /// A recording (`[replay] path`).
        Replay,
        /// The TI OPT8241-CDK.
        Opt8241,
    }
}

choice! {
    /// `[output] sink`: where processed frames are published.
    "[output] sink",
    pub enum SinkKind {
        /// v4l2loopback if present, else PipeWire if reachable, else y4m.
        #[default]
        Auto,
        Loopback,
        Pipewire,
        Y4m,
    }
}

choice! {
    /// `[board] on_unplug`: what sdid does while the board is unplugged.
    "[board] on_unplug",
    pub enum OnUnplug {
        /// Keep the output open with a "no signal" frame until the board is back.
        #[default]
        NoSignal,
        /// The simulator stands in until the board is back.
        Simulator,
        /// End sdid cleanly (status 0).
        Exit,
    }
}

choice! {
    /// `[lights] driver`: what drives LS1 and LS2 (docs/hardware.md).
    "[lights] driver",
    pub enum LightDriver {
        /// Nothing to drive.
        #[default]
        None,
        /// The board's own LED outputs.
        Board,
        /// A SCPI function generator over TCP (`address`).
        ScpiTcp,
        /// A SCPI function generator over USBTMC (`device`).
        Usbtmc,
        /// GPIO lines enabling the sources (`gpio_chip`, `ls1_line`, `ls2_line`).
        Gpio,
    }
}

choice! {
    /// `[separation] method`: the live separation mode's estimator (section 6).
    "[separation] method",
    pub enum SeparationMethod {
        /// M3: bilateral moments of every frame (moving scenes).
        #[default]
        M3,
        /// M1 over the last `window_frames` frames (static scenes).
        Window,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::IntoEnumIterator;

    fn round_trip<T>(names: &[&str])
    where
        T: IntoEnumIterator + std::str::FromStr<Err = UnknownName> + Copy + PartialEq,
        T: std::fmt::Debug + std::fmt::Display,
    {
        let all: Vec<T> = T::iter().collect();
        assert_eq!(all.len(), names.len());
        for (v, n) in all.into_iter().zip(names) {
            assert_eq!(v.to_string(), *n);
            assert_eq!(n.parse::<T>(), Ok(v));
        }
        let e = "No-Such".parse::<T>().unwrap_err();
        assert_eq!(e.given, "No-Such");
        assert!(e.to_string().contains(names[0]), "{e}");
    }

    #[test]
    fn every_choice_parses_its_names_and_only_those() {
        round_trip::<BackendKind>(&["auto", "sim", "replay", "opt8241"]);
        round_trip::<SinkKind>(&["auto", "loopback", "pipewire", "y4m"]);
        round_trip::<OnUnplug>(&["no-signal", "simulator", "exit"]);
        round_trip::<LightDriver>(&["none", "board", "scpi-tcp", "usbtmc", "gpio"]);
        round_trip::<SeparationMethod>(&["m3", "window"]);
        // Case matters: names are lower case, nothing else matches.
        assert!("Sim".parse::<BackendKind>().is_err());
        assert!("scpi_tcp".parse::<LightDriver>().is_err());
        let e = "m1".parse::<SeparationMethod>().unwrap_err().to_string();
        assert_eq!(e, "unknown [separation] method 'm1': use m3, window");
    }
}
