//! What the log-reader tests share.

use canodom_can::any_log::AnyLogReader;
use canodom_can::candump::{ReadError, format_frame};

/// (µs, channel, candump frame text) of every record `reader` reads.
pub fn records(mut reader: AnyLogReader<'_>) -> Result<Vec<(u64, String, String)>, ReadError> {
    let mut out = Vec::new();
    while let Some(r) = reader.next_record()? {
        let mut text = Vec::new();
        format_frame(&mut text, &r.frame);
        out.push((
            r.timestamp.as_micros(),
            r.iface.to_owned(),
            String::from_utf8_lossy(&text).into_owned(),
        ));
    }
    Ok(out)
}
