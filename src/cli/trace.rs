//! `photonkit trace`: caustic photons from a scene file, with their trajectory parameters.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::format::Output;
use photonkit::scene::{Scene, SceneFile};
use photonkit::trace::{self, Budget, Shard, Spool, StorePolicy, TraceOptions};

/// Trace photons from the emitters of a scene and store the caustic ones.
///
/// Photon number i leaves an emitter chosen in proportion to power, from the i-th point of a
/// Halton sequence (rotated by --seed), and is traced through mirrors and glass to the first
/// diffuse surface. It is stored there if it met at least one specular surface on the way
/// (a caustic photon, path L S+ D), with its position, normal, flux (W), incident direction,
/// emitter, trajectory parameters ((u, v) on a collimated emitter, or the unit emission
/// direction of a point or spot light), path length, bounce count, emission number and
/// surface id. The output is the same for a given seed whatever the number of threads.
///
/// Scene files are TOML in metres and watts, or glTF 2.0 (.gltf, .glb: meshes, cameras,
/// KHR_lights_punctual lights, transmissive, metallic and diffuse materials): see docs/scene.md
/// and samples/scenes/. --dry-run prints what was understood of a scene and traces nothing.
#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    photonkit trace -o sphere.phm                                  # the embedded default scene\n  \
    photonkit trace samples/scenes/prism.toml --photons 20000000 -o prism.phm\n  \
    photonkit trace scene.toml --stored 1000000 -o map.phm\n  \
    photonkit trace samples/scenes/gltf/cognac.glb -o cognac.phm      # a glTF 2.0 scene\n  \
    photonkit trace scene.gltf --dry-run        # what was understood: objects, materials, lights, camera\n  \
    photonkit trace scene.toml --photons 1e8 --shard 0/4 -o part0.phm   # one of four machines\n  \
    photonkit merge part0.phm part1.phm part2.phm part3.phm -o map.phm")]
pub struct Args {
    /// Scene file: TOML, or glTF 2.0 (.gltf or .glb); without it, the embedded default scene
    /// (a glass sphere above a floor under a vertical collimated beam,
    /// samples/scenes/glass-sphere.toml).
    scene: Option<PathBuf>,
    /// Read the scene, print what was understood of it (objects, materials, emitters with the
    /// number of trajectory parameters each gives its photons, camera) and trace nothing.
    #[arg(long)]
    dry_run: bool,
    /// Output photon map (`-` for standard output); required.
    #[arg(short, long, value_name = "FILE")]
    output: Option<String>,
    /// Number of photons to emit (e.g. 1000000 or 1e6). The default when neither --photons
    /// nor --stored is given is 1e6.
    #[arg(long, value_name = "N", value_parser = parse_count, conflicts_with = "stored")]
    photons: Option<u64>,
    /// Emit photons until N are stored (instead of a fixed number emitted).
    #[arg(long, value_name = "N", value_parser = parse_count, conflicts_with = "shard")]
    stored: Option<u64>,
    /// Seed of the emission sequence and of the Fresnel and Russian-roulette choices.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Trace only slice i of n of the emission numbers (0 ≤ i < n); join the slices with
    /// `photonkit merge`, which gives the file a single run gives.
    #[arg(long, value_name = "i/n", value_parser = parse_shard)]
    shard: Option<Shard>,
    /// Which photons to store: `caustic` (at least one specular interaction before the
    /// diffuse hit) or `direct` (caustic photons and those arriving straight from an emitter).
    #[arg(long, value_name = "WHAT", default_value = "caustic", value_parser = ["caustic", "direct"])]
    store: String,
    /// Number of worker threads (default: all cores, or RAYON_NUM_THREADS).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Drop a photon after this many specular interactions.
    #[arg(long, value_name = "N", default_value_t = 64)]
    max_bounces: u32,
    /// Memory for stored photons (e.g. 512M, 4G, 2GiB). Beyond it they are spooled to unnamed
    /// temporary files beside the output (removed however the run ends) and the map is
    /// written from there: the photon count is bounded by the disk, not the memory, and the
    /// file is the same either way.
    #[arg(long, value_name = "SIZE", default_value = "256MiB", value_parser = super::parse_memory)]
    memory: u64,
}

/// A count written as an integer or in scientific notation (`20000000`, `2e7`).
pub(crate) fn parse_count(s: &str) -> Result<u64, String> {
    if let Ok(n) = s.parse::<u64>() {
        return Ok(n);
    }
    match s.parse::<f64>() {
        Ok(x) if x >= 0.0 && x.fract() == 0.0 && x < 1.8e19 => Ok(x as u64),
        _ => Err(format!("'{s}' is not a whole number of photons")),
    }
}

fn parse_shard(s: &str) -> Result<Shard, String> {
    let (i, n) = s.split_once('/').ok_or_else(|| format!("'{s}': write the shard as i/n, e.g. 0/4"))?;
    let (index, count) = (i.trim().parse::<u64>(), n.trim().parse::<u64>());
    match (index, count) {
        (Ok(index), Ok(count)) if index < count => Ok(Shard { index, count }),
        _ => Err(format!("'{s}': needs whole numbers with 0 ≤ i < n")),
    }
}

/// Where a run writing to `output` spools photons: the output's directory (the disk the user
/// chose for them), or the system's temporary directory for standard output.
pub(crate) fn spool_dir(output: &str) -> PathBuf {
    match Output::parse(output) {
        Output::Path(p) => photonkit::format::folder_of(&p).to_path_buf(),
        Output::Stdout => std::env::temp_dir(),
    }
}

/// The scene at `path` (TOML or glTF) or the embedded default, with its name for records and
/// the bytes it was read from ([`SceneFile::content`]); tells the user how a glTF file was read
/// (notes) and, in one warning, what in it is not honoured.
pub(crate) fn load_scene(path: Option<&std::path::Path>) -> anyhow::Result<(Scene, String, Vec<u8>)> {
    let f = SceneFile::read_or_default(path)?;
    tell_about_scene(&f.notes, f.warning());
    Ok((f.scene, f.name, f.content))
}

/// Prints a scene file's notes (not under --quiet) and its warning.
pub(crate) fn tell_about_scene(notes: &[String], warning: Option<String>) {
    for n in notes {
        super::note!("photonkit: note: {n}");
    }
    if let Some(w) = warning {
        eprintln!("photonkit: warning: {w}");
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    // The scene first: a missing or broken scene is the first thing to fix.
    let (scene, label, text) = load_scene(a.scene.as_deref())?;
    if a.dry_run {
        print!("{label}\n{}", photonkit::scene::describe(&scene));
        return Ok(ExitCode::SUCCESS);
    }
    let Some(output) = a.output.clone() else {
        // A usage error, as clap's own (exit status 2).
        eprintln!(
            "photonkit trace: error: --output FILE is required (the photon map to write, or - for standard output)"
        );
        return Ok(ExitCode::from(2));
    };
    super::refuse_input_as_output(&output)?;
    let budget = match (a.photons, a.stored) {
        (_, Some(0)) | (Some(0), _) => bail!("--photons and --stored need at least 1"),
        (_, Some(n)) => Budget::Stored(n),
        (Some(n), None) => Budget::Emitted(n),
        (None, None) => Budget::Emitted(1_000_000),
    };
    let opts = TraceOptions {
        seed: a.seed,
        budget,
        store: if a.store == "direct" { StorePolicy::Direct } else { StorePolicy::Caustic },
        shard: a.shard,
        max_bounces: a.max_bounces,
        spool: Some(Spool { dir: spool_dir(&output), memory: a.memory }),
    };

    let total = match (budget, a.shard) {
        (Budget::Emitted(n), Some(s)) => Some(s.range(n).end - s.range(n).start),
        (Budget::Emitted(n), None) => Some(n),
        (Budget::Stored(_), _) => None,
    };
    let bar = ProgressBar::with_draw_target(total, super::draw_target());
    bar.set_style(
        ProgressStyle::with_template(
            "trace {bar:30} {human_pos}/{human_len} emitted, {msg} stored  {rate} {elapsed} (eta {eta})",
        )
        .expect("valid template")
        .with_key("rate", |s: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = write!(w, "{:.2} M/s", s.per_sec() / 1e6);
        }),
    );
    let stored = AtomicU64::new(0);
    let t = Instant::now();
    let progress = |e: u64, s: u64| {
        let s = stored.fetch_add(s, Ordering::Relaxed) + s;
        bar.inc(e);
        bar.set_message(indicatif::HumanCount(s).to_string());
    };
    let traced = match a.threads {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .context("starting the worker threads")?
            .install(|| trace::trace(&scene, &opts, &progress)),
        None => trace::trace(&scene, &opts, &progress),
    };
    bar.finish_and_clear();
    let traced = traced?;
    let secs = t.elapsed().as_secs_f64();
    if traced.stored == 0 && a.shard.is_none() {
        eprintln!(
            "photonkit trace: warning: no photon was stored (does light reach a diffuse surface through a mirror or glass?)"
        );
    }
    let mut info = trace::map_info(&scene, &opts, &traced, &label, &text);
    if let (Some(scene_file), Output::Path(out)) = (&a.scene, Output::parse(&output)) {
        trace::record_scene_location(&mut info, scene_file, &out);
    }
    traced.write(Output::parse(&output), info)?;
    let traced_n = traced.range.end - traced.range.start;
    super::note!(
        "photonkit trace: {} emitted, {} stored in {:.2} s ({:.2} M emitted/s, {:.2} M stored/s){}",
        traced_n,
        traced.stored,
        secs,
        traced_n as f64 / secs / 1e6,
        traced.stored as f64 / secs / 1e6,
        if traced.bounce_limited > 0 {
            format!("; {} dropped at the bounce limit", traced.bounce_limited)
        } else {
            String::new()
        }
    );
    super::print_record(&output)?;
    Ok(ExitCode::SUCCESS)
}
