//! `millgate figures`: the catalogue of published figures with every output's name
//! for each (`crate::outputs::figures`), as Markdown (docs/figures.md's table), CSV or
//! JSON.

use crate::cli::registers::{csv_field, Format};
use crate::outputs::figures::{rows, FigureRow};

/// The table in `format`.
pub fn export(format: Format) -> String {
    let rows = rows();
    match format {
        Format::Json => serde_json::to_string_pretty(&rows).unwrap_or_default() + "\n",
        Format::Csv => {
            let mut out = String::from(
                "subject,key,unit,type,guard,stale,register,sparkplug,metric,history,description,\
                 metric_deprecated\n",
            );
            for row in &rows {
                let fields = [
                    row.subject,
                    row.key,
                    row.unit,
                    &row.figure_type,
                    &row.guard,
                    row.stale,
                    &row.register,
                    &row.sparkplug,
                    &row.metric,
                    &row.history,
                    row.description,
                    row.metric_deprecated.as_deref().unwrap_or(""),
                ];
                let fields: Vec<String> = fields.iter().map(|f| csv_field(f)).collect();
                out += &fields.join(",");
                out.push('\n');
            }
            out
        }
        Format::Md => markdown(&rows),
    }
}

fn markdown(rows: &[FigureRow]) -> String {
    let mut out = String::from(
        "| subject | key | unit | type | guard | stale | register | Sparkplug | /metrics | history | description |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for row in rows {
        out += &format!(
            "| {} | `{}` | {} | {} | {} | {} | {} | {} | `{}`{} | {} | {} |\n",
            row.subject,
            row.key,
            row.unit.replace('*', "\\*"),
            row.figure_type,
            row.guard,
            row.stale,
            row.register,
            code_or_reason(&row.sparkplug),
            row.metric,
            row.metric_deprecated
                .as_ref()
                .map_or(String::new(), |old| format!(" (and `{old}`, deprecated)")),
            row.history,
            row.description.replace('|', "\\|"),
        );
    }
    out
}

/// A name as code; a reason why there is none (`none: ...`) as text.
fn code_or_reason(name: &str) -> String {
    if name.starts_with("none") {
        name.to_owned()
    } else {
        format!("`{name}`")
    }
}
