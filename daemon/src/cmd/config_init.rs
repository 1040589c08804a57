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

/// A platform `config init` knows.
#[derive(Debug, Clone, Copy)]
pub struct Platform {
    /// The name `--car` takes.
    pub name: &'static str,
    /// The cars it covers.
    pub cars: &'static str,
    /// What the configuration reads.
    pub provides: &'static str,
    /// The DBC's file name, written beside the configuration.
    pub dbc_file: &'static str,
    dbc_text: &'static str,
    example: &'static str,
}

/// Every platform, in `--list` order.
pub const PLATFORMS: &[Platform] = &[
    Platform {
        name: "honda",
        cars: "Honda Civic 2016-18 and other Nidec Hondas with this bus",
        provides: "WHEEL_SPEEDS (4 kph magnitudes) signed by GEARBOX_AUTO gear, STEERING_SENSORS angle; Honda checksums and counter",
        dbc_file: "opendbc_honda_civic_touring_2016_can.dbc",
        dbc_text: include_str!("../../../data/dbc/opendbc_honda_civic_touring_2016_can.dbc"),
        example: include_str!("../../examples/honda.toml"),
    },
    Platform {
        name: "toyota",
        cars: "Toyota / Lexus with the 2017 powertrain bus (RAV4, Corolla, Camry, Prius, ...)",
        provides: "WHEEL_SPEEDS (4 signed km/h), STEER_ANGLE_SENSOR (angle + fraction); no counters or checksums on these",
        dbc_file: "opendbc_toyota_2017.dbc",
        dbc_text: include_str!("../../../data/dbc/opendbc_toyota_2017.dbc"),
        example: include_str!("../../examples/toyota.toml"),
    },
    Platform {
        name: "vw_mqb",
        cars: "VW MQB (Golf 7, Passat B8, Tiguan, Audi A3, Skoda Octavia, ...)",
        provides: "ESP_19 (4 km/h magnitudes) signed by Gateway_73 gear, LWI_01 angle + sign bit, ESP_02 yaw rate + sign bit; VW CRC and counters",
        dbc_file: "opendbc_vw_mqb.dbc",
        dbc_text: include_str!("../../../data/dbc/opendbc_vw_mqb.dbc"),
        example: include_str!("../../examples/vw_mqb.toml"),
    },
];

/// The platform named `name`.
pub fn platform(name: &str) -> Option<&'static Platform> {
    PLATFORMS.iter().find(|p| p.name == name)
}

impl Platform {
    /// The configuration text: the example with the DBC beside it and the
    /// given interface, headed by what to check.
    pub fn config_text(&self, interface: &str) -> String {
        use std::fmt::Write as _;
        let mut out = format!(
            "# Written by `canodom config init --car {}`: {}.\n\
             # CHECK THESE before trusting the pose: the [vehicle] values are the\n\
             # platform's typical ones (wheelbase and steering ratio from opendbc's\n\
             # values.py; treads and wheel diameter typical) -- measure your car or\n\
             # calibrate (`canodom calibrate`, README \"Calibrate it\").\n\n",
            self.name, self.cars
        );
        for line in self.example.lines() {
            if line.starts_with("dbc = ") {
                let _ = writeln!(out, "dbc = \"{}\"", self.dbc_file);
            } else if line.starts_with("interface = ") {
                let _ = writeln!(out, "interface = {interface:?}");
            } else if line == "[vehicle]" {
                out.push_str("[vehicle]                        # check these\n");
            } else {
                out.push_str(line);
                out.push('\n');
            }
        }
        out
    }

    /// The DBC's text.
    pub fn dbc_text(&self) -> &'static str {
        self.dbc_text
    }
}

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
                "{:<8} {}\n         reads: {}\n         DBC: {}",
                p.name, p.cars, p.provides, p.dbc_file
            )?;
        }
        return Ok(());
    }
    let (Some(car), Some(out)) = (car, out) else {
        anyhow::bail!("--car PLATFORM and --out FILE are needed (or --list)");
    };
    let Some(p) = platform(car) else {
        let names: Vec<&str> = PLATFORMS.iter().map(|p| p.name).collect();
        anyhow::bail!(
            "unknown platform `{car}`: one of {} (canodom config init --list)",
            names.join(", ")
        );
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
