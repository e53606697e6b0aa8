//! USB identities of the boards sdid drives, parsed from `udev/board-ids`
//! (the one list; the udev rules are generated from it). Here, not in the
//! daemon's USB backend, so that `sdictl doctor` finds boards without
//! linking libusb.

/// The `udev/board-ids` file.
pub const BOARD_IDS_FILE: &str = include_str!("../../udev/board-ids");

/// (vendor, product, mode) triples parsed from [`BOARD_IDS_FILE`].
pub fn board_ids() -> Vec<(u16, u16, &'static str)> {
    BOARD_IDS_FILE
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .filter_map(|l| {
            // Columns: vendor product mode description...
            let mut cols = l.split_whitespace();
            let vendor = u16::from_str_radix(cols.next()?, 16).ok()?;
            let product = u16::from_str_radix(cols.next()?, 16).ok()?;
            Some((vendor, product, cols.next()?))
        })
        .collect()
}
