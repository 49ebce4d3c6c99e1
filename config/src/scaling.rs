//! Counts to engineering values: `count * scale + offset`, computed so that a decimal
//! scale and offset give the decimal the device meant.
//!
//! A DAQ sending 57 counts at a scale of 0.01 means 0.57; `57.0 * 0.01` is
//! `0.5700000000000001` in `f64` (0.01 has no exact binary value), and every output
//! that prints the value (capture CSVs, JSON) shows the extra digits. When the scale
//! and the offset are decimals (`m / 10^k`, as written in a configuration or a DBC),
//! [`Scaling::apply`] computes `(count * m + offset units) / 10^k` instead: the
//! numerator is an exact integer and `10^k` an exact power of ten, so the one
//! division is correctly rounded and gives the `f64` nearest the decimal meant, whose
//! shortest round-trip text is that decimal. Other scales, non-integer counts (float
//! registers) and numerators beyond 2^53 take `count * scale + offset` as before; the
//! two differ by at most one unit in the last place.
//!
//! Every decoding of counts goes through here: Modbus blocks and values, CAN signals
//! (the DBC's factor and offset), the captures' counts and the saturation limits.

/// Largest power of ten tried for a decimal scale or offset (`10^15`: 15 decimals).
const MAX_DECIMALS: i32 = 15;
/// Largest exponent of a composed divisor (`10^22` is the largest exact `f64` power of
/// ten).
const MAX_EXPONENT: i32 = 22;
/// Integers up to this are exact in `f64`.
const EXACT_INTEGER: f64 = 9_007_199_254_740_992.0; // 2^53

/// A linear decoding of counts: `count * scale + offset`.
///
/// ```
/// use millgate_config::Scaling;
/// let scaling = Scaling::new(0.01, 0.0);
/// assert_eq!(scaling.apply(57.0).to_string(), "0.57");
/// assert_eq!(57.0 * 0.01, 0.5700000000000001);
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scaling {
    /// The factor, as configured.
    pub scale: f64,
    /// The offset, as configured.
    pub offset: f64,
    /// Scale and offset as integers over one power of ten, when both are decimals.
    decimal: Option<Decimal>,
}

/// `scale = scale_units / 10^exponent`, `offset = offset_units / 10^exponent`, with
/// integer units.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Decimal {
    scale_units: f64,
    offset_units: f64,
    /// `10^exponent`.
    divisor: f64,
}

impl Scaling {
    /// `count * scale + offset`.
    pub fn new(scale: f64, offset: f64) -> Self {
        let decimal = decimal_digits(scale).zip(decimal_digits(offset)).and_then(
            |((scale_units, k_scale), (offset_units, k_offset))| {
                let exponent = k_scale.max(k_offset);
                let widen = |units: f64, k: i32| units * 10f64.powi(exponent - k);
                let (scale_units, offset_units) =
                    (widen(scale_units, k_scale), widen(offset_units, k_offset));
                (exponent <= MAX_EXPONENT
                    && scale_units.abs() < EXACT_INTEGER
                    && offset_units.abs() < EXACT_INTEGER)
                    .then(|| Decimal {
                        scale_units,
                        offset_units,
                        divisor: 10f64.powi(exponent),
                    })
            },
        );
        Self {
            scale,
            offset,
            decimal,
        }
    }

    /// The engineering value of `count`.
    #[inline]
    pub fn apply(&self, count: f64) -> f64 {
        if let Some(d) = &self.decimal {
            if count.fract() == 0.0 {
                let scaled = count * d.scale_units;
                let numerator = scaled + d.offset_units;
                // Both exact below 2^53 (a product or sum beyond it rounds to >= 2^53).
                if scaled.abs() < EXACT_INTEGER && numerator.abs() < EXACT_INTEGER {
                    return numerator / d.divisor;
                }
            }
        }
        count * self.scale + self.offset
    }
}

/// A float32 register's value as the `f64` nearest its shortest decimal: `0.57_f32`
/// is `0.5699999928474426` widened as it is, `0.57` here (what the device meant,
/// and what its own tools show); the value stays the same `f32` (`as f32` gives it
/// back). NaN and the infinities stay as they are.
pub fn f32_decimal(value: f32) -> f64 {
    use std::io::Write as _;
    // f32's Display is its shortest round-trip decimal without an exponent: at most
    // 48 bytes (`-0.` and 45 digits for the smallest subnormal).
    let mut buffer = [0u8; 64];
    let left = {
        let mut cursor = &mut buffer[..];
        if write!(cursor, "{value}").is_err() {
            return f64::from(value);
        }
        cursor.len()
    };
    let written = buffer.len() - left;
    std::str::from_utf8(&buffer[..written])
        .ok()
        .and_then(|text| text.parse().ok())
        .unwrap_or(f64::from(value))
}

/// `value` as `(units, k)` with `value` the `f64` nearest `units / 10^k` and
/// `units` an integer below 2^53, for the smallest `k` in `0..=15`; `None` when no
/// such decimal exists (`1/3`, NaN).
fn decimal_digits(value: f64) -> Option<(f64, i32)> {
    if !value.is_finite() {
        return None;
    }
    (0..=MAX_DECIMALS).find_map(|k| {
        let power = 10f64.powi(k);
        let units = (value * power).round();
        (units.abs() < EXACT_INTEGER && units / power == value).then_some((units, k))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shortest round-trip text of `count` decoded with `scale` and `offset`.
    fn text(scale: f64, offset: f64, count: f64) -> String {
        Scaling::new(scale, offset).apply(count).to_string()
    }

    #[test]
    fn decimal_scales_give_the_decimal_meant() {
        assert_eq!(text(0.01, 0.0, 57.0), "0.57");
        assert_eq!(text(0.01, 0.0, 82.0), "0.82");
        assert_eq!(text(0.1, 0.0, 3.0), "0.3");
        assert_eq!(text(0.01, 0.1, 57.0), "0.67");
        assert_eq!(text(0.05, -40.0, -7.0), "-40.35");
        assert_eq!(text(2.5, 0.0, 3.0), "7.5");
        assert_eq!(text(1.0, 0.0, -32768.0), "-32768");
        // Every i16 count at the common scales: the text is the count's decimal.
        for count in i16::MIN..=i16::MAX {
            for (scale, k) in [(0.1, 1_u32), (0.01, 2), (0.001, 3)] {
                // The decimal from integers: sign, whole part, k digits.
                let power = 10i32.pow(k);
                let magnitude = i32::from(count).abs();
                let sign = if count < 0 { "-" } else { "" };
                let (whole, fraction) = (magnitude / power, magnitude % power);
                let digits = format!("{fraction:0width$}", width = k as usize);
                let digits = digits.trim_end_matches('0');
                let expected = match digits {
                    "" if whole == 0 => "0".to_owned(),
                    "" => format!("{sign}{whole}"),
                    _ => format!("{sign}{whole}.{digits}"),
                };
                let got = Scaling::new(scale, 0.0).apply(f64::from(count));
                assert_eq!(got.to_string(), expected, "{count} x {scale}");
                // Within one ulp of the plain product.
                let plain = f64::from(count) * scale;
                assert!(
                    (got - plain).abs() <= plain.abs() * f64::EPSILON,
                    "{count} x {scale}"
                );
            }
        }
    }

    #[test]
    fn float32_registers_give_their_shortest_decimal_and_stay_the_same_f32() {
        assert_eq!(f32_decimal(0.57).to_string(), "0.57");
        assert_eq!(f64::from(0.57_f32).to_string(), "0.5699999928474426");
        assert_eq!(f32_decimal(-1.5e-7), -1.5e-7);
        assert_eq!(f32_decimal(f32::MAX), 3.4028235e38);
        assert_eq!(
            f32_decimal(f32::MIN_POSITIVE * 1e-6) as f32,
            f32::MIN_POSITIVE * 1e-6
        );
        assert!(f32_decimal(f32::NAN).is_nan());
        assert_eq!(f32_decimal(f32::NEG_INFINITY), f64::NEG_INFINITY);
        // Every 4099th bit pattern (about a million, all exponents): the same f32 back,
        // and the same shortest text.
        for bits in (0..=u32::MAX).step_by(4099) {
            let value = f32::from_bits(bits);
            if !value.is_finite() {
                continue;
            }
            let decimal = f32_decimal(value);
            assert_eq!((decimal as f32).to_bits(), bits, "{value}");
        }
    }

    #[test]
    fn other_scales_and_counts_take_the_plain_product() {
        let third = 1.0 / 3.0;
        assert_eq!(Scaling::new(third, 0.0).apply(7.0), 7.0 * third);
        assert_eq!(Scaling::new(0.01, 0.0).apply(57.5), 57.5 * 0.01);
        assert!(Scaling::new(0.01, 0.0).apply(f64::NAN).is_nan());
        assert_eq!(Scaling::new(0.01, 0.0).apply(1e17), 1e17 * 0.01);
        assert_eq!(Scaling::new(f64::NAN, 0.0).decimal, None);
    }
}
