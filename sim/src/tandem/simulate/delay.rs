//! The transport delay: every stand's exit gauge kept at the internal steps and read
//! back, interpolated, a delay later as the next stand's entry gauge.

/// The ring of exit-gauge deviations, one row of `stands` values per internal step;
/// a power-of-two number of rows, so the ring index is a mask.
pub(super) struct GaugeHistory {
    values: Vec<f64>,
    mask: usize,
    stands: usize,
    /// Steps stored so far (the newest is step `stored - 1`).
    stored: usize,
}

impl GaugeHistory {
    pub(super) fn new(steps: usize, stands: usize) -> GaugeHistory {
        let rows = steps.next_power_of_two();
        GaugeHistory {
            values: vec![0.0; rows * stands],
            mask: rows - 1,
            stands,
            stored: 0,
        }
    }

    pub(super) fn push(&mut self, row: &[f64]) {
        let at = (self.stored & self.mask) * self.stands;
        self.values[at..at + self.stands].copy_from_slice(&row[..self.stands]);
        self.stored += 1;
    }

    /// Stand `stand`'s deviation at step position `position` (fractional), by 4-point
    /// Lagrange interpolation; 0 before the first step. The caller keeps `position`
    /// at least two steps behind the newest.
    pub(super) fn at(&self, stand: usize, position: f64) -> f64 {
        if position < 0.0 {
            return 0.0;
        }
        let base = position as usize;
        let frac = position - base as f64;
        let value = |step: usize| self.values[(step & self.mask) * self.stands + stand];
        let p0 = if base == 0 { 0.0 } else { value(base - 1) };
        let (p1, p2, p3) = (value(base), value(base + 1), value(base + 2));
        let (u, v, w, x) = (frac + 1.0, frac, frac - 1.0, frac - 2.0);
        -p0 * v * w * x / 6.0 + p1 * u * w * x / 2.0 - p2 * u * v * x / 2.0 + p3 * u * v * w / 6.0
    }
}
