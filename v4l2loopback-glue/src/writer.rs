//! The producer side of one loopback node: negotiates the format before
//! readers open, keeps the node capture-ready and writes frames without
//! allocating.

use std::fs::File;
use std::os::fd::{AsFd, AsRawFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use nix::errno::Errno;

use crate::device::ModuleVersion;
use crate::error::err;
use crate::format::{IoMethod, LoopbackFormat, PixelFormat};
use crate::sys;
use crate::GlueError;
use sdi_core::view::no_signal_card;

/// Driver buffers requested for mmap streaming; the writer's request sets
/// the node's ring, which readers share. v4l2loopback grants at most its
/// `max_buffers` (default 2, module parameter or
/// [`crate::CreateOptions::max_buffers`]); see [`DriverFeatures::buffers`].
/// Not more than 10: OpenCV's V4L2 capture indexes a fixed array of 10
/// buffers by the index the driver hands out (it failed on a 32-buffer ring).
const MMAP_BUFFERS: u32 = 10;
/// The ring we ask of modules without a locked buffer queue (0.12.x): as
/// many as the common readers ask for (Chromium, Firefox, OpenCV and
/// GStreamer's v4l2src all ask 4; ffmpeg asks more), so none of them
/// shrinks it. 0.12.7's REQBUFS shrinks the shared ring to a reader's count
/// and unlinks the surplus buffers from its output list without the
/// device lock; our QBUF of one of them in that window is a kernel BUG
/// (`list_del` corruption in `buffer_written`, a panic in the VM). The
/// ring never grows back on 0.12.7 anyway, so after the first such reader
/// it was 4 whatever we asked (docs/loopback.md).
const MMAP_BUFFERS_UNLOCKED_QUEUE: u32 = 4;
/// Driver name reported by VIDIOC_QUERYCAP.
const LOOPBACK_DRIVER: &str = "v4l2 loopback";

enum Io {
    /// Driver buffers, filled round-robin (`next` is the next index).
    ///
    /// We do not take the index from VIDIOC_DQBUF: v4l2loopback 0.12.7
    /// returns the *most recently queued* output buffer there
    /// (`list_entry(dev->outbufs_list.prev, ...)` in `vidioc_dqbuf`), so a
    /// writer following DQBUF refills the one buffer readers are copying
    /// from, every frame after the first pass: torn frames and, with
    /// ffmpeg's zero-copy capture, the same buffer index handed out while
    /// still held. Both 0.12.7 and 0.15 accept QBUF of any allocated
    /// output buffer at any time, and round-robin over `MMAP_BUFFERS`
    /// leaves the last three frames untouched while readers copy them.
    ///
    /// A reader's REQBUFS with fewer buffers shrinks 0.12.7's ring for
    /// everyone (`dev->used_buffers`), and QBUF of our index `i` then marks
    /// the driver's buffer `i % used_buffers` as the newest frame: filling our
    /// own mapping of `i` would publish whatever that buffer held frames ago
    /// (a frame of the previous mode after a switch, seen by GStreamer's
    /// v4l2src). So each frame goes into the memory QUERYBUF names for `i`
    /// now, found among `offsets` (the mmap offset of each of `maps`).
    Mmap {
        maps: Vec<sys::Mapping>,
        offsets: Vec<u32>,
        next: usize,
    },
    /// Plain `write()` of the caller's frame.
    Write,
}

/// Which optional driver features took effect at open.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DriverFeatures {
    /// `keep_format` control set: the format survives our restarts.
    pub keep_format: bool,
    /// `sustain_framerate` control on: the driver repeats the last frame
    /// when the writer is 1.5 frame intervals late. Off from
    /// [`LoopbackWriter::open`]: the repeat hands each reader again the
    /// buffer it dequeued last (`get_capture_buffer`, `reread_count`, in
    /// 0.12.7 and 0.15 alike), whether or not the reader queued it back; a
    /// reader still holding it (GStreamer's `v4l2src ! filesink`: the sink
    /// keeps its last buffer) then fails ("buffer 3 was not queued, this
    /// indicate a driver bug"). Without it readers wait for the next frame.
    pub sustain_framerate: bool,
    /// Client-usage event subscribed (0.13+).
    pub client_usage_event: bool,
    /// S_PARM accepted our frame interval.
    pub frame_interval: bool,
    /// Driver buffers in the ring (mmap: granted by REQBUFS; write(): 0).
    ///
    /// v4l2loopback hands readers the very buffers the writer fills, with
    /// no ownership between them: a reader still copying a frame when the
    /// writer comes round the ring again gets a torn frame. With the
    /// default `max_buffers=2` that happens as soon as a reader lags one
    /// frame period (seen under load in the VM); load the module with
    /// `max_buffers=10` (udev/modprobe.d does) to give readers 9 periods
    /// (3 on 0.12.x, where the writer asks for 4: `MMAP_BUFFERS_UNLOCKED_QUEUE`).
    pub buffers: u32,
}

/// Writes frames to a v4l2loopback node.
pub struct LoopbackWriter {
    file: File,
    path: PathBuf,
    config: LoopbackFormat,
    io: Io,
    io_method: IoMethod,
    no_signal: Vec<u8>,
    version: Option<ModuleVersion>,
    features: DriverFeatures,
    watchers: Option<u32>,
    frames_written: u64,
}

fn pix_format(cfg: &LoopbackFormat) -> sys::v4l2_pix_format {
    sys::v4l2_pix_format {
        width: cfg.width,
        height: cfg.height,
        pixelformat: cfg.format.fourcc(),
        field: sys::V4L2_FIELD_NONE,
        bytesperline: cfg.bytes_per_line() as u32,
        sizeimage: cfg.frame_bytes() as u32,
        colorspace: match cfg.format {
            PixelFormat::Yuyv => sys::V4L2_COLORSPACE_SMPTE170M,
            _ => sys::V4L2_COLORSPACE_SRGB,
        },
        ..Default::default()
    }
}

fn describe(fmt: &sys::v4l2_pix_format) -> String {
    let code = fmt.pixelformat.to_le_bytes();
    format!(
        "{} {}x{}",
        String::from_utf8_lossy(&code).trim_end(),
        fmt.width,
        fmt.height
    )
}

impl LoopbackWriter {
    /// Opens `path`, negotiates `config` (S_FMT on the output type, S_PARM),
    /// starts streaming and shows the "no signal" card
    /// ([`sdi_core::view::no_signal_card`]), so readers can start at once.
    pub fn open(path: impl AsRef<Path>, config: LoopbackFormat) -> Result<Self, GlueError> {
        let path = path.as_ref().to_path_buf();
        config
            .validate()
            .map_err(|detail| GlueError::InvalidArgument { op: "open", detail })?;
        let mut writer = Self::open_node(path, config)?;
        let mut writer = match writer.negotiate() {
            Err(GlueError::FormatLocked { .. })
                if writer.control(sys::CID_KEEP_FORMAT) == Some(1) =>
            {
                writer.unpinned()?
            }
            r => r.map(|()| writer)?,
        };
        // After S_FMT: v4l2loopback 0.15 answers S_FMT with the node's
        // current format while keep_format is set (`vidioc_try_fmt_vid`).
        writer.features.keep_format = writer.set_control(sys::CID_KEEP_FORMAT, 1);
        writer.subscribe_client_usage();
        writer.write_first_card()?;
        Ok(writer)
    }

    /// The node opened and checked to be a loopback device; nothing
    /// negotiated yet, the driver's frame repeat off.
    fn open_node(path: PathBuf, config: LoopbackFormat) -> Result<Self, GlueError> {
        let file = File::options()
            .read(true)
            .write(true)
            .custom_flags(libc::O_CLOEXEC)
            .open(&path)
            .map_err(|e| match e.raw_os_error() {
                Some(libc::ENOENT) => GlueError::DeviceNotFound {
                    label: path.display().to_string(),
                    hint: "no such device node".into(),
                    not_added: None,
                },
                code => GlueError::from_errno("open", Errno::from_raw(code.unwrap_or(0))),
            })?;
        let mut cap = sys::v4l2_capability::default();
        sys::querycap(file.as_fd(), &mut cap).map_err(err("VIDIOC_QUERYCAP"))?;
        let driver = String::from_utf8_lossy(&cap.driver)
            .trim_end_matches('\0')
            .to_owned();
        if driver != LOOPBACK_DRIVER {
            return Err(GlueError::NotLoopback {
                path: path.display().to_string(),
                driver,
            });
        }
        let mut writer = Self {
            file,
            path,
            config,
            io: Io::Write,
            io_method: IoMethod::Write,
            no_signal: Vec::new(),
            version: ModuleVersion::of_loaded_module().ok(),
            features: DriverFeatures::default(),
            watchers: None,
            frames_written: 0,
        };
        // Off, also when an earlier producer left it on: the module's repeat
        // re-hands a reader the buffer it dequeued last, which it may still
        // hold (`sustain_framerate` on DriverFeatures).
        writer.set_sustain_framerate(false);
        Ok(writer)
    }

    /// The node still has an earlier producer's format, pinned by the
    /// `keep_format` every producer sets (so that readers survive its
    /// restarts): a new geometry (another sensor, ROI or mode size) would
    /// need the module reloaded. Unpinned and opened again: once nobody
    /// has the node open the module forgets the old format (0.12.7's
    /// `try_free_buffers`), and the new one is negotiated. If it is still
    /// locked, readers hold the node: the pin goes back for them and the
    /// error stands.
    fn unpinned(self) -> Result<Self, GlueError> {
        self.set_control(sys::CID_KEEP_FORMAT, 0);
        let (path, config) = (self.path.clone(), self.config);
        drop(self);
        let mut writer = Self::open_node(path, config)?;
        if let Err(e) = writer.negotiate() {
            writer.set_control(sys::CID_KEEP_FORMAT, 1);
            return Err(e);
        }
        Ok(writer)
    }

    /// Turns the driver's frame duplication (`sustain_framerate`) on or off
    /// (off after [`open`](Self::open); see
    /// [`DriverFeatures::sustain_framerate`]); false when the module has no
    /// such control.
    pub fn set_sustain_framerate(&mut self, on: bool) -> bool {
        let ok = self.set_control(sys::CID_SUSTAIN_FRAMERATE, i32::from(on));
        self.features.sustain_framerate = ok && on;
        ok
    }

    fn set_control(&self, id: u32, value: i32) -> bool {
        let mut ctrl = sys::v4l2_control { id, value };
        sys::s_ctrl(self.file.as_fd(), &mut ctrl).is_ok()
    }

    /// A control's value; `None` when the module has no such control.
    fn control(&self, id: u32) -> Option<i32> {
        let mut ctrl = sys::v4l2_control { id, value: 0 };
        sys::g_ctrl(self.file.as_fd(), &mut ctrl).ok()?;
        Some(ctrl.value)
    }

    /// S_FMT + check, S_PARM, buffers, STREAMON, no-signal card.
    fn negotiate(&mut self) -> Result<(), GlueError> {
        let cfg = self.config;
        let mut fmt = sys::v4l2_format {
            type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
            fmt: sys::v4l2_format_union {
                pix: pix_format(&cfg),
            },
        };
        match sys::s_fmt(self.file.as_fd(), &mut fmt) {
            Ok(_) => {}
            // exclusive_caps on 0.15: while another producer streams the node
            // is capture-only and output S_FMT is EINVAL (0.12.7: EBUSY)
            Err(Errno::EINVAL) if !self.announces_output() => {
                return Err(GlueError::Busy { op: "VIDIOC_S_FMT" })
            }
            Err(e) => return Err(GlueError::from_errno("VIDIOC_S_FMT", e)),
        }
        let mut got = sys::v4l2_format {
            type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
            ..Default::default()
        };
        sys::g_fmt(self.file.as_fd(), &mut got).map_err(err("VIDIOC_G_FMT"))?;
        let got_pix = got.pix();
        if got_pix.width != cfg.width
            || got_pix.height != cfg.height
            || got_pix.pixelformat != cfg.format.fourcc()
        {
            return Err(GlueError::FormatLocked {
                wanted: cfg.to_string(),
                current: describe(&got_pix),
            });
        }
        let mut parm = sys::v4l2_streamparm {
            type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
            ..Default::default()
        };
        parm.set_output(sys::v4l2_outputparm {
            capability: sys::V4L2_CAP_TIMEPERFRAME,
            timeperframe: sys::v4l2_fract {
                numerator: 1,
                denominator: cfg.fps,
            },
            ..Default::default()
        });
        self.features.frame_interval = match sys::s_parm(self.file.as_fd(), &mut parm) {
            Ok(_) => true,
            Err(Errno::ENODEV) => {
                return Err(GlueError::DeviceGone {
                    op: "VIDIOC_S_PARM",
                })
            }
            Err(_) => false,
        };
        self.io = match cfg.io {
            IoMethod::Mmap => match self.map_buffers() {
                Ok((maps, offsets)) => {
                    self.io_method = IoMethod::Mmap;
                    self.features.buffers = maps.len() as u32;
                    Io::Mmap {
                        maps,
                        offsets,
                        next: 0,
                    }
                }
                Err(GlueError::DeviceGone { op }) => return Err(GlueError::DeviceGone { op }),
                Err(_) => self.write_io(),
            },
            IoMethod::Write => self.write_io(),
        };
        if self.io_method == IoMethod::Mmap {
            let ty = sys::V4L2_BUF_TYPE_VIDEO_OUTPUT as libc::c_int;
            sys::streamon(self.file.as_fd(), &ty).map_err(err("VIDIOC_STREAMON"))?;
        }
        self.no_signal = no_signal_card(cfg.format, cfg.width as usize, cfg.height as usize);
        Ok(())
    }

    /// Whether the node currently offers the output type (exclusive_caps
    /// nodes stop doing so while a producer streams).
    fn announces_output(&self) -> bool {
        let mut cap = sys::v4l2_capability::default();
        sys::querycap(self.file.as_fd(), &mut cap).is_ok()
            && cap.device_caps & sys::V4L2_CAP_VIDEO_OUTPUT != 0
    }

    fn write_io(&mut self) -> Io {
        self.io_method = IoMethod::Write;
        Io::Write
    }

    /// The driver's output buffers mapped, with the mmap offset of each.
    fn map_buffers(&self) -> Result<(Vec<sys::Mapping>, Vec<u32>), GlueError> {
        let fd = self.file.as_fd();
        let mut req = sys::v4l2_requestbuffers {
            count: if self
                .version
                .is_some_and(ModuleVersion::has_locked_buffer_queue)
            {
                MMAP_BUFFERS
            } else {
                MMAP_BUFFERS_UNLOCKED_QUEUE
            },
            type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
            memory: sys::V4L2_MEMORY_MMAP,
            ..Default::default()
        };
        sys::reqbufs(fd, &mut req).map_err(err("VIDIOC_REQBUFS"))?;
        if req.count == 0 {
            return Err(GlueError::InvalidArgument {
                op: "VIDIOC_REQBUFS",
                detail: "0 buffers".into(),
            });
        }
        (0..req.count)
            .map(|index| {
                let mut buf = sys::v4l2_buffer {
                    index,
                    type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
                    memory: sys::V4L2_MEMORY_MMAP,
                    ..Default::default()
                };
                sys::querybuf(fd, &mut buf).map_err(err("VIDIOC_QUERYBUF"))?;
                if (buf.length as usize) < self.config.frame_bytes() {
                    return Err(GlueError::InvalidArgument {
                        op: "VIDIOC_QUERYBUF",
                        detail: format!(
                            "buffer of {} bytes < frame {}",
                            buf.length,
                            self.config.frame_bytes()
                        ),
                    });
                }
                let map = sys::Mapping::new(fd, buf.length as usize, buf.mmap_offset())
                    .map_err(err("mmap"))?;
                Ok((map, buf.mmap_offset()))
            })
            .collect::<Result<Vec<_>, GlueError>>()
            .map(|v| v.into_iter().unzip())
    }

    /// Subscribes to the client-usage event where the module has it.
    fn subscribe_client_usage(&mut self) {
        if !self
            .version
            .is_some_and(ModuleVersion::has_client_usage_event)
        {
            return;
        }
        let sub = sys::v4l2_event_subscription {
            type_: sys::V4L2_EVENT_PRI_CLIENT_USAGE,
            flags: sys::V4L2_EVENT_SUB_FL_SEND_INITIAL,
            ..Default::default()
        };
        self.features.client_usage_event = sys::subscribe_event(self.file.as_fd(), &sub).is_ok();
        if self.features.client_usage_event {
            self.watchers = Some(0);
        }
    }

    /// Whether capture readers are streaming: `None` when the module cannot
    /// tell (v4l2loopback < 0.13 has no client-usage event: "unsupported").
    pub fn readers_present(&mut self) -> Option<bool> {
        self.watchers().map(|n| n > 0)
    }

    /// How many capture readers stream, from the client-usage event
    /// (`V4L2_EVENT_PRI_CLIENT_USAGE`, v4l2loopback 0.13+); `None` when the
    /// module has no such event (0.12.x). Drains pending events without
    /// blocking.
    ///
    /// v4l2loopback 0.15 reports `!has_capture_token(dev->stream_tokens)`
    /// (`client_usage_queue_event`), i.e. 1 while a reader holds the capture
    /// stream and 0 otherwise, not a true count; and only a STREAMON /
    /// STREAMOFF of a capture *streaming* reader queues the event, so a
    /// reader using read() is not seen.
    pub fn watchers(&mut self) -> Option<u32> {
        if !self.features.client_usage_event {
            return None;
        }
        loop {
            let mut fds = [nix::poll::PollFd::new(
                self.file.as_fd(),
                nix::poll::PollFlags::POLLPRI,
            )];
            let ready = nix::poll::poll(&mut fds, nix::poll::PollTimeout::ZERO).unwrap_or(0);
            let pri = fds[0]
                .revents()
                .is_some_and(|r| r.contains(nix::poll::PollFlags::POLLPRI));
            if ready == 0 || !pri {
                break;
            }
            let mut ev = sys::v4l2_event::default();
            if sys::dqevent(self.file.as_fd(), &mut ev).is_err() {
                break;
            }
            if ev.type_ == sys::V4L2_EVENT_PRI_CLIENT_USAGE {
                // `struct v4l2_event_client_usage { __u32 count; }` at the
                // start of the union (little endian).
                self.watchers = Some(ev.u[0] as u32);
            }
        }
        self.watchers
    }

    /// Changes the output format. Refused with [`GlueError::FormatLocked`]
    /// while readers stream (the module cannot change formats under them);
    /// otherwise streaming is stopped, buffers released and the new format
    /// negotiated.
    pub fn reconfigure(&mut self, config: LoopbackFormat) -> Result<(), GlueError> {
        config
            .validate()
            .map_err(|detail| GlueError::InvalidArgument {
                op: "reconfigure",
                detail,
            })?;
        if config == self.config {
            return Ok(());
        }
        if self.readers_present() == Some(true) {
            return Err(GlueError::FormatLocked {
                wanted: config.to_string(),
                current: format!("{} (readers are streaming)", self.config),
            });
        }
        self.release_buffers();
        // keep_format would pin the old format (see `open`)
        self.set_control(sys::CID_KEEP_FORMAT, 0);
        let old = self.config;
        self.config = config;
        if let Err(e) = self.negotiate() {
            // back to the old geometry so the writer stays usable
            self.config = old;
            self.release_buffers();
            self.negotiate()?;
            self.set_control(sys::CID_KEEP_FORMAT, i32::from(self.features.keep_format));
            return Err(e);
        }
        self.set_control(sys::CID_KEEP_FORMAT, i32::from(self.features.keep_format));
        self.write_first_card()
    }

    fn release_buffers(&mut self) {
        if let Io::Mmap { maps, .. } = &mut self.io {
            let ty = sys::V4L2_BUF_TYPE_VIDEO_OUTPUT as libc::c_int;
            let _ = sys::streamoff(self.file.as_fd(), &ty);
            maps.clear();
            let mut req = sys::v4l2_requestbuffers {
                count: 0,
                type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
                memory: sys::V4L2_MEMORY_MMAP,
                ..Default::default()
            };
            let _ = sys::reqbufs(self.file.as_fd(), &mut req);
        }
        self.io = Io::Write;
    }

    /// Publishes one frame, packed in the node's format (exactly
    /// `frame_bytes`, as [`sdi_core::view::ViewRenderer`] renders it);
    /// `timestamp_us` is the capture timestamp (CLOCK_MONOTONIC; 0: the
    /// driver stamps it), moved just after a driver restamp that dated older
    /// frames later (see below).
    pub fn write(&mut self, frame: &[u8], timestamp_us: u64) -> Result<(), GlueError> {
        let bytes = self.config.frame_bytes();
        if frame.len() != bytes {
            return Err(GlueError::InputMismatch {
                expected: format!("{bytes} packed bytes"),
                got: frame.len().to_string(),
            });
        }
        let Self { io, file, .. } = self;
        match io {
            Io::Mmap {
                maps,
                offsets,
                next,
            } => {
                let fd = file.as_fd();
                // Which of our mappings the driver's buffer `index` is now,
                // and the timestamp that buffer carries.
                let query = |index: usize| -> Result<(Option<usize>, u64), GlueError> {
                    let mut buf = sys::v4l2_buffer {
                        index: index as u32,
                        type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
                        memory: sys::V4L2_MEMORY_MMAP,
                        ..Default::default()
                    };
                    sys::querybuf(fd, &mut buf).map_err(err("VIDIOC_QUERYBUF"))?;
                    let t = buf.timestamp;
                    let stamp_us = (t.tv_sec.max(0) as u64)
                        .saturating_mul(1_000_000)
                        .saturating_add(t.tv_usec.max(0) as u64);
                    Ok((
                        offsets.iter().position(|&o| o == buf.mmap_offset()),
                        stamp_us,
                    ))
                };
                // Past the end of a shrunk ring, start again at 0: each driver
                // buffer is then refilled only every used_buffers frames, the
                // longest a reader can hold one.
                let mut index = *next;
                let (found, _) = query(index)?;
                let mut target = found.unwrap_or(index);
                if target != index {
                    index = 0;
                    target = query(0)?.0.unwrap_or(0);
                }
                *next = (index + 1) % maps.len();
                maps[target].as_mut_slice()[..bytes].copy_from_slice(frame);
                // v4l2loopback 0.12.x restamps every buffer with the time of
                // any opener's REQBUFS (`init_buffers`), e.g. a reader
                // starting: readers then hold old frames dated that moment.
                // A frame captured before it is dated just after it instead,
                // so the node's timestamps never go back (it is still not
                // dated later than now). Otherwise the ring holds only our
                // earlier, older stamps and `timestamp_us` stands. The
                // latest stamp of the whole ring (the restamp runs buffer by
                // buffer, each later than the one before, and a reader may
                // hold any of them), read after the fill, just before QBUF:
                // checking only this buffer, before the conversion
                // (milliseconds under emulation), let vm_plain/daemon see a stamp
                // go back by up to 49 us (3 runs in 15).
                let held_us = (0..maps.len()).try_fold(0, |latest, i| {
                    query(i).map(|(_, stamp_us)| latest.max(stamp_us))
                })?;
                let timestamp_us = if timestamp_us != 0 && held_us >= timestamp_us {
                    held_us.saturating_add(1)
                } else {
                    timestamp_us
                };
                let mut buf = sys::v4l2_buffer {
                    index: index as u32,
                    type_: sys::V4L2_BUF_TYPE_VIDEO_OUTPUT,
                    memory: sys::V4L2_MEMORY_MMAP,
                    bytesused: bytes as u32,
                    field: sys::V4L2_FIELD_NONE,
                    flags: sys::V4L2_BUF_FLAG_TIMESTAMP_COPY,
                    timestamp: libc::timeval {
                        tv_sec: (timestamp_us / 1_000_000) as libc::time_t,
                        tv_usec: (timestamp_us % 1_000_000) as libc::suseconds_t,
                    },
                    ..Default::default()
                };
                sys::qbuf(fd, &mut buf).map_err(err("VIDIOC_QBUF"))?;
            }
            Io::Write => {
                let mut done = 0;
                while done < frame.len() {
                    match nix::unistd::write(file.as_fd(), &frame[done..]) {
                        Ok(0) => {
                            return Err(GlueError::Io {
                                op: "write",
                                errno: Errno::EIO,
                            })
                        }
                        Ok(n) => done += n,
                        Err(Errno::EINTR) => {}
                        Err(e) => return Err(GlueError::from_errno("write", e)),
                    }
                }
            }
        }
        self.frames_written += 1;
        Ok(())
    }

    /// Shows the "no signal" card (sensor paused), stamped `timestamp_us`
    /// (CLOCK_MONOTONIC, on the clock of the frames around it: a producer
    /// stamps it after the last frame and before the next).
    pub fn write_no_signal(&mut self, timestamp_us: u64) -> Result<(), GlueError> {
        let card = std::mem::take(&mut self.no_signal);
        let result = self.write(&card, timestamp_us);
        self.no_signal = card;
        result
    }

    /// The card a (re)negotiated node shows until the first frame, stamped
    /// now: before anything the producer stamps after this call returns.
    fn write_first_card(&mut self) -> Result<(), GlueError> {
        let now_us = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
            .map(|t| t.tv_sec() as u64 * 1_000_000 + t.tv_nsec() as u64 / 1000)
            .unwrap_or(0);
        self.write_no_signal(now_us)
    }

    /// The bytes of the "no signal" card in the output format.
    pub fn no_signal_frame(&self) -> &[u8] {
        &self.no_signal
    }

    pub fn config(&self) -> LoopbackFormat {
        self.config
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The I/O method in use (mmap falls back to write()).
    pub fn io_method(&self) -> IoMethod {
        self.io_method
    }

    pub fn module_version(&self) -> Option<ModuleVersion> {
        self.version
    }

    pub fn features(&self) -> DriverFeatures {
        self.features
    }

    pub fn frames_written(&self) -> u64 {
        self.frames_written
    }
}

impl AsRawFd for LoopbackWriter {
    fn as_raw_fd(&self) -> std::os::fd::RawFd {
        self.file.as_raw_fd()
    }
}

impl Drop for LoopbackWriter {
    fn drop(&mut self) {
        self.release_buffers();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_a_non_device_is_a_typed_error() {
        let e = LoopbackWriter::open("/nonexistent/video99", LoopbackFormat::view(30));
        assert!(matches!(e, Err(GlueError::DeviceNotFound { .. })));
        let e = LoopbackWriter::open("/dev/null", LoopbackFormat::view(30));
        assert!(e.is_err());
        let bad = LoopbackFormat {
            width: 641,
            ..LoopbackFormat::view(30)
        };
        assert!(matches!(
            LoopbackWriter::open("/dev/null", bad),
            Err(GlueError::InvalidArgument { .. })
        ));
    }
}
