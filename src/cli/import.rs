//! `photonkit import`: photons from other tracers into a PHM file.

use std::path::Path;
use std::process::ExitCode;

use photonkit::format::{Output, Parameterisation};
use photonkit::import::{self, Options, SourceFormat};

/// Import photons from a PLY point cloud, a CSV/TSV table or a Radiance photon map (mkpmap).
///
/// PLY and CSV name their fields as format-spec/import.md says (x y z, flux_r flux_g
/// flux_b or red green blue, nx ny nz, dx dy dz, emitter, param_0 param_1 [param_2], …);
/// fields with other names are kept as extra columns. The TSV that `inspect --dump` prints
/// reads back unchanged. Radiance maps of format 3.1 (kd-tree, or out-of-core with the
/// `.leaf` file beside the map) import with normals, flux and the caustic flag; primary rays
/// of the PD variant become trajectory parameters (emission directions).
#[derive(clap::Args)]
pub struct Args {
    /// The file to import (`-` for standard input; CSV from standard input needs `--from csv`).
    input: String,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
    /// The input's format (detected from its first bytes or its extension when not given).
    #[arg(long, value_enum)]
    from: Option<Source>,
    /// What the param_* fields of a PLY or CSV file are, for every emitter (default: per
    /// emitter, direction if its 3 parameters are unit vectors, else rect-uv if they lie in
    /// [0,1]²; see format-spec/import.md).
    #[arg(long, value_enum)]
    parameterisation: Option<Param>,
    /// Radiance: keep only photons whose caustic flag is set.
    #[arg(long)]
    caustic_only: bool,
    /// PLY/CSV without flux_* fields: take red green blue as the flux in watts (integer colours
    /// divided by their maximum). Without it such a file is refused: colours are usually
    /// display values a viewer wrote, not watts.
    #[arg(long)]
    flux_from_colour: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Source {
    Ply,
    Csv,
    Tsv,
    Radiance,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Param {
    RectUv,
    Direction,
    /// (u, v) and a wavelength in nm.
    RectUvSpectral,
    /// A direction and a wavelength in nm.
    DirectionSpectral,
    None,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let options = Options {
        format: a.from.map(|f| match f {
            Source::Ply => SourceFormat::Ply,
            Source::Csv | Source::Tsv => SourceFormat::Csv,
            Source::Radiance => SourceFormat::Radiance,
        }),
        parameterisation: a.parameterisation.map(|p| match p {
            Param::RectUv => Parameterisation::RectUv,
            Param::Direction => Parameterisation::Direction,
            Param::RectUvSpectral => Parameterisation::RectUvSpectral,
            Param::DirectionSpectral => Parameterisation::DirectionSpectral,
            Param::None => Parameterisation::None,
        }),
        caustic_only: a.caustic_only,
        flux_from_colour: a.flux_from_colour,
    };
    let path = Path::new(&a.input);
    let photons = import::import(path, &options)?;
    super::refuse_input_as_output(&a.output)?;
    let (n, format, emitters) = (photons.len(), photons.format, photons.emitters.len());
    let dims = photons.emitters.first().map_or(0, |e| e.param_dims);
    let parameters = import::stage_parameters(path, format, &options);
    photons.write(Output::parse(&a.output), parameters)?;
    let params = if dims == 0 {
        "no trajectory parameters (only world-space methods apply)".to_string()
    } else {
        format!("{dims} trajectory parameters")
    };
    super::note!(
        "photonkit import: {n} photons from {} ({}), {emitters} emitter(s), {params}",
        a.input,
        format.name()
    );
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}
