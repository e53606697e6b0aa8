//! Difference-imaging modes (section 5): what each expects physically and the
//! pipeline of stages it runs on every frame.

mod id;

pub use id::{ModeId, PhysicalSetup, UnknownMode};
