//! What a client may name in the path methods (`Snapshot(s)`,
//! `StartRecording(s)`): only a new file directly in the daemon's own state
//! directory, `<state dir>/NAME.ext`. The daemon never resolves any other
//! client path; everywhere else clients pass a descriptor
//! ([`super::client_fd`]). Every refusal is the same error, so a path
//! method tells nothing about files the caller cannot see.

use std::path::Path;

use super::errors::SdiError;

/// Kinds of files the daemon writes for clients.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    Png,
    Npy,
    Recording,
}

impl OutputKind {
    fn extension(self) -> &'static str {
        match self {
            OutputKind::Png => "png",
            OutputKind::Npy => "npy",
            OutputKind::Recording => "sdirec",
        }
    }
}

/// Longest file name the daemon creates (NAME_MAX).
pub const MAX_NAME_BYTES: usize = 255;

/// The file name `path` gives inside `state_dir`, if `path` is exactly
/// `<state_dir>/NAME` (absolute, compared as text, no trailing slash) with a
/// plain NAME: no `/`, not `.`/`..`, no control characters, at most
/// [`MAX_NAME_BYTES`], extension one of `allowed` (any case). Pure text:
/// nothing on disk is looked at.
pub fn state_dir_name(
    path: &str,
    state_dir: &Path,
    allowed: &[OutputKind],
) -> Option<(String, OutputKind)> {
    let dir = state_dir.to_str()?.trim_end_matches('/');
    if !dir.starts_with('/') {
        return None;
    }
    let name = path.strip_prefix(dir)?.strip_prefix('/')?;
    let plain = !name.is_empty()
        && name.len() <= MAX_NAME_BYTES
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.chars().any(char::is_control);
    if !plain {
        return None;
    }
    let (stem, ext) = name.rsplit_once('.')?;
    if stem.is_empty() {
        return None;
    }
    let kind = allowed
        .iter()
        .copied()
        .find(|k| ext.eq_ignore_ascii_case(k.extension()))?;
    Some((name.to_owned(), kind))
}

/// The one error for every path a path method refuses (whatever the
/// reason: outside the state directory, existing, unwritable, missing):
/// says what is allowed and where to go instead.
pub fn refused(path: &str, state_dir: Option<&Path>, allowed: &[OutputKind]) -> SdiError {
    let exts: Vec<String> = allowed
        .iter()
        .map(|k| format!(".{}", k.extension()))
        .collect();
    let place = match state_dir {
        Some(d) => format!("directly in its state directory {}", d.display()),
        None => "nowhere (it has no state directory)".to_owned(),
    };
    SdiError::InvalidPath(format!(
        "'{}' refused: by path the daemon creates only a new file NAME{} {place}; \
         for any other place pass a descriptor (SnapshotToFd, StartRecordingToFd: \
         sdictl does so without --by-path; the service's /tmp is private, PrivateTmp=yes)",
        path.escape_debug(),
        exts.join("|NAME"),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_paths() {
        let all = [OutputKind::Png, OutputKind::Npy];
        let dir = Path::new("/var/lib/sdi");
        for bad in [
            "",
            "rel.png",
            "/tmp/../etc/x.png",
            "/var/lib/sdi/../x.png",
            "/var/lib/sdi/x.jpg",
            "/var/lib/sdi/x.sdirec",
            "/proc/x.png",
            "/nonexistent-dir/x.png",
            "/tmp/x.png",
            "/var/lib/sdi/x.png/",
            "/var/lib/sdi/sub/x.png",
            "/var/lib/sdi//x.png",
            "/var/lib/sdix.png",
            "/var/lib/sdi/.png",
            "/var/lib/sdi/a\nb.png",
            "var/lib/sdi/x.png",
        ] {
            assert_eq!(state_dir_name(bad, dir, &all), None, "{bad:?}");
        }
        let long = format!("/var/lib/sdi/{}.png", "x".repeat(MAX_NAME_BYTES));
        assert_eq!(state_dir_name(&long, dir, &all), None);
        assert_eq!(
            state_dir_name("/var/lib/sdi/a.NPY", dir, &all),
            Some(("a.NPY".to_owned(), OutputKind::Npy))
        );
        assert_eq!(
            state_dir_name("/var/lib/sdi/run.sdirec", dir, &[OutputKind::Recording]),
            Some(("run.sdirec".to_owned(), OutputKind::Recording))
        );
        // A state directory given with a trailing slash.
        assert_eq!(
            state_dir_name("/s/a.png", Path::new("/s/"), &all),
            Some(("a.png".to_owned(), OutputKind::Png))
        );
    }

    #[test]
    fn one_message_for_every_refusal() {
        let all = [OutputKind::Png, OutputKind::Npy];
        let dir = Some(Path::new("/var/lib/sdi"));
        let msg = |p: &str| match refused(p, dir, &all) {
            SdiError::InvalidPath(m) => m.replacen(&p.escape_debug().to_string(), "P", 1),
            other => panic!("{other:?}"),
        };
        assert_eq!(msg("/etc/shadow.png"), msg("/root/missing/x.png"));
        assert!(msg("/a\nb.png").contains("PrivateTmp"));
        match refused("/a\nb.png", dir, &all) {
            SdiError::InvalidPath(m) => assert!(!m.contains('\n'), "{m}"),
            other => panic!("{other:?}"),
        }
    }
}
