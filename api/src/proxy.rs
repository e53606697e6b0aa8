//! The client side of `org.sdi.Camera1`: every method, property and signal,
//! with the typed replies of [`crate::types`] and errors as [`SdiError`].
//!
//! The declarations below are written once and expand into three things
//! that therefore cannot drift apart: the zbus proxy [`Camera1Proxy`],
//! [`Properties`] (every property read at once, for `sdictl status` and
//! `get`) and [`members`] (each member's D-Bus name and signature, which
//! `tests/tests/integration/dbus_contract.rs` compares with the served introspection).

use zbus::proxy;
use zbus::zvariant::{Fd, OwnedValue, SerializeDict, Type, Value};

use std::collections::HashMap;

use crate::contract::{bus_name, Member};
use crate::types::{
    CalibrationReply, DarkFrameReply, JobProgress, PhaseCalibrationReply, RecordingReply, Stats,
};
use crate::SdiError;

/// Declares the interface once: the proxy trait, [`Properties`] and [`members`].
macro_rules! camera1 {
    (
        methods {
            $( $(#[doc = $mdoc:literal])*
               fn $method:ident(&self $(, $arg:ident: $arg_ty:ty)*) -> $reply:ty; )*
        }
        properties {
            $( $(#[doc = $pdoc:literal])*
               fn $prop:ident(&self) -> $prop_ty:ty; )*
        }
        signals {
            $( $(#[doc = $sdoc:literal])*
               fn $signal:ident(&self $(, $sarg:ident: $sarg_ty:ty)*); )*
        }
    ) => {
        #[proxy(
            interface = "org.sdi.Camera1",
            default_service = "org.sdi.Daemon",
            default_path = "/org/sdi/Camera0"
        )]
        pub trait Camera1 {
            $( $(#[doc = $mdoc])*
               fn $method(&self $(, $arg: $arg_ty)*) -> Result<$reply, SdiError>; )*
            $( $(#[doc = $pdoc])*
               #[zbus(property)]
               fn $prop(&self) -> zbus::Result<$prop_ty>; )*
            $( $(#[doc = $sdoc])*
               #[zbus(signal)]
               fn $signal(&self $(, $sarg: $sarg_ty)*) -> zbus::Result<()>; )*
        }

        /// Every property of the interface, read through [`Camera1Proxy`].
        /// On the wire (and in `sdictl --json status`) a dictionary keyed by
        /// the property names.
        #[derive(Debug, Clone, PartialEq, SerializeDict, Type)]
        #[zvariant(signature = "a{sv}", rename_all = "PascalCase")]
        pub struct Properties {
            $( $(#[doc = $pdoc])* pub $prop: $prop_ty, )*
        }

        impl Properties {
            /// Reads every property.
            pub async fn read(camera: &Camera1Proxy<'_>) -> zbus::Result<Self> {
                Ok(Self { $( $prop: camera.$prop().await?, )* })
            }

            /// Every property's name, as on the bus.
            pub fn names() -> Vec<String> {
                vec![$( bus_name(stringify!($prop)), )*]
            }

            /// Reads the property called `name` on the bus, as the D-Bus
            /// value it is; None when there is no such property.
            pub async fn read_one(
                camera: &Camera1Proxy<'_>,
                name: &str,
            ) -> Option<zbus::Result<OwnedValue>> {
                $( if name == bus_name(stringify!($prop)) {
                    let value = camera.$prop().await;
                    return Some(value.and_then(|v| Ok(OwnedValue::try_from(Value::new(v))?)));
                } )*
                None
            }
        }

        /// Every member the proxy declares, with its D-Bus name and signature.
        pub fn members() -> Vec<Member> {
            vec![
                $( Member::method(
                    stringify!($method),
                    &[$(<$arg_ty as Type>::SIGNATURE),*],
                    <$reply as Type>::SIGNATURE,
                ), )*
                $( Member::property(stringify!($prop), <$prop_ty as Type>::SIGNATURE), )*
                $( Member::signal(stringify!($signal), &[$(<$sarg_ty as Type>::SIGNATURE),*]), )*
            ]
        }
    };
}

camera1! {
    methods {
        /// Switches the mode; returns (sequence, timestamp_us) of its first
        /// frame, once published (docs/dbus.md, "Setting changes").
        fn set_mode(&self, mode: &str) -> (u64, u64);
        /// Exposure per frame, microseconds; returns the first frame as `set_mode`.
        fn set_exposure_us(&self, exposure_us: f64) -> (u64, u64);
        /// Frame rate, Hz; returns the first frame as `set_mode`.
        fn set_frame_rate(&self, frame_rate_hz: f64) -> (u64, u64);
        /// Carrier frequency, Hz; returns the first frame as `set_mode`.
        fn set_modulation_hz(&self, modulation_hz: f64) -> (u64, u64);
        /// "diverging" or "grey"; returns the first frame as `set_mode`.
        fn set_colormap(&self, colormap: &str) -> (u64, u64);
        /// |DN| at full scale, 0 = auto; returns the first frame as `set_mode`.
        fn set_range(&self, max_abs_dn: f64) -> (u64, u64);
        /// Averages `frames` frames with the sources off into the dark frame.
        fn capture_dark_frame(&self, frames: u32) -> DarkFrameReply;
        /// Dark frame, then photon transfer (docs/dbus.md).
        fn calibrate(&self, frames: u32) -> CalibrationReply;
        /// The board's phase axis from `frames` frames of LS1 alone; stored,
        /// used from then on (docs/dbus.md).
        fn calibrate_phase(&self, frames: u32) -> PhaseCalibrationReply;
        /// Records into a new `<state dir>/NAME.sdirec` the daemon creates.
        fn start_recording(&self, path: &str) -> ();
        /// Records into the caller's empty file; `label` is what `Recording` shows.
        fn start_recording_to_fd(&self, fd: Fd<'_>, label: &str) -> ();
        fn stop_recording(&self) -> RecordingReply;
        /// Writes the latest frame into a new `<state dir>/NAME.png|.npy`.
        fn snapshot(&self, path: &str) -> ();
        /// Writes the latest frame into the caller's empty file, `png` or `npy`.
        fn snapshot_to_fd(&self, fd: Fd<'_>, format: &str) -> ();
        /// Writes every mode output into the caller's pipe or socket
        /// (`frame_stream`'s format) until the caller closes it or leaves
        /// the bus; a slow reader loses frames, never delays sdid. At most
        /// 2 streams per connection, 4 in all.
        fn stream_frames(&self, fd: Fd<'_>) -> ();
        /// Cancels the running job (its call ends with `Cancelled`); the
        /// job's name, "" when none runs.
        fn cancel(&self) -> String;
    }
    properties {
        /// Current mode name.
        fn mode(&self) -> String;
        /// All mode names.
        fn modes(&self) -> Vec<String>;
        /// The physical setup the current mode expects: {ls1, ls2, optics}.
        fn setup(&self) -> HashMap<String, String>;
        /// The backend delivering frames: "sim", "replay", "opt8241".
        fn backend(&self) -> String;
        /// The camera's name among several: the board's USB serial, `sim-N`
        /// for the simulator.
        fn serial(&self) -> String;
        /// The simulator's scene; "" when the frames come from elsewhere.
        fn scene(&self) -> String;
        /// "sensor -> output".
        fn device(&self) -> String;
        /// The sink publishing the output: "loopback", "pipewire" or "y4m".
        fn sink(&self) -> String;
        /// Output pixel format.
        fn format(&self) -> String;
        fn width(&self) -> u32;
        fn height(&self) -> u32;
        /// Frames per second, Hz.
        fn frame_rate(&self) -> f64;
        fn exposure_us(&self) -> f64;
        fn modulation_hz(&self) -> f64;
        fn colormap(&self) -> String;
        /// |DN| at full scale; 0 = symmetric auto range.
        fn range(&self) -> f64;
        /// Path or label being recorded to, "" when not recording.
        fn recording(&self) -> String;
        fn stats(&self) -> Stats;
        /// The ranges the setters accept, by property name: "ExposureUs",
        /// "FrameRate", "ModulationHz" -> (min, max); the board's own while
        /// it is the source.
        fn limits(&self) -> HashMap<String, (f64, f64)>;
        /// The job holding the camera and its progress ({name, frames_done,
        /// frames_total}; name "" when none).
        fn job(&self) -> JobProgress;
    }
    signals {
        /// The daemon stopped a recording by itself (size limit, free-space
        /// floor, disk full); `reason` says which.
        fn recording_stopped(&self, path: &str, reason: &str, frames: u64);
    }
}
