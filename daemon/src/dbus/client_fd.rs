//! Output files passed in by clients as Unix file descriptors (D-Bus type
//! `h`). The client opens the file as itself, wherever it may write; the
//! sandboxed daemon (ProtectHome, PrivateTmp, ProtectSystem=strict) only
//! writes through the descriptor and never sees a path.

use std::fs::File;
use std::os::fd::{AsRawFd, OwnedFd};

use nix::fcntl::{fcntl, FcntlArg, OFlag};

use super::errors::SdiError;
use super::paths::OutputKind;

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

/// Accepts `fd` if it is a pipe or socket open for writing, the reading
/// end held by the client (`StreamFrames`), and makes its writes blocking:
/// the daemon writes from a thread of its own, so a stalled reader only
/// stalls that thread.
pub fn stream_pipe(fd: OwnedFd) -> Result<File, SdiError> {
    use std::os::unix::fs::FileTypeExt;
    let bad = |why: String| SdiError::InvalidFd(why);
    let file = File::from(fd);
    let meta = file
        .metadata()
        .map_err(|e| bad(format!("fstat on the descriptor failed: {e}")))?;
    let t = meta.file_type();
    if !t.is_fifo() && !t.is_socket() {
        let what = kind_name(&meta);
        return Err(bad(format!(
            "the descriptor is {what}: pass the writing end of a pipe or a socket"
        )));
    }
    let flags = fcntl(file.as_raw_fd(), FcntlArg::F_GETFL)
        .map_err(|e| bad(format!("fcntl(F_GETFL) on the descriptor failed: {e}")))?;
    let flags = OFlag::from_bits_truncate(flags);
    let access = flags & OFlag::O_ACCMODE;
    if access != OFlag::O_WRONLY && access != OFlag::O_RDWR {
        return Err(bad(
            "the descriptor is the reading end: pass the writing end".into(),
        ));
    }
    fcntl(
        file.as_raw_fd(),
        FcntlArg::F_SETFL(flags - OFlag::O_NONBLOCK),
    )
    .map_err(|e| bad(format!("fcntl(F_SETFL) on the descriptor failed: {e}")))?;
    Ok(file)
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
    } else {
        "not a regular file"
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

    #[test]
    fn streams_take_only_writable_pipes_and_sockets() {
        let (a, _b) = UnixStream::pair().unwrap();
        assert!(stream_pipe(a.into()).is_ok());
        let (r, w) = nix::unistd::pipe().unwrap();
        assert!(stream_pipe(w).is_ok());
        assert!(matches!(stream_pipe(r), Err(SdiError::InvalidFd(_))));
        let dir = tempfile::tempdir().unwrap();
        let f = File::create(dir.path().join("f")).unwrap();
        assert!(matches!(stream_pipe(f.into()), Err(SdiError::InvalidFd(_))));
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
