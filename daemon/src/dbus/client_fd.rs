//! Output files passed in by clients as Unix file descriptors (D-Bus type
//! `h`). The client opens the file as itself, wherever it may write; the
//! sandboxed daemon (ProtectHome, PrivateTmp, ProtectSystem=strict) only
//! writes through the descriptor and never sees a path.

use std::fs::File;
use std::os::fd::{AsRawFd, OwnedFd};

use nix::fcntl::{fcntl, FcntlArg, OFlag};

use super::errors::SdiError;
use super::paths::OutputKind;
use crate::frame_stream::StreamTarget;

/// Longest label a client may give a recording (shown in `Recording`).
pub const MAX_LABEL_BYTES: usize = 4096;

/// Accepts `fd` if it is an empty regular file open for writing: not a
/// pipe, socket, tty or device, not on procfs/sysfs and the like, not
/// read-only, and holding no data the daemon would write over.
pub fn output_file(fd: OwnedFd) -> Result<File, SdiError> {
    let bad = |why: String| SdiError::InvalidFd(why);
    let file = File::from(fd);
    let meta = file
        .metadata()
        .map_err(|e| bad(format!("fstat on the descriptor failed: {e}")))?;
    if !meta.file_type().is_file() {
        let what = kind_name(&meta);
        return Err(bad(format!(
            "the descriptor is {what}, not a regular file: pass a file opened for writing"
        )));
    }
    if let Some(fs) = pseudo_file_system(&file) {
        return Err(bad(format!(
            "the file lives on {fs}, not on a file system for data"
        )));
    }
    let flags = fcntl(file.as_raw_fd(), FcntlArg::F_GETFL)
        .map_err(|e| bad(format!("fcntl(F_GETFL) on the descriptor failed: {e}")))?;
    let access = OFlag::from_bits_truncate(flags) & OFlag::O_ACCMODE;
    if access != OFlag::O_WRONLY && access != OFlag::O_RDWR {
        return Err(bad(
            "the file is open read-only: open it for writing (O_WRONLY or O_RDWR)".into(),
        ));
    }
    if meta.len() != 0 {
        return Err(bad(format!(
            "the file already holds {} bytes: pass a new, empty file (the daemon never overwrites)",
            meta.len()
        )));
    }
    Ok(file)
}

/// What `StreamFrames` takes, said once for every refusal.
const STREAM_WANTED: &str = "pass the writing end of a pipe (or a FIFO opened write-only) \
     or one end of a connected Unix stream socket, the other end kept by you";

/// Accepts `fd` for `StreamFrames` if sdid cannot read from it itself: a
/// pipe or FIFO opened write-only (one opened read-write would give sdid
/// the read side), or a connected Unix stream socket, which sdid shuts
/// down for reading (so both ends of one pair passed in end at the first
/// write) and whose other end is not sdid's own. The writes are made
/// non-blocking: the stream's thread must never wait in the kernel.
pub fn stream_target(fd: OwnedFd) -> Result<StreamTarget, SdiError> {
    use std::os::unix::fs::FileTypeExt;
    let bad = |why: String| SdiError::InvalidFd(why);
    let file = File::from(fd);
    let meta = file
        .metadata()
        .map_err(|e| bad(format!("fstat on the descriptor failed: {e}")))?;
    let t = meta.file_type();
    let flags = fcntl(file.as_raw_fd(), FcntlArg::F_GETFL)
        .map_err(|e| bad(format!("fcntl(F_GETFL) on the descriptor failed: {e}")))?;
    let flags = OFlag::from_bits_truncate(flags);
    if t.is_fifo() {
        if flags & OFlag::O_ACCMODE != OFlag::O_WRONLY {
            return Err(bad(format!(
                "the pipe is open for reading (sdid would hold a read side): {STREAM_WANTED}"
            )));
        }
        fcntl(
            file.as_raw_fd(),
            FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK),
        )
        .map_err(|e| bad(format!("fcntl(F_SETFL) on the descriptor failed: {e}")))?;
        return Ok(StreamTarget::Pipe(file));
    }
    if t.is_socket() {
        return stream_socket(OwnedFd::from(file))
            .map_err(|why| bad(format!("{why}: {STREAM_WANTED}")));
    }
    let what = kind_name(&meta);
    Err(bad(format!("the descriptor is {what}: {STREAM_WANTED}")))
}

/// The socket checks of [`stream_target`]; the refusal's reason.
fn stream_socket(fd: OwnedFd) -> Result<StreamTarget, String> {
    use nix::sys::socket::{
        getpeername, getsockname, getsockopt, shutdown, sockopt, AddressFamily, Shutdown, SockType,
        SockaddrLike, SockaddrStorage,
    };
    let domain = getsockname::<SockaddrStorage>(fd.as_raw_fd())
        .map_err(|e| format!("getsockname failed: {e}"))?
        .family();
    let kind = getsockopt(&fd, sockopt::SockType)
        .map_err(|e| format!("getsockopt(SO_TYPE) failed: {e}"))?;
    if domain != Some(AddressFamily::Unix) || kind != SockType::Stream {
        return Err(format!(
            "the socket is {domain:?} {kind:?}, not a Unix stream socket"
        ));
    }
    getpeername::<SockaddrStorage>(fd.as_raw_fd())
        .map_err(|e| format!("the socket is not connected ({e})"))?;
    let peer = getsockopt(&fd, sockopt::PeerCredentials)
        .map_err(|e| format!("getsockopt(SO_PEERCRED) failed: {e}"))?;
    if u32::try_from(peer.pid()).is_ok_and(|pid| pid == std::process::id()) {
        return Err("the socket's other end is sdid's own".into());
    }
    shutdown(fd.as_raw_fd(), Shutdown::Read)
        .map_err(|e| format!("shutting the socket down for reading failed: {e}"))?;
    Ok(StreamTarget::Socket(fd))
}

/// Kernel interface file systems whose "files" act when written (and may
/// check the writer's privileges at write time): never write there on a
/// client's behalf.
fn pseudo_file_system(file: &File) -> Option<&'static str> {
    use nix::sys::statfs::{self as sfs, fstatfs};
    let kind = fstatfs(file).ok()?.filesystem_type();
    [
        (sfs::PROC_SUPER_MAGIC, "procfs"),
        (sfs::SYSFS_MAGIC, "sysfs"),
        (sfs::CGROUP_SUPER_MAGIC, "cgroupfs"),
        (sfs::CGROUP2_SUPER_MAGIC, "cgroup2fs"),
        (sfs::DEBUGFS_MAGIC, "debugfs"),
        (sfs::TRACEFS_MAGIC, "tracefs"),
        (sfs::SECURITYFS_MAGIC, "securityfs"),
        (sfs::BPF_FS_MAGIC, "bpffs"),
        (sfs::DEVPTS_SUPER_MAGIC, "devpts"),
    ]
    .into_iter()
    .find(|(magic, _)| *magic == kind)
    .map(|(_, name)| name)
}

fn kind_name(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_fifo() {
        "a pipe"
    } else if t.is_char_device() {
        "a character device (tty, /dev/null, ...)"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_file() {
        "a regular file (or memfd)"
    } else {
        "of an unknown type"
    }
}

/// The snapshot format named by a client: `png` or `npy` (a leading dot and
/// any case are accepted).
pub fn snapshot_format(format: &str) -> Result<OutputKind, SdiError> {
    let f = format.strip_prefix('.').unwrap_or(format);
    if f.eq_ignore_ascii_case("png") {
        Ok(OutputKind::Png)
    } else if f.eq_ignore_ascii_case("npy") {
        Ok(OutputKind::Npy)
    } else {
        Err(SdiError::OutOfRange(format!(
            "unknown snapshot format '{}': allowed png, npy",
            format.escape_debug()
        )))
    }
}

/// The name a client gives a recording it passed by descriptor: shown in
/// the `Recording` property, never opened. Empty means "(descriptor)".
pub fn recording_label(label: &str) -> Result<String, SdiError> {
    if label.len() > MAX_LABEL_BYTES {
        return Err(SdiError::InvalidPath(format!(
            "label of {} bytes is too long: at most {MAX_LABEL_BYTES}",
            label.len()
        )));
    }
    if label.chars().any(char::is_control) {
        return Err(SdiError::InvalidPath(format!(
            "label '{}' contains control characters",
            label.escape_debug()
        )));
    }
    Ok(if label.is_empty() {
        "(descriptor)".to_owned()
    } else {
        label.to_owned()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;
    use std::os::unix::net::UnixStream;

    fn rejected(fd: OwnedFd) -> bool {
        matches!(output_file(fd), Err(SdiError::InvalidFd(_)))
    }

    #[test]
    fn accepts_only_empty_writable_regular_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        let f = File::create(&path).unwrap();
        assert!(output_file(f.into()).is_ok());
        // Read-only.
        assert!(rejected(File::open(&path).unwrap().into()));
        // Not empty.
        let mut f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        f.write_all(b"data").unwrap();
        assert!(rejected(f.into()));
        // Socket, pipe, character device, directory.
        let (a, _b) = UnixStream::pair().unwrap();
        assert!(rejected(a.into()));
        let (r, w) = nix::unistd::pipe().unwrap();
        assert!(rejected(w));
        drop(r);
        let null = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/null")
            .unwrap();
        assert!(rejected(null.into()));
        assert!(rejected(File::open(dir.path()).unwrap().into()));
        // An empty, writable regular file on procfs.
        let comm = std::fs::OpenOptions::new()
            .write(true)
            .open("/proc/self/comm")
            .unwrap();
        assert!(rejected(comm.into()));
    }

    fn refusal(fd: OwnedFd) -> String {
        match stream_target(fd) {
            Err(SdiError::InvalidFd(m)) => m,
            other => panic!("accepted: {other:?}"),
        }
    }

    #[test]
    fn streams_take_only_what_sdid_cannot_read_itself() {
        // A pair made by this process: its other end is "sdid's own" (a
        // client's pair is taken: tests/tests/integration/dbus_stream_slots.rs).
        let (a, _b) = UnixStream::pair().unwrap();
        assert!(refusal(a.into()).contains("sdid's own"));
        let (r, w) = nix::unistd::pipe().unwrap();
        assert!(stream_target(w).is_ok());
        assert!(refusal(r).contains("open for reading"));
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
        let rw = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&fifo)
            .unwrap();
        assert!(refusal(rw.into()).contains("open for reading"));
        let f = File::create(dir.path().join("f")).unwrap();
        let m = refusal(f.into());
        assert!(m.starts_with("the descriptor is a regular file"), "{m}");
        assert!(m.contains("pipe") && m.contains("socket"), "{m}");
        // A datagram socket, an unconnected one.
        let (d, _e) = std::os::unix::net::UnixDatagram::pair().unwrap();
        assert!(refusal(d.into()).contains("not a Unix stream socket"));
        let lone = nix::sys::socket::socket(
            nix::sys::socket::AddressFamily::Unix,
            nix::sys::socket::SockType::Stream,
            nix::sys::socket::SockFlag::empty(),
            None,
        )
        .unwrap();
        assert!(refusal(lone).contains("not connected"));
    }

    #[test]
    fn formats_and_labels() {
        assert_eq!(snapshot_format("PNG").unwrap(), OutputKind::Png);
        assert_eq!(snapshot_format(".npy").unwrap(), OutputKind::Npy);
        assert!(matches!(
            snapshot_format("jpg"),
            Err(SdiError::OutOfRange(_))
        ));
        assert_eq!(recording_label("").unwrap(), "(descriptor)");
        assert!(recording_label("a\nb").is_err());
        assert!(recording_label(&"x".repeat(MAX_LABEL_BYTES + 1)).is_err());
    }
}
