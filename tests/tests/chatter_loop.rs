//! The chatter closed loop on the physical tandem model, the small deterministic version
//! CI runs (`millgate_tests::experiments::chatter_loop::LoopPlan::quick`: the nominal mill, three
//! accelerated runs and two stable runs at the highest allowed speed, the band-gain
//! detector with thresholds commissioned on separate stable recordings). The README's
//! table comes from the full plan:
//!
//! ```text
//! cargo run --release -p millgate-tests --example chatter_loop -- --plot docs/img/chatter-closed-loop.svg
//! ```

use millgate_tests::experiments::chatter_loop::{
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
    // the automation's drop (150 m/min) per step, from the lower of the speed at the
    // request and the speed `lookback_s` before: the shed is the drops plus what the
    // mill gained in the look-back, at most its acceleration then (the operator's ramp,
    // or the re-acceleration after an earlier slow-down) times the look-back.
    assert_eq!((score.developed, score.accelerated), (0, 3));
    let critical = mills[0].critical_m_s();
    let policy = plan.policy;
    for (run, outcome) in runs.iter().zip(&outcomes) {
        match run.scenario {
            Scenario::Accelerated { accel_m_s2, .. } => {
                assert!(!outcome.events.is_empty(), "{run:?}: no slow-down");
                let most_gained =
                    accel_m_s2.max(policy.resume_accel_m_s2) * policy.lookback_s + 1e-9;
                for event in &outcome.events {
                    let gained = event.shed_m_s() - f64::from(event.drops) * policy.drop_m_s;
                    // A request still set when the run ends may be cut short in its
                    // deceleration: only the upper bound holds for it.
                    let least = if event.released_s.is_some() {
                        0.0
                    } else {
                        f64::NEG_INFINITY
                    };
                    assert!(
                        (1..=3).contains(&event.drops) && (least..=most_gained).contains(&gained),
                        "{run:?}: {event:?} (gained {gained} m/s in the look-back)"
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
