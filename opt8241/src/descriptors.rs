//! Choices sdid makes from a device's descriptors: the bulk IN endpoint and
//! the UVC VideoControl interface.
//!
//! The descriptors come from whatever device claims the board's IDs, so
//! they are hostile input: libusb parses the bytes, sdid's USB layer
//! (`daemon/src/backend/opt8241/usb.rs`) copies the parsed values into
//! [`AltSettingFields`], and these functions pick from them without I/O, so
//! the fuzz target (`fuzz/fuzz_targets/usb_descriptors.rs`) runs the same
//! choice as sdid.

/// bEndpointAddress bit 7: device to host.
const ENDPOINT_DIR_IN: u8 = 0x80;
/// bmAttributes bits 1:0 of a bulk endpoint.
const TRANSFER_TYPE_BULK: u8 = 0x02;
/// bInterfaceClass of video (UVC).
const CLASS_VIDEO: u8 = 0x0E;
/// bInterfaceSubClass of VideoControl.
const SUBCLASS_VIDEO_CONTROL: u8 = 0x01;

/// The bulk IN endpoint, as the descriptors give it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkEndpoint {
    pub interface: u8,
    pub address: u8,
    pub max_packet_bytes: u16,
}

/// One endpoint descriptor's fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EndpointFields {
    pub address: u8,
    pub attributes: u8,
    pub max_packet_bytes: u16,
}

/// One interface descriptor (an alternate setting) and its endpoints.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AltSettingFields {
    pub interface_number: u8,
    pub class_code: u8,
    pub sub_class_code: u8,
    pub endpoints: Vec<EndpointFields>,
}

/// First bulk IN endpoint of `interface`, in descriptor order.
pub fn bulk_in_endpoint<'a>(
    alt_settings: impl IntoIterator<Item = &'a AltSettingFields>,
    interface: u8,
) -> Option<BulkEndpoint> {
    alt_settings
        .into_iter()
        .filter(|a| a.interface_number == interface)
        .flat_map(|a| a.endpoints.iter())
        .find(|e| e.address & ENDPOINT_DIR_IN != 0 && e.attributes & 0x03 == TRANSFER_TYPE_BULK)
        .map(|e| BulkEndpoint {
            interface,
            address: e.address,
            max_packet_bytes: e.max_packet_bytes,
        })
}

/// The VideoControl interface (class 0x0E, subclass 0x01) of a UVC-mode
/// board; interface 0 when the descriptors do not say (FW `uvc.c`:
/// "Interface number is 0 for the XU").
pub fn video_control_interface<'a>(
    alt_settings: impl IntoIterator<Item = &'a AltSettingFields>,
) -> u8 {
    alt_settings
        .into_iter()
        .find(|a| a.class_code == CLASS_VIDEO && a.sub_class_code == SUBCLASS_VIDEO_CONTROL)
        .map_or(0, |a| a.interface_number)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alt(number: u8, class: (u8, u8), endpoints: &[(u8, u8)]) -> AltSettingFields {
        AltSettingFields {
            interface_number: number,
            class_code: class.0,
            sub_class_code: class.1,
            endpoints: endpoints
                .iter()
                .map(|&(address, attributes)| EndpointFields {
                    address,
                    attributes,
                    max_packet_bytes: 512,
                })
                .collect(),
        }
    }

    #[test]
    fn bulk_in_is_the_first_bulk_in_of_the_interface() {
        let alts = [
            alt(0, (0xFF, 0), &[(0x81, 0x03), (0x02, 0x02)]),
            alt(1, (0xFF, 0), &[(0x86, 0x02)]),
            alt(0, (0xFF, 0), &[(0x82, 0x02), (0x83, 0x02)]),
        ];
        let ep = bulk_in_endpoint(&alts, 0).unwrap();
        assert_eq!(
            (ep.interface, ep.address, ep.max_packet_bytes),
            (0, 0x82, 512)
        );
        assert_eq!(bulk_in_endpoint(&alts, 1).unwrap().address, 0x86);
        assert_eq!(bulk_in_endpoint(&alts, 2), None);
        assert_eq!(bulk_in_endpoint(&[], 0), None);
    }

    #[test]
    fn video_control_defaults_to_interface_0() {
        let alts = [alt(3, (0x0E, 0x02), &[]), alt(2, (0x0E, 0x01), &[])];
        assert_eq!(video_control_interface(&alts), 2);
        assert_eq!(video_control_interface(&alts[..1]), 0);
    }
}
