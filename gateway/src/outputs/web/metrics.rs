//! The maintenance page's `/metrics` families: its history query slots, how many are
//! held, and the requests refused because none freed in time.

use super::QuerySlots;
use crate::exposition::{Exposition, Families, Kind};

impl Families for QuerySlots {
    fn write_families(&self, page: &mut Exposition) {
        page.scalars([
            (
                "millgate_web_history_query_slots",
                Kind::Gauge,
                "History query slots of the maintenance page (outputs.web.history_queries).",
                self.limit() as f64,
            ),
            (
                "millgate_web_history_query_slots_in_use",
                Kind::Gauge,
                "History query slots held by a running query.",
                self.in_use() as f64,
            ),
            (
                "millgate_web_history_queries_refused_total",
                Kind::Counter,
                "Maintenance page requests answered 503 because no history query slot freed within 1 s.",
                self.refused() as f64,
            ),
        ]);
    }
}
