//! Which directory entry an output path names, so two outputs (or an output
//! and the input) that are the same entry are refused however they are
//! spelled (`out/f.npy` and `out/../out/f.npy`, a symlinked directory).
//!
//! Outputs are renamed into place (`atomic_file.rs`), which replaces the
//! directory entry, never the file behind it: two paths collide exactly when
//! their directories are the same (device, inode) and their last components
//! are equal. The directory is created first, so this holds for new files too.

use std::ffi::OsString;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

use crate::exit::CliError;

/// A directory entry: (device, inode) of its directory, and its name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputName {
    dir_dev: u64,
    dir_ino: u64,
    name: OsString,
}

fn io_error(what: &str, path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("{what} '{}': {e}", path.display()))
}

impl OutputName {
    /// The entry `path` names, creating its directory if needed. Refuses a
    /// path without a file name (`dir/..`, `/`) and one that is a directory.
    pub fn create_dir_of(path: &Path) -> Result<Self, CliError> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        std::fs::create_dir_all(dir).map_err(|e| io_error("cannot create directory", dir, e))?;
        Self::of_existing_dir(path, dir)
    }

    /// The entry `path` names, whose directory exists (an input).
    pub fn of(path: &Path) -> Result<Self, CliError> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        Self::of_existing_dir(path, dir)
    }

    fn of_existing_dir(path: &Path, dir: &Path) -> Result<Self, CliError> {
        let name = path
            .file_name()
            .ok_or_else(|| io_error("cannot write", path, "not a file name"))?;
        if path.is_dir() {
            return Err(io_error("cannot write", path, "is a directory"));
        }
        let meta = std::fs::metadata(dir).map_err(|e| io_error("cannot read", dir, e))?;
        Ok(Self {
            dir_dev: meta.dev(),
            dir_ino: meta.ino(),
            name: name.to_os_string(),
        })
    }
}

/// Refuses any two of `(flag, path, entry)` naming the same entry; `Usage`
/// error naming both flags.
pub fn refuse_same(entries: &[(&str, &Path, &OutputName)]) -> Result<(), CliError> {
    for (i, (flag_a, path_a, a)) in entries.iter().enumerate() {
        for (flag_b, path_b, b) in &entries[..i] {
            if a == b {
                return Err(CliError::Usage(format!(
                    "{flag_b} '{}' and {flag_a} '{}' are the same file; they must differ",
                    path_b.display(),
                    path_a.display()
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_entry_through_dot_dot_and_symlinked_dir() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("out/f.npy");
        let b = dir.path().join("out/../out/f.npy");
        let na = OutputName::create_dir_of(&a).unwrap();
        let nb = OutputName::create_dir_of(&b).unwrap();
        assert_eq!(na, nb);
        std::os::unix::fs::symlink(dir.path().join("out"), dir.path().join("link")).unwrap();
        let nc = OutputName::create_dir_of(&dir.path().join("link/f.npy")).unwrap();
        assert_eq!(na, nc);
        let nd = OutputName::create_dir_of(&dir.path().join("out/g.npy")).unwrap();
        assert_ne!(na, nd);
        let e = refuse_same(&[("--out", &a, &na), ("--png", &b, &nb)]).unwrap_err();
        assert!(matches!(e, CliError::Usage(_)), "{e}");
        assert!(refuse_same(&[("--out", &a, &na), ("--png", &b, &nd)]).is_ok());
    }

    #[test]
    fn a_directory_or_no_name_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        assert!(OutputName::create_dir_of(dir.path()).is_err());
        assert!(OutputName::create_dir_of(&dir.path().join("..")).is_err());
    }
}
