//! A new output file that sdictl creates as the calling user and hands to
//! the daemon as a descriptor: written under a hidden temporary name in the
//! destination's directory (created O_EXCL), flushed and linked to its name
//! on commit (never replacing an existing file), removed if dropped
//! uncommitted, so an error leaves nothing behind. The file handling is
//! [`crate::atomic_file::AtomicFile`]'s.

use std::fs::File;
use std::io::ErrorKind;
use std::path::Path;

use crate::atomic_file::AtomicFile;
use crate::exit::CliError;

pub struct NewFile {
    file: AtomicFile,
    dest: std::path::PathBuf,
}

fn io_error(what: &str, path: &Path, e: std::io::Error) -> CliError {
    let msg = format!("{what} {}: {e}", path.display());
    match e.kind() {
        ErrorKind::NotFound | ErrorKind::PermissionDenied | ErrorKind::AlreadyExists => {
            CliError::Usage(msg)
        }
        _ => CliError::Runtime(msg),
    }
}

impl NewFile {
    /// Creates the empty temporary file next to `dest`, which must not exist.
    pub fn create(dest: &Path) -> Result<Self, CliError> {
        if dest.file_name().is_none() {
            return Err(CliError::Usage(format!(
                "'{}' names no file",
                dest.display()
            )));
        }
        if dest.symlink_metadata().is_ok() {
            return Err(CliError::Usage(format!(
                "{} exists (sdictl never overwrites)",
                dest.display()
            )));
        }
        let file = AtomicFile::new(dest).map_err(|e| io_error("cannot create", dest, e))?;
        Ok(Self {
            file,
            dest: dest.to_owned(),
        })
    }

    /// The open file, to pass to the daemon.
    pub fn file(&self) -> &File {
        self.file.file()
    }

    /// Gives the finished file its name; fails (removing the temporary file)
    /// if something appeared at the destination meanwhile.
    pub fn commit(self) -> Result<(), CliError> {
        self.file
            .commit_new()
            .map_err(|e| io_error("cannot create", &self.dest, e))
    }

    /// The empty temporary file for a new `dir/stem-N.ext`, N chosen when
    /// it is committed ([`Numbered::commit`]).
    pub fn numbered(dir: &Path, stem: &str, ext: &str) -> Result<Numbered, CliError> {
        let first = dir.join(format!("{stem}-1.{ext}"));
        let file = AtomicFile::new(&first).map_err(|e| io_error("cannot create", &first, e))?;
        Ok(Numbered {
            file,
            dir: dir.to_owned(),
            stem: stem.to_owned(),
            ext: ext.to_owned(),
        })
    }
}

/// A new file named `stem-N.ext` with the first N free when it is linked
/// into place: the link refuses a taken name atomically and the next N is
/// tried, so files made at the same time never collide.
pub struct Numbered {
    file: AtomicFile,
    dir: std::path::PathBuf,
    stem: String,
    ext: String,
}

impl Numbered {
    /// The open file, to pass to the daemon.
    pub fn file(&self) -> &File {
        self.file.file()
    }

    /// Links the finished file to the first free name; returns it.
    pub fn commit(self) -> Result<std::path::PathBuf, CliError> {
        let Self {
            file,
            dir,
            stem,
            ext,
        } = self;
        let names = (1u32..).map(|n| dir.join(format!("{stem}-{n}.{ext}")));
        file.commit_first_free(names)
            .map_err(|e| io_error("cannot create a file in", &dir, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic_file::tests::entries;
    use std::io::Write;

    #[test]
    fn numbered_files_take_the_next_free_number() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("s-1.npy"), b"x").unwrap();
        let a = NewFile::numbered(dir.path(), "s", "npy").unwrap();
        let b = NewFile::numbered(dir.path(), "s", "npy").unwrap();
        assert_eq!(b.commit().unwrap(), dir.path().join("s-2.npy"));
        assert_eq!(a.commit().unwrap(), dir.path().join("s-3.npy"));
        assert_eq!(entries(dir.path()), ["s-1.npy", "s-2.npy", "s-3.npy"]);
    }

    #[test]
    fn commit_links_and_drop_cleans_up() {
        let dir = std::env::temp_dir().join(format!("sdictl-newfile-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let dest = dir.join("a.npy");
        let f = NewFile::create(&dest).unwrap();
        f.file().write_all(b"abc").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(&dest).unwrap(), b"abc");
        assert_eq!(entries(&dir), ["a.npy"]);
        // Existing destination: refused before anything is created.
        assert!(matches!(NewFile::create(&dest), Err(CliError::Usage(_))));
        // Dropped uncommitted: nothing left.
        let f = NewFile::create(&dir.join("b.png")).unwrap();
        f.file().write_all(b"half").unwrap();
        drop(f);
        assert_eq!(entries(&dir), ["a.npy"]);
        // Something appears at the destination meanwhile: not replaced.
        let f = NewFile::create(&dir.join("c.png")).unwrap();
        std::fs::write(dir.join("c.png"), b"theirs").unwrap();
        assert!(f.commit().is_err());
        assert_eq!(std::fs::read(dir.join("c.png")).unwrap(), b"theirs");
        assert_eq!(entries(&dir), ["a.npy", "c.png"]);
        // A directory that does not exist: a usage error.
        assert!(matches!(
            NewFile::create(&dir.join("missing/x.npy")),
            Err(CliError::Usage(_))
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
