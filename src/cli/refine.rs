//! `photonkit refine`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::format::{Output, PhotonMap, PhotonTable};
use photonkit::refine::{self, RefineParams, RefineRecord};

/// Refine a relaxed map progressively: passes of fresh photons estimate the flux at every
/// primal photon, and the photons relax toward a constant per-photon flux (after Spencer &
/// Jones 2013, "Progressive Photon Relaxation"; docs/progressive.md).
///
/// Each pass traces --photons-per-pass new photons (emission numbers continuing the map's
/// trace), gives each one's flux to the map photon nearest to it (so every photon learns the
/// flux of its own cell, more exactly with every pass), moves the photons within their
/// constraint bases toward equal flux, and sets each photon's flux to its cell's estimate,
/// the map's total kept exactly. The output is written after every pass (or every
/// --save-every passes, and after the last); --resume continues it up to --passes.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    photonkit refine out/relaxed.phm -o refined.phm --passes 8\n  \
    photonkit refine out/relaxed.phm -o refined.phm --passes 32 --resume   # 24 more")]
pub struct Args {
    /// Input photon map: the primal photons (a relaxed map, with its constraint basis).
    input: String,
    /// Output photon map, written after every pass (see --save-every).
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Write the output every N passes, and after the last. Writing the whole map is a large
    /// share of a pass on big maps; an interrupted run resumes from the last pass written
    /// (--resume), so N passes are the most it can lose.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    save_every: u64,
    /// Passes in all.
    #[arg(long, value_name = "N", default_value_t = RefineParams::default().passes)]
    passes: u64,
    /// Photons emitted per pass (default: as many as the map's trace emitted).
    #[arg(long, value_name = "N")]
    photons_per_pass: Option<u64>,
    /// Continue the refinement saved in the output (its passes count toward --passes).
    #[arg(long)]
    resume: bool,
    /// Relaxation iterations toward constant flux per pass (0: only the flux is refined).
    #[arg(long, value_name = "N", default_value_t = RefineParams::default().iterations)]
    iterations: usize,
    /// γ: the photons grow toward N₀·p^γ after p passes, by splitting the cells holding the
    /// most flux (0: the map's photons stay; docs/progressive.md, "Growth") [default: 1/3]
    #[arg(value_parser = super::finite_f32, long, value_name = "G", default_value_t = RefineParams::default().growth, hide_default_value = true)]
    growth: f32,
    /// w: the map's own photon fluxes count as w passes' worth of each cell's flux, so early
    /// passes do not replace a good estimate by a noisy one (0: the passes' photons alone;
    /// docs/progressive.md, "The prior")
    #[arg(long, value_name = "W", value_parser = super::finite_f32, default_value_t = RefineParams::default().prior_passes)]
    prior_passes: f32,
    /// a: a photon that detection held on its line weighs w / f^a passes, f its freedom across
    /// the constraint (|v_b|, 1 free, floored at 0.001), so held photons at folds keep more of
    /// the relaxed map's flux; held photons on the border of their emitter's lit parameter
    /// domain (where the light stops: a beam's edge, the spectrum's end, a shadow) weigh w, as
    /// free ones do (0: every photon's prior weighs w, the default, since the kernel narrows
    /// fast at held photons; 1/2 or 1 keep more of a caustic net the relaxation drew well;
    /// docs/progressive.md, "The prior")
    #[arg(long, value_name = "A", value_parser = super::finite_f32, default_value_t = RefineParams::default().prior_hold)]
    prior_hold: f32,
    /// Kf: neighbours of the repulsion (Eq. 8).
    #[arg(long, value_name = "N", default_value_t = RefineParams::default().kf)]
    kf: usize,
    /// Largest step per iteration as a fraction of the local photon spacing.
    #[arg(value_parser = super::finite_f32, long, default_value_t = RefineParams::default().step_limit)]
    step_limit: f32,
    /// Scene the map was traced from (default: the one its trace record names).
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if a.output.as_os_str() == "-" {
        bail!("refine writes its output after every pass: give a file, not standard output");
    }
    let input = PhotonMap::open(&a.input)?;
    let resumed = if a.resume && a.output.exists() {
        let saved = PhotonMap::open_path(&a.output)
            .with_context(|| format!("--resume: reading {}", a.output.display()))?;
        if RefineRecord::of(&saved.view()).is_none() {
            bail!("--resume: {} holds no refinement to continue", a.output.display());
        }
        // Read whole, so the file can be replaced after each pass.
        let table = PhotonTable::carrying(&saved.view(), saved.view().info().clone()).into_owned();
        Some(table)
    } else {
        None
    };
    super::refuse_input_as_output(&a.output.to_string_lossy())?;
    let map_view = match &resumed {
        Some(t) => t.view(),
        None => input.view(),
    };
    let r = photonkit::scene::for_map(Some(&input.view()), a.scene.as_deref())?;
    for note in &r.notes {
        super::note!("photonkit refine: note: {note}");
    }
    let p = RefineParams {
        passes: a.passes,
        photons_per_pass: a.photons_per_pass,
        iterations: a.iterations,
        kf: a.kf,
        step_limit: a.step_limit,
        growth: a.growth,
        prior_passes: a.prior_passes,
        prior_hold: a.prior_hold,
    };
    let done = RefineRecord::of(&map_view).map_or(0, |r| r.passes_done);
    if done >= a.passes {
        super::note!("photonkit refine: {} already holds {done} passes", a.output.display());
        return Ok(ExitCode::SUCCESS);
    }
    let bar = ProgressBar::with_draw_target(Some(a.passes - done), super::draw_target()).with_style(
        ProgressStyle::with_template("refine {bar:30} {pos}/{len} passes {elapsed} (eta {eta}) {msg}")
            .expect("valid template"),
    );
    let t = Instant::now();
    let result = refine::refine(&map_view, &r.scene, &p, None, &mut |done| {
        let m = done.measure;
        if m.pass % a.save_every == 0 || m.pass >= a.passes {
            done.table()?.write(Output::Path(a.output.clone()))?;
        }
        bar.inc(1);
        bar.suspend(|| {
            super::note!(
                "pass {:>3}: {} fresh photons, {:.1} per primal photon, mean step {:.3e} m, flux spread {:.4}",
                m.pass,
                m.fresh_stored,
                m.gathered_per_photon,
                m.mean_step,
                m.flux_cv
            )
        });
        Ok(true)
    });
    bar.finish_and_clear();
    result?;
    let secs = t.elapsed().as_secs_f64();
    super::note!(
        "refined {} photons, passes {}..{} in {secs:.2} s; written to {}",
        map_view.len(),
        done + 1,
        a.passes,
        a.output.display()
    );
    super::print_record(&a.output.to_string_lossy())?;
    Ok(ExitCode::SUCCESS)
}
