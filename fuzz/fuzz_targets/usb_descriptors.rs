//! Fuzz target: sdid's choices from a device's descriptors, the bulk IN
//! endpoint and the UVC VideoControl interface
//! (opt8241/src/descriptors.rs), and the UVC switch request built from the
//! latter (opt8241/src/uvc_switch.rs).
//!
//! Input: descriptor bytes as a device sends them (bLength,
//! bDescriptorType, fields); interface (4) and endpoint (5) descriptors are
//! read into the fields libusb hands sdid, others are skipped.
//! Invariant: no panic or abort; the endpoint chosen is a bulk IN endpoint
//! of the interface asked for, or none (a typed `NoBulkInEndpoint` in
//! `daemon/src/backend/opt8241/usb.rs`); the switch request names the interface chosen; time and
//! memory linear in the input.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdi_opt8241::descriptors::{
    bulk_in_endpoint, video_control_interface, AltSettingFields, EndpointFields,
};
use sdi_opt8241::uvc_switch::uvc_switch_request;

/// Interface descriptors with their endpoints, from a descriptor stream.
fn alt_settings(mut bytes: &[u8]) -> Vec<AltSettingFields> {
    let mut alts: Vec<AltSettingFields> = Vec::new();
    while let [len, kind, ..] = *bytes {
        let len = usize::from(len).clamp(2, bytes.len());
        let (d, rest) = bytes.split_at(len);
        bytes = rest;
        match (kind, d) {
            (4, [_, _, number, _, _, class, sub_class, ..]) => alts.push(AltSettingFields {
                interface_number: *number,
                class_code: *class,
                sub_class_code: *sub_class,
                endpoints: Vec::new(),
            }),
            (5, [_, _, address, attributes, mp0, mp1, ..]) => {
                if let Some(alt) = alts.last_mut() {
                    alt.endpoints.push(EndpointFields {
                        address: *address,
                        attributes: *attributes,
                        max_packet_bytes: u16::from_le_bytes([*mp0, *mp1]),
                    });
                }
            }
            _ => {}
        }
    }
    alts
}

fuzz_target!(|data: &[u8]| {
    let Some((&interface, descriptors)) = data.split_first() else {
        return;
    };
    let alts = alt_settings(descriptors);
    if let Some(ep) = bulk_in_endpoint(&alts, interface) {
        assert_eq!(ep.interface, interface);
        assert_ne!(ep.address & 0x80, 0, "not an IN endpoint");
        assert!(alts.iter().any(|a| a.interface_number == interface
            && a.endpoints
                .iter()
                .any(|e| e.address == ep.address && e.attributes & 3 == 2)));
    }
    let vc = video_control_interface(&alts);
    assert_eq!(uvc_switch_request(vc).index & 0xFF, u16::from(vc));
});
