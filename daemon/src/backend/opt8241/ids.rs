//! USB identity of the TI OPT8241-CDK ("TintinCDK" in TI's Voxel SDK).
//!
//! Kept in one place: `udev/board-ids` lists the same IDs for the udev rules,
//! and a unit test checks that both agree.

/// Texas Instruments.
pub const VENDOR_ID: u16 = 0x0451;
/// Vendor-specific bulk mode: registers over vendor requests, frames on bulk IN.
pub const PRODUCT_ID_BULK: u16 = 0x9105;
/// UVC mode (registers through UVC extension unit 3); sdid switches it to
/// bulk mode (`usb::switch_and_wait`).
pub const PRODUCT_ID_UVC: u16 = 0x9106;
/// Interface carrying the bulk IN endpoint in bulk mode.
pub const INTERFACE: u8 = 0;

/// The `udev/board-ids` file, for tools that generate rules from it.
pub const BOARD_IDS_FILE: &str = include_str!("../../../../udev/board-ids");

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn udev_board_ids_file_matches_constants() {
        let ids = board_ids();
        assert_eq!(
            ids,
            vec![
                (VENDOR_ID, PRODUCT_ID_BULK, "bulk"),
                (VENDOR_ID, PRODUCT_ID_UVC, "uvc")
            ]
        );
    }
}
