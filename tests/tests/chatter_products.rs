//! Per-product chatter thresholds against one mill-wide threshold on the physical
//! tandem model, the small deterministic version CI runs
//! (`millgate_tests::experiments::chatter_products::ProductPlan::quick`). The docs'
//! table comes from the full plan:
//!
//! ```text
//! cargo run -p millgate-tests --example chatter_products
//! ```

use millgate_tests::experiments::chatter_products::{evaluate, table, ProductPlan};

#[test]
fn per_product_thresholds_catch_at_least_as_much_without_more_false_alarms() -> anyhow::Result<()> {
    let result = evaluate(&ProductPlan::quick())?;
    println!("{}", table(&result));
    for (code, _, own, mill_wide, per_product) in &result.products {
        // Each product has its own thresholds, none above the mill-wide ones (the
        // mill-wide come from every product's recordings).
        assert_eq!(own.len(), result.mill_wide.len(), "product {code}");
        for (own, wide) in own.iter().zip(&result.mill_wide) {
            assert!(own <= wide, "product {code}: {own} > {wide}");
        }
        assert!(
            per_product.false_alarms <= mill_wide.false_alarms,
            "product {code}: {per_product:?} against {mill_wide:?}"
        );
        assert!(
            per_product.caught >= mill_wide.caught,
            "product {code}: {per_product:?} against {mill_wide:?}"
        );
    }
    Ok(())
}
