//! `photonkit export`: photons out to point-cloud viewers.

use std::process::ExitCode;

use photonkit::export::{self, ExportFormat};
use photonkit::format::{Output, PhotonMap};

/// Write a photon map as PLY (binary little-endian) or CSV for MeshLab, CloudCompare or
/// ParaView: every column under its format-spec/import.md name, flux as floats (watts) plus 8-bit
/// red green blue colours in PLY, normals as nx ny nz. `photonkit import` reads both back.
#[derive(clap::Args)]
pub struct Args {
    /// The PHM file (`-` for standard input).
    file: String,
    /// The output format.
    #[arg(long, value_enum)]
    to: To,
    /// Output file (`-` for standard output); default: FILE with the extension .ply or .csv.
    #[arg(short, long, value_name = "OUT")]
    output: Option<String>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum To {
    Ply,
    Csv,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let to = match a.to {
        To::Ply => ExportFormat::Ply,
        To::Csv => ExportFormat::Csv,
    };
    let map = PhotonMap::open(&a.file)?;
    if let Some(o) = &a.output {
        super::refuse_input_as_output(o)?;
    }
    let target = match &a.output {
        Some(o) => Output::parse(o),
        None => export::default_output(&a.file, to),
    };
    if let Output::Path(p) = &target
        && p.as_os_str() == a.file.as_str()
    {
        anyhow::bail!("{}: the export would overwrite its input; give -o", a.file);
    }
    export::export(&map, to, &target)?;
    if let Output::Path(p) = &target {
        super::note!("photonkit export: {} photons to {}", map.len(), p.display());
    }
    Ok(ExitCode::SUCCESS)
}
