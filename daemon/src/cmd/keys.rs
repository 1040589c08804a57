//! `canodom keys`: the SecOC key files of each party, derived from one
//! master key (issue #33; the derivation is
//! [`canodom_protocol::secoc_keys`]'s).

use anyhow::Context as _;
use canodom_pipeline::security::{Access, read_secret_file};
use canodom_protocol::secoc_keys::{MasterKey, Party};
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `keys`.
#[derive(Debug, clap::Args)]
pub struct KeysArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: KeysAction,
}

/// One `keys` subcommand.
#[derive(Debug, clap::Subcommand)]
pub enum KeysAction {
    /// Derive the key file of each party from the master key (HKDF-SHA256,
    /// a key per message and direction, bound to the vehicle).
    #[command(after_help = "Example (keep the master key off the vehicle):\n  \
umask 077; od -An -tx1 -N32 /dev/urandom | tr -d ' \\n' > master.key; echo >> master.key\n  \
canodom keys derive --master master.key --vehicle rc-car-7 --out keys/\n  \
# keys/canodom.keys     -> the vehicle computer (/etc/canodom/canodom.keys, LoadCredential=)\n  \
# keys/operator.keys    -> each operator's machine ([security] key_file of canodom calib)\n  \
# keys/param-store.keys -> the parameter-store ECU\n\n\
An operator's file holds only the command keys (odom_cmd, calib_cmd): it cannot sign \
CALIB_PARAMS or CALIB_ACK. Files are written 0600 and never overwritten.")]
    Derive {
        /// The master key file: 32 or 64 hex digits, mode 0600, owned by you.
        #[arg(long)]
        master: PathBuf,
        /// The vehicle's identity (its VIN or fleet name; no spaces): keys of
        /// two vehicles differ, so one's frames are refused by the other.
        #[arg(long)]
        vehicle: String,
        /// Write `canodom.keys`, `operator.keys` and `param-store.keys` into
        /// this folder (created 0700 if missing) instead of printing.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Only this party's file: canodom, operator or param-store.
        #[arg(long, value_parser = parse_party)]
        party: Option<Party>,
    },
}

fn parse_party(s: &str) -> Result<Party, String> {
    Party::from_name(s).ok_or_else(|| format!("`{s}`: expected canodom, operator or param-store"))
}

/// The file name of a party's key file.
pub fn file_name(party: Party) -> String {
    format!("{}.keys", party.name())
}

/// Runs `keys`.
///
/// # Errors
/// An unreadable or malformed master key, a file that exists already.
pub fn execute(args: &KeysArgs) -> anyhow::Result<()> {
    match &args.action {
        KeysAction::Derive {
            master,
            vehicle,
            out,
            party,
        } => derive(master, vehicle, out.as_deref(), *party),
    }
}

fn derive(
    master: &Path,
    vehicle: &str,
    out: Option<&Path>,
    only: Option<Party>,
) -> anyhow::Result<()> {
    let text = read_secret_file(master, Access::OwnerOnly)
        .with_context(|| format!("{}", master.display()))?;
    let master_key = MasterKey::parse(&text).with_context(|| format!("{}", master.display()))?;
    let parties: Vec<Party> = only.map_or_else(|| Party::ALL.to_vec(), |p| vec![p]);
    match out {
        None => {
            let mut stdout = std::io::stdout().lock();
            for p in parties {
                stdout.write_all(master_key.key_file(vehicle, p)?.as_bytes())?;
            }
        }
        Some(dir) => {
            use std::os::unix::fs::{DirBuilderExt as _, OpenOptionsExt as _};
            std::fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(dir)
                .with_context(|| format!("creating {}", dir.display()))?;
            for p in parties {
                let path = dir.join(file_name(p));
                let text = master_key.key_file(vehicle, p)?;
                let mut f = std::fs::OpenOptions::new()
                    .write(true)
                    .create_new(true)
                    .mode(0o600)
                    .custom_flags(libc::O_NOFOLLOW)
                    .open(&path)
                    .with_context(|| {
                        format!(
                            "{}: not written (an existing key file is never overwritten)",
                            path.display()
                        )
                    })?;
                f.write_all(text.as_bytes())?;
                f.sync_all()?;
                println!(
                    "{}: the {}'s keys for vehicle {vehicle}",
                    path.display(),
                    p.name()
                );
            }
        }
    }
    Ok(())
}
