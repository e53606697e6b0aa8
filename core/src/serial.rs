//! Which camera serials may name files and labels: one alphabet for the
//! daemon's outputs (`sdid-view-SERIAL.y4m`, "SDI camera SERIAL") and the
//! PipeWire camera's socket, lock and nodes (`sdi-camera-SERIAL`).

/// A serial that can be part of a file name and a label: 1 to 64 of
/// `[A-Za-z0-9._-]`, not starting with a dot.
pub fn names_a_file(serial: &str) -> bool {
    (1..=64).contains(&serial.len()) && !serial.starts_with('.') && serial.bytes().all(plain_byte)
}

/// A byte a serial may hold to name a file: `[A-Za-z0-9._-]`.
pub fn plain_byte(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b"._-".contains(&b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_serial_names_a_file_only_when_plain() {
        for ok in ["A1B2", "sim-0", "x_y.z"] {
            assert!(names_a_file(ok), "{ok}");
        }
        for bad in ["", ".hidden", "a/b", "..", "a b", &"x".repeat(65)] {
            assert!(!names_a_file(bad), "{bad}");
        }
    }
}
