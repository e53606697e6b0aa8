//! Validation of paths clients ask the daemon to write.

use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};

use super::errors::SdiError;

/// Kinds of files the daemon writes for clients.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    Png,
    Npy,
    Recording,
}

/// Checks `path` before the daemon (possibly root) writes it for the caller
/// with uid `caller_uid`: non-empty, absolute, no `..`, allowed extension,
/// outside /proc, /sys and /dev, the file does not exist yet, and its existing
/// parent directory is writable by the caller.
pub fn validate_output_path(
    path: &str,
    allowed: &[OutputKind],
    caller_uid: Option<u32>,
) -> Result<(PathBuf, OutputKind), SdiError> {
    let bad = |why: &str| SdiError::InvalidPath(format!("'{}': {why}", path.escape_debug()));
    if path.is_empty() {
        return Err(bad("empty path"));
    }
    let p = Path::new(path);
    if !p.is_absolute() {
        return Err(bad(
            "must be absolute (the daemon has its own working directory)",
        ));
    }
    if p.components().any(|c| matches!(c, Component::ParentDir)) {
        return Err(bad("must not contain '..'"));
    }
    let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
    let kind = match ext.to_ascii_lowercase().as_str() {
        "png" => OutputKind::Png,
        "npy" => OutputKind::Npy,
        "sdirec" => OutputKind::Recording,
        _ => OutputKind::Png,
    };
    let ext_ok = match kind {
        OutputKind::Png => ext.eq_ignore_ascii_case("png"),
        _ => true,
    };
    if !ext_ok || !allowed.contains(&kind) {
        let names: Vec<&str> = allowed
            .iter()
            .map(|k| match k {
                OutputKind::Png => ".png",
                OutputKind::Npy => ".npy",
                OutputKind::Recording => ".sdirec",
            })
            .collect();
        return Err(bad(&format!(
            "extension must be one of {}",
            names.join(", ")
        )));
    }
    for forbidden in ["/proc", "/sys", "/dev"] {
        if p.starts_with(forbidden) {
            return Err(bad(&format!("writing under {forbidden} is not allowed")));
        }
    }
    if let Some(why) = sandbox_hides(p, std::env::var_os("INVOCATION_ID").is_some()) {
        return Err(bad(&why));
    }
    if std::fs::symlink_metadata(p).is_ok() {
        return Err(bad("file exists (the daemon never overwrites)"));
    }
    let parent = p.parent().ok_or_else(|| bad("no parent directory"))?;
    let meta = std::fs::metadata(parent).map_err(|e| bad(&format!("parent directory: {e}")))?;
    if !meta.is_dir() {
        return Err(bad("parent is not a directory"));
    }
    if let Some(uid) = caller_uid {
        let mode = meta.mode();
        let writable = uid == 0 || (meta.uid() == uid && mode & 0o200 != 0) || mode & 0o002 != 0;
        if !writable {
            return Err(bad(&format!(
                "directory {} is not writable by the caller (uid {uid})",
                parent.display()
            )));
        }
    }
    Ok((p.to_owned(), kind))
}

/// Under systemd (`INVOCATION_ID` set) the unit's `PrivateTmp=yes` gives
/// sdid its own /tmp and /var/tmp: a file written there would "succeed" and
/// stay invisible to the caller, so such paths are refused with a hint.
pub fn sandbox_hides(path: &Path, under_systemd: bool) -> Option<String> {
    let private = ["/tmp", "/var/tmp"];
    (under_systemd && private.iter().any(|d| path.starts_with(d))).then(|| {
        "the service has a private /tmp (PrivateTmp=yes): a file written there would be \
         invisible to you; let sdictl create the file (sdictl snapshot/record without \
         --by-path passes a descriptor) or use a path below /var/lib/sdi"
            .to_owned()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_paths() {
        let all = [OutputKind::Png, OutputKind::Npy];
        for bad in [
            "",
            "rel.png",
            "/tmp/../etc/x.png",
            "/tmp/x.jpg",
            "/proc/x.png",
            "/nonexistent-dir/x.png",
        ] {
            assert!(
                matches!(
                    validate_output_path(bad, &all, None),
                    Err(SdiError::InvalidPath(_))
                ),
                "{bad}"
            );
        }
        let dir = tempfile::tempdir().unwrap();
        let ok = dir.path().join("a.npy");
        let (_, kind) = validate_output_path(ok.to_str().unwrap(), &all, Some(0)).unwrap();
        assert_eq!(kind, OutputKind::Npy);
        assert!(sandbox_hides(Path::new("/tmp/x.png"), true).is_some());
        assert!(sandbox_hides(Path::new("/var/tmp/x.png"), true).is_some());
        assert!(sandbox_hides(Path::new("/tmp/x.png"), false).is_none());
        assert!(sandbox_hides(Path::new("/var/lib/sdi/x.png"), true).is_none());
        std::fs::write(&ok, b"x").unwrap();
        assert!(validate_output_path(ok.to_str().unwrap(), &all, Some(0)).is_err());
    }
}
