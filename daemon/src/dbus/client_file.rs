//! Files the daemon creates itself for the path methods: a new plain name
//! ([`super::paths::state_dir_name`]) created relative to a descriptor of
//! its state directory with `O_CREAT|O_EXCL|O_NOFOLLOW` (no symlink, no
//! parent directory resolved from client input, never an existing file),
//! and handed to the caller with `fchown` on the descriptor before a byte
//! is written (never chown by path).

use std::fs::File;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};

use rustix::fs::{AtFlags, Mode, OFlags};

use super::errors::SdiError;
use super::paths::{refused, state_dir_name, OutputKind};

/// A new, empty file in the state directory, owned by the caller.
#[derive(Debug)]
pub struct StateDirFile {
    pub file: File,
    pub path: PathBuf,
    pub kind: OutputKind,
    dir: OwnedFd,
    name: String,
}

/// Creates `path` (which must be `<state_dir>/NAME`) for the caller with
/// uid `owner`. Every refusal and every failure to create is the same
/// `InvalidPath` ([`refused`]); the cause goes to the log, escaped.
pub fn create(
    state_dir: Option<&Path>,
    path: &str,
    allowed: &[OutputKind],
    owner: Option<u32>,
) -> Result<StateDirFile, SdiError> {
    let no = |why: &dyn std::fmt::Display| {
        tracing::info!(path = ?path, "path method refused: {why}");
        refused(path, state_dir, allowed)
    };
    let dir_path = state_dir.ok_or_else(|| no(&"no state directory"))?;
    let (name, kind) = state_dir_name(path, dir_path, allowed)
        .ok_or_else(|| no(&"not a new NAME.ext in the state directory"))?;
    // The state directory is the daemon's own configuration, not client input.
    std::fs::create_dir_all(dir_path).map_err(|e| no(&e))?;
    let dir = rustix::fs::open(
        dir_path,
        OFlags::DIRECTORY | OFlags::RDONLY | OFlags::CLOEXEC,
        Mode::empty(),
    )
    .map_err(|e| no(&e))?;
    let fd = rustix::fs::openat(
        &dir,
        name.as_str(),
        OFlags::WRONLY | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC,
        Mode::from_raw_mode(0o644),
    )
    .map_err(|e| no(&e))?;
    let created = StateDirFile {
        file: File::from(fd),
        path: dir_path.join(&name),
        kind,
        dir,
        name,
    };
    give_to(&created.file, owner);
    Ok(created)
}

/// Hands a file the daemon (as root) created over to the caller, by
/// descriptor: whatever the name points to by now is not touched. Without
/// CAP_CHOWN (the systemd unit) the file stays the daemon's, readable by
/// the group `sdi`.
fn give_to(file: &File, uid: Option<u32>) {
    let Some(uid) = uid else { return };
    if !nix::unistd::geteuid().is_root() || uid == 0 {
        return;
    }
    if let Err(e) = rustix::fs::fchown(file, Some(rustix::fs::Uid::from_raw(uid)), None) {
        tracing::warn!("fchown of a new file to uid {uid}: {e}");
    }
}

impl StateDirFile {
    /// Removes the file after a failure, if its name still names it (same
    /// device and inode): never anything else put there meanwhile.
    pub fn discard(self) {
        let (Ok(ours), Ok(now)) = (
            rustix::fs::fstat(self.file.as_fd()),
            rustix::fs::statat(&self.dir, self.name.as_str(), AtFlags::SYMLINK_NOFOLLOW),
        ) else {
            return;
        };
        if ours.st_dev == now.st_dev && ours.st_ino == now.st_ino {
            let _ = rustix::fs::unlinkat(&self.dir, self.name.as_str(), AtFlags::empty());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [OutputKind; 2] = [OutputKind::Png, OutputKind::Npy];

    fn invalid_path(r: Result<StateDirFile, SdiError>) -> String {
        match r {
            Err(SdiError::InvalidPath(m)) => m,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn creates_only_new_plain_names_in_the_state_dir() {
        let dir = tempfile::tempdir().unwrap();
        let p = |n: &str| format!("{}/{n}", dir.path().display());
        let f = create(Some(dir.path()), &p("a.npy"), &ALL, Some(0)).unwrap();
        assert_eq!(f.kind, OutputKind::Npy);
        assert_eq!(f.path, dir.path().join("a.npy"));
        assert_eq!(f.file.metadata().unwrap().len(), 0);
        // Existing file, symlink (even dangling), elsewhere, no state dir:
        // one message apart from the path it quotes.
        std::os::unix::fs::symlink("/nonexistent/target", dir.path().join("l.png")).unwrap();
        let strip = |m: String, path: &str| m.replacen(path, "P", 1);
        let exists = strip(
            invalid_path(create(Some(dir.path()), &p("a.npy"), &ALL, None)),
            &p("a.npy"),
        );
        let link = strip(
            invalid_path(create(Some(dir.path()), &p("l.png"), &ALL, None)),
            &p("l.png"),
        );
        let other = strip(
            invalid_path(create(Some(dir.path()), "/etc/x.png", &ALL, None)),
            "/etc/x.png",
        );
        assert_eq!(exists, link);
        assert_eq!(exists, other);
        assert!(!Path::new("/nonexistent/target").exists());
        assert!(create(None, &p("b.png"), &ALL, None).is_err());
        // Discard removes only our own file.
        let f = create(Some(dir.path()), &p("c.png"), &ALL, None).unwrap();
        f.discard();
        assert!(!dir.path().join("c.png").exists());
        let f = create(Some(dir.path()), &p("d.png"), &ALL, None).unwrap();
        std::fs::remove_file(dir.path().join("d.png")).unwrap();
        std::fs::write(dir.path().join("d.png"), b"theirs").unwrap();
        f.discard();
        assert_eq!(std::fs::read(dir.path().join("d.png")).unwrap(), b"theirs");
    }
}
