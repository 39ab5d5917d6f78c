//! `photonkit merge`: join the shards of one trace.

use std::process::ExitCode;

use photonkit::format::{Output, PhotonMap};

/// Join the shards written by `photonkit trace --shard i/n` into one photon map.
///
/// Give every shard of one trace (same scene, seed and --photons), in any order. The result
/// holds the same photons, in the same order and with the same flux, as a single run of the
/// whole trace; with SOURCE_DATE_EPOCH set for the runs it is the same file byte for byte.
#[derive(clap::Args)]
pub struct Args {
    /// The shard files.
    #[arg(required = true, value_name = "SHARD")]
    shards: Vec<String>,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let maps = a.shards.iter().map(|s| PhotonMap::open(s)).collect::<Result<Vec<_>, _>>()?;
    super::refuse_input_as_output(&a.output)?;
    let n = photonkit::trace::merge(&maps, Output::parse(&a.output))?;
    super::note!("photonkit merge: {} shards, {n} photons", maps.len());
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}
