//! Per-photon costs of detect (issue 4) and relax (issue 5) on a traced caustic, per core.
//!
//! `cargo bench --bench stages` (PHOTONKIT_BENCH_PHOTONS=N emitted; default 1.43 M, which
//! stores about 1 M caustic photons from the embedded default scene). PHOTONKIT_BENCH_ONLY=
//! `trace` (only), or a comma list of `detect`, `density`, `world-pca`, `gradient`, `relax-params`, `relax-world`
//! runs only those rows (for profilers such as `valgrind --tool=callgrind`, which count
//! instructions repeatably on a shared machine).
//!
//! Detect relabels the photons in spatial order inside (`spatial::order`); relax does it once
//! per run, which the bench does as `relax::relax_map_on` does and reports as a row.
//!
//! Costs are CPU seconds of the whole process (user + system, /proc/self/stat) divided by the
//! photons (and iterations): the cost per photon per core, which other processes sharing the
//! machine do not inflate the way they inflate wall-clock time. Wall time is printed beside,
//! and the clock speed the machine gave one thread before and after (`common/clock.rs`).
//! The paper's figures (7-core Core i7, 863 k photons): detection 5.3 s (≈ 43 µs per photon
//! per core), relaxation 28.4 s for 14 iterations (≈ 16.5 µs per photon-iteration per core).

#[path = "common/clock.rs"]
mod clock;

use std::time::Instant;

use photonkit::detect::{self, DetectInput, DetectParams};
use photonkit::relax::{self, Constraint, RelaxParams};
use photonkit::scene::Scene;
use photonkit::spatial::order::{locality_order, permuted, unpermuted};
use photonkit::spatial::{ParamColumn, PointSet, Space, SpatialIndex};
use photonkit::trace::{self, Budget, TraceOptions};

/// CPU seconds used by this process so far (10 ms resolution).
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// (CPU seconds, wall seconds) of `f`.
fn measure<T>(f: impl FnOnce() -> T) -> (T, f64, f64) {
    let (c, t) = (cpu(), Instant::now());
    let out = f();
    (out, cpu() - c, t.elapsed().as_secs_f64())
}

// Long because it is the benchmark read top to bottom: each measurement set up, timed and
// printed in turn, as the module docs list them.
fn main() {
    let emitted: u64 =
        std::env::var("PHOTONKIT_BENCH_PHOTONS").ok().and_then(|s| s.parse().ok()).unwrap_or(1_430_000);
    let threads = rayon::current_num_threads();
    let scene = Scene::default_scene();
    let opts = TraceOptions { budget: Budget::Emitted(emitted), ..TraceOptions::default() };
    let (traced, c, w) = measure(|| trace::trace(&scene, &opts, &|_, _| {}).unwrap());
    let ph = traced.photons().expect("photons held in memory");
    let n = ph.len();
    println!("default scene: {emitted} emitted, {n} stored; {threads} threads");
    println!("{}", clock::line("before"));
    println!("\n| stage | CPU s | wall s | µs per photon (per iteration) per core | paper | goal |");
    println!("| --- | --- | --- | --- | --- | --- |");
    let row = |stage: &str, c: f64, w: f64, per: f64, paper: &str, goal: &str| {
        println!("| {stage} | {c:.2} | {w:.2} | {:.2} | {paper} | {goal} |", c / per * 1e6);
    };
    row("trace", c, w, emitted as f64, "-", "-");
    let only = std::env::var("PHOTONKIT_BENCH_ONLY").ok();
    if only.as_deref() == Some("trace") {
        return;
    }

    let dims = [traced.param_dims];
    let params = ParamColumn { values: &ph.params, stride: traced.param_dims as usize, dims: &dims };
    let input = DetectInput {
        positions: &ph.position,
        normals: Some(&ph.normal),
        flux: Some(&ph.flux),
        params: Some(params),
        emitters: None,
        pages: Default::default(),
    };
    let runs = |what: &str| only.as_deref().is_none_or(|o| o.split(',').any(|x| x == what));
    let p = DetectParams::default();
    // Relax needs detect's constraint basis and r_param, so detect always runs; its row is
    // printed only when asked for.
    let (d, c, w) = measure(|| detect::detect(&input, &p, &|_| {}).unwrap());
    if runs("detect") {
        row("detect, param-pca (Kc = 50)", c, w, n as f64, "43", "≤ 4");
    }
    if runs("world-pca") {
        let wp = DetectParams { method: detect::Method::WorldPca, ..p };
        let (_, c, w) = measure(|| detect::detect(&input, &wp, &|_| {}).unwrap());
        row("detect, world-pca", c, w, n as f64, "-", "-");
    }
    if runs("gradient") {
        let gp = DetectParams { method: detect::Method::Gradient, ..p };
        let (_, c, w) = measure(|| detect::detect(&input, &gp, &|_| {}).unwrap());
        row("detect, gradient (2009 baseline)", c, w, n as f64, "≈ 74", "-");
    }

    // Detect relabels its photons in spatial order inside (its rows include that); relax_map
    // does so once per run, with the columns it reads: done here as it does, and its cost
    // spread over the run's iterations.
    let ((position, param_values, basis_u, basis_v, r_param, order), rc, rw) = measure(|| {
        let order = locality_order(&ph.position);
        (
            permuted(&ph.position, &order, 1),
            permuted(&ph.params, &order, params.stride),
            permuted(&d.basis_u, &order, 1),
            permuted(&d.basis_v, &order, 1),
            permuted(d.r_param.as_deref().unwrap(), &order, 1),
            order,
        )
    });
    let params = ParamColumn { values: &param_values, ..params };
    if runs("density") {
        let points = PointSet { positions: &position, params: Some(params), emitters: None };
        let (_, c, w) = measure(|| detect::param_radius(&points, 50, 50, 3.0, &|_| {}).unwrap());
        row("  of which density ρ and r_param (Eq. 1)", c, w, n as f64, "-", "-");
    }

    // Relaxation, 7 iterations in each space, as relax_map runs them.
    let rp = RelaxParams::default();
    let constraint = Constraint::Basis { u: &basis_u, v: &basis_v };
    for (label, space) in
        [("relax, world+params (Kf = 16)", Space::WorldParams), ("relax, world", Space::World)]
            .into_iter()
            .filter(|(_, s)| runs(if *s == Space::WorldParams { "relax-params" } else { "relax-world" }))
    {
        let mut pos = position.clone();
        let mut snapshot = pos.clone();
        let mut scratch = relax::Scratch::default();
        let mut index: Option<SpatialIndex> = None;
        let (mut build_c, mut build_w) = (0.0, 0.0);
        let (relaxed, c, w) = measure(|| {
            for it in 0..rp.iterations {
                // As relax_map: the index is brought up to the snapshot (built, refitted, or
                // rebuilt every `relax::REBUILD_EVERY` iterations; the "index rebuilds" row).
                snapshot.copy_from_slice(&pos);
                let pts = PointSet {
                    positions: &snapshot,
                    params: if space == Space::WorldParams { Some(params) } else { None },
                    emitters: None,
                };
                let ((), bc, bw) =
                    measure(|| relax::index_positions(&mut index, &pts, space, None, it, false).unwrap());
                build_c += bc;
                build_w += bw;
                let search = relax::IndexSearch {
                    index: index.as_ref().unwrap(),
                    points: &pts,
                    radius: if space == Space::WorldParams { Some(&r_param) } else { None },
                };
                relax::iterate(&mut pos, &search, constraint, &rp, it, &mut scratch);
            }
            unpermuted(&pos, &order)
        });
        assert_eq!(relaxed.len(), n);
        let per = (n * rp.iterations) as f64;
        row(label, c + rc, w + rw, per, "16.5", "≤ 1.5");
        row("  of which relabelling into spatial order and back", rc, rw, per, "-", "-");
        row("  of which index rebuilds", build_c, build_w, per, "-", "-");
        row("  of which iterations (search, force, move)", c - build_c, w - build_w, per, "-", "-");
    }
    println!("\n{}", clock::line("after"));
}
