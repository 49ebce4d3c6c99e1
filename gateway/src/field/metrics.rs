//! The acquisition's `/metrics` families: per channel (blocks, samples, timeouts,
//! errors, saturation, sequence faults), per source (connects; its status is the
//! catalogue's, `outputs::metrics`) and per CAN source (frames by kind, kernel drops
//! and timestamps, receive latency, bus state).

use millgate_config::Config;

use super::counters::{Acquisition, CanCounts, ChannelCountersSnapshot};
use crate::exposition::{Exposition, Families, Kind};

/// The acquisition's counters with the names of the channels and sources they count.
#[derive(Debug)]
pub(crate) struct AcquisitionFamilies {
    channel_names: Vec<String>,
    source_names: Vec<String>,
    can_names: Vec<String>,
    acquisition: Acquisition,
}

impl AcquisitionFamilies {
    /// The families of `config`'s channels and sources, counted in `acquisition`.
    pub(crate) fn new(config: &Config, acquisition: Acquisition) -> Self {
        Self {
            channel_names: config.channels.iter().map(|c| c.name.clone()).collect(),
            source_names: config.sources().map(|s| s.name().to_owned()).collect(),
            can_names: config.can_sources.iter().map(|s| s.name.clone()).collect(),
            acquisition,
        }
    }
}

impl Families for AcquisitionFamilies {
    /// Per channel, per source and per CAN source.
    fn write_families(&self, page: &mut Exposition) {
        let snapshots: Vec<_> = self
            .acquisition
            .counters
            .iter()
            .map(|c| c.snapshot())
            .collect();
        type CounterOf = fn(&ChannelCountersSnapshot) -> u64;
        let counters: [(&str, &str, CounterOf); 8] = [
            ("blocks_read", "Blocks or frames decoded", |s| s.blocks_read),
            ("blocks_missed", "Blocks lost, from sequence gaps", |s| {
                s.blocks_missed
            }),
            ("samples", "Samples passed to analysis", |s| s.samples),
            ("timeouts", "Requests without an answer in time", |s| {
                s.timeouts
            }),
            (
                "errors",
                "Transport errors, device exceptions and malformed replies (CAN: frames too short for their signals, failed reads)",
                |s| s.errors,
            ),
            (
                "saturated_samples",
                "Samples at the converter's limits, replaced by gaps",
                |s| s.saturated_samples,
            ),
            (
                "sequence_restarts",
                "Block sequences that went backwards or jumped past the elapsed time (DAQ restarts)",
                |s| s.sequence_restarts,
            ),
            (
                "sequence_stalls",
                "Times the block sequence stood still for 3 block periods while the DAQ answered",
                |s| s.sequence_stalls,
            ),
        ];
        for (name, help, value) in counters {
            let samples = self
                .channel_names
                .iter()
                .zip(&snapshots)
                .map(|(channel, s)| (vec![("channel", channel.as_str())], value(s) as f64));
            page.family(
                &format!("millgate_channel_{name}_total"),
                Kind::Counter,
                &format!("{help}."),
                samples,
            );
        }
        let sources = self
            .source_names
            .iter()
            .zip(&self.acquisition.health)
            .map(|(name, health)| (vec![("source", name.as_str())], health));
        page.family(
            "millgate_source_connects_total",
            Kind::Counter,
            "Successful connections.",
            sources.map(|(labels, health)| (labels, health.connects() as f64)),
        );
        let can: Vec<CanCounts> = self.acquisition.can.iter().map(|c| c.snapshot()).collect();
        type CanOf = fn(&CanCounts) -> f64;
        let per_can_source: [(&str, Kind, &str, CanOf); 14] = [
            ("millgate_can_frames_total", Kind::Counter, "CAN frames received.", |c| c.frames as f64),
            ("millgate_can_decoded_frames_total", Kind::Counter, "CAN data frames decoded into samples.", |c| c.decoded as f64),
            ("millgate_can_unknown_id_frames_total", Kind::Counter, "CAN data frames with an id no channel uses.", |c| c.unknown_id as f64),
            ("millgate_can_bad_length_frames_total", Kind::Counter, "CAN data frames too short for their signals.", |c| c.bad_length as f64),
            ("millgate_can_remote_frames_total", Kind::Counter, "CAN remote frames.", |c| c.remote_frames as f64),
            ("millgate_can_error_frames_total", Kind::Counter, "CAN error frames.", |c| c.error_frames as f64),
            ("millgate_can_error_passive_frames_total", Kind::Counter, "CAN error frames reporting error passive.", |c| c.error_passive as f64),
            ("millgate_can_bus_off_frames_total", Kind::Counter, "CAN error frames reporting bus off.", |c| c.bus_off as f64),
            ("millgate_can_bad_size_reads_total", Kind::Counter, "CAN socket reads neither a classic nor an FD frame.", |c| c.bad_size as f64),
            ("millgate_can_saturated_samples_total", Kind::Counter, "CAN signal values at the end of their raw range (saturated or not available), passed on as gaps.", |c| c.saturated_samples as f64),
            ("millgate_can_kernel_drops_total", Kind::Counter, "CAN frames the kernel dropped because the socket receive queue was full (SO_RXQ_OVFL); each drop marks a gap.", |c| c.kernel_drops as f64),
            ("millgate_can_kernel_timestamps_total", Kind::Counter, "CAN frames that carried a kernel receive timestamp (SO_TIMESTAMPNS); the others are dated on arrival.", |c| c.kernel_timestamps as f64),
            ("millgate_can_receive_latency_seconds_total", Kind::Counter, "Sum of the delays from kernel receive timestamp to the reader handling the frame, s.", |c| c.receive_latency_sum_ns as f64 * 1e-9),
            ("millgate_can_receive_latency_max_seconds", Kind::Gauge, "Largest delay from kernel receive timestamp to the reader handling the frame, s.", |c| c.receive_latency_max_ns as f64 * 1e-9),
        ];
        for (name, kind, help, value) in per_can_source {
            let samples = self
                .can_names
                .iter()
                .zip(&can)
                .map(|(source, counts)| (vec![("source", source.as_str())], value(counts)));
            page.family(name, kind, help, samples);
        }
        page.family(
            "millgate_can_bus_state",
            Kind::Gauge,
            "Last reported bus state: 0 error active, 1 error passive, 2 bus off.",
            self.can_names.iter().zip(&can).map(|(source, c)| {
                (
                    vec![("source", source.as_str())],
                    f64::from(c.bus_state.code()),
                )
            }),
        );
    }
}
