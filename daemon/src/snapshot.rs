//! Snapshots: the latest processed frame as PNG (rendered as the view stream
//! shows it) or `.npy`: signed DN, float32, shape (height, width); in the
//! separation mode I+ and I- in electrons, float32, shape (2, height, width).

use std::fs::File;
use std::io::{self, BufWriter, Write};

use crate::dbus::paths::OutputKind;
use crate::frame_loop::SnapshotData;

/// Writes `snap` into `file` (e.g. a descriptor a client passed), then syncs it.
pub fn write_to(file: File, kind: OutputKind, snap: &SnapshotData) -> io::Result<()> {
    let img = &snap.output.signed_dn;
    let mut w = BufWriter::new(file);
    match kind {
        OutputKind::Npy | OutputKind::Recording => match &snap.output.channels {
            Some(ch) => {
                let mut both = Vec::with_capacity(2 * img.data.len());
                both.extend_from_slice(&ch.i_plus_electrons.data);
                both.extend_from_slice(&ch.i_minus_electrons.data);
                sdi_core::npy::write_f32(&mut w, &[2, img.height, img.width], &both)?
            }
            None => sdi_core::npy::write_f32(&mut w, &[img.height, img.width], &img.data)?,
        },
        OutputKind::Png => {
            let mut rgb = vec![0u8; img.width * img.height * 3];
            snap.display.render_output_rgb8(&snap.output, &mut rgb);
            let png = encode_png(&rgb, img.width as u32, img.height as u32)?;
            w.write_all(&png)?;
        }
    }
    w.flush()?;
    w.get_ref().sync_all()
}

fn encode_png(rgb: &[u8], width: u32, height: u32) -> io::Result<Vec<u8>> {
    let mut buf = io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut buf,
        rgb,
        width,
        height,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(io::Error::other)?;
    Ok(buf.into_inner())
}
