//! Subcommands whose issue has not landed yet.

use std::process::ExitCode;

/// Accepts anything, so the message below is what the user sees.
#[derive(clap::Args)]
pub struct Args {
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, hide = true)]
    rest: Vec<String>,
}

pub fn run(stage: &str, issue: u32, _args: Args) -> anyhow::Result<ExitCode> {
    eprintln!("photonkit {stage}: not implemented yet (tracked in issue #{issue})");
    Ok(ExitCode::from(2))
}
