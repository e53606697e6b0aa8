//! `sdictl sim --truth` and `--two-shot-frames`: what the simulator knows and
//! a real sensor does not. The truth is the expected well contents I+ and I-
//! in electrons per exposure (eq. wellmeasurement), as `.npy`.

use std::path::{Path, PathBuf};

use sdi_core::simulator::WellExpectation;
use sdi_core::{Frame, Image};

use super::frames::NpyOut;
use crate::atomic_file::AtomicFile;
use crate::exit::CliError;

struct Out {
    file: AtomicFile,
    path: PathBuf,
    npy: NpyOut,
}

fn open(path: &Path, tail: &[usize]) -> Result<Out, CliError> {
    let err = |what: &str, e: &dyn std::fmt::Display| {
        CliError::Runtime(format!("{what} '{}': {e}", path.display()))
    };
    if path.is_dir() {
        return Err(err("cannot write", &"is a directory"));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| err("cannot create directory", &e))?;
    }
    let file = AtomicFile::new(path).map_err(|e| err("bad output", &e))?;
    let w = file.create().map_err(|e| err("cannot create", &e))?;
    let npy = NpyOut::new(w, tail).map_err(|e| err("cannot write", &e))?;
    Ok(Out {
        file,
        path: path.to_path_buf(),
        npy,
    })
}

fn write_err(e: std::io::Error) -> CliError {
    CliError::Runtime(format!("cannot write: {e}"))
}

/// Truth and two-shot pair writers of one `sim` run.
pub struct Extras {
    truth: Option<Out>,
    pairs: Option<Out>,
    /// Last dark-subtracted capture of each sequence parity (A even, B odd).
    last: [Vec<f32>; 2],
    plane: Vec<f32>,
}

impl Extras {
    pub fn open(
        truth: Option<&Path>,
        pairs: Option<&Path>,
        w: usize,
        h: usize,
    ) -> Result<Self, CliError> {
        Ok(Self {
            truth: truth.map(|p| open(p, &[2, h, w])).transpose()?,
            pairs: pairs.map(|p| open(p, &[2, h, w])).transpose()?,
            last: [vec![0.0; w * h], vec![0.0; w * h]],
            plane: vec![0.0; 2 * w * h],
        })
    }

    /// Notes a capture.
    pub fn captured(&mut self, frame: &Frame, dark: Option<&Image<f32>>) {
        if self.pairs.is_none() {
            return;
        }
        let slot = &mut self.last[(frame.sequence & 1) as usize];
        slot.copy_from_slice(&frame.dn.data);
        if let Some(d) = dark.filter(|d| d.same_size(&frame.dn)) {
            slot.iter_mut().zip(&d.data).for_each(|(v, k)| *v -= k);
        }
    }

    /// An output was produced: writes its truth (and pair).
    pub fn output(&mut self, e: &WellExpectation, _single_capture: bool) -> Result<(), CliError> {
        if let Some(t) = &mut self.truth {
            let n = e.i_plus_electrons.data.len();
            self.plane[..n].copy_from_slice(&e.i_plus_electrons.data);
            self.plane[n..].copy_from_slice(&e.i_minus_electrons.data);
            t.npy.push(&self.plane).map_err(write_err)?;
        }
        self.output_pair_only()
    }

    /// An output of a static scene whose truth is already written.
    pub fn output_pair_only(&mut self) -> Result<(), CliError> {
        if let Some(p) = &mut self.pairs {
            let n = self.last[0].len();
            self.plane[..n].copy_from_slice(&self.last[0]);
            self.plane[n..].copy_from_slice(&self.last[1]);
            p.npy.push(&self.plane).map_err(write_err)?;
        }
        Ok(())
    }

    /// Fixes the shapes and renames the files into place; a static scene's
    /// truth is (2, H, W).
    pub fn finish(self, static_scene: bool) -> Result<(), CliError> {
        for (out, single) in [(self.truth, static_scene), (self.pairs, false)] {
            if let Some(o) = out {
                o.npy.finish(single).map_err(write_err)?;
                o.file.commit().map_err(|e| {
                    CliError::Runtime(format!("cannot write '{}': {e}", o.path.display()))
                })?;
            }
        }
        Ok(())
    }
}
