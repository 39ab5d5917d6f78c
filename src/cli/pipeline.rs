//! `photonkit pipeline`: the paper's Algorithm 1 end to end, one stage after another.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::detect::DetectParams;
use photonkit::format::{Output, PhotonMap, PhotonTable};
use photonkit::pipeline::{self, PipelineError, PipelineParams, Stage, StageDone};
use photonkit::relax::RelaxParams;
use photonkit::scene::DEFAULT_SCENE_NAME;
use photonkit::trace::{self, Budget, DEFAULT_SPOOL_MEMORY, Spool, TraceOptions};

/// Run every stage on a scene: trace → detect → relax → collapse → relax → render.
///
/// Uses the paper's defaults (Kc = 50, β = 3, Kf = 16, 7 + 7 iterations) and writes each
/// stage's photon map into the output folder (traced.phm, detected.phm, relaxed-params.phm,
/// collapsed.phm, relaxed.phm) and the image (render.exr, render.png), printing each stage's
/// time and photon count. Every stage
/// also runs alone (`photonkit trace`, `detect`, …) and through pipes.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    photonkit pipeline                                   # the embedded default scene\n  \
    photonkit pipeline samples/scenes/prism.toml --photons 2e6 --out-dir prism-run\n  \
    photonkit pipeline samples/scenes/sphere-point.toml --stored 200000\n  \
    photonkit pipeline samples/scenes/gltf/reflector.gltf --photons 2e6   # a glTF 2.0 scene")]
pub struct Args {
    /// Scene file, TOML or glTF 2.0 (.gltf, .glb); without it, the embedded default scene (a
    /// glass sphere above a floor under a vertical collimated beam,
    /// samples/scenes/glass-sphere.toml).
    scene: Option<PathBuf>,
    /// Folder for the stages' photon maps (created if missing).
    #[arg(long, value_name = "DIR", default_value = "photonkit-out")]
    out_dir: PathBuf,
    /// Photons to emit (e.g. 1000000 or 1e6).
    #[arg(long, value_name = "N", value_parser = super::trace::parse_count, default_value = "1000000")]
    photons: u64,
    /// Emit photons until N are stored, instead of a fixed number emitted (for scenes where
    /// few emitted photons become caustic ones, e.g. a point light above a small glass).
    #[arg(long, value_name = "N", value_parser = super::trace::parse_count, conflicts_with = "photons")]
    stored: Option<u64>,
    /// Seed of the emission sequence.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[command(flatten)]
    detect: super::params::DetectArgs,
    #[command(flatten)]
    relax: super::params::RelaxArgs,
    /// Render the relaxed map even when fewer photons than `--min-relax-photons` were stored.
    #[arg(long)]
    relax_anyway: bool,
    /// Below this many stored photons the image is rendered from the traced map, not the
    /// relaxed one (with so few photons relaxation spreads the caustic; measured on the glass
    /// sphere, see MIN_RELAX_PHOTONS in src/cli/pipeline.rs).
    #[arg(long, value_name = "N", default_value_t = MIN_RELAX_PHOTONS)]
    min_relax_photons: u64,
    /// Keep the peak memory under SIZE (512M, 8G, 2GiB): the stages run one after another from
    /// their files, as `photonkit detect`, `relax`, `collapse`, `relax` and `render` with
    /// `--memory SIZE` (each tile by tile when the whole map would not fit; the maps are the
    /// same, bit for bit), and the trace spools to disk in pieces of at most a quarter of SIZE.
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory)]
    memory: Option<u64>,
    /// Options passed on to `photonkit render` (after `--`), e.g. `-- --width 300 --height 300`.
    #[arg(last = true, value_name = "RENDER OPTIONS")]
    render: Vec<String>,
}

/// Fewest stored photons whose relaxed map the pipeline renders by default. Measured on the
/// glass sphere (`photonkit compare --methods pm,ours`, debug build, 2026-12-04): the relaxed
/// map was worse than the traced one at 655 and 2 000 stored photons (NRMSE 4.66 against 2.23,
/// 2.68 against 2.10; SSIM lower too) and better from 7 000 (2.03 against 2.40; at 20 000, 1.76
/// against 2.29). With so few photons each one's Kf = 16 neighbours span a large part of the
/// caustic, and repulsion spreads its peak.
pub const MIN_RELAX_PHOTONS: u64 = 5_000;

/// `photonkit render`'s arguments, parsed from the pipeline's command line for it.
#[derive(clap::Parser)]
struct RenderCommand {
    #[command(flatten)]
    args: super::render::Args,
}

/// The pipeline under `--memory budget`: every stage as its subcommand, each in a process of
/// its own (so that none inherits what an earlier one left allocated), from the previous
/// stage's file to its own, with `--memory` (the trace: its spool); the stage table as the
/// pipeline prints it in memory. The maps are those the pipeline makes in memory.
fn run_budgeted(a: &Args, budget: u64, file: &dyn Fn(&str) -> PathBuf) -> anyhow::Result<()> {
    let memory = budget.to_string();
    let path = |name: &str| file(name).display().to_string();
    let scene: Vec<String> =
        a.scene.iter().flat_map(|s| ["--scene".to_string(), s.display().to_string()]).collect();
    let mut trace = vec!["trace".to_string()];
    trace.extend(a.scene.iter().map(|s| s.display().to_string()));
    trace.extend(match a.stored {
        Some(n) => ["--stored".to_string(), n.to_string()],
        None => ["--photons".to_string(), a.photons.to_string()],
    });
    trace.extend([
        "--seed".to_string(),
        a.seed.to_string(),
        "--memory".into(),
        (budget / 4).min(DEFAULT_SPOOL_MEMORY).to_string(),
    ]);
    let with = |command: &str, input: &str, output: &str, extra: Vec<String>| {
        let mut v = vec![command.to_string(), path(input), "-o".into(), path(output)];
        if command != "collapse" {
            v.extend(["--memory".to_string(), memory.clone()]);
        }
        v.extend(extra);
        v
    };
    trace.extend(["-o".to_string(), path("traced.phm")]);
    let stages: [(&str, &str, Vec<String>); 5] = [
        ("trace", "traced.phm", trace),
        ("detect", "detected.phm", with("detect", "traced.phm", "detected.phm", a.detect.to_argv())),
        (
            "relax (params)",
            "relaxed-params.phm",
            with("relax", "detected.phm", "relaxed-params.phm", [a.relax.to_argv(), scene.clone()].concat()),
        ),
        ("collapse", "collapsed.phm", with("collapse", "relaxed-params.phm", "collapsed.phm", Vec::new())),
        (
            "relax (world)",
            "relaxed.phm",
            with("relax", "collapsed.phm", "relaxed.phm", [a.relax.to_argv(), scene.clone()].concat()),
        ),
    ];
    let exe = std::env::current_exe().context("finding the photonkit executable for the stages")?;
    let run = |label: &str, argv: &[String]| -> anyhow::Result<f64> {
        let t = Instant::now();
        let mut c = std::process::Command::new(&exe);
        if super::quiet() {
            c.arg("--quiet");
        }
        let status = c.args(argv).status().with_context(|| format!("starting the {label} stage"))?;
        anyhow::ensure!(status.success(), "the {label} stage failed (`photonkit {}`)", argv.join(" "));
        Ok(t.elapsed().as_secs_f64())
    };
    for (label, output, argv) in stages {
        let seconds = run(label, &argv)?;
        let photons = PhotonMap::open_unverified(&path(output))?.len();
        report(label, seconds, photons, &file(output), "")?;
    }
    let traced = PhotonMap::open_unverified(&path("traced.phm"))?.len() as u64;
    let rendered = render_source(a, traced);
    let mut argv = vec!["render".to_string(), path(rendered), "-o".into(), path("render.exr")];
    argv.extend(scene);
    if !a.render.iter().any(|o| o == "--memory" || o.starts_with("--memory=")) {
        argv.extend(["--memory".to_string(), memory.clone()]);
    }
    argv.extend(a.render.iter().cloned());
    let seconds = run("render", &argv)?;
    let photons = PhotonMap::open_unverified(&path(rendered))?.len();
    report("render", seconds, photons, &file("render.exr"), &format!("  (and render.png, from {rendered})"))
}

/// The map the pipeline renders: the relaxed one, or with fewer than `--min-relax-photons`
/// stored (and no `--relax-anyway`) the traced one, with a note saying why.
fn render_source(a: &Args, stored: u64) -> &'static str {
    if stored < a.min_relax_photons && !a.relax_anyway {
        super::note!(
            "note: only {stored} photons stored (fewer than --min-relax-photons {}): relaxation at this \
             count spreads the caustic instead of sharpening it, so the image is rendered from \
             traced.phm (relaxed.phm is written all the same; --relax-anyway renders it)",
            a.min_relax_photons
        );
        "traced.phm"
    } else {
        "relaxed.phm"
    }
}

/// A spinner on a terminal, nothing otherwise.
pub(super) fn spinner(what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(None, super::draw_target())
        .with_style(ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"));
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

/// One line of the stage table; under `--json`, a photon map's new history record.
fn report(stage: &str, seconds: f64, photons: usize, file: &Path, note: &str) -> anyhow::Result<()> {
    super::note!("{stage:<16} {seconds:>8.2} s {photons:>10} photons  {}{note}", file.display());
    if file.extension().is_some_and(|e| e == "phm") {
        super::print_record(&file.to_string_lossy())?;
    }
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let (scene, label, text) = super::trace::load_scene(a.scene.as_deref())?;
    anyhow::ensure!(a.photons >= 1 && a.stored != Some(0), "--photons and --stored need at least 1");
    let budget = a.stored.map_or(Budget::Emitted(a.photons), Budget::Stored);
    let dp = a.detect.apply(DetectParams::default());
    let rp = a.relax.apply(RelaxParams::default());
    std::fs::create_dir_all(&a.out_dir).with_context(|| format!("creating {}", a.out_dir.display()))?;
    let file = |name: &str| a.out_dir.join(name);
    let total = Instant::now();
    super::note!("{:<16} {:>10} {:>18}  output", "stage", "time", "");
    if let Some(budget) = a.memory {
        run_budgeted(&a, budget, &file)?;
        return finish(&file, total);
    }

    // Trace.
    let opts = TraceOptions {
        seed: a.seed,
        budget,
        spool: Some(Spool { dir: a.out_dir.clone(), memory: DEFAULT_SPOOL_MEMORY }),
        ..TraceOptions::default()
    };
    let bar = spinner("trace");
    let t = Instant::now();
    let traced = trace::trace(&scene, &opts, &|_, _| {});
    bar.finish_and_clear();
    let traced = traced?;
    anyhow::ensure!(
        traced.stored > 0,
        "no photon was stored from {} emitted: does light reach a diffuse surface through a mirror or glass?",
        traced.emitted
    );
    let mut info = trace::map_info(&scene, &opts, &traced, &label, &text);
    if let Some(scene_file) = &a.scene {
        trace::record_scene_location(&mut info, scene_file, &file("traced.phm"));
    }
    traced.write(Output::Path(file("traced.phm")), info)?;
    report(
        "trace",
        t.elapsed().as_secs_f64(),
        traced.stored as usize,
        &file("traced.phm"),
        &format!("  ({} emitted)", traced.emitted),
    )?;

    // Detect, relax, collapse, relax: in memory, each stage's map written as it is made.
    {
        let traced_map = PhotonMap::open_path(&file("traced.phm"))?;
        let params = PipelineParams {
            detect: dp,
            method: None,
            relax: rp,
            iterations: [rp.iterations, rp.iterations],
        };
        let bar = spinner("detect");
        let mut on_stage = |done: &StageDone, table: &PhotonTable| -> Result<(), PipelineError> {
            let name = match done.stage {
                Stage::Detect => "detected.phm",
                Stage::RelaxParams => "relaxed-params.phm",
                Stage::Collapse => "collapsed.phm",
                Stage::RelaxWorld => "relaxed.phm",
            };
            table.write(Output::Path(file(name)))?;
            let note = if done.summary.is_empty() { String::new() } else { format!("  ({})", done.summary) };
            bar.suspend(|| report(done.stage.label(), done.seconds, done.photons, &file(name), &note))
                .map_err(|e| PipelineError::Caller(format!("{e:#}")))
        };
        let progress = |p: pipeline::Progress| match p {
            pipeline::Progress::Started(stage) => bar.set_message(stage.label()),
            pipeline::Progress::Iteration(stage, m) => {
                bar.set_message(format!("{}: iteration {}", stage.label(), m.iteration + 1))
            }
            pipeline::Progress::Note(note) => bar.suspend(|| super::note!("note: {note}")),
        };
        let relaxed = pipeline::run(&traced_map.view(), Some(&scene), &params, &mut on_stage, &progress);
        bar.finish_and_clear();
        relaxed?;
        drop(traced_map);
    }

    // Render, with the render subcommand's defaults (the scene's camera, 600×600, 4 samples
    // per pixel, K = 15 Epanechnikov): the relaxed map, or with too few photons the traced one.
    let rendered = render_source(&a, traced.stored);
    // The options after `--` are parsed as `photonkit render`'s; the map is the one in memory.
    let mut argv: Vec<std::ffi::OsString> =
        vec!["render".into(), file(rendered).into(), "-o".into(), file("render.exr").into()];
    argv.extend(a.render.iter().map(Into::into));
    let args = RenderCommand::try_parse_from(argv)?.args;
    // The map as written (its header names the file), memory-mapped.
    let map = PhotonMap::open_path(&file(rendered))?;
    let t = Instant::now();
    let other_scene = match &args.scene {
        Some(p) => Some(super::render::load_scene(None, Some(p))?),
        None => None,
    };
    let scene_name = a.scene.as_ref().map_or(DEFAULT_SCENE_NAME.to_string(), |p| p.display().to_string());
    let scene = other_scene.as_ref().map_or((&scene, scene_name.as_str()), |(s, n)| (s, n.as_str()));
    super::render::render_view(&args, &map.view(), Some(scene))?;
    report(
        "render",
        t.elapsed().as_secs_f64(),
        map.len(),
        &file("render.exr"),
        &format!("  (and render.png, from {rendered})"),
    )?;

    finish(&file, total)
}

/// The table's total and where to look.
fn finish(file: &dyn Fn(&str) -> PathBuf, total: Instant) -> anyhow::Result<ExitCode> {
    super::note!("{:<16} {:>8.2} s", "total", total.elapsed().as_secs_f64());
    super::note!(
        "look at {} (or the EXR), and at the photons with `photonkit inspect {}`",
        file("render.png").display(),
        file("relaxed.phm").display()
    );
    Ok(ExitCode::SUCCESS)
}
