//! `canodom decode`: a candump log to JSON lines, one object per decoded
//! frame, hand-written into one reused buffer (no per-frame allocation).

use anyhow::Context as _;
use canodom_can::candump::ReadError;
use canodom_can::frame::FrameKind;
use canodom_dbc::{Database, Value};
use canodom_report::float_text::push_f64;
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `decode`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom decode --dbc rc_car.dbc drive.log | head\n  \
candump -L can0 | canodom decode --dbc car.dbc - --all\n\n\
Output, one line per frame:\n  {\"t\": 1700000000.123456, \"iface\": \"vcan0\", \"id\": 256, \"extended\": false, \
\"name\": \"WHEEL_ENC_REAR\", \"signals\": {\"RL_TICKS\": 1200, ...}}\n\
Only the signals present for a multiplexed frame's mux value are printed; NaN and infinite values are null.\n\n\
Frames: classic CAN (`123#11223344`, at most 8 data bytes) and CAN FD (`123##<flags><data>`, \
`##` in candump -L, at most 64 bytes) are both decoded. A classic line with more than 8 data \
bytes is not a frame candump writes: it is reported as a malformed line (too_long) and skipped, \
or ends decode under --strict. A frame shorter than its message's DBC length is skipped as \
undecodable; bytes beyond that length are ignored.\n\n\
Names and values: messages and signals are named as cantools names them, by the \
SystemMessageLongSymbol / SystemSignalLongSymbol attributes where the DBC has them. A signal \
with an integer raw value and whole factor and offset is printed as an exact integer, also \
above 2^53 (JSON carries it; read it with an arbitrary-precision parser); other values as the \
shortest decimal that reads back as the same f64.\n\n\
A DBC message that cannot be decoded (a signal past its end, ...) is left out with a warning \
on stderr and its frames count as unknown ids; --strict refuses the DBC instead."
)]
pub struct DecodeArgs {
    /// The DBC file.
    #[arg(long)]
    pub dbc: PathBuf,
    /// The CAN log: candump (`-L` or plain), Vector ASC or BLF, each also
    /// `.gz` or `.zst` compressed, told apart by content; `-` or nothing
    /// reads standard input.
    #[arg(default_value = "-")]
    pub log: PathBuf,
    /// Also print frames of ids the DBC does not know, with "name": null.
    #[arg(long)]
    pub all: bool,
    /// A malformed log line is fatal instead of reported and skipped, and a
    /// DBC message that cannot be decoded refuses the DBC instead of being
    /// left out with a warning.
    #[arg(long)]
    pub strict: bool,
    /// Only the frames of this interface (a log may hold several buses).
    #[arg(long)]
    pub interface: Option<String>,
}

/// Counts of what `decode` did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecodeCounts {
    /// Frames read from the log (of the chosen interface).
    pub frames: u64,
    /// Frames printed.
    pub printed: u64,
    /// Frames of unknown ids skipped.
    pub unknown: u64,
    /// Frames too short for their message, or remote/error frames, skipped.
    pub undecodable: u64,
    /// Malformed lines skipped.
    pub malformed: u64,
    /// The same by reason.
    pub malformed_by_reason: canodom_can::candump::MalformedCounts,
}

/// Runs `decode` with standard output.
///
/// # Errors
/// Unreadable DBC or log, a malformed line under `--strict`, a write error.
pub fn execute(args: &DecodeArgs) -> anyhow::Result<()> {
    let db = Database::from_file(&args.dbc)?;
    super::dbc_warnings(&db, args.strict)?;
    let mut input = super::open_input(&args.log, "decode")?;
    let stdout = std::io::stdout().lock();
    let mut out = std::io::BufWriter::with_capacity(1 << 16, stdout);
    let counts = decode(&db, &mut input, &mut out, args, &mut std::io::stderr())?;
    out.flush()?;
    input.finish();
    let mut malformed = String::new();
    for (reason, n) in counts.malformed_by_reason.nonzero() {
        let _ = write!(malformed, " {reason}={n}");
    }
    eprintln!(
        "decode: {} frames printed, {} of unknown ids skipped, {} undecodable, {} malformed lines{malformed}",
        counts.printed, counts.unknown, counts.undecodable, counts.malformed
    );
    Ok(())
}

/// Decodes `input` into `out`; reports malformed lines on `diag`.
///
/// # Errors
/// I/O, or a malformed line under `--strict`.
pub fn decode(
    db: &Database,
    input: impl std::io::BufRead,
    out: &mut impl Write,
    args: &DecodeArgs,
    diag: &mut impl Write,
) -> anyhow::Result<DecodeCounts> {
    let mut reader = super::log_reader(input, args.interface.as_deref(), false)
        .with_context(|| args.log.display().to_string())?;
    // Plain candump output has no time: its frames print `"t": null`.
    let timed = reader.has_time();
    let mut counts = DecodeCounts::default();
    let mut line = Vec::with_capacity(512);
    loop {
        let record = match reader.next_record() {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(ReadError::Malformed(m)) => {
                if args.strict {
                    anyhow::bail!("{}: {m}", args.log.display());
                }
                counts.malformed += 1;
                counts.malformed_by_reason.add(m.reason);
                writeln!(diag, "{}: {m}; skipped", args.log.display())?;
                continue;
            }
            Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => {
                return Err(anyhow::Error::new(e).context(args.log.display().to_string()));
            }
        };
        counts.frames += 1;
        let frame = record.frame;
        let (raw, extended) = (frame.id().raw(), frame.id().is_extended());
        let message = db.message_by_id(frame.id());
        if message.is_none() && !args.all {
            counts.unknown += 1;
            continue;
        }
        if !matches!(frame.kind(), FrameKind::Data { .. } | FrameKind::Fd { .. }) {
            counts.undecodable += 1;
            continue;
        }
        line.clear();
        line.extend_from_slice(b"{\"t\": ");
        if timed {
            super::write_timestamp(&mut line, record.timestamp);
        } else {
            line.extend_from_slice(b"null");
        }
        line.extend_from_slice(b", \"iface\": ");
        write_json_str(&mut line, record.iface);
        line.extend_from_slice(b", \"id\": ");
        line.extend_from_slice(itoa::Buffer::new().format(raw).as_bytes());
        line.extend_from_slice(if extended {
            b", \"extended\": true, \"name\": "
        } else {
            b", \"extended\": false, \"name\": "
        });
        match message {
            None => {
                counts.unknown += 1;
                line.extend_from_slice(b"null, \"signals\": {}}\n");
            }
            Some(m) => {
                write_json_str(&mut line, m.name());
                line.extend_from_slice(b", \"signals\": {");
                let mut first = true;
                let decoded = m.decode_each_value(frame.data(), |s, v| {
                    if !first {
                        line.extend_from_slice(b", ");
                    }
                    first = false;
                    write_json_str(&mut line, s.name());
                    line.extend_from_slice(b": ");
                    write_json_value(&mut line, v);
                });
                if decoded.is_err() {
                    counts.undecodable += 1;
                    continue;
                }
                line.extend_from_slice(b"}}\n");
            }
        }
        out.write_all(&line)?;
        counts.printed += 1;
    }
    super::check_log_read(
        "decode",
        &args.log,
        &super::LogSeen::of(&reader, counts.frames, counts.malformed),
        args.interface.as_deref(),
    )?;
    if counts.unknown == counts.frames && !args.all {
        anyhow::bail!(
            "{}: none of its {} frames has an id of {}: is this the vehicle's DBC? \
             (`canodom dbc dump {}` lists its ids; --all prints every frame anyway)",
            args.log.display(),
            counts.frames,
            db.source_name(),
            db.source_name()
        );
    }
    Ok(counts)
}

/// A JSON number, as `{}` writes it (through [`push_f64`], which is
/// byte-identical and several times cheaper); NaN and infinities (not
/// representable) as `null`.
pub fn write_json_number(out: &mut Vec<u8>, v: f64) {
    if v.is_finite() {
        push_f64(out, v);
    } else {
        out.extend_from_slice(b"null");
    }
}

/// A decoded value as a JSON number: an integer exactly, at any size (an
/// `f64` would print `3791054832379806569` as `3791054832379806700`), a float
/// as [`write_json_number`] writes it.
pub fn write_json_value(out: &mut Vec<u8>, v: Value) {
    match v {
        Value::Integer(i) => out.extend_from_slice(itoa::Buffer::new().format(i).as_bytes()),
        Value::Float(f) => write_json_number(out, f),
    }
}

/// A JSON string with the escapes RFC 8259 requires.
pub fn write_json_str(out: &mut Vec<u8>, s: &str) {
    out.push(b'"');
    for &b in s.as_bytes() {
        match b {
            b'"' => out.extend_from_slice(b"\\\""),
            b'\\' => out.extend_from_slice(b"\\\\"),
            b'\n' => out.extend_from_slice(b"\\n"),
            b'\r' => out.extend_from_slice(b"\\r"),
            b'\t' => out.extend_from_slice(b"\\t"),
            0..=0x1F => {
                let _ = write!(out, "\\u{b:04x}");
            }
            _ => out.push(b),
        }
    }
    out.push(b'"');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_strings_are_escaped_and_parse_back() {
        let mut out = Vec::new();
        write_json_str(&mut out, "a\"b\\c\n\u{1}é");
        let s = String::from_utf8(out).unwrap();
        let back: String = serde_json::from_str(&s).unwrap();
        assert_eq!(back, "a\"b\\c\n\u{1}é");
    }

    #[test]
    fn numbers_are_json() {
        for v in [1.5, -0.0, 100.0, 1e-7, 1e21, -67.67] {
            let mut out = Vec::new();
            write_json_number(&mut out, v);
            let back: f64 = serde_json::from_slice(&out).unwrap();
            assert_eq!(back, v);
        }
        let mut out = Vec::new();
        write_json_number(&mut out, f64::NAN);
        assert_eq!(out, b"null");
    }

    #[test]
    fn integers_are_exact_beyond_2_pow_53() {
        for (v, text) in [
            (
                Value::Integer(3_791_054_832_379_806_569),
                "3791054832379806569",
            ),
            (
                Value::Integer(-9_223_372_036_854_775_807),
                "-9223372036854775807",
            ),
            (Value::Integer(1200), "1200"),
            (Value::Float(1200.0), "1200"),
            (Value::Float(-67.67), "-67.67"),
        ] {
            let mut out = Vec::new();
            write_json_value(&mut out, v);
            assert_eq!(String::from_utf8(out).unwrap(), text);
        }
    }
}
