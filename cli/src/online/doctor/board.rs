//! The board: attached, in which USB mode, at which speed.

use super::{Check, Status, Sys};

/// USB boards of `udev/board-ids` in sysfs: (mode, speed in Mb/s, sysfs name).
pub(super) fn boards(sys: &Sys) -> Vec<(&'static str, String, String)> {
    let ids = sdi_api::board_ids::board_ids();
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(sys.path("/sys/bus/usb/devices")) else {
        return out;
    };
    for e in entries.flatten() {
        let hex = |f: &str| {
            std::fs::read_to_string(e.path().join(f))
                .ok()
                .and_then(|s| u16::from_str_radix(s.trim(), 16).ok())
        };
        let (Some(v), Some(p)) = (hex("idVendor"), hex("idProduct")) else {
            continue;
        };
        if let Some((_, _, mode)) = ids.iter().find(|(iv, ip, _)| *iv == v && *ip == p) {
            let speed = std::fs::read_to_string(e.path().join("speed"))
                .map(|s| s.trim().to_owned())
                .unwrap_or_default();
            out.push((*mode, speed, e.file_name().to_string_lossy().into_owned()));
        }
    }
    out
}

/// The board verdict (pure, unit-tested).
pub(super) fn board_verdict(found: &[(&str, String, String)]) -> Check {
    let Some((mode, speed, name)) = found.first() else {
        return Check::new("board", Status::Warn, "no OPT8241-CDK attached (USB IDs of udev/board-ids): sdid shows the simulator or the no-signal card")
            .fix("plug the board in (a USB 2.0 port or better); `lsusb -d 0451:` should list 0451:9105 or 0451:9106");
    };
    let speed_text = match speed.as_str() {
        "1.5" | "12" => format!("{speed} Mb/s (USB 1.x: too slow for frames)"),
        "480" => "480 Mb/s (high speed)".into(),
        s => format!("{s} Mb/s"),
    };
    let slow = matches!(speed.as_str(), "1.5" | "12");
    let mut c = match *mode {
        "bulk" => Check::new("board", Status::Ok, format!("OPT8241-CDK at usb {name}, bulk mode, {speed_text}")),
        m => Check::new("board", Status::Ok, format!("OPT8241-CDK at usb {name}, {m} mode (sdid switches it to bulk mode when it opens it), {speed_text}")),
    };
    if slow {
        c.status = Status::Warn;
        c.fix = Some("use a USB 2.0 (or faster) port and cable, without a USB 1.1 hub".into());
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn board_modes_and_speeds() {
        assert_eq!(board_verdict(&[]).status, Status::Warn);
        let c = board_verdict(&[("uvc", "480".into(), "1-1".into())]);
        assert_eq!(c.status, Status::Ok);
        assert!(c.summary.contains("uvc mode"));
        assert_eq!(
            board_verdict(&[("bulk", "12".into(), "1-1".into())]).status,
            Status::Warn
        );
    }
}
