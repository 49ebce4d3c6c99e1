//! A plain-text summary of a validated configuration (what `millgate check` prints).

use std::fmt::Write as _;

use crate::layout::BLOCK_REGISTERS;
use crate::{ChannelSource, Config, ContextTags, OpcUaOutput, Outputs};

/// Lists sources, channels (with where each comes from), drivelines, tandem mills
/// and outputs, one item per line under a heading per section.
///
/// ```
/// let config = millgate_config::from_toml_str(
///     "name = \"Test mill\"",
///     "mill.toml",
///     std::path::Path::new("."),
/// )?;
/// let text = millgate_config::summary(&config);
/// assert!(text.starts_with("Test mill\n"));
/// assert!(text.contains("Channels (0):\n  none\n"));
/// # Ok::<(), millgate_config::ConfigError>(())
/// ```
pub fn summary(config: &Config) -> String {
    let mut text = String::new();
    // Writing to a String cannot fail; the results are ignored on purpose.
    let _ = writeln!(text, "{}", config.name);
    sources(&mut text, config);
    channels(&mut text, config);
    drivelines(&mut text, config);
    tandem_mills(&mut text, config);
    rod_mills(&mut text, config);
    outputs(&mut text, &config.outputs);
    if let Some(slots) = config.outputs.driveline_slots {
        let _ = writeln!(
            text,
            "  register map: {slots} driveline blocks reserved ({} configured; the unused \
             ones read 0)",
            config.drivelines.len()
        );
    }
    history(&mut text, config);
    text
}

/// The Modbus and CAN sources, one a line.
fn sources(text: &mut String, config: &Config) {
    let source_count = config.modbus_sources.len() + config.can_sources.len();
    let _ = writeln!(text, "Sources ({source_count}):");
    for source in &config.modbus_sources {
        let transport = match &source.serial {
            None => format!("Modbus TCP {}", source.address),
            Some(line) => format!(
                "Modbus RTU {} at {} Bd {}, silence {} us,",
                source.address,
                line.baud_rate,
                line.format(),
                line.inter_frame_delay.as_micros()
            ),
        };
        let _ = writeln!(
            text,
            "  {}: {transport} unit {}, poll every {} ms, timeout {} ms",
            source.name,
            source.unit_id,
            source.poll_period.as_millis(),
            source.timeout.as_millis()
        );
    }
    for source in &config.can_sources {
        let _ = writeln!(
            text,
            "  {}: CAN {}, DBC {}",
            source.name,
            source.interface,
            source.dbc.display()
        );
    }
    none_if_empty(text, source_count);
}

/// The channels, one a line, with where each comes from.
fn channels(text: &mut String, config: &Config) {
    let _ = writeln!(text, "Channels ({}):", config.channels.len());
    for channel in &config.channels {
        let origin = channel_origin(config, &channel.source);
        let _ = writeln!(
            text,
            "  {}: {} [{}] at {} Hz, value = raw * {} + {}, from {}",
            channel.name,
            channel.kind.name(),
            channel.unit,
            channel.sample_rate_hz,
            channel.scale,
            channel.offset,
            origin
        );
    }
    none_if_empty(text, config.channels.len());
}

/// Where a channel's values come from: the source, and the register, block or signal.
fn channel_origin(config: &Config, source: &ChannelSource) -> String {
    match source {
        ChannelSource::ModbusBlock {
            source,
            table,
            base,
        } => format!(
            "{} {} registers {}..={} (sample block)",
            config.modbus_sources[*source].name,
            table.name(),
            base,
            u32::from(*base) + u32::from(BLOCK_REGISTERS) - 1
        ),
        ChannelSource::ModbusValue {
            source,
            table,
            address,
            value_type,
            word_order,
        } => format!(
            "{} {} register {} ({} {})",
            config.modbus_sources[*source].name,
            table.name(),
            address,
            value_type.name(),
            word_order.name()
        ),
        ChannelSource::ModbusText {
            source,
            table,
            address,
            registers,
            byte_order,
        } => format!(
            "{} {} registers {}..={} (ascii {})",
            config.modbus_sources[*source].name,
            table.name(),
            address,
            u32::from(*address) + u32::from(*registers) - 1,
            byte_order.name()
        ),
        ChannelSource::Can {
            source,
            message,
            signal,
            signal_layout,
        } => format!(
            "{} {} {} (id {:#x}{})",
            config.can_sources[*source].name,
            message,
            signal,
            signal_layout.frame_id,
            if signal_layout.extended {
                ", extended"
            } else {
                ""
            }
        ),
    }
}

/// The drivelines, one a line: torque, bite detection, thresholds, model.
fn drivelines(text: &mut String, config: &Config) {
    let _ = writeln!(text, "Drivelines ({}):", config.drivelines.len());
    for driveline in &config.drivelines {
        let trigger = match driveline.metal_in_stand {
            Some(index) => format!(", metal in stand {}", config.channels[index].name),
            None => String::new(),
        };
        let _ = write!(
            text,
            "  {}: torque {}{}, bite at a rise > {} kN*m (capture {} s before, {} s after), \
             TAF warning {} alarm {}",
            driveline.name,
            config.channels[driveline.torque].name,
            trigger,
            driveline.bite.threshold_knm,
            driveline.bite.pre_trigger_s,
            driveline.bite.post_trigger_s,
            driveline.thresholds.taf_warning,
            driveline.thresholds.taf_alarm
        );
        if let Some(model) = &driveline.model {
            let _ = write!(
                text,
                ", model {} (gap warning {} mrad, alarm {} mrad, forecast over {} days, \
                 growth from bites over {} s apart)",
                model.display(),
                driveline.thresholds.gap_warning_mrad,
                driveline.thresholds.gap_alarm_mrad,
                driveline.wear.horizon_days,
                driveline.wear.growth_span_s
            );
        }
        text.push('\n');
        context_line(text, config, &driveline.context);
        if let Some((low, high)) = driveline.pool_speed_range_mpm {
            let _ = writeln!(
                text,
                "    wear trend pools bites rolled at {low} to {high} m/min (and in the rolling state)"
            );
        }
    }
    none_if_empty(text, config.drivelines.len());
}

/// The context tags of a mill or driveline, a line under it; listed only when
/// configured, so summaries without stay as they were.
fn context_line(text: &mut String, config: &Config, context: &ContextTags) {
    let mut tags: Vec<String> = context
        .tags()
        .map(|(key, channel)| format!("{key} <- {}", config.channels[channel].name))
        .collect();
    if !context.weld_stands.is_empty() {
        let names: Vec<&str> = context
            .weld_stands
            .iter()
            .map(|&channel| config.channels[channel].name.as_str())
            .collect();
        tags.insert(0, format!("weld_stands <- {}", names.join(", ")));
    }
    if tags.is_empty() {
        return;
    }
    let products = if context.products.is_empty() {
        String::new()
    } else {
        let codes: Vec<String> = context.products.iter().map(u32::to_string).collect();
        format!("; products {}", codes.join(", "))
    };
    let _ = writeln!(
        text,
        "    context from the PLC: {}{products}",
        tags.join(", ")
    );
}

/// The tandem mills, two lines each: stands and band, then the alarm.
fn tandem_mills(text: &mut String, config: &Config) {
    let _ = writeln!(text, "Tandem mills ({}):", config.tandem_mills.len());
    for mill in &config.tandem_mills {
        let stands: Vec<_> = mill
            .stands
            .iter()
            .map(|&index| config.channels[index].name.as_str())
            .collect();
        let _ = writeln!(
            text,
            "  {}: {} stands ({}), chatter band {}..{} Hz, window {} s, K_max {}",
            mill.name,
            stands.len(),
            stands.join(", "),
            mill.chatter_band_hz.0,
            mill.chatter_band_hz.1,
            mill.window_s,
            mill.k_max
        );
        let detector = match mill.detector {
            crate::ChatterDetectorKind::BandGain => format!(
                "band gain (reference band {}..{} Hz, window {} s, thresholds {:?})",
                mill.reference_band_hz.0,
                mill.reference_band_hz.1,
                mill.gain_window_s,
                mill.gain_thresholds
            ),
            crate::ChatterDetectorKind::Paper => "paper (sigma_n and K_mean)".to_owned(),
        };
        let _ = writeln!(
            text,
            "    alarm: {detector}; slow-down released below {} for {} s",
            mill.slow_down_release, mill.slow_down_hold_s
        );
        for (g, group) in mill.product_groups.iter().enumerate() {
            let _ = writeln!(
                text,
                "    product group {}: products {:?}, thresholds {:?} (other products: the \
                 mill's)",
                group.name,
                group.products,
                mill.thresholds_of(Some(g))
            );
        }
        context_line(text, config, &mill.context);
        if mill.context.has_weld_bits() {
            let _ = writeln!(
                text,
                "    weld hold: the alarm needs {} times its level during a weld and {} s after",
                mill.weld_alarm_factor, mill.weld_settle_s
            );
        }
    }
    none_if_empty(text, config.tandem_mills.len());
}

/// The rod mills, one a line (the heading only when there is one).
fn rod_mills(text: &mut String, config: &Config) {
    // Listed only when present, so summaries of other mills stay as they were.
    if !config.rod_mills.is_empty() {
        let _ = writeln!(text, "Rod mills ({}):", config.rod_mills.len());
    }
    for mill in &config.rod_mills {
        let channel = |index: usize| config.channels[index].name.as_str();
        let _ = writeln!(
            text,
            "  {}: mill {}, schedule {}, configuration from {} ({}), pass from {}, \
             finishing speed from {}, temperature from {}, near tongue < {} m/s, \
             hysteresis {} m/s",
            mill.name,
            mill.mill.display(),
            mill.schedule.display(),
            channel(mill.configuration),
            mill.configurations.join(", "),
            channel(mill.pass),
            channel(mill.finishing_speed),
            mill.temperature.map_or("the schedule", channel),
            mill.near_tongue_m_s,
            mill.hysteresis_m_s
        );
    }
}

/// The outputs configured, one a line.
fn outputs(text: &mut String, outputs: &Outputs) {
    let output_count = usize::from(outputs.plc.is_some())
        + usize::from(outputs.server.is_some())
        + usize::from(outputs.metrics.is_some())
        + usize::from(outputs.mqtt.is_some())
        + usize::from(outputs.web.is_some())
        + usize::from(outputs.opcua.is_some());
    let _ = writeln!(text, "Outputs ({output_count}):");
    plc_and_servers(text, outputs);
    if let Some(opcua) = &outputs.opcua {
        opcua_line(text, opcua);
    }
    none_if_empty(text, output_count);
}

/// The PLC, the Modbus server, `/metrics`, the maintenance page and Sparkplug B.
fn plc_and_servers(text: &mut String, outputs: &Outputs) {
    if let Some(plc) = &outputs.plc {
        let _ = writeln!(
            text,
            "  PLC: {} unit {}, holding registers from {}, write every {} ms, timeout {} ms{}{}",
            plc.address,
            plc.unit_id,
            plc.register_base,
            plc.write_period.as_millis(),
            plc.timeout.as_millis(),
            if plc.extension_blocks {
                ", with the extension blocks"
            } else {
                ""
            },
            match plc.requests_in_flight {
                1 => String::new(),
                n => format!(", {n} requests in flight"),
            }
        );
    }
    if let Some(server) = &outputs.server {
        let _ = writeln!(
            text,
            "  Modbus server: listen on {} unit {}, at most {} clients ({} per address), idle \
             timeout {} ms, commands from {}",
            server.bind,
            server.unit_id,
            server.max_connections,
            server.max_connections_per_peer,
            server.idle_timeout.as_millis(),
            if server.allow_remote_commands {
                "any host"
            } else {
                "loopback clients only"
            }
        );
    }
    if let Some(metrics) = &outputs.metrics {
        let _ = writeln!(text, "  Metrics: http://{}/metrics", metrics.bind);
    }
    if let Some(web) = &outputs.web {
        let _ = writeln!(
            text,
            "  Maintenance page: http://{}/, at most {} connections, headers within {} ms, \
             answers within {} ms",
            web.bind,
            web.max_connections,
            web.header_timeout.as_millis(),
            web.request_timeout.as_millis()
        );
    }
    if let Some(mqtt) = &outputs.mqtt {
        let servers = match &mqtt.brokers[..] {
            [broker] => format!("broker {broker}"),
            brokers => format!("brokers {} (failover in this order)", brokers.join(", ")),
        };
        let _ = writeln!(
            text,
            "  Sparkplug B: {servers} as client {}, edge node {}/{}, keep-alive {} s",
            mqtt.client_id,
            mqtt.group_id,
            mqtt.node_id,
            mqtt.keep_alive.as_secs()
        );
    }
}

/// The OPC UA server: endpoint, security, users, limits, certificates, commands.
fn opcua_line(text: &mut String, opcua: &OpcUaOutput) {
    let modes: Vec<_> = opcua.security_modes.iter().map(|m| m.name()).collect();
    let _ = writeln!(
        text,
        "  OPC UA server: {} (listen on {}), security {}, {}{} user(s), at most {} \
         connections, {} sessions ({} per client address), {} subscriptions per session, {} \
         monitored items per subscription; certificates in {}; acknowledge from {}",
        opcua.endpoint_url(),
        opcua.bind,
        modes.join(", "),
        if opcua.anonymous {
            "anonymous and "
        } else {
            ""
        },
        opcua.users.len(),
        opcua.max_connections,
        opcua.max_sessions,
        opcua.max_sessions_per_peer,
        opcua.max_subscriptions_per_session,
        opcua.max_monitored_items_per_subscription,
        opcua.pki_dir.display(),
        if opcua.allow_remote_commands {
            "loopback clients and signed-in users on any host"
        } else {
            "loopback clients only"
        }
    );
}

/// The history file (or none) and the cache folder.
fn history(text: &mut String, config: &Config) {
    match &config.history {
        Some(history) => {
            let _ = writeln!(
                text,
                "History: {}, events kept {} days, at most {} MiB",
                history.path.display(),
                history.retention_days,
                history.max_size_mb
            );
        }
        None => text.push_str("History: none\n"),
    }
    if let Some(cache) = &config.cache_dir {
        let _ = writeln!(text, "Cache: {}", cache.display());
    }
}

fn none_if_empty(text: &mut String, count: usize) {
    if count == 0 {
        text.push_str("  none\n");
    }
}
