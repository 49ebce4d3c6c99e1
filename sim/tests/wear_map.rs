//! Wear maps: the paper's nonlinear signature over a small grid, CSV and SVG output.

use millgate_sim::model::Model;
use millgate_sim::plot::wear_map_svg;
use millgate_sim::wear_map::{wear_map, WearMap, WearMapRow, WearMapSpec};

mod common;

use common::load;

fn row(map: &WearMap, static_torque_knm: f64, backlash_rad: f64) -> anyhow::Result<WearMapRow> {
    map.rows
        .iter()
        .find(|r| r.static_torque_knm == static_torque_knm && r.backlash_rad == backlash_rad)
        .copied()
        .ok_or_else(|| anyhow::anyhow!("no row {static_torque_knm} {backlash_rad}"))
}

fn first_period(row: &WearMapRow) -> anyhow::Result<f64> {
    row.first_period_s
        .ok_or_else(|| anyhow::anyhow!("no first period in {row:?}"))
}

/// The adjusted Table 2 driveline with a fast bite (load rise 300/s), where the
/// oscillation is strong enough for clean period measurement.
fn fast_bite() -> anyhow::Result<Model> {
    let mut model = load("table2-adjusted.toml")?;
    model.load.rise_rate = 300.0;
    Ok(model)
}

#[test]
fn backlash_raises_taf_and_lengthens_the_first_period_more_at_low_static_torque(
) -> anyhow::Result<()> {
    let model = fast_bite()?;
    let (low, high, gap) = (28.0, 112.0, 4.0e-3);
    let spec = WearMapSpec {
        static_torques_knm: vec![low, high],
        backlashes_rad: vec![0.0, gap],
        coupling: None,
        period_lowpass_hz: None,
    };
    let mut calls = 0;
    let map = wear_map(&model, &spec, |done, total, _| {
        calls += 1;
        assert_eq!((done, total), (calls, 4));
    })?;
    assert_eq!(calls, 4);
    assert_eq!(map.coupling, model.measurement.coupling);

    // Linear: TAF and periods do not depend on the static torque.
    let (linear_low, linear_high) = (row(&map, low, 0.0)?, row(&map, high, 0.0)?);
    assert!((linear_low.taf - linear_high.taf).abs() < 1e-9);
    let (worn_low, worn_high) = (row(&map, low, gap)?, row(&map, high, gap)?);

    // TAF rises with the gap, more at the lower static torque.
    assert!(worn_high.taf > linear_high.taf * 1.05, "{worn_high:?}");
    assert!(
        worn_low.taf > worn_high.taf * 1.1,
        "{worn_low:?} {worn_high:?}"
    );

    // The first period lengthens with the gap, more at the lower static torque.
    let lengthening_low = first_period(&worn_low)? - first_period(&linear_low)?;
    let lengthening_high = first_period(&worn_high)? - first_period(&linear_high)?;
    assert!(lengthening_high > 0.0, "{lengthening_high}");
    assert!(
        lengthening_low > 2.0 * lengthening_high,
        "{lengthening_low} {lengthening_high}"
    );
    // ... and so does the first-period shift (first - second).
    let shift = |r: &WearMapRow| r.period_shift_s.unwrap_or(f64::NAN);
    assert!(shift(&worn_low) > shift(&linear_low) + 0.001);
    Ok(())
}

#[test]
fn taf_depends_on_gap_over_static_torque() -> anyhow::Result<()> {
    // The chain is piecewise linear: doubling both the load and the gap scales the
    // whole response, so TAF is the same.
    let model = load("table2-adjusted-backlash.toml")?;
    let spec = WearMapSpec {
        static_torques_knm: vec![56.0, 112.0],
        backlashes_rad: vec![1.0e-3, 2.0e-3],
        coupling: Some(1),
        period_lowpass_hz: Some(15.0),
    };
    let map = wear_map(&model, &spec, |_, _, _| {})?;
    let a = row(&map, 56.0, 1.0e-3)?.taf;
    let b = row(&map, 112.0, 2.0e-3)?.taf;
    assert!((a - b).abs() < 1e-6 * a, "{a} {b}");
    assert!(row(&map, 56.0, 2.0e-3)?.taf > a);
    Ok(())
}

#[test]
fn csv_has_one_row_per_grid_point_and_svg_draws_every_gap() -> anyhow::Result<()> {
    let model = fast_bite()?;
    let spec = WearMapSpec {
        static_torques_knm: vec![50.0, 100.0, 150.0],
        backlashes_rad: vec![0.0, 2.0e-3],
        coupling: None,
        period_lowpass_hz: None,
    };
    let map = wear_map(&model, &spec, |_, _, _| {})?;
    let csv = map.to_csv();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("static_torque_knm,backlash_rad,taf,first_period_s,second_period_s,period_shift_s,shift_over_linear_s")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 6);
    for (fields, row) in rows.iter().zip(&map.rows) {
        assert_eq!(fields.len(), 7);
        let over_linear = map
            .shift_over_linear_s(row)
            .expect("the map has a zero-gap row");
        assert!((fields[6].parse::<f64>()? - over_linear).abs() < 1e-6);
        assert_eq!(fields[0].parse::<f64>()?, row.static_torque_knm);
        assert_eq!(fields[1].parse::<f64>()?, row.backlash_rad);
        assert!((fields[2].parse::<f64>()? - row.taf).abs() < 1e-6);
    }
    let svg = wear_map_svg(&map)?;
    assert!(svg.starts_with("<svg"));
    assert!(svg.contains("gap 0.0 mrad") && svg.contains("gap 2.0 mrad"));
    assert!(svg.contains("static torque, kN*m"));
    // Three panels (the third, the shift over zero gap, as the map has a zero-gap row),
    // one line per gap each.
    assert!(svg.contains("period shift over zero gap, ms"));
    assert!(svg.matches("<polyline").count() >= 6);
    let without_zero_gap = millgate_sim::wear_map::WearMap {
        rows: map
            .rows
            .iter()
            .filter(|r| r.backlash_rad > 0.0)
            .copied()
            .collect(),
        ..map.clone()
    };
    let svg = wear_map_svg(&without_zero_gap)?;
    assert!(!svg.contains("period shift over zero gap"));
    assert!(svg.contains("first - second period, ms"));
    Ok(())
}

#[test]
fn bad_grids_are_errors() -> anyhow::Result<()> {
    let model = load("table2-adjusted.toml")?;
    let mut spec = WearMapSpec::around(&model);
    spec.static_torques_knm[2] = -1.0;
    let message = wear_map(&model, &spec, |_, _, _| {})
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(message.contains("static_torques_knm[2]"), "{message}");
    let mut spec = WearMapSpec::around(&model);
    spec.coupling = Some(2);
    assert!(wear_map(&model, &spec, |_, _, _| {}).is_err());
    let mut spec = WearMapSpec::around(&model);
    spec.backlashes_rad.push(f64::NAN);
    assert!(wear_map(&model, &spec, |_, _, _| {}).is_err());
    Ok(())
}

#[test]
fn paper_load_rise_grid_shift_grows_with_gap_and_falls_with_static_torque() -> anyhow::Result<()> {
    // The paper's slow load rise (36.7/s), gap on the measured spindle coupling.
    let model = load("table2-adjusted.toml")?;
    let (low, high) = (56.0, 112.0);
    let gaps = [0.0, 2.0e-3, 4.0e-3];
    let spec = WearMapSpec {
        static_torques_knm: vec![low, high],
        backlashes_rad: gaps.to_vec(),
        coupling: None,
        period_lowpass_hz: None,
    };
    let map = wear_map(&model, &spec, |_, _, _| {})?;
    let shift = |torque: f64, gap: f64| -> anyhow::Result<f64> {
        row(&map, torque, gap)?
            .period_shift_s
            .ok_or_else(|| anyhow::anyhow!("no shift at {torque} {gap}"))
    };
    // Linear chain: the shift does not depend on the static torque and is small (the
    // weak first mode beating with the measured second one; 8.2 ms measured).
    let linear = shift(low, 0.0)?;
    assert!((linear - shift(high, 0.0)?).abs() < 1e-9);
    assert!(linear.abs() < 0.01, "{linear}");
    for torque in [low, high] {
        let excess: Vec<f64> = gaps
            .iter()
            .map(|&gap| {
                let row = row(&map, torque, gap)?;
                map.shift_over_linear_s(&row)
                    .ok_or_else(|| anyhow::anyhow!("no shift over linear at {torque} {gap}"))
            })
            .collect::<anyhow::Result<_>>()?;
        assert!((excess[1] - (shift(torque, gaps[1])? - linear)).abs() < 1e-12);
        assert_eq!(excess[0], 0.0);
        assert!(
            excess[1] > 0.002 && excess[2] > excess[1],
            "{torque}: {excess:?}"
        );
    }
    for gap in [2.0e-3, 4.0e-3] {
        assert!(shift(low, gap)? > shift(high, gap)? + 0.001, "{gap}");
        assert!(row(&map, low, gap)?.taf > row(&map, high, gap)?.taf * 1.05);
    }
    Ok(())
}
