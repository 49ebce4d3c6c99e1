//! A simulated record: chock accelerations, speed and interstand tensions per sample.

/// A simulated record.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// Output sample rate, Hz; sample k is at `k / sample_rate_hz` s.
    pub sample_rate_hz: f64,
    /// Chock acceleration per stand, m/s^2 (sensor noise included).
    pub acceleration: Vec<Vec<f64>>,
    /// Speed factor per sample.
    pub speed: Vec<f64>,
    /// Interstand tension deviation per interstand, Pa (noise-free truth).
    pub tension_pa: Vec<Vec<f64>>,
}

impl Record {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.speed.len()
    }

    /// True when the record holds no sample.
    pub fn is_empty(&self) -> bool {
        self.speed.is_empty()
    }

    /// CSV: `t` (s), then `s1_vib .. sN_vib` (chock acceleration, m/s^2; the channel
    /// names of `config/examples/tandem-5stand.toml`); with `truth` also
    /// `speed_factor` and the interstand tension deviations `tension_1_2_mpa` ...
    pub fn to_csv(&self, truth: bool) -> String {
        use std::fmt::Write as _;
        let stands = self.acceleration.len();
        let mut header: Vec<String> = std::iter::once("t".to_owned())
            .chain((1..=stands).map(|s| format!("s{s}_vib")))
            .collect();
        if truth {
            header.push("speed_factor".to_owned());
            header.extend((1..stands).map(|j| format!("tension_{j}_{}_mpa", j + 1)));
        }
        let mut csv = header.join(",");
        csv.push('\n');
        for k in 0..self.len() {
            let _ = write!(csv, "{}", k as f64 / self.sample_rate_hz);
            for stand in &self.acceleration {
                let _ = write!(csv, ",{:.6}", stand[k]);
            }
            if truth {
                let _ = write!(csv, ",{:.6}", self.speed[k]);
                for tension in &self.tension_pa {
                    let _ = write!(csv, ",{:.6}", tension[k] * 1e-6);
                }
            }
            csv.push('\n');
        }
        csv
    }
}
