//! Output files that appear whole or not at all: written to a hidden
//! temporary file (`tempfile`, created O_EXCL under a random name) in the
//! destination's directory, flushed to disk (file, then directory) and
//! renamed or linked into place on commit, removed if dropped uncommitted.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

pub struct AtomicFile {
    tmp: NamedTempFile,
    dest: PathBuf,
}

/// The directory holding `path` ("." for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Flushes a directory's entries, so a rename or link in it survives a crash.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

impl AtomicFile {
    /// Creates the empty temporary file next to `dest`, with mode 0644 (less the umask).
    pub fn new(dest: &Path) -> std::io::Result<Self> {
        use std::os::unix::fs::PermissionsExt;
        let name = dest.file_name().ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("'{}' is not a file name", dest.display()),
            )
        })?;
        let mut prefix = std::ffi::OsString::from(".");
        prefix.push(name);
        prefix.push(".");
        let tmp = tempfile::Builder::new()
            .prefix(&prefix)
            .suffix(".tmp")
            .permissions(std::fs::Permissions::from_mode(0o644))
            .tempfile_in(parent_dir(dest))?;
        Ok(Self {
            tmp,
            dest: dest.to_path_buf(),
        })
    }

    pub fn tmp_path(&self) -> &Path {
        self.tmp.path()
    }

    /// The temporary file, for buffered writing.
    pub fn create(&self) -> std::io::Result<BufWriter<File>> {
        self.tmp.as_file().try_clone().map(BufWriter::new)
    }

    /// The open temporary file (to pass on as a descriptor).
    pub fn file(&self) -> &File {
        self.tmp.as_file()
    }

    /// Moves the finished file into place, replacing any file there.
    pub fn commit(self) -> std::io::Result<()> {
        self.tmp.as_file().sync_all()?;
        self.tmp.persist(&self.dest).map_err(|e| e.error)?;
        sync_dir(parent_dir(&self.dest))
    }

    /// Gives the finished file the first of `names` that names no file
    /// (each tried with an atomic no-replace link, so two commits at once
    /// never take the same name); returns it. Removed on failure.
    pub fn commit_first_free(
        self,
        names: impl IntoIterator<Item = PathBuf>,
    ) -> std::io::Result<PathBuf> {
        self.tmp.as_file().sync_all()?;
        let mut tmp = self.tmp;
        for name in names {
            match tmp.persist_noclobber(&name) {
                Ok(_) => {
                    sync_dir(parent_dir(&name))?;
                    return Ok(name);
                }
                Err(e) if e.error.kind() == std::io::ErrorKind::AlreadyExists => tmp = e.file,
                // No hard links (as in `commit_new`): rename if still free.
                Err(e) if name.symlink_metadata().is_err() => {
                    e.file.persist(&name).map_err(|e| e.error)?;
                    sync_dir(parent_dir(&name))?;
                    return Ok(name);
                }
                Err(e) => return Err(e.error),
            }
        }
        Err(std::io::Error::new(
            std::io::ErrorKind::AlreadyExists,
            "every name is taken",
        ))
    }

    /// Gives the finished file its name, never replacing a file that
    /// appeared there meanwhile (`AlreadyExists`); the temporary file is
    /// removed on failure.
    pub fn commit_new(self) -> std::io::Result<()> {
        self.tmp.as_file().sync_all()?;
        match self.tmp.persist_noclobber(&self.dest) {
            Ok(_) => {}
            // File systems without hard links or RENAME_NOREPLACE (vfat,
            // some FUSE): rename, after checking again that nothing is in the way.
            Err(e)
                if e.error.kind() != std::io::ErrorKind::AlreadyExists
                    && self.dest.symlink_metadata().is_err() =>
            {
                e.file.persist(&self.dest).map_err(|e| e.error)?;
            }
            Err(e) => return Err(e.error),
        }
        sync_dir(parent_dir(&self.dest))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::io::Write;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("sdictl-atomic-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The names in `dir`, sorted.
    pub(crate) fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn commit_replaces_and_drop_cleans_up() {
        let dir = scratch("replace");
        let dest = dir.join("out.npy");
        std::fs::write(&dest, b"old").unwrap();
        let f = AtomicFile::new(&dest).unwrap();
        let mut w = f.create().unwrap();
        w.write_all(b"new").unwrap();
        w.flush().unwrap();
        drop(w);
        assert_eq!(
            std::fs::read(&dest).unwrap(),
            b"old",
            "not in place before commit"
        );
        f.commit().unwrap();
        assert_eq!(std::fs::read(&dest).unwrap(), b"new");
        let f = AtomicFile::new(&dir.join("other.png")).unwrap();
        f.file().write_all(b"half").unwrap();
        drop(f);
        assert_eq!(entries(&dir), ["out.npy"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn commit_new_never_replaces() {
        let dir = scratch("new");
        let dest = dir.join("a.npy");
        let f = AtomicFile::new(&dest).unwrap();
        std::fs::write(&dest, b"theirs").unwrap();
        let e = f.commit_new().unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::AlreadyExists);
        assert_eq!(std::fs::read(&dest).unwrap(), b"theirs");
        assert_eq!(entries(&dir), ["a.npy"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn new_file_mode_is_0644_less_umask() {
        use std::os::unix::fs::PermissionsExt;
        let dir = scratch("mode");
        let f = AtomicFile::new(&dir.join("m.npy")).unwrap();
        let mode = f.file().metadata().unwrap().permissions().mode() & 0o777;
        assert_eq!(mode & !0o644, 0, "{mode:o}");
        drop(f);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
