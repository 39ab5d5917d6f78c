//! The tracer on small scenes: photons against closed forms (a slab's transmission, unbiased
//! losses), spooled and sharded runs against in-memory ones, and thread-count independence.

use std::path::Path;

use super::chunks::{Scratch, copy, prefault};
use super::halton::PhotonRng;
use super::walk::roulette;
use super::*;
use crate::format::Output;

fn scene(src: &str) -> Scene {
    Scene::parse(src, "test.toml", Path::new(".")).unwrap()
}

fn run(s: &Scene, opts: &TraceOptions) -> Traced {
    trace(s, opts, &|_, _| {}).unwrap()
}

/// `opts` with a spool in `dir` that holds `memory` bytes of photons in memory.
fn spooled(opts: &TraceOptions, dir: &Path, memory: u64) -> TraceOptions {
    TraceOptions { spool: Some(Spool { dir: dir.to_path_buf(), memory }), ..opts.clone() }
}

#[test]
fn retain_bounces_keeps_exactly_the_photons_of_those_paths_with_their_columns() {
    let s = Scene::default_scene();
    let dir = tempfile::tempdir().unwrap();
    let opts = TraceOptions { budget: Budget::Emitted(20_000), ..TraceOptions::default() };
    let all = run(&s, &opts).photons().unwrap();
    // In memory, and spooled but for the last chunks.
    for opts in [opts.clone(), spooled(&opts, dir.path(), 100_000)] {
        let mut kept = run(&s, &opts);
        assert_eq!(kept.store.spooled_count() > 0, opts.spool.is_some());
        kept.retain_bounces(&[2]).unwrap();
        let k = kept.photons().unwrap();
        let want: Vec<usize> = (0..all.len()).filter(|&i| all.bounces[i] == 2).collect();
        assert!(!want.is_empty() && want.len() < all.len(), "the default scene has other paths too");
        assert_eq!(kept.stored as usize, want.len());
        assert_eq!(k.len(), want.len());
        let d = s.param_dims() as usize;
        for (j, &i) in want.iter().enumerate() {
            assert_eq!(k.emission_index[j], all.emission_index[i]);
            assert_eq!(k.position[j], all.position[i]);
            assert_eq!(k.flux[j], all.flux[i], "flux is not renormalised");
            assert_eq!(k.params[j * d..(j + 1) * d], all.params[i * d..(i + 1) * d]);
            assert_eq!(k.surface[j], all.surface[i]);
        }
    }
}

/// Photons spooled to disk (every one, or all but the last chunks) come back as a run
/// holding them in memory has them: the same photons and the same file byte for byte,
/// for either budget and with several emitters; the spool's files have no name, so the
/// directory holds only what was written.
#[test]
fn spooled_photons_are_the_photons_held_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    // The default scene with a second emitter (a point light above the ball): an
    // emitter column and three trajectory parameters.
    let two = crate::scene::DEFAULT_SCENE.to_string()
        + "[[emitters]]\nkind = \"point\"\nposition = [0.3, 0.0, 1.5]\npower_w = 5.0\n";
    for (scene, budget) in [
        (Scene::default_scene(), Budget::Emitted(100_000)),
        (Scene::default_scene(), Budget::Stored(30_000)),
        (scene(&two), Budget::Emitted(100_000)),
    ] {
        let opts = TraceOptions { budget, ..TraceOptions::default() };
        let held = run(&scene, &opts);
        assert_eq!(held.store.spooled_count(), 0);
        assert_eq!(held.emitter_column, scene.emitters().len() > 1);
        let info = map_info(&scene, &opts, &held, "default", b"");
        let want = dir.path().join("held.phm");
        held.write(Output::Path(want.clone()), info.clone()).unwrap();
        for memory in [1, held.stored * 30] {
            let t = run(&scene, &spooled(&opts, dir.path(), memory));
            assert!(t.store.spooled_count() > 0);
            assert_eq!(memory == 1, t.store.spooled_count() == t.stored, "memory {memory}");
            assert_eq!(
                (t.stored, t.emitted, t.range.clone()),
                (held.stored, held.emitted, held.range.clone())
            );
            assert_eq!(t.bounce_limited, held.bounce_limited);
            assert_eq!(t.photons().unwrap(), held.photons().unwrap(), "{budget:?}, memory {memory}");
            let got = dir.path().join("spooled.phm");
            t.write(Output::Path(got.clone()), info.clone()).unwrap();
            assert!(
                std::fs::read(&got).unwrap() == std::fs::read(&want).unwrap(),
                "{budget:?}, memory {memory}"
            );
            let mut names: Vec<_> =
                std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
            names.sort();
            assert_eq!(names, ["held.phm", "spooled.phm"]);
        }
    }
}

/// A glass slab (0.2 m thick) between a collimated beam and the floor, in a closed world.
pub(crate) fn slab(ideal: bool, ior: f32) -> String {
    format!(
        r#"
[materials.floor]
kind = "diffuse"
[materials.glass]
kind = "dielectric"
ior = {ior}
ideal = {ideal}
[[emitters]]
kind = "collimated"
center = [0, 0, 2]
size = [1, 1]
direction = [0, 0, -1]
power_w = 6
[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "extrusion"
outline = [[-2, -2], [2, -2], [2, 2], [-2, 2]]
z_range = [0.5, 0.7]
material = "glass"
"#
    )
}

/// The photon loop compiled for AVX ([`Tracer::chunk`]) and without ([`Tracer::chunk_any`])
/// store the same photons, bit for bit, on sample scenes with a small mesh (the prism's
/// eight triangles: the AVX pair test inlined), a large one (the water, through the
/// hierarchy) and none. (Without AVX there is nothing to compare.)
#[test]
fn the_loop_compiled_for_avx_stores_the_same_photons() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
    for name in ["prism", "water", "ring", "point-glass"] {
        let scene = Scene::load(&dir.join(format!("{name}.toml"))).unwrap();
        let opts = TraceOptions::default();
        let mut tracer = Tracer::new(&scene, &opts);
        if !tracer.avx {
            return;
        }
        let (mut with, mut without) = (Scratch::new(tracer.dims), Scratch::new(tracer.dims));
        let range = 3 * CHUNK..4 * CHUNK;
        let limited = tracer.chunk(range.clone(), &mut with);
        tracer.avx = false;
        assert_eq!(tracer.chunk(range, &mut without), limited);
        let (with, without) = (with.to_chunk(true), without.to_chunk(true));
        assert!(with.len() > 100, "{name}: {} stored", with.len());
        assert!(with == without, "{name}: the two loops stored different photons");
    }
}

/// Prefaulting maps pages without touching what they hold: a vector's contents, and its
/// neighbours' on the pages the range is widened to, stay as they were.
#[test]
fn prefaulting_leaves_memory_as_it_was() {
    let data: Vec<u64> = (0..10_000u64).map(|i| i.wrapping_mul(0x9E37_79B9_7F4A_7C15)).collect();
    let before = data.clone();
    prefault(data.as_ptr().wrapping_add(100) as *mut u8, 8 * 5_000);
    assert_eq!(data, before);
    let copied = copy(&data);
    assert_eq!(copied, before);
}

#[test]
fn shards_cover_the_range_exactly() {
    let n = 1_000_003;
    let mut next = 0;
    for i in 0..7 {
        let r = Shard { index: i, count: 7 }.range(n);
        assert_eq!(r.start, next);
        next = r.end;
    }
    assert_eq!(next, n);
}

#[test]
fn roulette_is_unbiased() {
    let mut rng = PhotonRng::new(9, 9);
    let a = Vec3::new(0.5, 0.25, 0.1);
    let n = 200_000;
    let mut sum = Vec3::ZERO;
    for _ in 0..n {
        let mut f = Vec3::ONE;
        if roulette(&mut f, a, &mut rng) {
            sum += f;
        }
    }
    let mean = sum / n as f32;
    assert!((mean - a).abs().max_element() < 0.005, "{mean}");
}

#[test]
fn ideal_slab_passes_the_whole_beam_with_uniform_density() {
    let s = scene(&slab(true, 1.5));
    let t = run(&s, &TraceOptions { budget: Budget::Emitted(40_000), ..Default::default() });
    let p = t.photons().unwrap();
    assert_eq!(p.len(), 40_000, "every photon crosses the slab");
    let total: f64 = p.flux.iter().flatten().map(|&f| f as f64).sum();
    assert!((total - 6.0).abs() < 1e-4, "{total}");
    assert!(p.bounces.iter().all(|&b| b == 2));
    // Normal incidence: the beam lands where it started, one photon per cell of a 10×10 grid
    // within 15 % (Halton points are far more even than random ones).
    let mut cells = [0u32; 100];
    for q in &p.position {
        assert!(q[0].abs() <= 0.5 + 1e-4 && q[1].abs() <= 0.5 + 1e-4 && q[2].abs() < 1e-5);
        let (i, j) = (((q[0] + 0.5) * 10.0).min(9.0) as usize, ((q[1] + 0.5) * 10.0).min(9.0) as usize);
        cells[j * 10 + i] += 1;
    }
    assert!(cells.iter().all(|&c| (340..=460).contains(&c)), "{cells:?}");
    // Trajectory parameters are the landing point: (u, v) = (x + ½, y + ½).
    for (q, uv) in p.position.iter().zip(p.params.chunks(2)) {
        assert!((q[0] + 0.5 - uv[0]).abs() < 1e-4 && (q[1] + 0.5 - uv[1]).abs() < 1e-4);
    }
}

#[test]
fn fresnel_slab_transmits_the_two_interface_fraction() {
    // Normal incidence, n = 1.5: each interface reflects R = 0.04. With the multiple
    // reflections inside the slab, the transmitted fraction is (1 − R)/(1 + R).
    let s = scene(&slab(false, 1.5));
    let n = 200_000;
    let t = run(&s, &TraceOptions { budget: Budget::Emitted(n), seed: 5, ..Default::default() });
    let total: f64 = t.photons().unwrap().flux.iter().flatten().map(|&f| f as f64).sum();
    let expected = 6.0 * (1.0 - 0.04) / (1.0 + 0.04);
    // Binomial noise: σ ≈ 6·sqrt(T(1−T)/n) ≈ 0.0036.
    assert!((total - expected).abs() < 0.015, "{total} vs {expected}");
}

#[test]
fn stored_budget_stops_at_the_photon_count() {
    let s = scene(&slab(false, 1.5));
    let t = run(&s, &TraceOptions { budget: Budget::Stored(5000), ..Default::default() });
    let p = t.photons().unwrap();
    assert_eq!(p.len(), 5000);
    assert_eq!(t.emitted, p.emission_index[4999] + 1);
    // The same photons as an emitted budget of that size.
    let u = run(&s, &TraceOptions { budget: Budget::Emitted(t.emitted), ..Default::default() })
        .photons()
        .unwrap();
    assert_eq!(p, u);
}

#[test]
fn direct_photons_are_stored_only_on_request() {
    let src =
        slab(true, 1.5).replace("[-2, -2], [2, -2], [2, 2], [-2, 2]", "[-2, -2], [0, -2], [0, 2], [-2, 2]");
    let s = scene(&src);
    let c =
        run(&s, &TraceOptions { budget: Budget::Emitted(10_000), ..Default::default() }).photons().unwrap();
    let d = run(
        &s,
        &TraceOptions { budget: Budget::Emitted(10_000), store: StorePolicy::Direct, ..Default::default() },
    )
    .photons()
    .unwrap();
    // Half the beam misses the half-slab.
    assert!((c.len() as f64 / 5000.0 - 1.0).abs() < 0.01, "{}", c.len());
    assert_eq!(d.len(), 10_000);
    assert!(d.bounces.iter().filter(|&&b| b == 0).count() == d.len() - c.len());
}

#[test]
fn mirror_losses_are_unbiased_under_russian_roulette() {
    let src = r#"
[materials.floor]
kind = "diffuse"
[materials.metal]
kind = "mirror"
reflectance = [0.9, 0.5, 0.2]
[[emitters]]
kind = "collimated"
center = [0, 0, 1]
size = [1, 1]
direction = [0, 0, 1]
power_w = 3
[[shapes]]
kind = "plane"
point = [0, 0, 0]
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "plane"
point = [0, 0, 2]
normal = [0, 0, -1]
material = "metal"
"#;
    let t = run(&scene(src), &TraceOptions { budget: Budget::Emitted(100_000), ..Default::default() });
    let p = t.photons().unwrap();
    let mut sum = [0.0f64; 3];
    for f in &p.flux {
        for k in 0..3 {
            sum[k] += f[k] as f64;
        }
    }
    // Each channel carries 1 W, times its reflectance.
    for (k, r) in [0.9, 0.5, 0.2].iter().enumerate() {
        assert!((sum[k] - r).abs() < 0.01, "channel {k}: {} vs {r}", sum[k]);
    }
}

#[test]
fn output_is_the_same_on_one_and_two_threads() {
    let s = Scene::default_scene();
    let opts = TraceOptions { budget: Budget::Emitted(30_000), seed: 3, ..Default::default() };
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let a = pool(1).install(|| run(&s, &opts)).photons().unwrap();
    let b = pool(2).install(|| run(&s, &opts)).photons().unwrap();
    assert!(a.len() > 1000);
    assert_eq!(a, b);
    let c = run(&s, &TraceOptions { seed: 4, ..opts }).photons().unwrap();
    assert_ne!(a, c);
}
