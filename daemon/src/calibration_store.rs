//! Where sdid keeps calibrations between runs: `calibration.toml` (core's
//! [`CalibrationStore`], keyed by sensor model and serial) in the state
//! directory: `--state-dir`, else systemd's `$STATE_DIRECTORY`
//! (/var/lib/sdi), else `$XDG_STATE_HOME/sdi`, else `~/.local/state/sdi`.

use std::io;
use std::path::{Path, PathBuf};

use sdi_core::calibration::{CalibrationRecord, CalibrationStore, PhaseRecord};

/// File name inside the state directory.
pub const FILE_NAME: &str = "calibration.toml";

/// The state directory, from the argument or the environment.
pub fn state_dir(arg: Option<&Path>) -> Option<PathBuf> {
    if let Some(p) = arg {
        return Some(p.to_owned());
    }
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    // systemd may list several directories separated by ':'; the first is ours.
    if let Some(d) = std::env::var("STATE_DIRECTORY")
        .ok()
        .filter(|v| !v.is_empty())
    {
        return d.split(':').next().map(PathBuf::from);
    }
    env("XDG_STATE_HOME")
        .or_else(|| env("HOME").map(|h| h.join(".local/state")))
        .map(|d| d.join("sdi"))
}

fn read_store(dir: &Path) -> io::Result<CalibrationStore> {
    match std::fs::read_to_string(dir.join(FILE_NAME)) {
        Ok(text) => CalibrationStore::from_toml(&text)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e.to_string())),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(CalibrationStore::default()),
        Err(e) => Err(e),
    }
}

/// The stored calibration of this sensor, if any.
pub fn load(dir: &Path, model: &str, serial: &str) -> io::Result<Option<CalibrationRecord>> {
    Ok(read_store(dir)?.get(model, serial).cloned())
}

/// The stored phase record of this board, if any.
pub fn load_phase(dir: &Path, model: &str, serial: &str) -> io::Result<Option<PhaseRecord>> {
    Ok(read_store(dir)?.phase(model, serial).cloned())
}

/// Where an unreadable store is kept aside when a new one replaces it.
pub const UNREADABLE_NAME: &str = "calibration.toml.unreadable";

/// Adds or replaces `record` in the store, atomically: a fresh temporary file
/// (`tempfile`, O_EXCL, random name) in `dir`, flushed, renamed over the
/// store, then the directory flushed. A store that cannot be parsed does not
/// block this: it is kept aside as [`UNREADABLE_NAME`] (the log says so) and
/// a new store holds `record`.
pub fn save(dir: &Path, record: CalibrationRecord) -> io::Result<PathBuf> {
    update(dir, |store| store.upsert(record))
}

/// Adds or replaces a board's phase record, as [`save`] does.
pub fn save_phase(dir: &Path, record: PhaseRecord) -> io::Result<PathBuf> {
    update(dir, |store| store.upsert_phase(record))
}

/// Reads the store (an unreadable one kept aside), changes it, writes it
/// back atomically ([`save`]).
fn update(dir: &Path, change: impl FnOnce(&mut CalibrationStore)) -> io::Result<PathBuf> {
    std::fs::create_dir_all(dir)?;
    let mut store = match read_store(dir) {
        Ok(store) => store,
        Err(e) if e.kind() == io::ErrorKind::InvalidData => {
            let aside = dir.join(UNREADABLE_NAME);
            std::fs::rename(dir.join(FILE_NAME), &aside)?;
            tracing::warn!(
                path = %aside.display(),
                "the stored calibrations could not be read ({e}); kept aside, a new store replaces them"
            );
            CalibrationStore::default()
        }
        Err(e) => return Err(e),
    };
    change(&mut store);
    let text = store
        .to_toml()
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e.to_string()))?;
    let path = dir.join(FILE_NAME);
    let mut tmp = tempfile::Builder::new()
        .prefix(&format!(".{FILE_NAME}."))
        .permissions(std::os::unix::fs::PermissionsExt::from_mode(0o644))
        .tempfile_in(dir)?;
    io::Write::write_all(&mut tmp, text.as_bytes())?;
    tmp.as_file().sync_all()?;
    tmp.persist(&path).map_err(|e| e.error)?;
    std::fs::File::open(dir)?.sync_all()?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::calibration::PhotonTransferFit;

    /// A photon-transfer fit as Calibrate stores it.
    fn fit() -> PhotonTransferFit {
        PhotonTransferFit {
            gain_dn_per_electron: 0.05,
            gain_se: 0.001,
            read_variance_dn2: 15.0,
            read_variance_se_dn2: 0.1,
            reduced_chi2: 1.0,
            points: 5,
        }
    }

    #[test]
    fn save_then_load_by_model_and_serial() {
        let dir = tempfile::tempdir().unwrap();
        let fit = PhotonTransferFit {
            gain_dn_per_electron: 0.052,
            gain_se: 0.0003,
            read_variance_dn2: 15.1,
            read_variance_se_dn2: 0.03,
            reduced_chi2: 1.0,
            points: 5,
        };
        assert!(load(dir.path(), "m", "s").unwrap().is_none());
        let rec = CalibrationRecord::from_fit("m", "s", &fit, 4.0, 30);
        save(dir.path(), rec.clone()).unwrap();
        save(
            dir.path(),
            CalibrationRecord::from_fit("m", "other", &fit, 4.0, 30),
        )
        .unwrap();
        assert_eq!(load(dir.path(), "m", "s").unwrap(), Some(rec));
        assert_eq!(state_dir(Some(Path::new("/x"))), Some(PathBuf::from("/x")));
    }

    #[test]
    fn a_phase_record_joins_the_gain_of_the_same_board() {
        let dir = tempfile::tempdir().unwrap();
        let fit = fit();
        let rec = CalibrationRecord::from_fit("m", "s", &fit, 4.0, 30);
        save(dir.path(), rec.clone()).unwrap();
        assert!(load_phase(dir.path(), "m", "s").unwrap().is_none());
        let phase = PhaseRecord {
            model: "m".into(),
            serial: "s".into(),
            angle_rad: 1.047,
            amplitude_dn: 80.0,
            coherence: 0.98,
            frames: 16,
        };
        save_phase(dir.path(), phase.clone()).unwrap();
        assert_eq!(load_phase(dir.path(), "m", "s").unwrap(), Some(phase));
        assert_eq!(load(dir.path(), "m", "s").unwrap(), Some(rec));
    }

    #[test]
    fn a_garbage_store_is_kept_aside_and_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let garbage = b"\xff\x00 this is [not toml";
        std::fs::write(dir.path().join(FILE_NAME), garbage).unwrap();
        assert!(load(dir.path(), "m", "s").is_err());
        let fit = fit();
        let rec = CalibrationRecord::from_fit("m", "s", &fit, 4.0, 30);
        save(dir.path(), rec.clone()).unwrap();
        assert_eq!(load(dir.path(), "m", "s").unwrap(), Some(rec));
        assert_eq!(
            std::fs::read(dir.path().join(UNREADABLE_NAME)).unwrap(),
            garbage
        );
    }
}
