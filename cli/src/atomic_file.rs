//! Output files that appear whole or not at all: written to a hidden temporary
//! file in the destination's directory, renamed into place on commit, removed
//! if dropped uncommitted.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

pub struct AtomicFile {
    tmp: PathBuf,
    dest: PathBuf,
    committed: bool,
}

impl AtomicFile {
    /// Reserves a temporary path next to `dest` (nothing is created yet).
    pub fn new(dest: &Path) -> std::io::Result<Self> {
        let name = dest.file_name().ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("'{}' is not a file name", dest.display()),
            )
        })?;
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".tmp-{}", std::process::id()));
        Ok(Self {
            tmp: dest.with_file_name(tmp_name),
            dest: dest.to_path_buf(),
            committed: false,
        })
    }

    pub fn tmp_path(&self) -> &Path {
        &self.tmp
    }

    /// Creates the temporary file for buffered writing.
    pub fn create(&self) -> std::io::Result<BufWriter<File>> {
        File::create(&self.tmp).map(BufWriter::new)
    }

    /// Moves the finished file into place.
    pub fn commit(mut self) -> std::io::Result<()> {
        std::fs::rename(&self.tmp, &self.dest)?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}
