//! FunctionFS descriptor and string blobs for the emulated OPT8241-CDK
//! (linux/usb/functionfs.h, v2 format): interface 0, vendor class, one bulk
//! IN endpoint, as the board's bulk-mode descriptors.

const DESCRIPTORS_MAGIC_V2: u32 = 3;
const STRINGS_MAGIC: u32 = 2;
const HAS_FS_DESC: u32 = 1;
const HAS_HS_DESC: u32 = 2;
/// Vendor requests to the device (not only the interface) reach us.
const ALL_CTRL_RECIP: u32 = 64;

fn interface() -> [u8; 9] {
    // bLength, INTERFACE, number 0, alt 0, 1 endpoint, vendor class, 0, 0, iInterface 1
    [9, 4, 0, 0, 1, 0xFF, 0, 0, 1]
}

fn bulk_in(max_packet: u16) -> [u8; 7] {
    let mp = max_packet.to_le_bytes();
    // ENDPOINT, address 0x82 (EP2 IN as on the board), bulk
    [7, 5, 0x82, 2, mp[0], mp[1], 0]
}

/// A v2 descriptors blob of two full-speed and two high-speed descriptors.
fn descriptors_blob(full_speed: [&[u8]; 2], high_speed: [&[u8]; 2]) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend_from_slice(&2u32.to_le_bytes()); // fs_count
    body.extend_from_slice(&2u32.to_le_bytes()); // hs_count
    for d in full_speed.iter().chain(&high_speed) {
        body.extend_from_slice(d);
    }
    let mut out = Vec::new();
    out.extend_from_slice(&DESCRIPTORS_MAGIC_V2.to_le_bytes());
    out.extend_from_slice(&((12 + body.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(HAS_FS_DESC | HAS_HS_DESC | ALL_CTRL_RECIP).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// The blob written first to ep0.
pub fn descriptors() -> Vec<u8> {
    descriptors_blob([&interface(), &bulk_in(64)], [&interface(), &bulk_in(512)])
}

/// The string blob written second to ep0.
pub fn strings(interface_name: &str) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend_from_slice(&0x0409u16.to_le_bytes());
    body.extend_from_slice(interface_name.as_bytes());
    body.push(0);
    let mut out = Vec::new();
    out.extend_from_slice(&STRINGS_MAGIC.to_le_bytes());
    out.extend_from_slice(&((16 + body.len()) as u32).to_le_bytes());
    out.extend_from_slice(&1u32.to_le_bytes()); // str_count
    out.extend_from_slice(&1u32.to_le_bytes()); // lang_count
    out.extend_from_slice(&body);
    out
}

/// UVC mode (0451:9106): interface 0 is a VideoControl interface (class
/// 0x0E, subclass 0x01) with its status interrupt endpoint. FunctionFS
/// refuses class-specific (CS_INTERFACE) descriptors, so the VC header and
/// the extension unit descriptor are absent; the class requests still
/// reach the function (interface recipient).
pub fn uvc_descriptors() -> Vec<u8> {
    let vc = [9, 4, 0, 0, 1, 0x0E, 0x01, 0, 1];
    // ENDPOINT, IN, interrupt, 16 bytes, bInterval 8
    let status = |interval: u8| [7u8, 5, 0x81, 3, 16, 0, interval];
    descriptors_blob([&vc, &status(8)], [&vc, &status(4)])
}
