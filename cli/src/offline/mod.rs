//! Offline tools: run the imaging core without the daemon.

pub mod board_plan;
pub mod frames;
pub mod noise_report;
pub mod report_files;
pub mod sensor_arg;
pub mod separate;
pub mod separation_report;
pub mod sim;
pub mod sim_truth;
