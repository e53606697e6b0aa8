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
use std::io::{self, Write};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use super::{Sink, SinkError, SinkInfo};
use sdi_core::display::DisplayMap;
use sdi_core::mode::ModeOutput;

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
    rgb: Vec<u8>,
    out: Vec<u8>,
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
            Choice::Stdout => Target::Stdout { broken: false },
            Choice::Fifo(p) => fifo(&p)?,
        };
        Ok(Self {
            target,
            width,
            height,
            frame_rate_hz,
            rgb: vec![0; width * height * 3],
            out: Vec::with_capacity(width * height * 3 + 16),
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

    fn pack_frame(&mut self) {
        let n = self.width * self.height;
        self.out.clear();
        self.out.extend_from_slice(b"FRAME\n");
        self.out.resize(6 + 3 * n, 0);
        let (y, uv) = self.out[6..].split_at_mut(n);
        let (u, v) = uv.split_at_mut(n);
        yuv444_planes(&self.rgb, y, u, v);
    }

    fn send(&mut self) -> Result<(), SinkError> {
        let header = self.header();
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
                    so.write_all(&self.out)?;
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
                        r.file.write_all(&self.out)
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

/// BT.601 full-range RGB -> Y, U, V planes in 16.16 fixed point: within one
/// code of the float formula (tested on every colour), and integer-only so
/// it vectorizes; the float version with `round()` was 57% of sdid's CPU in
/// raw mode (tests/bench/daemon_cpu.sh).
fn yuv444_planes(rgb: &[u8], y: &mut [u8], u: &mut [u8], v: &mut [u8]) {
    const HALF: i32 = 1 << 15;
    const OFFSET: i32 = 128 << 16;
    for (((px, y), u), v) in rgb.chunks_exact(3).zip(y).zip(u).zip(v) {
        let (r, g, b) = (i32::from(px[0]), i32::from(px[1]), i32::from(px[2]));
        // Coefficients x 65536: Y 0.299 0.587 0.114; U -0.168736 -0.331264
        // 0.5; V 0.5 -0.418688 -0.081312 (each row sums to 65536 or 0).
        *y = ((19595 * r + 38470 * g + 7471 * b + HALF) >> 16) as u8;
        *u = ((-11059 * r - 21709 * g + 32768 * b + OFFSET + HALF) >> 16).clamp(0, 255) as u8;
        *v = ((32768 * r - 27439 * g - 5329 * b + OFFSET + HALF) >> 16).clamp(0, 255) as u8;
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
            kind: "y4m",
            device: self.location(),
            format: "C444".into(),
            width: self.width as u32,
            height: self.height as u32,
        }
    }

    fn write(&mut self, output: &ModeOutput, display: &DisplayMap) -> Result<(), SinkError> {
        if output.signed_dn.width != self.width || output.signed_dn.height != self.height {
            return Ok(());
        }
        display.render_output_rgb8(output, &mut self.rgb);
        self.pack_frame();
        self.send()
    }

    fn write_no_signal(&mut self, _timestamp_us: u64) -> Result<(), SinkError> {
        // Dark grey with a diagonal stripe pattern.
        for (i, px) in self.rgb.chunks_exact_mut(3).enumerate() {
            let (x, y) = (i % self.width, i / self.width);
            let g = if (x + y) / 16 % 2 == 0 { 40 } else { 60 };
            px.copy_from_slice(&[g, g, g]);
        }
        self.pack_frame();
        self.send()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_point_yuv_is_within_one_code_of_bt601_for_every_colour() {
        let rgb: Vec<u8> = (0..1u32 << 24)
            .flat_map(|c| [c as u8, (c >> 8) as u8, (c >> 16) as u8])
            .collect();
        let n = rgb.len() / 3;
        let (mut y, mut u, mut v) = (vec![0; n], vec![0; n], vec![0; n]);
        yuv444_planes(&rgb, &mut y, &mut u, &mut v);
        let mut worst = 0;
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            let (r, g, b) = (f32::from(px[0]), f32::from(px[1]), f32::from(px[2]));
            let fy = (0.299 * r + 0.587 * g + 0.114 * b).round();
            let fu = (128.0 - 0.168_736 * r - 0.331_264 * g + 0.5 * b)
                .round()
                .clamp(0.0, 255.0);
            let fv = (128.0 + 0.5 * r - 0.418_688 * g - 0.081_312 * b)
                .round()
                .clamp(0.0, 255.0);
            for (ours, float) in [(y[i], fy), (u[i], fu), (v[i], fv)] {
                worst = worst.max((f32::from(ours) - float).abs() as u32);
            }
        }
        assert!(worst <= 1, "worst difference {worst} codes");
        // Grey stays grey: U = V = 128 exactly.
        for g in 0..=255u8 {
            let (mut y, mut u, mut v) = ([0], [0], [0]);
            yuv444_planes(&[g, g, g], &mut y, &mut u, &mut v);
            assert_eq!((y[0], u[0], v[0]), (g, 128, 128));
        }
    }

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

    #[test]
    fn stdout_only_when_asked_or_a_pipe() {
        assert_eq!(choose(Some(Path::new("-")), false), Choice::Stdout);
        assert_eq!(choose(None, true), Choice::Stdout);
        assert_eq!(choose(None, false), Choice::Fifo(default_fifo_path()));
        let p = Path::new("/run/x.y4m");
        assert_eq!(choose(Some(p), true), Choice::Fifo(p.to_owned()));
    }
}
