//! Fallback sink when no v4l2loopback device exists: a YUV4MPEG2 (C444)
//! stream on stdout or into a FIFO, which `ffplay`/`ffmpeg` read directly.
//!
//! Every reader of the FIFO gets the stream header first. A FIFO keeps one
//! pipe while any end is open, so a reader that opens the path while we
//! write to an earlier reader would join that pipe mid-stream (or, after
//! the earlier reader closed, read its leftover partial frame). So as soon
//! as a reader is connected, a fresh FIFO is renamed over the path
//! ([`renew_fifo`]): the next reader opens a pipe nobody writes to, blocks
//! in `open` until we take it (the next frame after the current reader has
//! gone), and starts with the header. The only window left is the few
//! microseconds between our `open` and the `rename`, in which a second
//! reader opening at the same moment would share the first one's pipe.

use std::fs::File;
use std::io::{self, IoSlice, Write};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use sdi_core::view::{
    no_signal_stripes_rgb8, rgb8_to_yuv444_planes, yuv444_planes_mut, PixelFormat, ViewRenderer,
};

/// What starts every frame of the stream.
const FRAME_TAG: &[u8] = b"FRAME\n";

use super::{Sink, SinkError, SinkInfo, SinkKindName};
use crate::out_frame::OutFrame;

enum Target {
    Stdout {
        broken: bool,
    },
    /// A FIFO opened (non-blocking) whenever a reader is present.
    Fifo {
        path: PathBuf,
        reader: Option<FifoReader>,
    },
}

/// The write end of the FIFO while a reader is connected.
struct FifoReader {
    file: File,
    header_sent: bool,
}

pub struct Y4mSink {
    target: Target,
    width: usize,
    height: usize,
    frame_rate_hz: f64,
    /// Renders each frame's Y, U and V planes at the sensor size; the
    /// card's, made once.
    view: ViewRenderer,
    card: Vec<u8>,
    header_sent: bool,
}

/// The FIFO the fallback stream goes into unless stdout is a pipe or "-" was
/// asked for: in the runtime directory.
pub fn default_fifo_path() -> PathBuf {
    let dir = std::env::var_os("XDG_RUNTIME_DIR")
        .map(PathBuf::from)
        .filter(|d| d.is_dir())
        .unwrap_or_else(|| PathBuf::from("/tmp"));
    dir.join("sdid-view.y4m")
}

impl Y4mSink {
    /// `path`: "-" for stdout, or a FIFO path; `None` picks stdout when it is
    /// a pipe (`sdid | ffplay -`), else the default FIFO ([`choose`]).
    pub fn new(
        path: Option<&Path>,
        width: usize,
        height: usize,
        frame_rate_hz: f64,
    ) -> io::Result<Self> {
        let target = match choose(path, stdout_is_pipe()) {
            Choice::Stdout => {
                fit_pipe(&io::stdout(), FRAME_TAG.len() + 3 * width * height);
                Target::Stdout { broken: false }
            }
            Choice::Fifo(p) => fifo(&p)?,
        };
        Ok(Self {
            target,
            width,
            height,
            frame_rate_hz,
            view: ViewRenderer::new(width, height, PixelFormat::Rgb24),
            card: yuv444_planes(&no_signal_stripes_rgb8(width, height)),
            header_sent: false,
        })
    }

    /// Where a user points `ffplay`.
    pub fn location(&self) -> String {
        match &self.target {
            Target::Stdout { .. } => "stdout".into(),
            Target::Fifo { path, .. } => path.display().to_string(),
        }
    }

    fn header(&self) -> String {
        let (num, den) = ((self.frame_rate_hz * 1000.0).round().max(1.0) as u64, 1000);
        format!(
            "YUV4MPEG2 W{} H{} F{num}:{den} Ip A1:1 C444 XCOLORRANGE=FULL\n",
            self.width, self.height
        )
    }

    /// Writes one frame of `planes` (Y, U, V).
    fn send(&mut self, planes: &[u8]) -> Result<(), SinkError> {
        let header = self.header();
        let frame_bytes = FRAME_TAG.len() + planes.len();
        match &mut self.target {
            Target::Stdout { broken } => {
                if *broken {
                    return Ok(());
                }
                let mut so = io::stdout().lock();
                let r = (|| {
                    if !self.header_sent {
                        so.write_all(header.as_bytes())?;
                    }
                    write_frame(&mut so, planes)?;
                    so.flush()
                })();
                match r {
                    Ok(()) => self.header_sent = true,
                    Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {
                        tracing::warn!("stdout reader went away; no longer streaming");
                        *broken = true;
                    }
                    Err(e) => return Err(e.into()),
                }
            }
            Target::Fifo { path, reader } => {
                if reader.is_none() {
                    // O_NONBLOCK: fails with ENXIO while nobody reads, which we skip.
                    match std::fs::OpenOptions::new()
                        .write(true)
                        .custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW)
                        .open(&*path)
                    {
                        Ok(f) => {
                            if !f.metadata()?.file_type().is_fifo() {
                                return Err(io::Error::new(
                                    io::ErrorKind::AlreadyExists,
                                    format!("{} is no longer a FIFO", path.display()),
                                )
                                .into());
                            }
                            set_blocking(&f)?;
                            fit_pipe(&f, frame_bytes);
                            if let Err(e) = renew_fifo(path) {
                                tracing::warn!(path = %path.display(), "y4m: cannot put a fresh FIFO in place ({e}); a reader opening while this one reads shares its pipe");
                            }
                            *reader = Some(FifoReader {
                                file: f,
                                header_sent: false,
                            });
                            tracing::info!(path = %path.display(), "y4m reader connected");
                        }
                        Err(e) if e.raw_os_error() == Some(libc::ENXIO) => return Ok(()),
                        Err(e) => return Err(e.into()),
                    }
                }
                if let Some(r) = reader.as_mut() {
                    let result = (|| {
                        if !r.header_sent {
                            r.file.write_all(header.as_bytes())?;
                            r.header_sent = true;
                        }
                        write_frame(&mut r.file, planes)
                    })();
                    match result {
                        Ok(()) => {}
                        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {
                            tracing::info!(path = %path.display(), "y4m reader went away");
                            *reader = None;
                        }
                        Err(e) => return Err(e.into()),
                    }
                }
            }
        }
        Ok(())
    }
}

/// The Y, U and V planes of an RGB8 picture, one after the other.
fn yuv444_planes(rgb: &[u8]) -> Vec<u8> {
    let mut planes = vec![0; rgb.len() / 3 * 3];
    let [y, u, v] = yuv444_planes_mut(&mut planes);
    rgb8_to_yuv444_planes(rgb, y, u, v);
    planes
}

/// The tag and `planes` as one frame, gathered by the kernel (no copy of
/// the planes behind the tag).
fn write_frame(w: &mut impl Write, planes: &[u8]) -> io::Result<()> {
    let mut parts = [IoSlice::new(FRAME_TAG), IoSlice::new(planes)];
    let mut parts = &mut parts[..];
    while !parts.is_empty() {
        match w.write_vectored(parts) {
            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
            Ok(n) => IoSlice::advance_slices(&mut parts, n),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Where the stream goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Choice {
    Stdout,
    Fifo(PathBuf),
}

/// Stdout only when asked ("-") or when it is a pipe; a terminal, a regular
/// file (`sdid > log.txt`), /dev/null or the journal's socket get the FIFO,
/// so y4m never ends up in a log.
pub fn choose(path: Option<&Path>, stdout_is_pipe: bool) -> Choice {
    match path {
        Some(p) if p == Path::new("-") => Choice::Stdout,
        Some(p) => Choice::Fifo(p.to_owned()),
        None if stdout_is_pipe => Choice::Stdout,
        None => Choice::Fifo(default_fifo_path()),
    }
}

/// True when stdout is a pipe or FIFO.
fn stdout_is_pipe() -> bool {
    use std::os::fd::AsFd;
    io::stdout()
        .as_fd()
        .try_clone_to_owned()
        .and_then(|fd| File::from(fd).metadata())
        .is_ok_and(|m| m.file_type().is_fifo())
}

fn fifo(path: &Path) -> io::Result<Target> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_fifo() => {}
        Ok(_) => {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!("{} exists and is not a FIFO", path.display()),
            ))
        }
        Err(_) => nix::unistd::mkfifo(path, nix::sys::stat::Mode::from_bits_truncate(0o600))
            .map_err(io::Error::from)?,
    }
    Ok(Target::Fifo {
        path: path.to_owned(),
        reader: None,
    })
}

/// Replaces the FIFO at `path` by a new one with the same mode, owner and
/// group (made beside it, then renamed over it), so the next reader gets a
/// pipe of its own instead of joining the connected reader's.
fn renew_fifo(path: &Path) -> io::Result<()> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let old = std::fs::symlink_metadata(path)?;
    let name = path
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "FIFO path has no name"))?;
    let mut next_name = std::ffi::OsString::from(".");
    next_name.push(name);
    next_name.push(".next");
    let next = path.with_file_name(next_name);
    match std::fs::remove_file(&next) {
        Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let mode = nix::sys::stat::Mode::from_bits_truncate(old.permissions().mode() & 0o777);
    nix::unistd::mkfifo(&next, mode).map_err(io::Error::from)?;
    // Owner, group and mode by descriptor (O_NOFOLLOW: never through a
    // link swapped in meanwhile); opening a FIFO nobody writes to for
    // reading does not block with O_NONBLOCK.
    let made = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW)
        .open(&next)?;
    let meta = made.metadata()?;
    if !meta.file_type().is_fifo() {
        return Err(io::Error::new(
            io::ErrorKind::AlreadyExists,
            format!("{} is not the FIFO just made", next.display()),
        ));
    }
    if (meta.uid(), meta.gid()) != (old.uid(), old.gid()) {
        // Only root can give the FIFO away; anyone else keeps their own.
        let _ = std::os::unix::fs::fchown(&made, Some(old.uid()), Some(old.gid()));
    }
    // The umask may have cut the mode: set it as it was.
    made.set_permissions(old.permissions())?;
    drop(made);
    std::fs::rename(&next, path)
}

/// Lets the pipe behind `fd` hold a whole frame of `bytes`, so a frame is
/// one write instead of pieces of the default 64 KiB, each waiting for the
/// reader (two context switches apiece). A reader that keeps up gets each
/// frame no later; one that lags has at most one more frame buffered.
/// Best effort: not a pipe, or above the kernel's pipe-max-size, it stays.
fn fit_pipe(fd: &impl std::os::fd::AsFd, bytes: usize) {
    use nix::fcntl::{fcntl, FcntlArg};
    use std::os::fd::AsRawFd;
    let size = i32::try_from(bytes).unwrap_or(i32::MAX);
    if let Err(e) = fcntl(fd.as_fd().as_raw_fd(), FcntlArg::F_SETPIPE_SZ(size)) {
        tracing::debug!("y4m: pipe kept at its size ({e})");
    }
}

fn set_blocking(f: &File) -> io::Result<()> {
    use nix::fcntl::{fcntl, FcntlArg, OFlag};
    use std::os::fd::AsRawFd;
    let flags = fcntl(f.as_raw_fd(), FcntlArg::F_GETFL).map_err(io::Error::from)?;
    let flags = OFlag::from_bits_truncate(flags) & !OFlag::O_NONBLOCK;
    fcntl(f.as_raw_fd(), FcntlArg::F_SETFL(flags)).map_err(io::Error::from)?;
    Ok(())
}

impl Sink for Y4mSink {
    fn info(&self) -> SinkInfo {
        SinkInfo {
            kind: SinkKindName::Y4m,
            device: self.location(),
            format: "C444".into(),
            width: self.width as u32,
            height: self.height as u32,
        }
    }

    fn write(&mut self, frame: &OutFrame) -> Result<(), SinkError> {
        let img = &frame.output.signed_dn;
        if img.width != self.width || img.height != self.height {
            return Ok(());
        }
        let planes = frame.view_yuv444(&mut self.view)?;
        self.send(&planes)
    }

    fn write_no_signal(&mut self, _timestamp_us: u64) -> Result<(), SinkError> {
        let card = std::mem::take(&mut self.card);
        let sent = self.send(&card);
        self.card = card;
        sent
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads what is in the FIFO now (non-blocking reader).
    fn drain(f: &mut File) -> Vec<u8> {
        use std::io::Read;
        let mut all = Vec::new();
        let mut buf = [0u8; 4096];
        loop {
            match f.read(&mut buf) {
                Ok(0) => return all,
                Ok(n) => all.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return all,
                Err(e) => panic!("read the FIFO: {e}"),
            }
        }
    }

    fn reader(path: &Path) -> File {
        std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)
            .unwrap()
    }

    /// A reader that opens while another reads gets a pipe of its own: it
    /// sees nothing of the first reader's stream, and its first bytes are
    /// the header once the first reader has gone, however soon after.
    #[test]
    fn every_fifo_reader_starts_with_the_header() {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("view.y4m");
        let mut sink = Y4mSink::new(Some(&path), 4, 2, 5.0).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o640)).unwrap();
        let ino = std::fs::metadata(&path).unwrap().ino();
        sink.write_no_signal(0).unwrap(); // nobody reads: skipped
        let mut first = reader(&path);
        sink.write_no_signal(0).unwrap();
        assert!(drain(&mut first).starts_with(b"YUV4MPEG2 W4 H2"));
        let meta = std::fs::metadata(&path).unwrap();
        assert_ne!(meta.ino(), ino, "no fresh FIFO at the path");
        assert!(meta.file_type().is_fifo());
        assert_eq!(meta.permissions().mode() & 0o777, 0o640);
        let mut second = reader(&path);
        sink.write_no_signal(0).unwrap();
        assert!(drain(&mut first).starts_with(b"FRAME\n"));
        assert!(
            drain(&mut second).is_empty(),
            "the second reader joined the first one's pipe"
        );
        drop(first);
        sink.write_no_signal(0).unwrap(); // EPIPE: the first reader is gone
        sink.write_no_signal(0).unwrap(); // connects the second
        let got = drain(&mut second);
        assert!(
            got.starts_with(b"YUV4MPEG2 W4 H2"),
            "{:?}",
            &got[..got.len().min(16)]
        );
    }

    /// A reader's pipe holds a whole frame (here more than the default
    /// 64 KiB), so a frame is written in one go.
    #[test]
    fn the_pipe_holds_a_whole_frame() {
        use nix::fcntl::{fcntl, FcntlArg};
        use std::os::fd::AsRawFd;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("view.y4m");
        let mut sink = Y4mSink::new(Some(&path), 320, 240, 60.0).unwrap();
        let mut r = reader(&path);
        sink.write_no_signal(0).unwrap();
        let size = fcntl(r.as_raw_fd(), FcntlArg::F_GETPIPE_SZ).unwrap();
        assert!(size as usize >= 6 + 3 * 320 * 240, "{size} bytes");
        assert!(drain(&mut r).starts_with(b"YUV4MPEG2 W320 H240"));
    }

    #[test]
    fn a_link_at_the_fifo_path_is_not_written_through() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("view.y4m");
        let mut sink = Y4mSink::new(Some(&path), 4, 2, 5.0).unwrap();
        let victim = dir.path().join("victim");
        std::fs::write(&victim, b"keep").unwrap();
        std::fs::remove_file(&path).unwrap();
        std::os::unix::fs::symlink(&victim, &path).unwrap();
        assert!(sink.write_no_signal(0).is_err());
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep");
    }

    /// A writer that takes at most 5 bytes of one slice per call.
    struct Trickle(Vec<u8>);

    impl Write for Trickle {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            let n = buf.len().min(5);
            self.0.extend_from_slice(&buf[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_frame_is_its_tag_and_planes_however_the_writes_split() {
        let planes: Vec<u8> = (0..=200).collect();
        let mut w = Trickle(Vec::new());
        write_frame(&mut w, &planes).unwrap();
        assert_eq!(&w.0[..6], FRAME_TAG);
        assert_eq!(&w.0[6..], &planes[..]);
    }

    #[test]
    fn stdout_only_when_asked_or_a_pipe() {
        assert_eq!(choose(Some(Path::new("-")), false), Choice::Stdout);
        assert_eq!(choose(None, true), Choice::Stdout);
        assert_eq!(choose(None, false), Choice::Fifo(default_fifo_path()));
        let p = Path::new("/run/x.y4m");
        assert_eq!(choose(Some(p), true), Choice::Fifo(p.to_owned()));
    }
}
