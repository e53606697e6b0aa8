//! A minimal V4L2 capture reader (mmap streaming): what the tests and
//! benchmarks use to read a loopback node as an application would, with
//! each buffer's timestamp and sequence. By hand over [`crate::sys`], like
//! the writer: the `v4l` crate's bindings need libclang at build time,
//! which a machine with only build-essential lacks.

use std::fs::{File, OpenOptions};
use std::os::fd::AsFd;
use std::path::Path;
use std::time::Duration;

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

use crate::error::GlueError;
use crate::sys;

/// One dequeued buffer.
pub struct Captured<'a> {
    /// The buffer's bytes (`bytesused` of them).
    pub bytes: &'a [u8],
    /// The writer's timestamp, microseconds (CLOCK_MONOTONIC for sdid).
    pub timestamp_us: i64,
    pub sequence: u32,
}

/// The format a capture node announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureFormat {
    pub width: u32,
    pub height: u32,
    /// FourCC, little-endian (`u32::from_le_bytes(*b"YUYV")`).
    pub fourcc: u32,
}

/// A capture node streaming through mmap'ed driver buffers.
pub struct CaptureReader {
    file: File,
    maps: Vec<sys::Mapping>,
    /// The buffer handed out by the last [`CaptureReader::next`], queued
    /// again at the next call.
    held: Option<u32>,
}

fn err(op: &'static str) -> impl Fn(Errno) -> GlueError {
    move |e| GlueError::from_errno(op, e)
}

fn io(op: &'static str) -> impl Fn(std::io::Error) -> GlueError {
    move |e| GlueError::Io {
        op,
        errno: Errno::from_raw(e.raw_os_error().unwrap_or(libc::EIO)),
    }
}

/// The driver name of a V4L2 node (`"v4l2 loopback"` for v4l2loopback).
pub fn driver_of(path: &Path) -> Result<String, GlueError> {
    let file = File::open(path).map_err(io("open"))?;
    let mut caps = sys::v4l2_capability::default();
    sys::querycap(file.as_fd(), &mut caps).map_err(err("VIDIOC_QUERYCAP"))?;
    let end = caps.driver.iter().position(|&b| b == 0).unwrap_or(16);
    Ok(String::from_utf8_lossy(&caps.driver[..end]).into_owned())
}

/// The capture format `path` announces (VIDIOC_G_FMT).
pub fn capture_format(path: &Path) -> Result<CaptureFormat, GlueError> {
    let file = File::open(path).map_err(io("open"))?;
    format_of(&file)
}

fn format_of(file: &File) -> Result<CaptureFormat, GlueError> {
    let mut f = sys::v4l2_format {
        type_: sys::V4L2_BUF_TYPE_VIDEO_CAPTURE,
        ..Default::default()
    };
    sys::g_fmt(file.as_fd(), &mut f).map_err(err("VIDIOC_G_FMT"))?;
    let pix = f.pix();
    Ok(CaptureFormat {
        width: pix.width,
        height: pix.height,
        fourcc: pix.pixelformat,
    })
}

impl CaptureReader {
    /// Opens `path`, requests `buffers` mmap buffers, queues them and
    /// starts streaming.
    pub fn open(path: &Path, buffers: u32) -> Result<Self, GlueError> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .map_err(io("open"))?;
        let mut req = sys::v4l2_requestbuffers {
            count: buffers,
            type_: sys::V4L2_BUF_TYPE_VIDEO_CAPTURE,
            memory: sys::V4L2_MEMORY_MMAP,
            ..Default::default()
        };
        sys::reqbufs(file.as_fd(), &mut req).map_err(err("VIDIOC_REQBUFS"))?;
        let mut maps = Vec::with_capacity(req.count as usize);
        for index in 0..req.count {
            let mut buf = Self::buffer(index);
            sys::querybuf(file.as_fd(), &mut buf).map_err(err("VIDIOC_QUERYBUF"))?;
            maps.push(
                sys::Mapping::new(file.as_fd(), buf.length as usize, buf.mmap_offset())
                    .map_err(err("mmap"))?,
            );
            sys::qbuf(file.as_fd(), &mut buf).map_err(err("VIDIOC_QBUF"))?;
        }
        let kind = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        sys::streamon(file.as_fd(), &kind).map_err(err("VIDIOC_STREAMON"))?;
        Ok(Self {
            file,
            maps,
            held: None,
        })
    }

    fn buffer(index: u32) -> sys::v4l2_buffer {
        sys::v4l2_buffer {
            index,
            type_: sys::V4L2_BUF_TYPE_VIDEO_CAPTURE,
            memory: sys::V4L2_MEMORY_MMAP,
            ..Default::default()
        }
    }

    /// The format the node streams.
    pub fn format(&self) -> Result<CaptureFormat, GlueError> {
        format_of(&self.file)
    }

    /// Driver buffers granted.
    pub fn buffers(&self) -> usize {
        self.maps.len()
    }

    /// Waits up to `timeout` for the next frame and dequeues it (the one
    /// returned before goes back to the driver first).
    pub fn next(&mut self, timeout: Duration) -> Result<Captured<'_>, GlueError> {
        if let Some(index) = self.held.take() {
            let mut buf = Self::buffer(index);
            sys::qbuf(self.file.as_fd(), &mut buf).map_err(err("VIDIOC_QBUF"))?;
        }
        let ms = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(self.file.as_fd(), PollFlags::POLLIN)];
        let ready = poll(&mut fds, PollTimeout::from(ms)).map_err(err("poll"))?;
        if ready == 0 {
            return Err(GlueError::Io {
                op: "waiting for a frame",
                errno: Errno::ETIMEDOUT,
            });
        }
        let mut buf = Self::buffer(0);
        sys::dqbuf(self.file.as_fd(), &mut buf).map_err(err("VIDIOC_DQBUF"))?;
        self.held = Some(buf.index);
        let map = self
            .maps
            .get(buf.index as usize)
            .ok_or(GlueError::InvalidArgument {
                op: "VIDIOC_DQBUF",
                detail: format!("buffer index {} of {}", buf.index, self.maps.len()),
            })?;
        let bytes = map.as_slice();
        let used = (buf.bytesused as usize).min(bytes.len());
        Ok(Captured {
            bytes: &bytes[..used],
            timestamp_us: buf.timestamp.tv_sec * 1_000_000 + buf.timestamp.tv_usec,
            sequence: buf.sequence,
        })
    }
}

impl Drop for CaptureReader {
    fn drop(&mut self) {
        let kind = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        let _ = sys::streamoff(self.file.as_fd(), &kind);
    }
}
