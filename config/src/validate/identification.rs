//! `identification` tables: a machine's nameplate (OPC 40001-1), of the gateway
//! (`[gateway.identification]`), a driveline or a mill.

use std::ops::RangeInclusive;

use crate::raw::RawIdentification;
use crate::{Identification, IdentificationField, IdentificationValue};

use super::Checker;

/// Longest nameplate text, characters (OPC UA sets no limit; HMI screens and
/// asset-management tools cut far shorter texts).
const MAX_TEXT_CHARS: usize = 255;
/// Allowed `year_of_construction`.
const YEAR_RANGE: RangeInclusive<i64> = 1800..=2100;

impl Checker<'_> {
    /// `{key}` (an `identification` table), empty when left out.
    pub(super) fn identification(
        &mut self,
        key: &str,
        raw: Option<&RawIdentification>,
    ) -> Option<Identification> {
        let Some(raw) = raw else {
            return Some(Identification::default());
        };
        let texts = [
            (IdentificationField::Manufacturer, &raw.manufacturer),
            (IdentificationField::ManufacturerUri, &raw.manufacturer_uri),
            (IdentificationField::Model, &raw.model),
            (IdentificationField::ProductCode, &raw.product_code),
            (
                IdentificationField::HardwareRevision,
                &raw.hardware_revision,
            ),
            (IdentificationField::SerialNumber, &raw.serial_number),
            (
                IdentificationField::ProductInstanceUri,
                &raw.product_instance_uri,
            ),
            (IdentificationField::AssetId, &raw.asset_id),
            (IdentificationField::Location, &raw.location),
        ];
        let mut fields = Vec::new();
        let mut valid = true;
        for (field, text) in texts {
            let Some(text) = text else { continue };
            match self.nameplate_text(&format!("{key}.{}", field.key()), field, text) {
                Some(text) => fields.push((field, IdentificationValue::Text(text))),
                None => valid = false,
            }
        }
        if let Some(year) = raw.year_of_construction {
            let field = IdentificationField::YearOfConstruction;
            match self.int_in(&format!("{key}.{}", field.key()), year, YEAR_RANGE, "") {
                Some(year) => fields.push((field, IdentificationValue::Year(year as u16))),
                None => valid = false,
            }
        }
        fields.sort_by_key(|(field, _)| *field);
        valid.then_some(Identification { fields })
    }

    /// A nameplate text: a name of 1..=255 characters, and a URI for the URI fields.
    fn nameplate_text(
        &mut self,
        key: &str,
        field: IdentificationField,
        text: &str,
    ) -> Option<String> {
        let text = self.name(key, text)?;
        let chars = text.chars().count();
        if chars > MAX_TEXT_CHARS {
            self.report.push(
                key,
                format!("{chars} characters are not allowed (must be 1..={MAX_TEXT_CHARS})"),
            );
            return None;
        }
        if field.is_uri() && !is_uri(&text) {
            self.report.push(
                key,
                format!(
                    "\"{text}\" is not allowed (must be a URI, scheme:rest without spaces, \
                     e.g. urn:example:mill:F1 or https://example.com/F1)"
                ),
            );
            return None;
        }
        Some(text)
    }
}

/// Whether `text` is shaped like a URI (RFC 3986): a scheme (a letter, then letters,
/// digits, `+`, `-` or `.`), a colon, and a non-empty rest without spaces.
fn is_uri(text: &str) -> bool {
    let Some((scheme, rest)) = text.split_once(':') else {
        return false;
    };
    let mut scheme_chars = scheme.chars();
    scheme_chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && scheme_chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
        && !rest.is_empty()
        && !rest.contains(char::is_whitespace)
}

#[cfg(test)]
mod tests {
    use super::is_uri;

    #[test]
    fn uris_need_a_scheme_and_no_spaces() {
        assert!(is_uri("urn:example:mill:F1"));
        assert!(is_uri("https://example.com/F1?x=1"));
        assert!(!is_uri("F1"));
        assert!(!is_uri("1http://x"));
        assert!(!is_uri("urn:"));
        assert!(!is_uri("urn:a b"));
    }
}
