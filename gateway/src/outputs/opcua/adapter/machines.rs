//! The Machinery companion model (OPC 40001-1) and NE 107 device health (OPC
//! 10000-100) of the gateway and of each driveline and mill: which objects are items,
//! what identifies them, and their state and health from the results.
//!
//! State: the gateway running is Executing, starting or stopped NotExecuting; a
//! driveline or mill whose source is stale or lost is NotAvailable, one without a
//! bite or window yet NotExecuting, else Executing. Health: the gateway starting is
//! CHECK_FUNCTION, stopped FAILURE, running with a source not ok OFF_SPEC; a driveline
//! or mill whose source is stale or lost is FAILURE (its figures are withdrawn), one
//! with a latched alarm (or a driveline's gap warning) MAINTENANCE_REQUIRED, a
//! driveline's degraded bite, a tandem mill's slow-down request or a rod mill's
//! refused input OFF_SPEC, else NORMAL.

use millgate_config::{Identification, IdentificationField, IdentificationValue};

use crate::state::results::{
    DrivelineResults, GatewayState, Results, RodMillResults, TandemMillResults,
};

use super::super::model::{DeviceHealth, MachineSpec, MachineState, NameplateValue};

/// The items: the gateway (object 0, its nameplate `gateway`), then `mills` (the
/// objects of the drivelines, tandem mills and rod mills, in this order, with their
/// nameplates from the configuration).
pub(super) fn machines<'a>(
    gateway: &Identification,
    mills: impl IntoIterator<Item = (usize, &'a Identification)>,
) -> Vec<MachineSpec> {
    // The gateway is millgate unless the plant names the box it runs on; its
    // software revision is always millgate's version.
    let gateway_nameplate = gateway
        .clone()
        .or_default(IdentificationField::Manufacturer, "millgate project")
        .or_default(IdentificationField::Model, "millgate");
    let mut identification = nameplate(&gateway_nameplate);
    identification.push((
        "SoftwareRevision",
        NameplateValue::String(env!("CARGO_PKG_VERSION").into()),
    ));
    let gateway = MachineSpec {
        object: 0,
        identification,
    };
    let mills = mills
        .into_iter()
        .map(|(object, identification)| MachineSpec {
            object,
            identification: nameplate(identification),
        });
    std::iter::once(gateway).chain(mills).collect()
}

/// The `Identification` properties of a configured nameplate, each of DI's data
/// type: Manufacturer and Model LocalizedText, YearOfConstruction UInt16, the
/// others String.
fn nameplate(identification: &Identification) -> Vec<(&'static str, NameplateValue)> {
    identification
        .fields
        .iter()
        .map(|(field, value)| {
            let value = match (field, value) {
                (_, IdentificationValue::Year(year)) => NameplateValue::UInt16(*year),
                (
                    IdentificationField::Manufacturer | IdentificationField::Model,
                    IdentificationValue::Text(text),
                ) => NameplateValue::LocalizedText(text.clone()),
                (_, IdentificationValue::Text(text)) => NameplateValue::String(text.clone()),
            };
            (field.browse_name(), value)
        })
        .collect()
}

/// Each item's state and health in `results`, in the order of [`machines`], for
/// `(drivelines, tandem_mills, rod_mills)` of each kind.
pub(super) fn states(
    results: &Results,
    (drivelines, tandem_mills, rod_mills): (usize, usize, usize),
) -> Vec<(MachineState, DeviceHealth)> {
    let gateway = results.gateway();
    let gateway = match gateway.state {
        GatewayState::Starting => (MachineState::NotExecuting, DeviceHealth::CheckFunction),
        GatewayState::Stopped => (MachineState::NotExecuting, DeviceHealth::Failure),
        GatewayState::Running if gateway.sources_ok => {
            (MachineState::Executing, DeviceHealth::Normal)
        }
        GatewayState::Running => (MachineState::Executing, DeviceHealth::OffSpec),
    };
    let empty = DrivelineResults::default();
    let drivelines = (0..drivelines).map(|k| {
        let d = results.drivelines.get(k).unwrap_or(&empty);
        let health = if d.taf_alarm || d.gap_alarm || d.gap_warning {
            DeviceHealth::MaintenanceRequired
        } else if d.last_bite_degraded {
            DeviceHealth::OffSpec
        } else {
            DeviceHealth::Normal
        };
        mill(
            d.source_stale,
            d.bite_counter == 0 && d.last_bite_unix_ms.is_none(),
            health,
        )
    });
    let empty = TandemMillResults::default();
    let tandem_mills = (0..tandem_mills).map(|k| {
        let m = results.tandem_mills.get(k).unwrap_or(&empty);
        let health = if m.chatter_alarm {
            DeviceHealth::MaintenanceRequired
        } else if m.slow_down_request {
            DeviceHealth::OffSpec
        } else {
            DeviceHealth::Normal
        };
        mill(m.source_stale, m.evaluations == 0, health)
    });
    let empty = RodMillResults::default();
    let rod_mills = (0..rod_mills).map(|k| {
        let m = results.rod_mills.get(k).unwrap_or(&empty);
        let health = if m.input_refused {
            DeviceHealth::OffSpec
        } else {
            DeviceHealth::Normal
        };
        mill(m.source_stale, m.evaluations == 0, health)
    });
    std::iter::once(gateway)
        .chain(drivelines)
        .chain(tandem_mills)
        .chain(rod_mills)
        .collect()
}

/// A driveline's or mill's state and health: its source stale, no result yet, the
/// health its results give.
fn mill(stale: bool, waiting: bool, health: DeviceHealth) -> (MachineState, DeviceHealth) {
    if stale {
        (MachineState::NotAvailable, DeviceHealth::Failure)
    } else if waiting {
        (MachineState::NotExecuting, health)
    } else {
        (MachineState::Executing, health)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_and_health_follow_the_source_the_results_and_the_alarms() {
        let none = Identification::default();
        let items = machines(&none, [(2, &none)]);
        assert_eq!(items.len(), 2);
        assert!(
            items[1].identification.is_empty(),
            "a mill without a nameplate"
        );
        let browse: Vec<_> = items[0].identification.iter().map(|(b, _)| *b).collect();
        assert_eq!(browse, ["Manufacturer", "Model", "SoftwareRevision"]);
        let mut results = Results {
            drivelines: vec![DrivelineResults::default()],
            ..Results::default()
        };
        let driveline = |results: &Results| states(results, (1, 0, 0))[1];
        assert_eq!(
            states(&results, (1, 0, 0))[0],
            (MachineState::NotExecuting, DeviceHealth::CheckFunction),
            "the gateway starting"
        );
        assert_eq!(
            driveline(&results),
            (MachineState::NotExecuting, DeviceHealth::Normal),
            "no bite yet"
        );
        results.drivelines[0].bite_counter = 1;
        results.drivelines[0].last_bite_degraded = true;
        assert_eq!(
            driveline(&results),
            (MachineState::Executing, DeviceHealth::OffSpec)
        );
        results.drivelines[0].gap_warning = true;
        assert_eq!(
            driveline(&results),
            (MachineState::Executing, DeviceHealth::MaintenanceRequired)
        );
        results.drivelines[0].source_stale = true;
        assert_eq!(
            driveline(&results),
            (MachineState::NotAvailable, DeviceHealth::Failure)
        );
    }
}
