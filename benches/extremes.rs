//! The heavy half of the numerical-extremes suite (issue 7; the light half is
//! `tests/suite/extremes.rs`): many photons at extreme scene scales, and Kc = 1000.
//!
//! `cargo bench --bench extremes`. Environment:
//! - `PHOTONKIT_BENCH_PHOTONS` (default 10 000 000): photons emitted from the default scene
//!   scaled by `PHOTONKIT_BENCH_SCALE` (default 1e-6), then trace → detect (param-pca, Kc = 50)
//!   → one relax iteration (world + params) → render (64×64, full radiance, 1 spp);
//! - `PHOTONKIT_BENCH_KC_PHOTONS` (default 1 000 000): photons stored from the default scene
//!   scaled by `PHOTONKIT_BENCH_KC_SCALE` (default 1e6), then detect with Kc = 1000.
//!
//! Every output is checked finite (the bench panics otherwise). Printed: per stage the process
//! CPU time (user + system of all threads, /proc/self/stat) and wall time, the CPU µs per photon
//! (the cost per photon per core, which a loaded machine does not inflate the way it inflates
//! wall time), and the peak resident set size (VmHWM) after each stage.

use std::time::Instant;

use glam::Vec3;
use photonkit::detect::{self, DetectInput, DetectParams};
use photonkit::relax::{self, Constraint, RelaxParams};
use photonkit::render::estimate::{PhotonData, PhotonLookup};
use photonkit::render::{Mode, RenderOptions, Renderer, View};
use photonkit::scene::Scene;
use photonkit::spatial::{ParamColumn, PointSet, Space, SpatialIndex};
use photonkit::trace::{self, Budget, TraceOptions};

/// CPU seconds used by this process so far, all threads (10 ms resolution).
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// Peak resident set size of this process so far, MB.
fn peak_rss_mb() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn env<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().and_then(|s| s.parse().ok()).unwrap_or(default)
}

/// Runs `f`, prints its table row (cost per `per` photons) and returns its result.
fn stage<T>(name: &str, per: usize, f: impl FnOnce() -> T) -> T {
    let (c, t) = (cpu(), Instant::now());
    let out = f();
    let (c, w) = (cpu() - c, t.elapsed().as_secs_f64());
    println!(
        "| {name} | {per} | {c:.1} | {w:.1} | {:.2} | {:.0} |",
        c / per.max(1) as f64 * 1e6,
        peak_rss_mb()
    );
    out
}

fn finite3(v: &[[f32; 3]]) -> bool {
    v.iter().flatten().all(|x| x.is_finite())
}

// Long because it is the benchmark read top to bottom: each measurement set up, timed and
// printed in turn, as the module docs list them.
fn main() {
    let emitted: u64 = env("PHOTONKIT_BENCH_PHOTONS", 10_000_000);
    let scale: f32 = env("PHOTONKIT_BENCH_SCALE", 1e-6);
    let kc_photons: u64 = env("PHOTONKIT_BENCH_KC_PHOTONS", 1_000_000);
    let kc_scale: f32 = env("PHOTONKIT_BENCH_KC_SCALE", 1e6);
    println!("{} threads", rayon::current_num_threads());
    println!("\n| stage | photons | CPU s | wall s | CPU µs per photon | peak RSS MB |");
    println!("| --- | --- | --- | --- | --- | --- |");

    // Many photons at a tiny (or huge) scale.
    let scene = Scene::default_scene().scaled(scale);
    let opts = TraceOptions { budget: Budget::Emitted(emitted), ..TraceOptions::default() };
    let traced = stage(&format!("trace, scale {scale:e} (per emitted)"), emitted as usize, || {
        trace::trace(&scene, &opts, &|_, _| {}).expect("trace")
    });
    let ph = traced.photons().expect("photons held in memory");
    drop(traced);
    let n = ph.position.len();
    assert!(finite3(&ph.position) && finite3(&ph.flux) && finite3(&ph.normal), "trace: not finite");
    let dims = [ph.params.len().checked_div(n).unwrap_or(0) as u32];
    let params = ParamColumn { values: &ph.params, stride: dims[0] as usize, dims: &dims };
    let input = DetectInput {
        positions: &ph.position,
        normals: Some(&ph.normal),
        flux: Some(&ph.flux),
        params: Some(params),
        emitters: None,
        pages: Default::default(),
    };
    let d = stage("detect, param-pca, Kc = 50", n, || {
        detect::detect(&input, &DetectParams::default(), &|_| {}).expect("detect")
    });
    assert!(finite3(&d.basis_u) && finite3(&d.basis_v) && d.lambda2.iter().all(|x| x.is_finite()));
    let constrained = d.summary.constrained_fraction();

    let rp = RelaxParams { iterations: 1, ..RelaxParams::default() };
    let r_param = d.r_param.clone().expect("param-pca gives r_param");
    let mut pos = ph.position.clone();
    let measure = stage("relax, 1 iteration, world + params (Kf = 16)", n, || {
        let pts = PointSet { positions: &ph.position, params: Some(params), emitters: None };
        let index = SpatialIndex::build(&pts, Space::WorldParams).expect("index");
        let search = relax::IndexSearch { index: &index, points: &pts, radius: Some(&r_param) };
        let constraint = Constraint::Basis { u: &d.basis_u, v: &d.basis_v };
        relax::iterate(&mut pos, &search, constraint, &rp, 0, &mut relax::Scratch::default())
    });
    assert!(finite3(&pos), "relax: not finite");
    let moved = pos
        .iter()
        .zip(&ph.position)
        .map(|(a, b)| Vec3::from(*a).distance(Vec3::from(*b)))
        .fold(0f32, f32::max);
    drop(d);

    let img = stage("render 64×64, full, 1 spp (index + render)", n, || {
        let data = PhotonData { positions: &pos, flux: &ph.flux, normals: Some(&ph.normal) };
        let lookup = PhotonLookup::new("bench", data).expect("lookup");
        let camera = scene.camera().cloned().expect("camera");
        let opts =
            RenderOptions { width: 64, height: 64, spp: 1, mode: Mode::Full, ..RenderOptions::default() };
        let r = Renderer {
            view: View::Scene { scene: &scene, camera },
            photons: Some(&lookup),
            diagnostic: None,
            opts,
        };
        r.render(&|_| {}).expect("render").0
    });
    assert!(img.pixels.iter().all(|p| p.is_finite() && p.min_element() >= 0.0), "render: not finite");
    let mean = img.pixels.iter().map(|p| p.element_sum() as f64).sum::<f64>() / img.pixels.len() as f64 / 3.0;
    println!(
        "\nscale {scale:e}: {emitted} emitted, {n} stored; {:.1} % constrained (Kc = 50); relax: largest move \
         {:.2e} m = {:.2e} scene extents, local nearest-neighbour spread {:.3}; mean pixel × scale² {:.4e} W/(m² sr)",
        100.0 * constrained,
        moved,
        moved / scene.extent(),
        measure.local_nn_cv,
        mean * (scale as f64).powi(2),
    );
    drop((ph, pos));

    // Kc = 1000 on many photons at the other extreme.
    let scene = Scene::default_scene().scaled(kc_scale);
    let opts = TraceOptions { budget: Budget::Stored(kc_photons), ..TraceOptions::default() };
    let traced = trace::trace(&scene, &opts, &|_, _| {}).expect("trace");
    let ph = traced.photons().expect("photons held in memory");
    let n = ph.position.len();
    let params = ParamColumn { values: &ph.params, stride: dims[0] as usize, dims: &dims };
    let input = DetectInput {
        positions: &ph.position,
        normals: Some(&ph.normal),
        flux: Some(&ph.flux),
        params: Some(params),
        emitters: None,
        pages: Default::default(),
    };
    let d = stage(&format!("detect, param-pca, Kc = 1000, scale {kc_scale:e}"), n, || {
        detect::detect(&input, &DetectParams { kc: 1000, ..DetectParams::default() }, &|_| {})
            .expect("detect")
    });
    assert!(finite3(&d.basis_u) && finite3(&d.basis_v) && d.lambda2.iter().all(|x| x.is_finite()));
    println!(
        "\nKc = 1000, scale {kc_scale:e}: {n} stored; {:.1} % constrained, mean factor {:.3}; {} measured, {} too few, \
         {} coincident",
        100.0 * d.summary.constrained_fraction(),
        d.summary.mean_factor,
        d.summary.measured,
        d.summary.too_few,
        d.summary.coincident
    );
}
