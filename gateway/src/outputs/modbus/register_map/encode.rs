//! Encoding the results into the map's words: a pure function of [`Results`].

use millgate_config::layout::encode_value;

use super::layout::slot_on;
use super::{Block, Field, RegisterMap};
use crate::state::catalogue::{self, Figure, Guard, Subject, Value};
use crate::state::results::Results;

impl RegisterMap {
    /// Encode `results` into the whole map.
    pub fn encode(&self, results: &Results) -> Vec<u16> {
        let mut words = vec![0u16; usize::from(self.len)];
        for register in &self.registers {
            let Some(value) = value_of(register.field, results) else {
                continue;
            };
            let (encoded, used) = encode_value(
                value / register.scale,
                register.value_type,
                register.word_order,
            );
            let start = usize::from(register.address);
            words[start..start + used].copy_from_slice(&encoded[..used]);
        }
        words
    }
}

/// Bit i for source i (the first 16) while its flag `index` of [`SOURCE`](crate::state::catalogue::SOURCE)
/// is set.
fn source_bits(results: &Results, index: usize) -> f64 {
    let flag = &catalogue::SOURCE[index];
    let mask = (0..results.sources.len().min(16))
        .filter(|&i| flag.read(&results.source(i)).good() == Some(Value::Bool(true)))
        .fold(0u16, |mask, i| mask | (1 << i));
    f64::from(mask)
}

/// A good figure as a register value: a time as Unix seconds, everything else as its
/// number.
fn register_value(value: Value) -> f64 {
    match value {
        Value::Time(ms) => ms.div_euclid(1000) as f64,
        other => other.as_f64(),
    }
}

/// The flags register of `subject`: every flag figure that is set, at its bit.
fn flags_of<R: Subject>(figures: &[Figure<R>], subject: &R) -> f64 {
    let flags = figures
        .iter()
        .filter_map(|f| match f.guard {
            Guard::FlagBit(bit) => Some((bit, f.read(subject).good())),
            _ => None,
        })
        .filter(|(_, value)| *value == Some(Value::Bool(true)))
        .fold(0u16, |flags, (bit, _)| flags | (1 << bit));
    f64::from(flags)
}

/// The quality register of page `page` of `subject`'s block: the bit of every value
/// figure on that page that is good (and finite).
fn quality_of<R: Subject>(figures: &[Figure<R>], page: u8, subject: &R) -> f64 {
    let mask = figures
        .iter()
        .filter(|figure| slot_on(figure, page).is_some())
        .filter_map(|f| match f.guard {
            Guard::QualityBit(bit) => Some((bit, f.read(subject).good())),
            _ => None,
        })
        .filter(|(_, value)| value.is_some_and(|v| v.as_f64().is_finite()))
        .fold(0u16, |mask, (bit, _)| mask | (1 << bit));
    f64::from(mask)
}

/// The value of a figure register: the good value, else nothing (the words stay 0).
fn figure_of<R: Subject>(figures: &[Figure<R>], index: usize, subject: &R) -> Option<f64> {
    figures[index]
        .read(subject)
        .good()
        .map(register_value)
        .filter(|v| v.is_finite())
}

/// What `field` of a block reads, with its subject and tables.
fn block_value<R: Subject>(field: Field, figures: &[Figure<R>], subject: &R) -> Option<f64> {
    match field {
        Field::Flags(_) => Some(flags_of(figures, subject)),
        Field::Quality(_, page) => Some(quality_of(figures, page, subject)),
        Field::Figure(_, index) => figure_of(figures, index, subject),
        _ => None,
    }
}

fn value_of(field: Field, results: &Results) -> Option<f64> {
    let block = match field {
        Field::SourceBits(index) => return Some(source_bits(results, index)),
        Field::AcknowledgeAlarms
        | Field::ResetWearTrend
        | Field::ResetWear
        | Field::ManualCapture
        | Field::ResetFatigue => return Some(0.0),
        Field::Flags(block) | Field::Quality(block, _) | Field::Figure(block, _) => block,
    };
    match block {
        Block::Gateway => block_value(field, catalogue::GATEWAY, &results.gateway()),
        Block::Driveline(k) => block_value(field, catalogue::DRIVELINE, results.drivelines.get(k)?),
        Block::TandemMill(m) => {
            block_value(field, catalogue::TANDEM_MILL, results.tandem_mills.get(m)?)
        }
        Block::RodMill(k) => block_value(field, catalogue::ROD_MILL, results.rod_mills.get(k)?),
        Block::RodSpan(k, span) => block_value(
            field,
            catalogue::ROD_SPAN,
            &results.rod_mills.get(k)?.published_span(span),
        ),
    }
}
