//! Frames from sdid for the page: a socket pair whose writing end goes to
//! sdid (`StreamFrames`, so the page works whatever sdid's sink is), read
//! here and rendered through `sdi_core`'s display map exactly as sdid
//! renders its view; the latest frame is published on a watch channel, so
//! a slow page skips frames instead of queueing them.

use std::os::fd::OwnedFd;
use std::sync::Arc;

use sdi_api::frame_stream::{get_f32s, FrameHeader, WireError, HEADER_BYTES};
use sdi_api::Camera1Proxy;
use sdi_core::display::{render_channels_rgb8, Colormap, DisplayMap, DisplayRange};
use sdi_core::mode::{ModeOutput, SeparatedChannels};
use sdi_core::Image;
use tokio::io::AsyncReadExt;
use tokio::net::UnixStream;
use tokio::sync::watch;
use zbus::zvariant::Fd;

use crate::exit::CliError;

/// One frame as the page shows it.
pub struct LiveFrame {
    pub header: FrameHeader,
    /// Signed DN, row-major.
    pub dn: Vec<f32>,
    /// `PixelFlags` bits per pixel.
    pub flags: Vec<u8>,
    /// The view as sdid renders it, RGBA.
    pub view_rgba: Vec<u8>,
    /// Separation mode: I+ and I- on one grey scale (the view's red and blue), RGBA.
    pub channels_rgba: Option<(Vec<u8>, Vec<u8>)>,
    /// Separation mode: the median standard error of I+ and of I-, electrons.
    pub channels_se_electrons: Option<(f64, f64)>,
}

/// Why the stream of frames ended.
#[derive(Debug, thiserror::Error)]
pub enum FramesError {
    #[error("creating the socket for sdid's frames: {0}")]
    Socket(#[source] std::io::Error),
    #[error("reading sdid's frames: {0}")]
    Read(#[source] std::io::Error),
    #[error("sdid's frame stream: {0}")]
    Wire(#[from] WireError),
    #[error("sdid's frame stream names colormap '{0}'")]
    Colormap(String),
}

/// Asks sdid to stream its frames into a new socket; returns our end.
pub async fn open(camera: &Camera1Proxy<'_>) -> Result<UnixStream, CliError> {
    let (ours, theirs) = std::os::unix::net::UnixStream::pair()
        .map_err(|e| CliError::Runtime(FramesError::Socket(e).to_string()))?;
    let theirs = OwnedFd::from(theirs);
    camera.stream_frames(Fd::from(&theirs)).await?;
    drop(theirs);
    ours.set_nonblocking(true)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    UnixStream::from_std(ours).map_err(|e| CliError::Runtime(e.to_string()))
}

/// Another camera's frame stream, and whom to tell once it is in use.
pub type Switch = (UnixStream, tokio::sync::oneshot::Sender<()>);

/// Reads frames until sdid closes the stream, publishing each.
pub async fn pump(
    mut stream: UnixStream,
    tx: &watch::Sender<Option<Arc<LiveFrame>>>,
) -> Result<(), FramesError> {
    let mut head = [0u8; HEADER_BYTES];
    let mut body = Vec::new();
    loop {
        match stream.read_exact(&mut head).await {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(FramesError::Read(e)),
        }
        let header = FrameHeader::decode(&head)?;
        body.resize(header.body_bytes(), 0);
        stream
            .read_exact(&mut body)
            .await
            .map_err(FramesError::Read)?;
        let frame = decode(header, &body)?;
        tx.send_replace(Some(Arc::new(frame)));
    }
}

/// The frame in `body` (exactly `header.body_bytes()` long), rendered.
pub fn decode(header: FrameHeader, body: &[u8]) -> Result<LiveFrame, FramesError> {
    let (w, h) = (header.width as usize, header.height as usize);
    let n = w * h;
    let mut dn = vec![0f32; n];
    get_f32s(&body[..4 * n], &mut dn);
    let flags = body[4 * n..5 * n].to_vec();
    let channels = header.has_channels.then(|| {
        let plane = |k: usize| {
            let mut img = Image::new(w, h);
            let start = 5 * n + 4 * k * n;
            get_f32s(&body[start..start + 4 * n], &mut img.data);
            img
        };
        SeparatedChannels {
            i_plus_electrons: plane(0),
            i_minus_electrons: plane(1),
            i_plus_se_electrons: plane(2),
            i_minus_se_electrons: plane(3),
        }
    });
    let colormap: Colormap = header
        .colormap
        .parse()
        .map_err(|_| FramesError::Colormap(header.colormap.clone()))?;
    let display = DisplayMap {
        colormap,
        range: if header.max_abs_dn > 0.0 {
            DisplayRange::Fixed {
                max_abs_dn: header.max_abs_dn,
            }
        } else {
            DisplayRange::SymmetricAuto
        },
    };
    let mut output = ModeOutput::new(w, h);
    output.signed_dn.data = dn;
    output.channels = channels;
    let mut rgb = vec![0u8; 3 * n];
    display.render_output_rgb8(&output, &mut rgb);
    let channels_rgba = output.channels.as_ref().map(|ch| {
        let mut both = vec![0u8; 3 * n];
        render_channels_rgb8(ch, &mut both);
        (grey_rgba(&both, 0), grey_rgba(&both, 2))
    });
    let channels_se_electrons = output.channels.as_ref().map(|ch| {
        (
            median(&ch.i_plus_se_electrons.data),
            median(&ch.i_minus_se_electrons.data),
        )
    });
    Ok(LiveFrame {
        header,
        dn: output.signed_dn.data,
        flags,
        view_rgba: rgba(&rgb),
        channels_rgba,
        channels_se_electrons,
    })
}

/// The median of the finite values; NaN when there are none.
fn median(values: &[f32]) -> f64 {
    let mut finite: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return f64::NAN;
    }
    let mid = finite.len() / 2;
    let (_, m, _) = finite.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

fn rgba(rgb: &[u8]) -> Vec<u8> {
    rgb.chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect()
}

/// Channel `c` of an RGB image as grey RGBA.
fn grey_rgba(rgb: &[u8], c: usize) -> Vec<u8> {
    rgb.chunks_exact(3)
        .flat_map(|p| [p[c], p[c], p[c], 255])
        .collect()
}
