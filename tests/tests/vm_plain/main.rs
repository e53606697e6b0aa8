//! The VM tests that run in the plain guest (the harness's init, no udevd
//! or system bus until a test starts its own), as one test binary booting
//! one guest: each file is a module, each test of [`GUEST`] runs in
//! the guest in a sandbox of its own (`tests/vm/guest-run`). Run one with
//! `cargo test -p sdi-tests --test vm_plain -- board::` (the guest boots
//! for the selected tests only). Map and budget: tests/README.md.

mod board;
mod board_daemon;
mod board_hostile;
mod cameras_loopback;
mod chromium_pipewire;
mod daemon;
mod dbus_activation;
mod dbus_policy;
mod doctor;
mod gstreamer;
mod hotplug;
mod loopback;
mod path_races;
mod pipewire;
mod smoke;
mod two_boards;
mod v4l2loopback_config;

use sdi_tests::vm::{self, Guest};

/// Every test of this binary that runs in the guest, with its own time
/// limit in seconds, in the order the guest runs them.
static GUEST: Guest = Guest::new(&[
    ("smoke::vm_boots_and_loads_modules", 180),
    (
        "v4l2loopback_config::plain_modprobe_creates_the_sdi_camera",
        180,
    ),
    (
        "hotplug::board_hotplug_tags_device_for_systemd_and_group",
        240,
    ),
    ("dbus_policy::policy_controls_who_may_do_what", 240),
    (
        "dbus_activation::sdictl_status_starts_sdid_by_activation",
        240,
    ),
    (
        "path_races::vm_races_against_a_root_sdid_without_systemd",
        900,
    ),
    ("doctor::vm_doctor_with_the_module_and_faults", 300),
    (
        "board::backend_replug_without_hotplug_events_is_found_by_the_bus_scan",
        600,
    ),
    ("board::opt8241_backend_against_usb_emulator", 600),
    (
        "board::uvc_switch_that_never_comes_back_is_a_typed_timeout",
        600,
    ),
    (
        "board::backend_replug_with_udevd_is_found_by_a_hotplug_event",
        600,
    ),
    (
        "board_daemon::sdid_auto_picks_the_board_survives_unplug_and_follows_on_unplug",
        900,
    ),
    (
        "board_daemon::sdid_switches_a_uvc_mode_board_to_bulk_mode_and_streams",
        600,
    ),
    (
        "two_boards::two_boards_are_two_cameras_and_one_replugged_costs_the_other_nothing",
        600,
    ),
    (
        "two_boards::a_board_plugged_in_later_is_a_new_camera_and_costs_the_first_nothing",
        600,
    ),
    (
        "two_boards::a_board_with_an_odd_serial_is_named_safely",
        300,
    ),
    (
        "two_boards::a_board_that_cannot_be_opened_costs_the_others_nothing",
        300,
    ),
    ("daemon::vm_daemon_on_loopback_while_modes_switch", 600),
    ("gstreamer::vm_gstreamer_reads_both_nodes", 400),
    ("loopback::vm_loopback_end_to_end", 900),
    ("loopback::vm_loopback_module_switch", 300),
    (
        "cameras_loopback::vm_two_cameras_on_their_own_labelled_nodes",
        300,
    ),
    (
        "cameras_loopback::vm_sdid_adds_each_cameras_nodes_once",
        400,
    ),
    (
        "pipewire::vm_pipewire_lists_the_sdi_camera_in_both_orders",
        1200,
    ),
    // Chromium on sdid's PipeWire camera, no module: here rather than in
    // vm_desktop to balance CI's two VM lanes (tests/README.md), so this
    // guest has the desktop guest's RAM.
    (
        "chromium_pipewire::vm_chromium_reads_the_pipewire_camera_through_the_portal",
        900,
    ),
    // Last: its 1 s reply bound failed once (a SetColormap took 1.15 s)
    // while CI's build and host tests still ran beside both guests; by
    // now they are done. The cause is not yet known.
    (
        "board_hostile::sdid_survives_hostile_boards_and_streams_the_genuine_one_again",
        600,
    ),
])
.with_mem_mb(vm::DESKTOP_MEM_MB)
.prepared_by(prepare);

/// The guest runs the programs the host built (`SDID`, `SDICTL`).
fn prepare() -> bool {
    sdi_tests::dbus::export_bins();
    true
}
