//! The files a report writes into its `--out` directory: the directory and
//! a hidden temporary for each file are created before anything is
//! computed, so an unwritable `--out` fails at once; the files appear
//! whole, together, when the report commits them (before it prints).

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::atomic_file::AtomicFile;
use crate::exit::CliError;

pub struct ReportFiles {
    files: Vec<(&'static str, PathBuf, AtomicFile)>,
}

fn io_error(what: &str, path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("{what} '{}': {e}", path.display()))
}

impl ReportFiles {
    /// Creates `dir` if needed and a temporary for each of `names` in it.
    pub fn create(dir: &Path, names: &[&'static str]) -> Result<Self, CliError> {
        std::fs::create_dir_all(dir).map_err(|e| io_error("cannot create directory", dir, e))?;
        let files = names
            .iter()
            .map(|&name| {
                let path = dir.join(name);
                if path.is_dir() {
                    return Err(io_error("cannot write", &path, "is a directory"));
                }
                let file =
                    AtomicFile::new(&path).map_err(|e| io_error("cannot write", &path, e))?;
                Ok((name, path, file))
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { files })
    }

    /// Whether `name` is one of this report's files.
    pub fn contains(&self, name: &str) -> bool {
        self.files.iter().any(|(n, _, _)| *n == name)
    }

    /// Writes the contents of `name` (one of the names given to `create`).
    pub fn write(&self, name: &str, bytes: &[u8]) -> Result<(), CliError> {
        let (_, path, file) = self
            .files
            .iter()
            .find(|(n, _, _)| *n == name)
            .ok_or_else(|| CliError::Runtime(format!("{name} is not an output of this report")))?;
        let mut w = file
            .create()
            .map_err(|e| io_error("cannot write", path, e))?;
        w.write_all(bytes)
            .and_then(|()| w.flush())
            .map_err(|e| io_error("cannot write", path, e))
    }

    /// Moves every file into place; their paths, in the order given.
    pub fn commit(self) -> Result<Vec<PathBuf>, CliError> {
        let mut done = Vec::new();
        for (_, path, file) in self.files {
            file.commit()
                .map_err(|e| io_error("cannot write", &path, e))?;
            done.push(path);
        }
        Ok(done)
    }
}
