//! Golden test on the paper's Table 2 (stiffness adjustment, domain notes 1.2).

use millgate_dsp::stiffness::{forward, inverse, Inertias, NaturalFrequencies, Stiffness};

const Q: Inertias = Inertias {
    q1_kgm2: 46.70e3,
    q2_kgm2: 11.85e3,
    q3_kgm2: 2.48e3,
};
const DRAWING: Stiffness = Stiffness {
    c12_nm_per_rad: 214.10e6,
    c23_nm_per_rad: 30.68e6,
};
const ADJUSTED: Stiffness = Stiffness {
    c12_nm_per_rad: 68.77e6,
    c23_nm_per_rad: 32.81e6,
};

#[test]
fn forward_reproduces_both_rows() {
    for (c, b1, b2) in [(DRAWING, 16.66, 25.98), (ADJUSTED, 12.03, 21.09)] {
        let beta = forward(&Q, &c).unwrap();
        println!("{c:?} -> {beta:?}");
        assert!((beta.beta1_hz - b1).abs() <= 0.01, "{beta:?}");
        assert!((beta.beta2_hz - b2).abs() <= 0.01, "{beta:?}");
    }
}

#[test]
fn inverse_from_printed_frequencies_finds_adjusted_row() {
    let beta = NaturalFrequencies {
        beta1_hz: 12.03,
        beta2_hz: 21.09,
    };
    let roots = inverse(&Q, &beta, Some(&DRAWING)).unwrap();
    println!("roots from (12.03, 21.09): {roots:?}");
    let hit = roots.iter().find(|c| {
        (c.c12_nm_per_rad / ADJUSTED.c12_nm_per_rad - 1.0).abs() < 0.005
            && (c.c23_nm_per_rad / ADJUSTED.c23_nm_per_rad - 1.0).abs() < 0.005
    });
    assert!(hit.is_some(), "{roots:?}");
    // Every root reproduces the measured frequencies.
    for root in &roots {
        let back = forward(&Q, root).unwrap();
        assert!((back.beta1_hz - 12.03).abs() < 1e-9 && (back.beta2_hz - 21.09).abs() < 1e-9);
    }
}
