//! One module per subcommand: its arguments (clap) and the call into the library.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};

use indicatif::ProgressDrawTarget;

/// `--quiet`: no progress bars and no notes on standard error (warnings and errors stay).
static QUIET: AtomicBool = AtomicBool::new(false);

/// `--json`: a stage that writes a photon map prints the record it added to the map's history
/// (its parameters and what it measured) as one line of JSON on standard output.
static JSON: AtomicBool = AtomicBool::new(false);

pub(crate) fn set_json(json: bool) {
    JSON.store(json, Ordering::Relaxed);
}

/// Under `--json`, prints the last history record of the map just written to `output` as one
/// JSON line on standard output (a script's summary of the stage).
pub(crate) fn print_record(output: &str) -> anyhow::Result<()> {
    if JSON.load(Ordering::Relaxed) {
        let map = photonkit::format::PhotonMap::open_path(std::path::Path::new(output))?;
        let record = map.meta().history.last().cloned();
        println!("{}", serde_json::to_string(&record)?);
    }
    Ok(())
}

pub(crate) fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

pub(crate) fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// Where progress bars draw: standard error when it is a terminal and `--quiet` is not given,
/// nowhere otherwise.
pub(crate) fn draw_target() -> ProgressDrawTarget {
    if std::io::stderr().is_terminal() && !quiet() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    }
}

/// `eprintln!` for what a command reports as it works (timings, counts, notes); silent under
/// `--quiet`. Warnings and errors use `eprintln!` directly.
macro_rules! note {
    ($($t:tt)*) => {
        if !$crate::cli::quiet() {
            eprintln!($($t)*);
        }
    };
}
pub(crate) use note;

pub mod compare;
pub mod detect;
pub mod export;
pub mod import;
pub mod inspect;
pub mod merge;
pub mod params;
pub mod pipeline;
pub mod refine;
pub mod relax;
pub mod render;
pub mod trace;

/// Refuses, before any work, an output that is one of the command's inputs (opened inputs are
/// registered by the library; the final rename checks again).
pub(crate) fn refuse_input_as_output(output: &str) -> anyhow::Result<()> {
    if output == "-" && JSON.load(Ordering::Relaxed) {
        anyhow::bail!(
            "--json prints the stage's summary on standard output: write the map to a file (-o FILE)"
        );
    }
    if output != "-" {
        photonkit::format::guard::check_output(std::path::Path::new(output))?;
    }
    Ok(())
}

/// A finite `f32` command-line value (NaN and infinities are refused, not propagated).
pub(crate) fn finite_f32(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() { Ok(v) } else { Err(format!("'{s}' is not a finite number")) }
}

/// A finite `f64` command-line value.
pub(crate) fn finite_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() { Ok(v) } else { Err(format!("'{s}' is not a finite number")) }
}

/// The tiling `--memory BUDGET` needs for a stage with memory model `model` on `map` (`None`:
/// the whole map fits, or no budget was given), noted on standard error, with the check its
/// tiles' working sets are held to ([`BudgetCheck`]); `doing` names the work in messages
/// ("detecting").
pub(crate) fn budget_tiling(
    map: &photonkit::format::PhotonMap,
    budget: Option<u64>,
    model: &photonkit::tiles::MemoryModel,
    doing: &str,
) -> anyhow::Result<Option<(photonkit::tiles::Tiling, BudgetCheck)>> {
    use indicatif::HumanBytes;
    let Some(budget) = budget else { return Ok(None) };
    // What the process holds before the tiling reads the map's positions: not the stage's to use.
    let held = photonkit::tiles::resident_bytes().unwrap_or(0);
    let tiling = photonkit::tiles::tiling_beside(map.positions(), budget, held, model).map_err(|e| {
        anyhow::anyhow!(
            "--memory {}: {doing} {} photons needs at least {} (what the map needs per photon, one tile, \
             and the {} the process holds already)",
            HumanBytes(budget),
            e.photons,
            HumanBytes(e.need),
            HumanBytes(e.held)
        )
    })?;
    Ok(tiling.map(|t| {
        let [nx, ny] = t.counts;
        note!("{doing} in {} tiles ({nx}×{ny}) to stay under --memory {}", t.len(), HumanBytes(budget));
        (t, BudgetCheck { budget, model: *model, photons: map.len(), held, warned: false })
    }))
}

/// What a `--memory` run's tiles are held to: the stage's model of the map's photons, with what
/// the process held before, within the budget.
pub(crate) struct BudgetCheck {
    budget: u64,
    model: photonkit::tiles::MemoryModel,
    photons: usize,
    held: u64,
    warned: bool,
}

impl BudgetCheck {
    /// Warns, once per run, when tile `tile`'s largest working set (of its rounds, `per_round`
    /// as [`rounds_text`] reads them) makes the model exceed the budget by more than its
    /// accuracy (5 %, measured on the water at 10⁶ and 10⁷): its halo grew past what the tiling
    /// allowed for, to certify every result (far-reaching searches or moves, as in a sparse
    /// surround).
    pub(crate) fn check(&mut self, tile: usize, per_round: &[[usize; 2]]) {
        let working = per_round.iter().map(|r| r[1]).max().unwrap_or(0);
        let (m, n) = (&self.model, self.photons);
        let need = self.held as f64 + m.per_photon * n as f64 + m.per_working_photon * working as f64;
        if !self.warned && need > 1.05 * self.budget as f64 {
            self.warned = true;
            note!(
                "warning: tile {tile} worked on {working} of the {n} photons: its halo grew to certify every \
                 result (far-reaching searches or moves, as in a sparse surround), so the peak may exceed \
                 --memory {} (about {})",
                indicatif::HumanBytes(self.budget),
                indicatif::HumanBytes(need as u64)
            );
        }
    }
}

/// A tile's rounds as `--tile` and `--memory` report them: per round, the photons still to
/// certify "of" the photons worked on.
pub(crate) fn rounds_text(per_round: &[[usize; 2]]) -> String {
    let rounds: Vec<String> = per_round.iter().map(|[m, w]| format!("{m} of {w}")).collect();
    if rounds.is_empty() { "none".to_string() } else { rounds.join(", ") }
}

/// A size in bytes as people write it: `512M`, `4G` (powers of 1000), `2GiB` (powers of 1024),
/// or a plain number of bytes.
pub(crate) fn parse_memory(s: &str) -> Result<u64, String> {
    match parse_size::parse_size(s) {
        Ok(0) => Err(format!("'{s}': needs more than 0 bytes")),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("'{s}' is not a size such as 512M, 4G or 2GiB ({e})")),
    }
}
