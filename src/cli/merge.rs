//! `photonkit merge`: join the shards of one trace, or the tile parts of one detection.

use std::process::ExitCode;

use anyhow::Context;
use photonkit::format::{Output, PhotonMap};

/// Join the shards written by `photonkit trace --shard i/n` into one photon map, or, with
/// `--map`, the tile parts written by `photonkit detect MAP --tile i/n` into MAP detected (or
/// those of `photonkit relax MAP --tile i/n` into MAP relaxed).
///
/// Shards: give every shard of one trace (same scene, seed and --photons), in any order. The
/// result holds the same photons, in the same order and with the same flux, as a single run of
/// the whole trace; with SOURCE_DATE_EPOCH set for the runs it is the same file byte for byte.
///
/// Tile parts: give every part of one detection of MAP (same parameters and tile count), in any
/// order. The result is the map `photonkit detect MAP -o OUT` writes with the same parameters;
/// with SOURCE_DATE_EPOCH set for the runs, byte for byte (docs/tiles.md).
#[derive(clap::Args)]
pub struct Args {
    /// The shard files, or with --map the tile parts.
    #[arg(required = true, value_name = "SHARD")]
    shards: Vec<String>,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
    /// The map the tile parts were detected or relaxed from: merge the tile parts onto it.
    #[arg(long, value_name = "MAP")]
    map: Option<String>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let maps = a.shards.iter().map(|s| PhotonMap::open(s)).collect::<Result<Vec<_>, _>>()?;
    if let Some(source) = &a.map {
        let source = PhotonMap::open(source)?;
        super::refuse_input_as_output(&a.output)?;
        let parts: Vec<_> = maps.iter().map(|m| m.view()).collect();
        if parts.first().is_some_and(photonkit::relax::part::is_relax_part) {
            let (table, r) = photonkit::relax::merge_parts(&source.view(), &parts)?;
            table.write(Output::parse(&a.output)).context("writing the relaxed map")?;
            super::note!(
                "photonkit merge: {} relax tile parts, {} photons, {} iterations",
                maps.len(),
                r.positions.len(),
                r.measures.len()
            );
            super::print_record(&a.output)?;
            return Ok(ExitCode::SUCCESS);
        }
        let (table, summary) = photonkit::detect::merge_parts(&source.view(), &parts)?;
        table.write(Output::parse(&a.output)).context("writing the detected map")?;
        super::note!(
            "photonkit merge: {} tile parts, {} photons: {:.1} % constrained (factor < 0.5), mean factor {:.3}",
            maps.len(),
            summary.photons,
            100.0 * summary.constrained_fraction(),
            summary.mean_factor
        );
        super::print_record(&a.output)?;
        return Ok(ExitCode::SUCCESS);
    }
    super::refuse_input_as_output(&a.output)?;
    let n = photonkit::trace::merge(&maps, Output::parse(&a.output))?;
    super::note!("photonkit merge: {} shards, {n} photons", maps.len());
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}
