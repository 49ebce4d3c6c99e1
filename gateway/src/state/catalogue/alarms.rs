//! The alarms and warnings: each is a flag of the catalogue
//! ([`Spec::alarm`](super::Spec::alarm)), whose key is the alarm's name in every
//! output and the history, and which says whether it latches
//! ([`Spec::latched`](super::Spec::latched)).

/// Which alarm or warning a record is about: the flag that carries it (see
/// [`Spec::alarm`](super::Spec::alarm)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlarmKind {
    /// A driveline's TAF at or above its warning threshold (follows each bite).
    TafWarning,
    /// A driveline's TAF reached its alarm threshold (latched).
    TafAlarm,
    /// A driveline's estimated opened gap at or above its warning threshold (follows
    /// each estimate; cleared by a wear reset).
    GapWarning,
    /// A driveline's gap diagnosis reached its alarm threshold: the pooled gap's 90%
    /// interval lay at or above it (latched).
    GapAlarm,
    /// A tandem mill's chatter warning (follows each window).
    ChatterWarning,
    /// A tandem mill's chatter alarm (latched).
    ChatterAlarm,
    /// A tandem mill's slow-down request to the PLC (follows its hysteresis).
    SlowDownRequest,
    /// A rod mill's span is unstable (follows the evaluations, with hysteresis).
    Unstable,
    /// A rod mill's span is near a tongue (follows the evaluations, with hysteresis).
    NearTongue,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::state::catalogue::{DRIVELINE, ROD_MILL, ROD_SPAN, TANDEM_MILL};

    #[test]
    fn every_kind_is_one_flag_and_latching_is_said_in_its_description() {
        let kinds = [
            AlarmKind::TafWarning,
            AlarmKind::TafAlarm,
            AlarmKind::GapWarning,
            AlarmKind::GapAlarm,
            AlarmKind::ChatterWarning,
            AlarmKind::ChatterAlarm,
            AlarmKind::SlowDownRequest,
            AlarmKind::Unstable,
            AlarmKind::NearTongue,
        ];
        for kind in kinds {
            let carriers = DRIVELINE
                .iter()
                .map(|figure| &figure.spec)
                .chain(TANDEM_MILL.iter().map(|figure| &figure.spec))
                .chain(ROD_MILL.iter().map(|figure| &figure.spec))
                .chain(ROD_SPAN.iter().map(|figure| &figure.spec))
                .filter(|spec| spec.alarm == Some(kind))
                .count();
            assert_eq!(carriers, 1, "{kind:?}");
            assert_eq!(
                kind.latched(),
                kind.flag()
                    .1
                    .description
                    .contains("latched until acknowledged"),
                "{kind:?}"
            );
        }
        assert_eq!(AlarmKind::GapAlarm.name(), "gap_alarm");
        assert!(AlarmKind::ChatterAlarm.latched());
        assert!(!AlarmKind::TafWarning.latched());
    }
}
