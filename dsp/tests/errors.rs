//! Every dsp error reads as a sentence naming what is wrong (the field, where there is
//! one), and is a `core::error::Error`, so callers can wrap it as a source.

use millgate_dsp::bite::BiteSettingsError;
use millgate_dsp::chatter::ChatterError;
use millgate_dsp::fit::FitError;
use millgate_dsp::pencil::PencilError;
use millgate_dsp::stiffness::StiffnessError;
use millgate_dsp::transient::TransientError;

/// `error`'s message, checked to be more than its variant name and to mention `names`.
fn message(error: &dyn core::error::Error, names: &str) -> String {
    let text = error.to_string();
    let variant = format!("{error:?}");
    assert_ne!(text, variant, "Display is not the Debug name");
    assert!(text.len() > variant.len(), "{variant}: {text}");
    assert!(
        text.contains(names),
        "{variant}: `{text}` does not name `{names}`"
    );
    assert!(
        error.source().is_none(),
        "{variant}: dsp errors wrap nothing"
    );
    text
}

#[test]
fn setting_errors_name_their_field() {
    for (error, field) in [
        (BiteSettingsError::ThresholdKnm, "threshold_knm"),
        (BiteSettingsError::RearmKnm, "rearm_knm"),
        (BiteSettingsError::BaselineAlpha, "baseline_alpha"),
        (BiteSettingsError::SaturationLimits, "saturation"),
        (
            BiteSettingsError::PostTriggerSamples,
            "post_trigger_samples",
        ),
    ] {
        message(&error, field);
    }
    for (error, field) in [
        (TransientError::SampleRateHz, "sample_rate_hz"),
        (TransientError::PeriodLowpassHz, "period_lowpass_hz"),
        (TransientError::PeakLowpassHz, "peak_lowpass_hz"),
        (TransientError::SettledFraction, "settled_fraction"),
        (TransientError::MinStaticKnm, "min_static_knm"),
        (TransientError::ReferenceShiftS, "reference_shift_s"),
        (TransientError::WindowLength, "window"),
        (TransientError::TriggerIndex, "trigger_index"),
        (TransientError::NonFinite, "NaN"),
    ] {
        message(&error, field);
    }
    for (error, field) in [
        (FitError::SampleRateHz, "sample_rate_hz"),
        (FitError::MaxModeHz, "max_mode_hz"),
        (FitError::MaxIterations, "max_iterations"),
        (FitError::Tolerance, "tolerance"),
        (FitError::TooFewSamples, "samples"),
        (FitError::NonFinite, "NaN"),
        (FitError::Flat, "zero"),
        (FitError::ModesNotFound, "modes"),
        (FitError::Singular, "singular"),
        (FitError::Diverged, "non-finite"),
    ] {
        message(&error, field);
    }
    for (error, field) in [
        (PencilError::SampleRateHz, "sample_rate_hz"),
        (PencilError::Decimation, "decimation"),
        (PencilError::TooFewSamples, "24 samples"),
        (PencilError::NonFinite, "NaN"),
        (PencilError::Flat, "zero"),
        (PencilError::Decomposition, "eigendecompositions"),
    ] {
        message(&error, field);
    }
    for (error, field) in [
        (StiffnessError::Q1, "Q1"),
        (StiffnessError::Q2, "Q2"),
        (StiffnessError::Q3, "Q3"),
        (StiffnessError::C12, "C12"),
        (StiffnessError::C23, "C23"),
        (StiffnessError::Beta1, "beta1_hz"),
        (StiffnessError::Beta2, "beta2_hz"),
        (StiffnessError::Drawing, "drawing"),
    ] {
        message(&error, field);
    }
    for (error, field) in [
        (ChatterError::BandLowHz, "band_low_hz"),
        (ChatterError::BandHighHz, "band_high_hz"),
        (ChatterError::KMax, "k_max"),
        (ChatterError::FrequencyStepHz, "frequency_step_hz"),
        (ChatterError::StandCount, "2..=8"),
        (ChatterError::SpectrumLength, "spectra"),
        (ChatterError::SignalLength, "signals"),
        (ChatterError::NonFinite, "NaN"),
        (ChatterError::Overflow, "overflows"),
    ] {
        message(&error, field);
    }
}
