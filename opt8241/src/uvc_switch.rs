//! The request that switches a UVC-mode board (USB 0451:9106) to vendor
//! bulk mode (0451:9105): SET_CUR of the FX2 firmware's extension unit,
//! as bytes. sdid sends it (`daemon/src/backend/opt8241/usb.rs`,
//! `switch_to_bulk`); the fuzz target `usb_descriptors` builds it from
//! hostile descriptors.

/// UVC extension unit of the board's FX2 firmware (SDK
/// `TI3DToF/VoxelXUProgrammer.h`, `_XU_ID = 3`).
pub const UVC_XU_ID: u8 = 3;
/// Its control "reboot to firmware mode": the firmware re-enumerates as the
/// bulk-mode device (SDK `CONTROL_REBOOT_FW_MODE = 6`; FW `uvc.c`, case 6,
/// `RENUMERATE_UNCOND`).
pub const XU_CONTROL_REBOOT_FW_MODE: u8 = 6;
/// UVC class request SET_CUR (UVC 1.1, table A-8).
pub const UVC_SET_CUR: u8 = 0x01;
/// bmRequestType of a class request to an interface, host to device (USB
/// 2.0, table 9-2: direction 0, type class 1 << 5, recipient interface 1).
pub const REQUEST_TYPE_CLASS_INTERFACE_OUT: u8 = 0x21;

/// One control request, as sent on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControlRequest {
    pub request_type: u8,
    pub request: u8,
    pub value: u16,
    pub index: u16,
    pub data: Vec<u8>,
}

impl std::fmt::Display for ControlRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "bmRequestType {:#04x} bRequest {:#04x} wValue {:#06x} wIndex {:#06x} data {:02x?}",
            self.request_type, self.request, self.value, self.index, self.data
        )
    }
}

/// SET_CUR of extension unit 3, control 6, to the VideoControl interface:
/// class request, recipient interface, wValue = control << 8, wIndex =
/// unit << 8 | interface, one data byte (its value is ignored by the
/// firmware; the SDK sends one byte, `VoxelXUProgrammer::reset`).
pub fn uvc_switch_request(video_control_interface: u8) -> ControlRequest {
    ControlRequest {
        request_type: REQUEST_TYPE_CLASS_INTERFACE_OUT,
        request: UVC_SET_CUR,
        value: u16::from(XU_CONTROL_REBOOT_FW_MODE) << 8,
        index: (u16::from(UVC_XU_ID) << 8) | u16::from(video_control_interface),
        data: vec![0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uvc_switch_request_is_set_cur_of_xu3_control6() {
        let r = uvc_switch_request(0);
        // class, interface recipient, host to device
        assert_eq!(r.request_type, 0x21);
        assert_eq!(r.request, 0x01);
        assert_eq!(r.value, 0x0600);
        assert_eq!(r.index, 0x0300);
        assert_eq!(r.data.len(), 1);
        assert_eq!(uvc_switch_request(2).index, 0x0302);
    }
}
