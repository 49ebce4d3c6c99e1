//! Tolerance comparisons for tests of numerical code, shared by the workspace's tests
//! (idsp's `testing` module does the same): `actual` is close to `expected` when
//! `|actual - expected| <= atol + rtol * |expected|`, numpy's `isclose` rule. NaN, and
//! unlike numpy an infinity, is close to nothing.
//!
//! ```
//! use millgate_dsp::testing::{allclose, isclose, relative_error};
//! assert!(isclose(1.0 + 1e-12, 1.0, 1e-9, 0.0));
//! assert!(!isclose(f64::NAN, f64::NAN, 1.0, 1.0));
//! assert!(allclose(&[0.0, 16.66], &[0.004, 16.661], 0.0, 0.01));
//! assert!((relative_error(101.0, 100.0) - 0.01).abs() < 1e-12);
//! ```

/// Whether `actual` is within `atol + rtol * |expected|` of `expected`; `rtol` and
/// `atol` >= 0. False when either value is NaN.
pub fn isclose(actual: f64, expected: f64, rtol: f64, atol: f64) -> bool {
    libm::fabs(actual - expected) <= atol + rtol * libm::fabs(expected)
}

/// Whether `actual` and `expected` have the same length and each pair is [`isclose`].
pub fn allclose(actual: &[f64], expected: &[f64], rtol: f64, atol: f64) -> bool {
    actual.len() == expected.len()
        && actual
            .iter()
            .zip(expected)
            .all(|(&a, &e)| isclose(a, e, rtol, atol))
}

/// Panics, naming `what` and both values, unless `actual` [`isclose`] to `expected`.
#[track_caller]
pub fn assert_isclose(actual: f64, expected: f64, rtol: f64, atol: f64, what: &str) {
    assert!(
        isclose(actual, expected, rtol, atol),
        "{what}: {actual} is not within {atol} + {rtol} x |{expected}| of {expected}"
    );
}

/// Panics, showing both slices, unless they are [`allclose`].
#[track_caller]
pub fn assert_allclose(actual: &[f64], expected: &[f64], rtol: f64, atol: f64) {
    assert!(
        allclose(actual, expected, rtol, atol),
        "{actual:?} is not within {atol} + {rtol} x |expected| of {expected:?}"
    );
}

/// The relative error `|estimate / truth - 1|` (infinite or NaN for a `truth` of 0).
pub fn relative_error(estimate: f64, truth: f64) -> f64 {
    libm::fabs(estimate / truth - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerances_are_absolute_plus_relative() {
        assert!(isclose(100.5, 100.0, 0.01, 0.0));
        assert!(!isclose(101.5, 100.0, 0.01, 0.0));
        assert!(isclose(0.5, 0.0, 0.0, 0.5));
        assert!(!isclose(0.5, 0.0, 0.5, 0.0), "relative to 0 is exact");
        assert!(!isclose(f64::INFINITY, f64::INFINITY, 0.0, 0.0));
        assert!(!allclose(&[1.0], &[1.0, 2.0], 1.0, 1.0), "lengths differ");
        assert!(allclose(&[], &[], 0.0, 0.0));
    }

    #[test]
    #[should_panic(expected = "gain: 2 is not within 0.1 + 0 x |1| of 1")]
    fn assert_isclose_names_what_and_both_values() {
        assert_isclose(2.0, 1.0, 0.0, 0.1, "gain");
    }
}
