//! Per-product chatter thresholds against one mill-wide threshold on the physical
//! tandem model (`millgate_tests::experiments::chatter_products`): the table of
//! `docs/chatter.md`, "Thresholds per product".
//!
//! ```text
//! cargo run -p millgate-tests --example chatter_products -- [--quick]
//! ```

use millgate_tests::experiments::chatter_products::{evaluate, table, ProductPlan};

fn main() -> anyhow::Result<()> {
    let plan = if std::env::args().any(|a| a == "--quick") {
        ProductPlan::quick()
    } else {
        ProductPlan::full()
    };
    let result = evaluate(&plan)?;
    println!("{plan:?}");
    print!("{}", table(&result));
    for outcome in &result.outcomes {
        println!("{outcome:?}");
    }
    Ok(())
}
