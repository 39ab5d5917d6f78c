//! The `photonkit` command line: parses arguments and calls the library; nothing else.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

/// Caustic photon maps with parameter-space relaxation constraints.
///
/// Stages read and write PHM photon-map files (see format-spec/phm-v1.md) and compose as a
/// pipeline; `-` as input or output means standard input or output.
#[derive(Parser)]
#[command(name = "photonkit", version, about, long_about)]
struct Cli {
    /// No progress bars and no notes on standard error (warnings and errors are still printed).
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Stages that write a photon map (trace, merge, detect, relax, collapse, import) print the
    /// record they add to its history — parameters and measurements — as one JSON line on
    /// standard output; `pipeline` prints one line per stage.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run every stage on a scene (the embedded default without one): trace, detect, relax, collapse, relax.
    Pipeline(cli::pipeline::Args),
    /// Trace caustic photons from a scene, recording their trajectory parameters.
    Trace(cli::trace::Args),
    /// Join the shards of one trace (`trace --shard i/n`) into the map a single run writes.
    Merge(cli::merge::Args),
    /// Detect features: parameter-space density, constrained k-NN and PCA constraints (Eq. 1–7).
    Detect(cli::detect::Args),
    /// Relax photons toward blue noise under their constraints (Eq. 8–9).
    Relax(cli::relax::Args),
    /// Drop the parameter dimensions from the neighbour search.
    Collapse(cli::relax::CollapseArgs),
    /// Refine a relaxed map progressively: fresh photons each pass, flux toward constant per photon.
    Refine(cli::refine::Args),
    /// Render radiance or irradiance from a photon map to OpenEXR and PNG.
    Render(cli::render::Args),
    /// Render a reference image by progressive photon mapping (traces its own photons).
    Reference(cli::render::ReferenceArgs),
    /// Compare every method's error and time against the truth (Table I with error rows).
    Compare(cli::compare::Args),
    /// Summarise, check, dump or subsample a photon map.
    Inspect(cli::inspect::Args),
    /// Import photons from PLY, CSV/TSV or Radiance photon maps.
    Import(cli::import::Args),
    /// Export a photon map as PLY or CSV for point-cloud viewers.
    Export(cli::export::Args),
    /// Print a shell completion script, e.g. `photonkit completions bash > ~/.local/share/bash-completion/completions/photonkit`.
    Completions {
        /// The shell: bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    cli::set_quiet(cli.quiet);
    cli::set_json(cli.json);
    if let Err(e) = photonkit::format::guard::install_signal_handlers() {
        eprintln!("photonkit: warning: no signal handlers ({e}): an interrupt may leave temporary files");
    }
    let result = match cli.command {
        Command::Pipeline(a) => cli::pipeline::run(a),
        Command::Trace(a) => cli::trace::run(a),
        Command::Merge(a) => cli::merge::run(a),
        Command::Detect(a) => cli::detect::run(a),
        Command::Relax(a) => cli::relax::run(a),
        Command::Collapse(a) => cli::relax::collapse(a),
        Command::Refine(a) => cli::refine::run(a),
        Command::Render(a) => cli::render::run(a),
        Command::Reference(a) => cli::render::reference(a),
        Command::Compare(a) => cli::compare::run(a),
        Command::Inspect(a) => cli::inspect::run(a),
        Command::Import(a) => cli::import::run(a),
        Command::Export(a) => cli::export::run(a),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            clap_complete::generate(shell, &mut Cli::command(), "photonkit", &mut std::io::stdout());
            Ok(ExitCode::SUCCESS)
        }
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("photonkit: error: {}", describe(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, leaving out a cause the message already quotes
/// (library errors name the file and embed the I/O error that caused them).
fn describe(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg
}
