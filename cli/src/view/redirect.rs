//! The file the browser opens instead of the page's URL, as Jupyter Server
//! does: a command line is readable by every user (`/proc/PID/cmdline`), so
//! the URL with its token is never one. The file, mode 0600 in the user's
//! runtime directory (`$XDG_RUNTIME_DIR`, else a new 0700 directory in the
//! temporary directory), sends the browser on to the page with the token in
//! the URL's fragment, which the browser never sends to a server; the page
//! takes it from there into the tab's session storage and drops it from
//! its address (`assets/app.js`). The file is removed when sdictl ends.

use std::io::Write;
use std::path::{Path, PathBuf};

use tempfile::{NamedTempFile, TempDir};

use crate::exit::CliError;

/// The redirect file; removed (with its directory, if sdictl made one) on drop.
pub struct RedirectFile {
    file: NamedTempFile,
    _dir: Option<TempDir>,
}

impl RedirectFile {
    /// Writes the file that leads to `url`, which must need no HTML escaping
    /// (sdictl's own `http://127.0.0.1:PORT/#token=HEX`).
    pub fn write(url: &str) -> Result<Self, CliError> {
        let runtime = std::env::var_os("XDG_RUNTIME_DIR")
            .map(PathBuf::from)
            .filter(|d| d.is_absolute() && d.is_dir());
        let (dir, own_dir) = match runtime {
            Some(d) => (d, None),
            None => {
                let d = tempfile::Builder::new()
                    .prefix("sdictl-view-")
                    .tempdir()
                    .map_err(|e| CliError::Runtime(format!("creating a private directory: {e}")))?;
                (d.path().to_owned(), Some(d))
            }
        };
        let err = |e: std::io::Error| {
            CliError::Runtime(format!("writing the page's file in {}: {e}", dir.display()))
        };
        // tempfile creates the file O_EXCL with mode 0600.
        let mut file = tempfile::Builder::new()
            .prefix("sdictl-view-")
            .suffix(".html")
            .tempfile_in(&dir)
            .map_err(err)?;
        file.write_all(html(url).as_bytes()).map_err(err)?;
        file.flush().map_err(err)?;
        Ok(Self {
            file,
            _dir: own_dir,
        })
    }

    pub fn path(&self) -> &Path {
        self.file.path()
    }
}

fn html(url: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">\n\
         <meta http-equiv=\"refresh\" content=\"0;url={url}\">\n\
         <title>sdictl view</title></head>\n\
         <body><p>Opening <a href=\"{url}\">the SDI viewer</a>...</p>\n\
         <script>location.replace(\"{url}\");</script></body></html>\n"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn the_file_is_private_and_leads_to_the_url() {
        let url = "http://127.0.0.1:1234/#token=00ff";
        let f = RedirectFile::write(url).unwrap();
        let meta = std::fs::metadata(f.path()).unwrap();
        assert_eq!(meta.permissions().mode() & 0o777, 0o600);
        let text = std::fs::read_to_string(f.path()).unwrap();
        assert!(text.contains(&format!("content=\"0;url={url}\"")), "{text}");
        let path = f.path().to_owned();
        drop(f);
        assert!(!path.exists());
    }
}
