//! The host integration tests that need neither a VM, root, nor a quiet
//! machine, as one test binary: linking one binary instead of one per file
//! is most of what building the tests costs. Each file stays a module, so a
//! test is found as `cargo test -p sdi-tests --test integration -- FILE::NAME`.
//! Timing checks and races (`dbus_fair_share`, `daemon_frame_clock`,
//! `daemon_lights`, `pipewire_camera`, `soak`, `system_*`, `package_*`)
//! stay binaries of their own; the VM tests are one binary per guest
//! (`vm_plain`, `vm_desktop`, `vm_systemd`). Map: tests/README.md.

mod daemon_cameras;
mod daemon_in_process;
mod daemon_lifecycle;
mod daemon_recording;
mod daemon_y4m_fallback;
mod dbus_api;
mod dbus_bad_input;
mod dbus_contract;
mod dbus_fd_passing;
mod dbus_group_state_dir;
mod dbus_jobs;
mod dbus_path_methods;
mod dbus_separation;
mod dbus_setting_contract;
mod dbus_stream_slots;
mod dbus_wrong_input;
mod npy_numpy;
mod science_recording;
/// Helpers of the D-Bus test modules.
mod support;
mod view_connections;
mod view_page;
