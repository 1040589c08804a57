//! The canodom daemon (filled by the daemon issue).
