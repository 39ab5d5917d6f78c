//! `photonkit detect`.

use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::detect::{self, DetectParams, Method, NoiseModel};
use photonkit::format::{MapView, Output, PhotonMap};
use photonkit::tiles::{TileSpec, Tiling};

/// Detect features: a constraint basis per photon for `relax` (Eq. 1–7).
///
/// For every photon, the Kc nearest photons in world space are gathered among those whose
/// trajectory parameters lie within r_param of its own (Eq. 1: r_param = β·sqrt(Kc/(πρ)), ρ the
/// photons' density in parameter space), projected into the photon's tangent plane, and their
/// principal components give the constraint: free along P1, held along P2 as strongly as the
/// neighbourhood is anisotropic beyond what noise explains (Eq. 2–7). Writes the columns
/// basis_u, basis_v (v already scaled by its factor in [0, 1]), lambda2 and r_param, sets the
/// state to `detected` and records the parameters and a report in the history. Every other
/// column passes through unchanged.
#[derive(clap::Args)]
pub struct Args {
    /// Input photon map (`-` for standard input).
    input: String,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
    /// How constraints are found. Default: param-pca, or world-pca (with a note) for a map
    /// without trajectory parameters.
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
    #[command(flatten)]
    detect: super::params::DetectArgs,
    /// Gain of `--method gradient`: the factor along the density gradient is 1 − gain·g, with
    /// g = |∇B̂|·r/B̂ (≈ 1.7 on a hard edge, ≈ 2.8/√Kc from noise alone).
    #[arg(value_parser = super::finite_f32, long, default_value_t = detect::DEFAULT_GAIN)]
    gain: f32,
    /// μ(K), σ(K) of the noise filter (Eq. 4–6): `simulated` tabulates them for any Kc under this
    /// implementation's normalisation; `paper` is the paper's fit at K = 100.
    #[arg(long, value_enum, default_value_t = NoiseArg::Simulated)]
    mu_sigma: NoiseArg,
    /// Detect only tile i of n (from 0) and write a tile part: the tile's photons with their
    /// detection and their indices in the map, for `photonkit merge --map INPUT PART…`. The
    /// map's box is cut in its two longest axes into n cells (2 → 2×1, 4 → 2×2, 9 → 3×3); each
    /// tile is measured with a halo wide enough that its photons get exactly the untiled
    /// result, so the merged map is the one `detect INPUT -o OUT` writes (docs/tiles.md).
    #[arg(long, value_name = "i/n", value_parser = parse_tile)]
    tile: Option<TileSpec>,
    /// Keep the peak memory under SIZE (512M, 8G, 2GiB): when the whole map would not fit,
    /// detect it tile by tile in this process, as many tiles as the budget needs, with the
    /// same result bit for bit (docs/tiles.md).
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory, conflicts_with = "tile")]
    memory: Option<u64>,
}

fn parse_tile(s: &str) -> Result<TileSpec, String> {
    s.parse().map_err(|e: photonkit::tiles::TileError| e.to_string())
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum MethodArg {
    /// The paper: PCA over neighbours restricted in parameter space.
    ParamPca,
    /// PCA over plain world-space neighbours.
    WorldPca,
    /// Photon relaxation 2009: constraint along the flux-density gradient, with --gain.
    Gradient,
    /// No constraint: photons move freely in their tangent plane.
    None,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum NoiseArg {
    Simulated,
    Paper,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let map = PhotonMap::open(&a.input)?;
    super::refuse_input_as_output(&a.output)?;
    let requested = a.method.map(|m| match m {
        MethodArg::ParamPca => Method::ParamPca,
        MethodArg::WorldPca => Method::WorldPca,
        MethodArg::Gradient => Method::Gradient,
        MethodArg::None => Method::None,
    });
    let (method, note) = detect::choose_method(&map.view(), requested)?;
    if let Some(note) = note {
        super::note!("note: {note}");
    }
    let p = a.detect.apply(DetectParams {
        method,
        gain: a.gain,
        noise: match a.mu_sigma {
            NoiseArg::Simulated => NoiseModel::Simulated,
            NoiseArg::Paper => NoiseModel::Paper,
        },
        ..DetectParams::default()
    });
    let capped = p.capped(map.len());
    if capped.kc < p.kc {
        super::note!("note: --kc {} exceeds the map's {} photons: using Kc = {}", p.kc, map.len(), capped.kc);
    }
    let p = capped;
    let view = map.view();
    let input = detect::map_input(&view)?;
    let units = detect::work_units(&input, p.method);
    let bar = ProgressBar::with_draw_target(Some(units), super::draw_target()).with_style(
        ProgressStyle::with_template("detect {bar:30} {percent}% {elapsed} (eta {eta})")
            .expect("valid template"),
    );
    let t = Instant::now();
    if let Some(tile) = a.tile {
        return run_tile(&map.view(), &p, tile, &a.output, bar, t);
    }
    let budgeted = super::budget_tiling(&map, a.memory, &detect::memory(&map.view()), "detecting")?;
    let d = if let Some((tiling, mut budget)) = budgeted {
        // Eq. 1's radius in one pass over the whole map when its index fits the budget.
        let radius = detect::Radius::for_budget(map.len(), budget.budget, budget.held, &budget.model);
        if radius == detect::Radius::PerTile && p.method == detect::Method::ParamPca && input.has_params() {
            super::note!(
                "note: Eq. 1's radius is found tile by tile (slower): one parameter index over the whole map \
                 ({} more) does not fit the budget",
                indicatif::HumanBytes((detect::RADIUS_PASS_BYTES * map.len() as f64) as u64)
            );
        }
        detect::detect_map_tiled(
            &map.view(),
            &p,
            &tiling,
            radius,
            &|k| bar.inc(k),
            &mut |tile, tiles, part| {
                bar.suspend(|| budget.check(tile, &part.per_round));
                bar.suspend(|| {
                    super::note!(
                        "tile {tile}/{tiles}: {} photons; measured per round / working set: {}",
                        part.indices.len(),
                        super::rounds_text(&part.per_round)
                    )
                });
            },
        )?
    } else {
        detect::detect_map(&map.view(), &p, &|k| bar.inc(k))?
    };
    bar.finish_and_clear();
    let seconds = t.elapsed().as_secs_f64();
    let s = d.summary.clone();
    detect::detected_map(&map.view(), d, &p, seconds)?
        .write(Output::parse(&a.output))
        .context("writing the detected map")?;
    super::note!(
        "detected {} photons with {} (Kc = {}) in {seconds:.2} s ({:.2} µs/photon): {:.1} % constrained \
         (factor < 0.5), mean factor {:.3}{}",
        s.photons,
        method.name(),
        p.kc,
        seconds * 1e6 / s.photons.max(1) as f64,
        100.0 * s.constrained_fraction(),
        s.mean_factor,
        if s.too_few + s.coincident > 0 {
            format!("; {} with fewer than 3 neighbours and {} coincident left free", s.too_few, s.coincident)
        } else {
            String::new()
        }
    );
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}

/// `--tile`: one tile's part.
fn run_tile(
    map: &MapView,
    p: &DetectParams,
    tile: TileSpec,
    output: &str,
    bar: ProgressBar,
    t: Instant,
) -> anyhow::Result<ExitCode> {
    let tiling = Tiling::new(map.positions(), tile.grid());
    let prepared = detect::PreparedInput::new(map, p)?;
    bar.set_length(map.len().div_ceil(tiling.len()).max(1) as u64);
    let part = detect::detect_map_tile(map, p, &tiling, tile.index, &|k| bar.inc(k))?;
    bar.finish_and_clear();
    let seconds = t.elapsed().as_secs_f64();
    detect::tile_part(map, &part, p, &prepared.scales, tile, seconds)?
        .write(Output::parse(output))
        .context("writing the tile part")?;
    super::note!(
        "detected tile {tile} ({}×{}, cut at the photons' quantiles): {} of {} photons in {seconds:.2} s; photons \
         measured per round of halos: {} ({} round{} in parameter space)",
        tiling.counts[0],
        tiling.counts[1],
        part.indices.len(),
        map.len(),
        super::rounds_text(&part.per_round),
        part.param_rounds,
        if part.param_rounds == 1 { "" } else { "s" },
    );
    super::print_record(output)?;
    Ok(ExitCode::SUCCESS)
}
