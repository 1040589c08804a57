//! The `canodom` binary: parse the command line, set up logging, run the
//! command (everything else lives in the library, where tests reach it).

use clap::Parser;
use std::io::IsTerminal as _;

/// canodom: fused wheel/steering odometry for car-like vehicles over CAN.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None, after_help = "Start with `canodom demo` (no CAN hardware needed), \
then `canodom <COMMAND> --help`.")]
struct Cli {
    #[command(subcommand)]
    command: canodom::cmd::Command,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    // The demo prints its own table; the daemon's periodic log would bury it.
    let default_level = match cli.command {
        canodom::cmd::Command::Demo(_) => "warn",
        _ => "info",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(format!("{default_level},{}", canodom_ros2::LOG_FILTER))
    });
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    // JSON logs are for the service (journald, collectors); the offline
    // commands' results go to stdout in their own formats.
    match &cli.command {
        canodom::cmd::Command::Run(a) if a.log_format == canodom::cmd::run::LogFormat::Json => {
            builder.json().init();
        }
        _ => builder.init(),
    }
    match cli.command.execute() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // `canodom decode log | head` is normal use, not a failure.
        Err(e)
            if e.downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe) =>
        {
            std::process::ExitCode::SUCCESS
        }
        // The message with its causes, never a backtrace: these are input
        // and environment errors for the user, not bugs (RUST_BACKTRACE=1 is
        // common on developer machines and would bury the one useful line).
        Err(e) => {
            eprintln!("Error: {}", error_text(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error with its causes, each once: many of our error types already
/// write their cause into their own message (`file: reason`), so the cause
/// chain would repeat the OS's reason.
fn error_text(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}
