//! Per-product chatter thresholds against one mill-wide threshold on the physical
//! tandem model (`sim::tandem`): two products of different stability (the example
//! schedule, and the same schedule with lower roll-gap friction, a different surface
//! or lubrication: its critical speed is lower), each rolled up to 95% of its own
//! critical speed (its highest allowed speed).
//!
//! One seeded set of recordings per product (accelerations to the top speed and
//! stable rolling there, a `product` column naming the product) is commissioned
//! twice with the command's code: once mill-wide (`commission`, every recording
//! together: what one `gain_thresholds` would be) and once by product
//! (`commission_by_product`: a group per product, the mill's thresholds the
//! fallback). Another seeded set is then run through the gateway's offline monitor
//! (`windows_in_context`, the row's product picking its group's thresholds) with each
//! configuration: stable runs at the top speed (any alarm after the settling time is
//! a false alarm) and ramps past the critical speed (caught when the first alarm comes
//! before developed chatter, [`developed_time`]; the lead is how long before).

use millgate::analysis::chatter::commission::{commission, commission_by_product};
use millgate::analysis::chatter::{windows_in_context, ContextColumns, Recording};
use millgate_config::Config;
use millgate_sim::tandem::simulate::{Record, SpeedRamp};
use millgate_sim::tandem::truth::{developed_time, mill_critical_speed};
use millgate_sim::tandem::{PassSchedule, TandemMill};
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

use super::chatter_eval::{
    monitor_config_with, noisy_run, parallel, recording_from, SAMPLE_RATE_HZ,
};
use crate::kit::tandem::{modbus_source, Stands};

/// Stands of the example schedule.
const STANDS: usize = 5;
/// Commissioning margin, percent (the command's default).
const MARGIN_PERCENT: f64 = 10.0;
/// The highest allowed speed of each product, times its critical speed.
const TOP: f64 = 0.95;

/// One product: its code and how its strip changes the example schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Product {
    /// The PLC's product code.
    pub code: u32,
    /// Factor on every stand's roll-gap friction.
    pub friction: f64,
}

/// How many runs of each kind, how long, with which seed.
#[derive(Debug, Clone, PartialEq)]
pub struct ProductPlan {
    /// The products.
    pub products: Vec<Product>,
    /// Commissioning recordings per product (two thirds accelerations to the top
    /// speed, the rest rolling there).
    pub commission_runs: usize,
    /// Stable runs per product at the top speed in the evaluation set.
    pub stable_runs: usize,
    /// Ramps per product past the critical speed in the evaluation set.
    pub ramps: usize,
    /// Scored length of a commissioning or stable run, s.
    pub run_s: f64,
    /// Settling time before a run is scored, s.
    pub settle_s: f64,
    /// Seed of the commissioning set (the evaluation set's is its complement).
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
}

impl ProductPlan {
    /// The docs' table (`cargo run -p millgate-tests --example chatter_products`).
    pub fn full() -> ProductPlan {
        ProductPlan {
            products: vec![
                Product {
                    code: 101,
                    friction: 1.0,
                },
                Product {
                    code: 202,
                    friction: 0.85,
                },
            ],
            commission_runs: 6,
            stable_runs: 6,
            ramps: 6,
            run_s: 30.0,
            settle_s: 8.0,
            seed: 39,
            threads: 2,
        }
    }

    /// The small deterministic version CI runs.
    pub fn quick() -> ProductPlan {
        ProductPlan {
            commission_runs: 3,
            stable_runs: 2,
            ramps: 2,
            run_s: 20.0,
            ..ProductPlan::full()
        }
    }
}

/// One simulated run of the evaluation set.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// The product.
    pub product: u32,
    /// A ramp past the critical speed (else stable rolling at the top speed).
    pub ramp: bool,
    /// When chatter developed, s (ramps).
    pub developed_s: Option<f64>,
    /// First alarm after the settling time with the mill-wide thresholds, s.
    pub mill_wide_alarm_s: Option<f64>,
    /// The same with the per-product thresholds.
    pub per_product_alarm_s: Option<f64>,
}

/// What one configuration did over the evaluation set, per product.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Score {
    /// Stable runs with an alarm.
    pub false_alarms: usize,
    /// Stable runs.
    pub stable: usize,
    /// Ramps whose first alarm came before developed chatter.
    pub caught: usize,
    /// Ramps.
    pub ramps: usize,
    /// Mean time from the first alarm to developed chatter over the caught ramps in
    /// which chatter developed before the run ended, s.
    pub mean_lead_s: f64,
}

/// The experiment's result.
#[derive(Debug, Clone, PartialEq)]
pub struct ProductResult {
    /// Per product: its code, its critical speed (m/s at the last stand), the
    /// per-product thresholds, and the scores (mill-wide, per-product).
    pub products: Vec<(u32, f64, Vec<f64>, Score, Score)>,
    /// The mill-wide thresholds.
    pub mill_wide: Vec<f64>,
    /// Every evaluation run.
    pub outcomes: Vec<Outcome>,
}

/// A product's mill and its critical speed factor.
fn product_mill(product: &Product) -> anyhow::Result<(TandemMill, f64)> {
    let mill = TandemMill::new(&PassSchedule::example()?.scaled(product.friction, 1.0))?;
    let critical = mill_critical_speed(&mill)?.speed;
    Ok((mill, critical))
}

/// `record` from the settling time on, with a `product` column of `code`.
fn product_recording(name: String, record: &Record, from: usize, code: u32) -> Recording {
    let mut recording = recording_from(name, record, from);
    recording.context = ContextColumns {
        product: Some(vec![f64::from(code); recording.len()]),
        ..ContextColumns::default()
    };
    recording
}

/// The monitor configuration with a product tag, `thresholds` the mill's and `groups`
/// (code, thresholds) one product group each.
fn config(thresholds: &[f64], groups: &[(u32, Vec<f64>)]) -> anyhow::Result<Config> {
    let list = |values: &[f64]| {
        let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
        items.join(", ")
    };
    let mut keys = format!(
        "k_max = 0.25\ngain_thresholds = [{}]\ncontext = {{ product = \"product\" }}\n",
        list(thresholds)
    );
    for (code, group) in groups {
        keys += &format!(
            "[[tandem_mills.product_groups]]\nname = \"product-{code}\"\nproducts = [{code}]\n\
             gain_thresholds = [{}]\n",
            list(group)
        );
    }
    let text = String::from("name = \"chatter products\"\n")
        + &modbus_source("daq")
        + "[[channels]]\nname = \"product\"\nkind = \"process_value\"\nunit = \"1\"\n\
           source = { modbus = \"daq\", table = \"holding\", address = 0 }\n\n"
        + &Stands::modbus(STANDS, "daq").bare().keys(&keys).toml();
    millgate_config::from_toml_str(&text, "chatter-products.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// The commissioning set of `plan`: per product, its recordings.
fn commissioning_set(plan: &ProductPlan) -> anyhow::Result<Vec<Recording>> {
    let mut jobs = Vec::new();
    let mut rng = SmallRng::seed_from_u64(plan.seed);
    for product in &plan.products {
        for k in 0..plan.commission_runs {
            let accelerated = k < plan.commission_runs - plan.commission_runs / 3;
            let accel_m_s2 = rng.random_range(0.2_f64.ln()..2.0_f64.ln()).exp();
            let noise = rng.random_range(0.5_f64.ln()..2.0_f64.ln()).exp();
            jobs.push((
                *product,
                k,
                accelerated,
                accel_m_s2,
                noise,
                rng.random::<u64>(),
            ));
        }
    }
    parallel(
        plan.threads,
        &jobs,
        |&(product, k, accelerated, accel_m_s2, noise, seed)| {
            let (mill, critical) = product_mill(&product)?;
            let top = TOP * critical;
            let unit_m_s = mill.exit_speed(mill.stands().len() - 1, 1.0);
            let (ramp, duration_s) = if accelerated {
                let ramp = SpeedRamp {
                    start: 0.6 * critical,
                    end: top,
                    hold_s: plan.settle_s,
                    accel_m_s2,
                };
                let reach = ramp.time_at(top, unit_m_s).unwrap_or(0.0);
                (ramp, reach + plan.run_s)
            } else {
                (SpeedRamp::constant(top), plan.settle_s + plan.run_s)
            };
            let record = noisy_run(&mill, ramp, duration_s, noise, seed)?;
            let from = (plan.settle_s * SAMPLE_RATE_HZ) as usize;
            Ok(product_recording(
                format!("product {} commissioning {k}", product.code),
                &record,
                from,
                product.code,
            ))
        },
    )
}

/// The first alarm at or after `from_s` of `recording` through `config`'s monitor.
fn first_alarm(config: &Config, recording: &Recording, from_s: f64) -> anyhow::Result<Option<f64>> {
    let (windows, _) = windows_in_context(
        config,
        0,
        &recording.time_s,
        &recording.stands,
        &recording.context,
    )?;
    Ok(windows
        .iter()
        .find(|w| w.t_s >= from_s && w.verdict.alarm)
        .map(|w| w.t_s))
}

/// Run `plan`: commission both ways, evaluate both on the other seeded set.
pub fn evaluate(plan: &ProductPlan) -> anyhow::Result<ProductResult> {
    let recordings = commissioning_set(plan)?;
    let bare = monitor_config_with(STANDS, "k_max = 0.25\ndetector = \"paper\"\n")?;
    let mill_wide = commission(&bare, 0, &recordings, MARGIN_PERCENT)?;
    let by_product = commission_by_product(&bare, 0, &recordings, MARGIN_PERCENT, 1)?;
    let groups: Vec<(u32, Vec<f64>)> = by_product
        .product_groups
        .iter()
        .filter_map(|g| Some((g.products[0], g.gain_thresholds.clone()?)))
        .collect();
    let mill_wide_config = config(&mill_wide.gain_thresholds, &[])?;
    let per_product_config = config(&by_product.gain_thresholds, &groups)?;

    let mut rng = SmallRng::seed_from_u64(!plan.seed);
    let mut jobs = Vec::new();
    for product in &plan.products {
        for k in 0..plan.stable_runs + plan.ramps {
            let ramp = k >= plan.stable_runs;
            let accel_m_s2 = rng.random_range(0.2_f64.ln()..2.0_f64.ln()).exp();
            let noise = rng.random_range(0.5_f64.ln()..2.0_f64.ln()).exp();
            let end = rng.random_range(1.2..1.5);
            jobs.push((*product, ramp, accel_m_s2, noise, end, rng.random::<u64>()));
        }
    }
    let outcomes = parallel(
        plan.threads,
        &jobs,
        |&(product, ramp, accel_m_s2, noise, end, seed)| {
            let (mill, critical) = product_mill(&product)?;
            let unit_m_s = mill.exit_speed(mill.stands().len() - 1, 1.0);
            let (speeds, duration_s) = if ramp {
                let ramp = SpeedRamp {
                    start: 0.7 * critical,
                    end: end * critical,
                    hold_s: plan.settle_s,
                    accel_m_s2,
                };
                let reach = ramp.time_at(end * critical, unit_m_s).unwrap_or(0.0);
                (ramp, reach + 5.0)
            } else {
                (
                    SpeedRamp::constant(TOP * critical),
                    plan.settle_s + plan.run_s,
                )
            };
            let record = noisy_run(&mill, speeds, duration_s, noise, seed)?;
            let recording = product_recording(String::new(), &record, 0, product.code);
            Ok(Outcome {
                product: product.code,
                ramp,
                developed_s: if ramp {
                    developed_time(&mill, &record)
                } else {
                    None
                },
                mill_wide_alarm_s: first_alarm(&mill_wide_config, &recording, plan.settle_s)?,
                per_product_alarm_s: first_alarm(&per_product_config, &recording, plan.settle_s)?,
            })
        },
    )?;
    let mut products = Vec::new();
    for product in &plan.products {
        let (mill, critical) = product_mill(product)?;
        let critical_m_s = critical * mill.exit_speed(mill.stands().len() - 1, 1.0);
        let own = groups
            .iter()
            .find(|(code, _)| *code == product.code)
            .map_or_else(Vec::new, |(_, t)| t.clone());
        let runs: Vec<&Outcome> = outcomes
            .iter()
            .filter(|o| o.product == product.code)
            .collect();
        products.push((
            product.code,
            critical_m_s,
            own,
            score(&runs, |o| o.mill_wide_alarm_s),
            score(&runs, |o| o.per_product_alarm_s),
        ));
    }
    Ok(ProductResult {
        products,
        mill_wide: mill_wide.gain_thresholds,
        outcomes,
    })
}

/// The score of `runs` by their first alarm `alarm`.
fn score(runs: &[&Outcome], alarm: fn(&Outcome) -> Option<f64>) -> Score {
    let mut score = Score::default();
    let (mut lead, mut led) = (0.0, 0);
    for run in runs {
        if run.ramp {
            score.ramps += 1;
            let developed = run.developed_s.unwrap_or(f64::INFINITY);
            if let Some(at) = alarm(run).filter(|&at| at < developed) {
                score.caught += 1;
                if developed.is_finite() {
                    lead += developed - at;
                    led += 1;
                }
            }
        } else {
            score.stable += 1;
            score.false_alarms += usize::from(alarm(run).is_some());
        }
    }
    score.mean_lead_s = if led > 0 { lead / f64::from(led) } else { 0.0 };
    score
}

/// The result as the docs' Markdown table.
pub fn table(result: &ProductResult) -> String {
    let list = |values: &[f64]| {
        let items: Vec<String> = values.iter().map(|v| format!("{v:.3}")).collect();
        items.join(", ")
    };
    let mut text = String::from(
        "| product | critical speed, m/s | thresholds | false alarms (stable runs) | caught before developed chatter (ramps) | mean lead, s |\n\
         |---|---|---|---|---|---|\n",
    );
    for (code, critical_m_s, own, mill_wide, per_product) in &result.products {
        for (what, thresholds, score) in [
            ("mill-wide", list(&result.mill_wide), mill_wide),
            ("per product", list(own), per_product),
        ] {
            text += &format!(
                "| {code} | {critical_m_s:.2} | {what}: [{thresholds}] | {} / {} | {} / {} | {:.2} |\n",
                score.false_alarms, score.stable, score.caught, score.ramps, score.mean_lead_s
            );
        }
    }
    text
}
