//! `photonkit relax` and `photonkit collapse`.

use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::format::{Output, PhotonMap, State};
use photonkit::relax::{self, RelaxParams, RelaxSpace};
use photonkit::scene::Scene;
use photonkit::tiles::{TileSpec, Tiling};

/// Relax photons toward a blue-noise distribution (Eq. 8–9).
///
/// Each iteration pushes every photon away from its Kf nearest neighbours (Eq. 8), projects
/// the push onto its constraint basis from `detect` (Eq. 9), moves all photons at once and
/// updates the neighbour index (exact neighbours every iteration). Before `collapse`,
/// neighbours are restricted to the photon's parameter-space radius exactly as `detect`
/// restricted them; after it, they are found in world space. Without constraint columns photons
/// move freely in their tangent plane (the map says so in its history). Flux is never changed: the total is preserved exactly.
#[derive(clap::Args)]
pub struct Args {
    /// Input photon map (`-` for standard input).
    input: String,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
    #[command(flatten)]
    relax: super::params::RelaxArgs,
    /// ε of Eq. 8 as a fraction of the Kf-th neighbour distance (keeps the force finite).
    #[arg(value_parser = super::finite_f32, long, default_value_t = 1e-3)]
    epsilon: f32,
    /// Largest step per iteration as a fraction of the local photon spacing.
    #[arg(value_parser = super::finite_f32, long, default_value_t = 0.5)]
    step_limit: f32,
    /// The scene the photons were traced in: photons that move are returned to their surface
    /// (the `surface` column), so photons on curved receivers stay on them. Without it, the
    /// scene the map's trace record names is used when it is found (as `render` finds it);
    /// failing that, photons move in their tangent plane, which keeps them exactly on planar
    /// receivers.
    #[arg(long, value_name = "SCENE")]
    scene: Option<std::path::PathBuf>,
    /// The 2009 method's flux diffusion: per iteration each photon's flux moves this fraction
    /// (0–1) toward its Kf neighbours' mean, totals kept per channel. 0 keeps every photon's
    /// flux as traced.
    #[arg(value_parser = super::finite_f32, long, value_name = "RATE", default_value_t = 0.0)]
    flux_diffusion: f32,
    /// Relax only tile i of n (from 0) and write a tile part: the tile's photons relaxed, with
    /// their indices in the map and what the report needs of each, for `photonkit merge --map
    /// INPUT PART…`. The tiles are detect's (2 → 2×1, 4 → 2×2, 9 → 3×3); each is relaxed with a
    /// halo whose every step is certified, so the merged map is the one `relax INPUT -o OUT`
    /// writes (docs/tiles.md). Not with --flux-diffusion, nor more than 64 iterations.
    #[arg(long, value_name = "i/n", value_parser = parse_tile)]
    tile: Option<TileSpec>,
    /// Keep the peak memory under SIZE (512M, 8G, 2GiB): when the whole map would not fit,
    /// relax it tile by tile in this process, as many tiles as the budget needs, with the same
    /// result bit for bit (docs/tiles.md). Not with --flux-diffusion, nor more than 64
    /// iterations.
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory, conflicts_with = "tile")]
    memory: Option<u64>,
}

fn parse_tile(s: &str) -> Result<TileSpec, String> {
    s.parse().map_err(|e: photonkit::tiles::TileError| e.to_string())
}

/// The scene given, or the one the map's trace record names when it is found
/// ([`photonkit::scene::for_map`]); none when the map names none or its scene is not here
/// (photons then move in their tangent planes).
fn scene_for(map: &PhotonMap, path: Option<&std::path::Path>) -> anyhow::Result<Option<Scene>> {
    match photonkit::scene::for_map(Some(&map.view()), path) {
        Ok(r) if r.recorded => {
            for note in &r.notes {
                eprintln!("photonkit: note: {note}");
            }
            Ok(Some(r.scene))
        }
        Ok(_) => Ok(None),
        Err(e) if path.is_some() => Err(e.into()),
        Err(e) => {
            super::note!("photonkit relax: note: {e}; photons move in their tangent planes");
            Ok(None)
        }
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let map = PhotonMap::open(&a.input)?;
    super::refuse_input_as_output(&a.output)?;
    let p = a.relax.apply(RelaxParams {
        epsilon: a.epsilon,
        step_limit: a.step_limit,
        flux_diffusion: a.flux_diffusion,
        ..RelaxParams::default()
    });
    anyhow::ensure!(
        p.epsilon.is_finite()
            && p.epsilon >= 0.0
            && p.step_limit.is_finite()
            && p.step_limit > 0.0
            && (0.0..=1.0).contains(&p.flux_diffusion),
        "--epsilon must be ≥ 0, --step-limit > 0 and --flux-diffusion in [0, 1]"
    );
    let capped = p.capped(map.len());
    if capped.kf < p.kf {
        super::note!(
            "note: --kf {} exceeds the {} other photons in the map: using Kf = {}",
            p.kf,
            capped.kf,
            capped.kf
        );
    }
    let p = capped;
    let bar = ProgressBar::with_draw_target(Some(p.iterations as u64), super::draw_target()).with_style(
        ProgressStyle::with_template("relax {bar:30} {pos}/{len} iterations {elapsed} (eta {eta}) {msg}")
            .expect("valid template"),
    );
    let t = Instant::now();
    let scene = scene_for(&map, a.scene.as_deref())?;
    if let Some(tile) = a.tile {
        bar.finish_and_clear();
        let tiling = Tiling::new(map.positions(), tile.grid());
        let part = relax::relax_tile(&map.view(), &p, scene.as_ref(), &tiling, tile.index)?;
        let seconds = t.elapsed().as_secs_f64();
        relax::tile_part(&map.view(), &part, &p, tile, seconds)?
            .write(Output::parse(&a.output))
            .context("writing the tile part")?;
        super::note!(
            "relaxed tile {tile} ({}×{}): {} of {} photons in {seconds:.2} s; photons pending per round of \
             halos / working set: {}",
            tiling.counts[0],
            tiling.counts[1],
            part.indices.len(),
            map.len(),
            super::rounds_text(&part.per_round),
        );
        super::print_record(&a.output)?;
        return Ok(ExitCode::SUCCESS);
    }
    // Photons returned to their surfaces carry new normals too.
    let model = relax::tiled::memory(scene.is_some());
    let budgeted = super::budget_tiling(&map, a.memory, &model, "relaxing")?;
    let relaxed = if let Some((tiling, mut budget)) = budgeted {
        bar.set_length(tiling.len() as u64);
        bar.set_style(
            ProgressStyle::with_template("relax {bar:30} {pos}/{len} tiles {elapsed} (eta {eta})")
                .expect("valid template"),
        );
        let relaxed = relax::relax_tiled(&map.view(), &p, scene.as_ref(), &tiling, |tile, tiles, part| {
            bar.suspend(|| budget.check(tile, &part.per_round));
            bar.set_position(tile as u64 + 1);
            bar.suspend(|| {
                super::note!(
                    "tile {tile}/{tiles}: {} photons; pending per round / working set: {}",
                    part.indices.len(),
                    super::rounds_text(&part.per_round)
                )
            });
        })?;
        relaxed.measures.iter().for_each(note_iteration);
        relaxed
    } else {
        relax::relax_map_on(&map.view(), &p, scene.as_ref(), |m| {
            bar.inc(1);
            // Printed whether or not the bar is drawn (stderr may not be a terminal).
            bar.suspend(|| note_iteration(m));
        })?
    };
    bar.finish_and_clear();
    let seconds = t.elapsed().as_secs_f64();
    if relaxed.refused_moves > 0 {
        super::note!(
            "note: {} moves were refused because the photon's surface was not found where it moved",
            relaxed.refused_moves
        );
    }
    if !relaxed.constrained {
        super::note!(
            "note: {} has no constraint basis (run `photonkit detect` first): relaxed unconstrained",
            map.file_name()
        );
    }
    let window;
    let space = match relaxed.space {
        RelaxSpace::WorldParams => "world space within parameter-space radius",
        RelaxSpace::WorldSpectral => {
            window = format!("world space within {} nm of each photon's wavelength", p.spectral_window);
            &window
        }
        RelaxSpace::World if map.meta().state == State::Collapsed => "world space (collapsed)",
        RelaxSpace::World => "world space",
    };
    relax::relaxed_map(&map.view(), relaxed, &p, seconds)?
        .write(Output::parse(&a.output))
        .context("writing the relaxed map")?;
    super::note!(
        "relaxed {} photons, {} iterations in {space}, {seconds:.2} s ({:.0} ns/photon/iteration)",
        map.len(),
        p.iterations,
        seconds * 1e9 / (map.len().max(1) * p.iterations.max(1)) as f64
    );
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}

/// One iteration's measures on standard error.
fn note_iteration(m: &relax::IterationMeasure) {
    super::note!(
        "iteration {:>2}: nearest-neighbour spread {:.4} (local {:.4}), mean step {:.3e}, largest step {:.3e}",
        m.iteration + 1,
        m.nn_cv,
        m.local_nn_cv,
        m.mean_displacement,
        m.max_displacement
    );
}

/// Drop the parameter dimensions from the neighbour search (Algorithm 1's collapse).
///
/// The map moves from state `detected` to `collapsed`; the next `relax` finds neighbours in
/// world space. The trajectory parameters and constraint basis stay in the file.
#[derive(clap::Args)]
pub struct CollapseArgs {
    /// Input photon map (`-` for standard input).
    input: String,
    /// Output photon map (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: String,
}

pub fn collapse(a: CollapseArgs) -> anyhow::Result<ExitCode> {
    let map = PhotonMap::open(&a.input)?;
    super::refuse_input_as_output(&a.output)?;
    relax::collapse(&map.view())?.write(Output::parse(&a.output))?;
    super::print_record(&a.output)?;
    Ok(ExitCode::SUCCESS)
}
