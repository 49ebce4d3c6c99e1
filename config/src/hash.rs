//! The configuration's hash: SHA-256 of its canonical TOML.

use sha2::{Digest, Sha256};

/// SHA-256 (lower-case hex) of `text`'s canonical TOML: every table's keys sorted,
/// written back by `toml`, so comments, blank lines, key order and how a number or
/// string is spelt do not change it. `text` has passed the syntax check.
pub(crate) fn canonical_hash(text: &str) -> String {
    let table: toml::Table = text.parse().unwrap_or_default();
    let canonical = toml::to_string(&sorted(table)).unwrap_or_default();
    Sha256::digest(canonical.as_bytes())
        .iter()
        .map(|byte| format!("{byte:02x}"))
        .collect()
}

/// `table` with its keys, and those of every table inside it, in sorted order (the
/// order `toml` keeps when it preserves insertion order).
fn sorted(table: toml::Table) -> toml::Table {
    let mut entries: Vec<(String, toml::Value)> = table.into_iter().collect();
    entries.sort_by(|a, b| a.0.cmp(&b.0));
    entries
        .into_iter()
        .map(|(key, value)| (key, sorted_value(value)))
        .collect()
}

fn sorted_value(value: toml::Value) -> toml::Value {
    match value {
        toml::Value::Table(table) => toml::Value::Table(sorted(table)),
        toml::Value::Array(items) => {
            toml::Value::Array(items.into_iter().map(sorted_value).collect())
        }
        scalar => scalar,
    }
}

#[cfg(test)]
mod tests {
    use super::canonical_hash;

    #[test]
    fn comments_layout_and_key_order_do_not_count_values_do() {
        let one = "name = \"F1\"\n[history]\npath = \"h.db\"\nmax_size_mb = 100\n";
        let same = "# the mill\nname = 'F1'\n\n[history]  # kept\nmax_size_mb = 1_00\n\
                    path = \"h.db\"\n";
        let other = "name = \"F1\"\n[history]\npath = \"h.db\"\nmax_size_mb = 101\n";
        let hash = canonical_hash(one);
        assert_eq!(hash.len(), 64);
        assert!(hash
            .bytes()
            .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase()));
        assert_eq!(canonical_hash(same), hash);
        assert_ne!(canonical_hash(other), hash);
    }

    #[test]
    fn the_hash_is_sha256_of_the_canonical_text() {
        // Computed independently: `printf 'name = "F1"\n' | sha256sum`.
        assert_eq!(
            canonical_hash("name='F1'"),
            "9ac98ad7d885c61bbd1a228bb5ed4229e0c3ae285c126dfb3bb2144d275cd859"
        );
    }
}
