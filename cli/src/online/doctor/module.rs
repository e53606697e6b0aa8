//! The v4l2loopback module: installed, loaded, its version; and whether
//! Secure Boot or lockdown lets it in (the "Key was rejected" case).

use std::time::Duration;

use super::{output, Check, Status, Sys};

fn modinfo(field: &str) -> Option<String> {
    output(
        "modinfo",
        &["-F", field, "v4l2loopback"],
        Duration::from_secs(5),
    )
    .map(|s| s.trim().to_owned())
}

/// The module's state, as the checks need it.
#[derive(Debug, Default)]
pub(super) struct Module {
    installed: bool,
    pub(super) loaded: bool,
    version: Option<String>,
    /// Signer of the installed .ko (modinfo), if signed.
    signer: Option<String>,
    /// The loaded module's taint flags ("E": unsigned, "O": out of tree).
    taint: Option<String>,
}

pub(super) fn module(sys: &Sys) -> Module {
    let filename = modinfo("filename");
    let loaded = sys.exists("/sys/module/v4l2loopback");
    let version = sys
        .read("/sys/module/v4l2loopback/version")
        .or_else(|| modinfo("version"))
        .filter(|v| !v.is_empty());
    Module {
        installed: filename.is_some() || loaded,
        loaded,
        version,
        signer: modinfo("signer").filter(|s| !s.is_empty()),
        taint: sys.read("/sys/module/v4l2loopback/taint"),
    }
}

pub(super) fn check_module(m: &Module) -> Check {
    let version = m
        .version
        .as_deref()
        .unwrap_or("0.12.x or older (no version string)");
    match (m.installed, m.loaded) {
        (_, true) => Check::new("module", Status::Ok, format!("v4l2loopback {version} loaded")),
        (true, false) => Check::new("module", Status::Fail, format!("v4l2loopback {version} installed but not loaded"))
            .fix("sudo modprobe v4l2loopback (its options come from /etc/modprobe.d/sdi.conf, which `make install` puts there); to load it at boot: /etc/modules-load.d/sdi.conf"),
        (false, false) => Check::new("module", Status::Fail, "v4l2loopback is not installed for this kernel")
            .fix("sudo apt install v4l2loopback-dkms linux-headers-$(uname -r) (Debian/Ubuntu; other distributions: their v4l2loopback package), then sudo modprobe v4l2loopback"),
    }
}

/// Secure Boot state from the EFI variable: None without EFI.
pub(super) fn secure_boot(sys: &Sys) -> Option<bool> {
    let dir = sys.path("/sys/firmware/efi/efivars");
    let entries = std::fs::read_dir(dir).ok()?;
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().starts_with("SecureBoot-") {
            // 4 bytes of attributes, then the value
            let bytes = std::fs::read(e.path()).ok()?;
            return bytes.get(4).map(|&b| b == 1);
        }
    }
    sys.exists("/sys/firmware/efi").then_some(false)
}

/// The selected lockdown mode (`[none] integrity confidentiality`).
pub(super) fn lockdown(sys: &Sys) -> Option<String> {
    let text = sys.read("/sys/kernel/security/lockdown")?;
    let start = text.find('[')?;
    let end = text[start..].find(']')?;
    Some(text[start + 1..start + end].to_owned())
}

const MOK_STEPS: &str = "modprobe fails with \"Key was rejected by service\" when Secure Boot is on and the module is not signed by a key the firmware trusts. DKMS signs the modules it builds with its own key; enrol that key once: sudo mokutil --import /var/lib/dkms/mok.pub (choose a one-time password), reboot, pick \"Enroll MOK\" in the blue MokManager screen and type that password; then sudo dkms autoinstall (or reinstall v4l2loopback-dkms) and sudo modprobe v4l2loopback. Check with: mokutil --test-key /var/lib/dkms/mok.pub";

/// The Secure Boot / lockdown / signature verdict (pure, unit-tested).
pub(super) fn signature_verdict(sb: Option<bool>, lockdown: Option<&str>, m: &Module) -> Check {
    let sb_text = match sb {
        Some(true) => "Secure Boot on",
        Some(false) => "Secure Boot off",
        None => "no EFI (no Secure Boot)",
    };
    let lock = lockdown.unwrap_or("none");
    let enforced = sb == Some(true) || lock != "none";
    let state = format!("{sb_text}, lockdown {lock}");
    if m.loaded {
        let unsigned = m.taint.as_deref().is_some_and(|t| t.contains('E'));
        let sig = if unsigned {
            "unsigned"
        } else {
            "signature accepted"
        };
        return Check::new(
            "secure-boot",
            Status::Ok,
            format!("{state}; the loaded module: {sig}"),
        );
    }
    if !m.installed {
        return Check::new(
            "secure-boot",
            Status::Skip,
            format!("{state}; no module to check"),
        );
    }
    match (&m.signer, enforced) {
        (None, true) => Check::new(
            "secure-boot",
            Status::Fail,
            format!("{state}, and the v4l2loopback module is not signed: the kernel will refuse it"),
        )
        .fix(MOK_STEPS),
        (Some(signer), true) => Check::new(
            "secure-boot",
            Status::Warn,
            format!("{state}; the module is signed by \"{signer}\": it loads only if that key is enrolled"),
        )
        .fix(MOK_STEPS),
        (signer, false) => Check::new(
            "secure-boot",
            Status::Ok,
            format!(
                "{state}; module {}",
                signer
                    .as_ref()
                    .map_or("unsigned (fine without Secure Boot)".to_owned(), |s| format!("signed by \"{s}\""))
            ),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn module(installed: bool, loaded: bool, signer: Option<&str>, taint: Option<&str>) -> Module {
        Module {
            installed,
            loaded,
            version: None,
            signer: signer.map(str::to_owned),
            taint: taint.map(str::to_owned),
        }
    }

    #[test]
    fn unsigned_module_under_secure_boot_fails_with_mok_steps() {
        let c = signature_verdict(
            Some(true),
            Some("integrity"),
            &module(true, false, None, None),
        );
        assert_eq!(c.status, Status::Fail);
        assert!(c
            .fix
            .as_deref()
            .is_some_and(|f| f.contains("mokutil --import") && f.contains("Key was rejected")));
        let c = signature_verdict(
            Some(true),
            None,
            &module(true, false, Some("DKMS module signing key"), None),
        );
        assert_eq!(c.status, Status::Warn);
        let c = signature_verdict(Some(false), Some("none"), &module(true, false, None, None));
        assert_eq!(c.status, Status::Ok);
        // lockdown alone (no Secure Boot) also refuses unsigned modules
        let c = signature_verdict(None, Some("integrity"), &module(true, false, None, None));
        assert_eq!(c.status, Status::Fail);
        // loaded: it got in, whatever the state
        let c = signature_verdict(Some(true), None, &module(true, true, None, Some("OE")));
        assert_eq!(c.status, Status::Ok);
        assert!(c.summary.contains("unsigned"));
        let c = signature_verdict(None, None, &module(false, false, None, None));
        assert_eq!(c.status, Status::Skip);
    }
}
