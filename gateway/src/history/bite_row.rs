//! A bite as read back from the history: the row's own columns (its id, run,
//! driveline and channel, the second period, the transient's quality, the wear
//! reference) and the catalogue's figures that name a bite column, set back into
//! [`DrivelineResults`] by the catalogue (`time` is `last_bite_time`).
//!
//! Exports (`millgate history bites`, the web API) list the columns in the order they
//! have always had, then the figures added to the catalogue since, in catalogue order.

use std::sync::OnceLock;

use serde::ser::{Serialize, SerializeMap, Serializer};

use super::figures::{bite_columns, from_sql};
use super::record::{Cell, Record, StoredCoil, ToCell};
use crate::state::catalogue::Value;
use crate::state::context::{Coil, MillState, ProcessContext};
use crate::state::results::DrivelineResults;
use crate::state::time::UtcTime;
use millgate_config::text::AsciiText;

/// A bite (table `bites`); torques kN*m, periods s, frequencies Hz, gaps mrad.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteRow {
    /// Row id.
    pub id: i64,
    /// The gateway run that recorded it.
    pub run_id: i64,
    /// Driveline name.
    pub driveline: String,
    /// Torque channel.
    pub channel: String,
    /// Second period, s.
    pub second_period_s: Option<f64>,
    /// `good`, `few_crossings`, `low_static`.
    pub quality: String,
    /// The linear reference's TAF.
    pub reference_taf: Option<f64>,
    /// Measured minus reference first-period shift, s.
    pub shift_over_linear_s: Option<f64>,
    /// The process context the bite was rolled in (schema v13; every value `None`
    /// without `drivelines[].context`, for an invalid context and before v13).
    pub context: ProcessContext,
    /// The catalogue's figures the row keeps: the bite's counter and time, what its
    /// window measured (also from a degraded window: `last_bite_degraded`), the wear
    /// index and trend and the gap estimate after it; every other figure at its
    /// default.
    pub figures: DrivelineResults,
}

/// The columns of the first exports, in their order: kept so, whatever the
/// catalogue's order, for the tools that read them by position.
const FIRST_ORDER: [&str; 25] = [
    "id",
    "run_id",
    "driveline",
    "time",
    "bite_counter",
    "channel",
    "static_torque_knm",
    "peak_torque_knm",
    "taf",
    "first_period_s",
    "second_period_s",
    "period_shift_s",
    "beta1_hz",
    "beta2_hz",
    "quality",
    "degraded",
    "wear_index",
    "wear_trend",
    "reference_taf",
    "shift_over_linear_s",
    "gap_mrad",
    "gap_low_mrad",
    "gap_high_mrad",
    "gap_coupling",
    "bites_pooled",
];

/// A column of a bite row.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Column {
    /// One of the row's own.
    Own(&'static str),
    /// A catalogue figure's (its index in the driveline table).
    Figure(usize),
}

/// A bite row's own columns (not figures of the catalogue), as written: its id
/// aside, what [`BiteRow`] reads back beside the figures (`rows.rs` writes them).
pub(super) const OWN_COLUMNS: [&str; 7] = [
    "run_id",
    "driveline",
    "channel",
    "second_period_s",
    "quality",
    "reference_taf",
    "shift_over_linear_s",
];

/// The bite's process context (schema v13), the row's own columns after the
/// figures in the exports.
pub(super) const CONTEXT_COLUMNS: [&str; 6] = [
    "speed_mpm",
    "coil",
    "product",
    "thickness_mm",
    "pass",
    "mill_state",
];

/// Whether `name` is one of the row's own columns (not a figure of the catalogue).
fn own(name: &str) -> bool {
    name == "id" || OWN_COLUMNS.contains(&name) || CONTEXT_COLUMNS.contains(&name)
}

/// Every column, in export order, with its name.
fn layout() -> &'static [(&'static str, Column)] {
    static LAYOUT: OnceLock<Vec<(&'static str, Column)>> = OnceLock::new();
    LAYOUT.get_or_init(|| {
        let figure = |name: &str| {
            bite_columns()
                .position(|(_, column)| column == name)
                .map(Column::Figure)
        };
        let mut layout: Vec<(&'static str, Column)> = FIRST_ORDER
            .iter()
            .map(|&name| {
                let column = match own(name) {
                    true => Column::Own(name),
                    false => figure(name).unwrap_or_else(|| {
                        panic!("bites.{name} is neither the row's nor a catalogue figure's")
                    }),
                };
                (name, column)
            })
            .collect();
        for (index, (_, name)) in bite_columns().enumerate() {
            if !FIRST_ORDER.contains(&name) {
                layout.push((name, Column::Figure(index)));
            }
        }
        layout.extend(CONTEXT_COLUMNS.map(|name| (name, Column::Own(name))));
        layout
    })
}

fn columns() -> &'static [&'static str] {
    static COLUMNS: OnceLock<Vec<&'static str>> = OnceLock::new();
    COLUMNS.get_or_init(|| layout().iter().map(|(name, _)| *name).collect())
}

/// A figure's value as an export cell: flags 0/1, times as text.
fn figure_cell(value: Option<Value>) -> Cell {
    match value {
        None => Cell::Null,
        Some(Value::Real(v)) => Cell::Real(v),
        Some(Value::Count(v)) | Some(Value::Index(v)) => {
            i64::try_from(v).map_or(Cell::Null, Cell::Integer)
        }
        Some(Value::Bool(v)) => Cell::Integer(i64::from(v)),
        Some(Value::Time(ms)) => Cell::Text(UtcTime::from_unix_ms(ms).to_string()),
    }
}

impl BiteRow {
    fn own(&self, name: &str) -> Cell {
        match name {
            "id" => self.id.to_cell(),
            "run_id" => self.run_id.to_cell(),
            "driveline" => self.driveline.to_cell(),
            "channel" => self.channel.to_cell(),
            "second_period_s" => self.second_period_s.to_cell(),
            "quality" => self.quality.to_cell(),
            "reference_taf" => self.reference_taf.to_cell(),
            "shift_over_linear_s" => self.shift_over_linear_s.to_cell(),
            "speed_mpm" => self.context.speed_mpm.to_cell(),
            "coil" => match self.context.coil {
                Some(Coil::Number(number)) => Cell::Integer(number.into()),
                Some(Coil::Text(text)) => Cell::Text(text.as_str().to_owned()),
                None => Cell::Null,
            },
            "product" => self.context.product.map(i64::from).to_cell(),
            "thickness_mm" => self.context.thickness_mm.to_cell(),
            "pass" => self.context.pass.map(i64::from).to_cell(),
            "mill_state" => self.context.state.map(|s| s.name().to_owned()).to_cell(),
            other => unreachable!("{other} is not one of the row's own columns"),
        }
    }

    fn figure(&self, index: usize) -> Option<Value> {
        bite_columns()
            .nth(index)
            .and_then(|(figure, _)| figure.value(&self.figures))
    }

    /// The bite's time as stored (UTC ISO-8601), empty if the row has none.
    pub fn time(&self) -> String {
        self.figures
            .last_bite_unix_ms
            .map(|ms| UtcTime::from_unix_ms(ms).to_string())
            .unwrap_or_default()
    }
}

impl Record for BiteRow {
    const TABLE: &'static str = "bites";
    const NAME_COLUMN: &'static str = "driveline";
    const TIME_COLUMN: &'static str = "time";
    const PRODUCT_COLUMN: Option<&'static str> = Some("product");

    fn columns() -> &'static [&'static str] {
        columns()
    }

    fn from_row(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        let mut figures = DrivelineResults::default();
        for (figure, column) in bite_columns() {
            figure.set(
                &mut figures,
                from_sql(figure.figure_type, row.get_ref(column)?),
            );
        }
        Ok(Self {
            id: row.get("id")?,
            run_id: row.get("run_id")?,
            driveline: row.get("driveline")?,
            channel: row.get("channel")?,
            second_period_s: row.get("second_period_s")?,
            quality: row.get("quality")?,
            reference_taf: row.get("reference_taf")?,
            shift_over_linear_s: row.get("shift_over_linear_s")?,
            context: context_of(row)?,
            figures,
        })
    }

    fn cells(&self) -> Vec<Cell> {
        layout()
            .iter()
            .map(|(name, column)| match column {
                Column::Own(_) => self.own(name),
                Column::Figure(index) => figure_cell(self.figure(*index)),
            })
            .collect()
    }
}

impl Serialize for BiteRow {
    /// The columns as members in export order: flags as booleans, times as text,
    /// no value as null.
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(layout().len()))?;
        for (name, column) in layout() {
            match column {
                Column::Own(_) => match self.own(name) {
                    Cell::Null => map.serialize_entry(name, &())?,
                    Cell::Integer(v) => map.serialize_entry(name, &v)?,
                    Cell::Real(v) => map.serialize_entry(name, &v)?,
                    Cell::Text(v) => map.serialize_entry(name, &v)?,
                },
                Column::Figure(index) => match self.figure(*index) {
                    None => map.serialize_entry(name, &())?,
                    Some(Value::Real(v)) => map.serialize_entry(name, &v)?,
                    Some(Value::Count(v)) | Some(Value::Index(v)) => {
                        map.serialize_entry(name, &v)?
                    }
                    Some(Value::Bool(v)) => map.serialize_entry(name, &v)?,
                    Some(Value::Time(ms)) => {
                        map.serialize_entry(name, &UtcTime::from_unix_ms(ms).to_string())?
                    }
                },
            }
        }
        map.end()
    }
}

/// The process context of a bite row (a code out of u32's range, an unknown state: no
/// value).
fn context_of(row: &rusqlite::Row<'_>) -> rusqlite::Result<ProcessContext> {
    let code = |column: &str| -> rusqlite::Result<Option<u32>> {
        Ok(row
            .get::<_, Option<i64>>(column)?
            .and_then(|v| u32::try_from(v).ok()))
    };
    Ok(ProcessContext {
        weld: None,
        speed_mpm: row.get("speed_mpm")?,
        coil: match row.get::<_, Option<StoredCoil>>("coil")? {
            Some(StoredCoil::Number(number)) => u32::try_from(number).ok().map(Coil::Number),
            Some(StoredCoil::Text(text)) => AsciiText::new(&text).map(Coil::Text),
            None => None,
        },
        product: code("product")?,
        thickness_mm: row.get("thickness_mm")?,
        pass: code("pass")?,
        state: row
            .get::<_, Option<String>>("mill_state")?
            .as_deref()
            .and_then(MillState::from_name),
    })
}

/// The figures of a driveline a bite row gives, as the analysis would publish them:
/// what a degraded window measured is no value.
pub fn trusted(row: &BiteRow) -> DrivelineResults {
    let mut figures = row.figures.clone();
    if figures.last_bite_degraded {
        for (figure, _) in bite_columns().filter(|(figure, _)| figure.from_window) {
            figure.set(&mut figures, None);
        }
    }
    figures
}

#[cfg(test)]
mod tests {
    use rusqlite::Connection;

    use super::*;
    use crate::state::catalogue::DRIVELINE;
    use crate::state::events::{BiteRecord, HistoryEvent, WearState};

    /// A degraded bite with every figure of its row set, stored and read back.
    fn stored() -> (BiteRecord, BiteRow) {
        let mut connection = Connection::open_in_memory().unwrap();
        crate::testing::history_with_run(&mut connection);
        let time = UtcTime::parse("2026-05-04T23:59:58.250Z").unwrap();
        let mut figures: DrivelineResults =
            crate::history::figures::tests::every_kept_figure_set(|f| f.columns.bite.is_some());
        figures.bite_counter = 7;
        figures.last_bite_degraded = true;
        let mut record = BiteRecord::clean("F1", "torque", time, figures);
        record.second_period_s = Some(0.048);
        record.gap_state = Some(WearState::Ok);
        let transaction = connection.transaction().unwrap();
        let event = HistoryEvent::Bite(Box::new(record.clone()));
        super::super::rows::insert(&transaction, 1, &event).unwrap();
        transaction.commit().unwrap();
        let row = connection
            .query_row(
                &format!("SELECT {} FROM bites", columns().join(", ")),
                [],
                BiteRow::from_row,
            )
            .unwrap();
        (record, row)
    }

    #[test]
    fn a_bite_row_gives_back_every_figure_it_keeps() {
        let (record, row) = stored();
        for (figure, column) in bite_columns() {
            let kept = figure.value(&row.figures);
            assert_eq!(kept, figure.value(&record.figures), "bites.{column}");
            assert!(kept.is_some(), "the test sets {}", figure.key);
        }
        assert_eq!(row.time(), "2026-05-04T23:59:58.250Z");
        assert_eq!(
            (row.second_period_s, row.quality.as_str()),
            (Some(0.048), "good")
        );
    }

    #[test]
    fn a_degraded_row_publishes_no_untrusted_values() {
        let (_, row) = stored();
        let published = trusted(&row);
        for figure in DRIVELINE.iter().filter(|f| f.columns.bite.is_some()) {
            let value = figure.value(&published);
            match figure.from_window {
                true => assert_eq!(value, None, "{} from a degraded window", figure.key),
                false => assert_eq!(value, figure.value(&row.figures), "{}", figure.key),
            }
        }
        assert_eq!(published.bite_counter, 7);
        assert!(published.last_bite_degraded);
    }

    #[test]
    fn the_export_keeps_the_first_order_and_types() {
        let (_, row) = stored();
        let text = serde_json::to_string(&row).unwrap();
        let at: Vec<usize> = FIRST_ORDER
            .iter()
            .map(|key| {
                text.find(&format!("\"{key}\":"))
                    .unwrap_or_else(|| panic!("{key}"))
            })
            .collect();
        assert!(at.windows(2).all(|w| w[0] < w[1]), "in order: {text}");
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(json["degraded"], serde_json::json!(true));
        assert_eq!(json["time"], serde_json::json!("2026-05-04T23:59:58.250Z"));
        assert_eq!(json["bite_counter"], serde_json::json!(7));
        assert!(json["gap_coupling"].is_u64(), "an index");
        let cells = row.cells();
        assert_eq!(cells.len(), json.as_object().unwrap().len());
        assert_eq!(cells[15], Cell::Integer(1), "degraded as 0/1 in CSV");
    }
}
