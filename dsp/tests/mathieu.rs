//! Mathieu characteristic values, growth exponents and tongues against values computed
//! independently: Abramowitz and Stegun Table 20.1, and `mathieu/golden.py` (mpmath at
//! 40 digits for the characteristic values, cross-checked with scipy; scipy's DOP853 on
//! the damped equation over a full period for the exponents, cross-checked with mpmath's
//! Taylor integrator; brentq on those exponents for damped tongue edges).

use millgate_dsp::mathieu::{Mathieu, MathieuError, MAX_ORDER};

/// Rows of a golden CSV (comment lines start with `#`), each split at commas.
fn rows(text: &str) -> impl Iterator<Item = Vec<&str>> {
    text.lines()
        .filter(|line| !line.starts_with('#') && !line.is_empty())
        .map(|line| line.split(',').collect())
}

fn number(field: &str) -> f64 {
    field
        .parse()
        .unwrap_or_else(|_| panic!("not a number: {field}"))
}

#[test]
fn abramowitz_stegun_table_20_1() {
    let m = Mathieu::default();
    // q, a0, b1, a1, b2, a2 (8 decimals as printed).
    let table = [
        [
            1.0,
            -0.45513860,
            -0.11024882,
            1.85910807,
            3.91702477,
            4.37130098,
        ],
        [
            5.0,
            -5.80004602,
            -5.79008060,
            1.85818754,
            2.09946045,
            7.44910974,
        ],
    ];
    for row in table {
        let q = row[0];
        let got = [
            m.characteristic_a(0, q).unwrap(),
            m.characteristic_b(1, q).unwrap(),
            m.characteristic_a(1, q).unwrap(),
            m.characteristic_b(2, q).unwrap(),
            m.characteristic_a(2, q).unwrap(),
        ];
        for (value, expected) in got.iter().zip(&row[1..]) {
            assert!(
                (value - expected).abs() <= 5.1e-9,
                "q {q}: {value} vs A&S {expected}"
            );
        }
    }
}

#[test]
fn characteristic_values_match_mpmath_to_1e_10() {
    let m = Mathieu::default();
    let mut worst: f64 = 0.0;
    let mut count = 0;
    for row in rows(include_str!("mathieu/characteristic.csv")) {
        let order: u8 = row[1].parse().unwrap();
        let q = number(row[2]);
        let expected = number(row[3]);
        let value = match row[0] {
            "a" => m.characteristic_a(order, q),
            _ => m.characteristic_b(order, q),
        }
        .unwrap();
        let error = (value - expected).abs() / expected.abs().max(1.0);
        assert!(
            error <= 1e-10,
            "{}_{order}({q}) = {value}, mpmath {expected}",
            row[0]
        );
        worst = worst.max(error);
        count += 1;
    }
    // Every order 0..=10 (a) and 1..=10 (b) at 19 values of q.
    assert_eq!(count, 19 * 21);
    println!("worst relative error {worst:.1e} over {count} values");
}

#[test]
fn exponents_match_an_independent_integration() {
    let m = Mathieu::default();
    let mut worst: f64 = 0.0;
    let mut count = 0;
    for row in rows(include_str!("mathieu/floquet.csv")) {
        let [a, q, c, expected] = [0, 1, 2, 3].map(|i| number(row[i]));
        let value = m.exponent(a, q, c).unwrap();
        // Near a tongue edge mu = acosh(|Delta| / 2) / pi turns a trace error e into
        // sqrt(e); both sides integrate to ~1e-12, so allow 1e-6 there.
        let tolerance = 1e-8 * expected.abs().max(1.0) + if value + c < 1e-3 { 1e-6 } else { 0.0 };
        assert!(
            (value - expected).abs() <= tolerance,
            "a {a} q {q} c {c}: {value} vs {expected}"
        );
        worst = worst.max((value - expected).abs());
        count += 1;
    }
    assert_eq!(count, 18 * 11 * 3);
    println!("worst absolute error {worst:.1e} over {count} points");
}

#[test]
fn damped_tongue_edges_match_brentq_on_the_independent_exponent() {
    let m = Mathieu::default();
    for row in rows(include_str!("mathieu/damped_edges.csv")) {
        let order: u8 = row[0].parse().unwrap();
        let [q, c, lower, upper] = [1, 2, 3, 4].map(|i| number(row[i]));
        let (lo, hi) = m
            .damped_tongue(order, q, c)
            .unwrap()
            .expect("tongue exists");
        assert!(
            (lo - lower).abs() < 1e-8 && (hi - upper).abs() < 1e-8,
            "tongue {order} q {q} c {c}: ({lo}, {hi}) vs ({lower}, {upper})"
        );
    }
}

#[test]
fn damping_closes_narrow_tongues_and_keeps_wide_ones() {
    let m = Mathieu::default();
    // Principal tongue at q = 0.5: largest undamped exponent ~ q / 2 = 0.25.
    assert!(m.damped_tongue(1, 0.5, 0.2).unwrap().is_some());
    assert!(m.damped_tongue(1, 0.5, 0.3).unwrap().is_none());
    // Without damping the edges are the characteristic values.
    let (lo, hi) = m.damped_tongue(2, 1.0, 0.0).unwrap().unwrap();
    assert_eq!(lo, m.characteristic_b(2, 1.0).unwrap());
    assert_eq!(hi, m.characteristic_a(2, 1.0).unwrap());
}

/// The exponent one step of `1e-7` (relative) inside and outside an edge has the
/// right sign (> 0 unstable; stable is < 0 with damping, 0 without).
fn assert_edge(m: &Mathieu, edge: f64, q: f64, c: f64, unstable_above: bool) {
    let step = 1e-7 * edge.abs().max(1.0);
    let above = m.exponent(edge + step, q, c).unwrap();
    let below = m.exponent(edge - step, q, c).unwrap();
    if unstable_above {
        assert!(
            above > 0.0 && below <= 0.0,
            "edge {edge}: {below} .. {above}"
        );
    } else {
        assert!(
            above <= 0.0 && below > 0.0,
            "edge {edge}: {below} .. {above}"
        );
    }
}

#[test]
fn locate_agrees_with_the_exponent() {
    let m = Mathieu::default();
    let mut inside = 0;
    for c in [0.0, 0.02, 0.15] {
        for q in [0.1, 0.8, 2.0, -1.5, 6.0] {
            for k in 0..60 {
                let a = -3.0 + 0.61 * f64::from(k);
                let location = m.locate(a, q, c).unwrap();
                let exponent = m.exponent(a, q, c).unwrap();
                assert_eq!(
                    location.inside,
                    exponent > 0.0,
                    "a {a} q {q} c {c}: {location:?}, exponent {exponent}"
                );
                assert_eq!(location.inside, location.distance < 0.0);
                assert!(location.order <= MAX_ORDER);
                inside += usize::from(location.inside);
                // Edges closer than 1e-6, and tongues narrower than 1e-4 (whose exponent,
                // < 1e-5, a 1e-7 step cannot resolve), are not probed.
                let narrow = location.order > 0 && {
                    let n = location.order;
                    let width = (m.characteristic_a(n, q).unwrap()
                        - m.characteristic_b(n, q).unwrap())
                    .abs();
                    width < 1e-4
                };
                if location.distance.abs() < 1e-6 || narrow {
                    continue;
                }
                // The nearest edge is where the stability changes: one of a -+ |distance|.
                let span = location.distance.abs();
                let step = 1e-7 * (a.abs() + span).max(1.0);
                let beyond = |sign: f64| m.exponent(a + sign * (span + step), q, c).unwrap();
                let sign = if (beyond(1.0) > 0.0) != location.inside {
                    1.0
                } else {
                    -1.0
                };
                let edge = a + sign * span;
                let unstable_above = (sign > 0.0) != location.inside;
                assert_edge(&m, edge, q, c, unstable_above);
                // Nothing changes between the point and its nearest edge.
                for fraction in [0.25, 0.5, 0.75] {
                    let between = a + fraction * (edge - a);
                    let e = m.exponent(between, q, c).unwrap();
                    assert_eq!(e > 0.0, location.inside, "a {between} q {q} c {c}");
                }
            }
        }
    }
    assert!(
        inside > 50,
        "the grid crosses tongues ({inside} points inside)"
    );
}

#[test]
fn large_q_keeps_the_branch_by_index() {
    // At q = 100 a_0 and b_1 agree to 3e-15 (below one ulp of 180), far from 0 and 1;
    // a_1 is 39 above them. The index picks each one, whatever lies nearest n^2.
    let m = Mathieu::default();
    let a0 = m.characteristic_a(0, 100.0).unwrap();
    let b1 = m.characteristic_b(1, 100.0).unwrap();
    let a1 = m.characteristic_a(1, 100.0).unwrap();
    assert!((a0 + 180.253_249_152_251_4).abs() < 1e-10, "{a0}");
    assert!((b1 + 180.253_249_152_251_4).abs() < 1e-10, "{b1}");
    assert!((a1 + 141.280_056_808_620).abs() < 1e-10, "{a1}");
    let values: Vec<f64> = (0..=MAX_ORDER)
        .map(|n| m.characteristic_a(n, 100.0).unwrap())
        .collect();
    assert!(values.windows(2).all(|w| w[0] < w[1]), "{values:?}");
}

#[test]
fn inputs_out_of_range_are_refused() {
    let m = Mathieu::default();
    assert_eq!(m.characteristic_a(0, f64::INFINITY), Err(MathieuError::Q));
    assert_eq!(m.exponent(2.0e4, 1.0, 0.0), Err(MathieuError::A));
    assert_eq!(m.locate(1.0, 1.0, 11.0), Err(MathieuError::Damping));
    assert_eq!(m.damped_tongue(0, 1.0, 0.1), Err(MathieuError::Order));
    assert_eq!(
        MathieuError::A.to_string(),
        "Mathieu a (and a - c^2) must be finite with magnitude <= 10000"
    );
}
