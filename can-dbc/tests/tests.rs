//! Integration tests of canodom-dbc, one binary with a module per topic.

// Test helpers outside `#[test]` functions unwrap too: a broken fixture must fail loudly.
#![allow(
    clippy::unwrap_used,
    clippy::too_many_lines,
    clippy::missing_panics_doc,
    clippy::case_sensitive_file_extension_comparisons
)]

mod cantools_diff;
mod corpus;
mod error_paths;
mod issue20;
mod opendbc_packer;
mod properties;
mod rc_car;
pub mod util;
