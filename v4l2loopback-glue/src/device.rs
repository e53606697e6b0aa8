//! Finding or creating a loopback node, by module version.
//!
//! * 0.12.x (Debian 12): no control device; nodes come from module
//!   parameters and are found by card label in
//!   `/sys/devices/virtual/video4linux/*/name`.
//! * 0.13 / 0.14: control device `/dev/v4l2loopback` with the legacy
//!   `ADD` ioctl `0x4C80`.
//! * 0.15+: the control ioctls were renumbered (`ADD _IOW('~', 1)`,
//!   `REMOVE _IOW('~', 2)`, `QUERY _IOWR('~', 3)`) and a `VERSION` ioctl
//!   (`_IOR('~', 0, u32)`) was added; the legacy numbers still work, but with
//!   the 0.15 struct layout (min/max sizes), so we use the new ones there.

use std::fs::File;
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};

use crate::error::err;
use crate::sys;
use crate::GlueError;

const SYSFS_NODES: &str = "/sys/devices/virtual/video4linux";
const CONTROL_DEVICE: &str = "/dev/v4l2loopback";
const OPEN_CONTROL: &str = "open /dev/v4l2loopback";
/// Bytes of a card label v4l2loopback keeps (`char card_label[32]`, NUL
/// terminated): a longer one is cut, and never matches when looked up.
pub const LABEL_MAX: usize = 31;

/// Version of the loaded v4l2loopback module.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct ModuleVersion {
    pub major: u32,
    pub minor: u32,
    pub patch: u32,
}

impl std::fmt::Display for ModuleVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

impl ModuleVersion {
    const fn new(major: u32, minor: u32, patch: u32) -> Self {
        Self {
            major,
            minor,
            patch,
        }
    }

    /// Parses "0.12.7" (extra suffixes such as "-1" are ignored).
    pub fn parse(text: &str) -> Option<Self> {
        let mut it = text
            .trim()
            .split(['.', '-', ' '])
            .map(|p| p.parse::<u32>().ok());
        Some(Self::new(
            it.next()??,
            it.next()??,
            it.next().flatten().unwrap_or(0),
        ))
    }

    /// From `KERNEL_VERSION(a, b, c)` as returned by the 0.15 VERSION ioctl.
    pub fn from_code(code: u32) -> Self {
        Self::new(code >> 16, (code >> 8) & 0xff, code & 0xff)
    }

    /// 0.13+: `/dev/v4l2loopback` can add devices.
    pub fn has_control_device(self) -> bool {
        self >= Self::new(0, 13, 0)
    }

    /// 0.13+: the client-usage event tells when capture readers stream.
    pub fn has_client_usage_event(self) -> bool {
        self >= Self::new(0, 13, 0)
    }

    /// 0.15+: a REQBUFS rebuilds the buffer queue under the module's list
    /// lock (`prepare_buffer_queue`), so a reader's REQBUFS may race our
    /// QBUF. 0.12.7 unlinks buffers with no lock (see [`crate::LoopbackWriter`]).
    pub fn has_locked_buffer_queue(self) -> bool {
        self >= Self::new(0, 15, 0)
    }

    /// 0.15+: renumbered control ioctls.
    pub fn has_new_control_ioctls(self) -> bool {
        self >= Self::new(0, 15, 0)
    }

    /// Version of the loaded module, or `ModuleNotLoaded` with the command
    /// that loads it. Debian's 0.12.7 build carries no version string
    /// (neither sysfs nor modinfo), so a module without a control device and
    /// without a version reads as 0.12.0, meaning "0.12.x".
    pub fn of_loaded_module() -> Result<Self, GlueError> {
        if !Path::new("/sys/module/v4l2loopback").exists() {
            return Err(GlueError::ModuleNotLoaded {
                modprobe: modprobe_command("SDI"),
            });
        }
        if let Ok(text) = std::fs::read_to_string("/sys/module/v4l2loopback/version") {
            if let Some(v) = Self::parse(&text) {
                return Ok(v);
            }
        }
        // Debian's 0.12.7 build exposes no sysfs version: ask modinfo.
        if let Ok(o) = std::process::Command::new("modinfo")
            .args(["-F", "version", "v4l2loopback"])
            .output()
        {
            if let Some(v) = Self::parse(&String::from_utf8_lossy(&o.stdout)) {
                return Ok(v);
            }
        }
        if let Ok(ctl) = File::open(CONTROL_DEVICE) {
            let mut code = 0u32;
            if sys::ctl_version(ctl.as_fd(), &mut code).is_ok() {
                return Ok(Self::from_code(code));
            }
            return Ok(Self::new(0, 13, 0));
        }
        Ok(Self::new(0, 12, 0))
    }
}

/// The command that loads the module with one node labelled `label`.
pub fn modprobe_command(label: &str) -> String {
    format!("modprobe v4l2loopback devices=1 exclusive_caps=1 card_label=\"{label}\"")
}

/// A loopback node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoopbackDevice {
    pub path: PathBuf,
    pub label: String,
    pub version: ModuleVersion,
}

/// All loopback nodes as (path, label).
fn list_nodes() -> Vec<(PathBuf, String)> {
    let Ok(entries) = std::fs::read_dir(SYSFS_NODES) else {
        return Vec::new();
    };
    let mut nodes: Vec<(PathBuf, String)> = entries
        .flatten()
        .filter_map(|e| {
            let name = std::fs::read_to_string(e.path().join("name")).ok()?;
            Some((
                Path::new("/dev").join(e.file_name()),
                name.trim_end().to_owned(),
            ))
        })
        .collect();
    nodes.sort();
    nodes
}

/// Finds the node whose card label is `label`.
pub fn find_device(label: &str) -> Result<LoopbackDevice, GlueError> {
    let version = ModuleVersion::of_loaded_module().map_err(|e| match e {
        // Name the label the caller looks for in the command that loads it.
        GlueError::ModuleNotLoaded { .. } => GlueError::ModuleNotLoaded {
            modprobe: modprobe_command(label),
        },
        other => other,
    })?;
    list_nodes()
        .into_iter()
        .find(|(_, l)| l == label)
        .map(|(path, label)| LoopbackDevice {
            path,
            label,
            version,
        })
        .ok_or_else(|| GlueError::DeviceNotFound {
            label: label.to_owned(),
            hint: if version.has_control_device() {
                "create it with create_device() or `v4l2loopback-ctl add`".into()
            } else {
                format!(
                    "v4l2loopback {version} has no control device: reload it with {}",
                    modprobe_command(label)
                )
            },
            not_added: None,
        })
}

/// Opens the control device (0.13+) read-write.
fn open_control() -> Result<File, GlueError> {
    File::options()
        .read(true)
        .write(true)
        .open(CONTROL_DEVICE)
        .map_err(|e| GlueError::Io {
            op: OPEN_CONTROL,
            errno: nix::errno::Errno::from_raw(e.raw_os_error().unwrap_or(0)),
        })
}

/// The module version reported by the control device's `VERSION` ioctl
/// (0.15+); `Unsupported` on older modules.
pub fn control_version() -> Result<ModuleVersion, GlueError> {
    let ctl = open_control()?;
    let mut code = 0u32;
    match sys::ctl_version(ctl.as_fd(), &mut code) {
        Ok(_) => Ok(ModuleVersion::from_code(code)),
        Err(nix::errno::Errno::ENOSYS | nix::errno::Errno::ENOTTY) => Err(GlueError::Unsupported {
            version: "< 0.15".into(),
            what: "the VERSION ioctl",
        }),
        Err(e) => Err(GlueError::from_errno("V4L2LOOPBACK_CTL_VERSION", e)),
    }
}

/// What the control device's `QUERY` ioctl reports about one node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeInfo {
    pub video_nr: u32,
    pub label: String,
    pub max_width: u32,
    pub max_height: u32,
    /// false: exclusive_caps (OUTPUT only until a producer streams).
    pub announce_all_caps: bool,
    pub max_buffers: i32,
    pub max_openers: i32,
}

/// The number N of `/dev/videoN`.
pub fn video_nr(path: &Path) -> Option<u32> {
    path.file_name()?
        .to_str()?
        .strip_prefix("video")?
        .parse()
        .ok()
}

fn label_of(raw: &[u8; 32]) -> String {
    let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
    String::from_utf8_lossy(&raw[..end]).into_owned()
}

/// `QUERY` of `/dev/video<nr>` through the control device (0.13+).
pub fn query_device(nr: u32) -> Result<NodeInfo, GlueError> {
    let version = ModuleVersion::of_loaded_module()?;
    if !version.has_control_device() {
        return Err(GlueError::Unsupported {
            version: version.to_string(),
            what: "querying devices (no /dev/v4l2loopback)",
        });
    }
    let ctl = open_control()?;
    if version.has_new_control_ioctls() {
        let mut cfg = sys::loopback_config_v15 {
            output_nr: nr as i32,
            unused: -1,
            ..Default::default()
        };
        sys::ctl_query_v15(ctl.as_fd(), &mut cfg).map_err(err("V4L2LOOPBACK_CTL_QUERY"))?;
        Ok(NodeInfo {
            video_nr: cfg.output_nr as u32,
            label: label_of(&cfg.card_label),
            max_width: cfg.max_width,
            max_height: cfg.max_height,
            announce_all_caps: cfg.announce_all_caps != 0,
            max_buffers: cfg.max_buffers,
            max_openers: cfg.max_openers,
        })
    } else {
        let mut cfg = sys::loopback_config_legacy {
            output_nr: nr as i32,
            unused: -1,
            ..Default::default()
        };
        sys::ctl_query_legacy(ctl.as_fd(), &mut cfg).map_err(err("V4L2LOOPBACK_CTL_QUERY"))?;
        Ok(NodeInfo {
            video_nr: cfg.output_nr as u32,
            label: label_of(&cfg.card_label),
            max_width: cfg.max_width as u32,
            max_height: cfg.max_height as u32,
            announce_all_caps: cfg.announce_all_caps != 0,
            max_buffers: cfg.max_buffers,
            max_openers: cfg.max_openers,
        })
    }
}

/// Removes a node created at run time (0.13+). `Busy` while anyone has it
/// open (the module refuses, v4l2loopback.c `V4L2LOOPBACK_CTL_REMOVE`).
pub fn remove_device(dev: &LoopbackDevice) -> Result<(), GlueError> {
    if !dev.version.has_control_device() {
        return Err(GlueError::Unsupported {
            version: dev.version.to_string(),
            what: "removing devices (no /dev/v4l2loopback)",
        });
    }
    let nr = video_nr(&dev.path).ok_or_else(|| GlueError::InvalidArgument {
        op: "V4L2LOOPBACK_CTL_REMOVE",
        detail: format!("{} is not /dev/videoN", dev.path.display()),
    })?;
    let ctl = open_control()?;
    sys::ctl_remove(ctl.as_fd(), nr, dev.version.has_new_control_ioctls())
        .map_err(err("V4L2LOOPBACK_CTL_REMOVE"))?;
    Ok(())
}

/// Parameters of a node to create (0.13+).
#[derive(Clone, Debug)]
pub struct CreateOptions {
    pub label: String,
    /// Advertise only OUTPUT until a producer streams, then only CAPTURE
    /// (browsers need this to list the node).
    pub exclusive_caps: bool,
    pub max_width: u32,
    pub max_height: u32,
    /// Requested `/dev/videoN`, or any.
    pub video_nr: Option<u32>,
    /// Buffers in the node's ring: readers may lag `max_buffers - 1`
    /// frames before they see a torn one (see `DriverFeatures::buffers`).
    pub max_buffers: u32,
}

impl CreateOptions {
    pub fn new(label: &str) -> Self {
        Self {
            label: label.to_owned(),
            exclusive_caps: true,
            max_width: 8192,
            max_height: 8192,
            video_nr: None,
            max_buffers: 10,
        }
    }
}

/// Returns the node labelled `opts.label`, creating it through the control
/// device when the module has one (0.13+). On 0.12.x an absent node is an
/// error naming the modprobe command.
pub fn create_device(opts: &CreateOptions) -> Result<LoopbackDevice, GlueError> {
    match find_device(&opts.label) {
        Err(GlueError::DeviceNotFound { .. }) => add_device(opts),
        other => other,
    }
}

/// A node looked up by label, and whether [`find_or_add_device`] added it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    pub device: LoopbackDevice,
    pub added: bool,
}

/// The node labelled `opts.label`, added through the control device when
/// there is none. Where it cannot be added (module 0.12.x, no write access
/// to `/dev/v4l2loopback`, a label over [`LABEL_MAX`] bytes, the ioctl
/// refused), the error is [`find_device`]'s `DeviceNotFound` with the
/// reason in `not_added`.
pub fn find_or_add_device(opts: &CreateOptions) -> Result<Found, GlueError> {
    match find_device(&opts.label) {
        Ok(device) => Ok(Found {
            device,
            added: false,
        }),
        Err(GlueError::DeviceNotFound { label, hint, .. }) => match add_device(opts) {
            Ok(device) => Ok(Found {
                device,
                added: true,
            }),
            Err(e) => Err(GlueError::DeviceNotFound {
                label,
                hint,
                not_added: Some(not_added_reason(&e)),
            }),
        },
        Err(e) => Err(e),
    }
}

/// Why [`add_device`] failed, for people.
fn not_added_reason(e: &GlueError) -> String {
    match e {
        GlueError::Unsupported { .. } => {
            "this v4l2loopback has no control device (0.13 and later have)".into()
        }
        GlueError::Io { op, errno } if *op == OPEN_CONTROL => match errno {
            nix::errno::Errno::ENOENT => format!("{CONTROL_DEVICE} does not exist"),
            nix::errno::Errno::EACCES | nix::errno::Errno::EPERM => {
                format!("no permission to open {CONTROL_DEVICE} (adding nodes takes root)")
            }
            _ => e.to_string(),
        },
        e => e.to_string(),
    }
}

/// `LabelTooLong` when v4l2loopback would cut `label`.
fn check_label(label: &str) -> Result<(), GlueError> {
    if label.len() > LABEL_MAX {
        return Err(GlueError::LabelTooLong {
            label: label.to_owned(),
            len: label.len(),
            max: LABEL_MAX,
        });
    }
    Ok(())
}

/// Adds a node labelled `opts.label` through the control device (0.13+),
/// whether or not one with that label exists.
fn add_device(opts: &CreateOptions) -> Result<LoopbackDevice, GlueError> {
    check_label(&opts.label)?;
    let version = ModuleVersion::of_loaded_module()?;
    if !version.has_control_device() {
        return Err(GlueError::Unsupported {
            version: version.to_string(),
            what: "creating devices at run time (no /dev/v4l2loopback); use module parameters",
        });
    }
    let ctl = open_control()?;
    let mut label = [0u8; 32];
    label[..opts.label.len()].copy_from_slice(opts.label.as_bytes()); // checked above
    let nr = opts.video_nr.map_or(-1, |n| n as i32);
    let created = if version.has_new_control_ioctls() {
        let cfg = sys::loopback_config_v15 {
            output_nr: nr,
            unused: nr,
            card_label: label,
            max_width: opts.max_width,
            max_height: opts.max_height,
            announce_all_caps: i32::from(!opts.exclusive_caps),
            max_buffers: opts.max_buffers as i32,
            ..Default::default()
        };
        sys::ctl_add_v15(ctl.as_fd(), &cfg)
    } else {
        let cfg = sys::loopback_config_legacy {
            output_nr: nr,
            unused: nr,
            card_label: label,
            max_width: opts.max_width as i32,
            max_height: opts.max_height as i32,
            announce_all_caps: i32::from(!opts.exclusive_caps),
            max_buffers: opts.max_buffers as i32,
            ..Default::default()
        };
        sys::ctl_add_legacy(ctl.as_fd(), &cfg)
    }
    .map_err(err("V4L2LOOPBACK_CTL_ADD"))?;
    Ok(LoopbackDevice {
        path: PathBuf::from(format!("/dev/video{created}")),
        label: opts.label.clone(),
        version,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn versions_parse_and_gate_features() {
        let v = ModuleVersion::parse("0.12.7\n").unwrap();
        assert_eq!(v, ModuleVersion::new(0, 12, 7));
        assert!(!v.has_control_device() && !v.has_client_usage_event());
        let v = ModuleVersion::parse("0.13.2-1").unwrap();
        assert!(v.has_control_device() && !v.has_new_control_ioctls());
        assert_eq!(
            ModuleVersion::from_code((15 << 8) | 1),
            ModuleVersion::new(0, 15, 1)
        );
        assert!(ModuleVersion::new(0, 15, 0).has_new_control_ioctls());
        assert!(ModuleVersion::parse("garbage").is_none());
        assert!(modprobe_command("SDI view").contains("card_label=\"SDI view\""));
        assert_eq!(video_nr(Path::new("/dev/video42")), Some(42));
        assert_eq!(video_nr(Path::new("/dev/v4l2loopback")), None);
        let mut raw = [0u8; 32];
        raw[..7].copy_from_slice(b"SDI cam");
        assert_eq!(label_of(&raw), "SDI cam");
    }

    #[test]
    fn labels_over_31_bytes_are_refused_with_the_reason() {
        assert!(check_label(&"x".repeat(LABEL_MAX)).is_ok());
        let e = check_label("SDI camera 0123456789abcdefghijk").unwrap_err();
        assert!(matches!(e, GlueError::LabelTooLong { len: 32, .. }), "{e}");
        let why = not_added_reason(&e);
        assert!(
            why.contains("32 bytes") && why.contains("at most 31"),
            "{why}"
        );
        let e = GlueError::DeviceNotFound {
            label: "SDI camera x".into(),
            hint: "load it".into(),
            not_added: Some(why),
        };
        assert!(e.to_string().contains("load it; not added: label"), "{e}");
    }

    #[test]
    fn control_device_errors_read_as_reasons() {
        let e = GlueError::Io {
            op: OPEN_CONTROL,
            errno: nix::errno::Errno::EACCES,
        };
        assert!(not_added_reason(&e).contains("takes root"));
        let e = GlueError::Io {
            op: OPEN_CONTROL,
            errno: nix::errno::Errno::ENOENT,
        };
        assert_eq!(not_added_reason(&e), "/dev/v4l2loopback does not exist");
    }
}
