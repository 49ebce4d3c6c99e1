//! The gap maps' curves: what a bite's TAF is at each opened gap, per coupling, and
//! the live pooled estimate on them.

use std::sync::Arc;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::Json;
use serde::Serialize;

use super::{driveline_index, ApiError, DrivelineName, Params};
use crate::outputs::web::shared::WebState;
use crate::state::gap_maps::{GapMapState, GapMaps};
use crate::state::results::GapResults;

/// One TAF curve of a gap map: TAF over the static torque the analysis measures,
/// at one opened gap.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct MapCurve {
    /// Opened gap, mrad.
    pub gap_mrad: f64,
    /// `[static torque kN*m, TAF]`, static torque ascending.
    pub points: Vec<[f64; 2]>,
}

impl MapCurve {
    fn new(gap_mrad: f64, curve: Vec<(f64, f64)>) -> Self {
        Self {
            gap_mrad,
            points: curve.into_iter().map(|(s, taf)| [s, taf]).collect(),
        }
    }
}

/// A coupling's gap map: its curves at every whole mrad.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct CouplingCurves {
    /// Coupling (model index, 0 = motor side).
    pub coupling: usize,
    /// Its name in the model.
    pub name: String,
    /// Gap 0 (the linear driveline) first.
    pub curves: Vec<MapCurve>,
}

/// The pooled gap estimate on its coupling's map: the curve at the estimate and at
/// the ends of its 90% interval.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct EstimateCurves {
    /// The coupling the estimate names, else the likeliest.
    pub coupling: usize,
    /// Whether the estimate names the coupling (else the bites cannot tell the
    /// couplings apart and `coupling` is only the likeliest).
    pub determined: bool,
    /// At the estimated gap.
    pub gap: MapCurve,
    /// At the interval's lower end.
    pub low: MapCurve,
    /// At its upper end.
    pub high: MapCurve,
}

/// A driveline's gap maps as `/api/drivelines/{name}/map` gives them.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub(crate) struct GapMapView {
    /// `ready`, `building` (read from the cache or simulated), `failed` or `no_model`.
    pub state: &'static str,
    /// What `state` means here (progress, the failure); `None` when ready.
    pub message: Option<String>,
    /// Simulations done and in all while `building` (0 of 0 until the build reports).
    pub simulations: Option<[usize; 2]>,
    /// The model's name, when ready.
    pub model: Option<String>,
    /// The static torque range every curve covers, kN*m, when ready.
    pub static_range_knm: Option<[f64; 2]>,
    /// Every coupling that may carry the gap, in the wear settings' order.
    pub couplings: Vec<CouplingCurves>,
    /// The live pooled estimate on its map; `None` without an estimate.
    pub estimate: Option<EstimateCurves>,
}

impl GapMapView {
    fn not_ready(state: &'static str, message: String, simulations: Option<[usize; 2]>) -> Self {
        Self {
            state,
            message: Some(message),
            simulations,
            model: None,
            static_range_knm: None,
            couplings: Vec::new(),
            estimate: None,
        }
    }

    fn new(maps: &GapMaps, gap: Option<&GapResults>) -> Self {
        let couplings = maps
            .maps()
            .iter()
            .enumerate()
            .map(|(index, map)| CouplingCurves {
                coupling: map.coupling,
                name: map.name.clone(),
                curves: maps
                    .whole_mrad_curves(index)
                    .into_iter()
                    .map(|(mrad, curve)| MapCurve::new(f64::from(mrad), curve))
                    .collect(),
            })
            .collect();
        let estimate = gap.and_then(|gap| {
            let coupling = gap.coupling.or(gap.likeliest_coupling)?;
            let index = maps.index_of(coupling)?;
            let curve = |mrad: f64| MapCurve::new(mrad, maps.taf_curve(index, mrad * 1e-3));
            Some(EstimateCurves {
                coupling,
                determined: gap.coupling.is_some(),
                gap: curve(gap.gap_mrad),
                low: curve(gap.low_mrad),
                high: curve(gap.high_mrad),
            })
        });
        let (low, high) = maps.static_range_knm();
        Self {
            state: "ready",
            message: None,
            simulations: None,
            model: Some(maps.data().model_name.clone()),
            static_range_knm: Some([low, high]),
            couplings,
            estimate,
        }
    }
}

/// `GET /api/drivelines/{name}/map`: the gap maps' TAF curves over static torque
/// (what a bite's TAF is at each opened gap, per coupling) and the live estimate on
/// them.
pub(crate) async fn gap_maps(
    State(state): State<Arc<WebState>>,
    DrivelineName(name): DrivelineName,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
) -> Result<Json<GapMapView>, ApiError> {
    Params::of(query, &[])?;
    let index = driveline_index(&state, &name)?;
    let view = match state.board.gap_maps(index) {
        Some(GapMapState::Ready(maps)) => {
            let results = state.board.results();
            GapMapView::new(&maps, results.drivelines[index].gap.as_ref())
        }
        Some(GapMapState::Building { done, total }) => GapMapView::not_ready(
            "building",
            if total == 0 {
                "the gap maps are being read from the cache or built".into()
            } else {
                format!("the gap maps are being built: {done} of {total} simulations")
            },
            Some([done, total]),
        ),
        Some(GapMapState::Failed(why)) => {
            GapMapView::not_ready("failed", format!("no gap maps: {why}"), None)
        }
        Some(GapMapState::NoModel) | None => GapMapView::not_ready(
            "no_model",
            format!("driveline \"{name}\" has no model configured: no gap maps"),
            None,
        ),
    };
    Ok(Json(view))
}
