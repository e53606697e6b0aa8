//! `.npy` against an independent implementation: numpy (Debian's python3)
//! reads the files sdi-core writes and writes files sdi-core reads.
//! numpy missing: skipped, or a failure with `SDI_REQUIRE_VM` set (CI).

use std::path::Path;
use std::process::Command;

use sdi_core::npy::{read_f32, write_f32, NpyError, NpyF32Writer};

const PYTHON: &str = "/usr/bin/python3";

/// Runs `script` with `args`; None (skip) when numpy cannot be imported here.
fn numpy(script: &str, args: &[&Path]) -> Option<String> {
    let probe = Command::new(PYTHON).args(["-c", "import numpy"]).output();
    if !probe.as_ref().is_ok_and(|o| o.status.success()) {
        sdi_tests::skip::unavailable(
            "SDI_REQUIRE_VM",
            format_args!("no numpy for {PYTHON} (apt-get install python3-numpy)"),
        );
        return None;
    }
    let out = Command::new(PYTHON)
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("run python3");
    assert!(
        out.status.success(),
        "python3 failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(String::from_utf8_lossy(&out.stdout).trim().to_owned())
}

fn hex(data: &[f32]) -> String {
    data.iter()
        .flat_map(|v| v.to_le_bytes())
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Values a reader might get wrong: signs, specials, subnormals, extremes.
fn awkward(n: usize) -> Vec<f32> {
    let special = [
        0.0,
        -0.0,
        1.5,
        -2.25e-3,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MIN_POSITIVE / 4.0,
        f32::MAX,
        f32::MIN,
        65535.0,
        -32768.0,
    ];
    (0..n)
        .map(|i| special[i % special.len()] + if i >= special.len() { i as f32 } else { 0.0 })
        .collect()
}

const DESCRIBE: &str = "import sys, numpy as np
a = np.load(sys.argv[1], allow_pickle=False)
print(a.dtype.str, a.shape, a.flags['C_CONTIGUOUS'], a.tobytes().hex())";

#[test]
fn numpy_reads_what_we_write() {
    let dir = tempfile::tempdir().unwrap();
    for shape in [
        vec![],
        vec![1],
        vec![7],
        vec![3, 5],
        vec![2, 3, 4],
        vec![0, 4],
    ] {
        let n: usize = shape.iter().product();
        let data = awkward(n);
        let path = dir.path().join("a.npy");
        write_f32(std::fs::File::create(&path).unwrap(), &shape, &data).unwrap();
        let Some(got) = numpy(DESCRIBE, &[&path]) else {
            return;
        };
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let tuple = match dims.len() {
            1 => format!("({},)", dims[0]),
            _ => format!("({})", dims.join(", ")),
        };
        let want = format!("<f4 {tuple} True {}", hex(&data));
        assert_eq!(got, want.trim_end(), "{shape:?}");
    }
    // The streaming writer, one frame at a time, as `sdictl sim` writes.
    let path = dir.path().join("stream.npy");
    let data = awkward(3 * 2 * 5);
    let mut w = NpyF32Writer::new(std::fs::File::create(&path).unwrap(), &[3, 2, 5]).unwrap();
    for frame in data.chunks(10) {
        w.write(frame).unwrap();
    }
    w.finish().unwrap();
    let got = numpy(DESCRIBE, &[&path]).unwrap();
    assert_eq!(got, format!("<f4 (3, 2, 5) True {}", hex(&data)));
}

#[test]
fn we_read_what_numpy_writes() {
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name);
    let (v1, v2, scalar, empty, big_endian, fortran, f8) = (
        p("v1.npy"),
        p("v2.npy"),
        p("scalar.npy"),
        p("empty.npy"),
        p("big_endian.npy"),
        p("fortran.npy"),
        p("f8.npy"),
    );
    let script = "import sys, numpy as np
a = (np.arange(24, dtype='<f4').reshape(2, 3, 4) - 7.5) * np.float32(0.3)
a[0, 0, 0] = np.nan; a[1, 2, 3] = -np.inf
np.save(sys.argv[1], a)
with open(sys.argv[2], 'wb') as f:
    np.lib.format.write_array(f, a, version=(2, 0))
np.save(sys.argv[3], np.float32(-1.25))
np.save(sys.argv[4], np.zeros((0, 3), dtype='<f4'))
np.save(sys.argv[5], a.astype('>f4'))
np.save(sys.argv[6], np.asfortranarray(a))
np.save(sys.argv[7], a.astype('<f8'))
print(a.tobytes().hex())";
    let Some(want) = numpy(
        script,
        &[&v1, &v2, &scalar, &empty, &big_endian, &fortran, &f8],
    ) else {
        return;
    };
    let read = |path: &Path| read_f32(std::fs::File::open(path).unwrap());
    for path in [&v1, &v2, &big_endian] {
        let (shape, data) = read(path).unwrap();
        assert_eq!(shape, [2, 3, 4], "{}", path.display());
        assert_eq!(hex(&data), want, "{}", path.display());
    }
    assert_eq!(read(&scalar).unwrap(), (vec![], vec![-1.25]));
    assert_eq!(read(&empty).unwrap(), (vec![0, 3], vec![]));
    // What we do not read is refused with a typed error, not misread.
    assert!(matches!(read(&fortran), Err(NpyError::FortranOrder)));
    assert!(matches!(read(&f8), Err(NpyError::UnsupportedDtype(_))));
}
