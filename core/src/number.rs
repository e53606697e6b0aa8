//! Numbers in messages as a person writes them: `1e-300`, not three hundred
//! digits; `12000000` and `0.5` as they are.

use std::fmt;

/// Displays an `f64` in plain decimal between 1e-4 and 1e9 (in magnitude),
/// else in scientific notation, both with the fewest digits that read back
/// to the same value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Number(pub f64);

impl fmt::Display for Number {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        let plain = x == 0.0 || !x.is_finite() || (1e-4..1e9).contains(&x.abs());
        match plain {
            true => write!(f, "{x}"),
            false => write!(f, "{x:e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Number;

    #[test]
    fn numbers_read_as_written() {
        for (x, s) in [
            (1e-300, "1e-300"),
            (-1e300, "-1e300"),
            (f64::MAX, "1.7976931348623157e308"),
            (f64::MIN_POSITIVE, "2.2250738585072014e-308"),
            (12e6, "12000000"),
            (0.5, "0.5"),
            (2000.0, "2000"),
            (0.0, "0"),
            (-0.0, "-0"),
            (1e-4, "0.0001"),
            (5e-5, "5e-5"),
            (1e9, "1e9"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
        ] {
            assert_eq!(Number(x).to_string(), s);
            if x.is_finite() {
                assert_eq!(s.parse::<f64>().unwrap(), x, "{s} reads back");
            }
        }
    }
}
