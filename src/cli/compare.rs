//! `photonkit compare`: the speed–accuracy trade of every method on one scene.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use photonkit::eval::compare::CompareError;
use photonkit::eval::compare::{self, CompareOptions, MethodKind, Progress, Target};
use photonkit::eval::report::{self, Run};
use photonkit::eval::truth::{Quality, TruthError};
use photonkit::render::Mode;
use photonkit::scene::Camera;

/// Run every method on the same traced photons, time every stage, and measure each image
/// against the truth.
///
/// The methods: standard photon mapping (K = 15), the 2009 photon relaxation (gradient
/// constraint, 14 world-space iterations), diffusion-based photon mapping (500 neighbours,
/// q = 0.02), this method (parameter-space PCA, 7 + 7 iterations) and progressive photon
/// mapping at several pass counts.
///
/// The truth: for the sample scenes with simple optics (glass sphere, wavy water, prism, metal
/// ring) the closed-form floor irradiance, compared through an orthographic top-down view in
/// irradiance mode (W/m²), using only the photons of the path families the truth integrates;
/// for any other scene a long progressive photon mapping run through the scene's camera
/// (caustic radiance).
///
/// Writes report.md (a table shaped like the paper's Table I with error rows, and an
/// equal-time table), report.csv, grid.png (images and error maps), error-vs-time.png and the
/// stages' photon maps into --out-dir.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    photonkit compare                                         # the embedded glass sphere\n  \
    photonkit compare samples/scenes/water.toml --photons 2e6\n  \
    photonkit compare samples/scenes/prism.toml --sweep photons=1e5,3e5,1e6\n  \
    photonkit compare samples/scenes/ring.toml --methods pm,ours --sweep kc=20,50,100")]
pub struct Args {
    /// Scene file, TOML or glTF 2.0 (.gltf, .glb); without it, the embedded default scene.
    scene: Option<PathBuf>,
    /// Folder for the report, images and photon maps (created if missing).
    #[arg(long, value_name = "DIR", default_value = "photonkit-compare")]
    out_dir: PathBuf,
    /// Photons to emit for the shared map (e.g. 1000000 or 1e6).
    #[arg(long, value_name = "N", value_parser = super::trace::parse_count, default_value = "1000000")]
    photons: u64,
    /// Seed of the emission sequence.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Methods to run, comma-separated: pm, relax2009, diffusion, ours, ppm, ours-progressive
    /// (this method's map refined progressively: `photonkit refine`).
    #[arg(long, value_delimiter = ',', default_value = "pm,relax2009,diffusion,ours,ppm")]
    methods: Vec<String>,
    /// K of the k-NN radiance estimate of the relaxed maps (2009 relaxation, ours).
    #[arg(short, default_value_t = 15)]
    k: usize,
    /// The K values standard photon mapping runs at (comma-separated): each is a row, so the
    /// baseline is seen at its best (more neighbours trade its noise for blur).
    #[arg(long, value_delimiter = ',', default_value = "15,50,200")]
    pm_k: Vec<usize>,
    /// Density estimate of standard PM and the relaxed maps: `knn` (the paper's: radius the
    /// distance from the point to its K-th photon) or `variable` (each photon's kernel radius
    /// the distance to its own K-th nearest photon: unbiased on stratified photons, where
    /// `knn` reads about 1 % low; see docs/truth.md).
    #[arg(long, value_enum, default_value_t = FixedKEstimator::Knn)]
    estimator: FixedKEstimator,
    #[command(flatten)]
    detect: super::params::DetectArgs,
    #[command(flatten)]
    relax: super::params::RelaxArgs,
    /// World-space iterations of the 2009 relaxation.
    #[arg(long, default_value_t = 14)]
    iterations_2009: usize,
    /// Neighbours of diffusion-based photon mapping.
    #[arg(long, default_value_t = 500)]
    diffusion_k: usize,
    /// Control q of diffusion-based photon mapping.
    #[arg(value_parser = super::finite_f32, long, default_value_t = 0.02)]
    diffusion_q: f32,
    /// Pass counts at which progressive photon mapping is measured.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
    ppm_passes: Vec<u64>,
    /// Pass counts at which ours-progressive is measured (--photons emitted per pass).
    #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
    refine_passes: Vec<u64>,
    /// Relaxation iterations toward constant flux per pass of ours-progressive (0: only the
    /// photons' flux is refined).
    #[arg(long, value_name = "N", default_value_t = photonkit::refine::RefineParams::default().iterations)]
    refine_iterations: usize,
    /// γ of ours-progressive: its photons grow toward N₀·p^γ after p passes, by splitting the
    /// cells holding the most flux (0: fixed) [default: 1/3]
    #[arg(long, value_name = "G", value_parser = super::finite_f32, default_value_t = photonkit::refine::RefineParams::default().growth, hide_default_value = true)]
    refine_growth: f32,
    /// w of ours-progressive: the relaxed map's own photon fluxes count as w passes of its
    /// cells' flux (0: the passes' photons alone)
    #[arg(long, value_name = "W", value_parser = super::finite_f32, default_value_t = photonkit::refine::RefineParams::default().prior_passes)]
    refine_prior: f32,
    /// a of ours-progressive: a photon detection held weighs w / f^a passes, f its freedom
    /// across its constraint, unless it lies on the border of its lit parameter domain (0:
    /// every photon's prior weighs w)
    #[arg(long, value_name = "A", value_parser = super::finite_f32, default_value_t = photonkit::refine::RefineParams::default().prior_hold)]
    refine_prior_hold: f32,
    /// Photons per progressive pass (default: --photons).
    #[arg(long, value_name = "N", value_parser = super::trace::parse_count)]
    ppm_photons: Option<u64>,
    /// Photons emitted per refinement pass of ours-progressive (default: --photons).
    #[arg(long, value_name = "N", value_parser = super::trace::parse_count)]
    refine_photons: Option<u64>,
    /// k of progressive photon mapping's initial radius at each point: the distance to the
    /// k-th nearest photon of its first pass (Hachisuka & Jensen advise k in the tens); 0 for
    /// one radius over the whole image.
    #[arg(long, default_value_t = 30)]
    ppm_k: usize,
    /// Samples per pixel of every image, on a jittered grid when a square: each pixel is then
    /// the estimate averaged over its cell, as the truth is (point samples against cell
    /// averages would measure aliasing, not the method).
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Samples per pixel in the truth's core and edge pixels: where the irradiance varies
    /// within a pixel, too few point samples of a narrow kernel's estimate miss the pixel's
    /// average by more than the methods differ (the ring's core, relaxed: 2.6 at 16 samples
    /// against 0.47 at 4096; refined over 64 passes: 0.54 at 256 against 0.30 at 4096; see
    /// docs/truth.md, "Sampling"). These renders are not timed: a method's time counts a render
    /// at --spp. Progressive photon mapping takes at most 256 a pass (its passes average
    /// them), diffusion-based PM at most 1024 (its 500-neighbour lookups are slow; within 6 %
    /// of 4096). At most --spp: every pixel takes --spp.
    #[arg(long, default_value_t = CompareOptions::default().feature_spp, value_name = "N")]
    feature_spp: u32,
    /// Independent runs of every method (seeds --seed, --seed + 1, …): times and errors are
    /// their means, and the spread across them splits each error into bias² (blur) and
    /// variance (noise), per region (core, edge, smooth, dark; see docs/truth.md).
    #[arg(long, default_value_t = 4)]
    seeds: u32,
    /// Columns of the floor grid (closed-form truth), or the image width (reference truth).
    #[arg(long, default_value_t = 128)]
    cells: usize,
    /// Passes of the progressive reference for a scene without a closed-form truth.
    #[arg(long, default_value_t = 64)]
    reference_passes: u64,
    /// Integrate the closed-form truth quickly (for tests) instead of to convergence.
    #[arg(long, hide = true)]
    fast_truth: bool,
    /// Vary one setting over runs: photons=…, k=…, kc=…, beta=…, k-density=…, growths=…, spectral-scale=…, spectral-window=… or iterations=…
    /// (comma-separated values), e.g. photons=1e5,3e5,1e6. Progressive photon mapping runs
    /// again only when its photons per pass change (they follow --photons unless
    /// --ppm-photons is given).
    #[arg(long, value_name = "KEY=V1,V2,…")]
    sweep: Option<String>,
}

/// The runs of a sweep: a label and the options of each.
fn sweep_runs(base: &CompareOptions, spec: Option<&str>) -> anyhow::Result<Vec<(String, CompareOptions)>> {
    let Some(spec) = spec else { return Ok(vec![(String::new(), base.clone())]) };
    let (key, values) = spec.split_once('=').context("--sweep: write KEY=V1,V2,… (e.g. photons=1e5,1e6)")?;
    let mut runs = Vec::new();
    for v in values.split(',').map(str::trim).filter(|v| !v.is_empty()) {
        let mut o = base.clone();
        let bad = || format!("--sweep {key}: '{v}' is not a valid value");
        match key.trim() {
            "photons" => o.photons = super::trace::parse_count(v).map_err(|e| anyhow::anyhow!(e))?,
            "k" => o.k = v.parse().with_context(bad)?,
            "kc" => o.kc = v.parse().with_context(bad)?,
            "beta" => o.beta = super::finite_f32(v).map_err(anyhow::Error::msg).with_context(bad)?,
            "k-density" => o.k_density = Some(v.parse().with_context(bad)?),
            "growths" => o.growths = v.parse().with_context(bad)?,
            "spectral-scale" => {
                o.spectral_scale = super::finite_f32(v).map_err(anyhow::Error::msg).with_context(bad)?
            }
            "spectral-window" => {
                o.spectral_window = super::finite_f32(v).map_err(anyhow::Error::msg).with_context(bad)?
            }
            "iterations" => {
                o.iterations = v.parse().with_context(bad)?;
                o.iterations_2009 = 2 * o.iterations;
            }
            k => {
                bail!(
                    "--sweep: unknown setting '{k}' (photons, k, kc, beta, k-density, growths, spectral-scale, spectral-window, iterations)"
                )
            }
        }
        o.check().with_context(|| format!("--sweep {key}: '{v}'"))?;
        runs.push((format!("{} = {v}", key.trim()), o));
    }
    if runs.is_empty() {
        bail!("--sweep {key}: no values given");
    }
    Ok(runs)
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let (scene, label, text) = super::trace::load_scene(a.scene.as_deref())?;
    let methods = a
        .methods
        .iter()
        .map(|m| {
            MethodKind::from_slug(m.trim()).with_context(|| {
                format!(
                    "--methods: unknown method '{m}' (pm, relax2009, diffusion, ours, ppm, ours-progressive)"
                )
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    if a.cells < 4 {
        bail!("--cells needs at least 4");
    }
    let base = CompareOptions {
        photons: a.photons,
        seed: a.seed,
        k: a.k,
        pm_ks: a.pm_k.clone(),
        variable_kernel: matches!(a.estimator, FixedKEstimator::Variable),
        kc: a.detect.kc,
        beta: a.detect.beta,
        k_density: a.detect.k_density,
        growths: a.detect.growths,
        spectral_scale: a.detect.spectral_scale,
        kf: a.relax.kf,
        spectral_window: a.relax.spectral_window,
        iterations: a.relax.iterations,
        iterations_2009: a.iterations_2009,
        diffusion_k: a.diffusion_k,
        diffusion_q: a.diffusion_q,
        ppm_passes: a.ppm_passes.clone(),
        refine_passes: a.refine_passes.clone(),
        refine_iterations: a.refine_iterations,
        refine_growth: a.refine_growth,
        refine_prior: a.refine_prior,
        refine_prior_hold: a.refine_prior_hold,
        ppm_photons_per_pass: a.ppm_photons,
        refine_photons_per_pass: a.refine_photons,
        ppm_k: a.ppm_k,
        spp: a.spp,
        feature_spp: a.feature_spp,
        seeds: a.seeds,
        methods,
    };
    base.check()?;
    let runs = sweep_runs(&base, a.sweep.as_deref())?;
    std::fs::create_dir_all(&a.out_dir).with_context(|| format!("creating {}", a.out_dir.display()))?;

    // The truth: closed form where the optics allow, else a long progressive run.
    let quality = if a.fast_truth { Quality::Test } else { Quality::Report };
    let target = match Target::closed_form(&scene, a.cells, quality) {
        Ok(t) => t,
        Err(CompareError::Truth(TruthError::Unsupported(why))) => {
            super::note!(
                "photonkit compare: note: no closed-form truth for this scene ({why}): the truth is a progressive \
                 reference of {} passes",
                a.reference_passes
            );
            let Some(cam) = scene.camera().cloned() else {
                bail!("the scene has no [camera] to view the reference through")
            };
            let h = ((a.cells as f64) * cam.resolution[1] as f64 / cam.resolution[0] as f64).round().max(1.0)
                as u32;
            let cam = Camera { resolution: [a.cells as u32, h], ..cam };
            let per_pass = a.ppm_photons.unwrap_or(a.photons);
            Target::progressive_reference(
                &scene,
                cam,
                Mode::Caustic,
                a.reference_passes,
                per_pass,
                a.spp,
                &|p| {
                    if !super::quiet() {
                        eprint!("\rreference pass {p}/{}", a.reference_passes)
                    }
                },
            )?
        }
        Err(e) => return Err(e.into()),
    };
    super::note!("truth: {}", target.description);

    let mut done = Vec::new();
    for (i, (label_run, o)) in runs.iter().enumerate() {
        if !label_run.is_empty() {
            super::note!("— {label_run}");
        }
        // Progressive photon mapping depends on none of the swept settings but the photon
        // count (when its photons per pass follow it): run it again only when that changed.
        let mut o = o.clone();
        let per_pass = |o: &CompareOptions| o.ppm_photons_per_pass.unwrap_or(o.photons);
        if i > 0 && per_pass(&o) == per_pass(&runs[0].1) {
            o.methods.retain(|&m| m != MethodKind::Progressive);
        }
        let o = &o;
        let bar = super::pipeline::spinner("compare");
        let rows = compare::run(&scene, &label, &text, &target, o, &a.out_dir, &|p| match p {
            Progress::Started(what) => bar.set_message(format!("{what}…")),
            Progress::Finished(line) => bar.suspend(|| super::note!("  {line}")),
        });
        bar.finish_and_clear();
        let rows = rows?;
        done.push(Run { label: label_run.clone(), rows });
    }
    let title = format!("photonkit compare: {label}");
    let command: Vec<String> = std::env::args().collect();
    report::write(&a.out_dir, &title, &target, &done, &command.join(" "), [a.spp, a.feature_spp])?;
    for r in &done {
        if !r.label.is_empty() {
            println!("## {}\n", r.label);
        }
        println!("{}", report::table_markdown(&r.rows));
    }
    super::note!("report: {}", a.out_dir.join("report.md").display());
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sweep_gives_one_run_per_value_and_refuses_bad_ones() {
        let base = CompareOptions::default();
        let runs = sweep_runs(&base, Some("k-density=50, 16")).unwrap();
        let got: Vec<_> = runs.iter().map(|(label, o)| (label.as_str(), o.k_density, o.kc)).collect();
        assert_eq!(got, [("k-density = 50", Some(50), 50), ("k-density = 16", Some(16), 50)]);
        let runs = sweep_runs(&base, Some("iterations=3")).unwrap();
        assert_eq!((runs[0].1.iterations, runs[0].1.iterations_2009), (3, 6));
        assert_eq!(sweep_runs(&base, None).unwrap(), [(String::new(), base.clone())]);
        for bad in ["k-density=1", "k-density=x", "kc=", "colour=1", "photons"] {
            assert!(sweep_runs(&base, Some(bad)).is_err(), "{bad}");
        }
    }
}

/// The density estimate of the fixed-K methods.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum FixedKEstimator {
    Knn,
    Variable,
}
