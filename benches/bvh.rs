//! The BVH decision (issue 3): photonkit's SAH BVH (`scene::bvh`) against the `bvh` crate
//! (0.13) and the `obvhs` crate (0.4) on the triangle meshes of the sample scenes and on a
//! random-triangle soup.
//!
//! `cargo bench --bench bvh` (PHOTONKIT_BENCH_RAYS=N rays per mesh, default 200 000, a tenth
//! of that for the soup; PHOTONKIT_BENCH_SOUP=N soup triangles, default 1 M).
//!
//! All hierarchies are built over the same triangles and shoot the same rays (origins on a
//! sphere around the mesh's bounding box, aimed at points inside it), on one thread; times are this
//! thread's CPU time (user + system, /proc/thread-self/stat). Every ray's nearest hit is the
//! same triangle test (the tracer's two-sided test in each triangle's precomputed frame,
//! `bvh::Tri`) over the candidates each hierarchy hands out, so the hits must agree exactly: the bench checks triangle and
//! distance for every ray.
//!
//! The crate offers two ways to a nearest hit: `traverse_iterator` (every triangle whose box
//! the ray meets, unordered: test them all) and `nearest_traverse_iterator` (boxes in order of
//! entry distance, from a binary heap: stop once a box starts beyond the best hit).
//!
//! obvhs builds a binary BVH by PLOC (Morton-sorted agglomerative clustering) refined by
//! reinsertion, and from it either its compressed wide BVH8 (CWBVH, `build_cwbvh_from_tris`:
//! eight quantised child boxes per 80-byte node, leaves of up to three triangles) or a BVH2 with
//! collapsed leaves (`build_bvh2_from_tris`); both are built here, each timed as a whole build.
//! Both use the `slow_build` preset: spatial pre-splits of large triangles, the widest PLOC
//! search, reinsertion of 20 % of the nodes and 128-bit Morton codes. Against `medium_build`
//! (no pre-splits, narrower search, 5 % reinsertion) it made the CWBVH's soup queries about
//! 40 % faster (0.29 → 0.41 M rays/s) and the meshes' the same within the clock's noise, for
//! about twice the build time (1.3 s instead of 0.7 s on the 1 M-triangle soup, against 0.95 s
//! for ours); `very_slow_build` added another 10 % on the soup for 4.5 times slow's build
//! (5.9 s), which is not worth it. Its leaf callback gets a slot of `primitive_indices`, which
//! maps every box of a pre-split triangle back to the input triangle, and the best distance so
//! far as the ray's `tmax`; it runs the same `Tri::intersect` on that triangle and answers the
//! distance, or infinity for a miss, so obvhs prunes its boxes with it. The build runs on this
//! thread alone: the crate's rayon support is its `parallel` feature, off by default and not
//! enabled here.
//!
//! A hit differing is a ray whose (triangle, distance) is not ours. Two causes: a ray through
//! an edge that two triangles share can meet both at the same distance, and which one counts
//! then follows each hierarchy's order of testing; or a hierarchy passes over the node of a hit
//! nearer by an ulp or so (its box entry rounded beyond the best hit so far).

use std::path::Path;
use std::time::Duration;

use bvh::aabb::{Aabb, Bounded};
use bvh::bounding_hierarchy::BHShape;
use glam::Vec3;
use nalgebra::{Point3, Vector3};
use obvhs::BvhBuildParams;
use photonkit::scene::bvh::{Bvh, Tri, TriHit};
use photonkit::scene::{Ray, Scene, SurfaceGeometry};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// CPU seconds this thread has run (user + system; 10 ms resolution).
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// (result, thread CPU seconds) of `f`, repeated until it has run for at least 0.3 s (the
/// clock ticks every 10 ms); the seconds are per run.
fn timed<T>(mut f: impl FnMut() -> T) -> (T, f64) {
    let c0 = cpu();
    let mut runs = 1;
    let mut out = f();
    while cpu() - c0 < 0.3 {
        out = f();
        runs += 1;
    }
    (out, (cpu() - c0) / runs as f64)
}

fn env_count(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|s| s.parse::<f64>().ok()).map_or(default, |x| x as usize)
}

/// A triangle as the `bvh` crate wants it.
struct CrateTri {
    v: [Vec3; 3],
    /// The triangle as the tracer's test wants it, computed once as our hierarchy does.
    frame: Tri,
    /// Place in the input list.
    index: u32,
    node: usize,
}

fn p3(v: Vec3) -> Point3<f32> {
    Point3::new(v.x, v.y, v.z)
}

impl Bounded<f32, 3> for CrateTri {
    fn aabb(&self) -> Aabb<f32, 3> {
        let [a, b, c] = self.v;
        Aabb::with_bounds(p3(a.min(b).min(c)), p3(a.max(b).max(c)))
    }
}

impl BHShape<f32, 3> for CrateTri {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node = index;
    }
    fn bh_node_index(&self) -> usize {
        self.node
    }
}

/// The nearest hit among `candidates`: (input index, distance).
fn nearest<'a>(ray: &Ray, candidates: impl Iterator<Item = &'a CrateTri>) -> Option<(u32, f32)> {
    let mut best: Option<(u32, f32)> = None;
    let mut t_best = f32::INFINITY;
    for c in candidates {
        if let Some((t, _, _)) = c.frame.intersect(ray, 1e-4, t_best) {
            t_best = t;
            best = Some((c.index, t));
        }
    }
    best
}

/// Rays from a sphere around the box of `tris` towards points inside it.
fn rays(tris: &[[Vec3; 3]], n: usize, seed: u64) -> Vec<Ray> {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for t in tris {
        for &p in t {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let (c, e) = ((lo + hi) / 2.0, hi - lo);
    let r = e.length();
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut u = || Vec3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>()) - 0.5;
    (0..n)
        .map(|_| {
            // An origin on the sphere of radius |diagonal| about the centre, so a flat mesh
            // (the height field) is seen from every side, not only edge-on.
            let o = loop {
                let d = u();
                if (0.01..=0.25).contains(&d.length_squared()) {
                    break c + d.normalize() * r;
                }
            };
            let target = c + u() * e;
            Ray::new(o, (target - o).normalize())
        })
        .collect()
}

fn row(label: &str, tris: &[[Vec3; 3]], n_rays: usize) {
    let rays = rays(tris, n_rays, 11);
    let (ours, ours_build) = timed(|| Bvh::build(tris));
    let mut shapes: Vec<CrateTri> = tris
        .iter()
        .enumerate()
        .map(|(i, &v)| CrateTri { v, frame: Tri::new(v[0], v[1], v[2]), index: i as u32, node: 0 })
        .collect();
    let (theirs, theirs_build) = timed(|| bvh::bvh::Bvh::build(&mut shapes));
    let crate_rays: Vec<bvh::ray::Ray<f32, 3>> = rays
        .iter()
        .map(|r| bvh::ray::Ray::new(p3(r.origin), Vector3::new(r.dir.x, r.dir.y, r.dir.z)))
        .collect();

    let (a, ours_s) = timed(|| {
        rays.iter().map(|r| ours.intersect(r, 1e-4, f32::INFINITY)).collect::<Vec<Option<TriHit>>>()
    });
    let (b, all_s) = timed(|| {
        rays.iter()
            .zip(&crate_rays)
            .map(|(r, cr)| nearest(r, theirs.traverse_iterator(cr, &shapes)))
            .collect::<Vec<_>>()
    });
    let (c, ordered_s) = timed(|| {
        rays.iter()
            .zip(&crate_rays)
            .map(|(r, cr)| {
                let mut t_best = f32::INFINITY;
                let mut best = None;
                // Boxes come nearest first: stop at the first one entered beyond the best hit.
                for s in theirs.nearest_traverse_iterator(cr, &shapes) {
                    match cr.intersection_slice_for_aabb(&s.aabb()) {
                        Some((t0, _)) if t0 <= t_best => {}
                        _ => break,
                    }
                    if let Some((t, _, _)) = s.frame.intersect(r, 1e-4, t_best) {
                        t_best = t;
                        best = Some((s.index, t));
                    }
                }
                best
            })
            .collect::<Vec<_>>()
    });

    // obvhs: the same triangles, as its own (glam) vectors, built into a CWBVH and a BVH2.
    let obvhs_tris: Vec<obvhs::triangle::Triangle> = tris
        .iter()
        .map(|[a, b, c]| obvhs::triangle::Triangle {
            v0: a.to_array().into(),
            v1: b.to_array().into(),
            v2: c.to_array().into(),
        })
        .collect();
    let frames: Vec<Tri> = tris.iter().map(|v| Tri::new(v[0], v[1], v[2])).collect();
    // The preset chosen in the module comment.
    let preset = BvhBuildParams::slow_build();
    let (cw, cw_build) =
        timed(|| obvhs::cwbvh::builder::build_cwbvh_from_tris(&obvhs_tris, preset, &mut Duration::default()));
    let (b2, b2_build) =
        timed(|| obvhs::bvh2::builder::build_bvh2_from_tris(&obvhs_tris, preset, &mut Duration::default()));
    let obvhs_rays: Vec<obvhs::ray::Ray> = rays
        .iter()
        .map(|r| obvhs::ray::Ray::new_inf(r.origin.to_array().into(), r.dir.to_array().into()))
        .collect();
    // The leaf test: obvhs hands out a slot of its `primitive_indices` (which map split
    // duplicates back to the input triangle too) and its best distance so far as `tmax`; the
    // answer is the tracer's test on the input triangle, infinity for a miss.
    let test = |slots: &[u32], r: &Ray, or: &obvhs::ray::Ray, slot: usize| {
        frames[slots[slot] as usize].intersect(r, 1e-4, or.tmax).map_or(f32::INFINITY, |h| h.0)
    };
    let (d, cw_s) = timed(|| {
        rays.iter()
            .zip(&obvhs_rays)
            .map(|(r, &or)| {
                let mut hit = obvhs::ray::RayHit::none();
                cw.ray_traverse(or, &mut hit, |or, slot| test(&cw.primitive_indices, r, or, slot))
                    .then(|| (cw.primitive_indices[hit.primitive_id as usize], hit.t))
            })
            .collect::<Vec<_>>()
    });
    let (e, b2_s) = timed(|| {
        rays.iter()
            .zip(&obvhs_rays)
            .map(|(r, &or)| {
                let mut hit = obvhs::ray::RayHit::none();
                b2.ray_traverse(or, &mut hit, |or, slot| test(&b2.primitive_indices, r, or, slot))
                    .then(|| (b2.primitive_indices[hit.primitive_id as usize], hit.t))
            })
            .collect::<Vec<_>>()
    });

    let ours_hits: Vec<Option<(u32, f32)>> = a.iter().map(|h| h.map(|h| (h.index, h.t))).collect();
    let mismatch_all = ours_hits.iter().zip(&b).filter(|(x, y)| x != y).count();
    let mismatch_ordered = ours_hits.iter().zip(&c).filter(|(x, y)| x != y).count();
    let mismatch_cw = ours_hits.iter().zip(&d).filter(|(x, y)| x != y).count();
    let mismatch_b2 = ours_hits.iter().zip(&e).filter(|(x, y)| x != y).count();
    let hits = ours_hits.iter().flatten().count();
    let mrays = |s: f64| n_rays as f64 / s / 1e6;
    println!(
        "| {label} | {} | {hits}/{n_rays} | {:.2} | {:.2} | **{:.2}** | {:.3} ({:.1}× slower) | {:.3} ({:.1}× slower) | {mismatch_all} / {mismatch_ordered} | {:.2} / {:.2} | {} | {} | {mismatch_cw} / {mismatch_b2} |",
        tris.len(),
        ours_build * 1e3,
        theirs_build * 1e3,
        mrays(ours_s),
        mrays(all_s),
        all_s / ours_s,
        mrays(ordered_s),
        ordered_s / ours_s,
        cw_build * 1e3,
        b2_build * 1e3,
        relative(mrays(cw_s), cw_s / ours_s),
        relative(mrays(b2_s), b2_s / ours_s),
    );
}

/// "rate (N× slower)" or "rate (N× faster)", from the ratio of its time to ours.
fn relative(mrays: f64, time_ratio: f64) -> String {
    if time_ratio >= 1.0 {
        format!("{mrays:.3} ({time_ratio:.1}× slower)")
    } else {
        format!("{mrays:.3} ({:.1}× faster)", 1.0 / time_ratio)
    }
}

fn scene_triangles(file: &str) -> Vec<[Vec3; 3]> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes").join(file);
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    for s in scene.surfaces() {
        if let SurfaceGeometry::Mesh(m) = &s.geometry {
            out.extend((0..m.indices.len()).map(|i| m.triangle(i)));
        }
    }
    out
}

fn main() {
    let n_rays = env_count("PHOTONKIT_BENCH_RAYS", 200_000);
    let n_soup = env_count("PHOTONKIT_BENCH_SOUP", 1_000_000);
    println!("closest hit, one thread, thread CPU time; {n_rays} rays per mesh\n");
    println!(
        "| triangles of | count | rays hitting | ours build ms | bvh build ms | ours M rays/s | bvh 0.13 all candidates M rays/s | bvh 0.13 nearest-first M rays/s | hits differing (all / nearest-first) | obvhs build ms (CWBVH / BVH2) | obvhs CWBVH M rays/s | obvhs BVH2 M rays/s | obvhs hits differing (CWBVH / BVH2) |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for (label, file) in [
        ("water.toml (height field)", "water.toml"),
        ("cognac.toml (two revolutions)", "cognac.toml"),
        ("reflector.toml (paraboloid + shield)", "reflector.toml"),
        ("point-glass.toml (revolution)", "point-glass.toml"),
        ("prism.toml (extrusion)", "prism.toml"),
    ] {
        row(label, &scene_triangles(file), n_rays);
    }
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut u = || Vec3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>()) - 0.5;
    // Triangles about 0.1 across, centres uniform in a 10 m cube.
    let soup: Vec<[Vec3; 3]> = (0..n_soup)
        .map(|_| {
            let c = u() * 10.0;
            [c + u() * 0.2, c + u() * 0.2, c + u() * 0.2]
        })
        .collect();
    // A tenth of the rays: the crate's all-candidates query tests every box along the ray.
    row("random soup", &soup, n_rays / 10);
}
