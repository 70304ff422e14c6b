//! Config edits for the tests, included by each test file that edits a config
//! (`#[path = ".../tests/config_edit.rs"] mod config_edit;`).

/// `text` (a config) with each edit's first `from` replaced by its `to`. A `from` that is not
/// there fails the test: replaced silently, the run would be another one than the test names
/// (the default config's wording changed, and the test ran the default).
pub fn edited(text: &str, edits: &[(&str, &str)]) -> String {
    let mut text = text.to_string();
    for (from, to) in edits {
        assert!(text.contains(from), "`{from}` not in the config:\n{text}");
        text = text.replacen(from, to, 1);
    }
    text
}
