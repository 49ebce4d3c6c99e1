//! The chatter closed loop on the physical tandem model, the small deterministic version
//! CI runs (`millgate_tests::chatter_loop::LoopPlan::quick`: the nominal mill, three
//! accelerated runs and two stable runs at the highest allowed speed, the band-gain
//! detector with thresholds commissioned on separate stable recordings). The README's
//! table comes from the full plan:
//!
//! ```text
//! cargo run --release -p millgate-tests --example chatter_loop -- --plot docs/img/chatter-closed-loop.svg
//! ```

use millgate_tests::chatter_loop::{
    mills, open_loop_developed, runs, score, Detector, LoopPlan, Scenario,
};

#[test]
fn the_slow_down_request_keeps_accelerated_runs_below_developed_chatter() -> anyhow::Result<()> {
    let plan = LoopPlan {
        welds: 0,
        ..LoopPlan::quick()
    };
    let mills = mills(&plan)?;
    let runs = runs(&plan, &mills);
    // Open loop, every run past the critical speed develops chatter.
    let (open, accelerated) = open_loop_developed(&plan, &mills, &runs)?;
    assert_eq!((open, accelerated), (3, 3));
    let (score, outcomes) = score(&plan, &mills, &runs, Detector::BandGain)?;
    println!("{score:?}");
    // Closed loop: none does; each was slowed down at least once, each slow-down by
    // the automation's drop (150 m/min), or a multiple of it when the request held.
    assert_eq!((score.developed, score.accelerated), (0, 3));
    let critical = mills[0].critical_m_s();
    for (run, outcome) in runs.iter().zip(&outcomes) {
        match run.scenario {
            Scenario::Accelerated { .. } => {
                assert!(!outcome.events.is_empty(), "{run:?}: no slow-down");
                for event in &outcome.events {
                    let shed = event.shed_m_s() * 60.0;
                    let steps = shed / 150.0;
                    assert!(
                        (steps - steps.round()).abs() < 1e-6
                            && (1.0..=3.0).contains(&steps.round()),
                        "{run:?}: {event:?}"
                    );
                    // Requested near the critical speed (the gain rises there), not far
                    // below it.
                    assert!(
                        event.speed_at_request_m_s > 0.95 * critical,
                        "{run:?}: {event:?} at critical {critical}"
                    );
                }
            }
            // Stable rolling at 95% of the critical speed: no slow-down.
            _ => assert!(outcome.events.is_empty(), "{run:?}: {:?}", outcome.events),
        }
    }
    Ok(())
}
