//! Acceptance: the simulated transient of the Table 2 adjusted model (no backlash),
//! analysed by dsp's eq. (1) fit, gives frequencies within 1% of the modal ones.

use millgate_dsp::fit::{fit_eq1, FitOptions};
use millgate_sim::chain::simulate;
use millgate_sim::modal;
use millgate_sim::model::Model;

#[test]
fn eq1_fit_of_the_simulated_transient_recovers_the_modal_frequencies() -> anyhow::Result<()> {
    let model = Model::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/models/table2-adjusted.toml"
    ))?;
    let modes = modal::modes(&model)?;
    let transient = simulate(&model)?;
    // Eq. (1) starts at the bite: fit from the load onset on.
    let onset = (model.load.onset * model.measurement.sample_rate).ceil() as usize;
    let fit = fit_eq1(
        &transient.torque_knm[onset..],
        &FitOptions::new(model.measurement.sample_rate),
    )
    .map_err(|error| anyhow::anyhow!("fit failed: {error:?}"))?;
    println!(
        "eq. (1) fit: {:.3} Hz, {:.3} Hz; modal: {:.3} Hz, {:.3} Hz",
        fit.f1_hz, fit.f2_hz, modes.frequencies_hz[1], modes.frequencies_hz[2]
    );
    for (fitted, modal) in [
        (fit.f1_hz, modes.frequencies_hz[1]),
        (fit.f2_hz, modes.frequencies_hz[2]),
    ] {
        assert!(
            (fitted - modal).abs() < 0.01 * modal,
            "fitted {fitted:.3} Hz vs modal {modal:.3} Hz ({fit:?})"
        );
    }
    Ok(())
}
