//! `canodom dbc`: the everyday DBC tools: what a file holds (to fill in
//! `[signals]`), and canodom's own DBC at the configured base id (to decode
//! what the daemon sends with any CAN tool).

use canodom_dbc::{Database, LoadMode};
use canodom_pipeline::config::Config;
use std::io::Write as _;
use std::path::PathBuf;

/// Arguments of `dbc`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:\n  canodom dbc dump car.dbc\n  \
canodom dbc dump car.dbc --json | jq '.messages[] | select(.name == \"WHEEL_SPEEDS\")'\n  \
canodom dbc own --config car.toml --out canodom.dbc\n  \
candump -L can0 | canodom decode --dbc canodom.dbc -")]
pub struct DbcArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: DbcAction,
}

/// One `dbc` subcommand.
#[derive(Debug, clap::Subcommand)]
pub enum DbcAction {
    /// List a DBC file's messages (id, length, sender, cycle time) and signals
    /// (start bit as the DBC writes it, length, byte order, type, scale,
    /// offset, range, unit, value table): what `[signals]` names as MESSAGE.SIGNAL.
    Dump {
        /// The DBC file.
        file: PathBuf,
        /// One JSON document instead of the text listing.
        #[arg(long)]
        json: bool,
        /// Refuse a file with a message that cannot be decoded instead of
        /// listing it as left out.
        #[arg(long)]
        strict: bool,
    },
    /// Write canodom's own DBC (pose, quality, commands, calibration frames)
    /// at the configuration's `[output] base_id`, or at --base-id.
    Own {
        /// The daemon's configuration (for its base id).
        #[arg(long, required_unless_present = "base_id")]
        config: Option<PathBuf>,
        /// The base id instead of the configuration's (e.g. 0x6A0).
        #[arg(long, value_parser = parse_id, conflicts_with = "config")]
        base_id: Option<u32>,
        /// Write here instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// A standard CAN id in hex (`0x6A0`) or decimal.
fn parse_id(s: &str) -> Result<u32, String> {
    let parsed = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => s.parse(),
    };
    parsed.map_err(|_| format!("expected a CAN id such as 0x600, got `{s}`"))
}

/// Runs `dbc`.
///
/// # Errors
/// An unreadable DBC or configuration, a base id canodom's frames do not
/// fit, a write error.
pub fn execute(args: &DbcArgs) -> anyhow::Result<()> {
    match &args.action {
        DbcAction::Dump { file, json, strict } => {
            let mode = if *strict {
                LoadMode::Strict
            } else {
                LoadMode::Tolerant
            };
            let description = Database::from_file_with(file, mode)?.describe();
            let mut out = std::io::stdout().lock();
            if *json {
                serde_json::to_writer_pretty(&mut out, &description)?;
                writeln!(out)?;
            } else {
                write!(out, "{description}")?;
            }
            Ok(())
        }
        DbcAction::Own {
            config,
            base_id,
            out,
        } => {
            let base = match (base_id, config) {
                (Some(raw), _) => canodom_protocol::own_dbc::BaseId::new(*raw, false)?,
                (None, Some(path)) => Config::load(path)?.output.base_id,
                (None, None) => anyhow::bail!("dbc own needs --config FILE or --base-id ID"),
            };
            let text = canodom_protocol::own_dbc::dbc_for_base(base);
            match out {
                Some(path) => std::fs::write(path, text)
                    .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", path.display()))?,
                None => std::io::stdout().lock().write_all(text.as_bytes())?,
            }
            Ok(())
        }
    }
}
