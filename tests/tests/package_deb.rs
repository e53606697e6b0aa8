//! The Debian packages of `make deb` (`packaging/debian/mkdeb.sh`), built
//! from the programs cargo built for the tests (`sdi_tests::package`), or
//! the ones in `SDI_DEB_DIR`: `sdi` holds every file `make install
//! PREFIX=/usr` installs (modes, owner, stripped programs, gzipped man page,
//! copyright and changelog), its control fields are right, the PipeWire
//! camera gets its own package when its program is there, lintian finds no
//! error, and dpkg installs, removes and purges it in a scratch root
//! (`dpkg --root`, maintainer scripts run chrootless with DPKG_ROOT), where
//! the group is created, remove keeps the state and purge takes it away
//! with no installed file left behind. tests/tests/vm_desktop/package.rs installs
//! it on a running system (the VM).

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use sdi_tests::package::{self, contents, field, Debs, VERSION};
use sdi_tests::process::{must, run};

/// A fresh scratch directory for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sdi-deb-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

fn debs() -> Option<&'static Debs> {
    package::debs()
}

/// The files (not directories) of `sdi`, besides what `make install` puts
/// in place (the man page gzipped).
const DOC_FILES: &[&str] = &[
    "usr/share/doc/sdi/copyright",
    "usr/share/doc/sdi/changelog.Debian.gz",
];

fn expected_sdi_files() -> Vec<String> {
    let mut files: Vec<String> = package::MAKE_INSTALL_FILES
        .iter()
        .map(|f| {
            if f.starts_with("usr/share/man/") {
                format!("{f}.gz")
            } else {
                f.to_string()
            }
        })
        .chain(DOC_FILES.iter().map(|f| f.to_string()))
        .collect();
    files.sort();
    files
}

/// True when `path` is an ELF file with a symbol table or debug sections.
fn unstripped(path: &Path) -> bool {
    let out = must(Command::new("readelf").args(["-S", "-W"]).arg(path));
    let text = String::from_utf8_lossy(&out.stdout);
    text.contains(".symtab") || text.contains(".debug_info") || text.contains(".debug_line")
}

#[test]
fn sdi_package_holds_what_make_install_installs() {
    let Some(debs) = debs() else { return };
    let deb = &debs.sdi;
    let entries = contents(deb);
    let mut files: Vec<String> = entries
        .iter()
        .filter(|e| !e.is_dir())
        .map(|e| e.path.clone())
        .collect();
    files.sort();
    assert_eq!(files, expected_sdi_files(), "files in {}", deb.display());
    // /etc/sdi: the directory sdid reads sdid.toml from; no conffile in it.
    assert!(entries.iter().any(|e| e.path == "etc/sdi" && e.is_dir()));
    for e in &entries {
        assert_eq!(e.owner, "root/root", "{e:?}");
        let want = if e.is_dir() || e.path.starts_with("usr/bin/") {
            "rwxr-xr-x"
        } else {
            "rw-r--r--"
        };
        assert_eq!(&e.mode[1..], want, "{e:?}");
    }

    // Control fields.
    assert_eq!(field(deb, "Package"), "sdi");
    assert_eq!(field(deb, "Version"), VERSION);
    assert_eq!(field(deb, "Architecture"), package::architecture());
    let depends = field(deb, "Depends");
    eprintln!("Depends: {depends}");
    assert!(depends.contains("libc6"), "dpkg-shlibdeps: {depends}");
    assert!(
        depends.contains("systemd | systemd-sysusers"),
        "postinst runs systemd-sysusers: {depends}"
    );
    assert!(!depends.contains("v4l2loopback"), "{depends}");
    let recommends = field(deb, "Recommends");
    for r in ["v4l2loopback-dkms", "dbus"] {
        assert!(recommends.contains(r), "Recommends: {recommends}");
    }
    assert!(field(deb, "Suggests").contains("sdi-pipewire-camera"));
    assert!(!field(deb, "Description").is_empty());

    // The files themselves.
    let dir = scratch("contents");
    let root = dir.join("root");
    must(Command::new("dpkg-deb").arg("-x").arg(deb).arg(&root));
    for program in ["usr/bin/sdid", "usr/bin/sdictl"] {
        assert!(!unstripped(&root.join(program)), "{program} not stripped");
    }
    let man = must(Command::new("zcat").arg(root.join("usr/share/man/man1/sdictl.1.gz")));
    assert!(String::from_utf8_lossy(&man.stdout).contains(".TH sdictl 1"));
    // gzip -n: no name or time stamp in the header (reproducible).
    let gz = fs::read(root.join("usr/share/man/man1/sdictl.1.gz")).unwrap();
    assert_eq!(gz[3] & 0x08, 0, "gzip header carries a file name");
    assert_eq!(&gz[4..8], &[0, 0, 0, 0], "gzip header carries a time");
    let unit = fs::read_to_string(root.join("usr/lib/systemd/system/sdid.service")).unwrap();
    assert!(unit.contains("ExecStart=/usr/bin/sdid\n"), "{unit}");
    let copyright = fs::read_to_string(root.join("usr/share/doc/sdi/copyright")).unwrap();
    assert!(copyright
        .starts_with("Format: https://www.debian.org/doc/packaging-manuals/copyright-format/1.0/"));
    assert!(copyright.contains("License: MIT or Apache-2.0"));
    let changelog =
        must(Command::new("zcat").arg(root.join("usr/share/doc/sdi/changelog.Debian.gz")));
    assert!(String::from_utf8_lossy(&changelog.stdout).starts_with(&format!("sdi ({VERSION})")));

    // Maintainer scripts: the board IDs filled in from udev/board-ids.
    let control = dir.join("control");
    must(Command::new("dpkg-deb").arg("-e").arg(deb).arg(&control));
    let postinst = fs::read_to_string(control.join("postinst")).unwrap();
    assert!(!postinst.contains('@'), "unfilled placeholder:\n{postinst}");
    assert!(postinst.contains("BOARD_IDS=\"0451:9105 0451:9106\""));
    for script in ["postinst", "prerm", "postrm"] {
        must(Command::new("sh").arg("-n").arg(control.join(script)));
    }
    assert!(!control.join("conffiles").exists(), "no file under /etc");

    if let Some(camera) = &debs.camera {
        check_camera_package(camera);
    } else {
        eprintln!("no sdi-pipewire-camera package: the program was not built beside sdid");
    }
    fs::remove_dir_all(&dir).unwrap();
}

/// The PipeWire camera's package: its program in /usr/libexec/sdi,
/// WirePlumber's rule keeping the loopback nodes out of PipeWire, the
/// docs, shared-library dependencies and exactly this version of sdi.
fn check_camera_package(deb: &Path) {
    let mut files: Vec<String> = contents(deb)
        .into_iter()
        .filter(|e| !e.is_dir())
        .map(|e| format!("{} {} {}", e.mode, e.owner, e.path))
        .collect();
    files.sort();
    assert_eq!(
        files,
        [
            "-rw-r--r-- root/root usr/lib/systemd/user/sdi-pipewire-camera.service",
            "-rw-r--r-- root/root usr/share/doc/sdi-pipewire-camera/changelog.Debian.gz",
            "-rw-r--r-- root/root usr/share/doc/sdi-pipewire-camera/copyright",
            "-rw-r--r-- root/root usr/share/wireplumber/main.lua.d/51-sdi-v4l2.lua",
            "-rw-r--r-- root/root usr/share/wireplumber/wireplumber.conf.d/51-sdi-v4l2.conf",
            "-rwxr-xr-x root/root usr/libexec/sdi/sdi-pipewire-camera",
            "lrwxrwxrwx root/root usr/lib/systemd/user/pipewire.service.wants/sdi-pipewire-camera.service",
        ]
    );
    let depends = field(deb, "Depends");
    eprintln!("sdi-pipewire-camera Depends: {depends}");
    assert!(depends.contains("libc6"), "{depends}");
    assert!(depends.contains(&format!("sdi (= {VERSION})")), "{depends}");
    assert_eq!(field(deb, "Version"), VERSION);
}

/// `make deb-package` with a program at TARGETDIR/sdi-pipewire-camera
/// builds the second package (a stand-in program here; the real one is
/// checked above when it was built).
#[test]
fn camera_package_when_its_program_is_there() {
    if !package::have_tools("building the Debian packages", package::BUILD_TOOLS) {
        return;
    }
    let dir = scratch("camera");
    let release = dir.join("release");
    fs::create_dir_all(&release).unwrap();
    for name in ["sdid", "sdictl"] {
        let built = sdi_tests::dbus::bin(name);
        if fs::hard_link(&built, release.join(name)).is_err() {
            fs::copy(&built, release.join(name)).unwrap();
        }
    }
    fs::copy("/bin/true", release.join("sdi-pipewire-camera")).unwrap();
    let debs = package::build(&release, &dir.join("deb"));
    let camera = debs.camera.expect("no sdi-pipewire-camera package");
    check_camera_package(&camera);
    // And none without the program: a stale one is not left behind either.
    fs::remove_file(release.join("sdi-pipewire-camera")).unwrap();
    let debs = package::build(&release, &dir.join("deb"));
    assert!(debs.camera.is_none(), "{:?}", debs.camera);
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn lintian_reports_no_errors() {
    let Some(debs) = debs() else { return };
    if !package::have_tools("lintian on the packages", &[("lintian", "lintian")]) {
        return;
    }
    let files: Vec<&Path> = std::iter::once(debs.sdi.as_path())
        .chain(debs.camera.as_deref())
        .collect();
    assert_no_lintian_error(
        "this machine's lintian",
        &mut Command::new("lintian"),
        &files,
    );
}

/// Debian 13's lintian, from the Debian 13 guest's root (chrooted, in a
/// mount namespace of its own: the root is not changed), on the same
/// packages: one build serves both releases. A second or two here against a
/// minute inside the guest under TCG.
#[test]
fn debian13_lintian_reports_no_errors() {
    let Some(debs) = debs() else { return };
    let root = sdi_tests::vm::debian13_root_when_built();
    if !root.join("usr/bin/lintian").exists() {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_PACKAGING",
            format_args!(
                "Debian 13's lintian: no Debian 13 root at {} (run: sudo tests/vm/debian13-root.sh)",
                root.display()
            ),
        );
        return;
    }
    if !nix::unistd::geteuid().is_root() {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_PACKAGING",
            format_args!(
                "Debian 13's lintian: chroot into {} needs root",
                root.display()
            ),
        );
        return;
    }
    let names: Vec<String> = std::iter::once(&debs.sdi)
        .chain(debs.camera.as_ref())
        .map(|p| format!("/tmp/{}", p.file_name().unwrap().to_string_lossy()))
        .collect();
    let copies: Vec<&Path> = std::iter::once(debs.sdi.as_path())
        .chain(debs.camera.as_deref())
        .collect();
    let script = format!(
        "r=$1; shift; mount -t tmpfs sdi-lintian \"$r/tmp\" && mount -t proc proc \"$r/proc\" \
         && cp {} \"$r/tmp/\" && exec chroot \"$r\" lintian \"$@\"",
        copies
            .iter()
            .map(|p| format!("'{}'", p.display()))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let mut cmd = Command::new("unshare");
    cmd.args([
        "--mount",
        "--propagation",
        "private",
        "sh",
        "-c",
        &script,
        "sh",
    ])
    .arg(&root);
    let files: Vec<&Path> = names.iter().map(Path::new).collect();
    assert_no_lintian_error("Debian 13's lintian", &mut cmd, &files);
}

/// `lintian --fail-on error` run by `cmd` on `files`: no error.
fn assert_no_lintian_error(which: &str, cmd: &mut Command, files: &[&Path]) {
    let t0 = std::time::Instant::now();
    let version = String::from_utf8_lossy(
        &run(Command::new(cmd.get_program())
            .args(cmd.get_args())
            .arg("--version"))
        .stdout,
    )
    .trim()
    .to_owned();
    let out = run(cmd
        .args(["--fail-on", "error", "--display-info"])
        .args(files));
    let text = String::from_utf8_lossy(&out.stdout);
    let errors: Vec<&str> = text.lines().filter(|l| l.starts_with("E: ")).collect();
    eprintln!(
        "MEASURED: {which} ({version}): {} errors, {} other tags, {:.1} s",
        errors.len(),
        text.lines().count() - errors.len(),
        t0.elapsed().as_secs_f64()
    );
    assert!(errors.is_empty(), "{which} errors:\n{}", errors.join("\n"));
    assert!(out.status.success(), "{which} failed ({})", out.status);
}

/// dpkg on a scratch root.
struct Root {
    dir: PathBuf,
}

impl Root {
    fn new(dir: PathBuf) -> Self {
        let admin = dir.join("var/lib/dpkg");
        for sub in ["info", "updates", "triggers"] {
            fs::create_dir_all(admin.join(sub)).unwrap();
        }
        fs::write(admin.join("status"), "").unwrap();
        Self { dir }
    }

    /// `dpkg --root=DIR ARGS`: maintainer scripts run outside a chroot (the
    /// root has no shell) with DPKG_ROOT=DIR; the dependencies (libc6,
    /// systemd) are not installed in it.
    fn dpkg(&self, args: &[&str]) -> Output {
        let out = run(Command::new("dpkg")
            .arg(format!("--root={}", self.dir.display()))
            .args(["--force-script-chrootless", "--force-depends"])
            .args(args));
        assert!(
            out.status.success(),
            "dpkg {args:?} failed ({})",
            out.status
        );
        out
    }

    fn path(&self, rel: &str) -> PathBuf {
        self.dir.join(rel.trim_start_matches('/'))
    }

    /// Every file (not directory) under the root, but dpkg's own database.
    fn files(&self) -> Vec<String> {
        let mut out = Vec::new();
        let mut stack = vec![self.dir.clone()];
        while let Some(d) = stack.pop() {
            for e in fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                let rel = p.strip_prefix(&self.dir).unwrap().display().to_string();
                if rel == "var/lib/dpkg" {
                    continue;
                }
                if e.file_type().unwrap().is_dir() {
                    stack.push(p);
                } else {
                    out.push(rel);
                }
            }
        }
        out.sort();
        out
    }
}

#[test]
fn dpkg_installs_removes_and_purges_in_a_scratch_root() {
    let Some(debs) = debs() else { return };
    if !sdi_tests::process::is_root() {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_PACKAGING",
            format_args!("installing with dpkg --root needs root"),
        );
        return;
    }
    if !package::have_tools("the maintainer scripts", &[("systemd-sysusers", "systemd")]) {
        return;
    }
    let dir = scratch("root");
    let root = Root::new(dir.join("root"));
    let install = root.dpkg(&["--install", debs.sdi.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&install.stderr);
    assert!(!stderr.contains("sdi: purge"), "{stderr}");
    let listed = stdout_of_dpkg(&root, &["--listfiles", "sdi"]);
    let installed: Vec<&str> = listed.lines().filter(|p| !root.path(p).is_dir()).collect();
    let mut names: Vec<String> = installed
        .iter()
        .map(|p| p.trim_start_matches('/').to_owned())
        .collect();
    names.sort();
    assert_eq!(names, expected_sdi_files(), "dpkg -L sdi");
    for p in &installed {
        assert!(root.path(p).is_file(), "{p} not installed");
    }
    // postinst: the group, from the package's sysusers.d file.
    let group = fs::read_to_string(root.path("etc/group")).unwrap_or_default();
    assert!(
        group.lines().any(|l| l.starts_with("sdi:x:")),
        "no group sdi in the root's /etc/group:\n{group}"
    );
    // postinst recorded the unit's enablement links for purge.
    let state = root.path("var/lib/systemd/deb-systemd-helper-enabled/sdid.service.dsh-also");
    assert!(state.is_file(), "{} missing", state.display());

    // What the running service and the administrator add.
    fs::create_dir_all(root.path("var/lib/sdi")).unwrap();
    fs::write(root.path("var/lib/sdi/calibration.toml"), "# test\n").unwrap();
    fs::write(root.path("var/lib/sdi/run.sdirec"), b"SDIREC").unwrap();
    fs::write(root.path("etc/sdi/sdid.toml"), "mode = \"raw\"\n").unwrap();

    // remove: the package's files go, the state and the admin's file stay.
    let remove = root.dpkg(&["--remove", "sdi"]);
    for p in &installed {
        assert!(!root.path(p).exists(), "{p} still there after remove");
    }
    assert!(
        root.path("var/lib/sdi/run.sdirec").is_file(),
        "remove took the recordings"
    );
    assert!(root.path("var/lib/sdi/calibration.toml").is_file());
    assert!(!String::from_utf8_lossy(&remove.stderr).contains("sdi: purge"));

    // purge: the state directory too, said on stderr; the group stays
    // (Debian leaves system groups), so does the administrator's sdid.toml.
    let purge = root.dpkg(&["--purge", "sdi"]);
    let stderr = String::from_utf8_lossy(&purge.stderr);
    assert!(
        stderr.contains("sdi: purge: removing /var/lib/sdi (2 files"),
        "purge said:\n{stderr}"
    );
    assert!(
        !root.path("var/lib/sdi").exists(),
        "purge left /var/lib/sdi"
    );
    assert!(!state.exists(), "purge left {}", state.display());
    let left = root.files();
    // systemd-sysusers's files (and its lock), the administrator's config.
    let expected_left = [
        "etc/.pwd.lock",
        "etc/group",
        "etc/gshadow",
        "etc/sdi/sdid.toml",
    ];
    let unexpected: Vec<&String> = left
        .iter()
        .filter(|f| !expected_left.contains(&f.as_str()))
        .collect();
    assert!(unexpected.is_empty(), "purge left {unexpected:?}");
    for p in &installed {
        assert!(!root.path(p).exists(), "{p} still there after purge");
    }
    for gone in ["usr/share/doc/sdi", "usr/lib/systemd/system", "usr/bin"] {
        assert!(!root.path(gone).exists(), "{gone} left behind");
    }
    let status = stdout_of_dpkg(&root, &["--status", "sdi"]);
    assert!(!status.contains("Status: install"), "{status}");
    fs::remove_dir_all(&dir).unwrap();
}

/// stdout of a dpkg query on the root (may fail: unknown package).
fn stdout_of_dpkg(root: &Root, args: &[&str]) -> String {
    let out = run(Command::new("dpkg")
        .arg(format!("--root={}", root.dir.display()))
        .args(args));
    String::from_utf8_lossy(&out.stdout).into_owned()
}
