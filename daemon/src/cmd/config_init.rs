//! `canodom config init`: a ready configuration for a car platform opendbc
//! knows (issue #32), with the platform's DBC (carried in the repository,
//! `data/dbc`, MIT, © comma.ai) written beside it.
//!
//! Each platform's configuration is its example in `daemon/examples/` (the
//! tests replay simulated drives from exactly these files): the signals,
//! signs and units as opendbc's `car/<maker>/carstate.py` reads them, the
//! wheelbase and steering ratio from its `values.py`, the treads and wheel
//! diameter typical values to check.

use std::io::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `config`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:\n  canodom config init --list\n  \
canodom config init --car vw_mqb --out car.toml     # writes car.toml and opendbc_vw_mqb.dbc beside it\n  \
canodom replay --config car.toml drive.log --out pose.csv")]
pub struct ConfigArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: ConfigAction,
}

/// One `config` subcommand.
#[derive(Debug, clap::Subcommand)]
pub enum ConfigAction {
    /// Write a ready configuration for a car platform, and its DBC beside
    /// it; or list the platforms (--list).
    Init {
        /// The platform (see --list).
        #[arg(long, required_unless_present = "list", conflicts_with = "list")]
        car: Option<String>,
        /// The configuration file to write (refused if it exists); the DBC
        /// goes into the same folder.
        #[arg(long, required_unless_present = "list")]
        out: Option<PathBuf>,
        /// The CAN interface to put in the configuration.
        #[arg(long, default_value = "can0")]
        interface: String,
        /// List the platforms and what each provides.
        #[arg(long)]
        list: bool,
    },
}

use canodom_cars::refusal;
pub use canodom_cars::{PLATFORMS, Platform, platform};

/// Writes `platform`'s configuration to `out` and its DBC beside it.
///
/// # Errors
/// `out` exists, a different file is where the DBC goes, or a write failed.
pub fn write(platform: &Platform, out: &Path, interface: &str) -> anyhow::Result<PathBuf> {
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let dbc = dir.join(platform.dbc_file);
    match std::fs::read_to_string(&dbc) {
        Ok(text) if text == platform.dbc_text => {}
        Ok(_) => anyhow::bail!(
            "{}: a different file is already there; the configuration needs opendbc's {} (move it away)",
            dbc.display(),
            platform.dbc_file
        ),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::write(&dbc, platform.dbc_text)
                .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", dbc.display()))?;
        }
        Err(e) => anyhow::bail!("{}: cannot read: {e}", dbc.display()),
    }
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(out)
        .map_err(|e| {
            anyhow::anyhow!(
                "{}: cannot create (an existing file is kept): {e}",
                out.display()
            )
        })?;
    file.write_all(platform.config_text(interface).as_bytes())
        .and_then(|()| file.sync_all())
        .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", out.display()))?;
    Ok(dbc)
}

/// Runs `config`.
///
/// # Errors
/// An unknown platform, or a file that cannot be written.
pub fn execute(args: &ConfigArgs) -> anyhow::Result<()> {
    let ConfigAction::Init {
        car,
        out,
        interface,
        list,
    } = &args.action;
    if *list {
        let mut stdout = std::io::stdout().lock();
        for p in PLATFORMS {
            writeln!(
                stdout,
                "{:<14} {}\n               reads: {}\n               DBC: {}\n               also: {}",
                p.name,
                p.cars,
                p.provides,
                p.dbc_file,
                p.aliases.join(", ")
            )?;
        }
        writeln!(stdout, "\n{}", canodom_cars::LIST_FOOTER)?;
        return Ok(());
    }
    let (Some(car), Some(out)) = (car, out) else {
        anyhow::bail!("--car PLATFORM and --out FILE are needed (or --list)");
    };
    let Some(p) = platform(car) else {
        anyhow::bail!("{}", refusal(car));
    };
    let dbc = write(p, out, interface)?;
    // What was written loads: the same validation `run` does.
    canodom_pipeline::config::Config::load(out)?;
    println!(
        "wrote {} and {}: check the [vehicle] values, then `canodom replay --config {} LOG --out pose.csv`",
        out.display(),
        dbc.display(),
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_platform_writes_a_configuration_that_loads() {
        let dir = std::env::temp_dir().join(format!("canodom-config-init-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for p in PLATFORMS {
            let out = dir.join(format!("{}.toml", p.name));
            write(p, &out, "vcan0").unwrap();
            let c = canodom_pipeline::config::Config::load(&out).unwrap();
            assert_eq!(c.interface, "vcan0");
            assert!(
                std::fs::read_to_string(&out)
                    .unwrap()
                    .contains("check these")
            );
            // Never overwritten.
            let e = write(p, &out, "vcan0").unwrap_err().to_string();
            assert!(e.contains("cannot create"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
