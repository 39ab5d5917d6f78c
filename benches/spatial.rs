//! The spatial index: photonkit's kd-tree over {x, y, z, params} with the parameter range test
//! inside the traversal, against kiddo 6 with over-fetch and filter (issue 4's decision).
//!
//! `cargo bench --bench spatial` (PHOTONKIT_BENCH_PHOTONS=N changes the size; default 1 M;
//! PHOTONKIT_BENCH_SET=scene takes the default scene's caustic photons instead of the
//! synthetic set; PHOTONKIT_BENCH_ONLY=photonkit skips kiddo).
//!
//! The photons: `synthetic::collimated_cusp` (one collimated emitter, (u, v) parameters, three
//! overlapping filaments between two folds). Each query workload runs on one thread over
//! every photon, in the index's leaf order, so the figures are per query per core:
//!
//! - **density**: the Kc = 50 nearest in parameter space (Eq. 1's ρ);
//! - **constrained Kc = 50**: world-space neighbours within r_param = 3·r_50 (Eq. 1), detect's query;
//! - **constrained Kf = 16**: the same restriction, relaxation's first phase;
//! - **world Kf = 16**: world-space neighbours, relaxation after collapse.
//!
//! kiddo has no predicate query: it fetches k' world neighbours, keeps those within r_param,
//! and doubles k' until k survive (exact, since every photon not fetched is farther). Every
//! workload is checked on a sample against the brute-force scan (photonkit exactly; kiddo by
//! distance, since it breaks ties its own way).

use std::num::NonZero;
use std::time::Instant;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use photonkit::spatial::{Neighbours, ParamColumn, PointSet, Space, SpatialIndex, brute_force_knn};

/// CPU seconds this thread has run (user + system, from /proc; 10 ms resolution): other
/// processes sharing the machine inflate wall-clock times but not this.
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// A stopwatch reading thread CPU time.
struct Clock(f64);

impl Clock {
    fn start() -> Self {
        Clock(cpu())
    }
    fn secs(&self) -> f64 {
        cpu() - self.0
    }
}

fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

struct Kiddo {
    world: ImmutableKdTree<f32, 3>,
    params: ImmutableKdTree<f32, 2>,
}

/// kiddo's answer to the constrained query: over-fetch world neighbours and filter.
fn kiddo_constrained(
    t: &ImmutableKdTree<f32, 3>,
    set: &PointSet,
    q: [f32; 3],
    qp: &[f32],
    r: f32,
    k: usize,
    out: &mut Vec<(f32, u32)>,
) -> usize {
    let n = set.len();
    let mut fetch = (2 * k).min(n);
    let r2 = r * r;
    loop {
        out.clear();
        let found = t.query(&q).nearest_n::<SquaredEuclidean<f32>>(NonZero::new(fetch).unwrap()).execute();
        for f in &found {
            let p = set.params_of(f.item as usize);
            let d = (p[0] - qp[0]) * (p[0] - qp[0]) + (p[1] - qp[1]) * (p[1] - qp[1]);
            if d <= r2 {
                out.push((f.distance, f.item));
                if out.len() == k {
                    return fetch;
                }
            }
        }
        if fetch >= n {
            return fetch;
        }
        fetch = (fetch * 2).min(n);
    }
}

/// Positions and (u, v) parameters of the default scene's caustic photons, about `n` of them.
fn scene_photons(n: usize) -> photonkit::synthetic::SyntheticMap {
    use photonkit::trace::{Budget, TraceOptions};
    let scene = photonkit::scene::Scene::default_scene();
    let opts = TraceOptions { budget: Budget::Emitted((n as f64 * 1.43) as u64), ..TraceOptions::default() };
    let t = photonkit::trace::trace(&scene, &opts, &|_, _| {}).unwrap();
    assert_eq!(t.param_dims, 2, "the default scene's emitter is collimated");
    let ph = t.photons().expect("photons held in memory");
    photonkit::synthetic::SyntheticMap {
        position: ph.position.to_vec(),
        params: ph.params.to_vec(),
        param_dims: 2,
        ..Default::default()
    }
}

// Long because it is the benchmark read top to bottom: each measurement set up, timed and
// printed in turn, as the module docs list them.
fn main() {
    let n: usize =
        std::env::var("PHOTONKIT_BENCH_PHOTONS").ok().and_then(|s| s.parse().ok()).unwrap_or(1_000_000);
    // PHOTONKIT_BENCH_ONLY=photonkit skips kiddo (for profiling).
    let with_kiddo = std::env::var("PHOTONKIT_BENCH_ONLY").map_or(true, |s| s != "photonkit");
    let (kc, kf, beta) = (50usize, 16usize, 3.0f32);
    // PHOTONKIT_BENCH_SET=scene: the caustic photons of the embedded default scene (traced from
    // 1.43·N emitted, about N stored) instead of the synthetic set.
    let from_scene = std::env::var("PHOTONKIT_BENCH_SET").is_ok_and(|s| s == "scene");
    let m = if from_scene { scene_photons(n) } else { photonkit::synthetic::collimated_cusp(n, 7) };
    let n = m.position.len();
    let set = PointSet {
        positions: &m.position,
        params: Some(ParamColumn { values: &m.params, stride: 2, dims: &[2] }),
        emitters: None,
    };
    let what = if from_scene { "default scene" } else { "collimated_cusp" };
    println!("{n} photons ({what}); queries: one thread, CPU time; builds: wall clock, rayon pool");

    // Builds.
    let t = Instant::now();
    let ours_p = SpatialIndex::build(&set, Space::Params).unwrap();
    let b_ours_p = secs(t);
    let t = Instant::now();
    let ours_wp = SpatialIndex::build(&set, Space::WorldParams).unwrap();
    let b_ours_wp = secs(t);
    let t = Instant::now();
    let mut ours_w = SpatialIndex::build(&set, Space::World).unwrap();
    let b_ours_w = secs(t);
    let t = Instant::now();
    ours_w.rebuild(&set).unwrap();
    let b_ours_w_re = secs(t);
    let pts2: Vec<[f32; 2]> = m.params.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let t = Instant::now();
    let kid = Kiddo {
        world: ImmutableKdTree::new_from_slice(&m.position).unwrap(),
        params: ImmutableKdTree::new_from_slice(&pts2).unwrap(),
    };
    let b_kiddo = secs(t);
    println!(
        "build: photonkit params {b_ours_p:.3} s, world+params {b_ours_wp:.3} s, world {b_ours_w:.3} s \
         (rebuild {b_ours_w_re:.3} s); kiddo world + params {b_kiddo:.3} s"
    );

    let order = ours_wp.order();
    let mut out = Neighbours::with_capacity(kc);
    let mut kout = Vec::new();

    // Density (parameter space, k = Kc) and r_param = β·r_Kc.
    let mut r_param = vec![0f32; n];
    // Each workload loops in its own tree's leaf order, as the stages do.
    let order_p = ours_p.order();
    let t = Clock::start();
    for &i in &order_p {
        ours_p.knn(&set.query(i as usize, None), kc, &mut out);
        r_param[i as usize] = beta * out.last().map_or(0.0, |l| l.dist2.sqrt());
    }
    let d_ours = t.secs();
    let t = Clock::start();
    let mut acc = 0.0f32;
    for &i in order.iter().filter(|_| with_kiddo) {
        let found = kid
            .params
            .query(&pts2[i as usize])
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(kc).unwrap())
            .execute();
        acc += found.last().map_or(0.0, |l| l.distance);
    }
    let d_kiddo = t.secs();
    std::hint::black_box(acc);

    let mut report = vec![("density (params, k = 50)", d_ours, d_kiddo, 0.0)];
    for (label, k) in [("constrained Kc = 50", kc), ("constrained Kf = 16", kf)] {
        let t = Clock::start();
        for &i in &order {
            ours_wp.knn(&set.query(i as usize, Some(r_param[i as usize])), k, &mut out);
        }
        let ours = t.secs();
        let t = Clock::start();
        let mut fetched = 0usize;
        for &i in order.iter().filter(|_| with_kiddo) {
            let i = i as usize;
            fetched += kiddo_constrained(
                &kid.world,
                &set,
                m.position[i],
                set.params_of(i),
                r_param[i],
                k,
                &mut kout,
            );
        }
        let kid_s = t.secs();
        report.push((label, ours, kid_s, fetched as f64 / n as f64));
    }
    let order_w = ours_w.order();
    let t = Clock::start();
    for &i in &order_w {
        ours_w.knn(&set.query(i as usize, None), kf, &mut out);
    }
    let ours = t.secs();
    let t = Clock::start();
    for &i in order_w.iter().filter(|_| with_kiddo) {
        let f = kid
            .world
            .query(&m.position[i as usize])
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(kf).unwrap())
            .execute();
        std::hint::black_box(f);
    }
    report.push(("world Kf = 16", ours, t.secs(), 0.0));

    println!(
        "\n| query | photonkit µs/query | kiddo µs/query | kiddo/photonkit | kiddo photons fetched per query |"
    );
    println!("| --- | --- | --- | --- | --- |");
    for (label, ours, kid_s, fetched) in report {
        let f = if fetched > 0.0 { format!("{fetched:.0}") } else { "-".into() };
        println!(
            "| {label} | {:.2} | {:.2} | {:.2}× | {f} |",
            ours / n as f64 * 1e6,
            kid_s / n as f64 * 1e6,
            kid_s / ours
        );
    }

    // Exactness on a sample.
    let sample: Vec<usize> = (0..n).step_by((n / 200).max(1)).collect();
    for &i in &sample {
        let q = set.query(i, Some(r_param[i]));
        ours_wp.knn(&q, kc, &mut out);
        let want = brute_force_knn(&set, Space::WorldParams, &q, kc);
        assert_eq!(out.as_slice(), &want[..], "photonkit differs from brute force at photon {i}");
        kiddo_constrained(&kid.world, &set, m.position[i], set.params_of(i), r_param[i], kc, &mut kout);
        let kd: Vec<f32> = kout.iter().map(|x| x.0).collect();
        let wd: Vec<f32> = want.iter().map(|x| x.dist2).collect();
        assert_eq!(kd, wd, "kiddo's distances differ from brute force at photon {i}");
    }
    println!(
        "\nchecked {} queries against brute force: photonkit exact (indices and distances), kiddo equal distances",
        sample.len()
    );
}
