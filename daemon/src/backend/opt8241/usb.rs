//! libusb (rusb) side of the board: finding it, its endpoints, control
//! transfers and the bulk stream.
//!
//! The stream runs on dedicated threads, each with its own synchronous bulk
//! read in flight, so several transfers are queued at the host controller at
//! any time (the SDK keeps one read and two frame buffers, and its users see
//! frame drops: `Voxel/USBBulkStreamer.cpp`, `MAX_BUFFER_COUNT 2`). Each read
//! asks for `frame_bytes + 255` like the SDK (`BULK_XFER_EXTRA_SIZE`), so a
//! frame ends at the device's short or zero-length packet. Completions are
//! delivered in completion order; the frame-number check of
//! `FrameAssembler` (`sdi_opt8241::frame_assembler`) catches the rare reordering.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use rusb::{Context, Device, DeviceHandle, Direction, TransferType, UsbContext};

use sdi_opt8241::descriptors::{self, AltSettingFields, BulkEndpoint, EndpointFields};
use sdi_opt8241::uvc_switch::{uvc_switch_request, ControlRequest};

use sdi_opt8241::protocol::{Transport, TransportError};

use super::ids;

/// Extra bytes asked for beyond one frame (SDK `BULK_XFER_EXTRA_SIZE`).
pub const BULK_EXTRA_BYTES: usize = 255;

/// Errors of finding and opening the board.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsbError {
    #[error("no OPT8241-CDK (USB {vid:04x}:{pid:04x}) found{}", serial.as_ref().map(|s| format!(" with serial {s}")).unwrap_or_default())]
    NotFound {
        vid: u16,
        pid: u16,
        serial: Option<String>,
    },
    #[error("{} boards attached ({}): choose one by serial number", serials.len(), serials.join(", "))]
    Ambiguous { serials: Vec<String> },
    #[error("{count} boards in UVC mode (USB 0451:9106) attached: choose one by serial number")]
    AmbiguousUvc { count: usize },
    #[error(
        "could not switch the board from UVC mode (0451:9106) to bulk mode (0451:9105): {error}"
    )]
    UvcSwitch { error: String },
    #[error("the board was told to leave UVC mode (0451:9106) but no bulk-mode board (0451:9105) appeared within {waited_ms} ms (switch request: {request}); replug it")]
    UvcSwitchTimeout { waited_ms: u128, request: String },
    #[error("permission denied opening the board: install sdid's udev rules (udev/board-ids) or run sdid as root")]
    Access,
    #[error("interface {interface} has no bulk IN endpoint")]
    NoBulkInEndpoint { interface: u8 },
    #[error("the board is busy (claimed by another program)")]
    Busy,
    #[error("device disconnected")]
    Disconnected,
    #[error("USB error during {op}: {error}")]
    Usb { op: &'static str, error: String },
}

fn usb_err(op: &'static str, e: rusb::Error) -> UsbError {
    match e {
        rusb::Error::Access => UsbError::Access,
        rusb::Error::NoDevice => UsbError::Disconnected,
        rusb::Error::Busy => UsbError::Busy,
        other => UsbError::Usb {
            op,
            error: other.to_string(),
        },
    }
}

/// Maps a libusb error to the protocol's transport error.
pub fn transport_error(e: rusb::Error) -> TransportError {
    match e {
        rusb::Error::Timeout => TransportError::Timeout,
        rusb::Error::Pipe => TransportError::Stall,
        rusb::Error::NoDevice => TransportError::Disconnected,
        other => TransportError::Other(other.to_string()),
    }
}

/// Which board to open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BoardSelector {
    pub vendor_id: u16,
    pub product_id: u16,
    /// Required when several boards are attached.
    pub serial: Option<String>,
}

impl Default for BoardSelector {
    fn default() -> Self {
        Self {
            vendor_id: ids::VENDOR_ID,
            product_id: ids::PRODUCT_ID_BULK,
            serial: None,
        }
    }
}

/// First bulk IN endpoint of `interface` in the active configuration.
pub fn find_bulk_in(device: &Device<Context>, interface: u8) -> Result<BulkEndpoint, UsbError> {
    let config = device
        .active_config_descriptor()
        .map_err(|e| usb_err("reading the configuration descriptor", e))?;
    descriptors::bulk_in_endpoint(&alt_settings(&config), interface)
        .ok_or(UsbError::NoBulkInEndpoint { interface })
}

/// The configuration's interface descriptors as plain fields, for the
/// choices in [`descriptors`].
fn alt_settings(config: &rusb::ConfigDescriptor) -> Vec<AltSettingFields> {
    config
        .interfaces()
        .flat_map(|i| i.descriptors())
        .map(|d| AltSettingFields {
            interface_number: d.interface_number(),
            class_code: d.class_code(),
            sub_class_code: d.sub_class_code(),
            endpoints: d
                .endpoint_descriptors()
                .map(|e| EndpointFields {
                    address: e.address(),
                    // bEndpointAddress keeps the direction bit; bmAttributes' type bits.
                    attributes: match e.transfer_type() {
                        TransferType::Control => 0,
                        TransferType::Isochronous => 1,
                        TransferType::Bulk => 2,
                        TransferType::Interrupt => 3,
                    },
                    max_packet_bytes: e.max_packet_size(),
                })
                .collect(),
        })
        .collect()
}

fn serial_of(device: &Device<Context>) -> Option<String> {
    let desc = device.device_descriptor().ok()?;
    let handle = device.open().ok()?;
    handle.read_serial_number_string_ascii(&desc).ok()
}

/// The serial of every attached board (either mode) that tells one,
/// sorted, each once.
pub fn board_serials(context: &Context) -> Vec<String> {
    let Ok(list) = context.devices() else {
        return Vec::new();
    };
    let mut serials: Vec<String> = list
        .iter()
        .filter(is_board)
        .filter_map(|d| serial_of(&d))
        .collect();
    serials.sort();
    serials.dedup();
    serials
}

/// The bus number and address of every attached board (either mode).
/// Cheap: descriptors only.
pub fn board_addresses(context: &Context) -> Vec<(u8, u8)> {
    let Ok(list) = context.devices() else {
        return Vec::new();
    };
    let mut found: Vec<(u8, u8)> = list
        .iter()
        .filter(is_board)
        .map(|d| (d.bus_number(), d.address()))
        .collect();
    found.sort_unstable();
    found
}

/// Is a board (any mode) attached? Cheap: descriptors only.
pub fn board_present(context: &Context) -> bool {
    context
        .devices()
        .is_ok_and(|list| list.iter().any(|d| is_board(&d)))
}

/// A board in either mode, by its descriptor's IDs.
fn is_board(device: &Device<Context>) -> bool {
    device.device_descriptor().is_ok_and(|desc| {
        desc.vendor_id() == ids::VENDOR_ID
            && (desc.product_id() == ids::PRODUCT_ID_BULK
                || desc.product_id() == ids::PRODUCT_ID_UVC)
    })
}

/// A board found on the bus, in either mode.
pub enum Found {
    /// Vendor bulk mode (0451:9105): ready to open.
    Bulk(Device<Context>),
    /// UVC mode (0451:9106): to be switched with [`switch_to_bulk`] first.
    Uvc(Device<Context>),
}

/// Finds the board the selector names: in bulk mode if there is one, else
/// in UVC mode (the same serial number, if the selector names one).
pub fn find_board(context: &Context, sel: &BoardSelector) -> Result<Found, UsbError> {
    let list = context
        .devices()
        .map_err(|e| usb_err("listing devices", e))?;
    let mut matches = Vec::new();
    let mut uvc = Vec::new();
    for d in list.iter() {
        let Ok(desc) = d.device_descriptor() else {
            continue;
        };
        if desc.vendor_id() != sel.vendor_id {
            continue;
        }
        if desc.product_id() == sel.product_id {
            matches.push(d);
        } else if sel.product_id == ids::PRODUCT_ID_BULK && desc.product_id() == ids::PRODUCT_ID_UVC
        {
            uvc.push(d);
        }
    }
    let not_found = || UsbError::NotFound {
        vid: sel.vendor_id,
        pid: sel.product_id,
        serial: sel.serial.clone(),
    };
    let by_serial = |list: Vec<Device<Context>>, want: &str| {
        list.into_iter()
            .find(|d| serial_of(d).as_deref() == Some(want))
    };
    match (&sel.serial, matches.len()) {
        (None, 1) => Ok(Found::Bulk(matches.remove(0))),
        (None, n) if n > 1 => Err(UsbError::Ambiguous {
            serials: matches
                .iter()
                .map(|d| serial_of(d).unwrap_or_else(|| "?".into()))
                .collect(),
        }),
        (None, _) => match uvc.len() {
            0 => Err(not_found()),
            1 => Ok(Found::Uvc(uvc.remove(0))),
            count => Err(UsbError::AmbiguousUvc { count }),
        },
        (Some(want), _) => by_serial(matches, want)
            .map(Found::Bulk)
            .or_else(|| by_serial(uvc, want).map(Found::Uvc))
            .ok_or_else(not_found),
    }
}

/// How long the board may take to come back in bulk mode after the switch
/// (the SDK waits a fixed 10 s, `TintinEEPROMDownloader::_configureForDownload`).
pub const UVC_SWITCH_TIMEOUT: Duration = Duration::from_secs(15);
/// Interval of the bus scans while waiting for the bulk-mode board.
const UVC_SWITCH_POLL: Duration = Duration::from_millis(100);

/// The VideoControl interface of a UVC-mode board
/// ([`descriptors::video_control_interface`]).
pub fn video_control_interface(device: &Device<Context>) -> u8 {
    device.active_config_descriptor().map_or(0, |c| {
        descriptors::video_control_interface(&alt_settings(&c))
    })
}

/// Tells a UVC-mode board to re-enumerate in bulk mode. Returns the request
/// sent and what the transfer returned: the firmware drops off the bus while
/// answering, so an error here does not mean the switch failed.
pub fn switch_to_bulk(device: &Device<Context>) -> Result<(ControlRequest, String), UsbError> {
    let interface = video_control_interface(device);
    let handle = device.open().map_err(|e| match e {
        rusb::Error::Access => UsbError::Access,
        other => UsbError::UvcSwitch {
            error: format!("opening the UVC-mode board: {other}"),
        },
    })?;
    // uvcvideo holds the VideoControl interface of a real board: detach it
    // for the request (libusb re-attaches it on release if the board is
    // still there, i.e. did not switch).
    let _ = handle.set_auto_detach_kernel_driver(true);
    handle
        .claim_interface(interface)
        .map_err(|e| UsbError::UvcSwitch {
            error: format!("claiming the VideoControl interface {interface}: {e}"),
        })?;
    let req = uvc_switch_request(interface);
    let outcome = match handle.write_control(
        req.request_type,
        req.request,
        req.value,
        req.index,
        &req.data,
        Duration::from_secs(1),
    ) {
        Ok(n) => format!("sent, {n} byte(s)"),
        Err(rusb::Error::Pipe) => {
            return Err(UsbError::UvcSwitch {
                error: format!("the board stalled the request ({req})"),
            })
        }
        Err(e) => format!("sent, transfer ended with: {e}"),
    };
    let _ = handle.release_interface(interface);
    drop(handle);
    Ok((req, outcome))
}

/// Switches a UVC-mode board and waits (at most [`UVC_SWITCH_TIMEOUT`]) for
/// it to come back in bulk mode; returns the bulk-mode device, found with a
/// fresh libusb context (and by the same serial number when it has one).
pub fn switch_and_wait(
    device: &Device<Context>,
    sel: &BoardSelector,
) -> Result<Device<Context>, UsbError> {
    let serial = sel.serial.clone().or_else(|| serial_of(device));
    tracing::info!(
        serial = serial.as_deref().unwrap_or("?"),
        "the OPT8241-CDK is in UVC mode (0451:9106); switching it to bulk mode (0451:9105)"
    );
    let t0 = Instant::now();
    let (req, outcome) = switch_to_bulk(device)?;
    tracing::info!(request = %req, %outcome, "UVC -> bulk switch requested; waiting for re-enumeration");
    let want = BoardSelector {
        serial,
        ..sel.clone()
    };
    loop {
        std::thread::sleep(UVC_SWITCH_POLL);
        if let Ok(ctx) = Context::new() {
            if let Ok(Found::Bulk(d)) = find_board(&ctx, &want) {
                tracing::info!(took = ?t0.elapsed(), "the board is back in bulk mode");
                return Ok(d);
            }
        }
        if t0.elapsed() >= UVC_SWITCH_TIMEOUT {
            return Err(UsbError::UvcSwitchTimeout {
                waited_ms: t0.elapsed().as_millis(),
                request: format!("{req}; {outcome}"),
            });
        }
    }
}

/// An opened, claimed board.
pub struct OpenBoard {
    pub handle: Arc<DeviceHandle<Context>>,
    pub endpoint: BulkEndpoint,
    pub serial: Option<String>,
}

/// Opens the board, claims its interface and finds its endpoint. A board
/// in UVC mode is switched to bulk mode first ([`switch_and_wait`]).
pub fn open_board(context: &Context, sel: &BoardSelector) -> Result<OpenBoard, UsbError> {
    let device = match find_board(context, sel)? {
        Found::Bulk(d) => d,
        Found::Uvc(d) => switch_and_wait(&d, sel)?,
    };
    let endpoint = find_bulk_in(&device, ids::INTERFACE)?;
    let handle = device.open().map_err(|e| usb_err("opening", e))?;
    // Not supported on every platform; harmless when no kernel driver is bound.
    let _ = handle.set_auto_detach_kernel_driver(true);
    handle
        .claim_interface(endpoint.interface)
        .map_err(|e| usb_err("claiming interface 0", e))?;
    let serial = device
        .device_descriptor()
        .ok()
        .and_then(|d| handle.read_serial_number_string_ascii(&d).ok());
    Ok(OpenBoard {
        handle: Arc::new(handle),
        endpoint,
        serial,
    })
}

/// Vendor control transfers over libusb.
pub struct UsbTransport {
    pub handle: Arc<DeviceHandle<Context>>,
}

impl Transport for UsbTransport {
    fn control_in(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, TransportError> {
        let rt = rusb::request_type(
            Direction::In,
            rusb::RequestType::Vendor,
            rusb::Recipient::Device,
        );
        self.handle
            .read_control(rt, request, value, index, buf, timeout)
            .map_err(transport_error)
    }

    fn control_out(
        &mut self,
        request: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, TransportError> {
        let rt = rusb::request_type(
            Direction::Out,
            rusb::RequestType::Vendor,
            rusb::Recipient::Device,
        );
        self.handle
            .write_control(rt, request, value, index, data, timeout)
            .map_err(transport_error)
    }
}

/// What the stream threads report.
#[derive(Debug)]
pub enum StreamEvent {
    /// A completed transfer; `short` when it ended before the requested length.
    Data { bytes: Vec<u8>, short: bool },
    /// No data within the read timeout (board stopped or not streaming).
    Timeout,
    /// The endpoint stalled; its halt was cleared.
    HaltCleared,
    /// The device sent more than asked (babble): the stream was misaligned.
    Overflow,
    /// Any other transfer error (retried).
    Error(String),
    /// The device is gone; the thread has ended.
    Disconnected,
}

/// Several bulk reads in flight on dedicated threads.
pub struct BulkStream {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    pub events: mpsc::Receiver<StreamEvent>,
}

impl BulkStream {
    /// Starts `in_flight` reader threads on `endpoint`, each reading
    /// `frame_bytes + BULK_EXTRA_BYTES` per transfer.
    pub fn start(
        handle: Arc<DeviceHandle<Context>>,
        endpoint: BulkEndpoint,
        frame_bytes: usize,
        in_flight: usize,
        read_timeout: Duration,
    ) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, events) = mpsc::sync_channel(in_flight.max(1) * 4);
        // A halt left over from an earlier session (the SDK clears it too).
        let _ = handle.clear_halt(endpoint.address);
        let threads = (0..in_flight.max(1))
            .map(|i| {
                let (handle, stop, tx) = (handle.clone(), stop.clone(), tx.clone());
                std::thread::Builder::new()
                    .name(format!("opt8241-bulk-{i}"))
                    .spawn(move || {
                        read_loop(&handle, endpoint, frame_bytes, read_timeout, &stop, &tx)
                    })
            })
            .filter_map(Result::ok)
            .collect();
        Self {
            stop,
            threads,
            events,
        }
    }

    /// Stops the readers and waits for them (at most one read timeout).
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Drain so no reader blocks on a full channel.
        while self.events.try_recv().is_ok() {}
        for t in self.threads.drain(..) {
            while !t.is_finished() {
                while self.events.try_recv().is_ok() {}
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = t.join();
        }
    }
}

impl Drop for BulkStream {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Pause of a reader after a transfer that failed or carried nothing (a
/// zero-length packet on its own, which a board in step never sends: its
/// frames end within the transfer): a device that does this on every
/// transfer must not turn the readers into busy loops.
pub const FAILED_TRANSFER_PAUSE: Duration = Duration::from_millis(10);

fn read_loop(
    handle: &DeviceHandle<Context>,
    ep: BulkEndpoint,
    frame_bytes: usize,
    timeout: Duration,
    stop: &AtomicBool,
    tx: &mpsc::SyncSender<StreamEvent>,
) {
    let want = frame_bytes + BULK_EXTRA_BYTES;
    let mut buf = vec![0u8; want];
    while !stop.load(Ordering::SeqCst) {
        let event = match handle.read_bulk(ep.address, &mut buf, timeout) {
            Ok(n) => StreamEvent::Data {
                bytes: buf[..n].to_vec(),
                short: n < want,
            },
            Err(rusb::Error::Timeout) => StreamEvent::Timeout,
            Err(rusb::Error::Pipe) => match handle.clear_halt(ep.address) {
                Ok(()) => StreamEvent::HaltCleared,
                Err(e) => StreamEvent::Error(format!("clearing halt: {e}")),
            },
            Err(rusb::Error::Overflow) => StreamEvent::Overflow,
            Err(rusb::Error::NoDevice) | Err(rusb::Error::Io) => {
                let _ = tx.send(StreamEvent::Disconnected);
                return;
            }
            Err(e) => StreamEvent::Error(e.to_string()),
        };
        let pause = match &event {
            StreamEvent::Data { bytes, .. } => bytes.is_empty(),
            StreamEvent::Timeout => false,
            _ => true,
        };
        if tx.send(event).is_err() {
            return;
        }
        if pause {
            std::thread::sleep(FAILED_TRANSFER_PAUSE);
        }
    }
}

#[cfg(test)]
mod tests {
    use sdi_opt8241::uvc_switch::REQUEST_TYPE_CLASS_INTERFACE_OUT;

    #[test]
    fn the_uvc_switch_request_type_is_libusbs() {
        let rt = rusb::request_type(
            rusb::Direction::Out,
            rusb::RequestType::Class,
            rusb::Recipient::Interface,
        );
        assert_eq!(REQUEST_TYPE_CLASS_INTERFACE_OUT, rt);
    }
}
