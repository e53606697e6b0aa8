//! USB identity of the TI OPT8241-CDK ("TintinCDK" in TI's Voxel SDK).
//!
//! Kept in one place: `udev/board-ids` lists the same IDs for the udev rules
//! (parsed by `sdi_api::board_ids`), and a unit test checks that both agree.

/// Texas Instruments.
pub const VENDOR_ID: u16 = 0x0451;
/// Vendor-specific bulk mode: registers over vendor requests, frames on bulk IN.
pub const PRODUCT_ID_BULK: u16 = 0x9105;
/// UVC mode (registers through UVC extension unit 3); sdid switches it to
/// bulk mode (`usb::switch_and_wait`).
pub const PRODUCT_ID_UVC: u16 = 0x9106;
/// Interface carrying the bulk IN endpoint in bulk mode.
pub const INTERFACE: u8 = 0;

pub use sdi_api::board_ids::{board_ids, BOARD_IDS_FILE};

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
