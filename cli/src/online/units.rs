//! Frequencies and durations as a person reads them: `12 MHz`, `1.5 kHz`,
//! `900 us`, `1.2 ms`.

/// `x` with at most `decimals` decimals, trailing zeros dropped.
fn trimmed(x: f64, decimals: usize) -> String {
    let s = format!("{x:.decimals$}");
    match s.contains('.') {
        true => s.trim_end_matches('0').trim_end_matches('.').to_owned(),
        false => s,
    }
}

/// A frequency in Hz, GHz, MHz or kHz, to the Hz it was set to (six
/// significant decimals of the unit at most).
pub fn hz(hz: f64) -> String {
    let (value, unit) = match hz.abs() {
        x if x >= 1e9 => (hz / 1e9, "GHz"),
        x if x >= 1e6 => (hz / 1e6, "MHz"),
        x if x >= 1e3 => (hz / 1e3, "kHz"),
        _ => (hz, "Hz"),
    };
    format!("{} {unit}", trimmed(value, 6))
}

/// A duration in us, ms or s with two significant decimals past 1 ms.
pub fn duration_us(us: f64) -> String {
    match us.abs() {
        x if x >= 1e6 => format!("{} s", trimmed(us / 1e6, 2)),
        x if x >= 1e3 => format!("{} ms", trimmed(us / 1e3, 1)),
        _ => format!("{us:.0} us"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn as_a_person_writes_them() {
        assert_eq!(hz(12e6), "12 MHz");
        assert_eq!(hz(1500.0), "1.5 kHz");
        assert_eq!(hz(20e6 / 3.0), "6.666667 MHz");
        assert_eq!(hz(60.0), "60 Hz");
        assert_eq!(duration_us(76.4), "76 us");
        assert_eq!(duration_us(900.0), "900 us");
        assert_eq!(duration_us(1234.0), "1.2 ms");
        assert_eq!(duration_us(2.5e6), "2.5 s");
    }
}
