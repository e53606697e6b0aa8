//! The Debian packages (`make deb`, `packaging/debian/mkdeb.sh`) for the
//! tests: built by `make deb-package` from the programs cargo built for the
//! tests (a release build inside a test would take minutes), or taken from
//! `SDI_DEB_DIR` (e.g. `target/debian` after `make deb`).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use crate::process::{must, repo_root, run, stdout_of};

/// Every file `make install` puts under DESTDIR for PREFIX=/usr.
pub const MAKE_INSTALL_FILES: &[&str] = &[
    "usr/bin/sdid",
    "usr/bin/sdictl",
    "usr/lib/systemd/system/sdid.service",
    "usr/lib/systemd/user/sdid.service",
    "usr/lib/udev/rules.d/70-sdi-board.rules",
    "usr/lib/udev/rules.d/70-sdi-loopback.rules",
    "usr/share/dbus-1/system.d/org.sdi.Daemon.conf",
    "usr/share/dbus-1/system-services/org.sdi.Daemon.service",
    "usr/lib/modprobe.d/sdi-v4l2loopback.conf",
    "usr/lib/modules-load.d/sdi-v4l2loopback.conf",
    "usr/lib/sysusers.d/sdi.conf",
    "usr/share/man/man1/sdictl.1",
    "usr/share/bash-completion/completions/sdictl",
    "usr/share/zsh/vendor-completions/_sdictl",
    "usr/share/fish/vendor_completions.d/sdictl.fish",
];

/// What `make install` adds (PREFIX=/usr) where the PipeWire camera
/// program was built: the `sdi-pipewire-camera` package's files.
pub const CAMERA_INSTALL_FILES: &[&str] = &[
    "usr/libexec/sdi/sdi-pipewire-camera",
    "usr/share/wireplumber/main.lua.d/51-sdi-v4l2.lua",
    "usr/share/wireplumber/wireplumber.conf.d/51-sdi-v4l2.conf",
    "usr/lib/systemd/user/sdi-pipewire-camera.service",
    "usr/lib/systemd/user/pipewire.service.wants/sdi-pipewire-camera.service",
];

/// The packages' version: the workspace's plus the Debian revision.
pub const VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), "-1");

/// The environment variable naming a directory of packages to test instead
/// of building them.
pub const DEB_DIR_VAR: &str = "SDI_DEB_DIR";

/// The built packages.
#[derive(Clone, Debug)]
pub struct Debs {
    pub sdi: PathBuf,
    /// Only when the PipeWire camera program was there to package.
    pub camera: Option<PathBuf>,
}

/// True when every program in `tools` (name, Debian package) is installed
/// ([`crate::skip::have_all`]); CI sets `SDI_REQUIRE_PACKAGING`.
pub fn have_tools(what: &str, tools: &[(&str, &str)]) -> bool {
    crate::skip::have_all(what, tools, "SDI_REQUIRE_PACKAGING")
}

/// What building the packages needs.
pub const BUILD_TOOLS: &[(&str, &str)] = &[
    ("dpkg-deb", "dpkg"),
    ("dpkg-shlibdeps", "dpkg-dev"),
    ("strip", "binutils"),
    ("make", "make"),
];

/// The packages of this test process: from `SDI_DEB_DIR`, or built once
/// from the test programs into `target/<profile>/sdi-tests-deb/<test>/`.
/// None (after the skip line) when the tools are missing.
pub fn debs() -> Option<&'static Debs> {
    static DEBS: OnceLock<Option<Debs>> = OnceLock::new();
    DEBS.get_or_init(|| {
        if let Some(dir) = std::env::var_os(DEB_DIR_VAR) {
            return Some(find(Path::new(&dir)));
        }
        if !have_tools("building the Debian packages", BUILD_TOOLS) {
            return None;
        }
        let bindir = crate::dbus::bin("sdid").parent().unwrap().to_owned();
        let test = std::env::current_exe().unwrap();
        let test = test.file_stem().unwrap().to_string_lossy();
        let test = test.split('-').next().unwrap_or("test");
        let out = bindir.parent().unwrap().join("sdi-tests-deb").join(test);
        Some(build(&bindir, &out))
    })
    .as_ref()
}

/// `make deb-package` of the programs in `targetdir` into `debdir`. The
/// tests' packages are compressed fast (gzip -1); `make deb` uses xz.
pub fn build(targetdir: &Path, debdir: &Path) -> Debs {
    let t0 = std::time::Instant::now();
    must(
        Command::new("make")
            .arg("-s")
            .arg("-C")
            .arg(repo_root())
            .arg("deb-package")
            .arg(format!("TARGETDIR={}", targetdir.display()))
            .arg(format!("DEBDIR={}", debdir.display()))
            .env("DEB_COMPRESS", "-Zgzip -z1"),
    );
    eprintln!(
        "make deb-package of {}: {:.1} s",
        targetdir.display(),
        t0.elapsed().as_secs_f64()
    );
    find(debdir)
}

/// The packages in `dir`, by their file names.
pub fn find(dir: &Path) -> Debs {
    let arch = architecture();
    let named = |package: &str| dir.join(format!("{package}_{VERSION}_{arch}.deb"));
    let sdi = named("sdi");
    assert!(
        sdi.is_file(),
        "no {} (make deb, or {DEB_DIR_VAR})",
        sdi.display()
    );
    let camera = Some(named("sdi-pipewire-camera")).filter(|p| p.is_file());
    Debs { sdi, camera }
}

/// `dpkg --print-architecture`.
pub fn architecture() -> String {
    stdout_of(&run(Command::new("dpkg").arg("--print-architecture")))
        .trim()
        .to_owned()
}

/// One entry of `dpkg-deb --contents`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    /// `-rwxr-xr-x`, `drwxr-xr-x`, `lrwxrwxrwx`, ...
    pub mode: String,
    /// `root/root`
    pub owner: String,
    /// Without the leading `./`; directories without a trailing `/`.
    pub path: String,
}

impl Entry {
    pub fn is_dir(&self) -> bool {
        self.mode.starts_with('d')
    }
}

/// The files and directories in `deb`.
pub fn contents(deb: &Path) -> Vec<Entry> {
    let out = stdout_of(
        &Command::new("dpkg-deb")
            .arg("--contents")
            .arg(deb)
            .output()
            .unwrap(),
    );
    out.lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            // mode owner size date time path [-> target]
            let path = f.get(5)?.trim_start_matches("./").trim_end_matches('/');
            (!path.is_empty()).then(|| Entry {
                mode: f[0].to_owned(),
                owner: f[1].to_owned(),
                path: path.to_owned(),
            })
        })
        .collect()
}

/// A field of `deb`'s control file.
pub fn field(deb: &Path, name: &str) -> String {
    stdout_of(
        &Command::new("dpkg-deb")
            .arg("--field")
            .arg(deb)
            .arg(name)
            .output()
            .unwrap(),
    )
    .trim()
    .to_owned()
}

/// `apt-get ARGS`, non-interactive, output echoed; asserts success and
/// returns stdout and stderr together (maintainer scripts write to either).
/// The guest runs the test in a chroot of the host's root, where udevadm
/// ignores requests (right for a real chroot); SYSTEMD_IGNORE_CHROOT tells
/// the maintainer scripts' udevadm that this one is the running system.
pub fn apt_get(args: &[&str]) -> String {
    let t0 = std::time::Instant::now();
    let out = run(Command::new("apt-get")
        .args(["-y", "-o", "Dpkg::Use-Pty=0"])
        .args(args)
        .env("DEBIAN_FRONTEND", "noninteractive")
        .env("SYSTEMD_IGNORE_CHROOT", "1"));
    eprintln!("apt-get {args:?}: {:.1} s", t0.elapsed().as_secs_f64());
    assert!(
        out.status.success(),
        "apt-get {args:?} failed ({})",
        out.status
    );
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The id of group `group`, if it exists.
pub fn gid_of(group: &str) -> Option<u32> {
    let out = run(Command::new("getent").args(["group", group]));
    String::from_utf8_lossy(&out.stdout)
        .split(':')
        .nth(2)
        .and_then(|g| g.trim().parse().ok())
}

/// The host side of a VM test that installs the packages: builds them
/// ([`debs`]), names them to the guest (`SDI_DEB`, and `SDI_CAMERA_DEB`
/// when the camera was built); every guest has a writable `/usr` (a
/// throw-away overlay, like /etc and /var) for dpkg. None, after the skip
/// line, when the packages cannot be built. Without the camera package
/// `camera_needed_by` (a test's name, or its part) fails under
/// `SDI_REQUIRE_VM` and is skipped otherwise.
pub fn export_for_vm(camera_needed_by: &str) -> Option<&'static Debs> {
    let debs = debs()?;
    std::env::set_var("SDI_DEB", &debs.sdi);
    match &debs.camera {
        Some(camera) => std::env::set_var("SDI_CAMERA_DEB", camera),
        None => {
            let why = "no sdi-pipewire-camera package: the camera program was not built \
                       (cargo build -p sdi-pipewire-camera, which needs libpipewire-0.3-dev \
                       libspa-0.2-dev clang libclang-dev)";
            crate::skip::unavailable("SDI_REQUIRE_VM", format_args!("{camera_needed_by}: {why}"));
        }
    }
    Some(debs)
}

/// Asserts the package's view node is there, as its modprobe.d options
/// make it: `/dev/video42`, "SDI camera".
pub fn assert_view_node() {
    let name = std::fs::read_to_string("/sys/class/video4linux/video42/name")
        .expect("no /dev/video42 from the package's modprobe.d options");
    assert_eq!(name.trim(), "SDI camera");
}

/// The emulated board's picture in [`configure_emulated_board`]: width,
/// height.
pub const EMULATED_BOARD_PX: (usize, usize) = (64, 48);

/// The administrator's `/etc/sdi/sdid.toml` for the emulated board with
/// `serial`: [`EMULATED_BOARD_PX`] at 15 Hz, small and slow enough for TCG.
pub fn configure_emulated_board(serial: &str) {
    let (w, h) = EMULATED_BOARD_PX;
    std::fs::write(
        "/etc/sdi/sdid.toml",
        format!(
            "frame_rate_hz = 15.0\nexposure_us = 2000.0\n\
             [board]\nserial = \"{serial}\"\nroi = [0, 0, {w}, {h}]\n"
        ),
    )
    .expect("write /etc/sdi/sdid.toml");
}
