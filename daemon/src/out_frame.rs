//! [`OutFrame`]: a mode's output as it leaves the frame loop, with the mode
//! that made it and the display map it is shown with, and each wire format
//! rendered once however many consumers publish it (the loopback view and
//! the PipeWire camera's view are the same YUYV bytes; the data nodes the
//! same Y16; the frame streams the same body).

use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use sdi_api::frame_stream::put_f32s;
use sdi_core::display::DisplayMap;
use sdi_core::mode::{ModeId, ModeOutput};
use sdi_core::view::{PackError, PixelFormat, ViewRenderer};

/// One processed frame on its way out; shared (`Arc`) by every consumer
/// and kept as the latest for snapshots.
pub struct OutFrame {
    pub output: ModeOutput,
    /// The mode that produced `output`.
    pub mode: ModeId,
    /// How `output` is shown (colormap, range) in the views.
    pub display: DisplayMap,
    renders: Mutex<Vec<(Picture, Slot)>>,
    stream_body: OnceLock<Arc<[u8]>>,
}

/// Which of a renderer's pictures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PictureKind {
    /// [`ViewRenderer::render`].
    View,
    /// [`ViewRenderer::render_signed_dn`].
    SignedDn,
    /// [`ViewRenderer::render_yuv444`].
    Yuv444,
}

/// A picture's bytes once rendered; locked while they are being rendered.
type Slot = Arc<Mutex<Option<Arc<[u8]>>>>;

/// What a renderer makes of a frame, at its geometry and pixel format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Picture {
    kind: PictureKind,
    width: usize,
    height: usize,
    format: PixelFormat,
}

impl OutFrame {
    pub fn new(output: ModeOutput, mode: ModeId, display: DisplayMap) -> Self {
        Self {
            output,
            mode,
            display,
            renders: Mutex::default(),
            stream_body: OnceLock::new(),
        }
    }

    /// The view ([`ViewRenderer::render`]) at `renderer`'s geometry and
    /// format: rendered by the first consumer that asks, with its own
    /// renderer, and shared with the rest.
    pub fn view(&self, renderer: &mut ViewRenderer) -> Result<Arc<[u8]>, PackError> {
        self.rendered(PictureKind::View, renderer)
    }

    /// The signed image itself ([`ViewRenderer::render_signed_dn`], a data
    /// node's frame), once per format like [`OutFrame::view`].
    pub fn signed_dn(&self, renderer: &mut ViewRenderer) -> Result<Arc<[u8]>, PackError> {
        self.rendered(PictureKind::SignedDn, renderer)
    }

    /// The view as the y4m stream's Y, U and V planes
    /// ([`ViewRenderer::render_yuv444`]), once like [`OutFrame::view`].
    pub fn view_yuv444(&self, renderer: &mut ViewRenderer) -> Result<Arc<[u8]>, PackError> {
        self.rendered(PictureKind::Yuv444, renderer)
    }

    /// The output, for the frame loop to reuse once every consumer is done.
    pub fn into_output(self) -> ModeOutput {
        self.output
    }

    fn rendered(
        &self,
        kind: PictureKind,
        renderer: &mut ViewRenderer,
    ) -> Result<Arc<[u8]>, PackError> {
        let picture = Picture {
            kind,
            width: renderer.width(),
            height: renderer.height(),
            format: renderer.format(),
        };
        // The list's lock is held only to find the picture's slot; the
        // slot's while it is rendered, so a second consumer of the same
        // picture waits for those bytes instead of rendering them again.
        let slot = {
            let mut renders = self.renders.lock().unwrap_or_else(PoisonError::into_inner);
            match renders.iter().find(|(p, _)| *p == picture) {
                Some((_, slot)) => slot.clone(),
                None => {
                    let slot = Arc::default();
                    renders.push((picture, Arc::clone(&slot)));
                    slot
                }
            }
        };
        let mut bytes = slot.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(b) = &*bytes {
            return Ok(b.clone());
        }
        let b: Arc<[u8]> = Arc::from(match kind {
            PictureKind::View => renderer.render(&self.output, &self.display)?,
            PictureKind::SignedDn => renderer.render_signed_dn(&self.output.signed_dn)?,
            PictureKind::Yuv444 => renderer.render_yuv444(&self.output, &self.display),
        });
        *bytes = Some(b.clone());
        Ok(b)
    }

    /// The body of a frame stream's message (`sdi_api::frame_stream`): the
    /// signed image, the flags and the separated channels; the header, which
    /// counts each stream's own drops, goes before it.
    pub fn stream_body(&self) -> Arc<[u8]> {
        self.stream_body
            .get_or_init(|| {
                let out = &self.output;
                let mut body = Vec::new();
                put_f32s(&mut body, &out.signed_dn.data);
                body.extend_from_slice(&out.flags.data);
                if let Some(ch) = &out.channels {
                    put_f32s(&mut body, &ch.i_plus_electrons.data);
                    put_f32s(&mut body, &ch.i_minus_electrons.data);
                    put_f32s(&mut body, &ch.i_plus_se_electrons.data);
                    put_f32s(&mut body, &ch.i_minus_se_electrons.data);
                }
                body.into()
            })
            .clone()
    }

    /// How many distinct pictures have been rendered of this frame.
    #[cfg(test)]
    fn pictures(&self) -> usize {
        self.renders
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::Image;

    fn frame() -> OutFrame {
        let mut out = ModeOutput::new(8, 6);
        out.signed_dn = Image {
            width: 8,
            height: 6,
            data: (0..48).map(|i| i as f32 - 20.0).collect(),
        };
        OutFrame::new(out, ModeId::DepthEdge, DisplayMap::default())
    }

    /// Two consumers of one picture get one rendering (the same bytes, by
    /// pointer); another format or the data picture is its own; each equals
    /// what the renderer makes alone.
    #[test]
    fn each_picture_is_rendered_once() {
        let f = frame();
        let mut a = ViewRenderer::new(16, 12, PixelFormat::Yuyv);
        let mut b = ViewRenderer::new(16, 12, PixelFormat::Yuyv);
        let first = f.view(&mut a).unwrap();
        let second = f.view(&mut b).unwrap();
        assert!(Arc::ptr_eq(&first, &second));
        let mut alone = ViewRenderer::new(16, 12, PixelFormat::Yuyv);
        assert_eq!(&*first, alone.render(&f.output, &f.display).unwrap());
        let mut rgb = ViewRenderer::new(16, 12, PixelFormat::Rgb24);
        let rgb_bytes = f.view(&mut rgb).unwrap();
        assert_eq!(rgb_bytes.len(), 16 * 12 * 3);
        let mut y16 = ViewRenderer::new(8, 6, PixelFormat::Y16);
        let data = f.signed_dn(&mut y16).unwrap();
        let mut y16_alone = ViewRenderer::new(8, 6, PixelFormat::Y16);
        assert_eq!(
            &*data,
            y16_alone.render_signed_dn(&f.output.signed_dn).unwrap()
        );
        assert_eq!(f.pictures(), 3);
        assert!(Arc::ptr_eq(&f.stream_body(), &f.stream_body()));
    }

    /// A data renderer whose size is not the image's fails, and the next
    /// consumer of that picture gets the same error, not stale bytes.
    #[test]
    fn a_failed_rendering_is_not_kept() {
        let f = frame();
        let mut wrong = ViewRenderer::new(4, 4, PixelFormat::Y16);
        assert!(f.signed_dn(&mut wrong).is_err());
        assert!(f.signed_dn(&mut wrong).is_err());
    }
}
