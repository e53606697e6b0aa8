use sdi_core::display::Colormap;
use sdi_core::mode::ModeId;
use sdi_core::sensor::capture_range::FRAME_RATE_HZ;
use sdi_core::sensor::SensorPreset;
use sdi_core::separation::LiveMethod;

use super::*;

fn parse(text: &str) -> Config {
    toml::from_str(text).unwrap_or_else(|e| panic!("{text}: {e}"))
}

fn validated(text: &str) -> Result<(Config, Vec<Adjustment>), Invalid> {
    let mut c = parse(text);
    c.validate().map(|a| (c, a))
}

fn invalid_key(text: &str) -> &'static str {
    match validated(text) {
        Err(e) => e.key,
        Ok(_) => panic!("{text}: accepted"),
    }
}

#[test]
fn parses_and_rejects_unknown_keys() {
    let c = parse("mode = \"depth-edge\"\n[output]\nsink = \"y4m\"\n");
    assert_eq!(c.mode, ModeId::DepthEdge);
    assert_eq!(c.output.sink, SinkKind::Y4m);
    let c = parse("[output]\nsink = \"pipewire\"\n");
    assert_eq!(c.output.sink, SinkKind::Pipewire);
    assert_eq!(c.backend, BackendKind::Auto);
    assert_eq!(c.board.on_unplug, OnUnplug::NoSignal);
    assert_eq!(c.lights.driver, LightDriver::None);
    assert_eq!(c.sensor, SensorSpec::Preset(SensorPreset::TiOpt8241));
    assert_eq!(parse(""), Config::default());
    let c = parse("scene = \"fan-pellets\"");
    assert_eq!(c.scene, Some(sdi_core::scene::SceneId::FanPellets));
    assert!(toml::from_str::<Config>("nope = 1").is_err());
}

#[test]
fn unknown_names_are_refused_when_parsed_naming_the_choices() {
    for (text, hint) in [
        ("backend = \"usb\"", "opt8241"),
        ("mode = \"nope\"", "depth-edge"),
        ("[output]\nsink = \"x11\"", "pipewire"),
        ("[display]\ncolormap = \"jet\"", "diverging"),
        ("[board]\non_unplug = \"restart\"", "no-signal"),
        ("[lights]\ndriver = \"laser\"", "scpi-tcp"),
        ("[separation]\nmethod = \"m1\"", "window"),
        (
            "scene = \"lab\"",
            "unknown scene 'lab': use flat-field, colour-chart",
        ),
        ("sensor = \"\"", "preset"),
    ] {
        let e = toml::from_str::<Config>(text).unwrap_err().to_string();
        assert!(e.contains(hint), "{text}: {e}");
    }
}

#[test]
fn colormap_accepts_grey_and_gray_everywhere() {
    for name in ["grey", "gray"] {
        let c = parse(&format!("[display]\ncolormap = \"{name}\"\n"));
        assert_eq!(c.display.colormap, Colormap::Grey);
        assert_eq!(name.parse::<Colormap>(), Ok(Colormap::Grey));
    }
    assert_eq!("diverging".parse::<Colormap>(), Ok(Colormap::Diverging));
    assert!("Grey".parse::<Colormap>().is_err());
    assert!("jet".parse::<Colormap>().is_err());
    // Written back under its one name.
    let text = toml::to_string(&parse("[display]\ncolormap = \"gray\"\n")).unwrap();
    assert!(text.contains("colormap = \"grey\""), "{text}");
    assert_eq!(Colormap::NAMES, &["diverging", "grey"]);
}

#[test]
fn sensor_is_a_preset_or_a_file() {
    assert_eq!(
        parse("sensor = \"pmd\"").sensor,
        SensorSpec::Preset(SensorPreset::PmdCamBoardNano)
    );
    assert_eq!(
        parse("sensor = \"/etc/sdi/s.toml\"").sensor,
        SensorSpec::File("/etc/sdi/s.toml".into())
    );
}

#[test]
fn separation_method() {
    let (c, _) = validated("").unwrap();
    assert!(matches!(
        c.separation.live_method(),
        LiveMethod::Bilateral(_)
    ));
    let (c, _) = validated("[separation]\nmethod = \"window\"\nwindow_frames = 50\n").unwrap();
    assert_eq!(
        c.separation.live_method(),
        LiveMethod::SlidingWindow { frames: 50 }
    );
    for (bad, key) in [
        (
            "method = \"window\"\nwindow_frames = 1",
            "separation.window_frames",
        ),
        (
            "method = \"window\"\nwindow_frames = 100000",
            "separation.window_frames",
        ),
        ("sigma_range_dn = -1.0", "separation.sigma_range_dn"),
        ("sigma_range_dn = nan", "separation.sigma_range_dn"),
        ("sigma_domain_px = nan", "separation.sigma_domain_px"),
        ("sigma_domain_px = 0.0", "separation.sigma_domain_px"),
        ("sigma_domain_px = inf", "separation.sigma_domain_px"),
    ] {
        assert_eq!(invalid_key(&format!("[separation]\n{bad}\n")), key, "{bad}");
    }
    // One set of bounds, core's: an infinite range sigma is no range weighting.
    assert!(validated("[separation]\nsigma_range_dn = inf\n").is_ok());
    // The window's parameters are not checked while M3 is selected, and back.
    assert!(validated("[separation]\nwindow_frames = 0\n").is_ok());
    assert!(validated("[separation]\nmethod = \"window\"\nsigma_domain_px = -1.0\n").is_ok());
}

#[test]
fn capture_settings_share_the_one_range() {
    let lo = FRAME_RATE_HZ.min;
    let hi = FRAME_RATE_HZ.max;
    assert!(validated(&format!("frame_rate_hz = {hi:?}")).is_ok());
    assert!(validated(&format!("frame_rate_hz = {lo:?}")).is_ok());
    for bad in [hi + 1.0, lo / 2.0, 0.0, -5.0, 10_000.0] {
        assert_eq!(
            invalid_key(&format!("frame_rate_hz = {bad:?}")),
            "frame_rate_hz",
            "{bad}"
        );
    }
    assert_eq!(invalid_key("frame_rate_hz = nan"), "frame_rate_hz");
    assert_eq!(invalid_key("exposure_us = 0.5"), "exposure_us");
    assert_eq!(invalid_key("exposure_us = 1e7"), "exposure_us");
    assert_eq!(invalid_key("modulation_hz = 10.0"), "modulation_hz");
    assert_eq!(invalid_key("modulation_hz = 1e9"), "modulation_hz");
    assert!(validated("exposure_us = 2000.0\nframe_rate_hz = 30.0\nmodulation_hz = 12e6").is_ok());
    // Longer than the frame period.
    let e = validated("exposure_us = 40000.0\nframe_rate_hz = 30.0").unwrap_err();
    assert_eq!(e.key, "exposure_us");
    assert!(e.to_string().contains("frame period"), "{e}");
}

#[test]
fn combinations_are_refused_naming_the_key() {
    assert_eq!(invalid_key("backend = \"replay\""), "replay.path");
    assert!(validated("backend = \"replay\"\n[replay]\npath = \"/var/lib/sdi/r.sdirec\"").is_ok());
    assert_eq!(
        invalid_key("[lights]\ndriver = \"scpi-tcp\""),
        "lights.address"
    );
    assert_eq!(
        invalid_key("[lights]\ndriver = \"usbtmc\"\ndevice = \"\""),
        "lights.device"
    );
    assert_eq!(
        invalid_key("[lights]\ndriver = \"gpio\"\ngpio_chip = \"\""),
        "lights.gpio_chip"
    );
    assert_eq!(
        invalid_key("[lights]\ndriver = \"gpio\"\nls1_line = 3\nls2_line = 3"),
        "lights.ls2_line"
    );
    assert!(validated("[lights]\ndriver = \"usbtmc\"").is_ok());
    assert!(validated("[lights]\ndriver = \"gpio\"").is_ok());
    assert_eq!(
        invalid_key("[display]\nrange_max_abs_dn = -1.0"),
        "display.range_max_abs_dn"
    );
    assert_eq!(
        invalid_key("[display]\nrange_max_abs_dn = nan"),
        "display.range_max_abs_dn"
    );
}

#[test]
fn adjustments_are_made_and_reported() {
    let (c, a) = validated("").unwrap();
    assert!(a.is_empty());
    assert_eq!(c, Config::default());
    let (c, a) = validated("[lights]\ndriver = \"scpi-tcp\"\naddress = \"192.0.2.10\"").unwrap();
    assert_eq!(c.lights.address, "192.0.2.10:5025");
    assert_eq!(a.len(), 1);
    assert_eq!(a[0].key, "lights.address");
    assert_eq!(
        a[0].to_string(),
        "lights.address = 192.0.2.10 adjusted to 192.0.2.10:5025: no port given: the SCPI port"
    );
    let (c, a) =
        validated("[lights]\ndriver = \"scpi-tcp\"\naddress = \"127.0.0.1:5025\"").unwrap();
    assert_eq!(c.lights.address, "127.0.0.1:5025");
    assert!(a.is_empty());
    let (c, a) = validated("[display]\nrange_max_abs_dn = 1e9").unwrap();
    assert_eq!(c.display.range_max_abs_dn, sdi_core::display::MAX_RANGE_DN);
    assert_eq!(a[0].key, "display.range_max_abs_dn");
    // Validating again changes nothing more.
    let mut again = c.clone();
    assert_eq!(again.validate(), Ok(vec![]));
    assert_eq!(again, c);
}

#[test]
fn board_and_lights_sections() {
    let c = parse(
        "backend = \"opt8241\"\n[board]\nserial = \"EMU0001\"\non_unplug = \"exit\"\nroi = [0, 0, 64, 48]\n[lights]\ndriver = \"scpi-tcp\"\naddress = \"127.0.0.1:5025\"\n",
    );
    assert_eq!(c.backend, BackendKind::Opt8241);
    assert_eq!(c.board.serial.as_deref(), Some("EMU0001"));
    assert_eq!(c.board.on_unplug, OnUnplug::Exit);
    assert_eq!(c.board.roi, Some([0, 0, 64, 48]));
    assert_eq!(c.lights.driver, LightDriver::ScpiTcp);
    assert_eq!(c.lights.address, "127.0.0.1:5025");
    assert!(toml::from_str::<Config>("[board]\nunplug = 1").is_err());
}

#[test]
fn load_reads_validates_and_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sdid.toml");
    std::fs::write(
        &path,
        "frame_rate_hz = 30.0\n[display]\ncolormap = \"gray\"\n",
    )
    .unwrap();
    let (c, a) = Config::load(Some(&path)).unwrap();
    assert_eq!(c.frame_rate_hz, Some(30.0));
    assert_eq!(c.display.colormap, Colormap::Grey);
    assert!(a.is_empty());
    std::fs::write(&path, "frame_rate_hz = 1000.0\n").unwrap();
    match Config::load(Some(&path)) {
        Err(ConfigError::Invalid { path: p, source }) => {
            assert_eq!(p, path);
            assert_eq!(source.key, "frame_rate_hz");
        }
        other => panic!("{other:?}"),
    }
    // read() leaves validation to the caller (command-line overrides first).
    let (c, read) = Config::read(Some(&path)).unwrap();
    assert_eq!((c.frame_rate_hz, read), (Some(1000.0), Some(path.clone())));
    assert!(matches!(
        Config::load(Some(&dir.path().join("absent.toml"))),
        Err(ConfigError::Read { .. })
    ));
}

/// Every ```toml block in docs/ is an sdid.toml example: each still loads.
#[test]
fn the_examples_in_docs_load() {
    let docs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs");
    let mut seen = 0;
    for entry in std::fs::read_dir(&docs).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "md") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let mut rest = text.as_str();
        while let Some(start) = rest.find("```toml\n") {
            let body = &rest[start + 8..];
            let end = body.find("```").unwrap();
            let mut c: Config = toml::from_str(&body[..end])
                .unwrap_or_else(|e| panic!("{}: {e}\n{}", path.display(), &body[..end]));
            c.validate()
                .unwrap_or_else(|e| panic!("{}: {e}\n{}", path.display(), &body[..end]));
            seen += 1;
            rest = &body[end..];
        }
    }
    assert!(seen >= 3, "{seen} examples");
}

#[test]
fn clap_parsers_use_the_same_names_and_ranges() {
    use clap::Parser;
    #[derive(Parser, Debug)]
    struct Args {
        #[arg(long, value_parser = cli::choice::<Colormap>())]
        colormap: Option<Colormap>,
        #[arg(long, value_parser = cli::choice::<BackendKind>())]
        backend: Option<BackendKind>,
        #[arg(long, value_parser = cli::in_range(FRAME_RATE_HZ))]
        frame_rate_hz: Option<f64>,
    }
    let a = Args::try_parse_from(["x", "--colormap", "gray", "--backend", "sim"]).unwrap();
    assert_eq!(a.colormap, Some(Colormap::Grey));
    assert_eq!(a.backend, Some(BackendKind::Sim));
    let a = Args::try_parse_from(["x", "--colormap", "grey", "--frame-rate-hz", "240"]).unwrap();
    assert_eq!(
        (a.colormap, a.frame_rate_hz),
        (Some(Colormap::Grey), Some(240.0))
    );
    for bad in [
        &["x", "--colormap", "jet"][..],
        &["x", "--backend", "usb"],
        &["x", "--frame-rate-hz", "241"],
        &["x", "--frame-rate-hz", "0.05"],
        &["x", "--frame-rate-hz", "fast"],
    ] {
        assert!(Args::try_parse_from(bad).is_err(), "{bad:?}");
    }
}

#[test]
fn recording_bounds_are_validated() {
    let (c, a) = validated("[recording]\nmax_bytes = 600000\nmin_free_bytes = 0").unwrap();
    assert_eq!(c.recording.max_bytes, Some(600_000));
    assert!(a.is_empty());
    assert_eq!(
        invalid_key("[recording]\nmax_bytes = 0"),
        "recording.max_bytes"
    );
    let (c, a) = validated("[recording]\nmax_bytes = 1000").unwrap();
    assert_eq!(
        c.recording.max_bytes,
        Some(crate::validate::MIN_RECORDING_BYTES)
    );
    assert_eq!(a[0].key, "recording.max_bytes");
    assert_eq!(
        invalid_key("[recording]\nmin_free_bytes = 9223372036854775807"),
        "recording.min_free_bytes"
    );
    // Negative numbers are refused when parsed.
    assert!(toml::from_str::<Config>("[recording]\nmax_bytes = -1").is_err());
}

/// Values in errors read as a person writes them (not 300 digits).
#[test]
fn out_of_range_values_are_printed_as_written() {
    let check = crate::cli::in_range(sdi_core::sensor::capture_range::EXPOSURE_US);
    let e = check("1e-300").unwrap_err();
    assert_eq!(
        e,
        "exposure_us = 1e-300 us is out of range: allowed [1, 1000000] us"
    );
    let e = check("-1e300").unwrap_err();
    assert!(e.starts_with("exposure_us = -1e300 us"), "{e}");
}

#[test]
fn camera_sections_lay_over_the_file_for_their_camera_alone() {
    let text = "backend = \"sim\"\ncameras = 2\nmode = \"raw\"\nframe_rate_hz = 30\n\
                [camera.\"sim-1\"]\nmode = \"depth-edge\"\nexposure_us = 1000\ncolormap = \"grey\"\n";
    let (c, _) = validated(text).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.sim_serials(), ["sim-0", "sim-1"]);
    let first = c.for_camera("sim-0");
    assert_eq!((first.mode, first.exposure_us), (ModeId::Raw, None));
    let second = c.for_camera("sim-1");
    assert_eq!(second.mode, ModeId::DepthEdge);
    assert_eq!(second.exposure_us, Some(1000.0));
    assert_eq!(second.frame_rate_hz, Some(30.0));
    assert_eq!(second.display.colormap, Colormap::Grey);
    assert!(second.camera.is_empty());
}

#[test]
fn camera_sections_and_counts_are_checked() {
    // A section's own value, against the file's frame rate.
    let e = validated("frame_rate_hz = 100\n[camera.\"sim-0\"]\nexposure_us = 20000\n")
        .err()
        .unwrap_or_else(|| panic!("accepted"));
    assert_eq!(e.key, "camera");
    assert!(e.reason.contains("[camera.\"sim-0\"] exposure_us"), "{e}");
    assert!(toml::from_str::<Config>("[camera.x]\nnope = 1").is_err());
    assert_eq!(invalid_key("backend = \"sim\"\ncameras = 0"), "cameras");
    assert_eq!(invalid_key("backend = \"sim\"\ncameras = 9"), "cameras");
    assert_eq!(invalid_key("cameras = 2"), "cameras");
    assert_eq!(
        invalid_key("backend = \"sim\"\ncameras = 2\n[output]\ny4m_path = \"-\""),
        "output.y4m_path"
    );
    // Each camera has its own PipeWire camera, named by its serial.
    validated("backend = \"sim\"\ncameras = 2\n[output]\nsink = \"pipewire\"")
        .unwrap_or_else(|e| panic!("{e}"));
    // An adjusted value in a section says which.
    let (_, adjusted) = validated("[camera.\"sim-0\"]\nrange_max_abs_dn = 1e12\n")
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        adjusted.iter().any(|a| a.given.contains("sim-0")),
        "{adjusted:?}"
    );
}
