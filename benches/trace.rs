//! Tracer throughput (issue 3): emitted photons per second per core on the sample scenes.
//!
//! `cargo bench --bench trace` — the prism (`samples/scenes/prism.toml`, the paper's Fig. 6)
//! with 20 M emitted photons (PHOTONKIT_BENCH_PHOTONS=N changes it), then every other sample
//! scene with 2 M each (PHOTONKIT_BENCH_OTHERS=N), through `photonkit::trace::trace` with the
//! default options (seed 1, caustic photons, 64 bounces) on rayon's pool.
//! PHOTONKIT_BENCH_ONLY=NAME,… traces only the scenes of those file stems (e.g. `prism`), so a
//! profiler such as `valgrind --tool=callgrind` counts no other scene's loading.
//! PHOTONKIT_BENCH_REPEAT=N traces each scene N times in a row and adds a line per scene with
//! the median, the range and how many runs reached the goal: on a shared machine single runs
//! spread widely.
//!
//! Rates are photons per CPU second of the whole process (user + system, /proc/self/stat),
//! i.e. per core: other jobs sharing the machine inflate wall-clock time but not this. The
//! paper traced 20 M photons of its prism scene in 12.3 s on 7 cores (≈ 0.23 M/s per core);
//! the goal is ≥ 4 M/s per core. The clock speed one thread got before and after is printed
//! too (`common/clock.rs`): on a shared virtual machine it varies, and the rates with it.

#[path = "common/clock.rs"]
mod clock;

use std::path::Path;
use std::time::Instant;

use photonkit::scene::Scene;
use photonkit::trace::{self, Budget, TraceOptions};

/// CPU seconds used by this process so far (user + system; 10 ms resolution).
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn env_count(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|s| s.parse::<f64>().ok()).map_or(default, |x| x as u64)
}

/// One scene's runs in a line: median (the mean of the middle two for an even count), range,
/// and how many reached the goal.
fn summary(name: &str, rates: &mut [f64]) -> String {
    rates.sort_by(f64::total_cmp);
    let k = rates.len();
    let median = (rates[(k - 1) / 2] + rates[k / 2]) / 2.0;
    let met = rates.iter().filter(|&&r| r >= GOAL_M_PER_S_PER_CORE).count();
    format!(
        "{name}: median {median:.2} M emitted/s per core over {k} runs (range {:.2}–{:.2}); \
         {met} of {k} at or above the goal of {GOAL_M_PER_S_PER_CORE}",
        rates[0],
        rates[k - 1]
    )
}

/// Paper: 20 M photons in 12.3 s on 7 cores.
const PAPER_M_PER_S_PER_CORE: f64 = 20.0 / (12.3 * 7.0);
const GOAL_M_PER_S_PER_CORE: f64 = 4.0;

fn main() {
    let prism_n = env_count("PHOTONKIT_BENCH_PHOTONS", 20_000_000);
    let other_n = env_count("PHOTONKIT_BENCH_OTHERS", 2_000_000);
    let repeat = env_count("PHOTONKIT_BENCH_REPEAT", 1).max(1) as usize;
    let mut summaries = Vec::new();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("samples/scenes")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    if let Ok(only) = std::env::var("PHOTONKIT_BENCH_ONLY") {
        let only: Vec<&str> = only.split(',').collect();
        files.retain(|p| p.file_stem().is_some_and(|s| only.iter().any(|o| s == *o)));
    }
    // The prism first: it is the headline figure.
    files.sort_by_key(|p| p.file_stem().is_none_or(|s| s != "prism"));

    println!("tracer throughput: {} rayon threads", rayon::current_num_threads());
    println!("{}", clock::line("before"));
    println!(
        "paper: {PAPER_M_PER_S_PER_CORE:.2} M emitted/s per core (20 M in 12.3 s on 7 cores); \
         goal ≥ {GOAL_M_PER_S_PER_CORE} M/s per core\n"
    );
    println!(
        "| scene | triangles | emitted | stored | CPU s | wall s | M emitted/s per core | × paper | share of goal |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for path in files {
        let name = path.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned());
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let n = if name == "prism" { prism_n } else { other_n };
        let opts = TraceOptions { budget: Budget::Emitted(n), ..TraceOptions::default() };
        let mut rates = Vec::with_capacity(repeat);
        for _ in 0..repeat {
            let (c0, t0) = (cpu(), Instant::now());
            let traced = trace::trace(&scene, &opts, &|_, _| {}).unwrap_or_else(|e| panic!("{name}: {e}"));
            let (c, w) = (cpu() - c0, t0.elapsed().as_secs_f64());
            let rate = n as f64 / c.max(0.01) / 1e6;
            println!(
                "| {name} | {} | {n} | {} | {c:.2} | {w:.2} | **{rate:.2}** | {:.1}× | {:.0} % |",
                scene.triangle_count(),
                traced.stored,
                rate / PAPER_M_PER_S_PER_CORE,
                100.0 * rate / GOAL_M_PER_S_PER_CORE
            );
            drop(traced);
            rates.push(rate);
        }
        if repeat > 1 {
            summaries.push(summary(&name, &mut rates));
        }
    }
    if !summaries.is_empty() {
        println!("\n{}", summaries.join("\n"));
    }
    println!("\n{}", clock::line("after"));
}
