//! sdid: captures frames from a backend, runs the chosen mode's pipeline,
//! publishes the result on an output sink, and serves the D-Bus API.
//!
//! Data flows one way: backend -> frame_loop (pipeline) -> sink / recorder;
//! D-Bus talks to the frame loop only through its command channel.
#![forbid(unsafe_code)]

pub mod args;
pub mod backend;
pub mod bus;
pub mod calibration_store;
pub mod camera_plan;
pub mod cause_log;
pub mod dark_capture;
pub mod dbus;
pub mod fanout;
pub mod frame_loop;
pub mod frame_stream;
pub mod job;
pub mod light;
pub mod logging;
pub mod monotonic;
pub mod out_frame;
pub mod phase_calibration;
pub mod photon_transfer;
pub mod publish_clock;
pub mod queue;
pub mod recorder;
pub mod sink;
pub mod snapshot;
pub mod startup;
pub mod stats;
