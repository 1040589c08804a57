//! Fuzz DBC loading with arbitrary bytes: loading must return Ok or Err, never panic, and a
//! database that loads must decode and re-encode frames of every message without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(db) = canodom_dbc::Database::from_bytes(data, "fuzz.dbc") else {
        return;
    };
    for m in db.messages() {
        for fill in [0x00u8, 0xFF, 0x5A] {
            let frame = vec![fill; m.length()];
            let decoded: Vec<(usize, f64)> = m
                .decode(&frame)
                .unwrap()
                .map(|(s, v)| (s.index(), v))
                .collect();
            let mut out = vec![0u8; m.length()];
            let _ = m.encode_into(decoded, &mut out);
            assert!(m.decode(&frame[..m.length().saturating_sub(1)]).is_err() || m.length() == 0);
        }
        for s in m.signals() {
            let _ = db.signal(&format!("{}.{}", m.name(), s.name()));
        }
    }
});
