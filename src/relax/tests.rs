//! Relaxation's kernels against closed forms, and whole runs on synthetic maps.

use glam::Vec3;

use super::iteration::{CHUNK, map_spacing};
use super::*;

#[test]
fn repulsion_vanishes_for_neighbours_evenly_on_the_kf_circle() {
    let r = 2.0;
    let ring: Vec<Vec3> = (0..16)
        .map(|k| (k as f32 * std::f32::consts::TAU / 16.0).sin_cos())
        .map(|(s, c)| Vec3::new(r * c, r * s, 0.0))
        .collect();
    let f = repulsion(Vec3::ZERO, &ring, r, 0.0);
    assert!(f.length() < 1e-5, "{f}");
}

#[test]
fn repulsion_matches_eq8_by_hand_and_pushes_away_from_a_close_neighbour() {
    // Neighbours at (0.5,0,0) and (-2,0,0); r_K = 2, ε = 0:
    // (x_i − x_j)(r_K/|..| − 1): (−0.5,0,0)(4 − 1) = (−1.5,0,0); (2,0,0)(1 − 1) = 0; mean (−0.75,0,0).
    let f = repulsion(Vec3::ZERO, &[Vec3::new(0.5, 0.0, 0.0), Vec3::new(-2.0, 0.0, 0.0)], 2.0, 0.0);
    assert!((f - Vec3::new(-0.75, 0.0, 0.0)).length() < 1e-6, "{f}");
}

#[test]
fn repulsion_is_finite_for_coincident_photons_and_scales_with_the_scene() {
    let f = repulsion(Vec3::ONE, &[Vec3::ONE, Vec3::ONE], 0.0, 1e-3);
    assert!(f.is_finite());
    let xs = [Vec3::new(0.3, 0.1, 0.0), Vec3::new(-0.2, 0.5, 0.0), Vec3::new(0.9, -0.4, 0.0)];
    let r = xs[2].length();
    let f1 = repulsion(Vec3::ZERO, &xs, r, 1e-3);
    for s in [1e-6f32, 1e6] {
        let fs = repulsion(Vec3::ZERO, &xs.map(|x| x * s), r * s, 1e-3);
        assert!((fs / s - f1).length() < 1e-5 * f1.length(), "scale {s}");
    }
}

#[test]
fn a_zero_v_factor_never_moves_along_p2_and_a_unit_factor_moves_freely() {
    let (p1, p2) = (Vec3::X, Vec3::Y);
    let f = Vec3::new(0.3, -0.7, 0.0);
    let locked = project_on_basis(f, p1, p2 * 0.0);
    assert_eq!(locked.dot(p2), 0.0);
    assert!((locked - Vec3::new(0.3, 0.0, 0.0)).length() < 1e-7);
    let free = project_on_basis(f, p1, p2);
    assert!((free - f).length() < 1e-7);
    let half = project_on_basis(f, p1, p2 * 0.5);
    assert!((half.dot(p2) - 0.5 * f.dot(p2)).abs() < 1e-7);
}

#[test]
fn tangent_projection_removes_the_normal_component_and_steps_are_clamped() {
    let n = Vec3::new(1.0, 1.0, 1.0).normalize();
    let t = project_on_tangent(Vec3::new(0.2, -3.0, 5.0), n);
    assert!(t.dot(n).abs() < 1e-6);
    assert!((clamp_step(Vec3::new(3.0, 4.0, 0.0), 1.0).length() - 1.0).abs() < 1e-6);
    assert_eq!(clamp_step(Vec3::new(0.3, 0.4, 0.0), 1.0), Vec3::new(0.3, 0.4, 0.0));
}

#[test]
fn coefficient_of_variation_matches_closed_form() {
    // 1, 2, 3: mean 2, population sd sqrt(2/3).
    let cv = coefficient_of_variation(&[1.0, 2.0, 3.0]);
    assert!((cv - (2.0f64 / 3.0).sqrt() / 2.0).abs() < 1e-12);
    assert_eq!(coefficient_of_variation(&[5.0]), 0.0);
    let m = IterationMeasure::of(3, &[1.0, 2.0, 3.0], &[0.5, f32::NAN, 1.5], &[0.25, 0.5, 0.0]);
    assert!((m.nn_cv - (2.0f64 / 3.0).sqrt() / 2.0).abs() < 1e-12);
    // Ratios 0.5 and 1.5 (the NaN is left out): mean 1, sd 0.5.
    assert!((m.local_nn_cv - 0.5).abs() < 1e-12);
    assert_eq!((m.iteration, m.mean_displacement, m.max_displacement, m.separated), (3, 0.25, 0.5, 0));
    let m = IterationMeasure::of(0, &[0.0, 0.0, 1.0], &[f32::NAN; 3], &[0.0; 3]);
    assert_eq!((m.separated, m.local_nn_cv), (2, 0.0));
}

/// An exact sum is the same whatever the order of its values and however they are split
/// between sums that are then merged (tiles: docs/tiles.md), and it is exact where a running
/// f64 sum is not.
#[test]
fn exact_sums_do_not_depend_on_order_or_split() {
    // 1e20 + 1 − 1e20: a running f64 sum gives 0.
    let mut s = ExactSum::default();
    [1e20, 1.0, -1e20].iter().for_each(|&x| s.add(x));
    assert_eq!(s.total(), 1.0);
    assert_eq!(1e20f64 + 1.0 - 1e20, 0.0);
    // Values over many magnitudes, with subnormals and signs, in three orders and two splits.
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let values: Vec<f64> = (0..5000)
        .map(|i| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let x = (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.3;
            match i % 5 {
                0 => x * 1e-310,
                1 => x * 1e30,
                2 => (x as f32) as f64,
                3 => x * x,
                _ => x * 1e-8,
            }
        })
        .collect();
    let sum_of = |v: &[f64]| {
        let mut s = ExactSum::default();
        v.iter().for_each(|&x| s.add(x));
        s
    };
    let want = sum_of(&values).total();
    let mut reversed = values.clone();
    reversed.reverse();
    let mut sorted = values.clone();
    sorted.sort_by(f64::total_cmp);
    assert_eq!(sum_of(&reversed).total().to_bits(), want.to_bits());
    assert_eq!(sum_of(&sorted).total().to_bits(), want.to_bits());
    for cut in [1, 2499, 4999] {
        let mut a = sum_of(&values[..cut]);
        a.merge(&sum_of(&values[cut..]));
        assert_eq!(a.total().to_bits(), want.to_bits(), "split at {cut}");
    }
    // Against an f64 running sum of the values sorted by magnitude (accurate to far better
    // than 1e-6 of the largest here).
    let mut by_size = values.clone();
    by_size.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    let running: f64 = by_size.iter().sum();
    assert!((want - running).abs() <= 1e-6 * 1e30, "{want} against {running}");
    // Measures from sums split between two sets equal those of the whole.
    let nn: Vec<f32> = values.iter().map(|&x| (x.abs() as f32).min(1.0)).collect();
    let ratio: Vec<f32> = nn.iter().map(|&d| if d > 0.5 { f32::NAN } else { d }).collect();
    let whole = IterationMeasure::of(1, &nn, &ratio, &nn);
    let mut a = MeasureSums::default();
    let mut b = MeasureSums::default();
    for (k, &d) in nn.iter().enumerate() {
        if k % 3 == 0 { &mut a } else { &mut b }.add(d, ratio[k], d);
    }
    b.merge(&a);
    assert_eq!(b.measure(1), whole);
}

/// Per-iteration sums of photon-major series, added in parallel stretches, against each
/// iteration's values added one by one (three iterations, photons over two stretches).
#[test]
fn series_sums_are_each_iterations_sums() {
    let r = 3;
    let n = 70_001;
    let value =
        |k: usize, salt: u64| ((k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15 ^ salt) >> 40) as f32 * 1e-3;
    let nn: Vec<f32> = (0..n * r).map(|k| if k % 97 == 0 { 0.0 } else { value(k, 1) }).collect();
    let ratio: Vec<f32> = (0..n * r).map(|k| if k % 5 == 0 { f32::NAN } else { value(k, 2) }).collect();
    let step: Vec<f32> = (0..n * r).map(|k| value(k, 3)).collect();
    let mut sums = vec![MeasureSums::default(); r];
    MeasureSums::add_series(&mut sums, &nn, &ratio, &step);
    for (t, sum) in sums.iter().enumerate() {
        let mut one = MeasureSums::default();
        for k in 0..n {
            one.add(nn[k * r + t], ratio[k * r + t], step[k * r + t]);
        }
        assert_eq!(sum.measure(t), one.measure(t), "iteration {t}");
        assert!(one.measure(t).nn_cv > 0.0 && one.measure(t).separated > 0);
    }
    assert_ne!(sums[0].measure(0), sums[1].measure(0));
}

/// k nearest by brute force, ties broken by index.
struct BruteForce<'a>(&'a [[f32; 3]]);

impl NeighbourSearch for BruteForce<'_> {
    fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>) {
        let xi = Vec3::from(self.0[i]);
        let mut all: Vec<(f32, u32)> = (0..self.0.len())
            .filter(|&j| j != i)
            .map(|j| (xi.distance_squared(self.0[j].into()), j as u32))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        out.clear();
        out.extend(all.iter().take(k).map(|&(_, j)| j));
    }
}

fn relax_plane(pos: &mut [[f32; 3]], iterations: usize) -> Vec<IterationMeasure> {
    let normal = vec![[0.0, 0.0, 1.0]; pos.len()];
    let p = RelaxParams::default();
    let mut scratch = Scratch::default();
    (0..iterations)
        .map(|it| {
            let snapshot = pos.to_vec();
            let index = BruteForce(&snapshot);
            iterate(pos, &index, Constraint::Tangent { normal: &normal }, &p, it, &mut scratch)
        })
        .collect()
}

/// Radially averaged power spectrum |Σ exp(−2πi f·x)|²/N of the points inside the square
/// [lo, lo+side]², at f = k/side for integer vectors k with |k| in [kmin, kmax]. A uniform
/// density has zero power there (the window's transform vanishes), white noise has 1.
fn low_frequency_power(pos: &[[f32; 3]], lo: f64, side: f64, kmin: f64, kmax: f64) -> f64 {
    let inside: Vec<(f64, f64)> = pos
        .iter()
        .map(|p| ((p[0] as f64 - lo) / side, (p[1] as f64 - lo) / side))
        .filter(|&(x, y)| (0.0..1.0).contains(&x) && (0.0..1.0).contains(&y))
        .collect();
    let (mut sum, mut count) = (0.0, 0);
    let km = kmax.ceil() as i32;
    for kx in 0..=km {
        for ky in -km..=km {
            let k = ((kx * kx + ky * ky) as f64).sqrt();
            if k < kmin || k > kmax || (kx == 0 && ky < 0) {
                continue;
            }
            let (mut re, mut im) = (0.0f64, 0.0f64);
            for &(x, y) in &inside {
                let ph = -std::f64::consts::TAU * (kx as f64 * x + ky as f64 * y);
                re += ph.cos();
                im += ph.sin();
            }
            sum += (re * re + im * im) / inside.len() as f64;
            count += 1;
        }
    }
    sum / count as f64
}

/// Coefficient of variation of nearest-neighbour distances of photons in [0.2, 0.8]².
fn interior_cv(pos: &[[f32; 3]]) -> f64 {
    let index = BruteForce(pos);
    let mut ids = Vec::new();
    let d: Vec<f32> = (0..pos.len())
        .filter(|&i| pos[i][..2].iter().all(|&x| (0.2..0.8).contains(&x)))
        .map(|i| {
            index.neighbours(i, 1, &mut ids);
            Vec3::from(pos[i]).distance(pos[ids[0] as usize].into())
        })
        .collect();
    coefficient_of_variation(&d)
}

fn uniform(n: usize, seed: u64) -> Vec<[f32; 3]> {
    crate::synthetic::uniform_square(n, seed, 1.0).position
}

/// Measured with seed 7: interior NN spread 0.49 → 0.095, low-frequency power 0.82 → 0.040.
#[test]
fn uniform_photons_relax_toward_blue_noise() {
    let mut pos = uniform(1200, 7);
    let start = pos.clone();
    let white = low_frequency_power(&pos, 0.2, 0.6, 1.0, 5.0);
    let m = relax_plane(&mut pos, 14);
    let blue = low_frequency_power(&pos, 0.2, 0.6, 1.0, 5.0);
    // Nearest-neighbour spread away from the border (photons at the border of a set drift
    // outward, which is what constraints are for): ≈ 0.52 for uniform random points.
    let (cv0, cv1) = (interior_cv(&start), interior_cv(&pos));
    assert!(cv0 > 0.45, "start cv {cv0}");
    assert!(cv1 < cv0 / 3.0, "cv {cv0} -> {cv1}");
    assert!(m[1].nn_cv < m[0].nn_cv);
    // The blue-noise dip: low-frequency power falls well below white noise's 1.
    assert!(white > 0.6, "white {white}");
    assert!(blue < white / 5.0, "power {white} -> {blue}");
    // Displacements shrink as the set settles, and everything stays on the plane.
    assert!(m[13].mean_displacement < m[0].mean_displacement);
    assert!(pos.iter().all(|p| p[2] == 0.0 && p[0].is_finite() && p[1].is_finite()));
}

#[test]
fn coincident_photons_come_apart() {
    let mut pos = uniform(300, 3);
    for i in 0..20 {
        pos[100 + i] = pos[100];
    }
    relax_plane(&mut pos, 7);
    let p = Vec3::from(pos[100]);
    let min = (101..120).map(|i| p.distance(pos[i].into())).fold(f32::MAX, f32::min);
    assert!(min > 1e-4, "stack did not separate: {min}");
    assert!(pos.iter().all(|p| p.iter().all(|x| x.is_finite())));
}

/// A search that counts the neighbours asked for (the work a crowd makes).
struct Counting<'a>(BruteForce<'a>, std::sync::atomic::AtomicUsize);

impl NeighbourSearch for Counting<'_> {
    fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>) {
        self.1.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
        self.0.neighbours(i, k, out);
    }
}

/// Issue 31 item 5: a crowd of photons on one point (1 500 beside 300 spread ones) asks
/// for a bounded number of neighbours per photon, not a search as large as the crowd,
/// and still comes apart, by about the map's mean spacing; a map that is all one point
/// has no length to separate its photons by and stays as it is, finite.
#[test]
fn a_crowd_on_one_point_costs_bounded_searches_and_comes_apart() {
    let mut pos = uniform(300, 5);
    pos.extend(std::iter::repeat_n([0.5, 0.5, 0.0], 1500));
    let n = pos.len();
    let normal = vec![[0.0, 0.0, 1.0]; n];
    let p = RelaxParams::default();
    let snapshot = pos.clone();
    let index = Counting(BruteForce(&snapshot), Default::default());
    iterate(&mut pos, &index, Constraint::Tangent { normal: &normal }, &p, 0, &mut Scratch::default());
    let asked = index.1.into_inner();
    assert!(asked <= n * 5 * p.kf, "{asked} neighbours asked for {n} photons (Kf {})", p.kf);
    let spacing = map_spacing(&snapshot);
    let crowd: Vec<Vec3> = pos[300..].iter().map(|&x| Vec3::from(x)).collect();
    let spread = crowd.iter().map(|x| x.distance(Vec3::new(0.5, 0.5, 0.0))).fold(0.0f32, f32::max);
    assert!(spread > 0.1 * spacing && spread < 2.0 * spacing, "spread {spread}, spacing {spacing}");
    let distinct: std::collections::HashSet<[u32; 3]> =
        crowd.iter().map(|x| x.to_array().map(f32::to_bits)).collect();
    assert_eq!(distinct.len(), crowd.len(), "every photon of the crowd moved its own way");

    let mut one = vec![[0.25f32, -1.0, 0.0]; 500];
    let normal = vec![[0.0, 0.0, 1.0]; one.len()];
    let snapshot = one.clone();
    let index = Counting(BruteForce(&snapshot), Default::default());
    iterate(&mut one, &index, Constraint::Tangent { normal: &normal }, &p, 0, &mut Scratch::default());
    assert!(index.1.into_inner() <= 500 * 5 * p.kf);
    assert_eq!(one, snapshot);
}

// ---- Issue 5: basis factors 0 and 1, the paper's Fig. 3 (e–f), stability.

/// Runs `iterations` Jacobi iterations of `iterate` with the brute-force search under the
/// same basis for every photon, returning the positions after each.
fn relax_in_basis(pos: &mut [[f32; 3]], u: [f32; 3], v: [f32; 3], iterations: usize) -> Vec<Vec<[f32; 3]>> {
    let (bu, bv) = (vec![u; pos.len()], vec![v; pos.len()]);
    let p = RelaxParams::default();
    let mut scratch = Scratch::default();
    (0..iterations)
        .map(|it| {
            let snapshot = pos.to_vec();
            let index = BruteForce(&snapshot);
            iterate(pos, &index, Constraint::Basis { u: &bu, v: &bv }, &p, it, &mut scratch);
            pos.to_vec()
        })
        .collect()
}

/// Issue 5: Eq. 9 through `iterate`. Measured (300 uniform photons, 20 iterations): with
/// v_b = 0 all 300 moved in x and none in y (to the bit); with v_b = ŷ all 300 moved in both
/// (mean |Δy| 0.29).
#[test]
fn basis_factor_zero_never_moves_along_p2_and_factor_one_moves_along_both() {
    let start = uniform(300, 5);
    let mut locked = start.clone();
    let steps = relax_in_basis(&mut locked, [1.0, 0.0, 0.0], [0.0; 3], 20);
    let moved_x = |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).filter(|(p, q)| p[0] != q[0]).count();
    let moved_y = |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).filter(|(p, q)| p[1] != q[1]).count();
    for (it, pos) in steps.iter().enumerate() {
        for (i, (p, q)) in pos.iter().zip(&start).enumerate() {
            assert_eq!(p[1].to_bits(), q[1].to_bits(), "photon {i} moved along P2 in iteration {it}");
            assert_eq!(p[2].to_bits(), q[2].to_bits(), "photon {i} left the plane in iteration {it}");
        }
    }
    let mx = moved_x(&locked, &start);
    let mut free = start.clone();
    relax_in_basis(&mut free, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], 20);
    let (fx, fy) = (moved_x(&free, &start), moved_y(&free, &start));
    assert!(mx > 290, "only {mx} of 300 photons moved along u_b");
    assert!(fx > 290 && fy > 290, "free: {fx} moved along x, {fy} along y");
    assert!(free.iter().all(|p| p[2] == 0.0));
}

/// Writes `m` into `dir` as `file` and opens it.
fn map_in(dir: &std::path::Path, file: &str, m: &crate::synthetic::SyntheticMap) -> crate::format::PhotonMap {
    m.written_to(&dir.join(file))
}

/// Relaxes `map` and writes it to `dir/file`, returning the written map.
fn relax_to(
    map: &crate::format::PhotonMap,
    p: &RelaxParams,
    dir: &std::path::Path,
    file: &str,
) -> crate::format::PhotonMap {
    let r = relax_map(&map.view(), p, |_| {}).unwrap();
    let path = dir.join(file);
    relaxed_map(&map.view(), r, p, 0.0).unwrap().write(crate::format::Output::Path(path.clone())).unwrap();
    crate::format::PhotonMap::open_path(&path).unwrap()
}

/// Detects (param-pca, defaults) and writes `map` to `dir/file`.
fn detect_to(map: &crate::format::PhotonMap, dir: &std::path::Path, file: &str) -> crate::format::PhotonMap {
    let p = crate::detect::DetectParams::default();
    let d = crate::detect::detect_map(&map.view(), &p, &|_| {}).unwrap();
    let path = dir.join(file);
    let table = crate::detect::detected_map(&map.view(), d, &p, 0.0).unwrap();
    table.write(crate::format::Output::Path(path.clone())).unwrap();
    crate::format::PhotonMap::open_path(&path).unwrap()
}

/// The paper's Fig. 3 (as in detect's tests): params (u, v) uniform; set A (u < ½) lands on
/// x = 1.2·u, set B on x = 0.4 + 1.2·(u − ½), y = v, overlapping in 0.4 ≤ x < 0.6.
fn fig3(n: usize, seed: u64) -> crate::synthetic::SyntheticMap {
    use rand::{RngExt, SeedableRng};
    let mut r = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let mut m = crate::synthetic::uniform_square(n, seed, 1.0);
    for i in 0..n {
        let (u, v) = (r.random::<f32>(), r.random::<f32>());
        let x = if u < 0.5 { 1.2 * u } else { 0.4 + 1.2 * (u - 0.5) };
        m.position[i] = [x, v, 0.0];
        m.params[2 * i] = u;
        m.params[2 * i + 1] = v;
    }
    m
}

/// Coefficient of variation of nearest-neighbour distances (over all photons, both sets)
/// of the photons inside the overlap's interior x ∈ [0.44, 0.56], y ∈ [0.1, 0.9].
fn overlap_cv(pos: &[[f32; 3]]) -> f64 {
    let index = BruteForce(pos);
    let mut ids = Vec::new();
    let d: Vec<f32> = (0..pos.len())
        .filter(|&i| (0.44..0.56).contains(&pos[i][0]) && (0.1..0.9).contains(&pos[i][1]))
        .map(|i| {
            index.neighbours(i, 1, &mut ids);
            Vec3::from(pos[i]).distance(pos[ids[0] as usize].into())
        })
        .collect();
    assert!(d.len() > 100, "{} photons in the overlap", d.len());
    coefficient_of_variation(&d)
}

/// Issue 5, Fig. 3 (e–f): detect (param-pca), relax in world+params space, collapse, relax
/// in world space. In the params stage A and B relax each on its own, so in the overlap two
/// independent blue-noise sets lie on top of each other; only after the collapse do they
/// relax as one set.
///
/// Measured (4000 photons, 7 + 7 iterations; NN-distance CV in x ∈ [0.44, 0.56],
/// y ∈ [0.1, 0.9], both sets): seed 50: input 0.523, params stage 0.290, collapse + world
/// 0.138. Seeds 51–54: input 0.48–0.52, params stage 0.20–0.26, final 0.10–0.13; final /
/// params-stage ratio 0.47–0.54, params-stage / input 0.41–0.55. Thresholds: final < 0.75 ×
/// params stage (a collapse that kept the parameter restriction leaves ≈ the params-stage
/// value), params stage < 0.75 × input, input > 0.45 (uniform random points give ≈ 0.52).
#[test]
fn fig3_collapse_and_world_relax_even_out_the_overlap_of_two_sets() {
    let dir = tempfile::tempdir().unwrap();
    let p = RelaxParams::default();
    let input = map_in(dir.path(), "in.phm", &fig3(4000, 50));
    let detected = detect_to(&input, dir.path(), "d.phm");
    let r1 = relax_to(&detected, &p, dir.path(), "r1.phm");
    assert_eq!(r1.meta().history.last().unwrap().report["space"], "world_params");
    let c_path = dir.path().join("c.phm");
    collapse(&r1.view()).unwrap().write(crate::format::Output::Path(c_path.clone())).unwrap();
    let c = crate::format::PhotonMap::open_path(&c_path).unwrap();
    let r2 = relax_to(&c, &p, dir.path(), "r2.phm");
    assert_eq!(r2.meta().history.last().unwrap().report["space"], "world");
    let (cv0, cv1, cv2) =
        (overlap_cv(input.positions()), overlap_cv(r1.positions()), overlap_cv(r2.positions()));
    assert!(cv0 > 0.45, "input cv {cv0}");
    assert!(cv1 < 0.75 * cv0, "params stage cv {cv1} vs input {cv0}");
    assert!(cv2 < 0.75 * cv1, "collapse + world cv {cv2} vs params stage {cv1}");
    assert!(all_finite(r2.positions()) && r2.positions().iter().all(|q| q[2] == 0.0));
}

/// Detect and relax (both spaces) give the same bits on one thread and on three: the
/// k-NN buffers are reused across queries (their gathered candidates and bounds change
/// the order neighbours come in), so this holds only because each chunk starts afresh.
#[test]
fn detect_and_relax_are_the_same_on_one_and_three_threads() {
    let dir = tempfile::tempdir().unwrap();
    // Several chunks of photons, so that threads interleave chunks differently.
    let input = map_in(dir.path(), "in.phm", &fig3(5 * CHUNK + 123, 60));
    let p = RelaxParams { iterations: 2, ..RelaxParams::default() };
    let run = |threads: usize, tag: &str| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let d = detect_to(&input, dir.path(), &format!("d{tag}.phm"));
            let dp = crate::detect::detect_map(&input.view(), &Default::default(), &|_| {}).unwrap();
            let r1 = relax_map(&d.view(), &p, |_| {}).unwrap();
            let r1_file = relax_to(&d, &p, dir.path(), &format!("r{tag}.phm"));
            let c_path = dir.path().join(format!("c{tag}.phm"));
            collapse(&r1_file.view()).unwrap().write(crate::format::Output::Path(c_path.clone())).unwrap();
            let c = crate::format::PhotonMap::open_path(&c_path).unwrap();
            let r2 = relax_map(&c.view(), &p, |_| {}).unwrap();
            (dp.basis_u, dp.basis_v, dp.lambda2, dp.r_param, r1.positions, r2.positions)
        })
    };
    let (one, three) = (run(1, "1"), run(3, "3"));
    assert!(one.0 == three.0 && one.1 == three.1 && one.2 == three.2 && one.3 == three.3, "detect");
    assert!(one.4 == three.4, "relax in world + params");
    assert!(one.5 == three.5, "relax in world");
    assert!(one.4 != input.positions(), "the photons moved");
}

/// `m` with every position scaled by `s`.
fn scaled(m: &crate::synthetic::SyntheticMap, s: f32) -> crate::synthetic::SyntheticMap {
    let mut m = m.clone();
    for x in m.position.iter_mut() {
        *x = x.map(|c| c * s);
    }
    m
}

fn all_finite(pos: &[[f32; 3]]) -> bool {
    pos.iter().flatten().all(|x| x.is_finite())
}

/// A cluster of 100 uniform photons in the unit square and 5 far away (at x = 1000), with
/// far-away parameters too.
fn cluster_and_strays() -> crate::synthetic::SyntheticMap {
    let mut m = crate::synthetic::uniform_square(105, 8, 1.0);
    for k in 0..5 {
        let i = 100 + k;
        m.position[i] = [1000.0 + k as f32 * 0.01, 0.5, 0.0];
        m.params[2 * i] = 0.9 + 0.02 * k as f32;
        m.params[2 * i + 1] = 0.99;
    }
    m
}

/// Issue 5, stability (a): photons with few or far neighbours. Measured (7 iterations):
/// the 5 strays at x ≈ 1000 end at x = 512 … 2375 (world) and 512 … 2375 (world+params),
/// their r_K being the distance to the cluster; the 3-photon map grows from the unit square
/// to a 5.9 × 3.1 box. Finite, but see the ignored test below for longer runs.
#[test]
fn isolated_photons_stay_finite() {
    let dir = tempfile::tempdir().unwrap();
    let p = RelaxParams::default();
    let m = cluster_and_strays();
    let world = relax_to(&map_in(dir.path(), "a.phm", &m), &p, dir.path(), "a1.phm");
    assert!(all_finite(world.positions()));
    let detected = detect_to(&map_in(dir.path(), "a.phm", &m), dir.path(), "ad.phm");
    let wp = relax_to(&detected, &p, dir.path(), "ad1.phm");
    assert!(all_finite(wp.positions()));
    let three = crate::synthetic::uniform_square(3, 9, 1.0);
    let t = relax_to(&map_in(dir.path(), "t.phm", &three), &p, dir.path(), "t1.phm");
    assert!(all_finite(t.positions()));
    let td = detect_to(&map_in(dir.path(), "t.phm", &three), dir.path(), "td.phm");
    let t2 = relax_to(&td, &p, dir.path(), "td1.phm");
    assert!(all_finite(t2.positions()));
}

/// Relaxes 300 uniform photons for `iterations` in world space: detected (param-pca) and
/// collapsed when `constrained`, else free in their tangent plane. Returns the positions,
/// or the error when the index refused them.
fn long_run(constrained: bool, iterations: usize) -> Result<Vec<[f32; 3]>, RelaxError> {
    let dir = tempfile::tempdir().unwrap();
    let mut map = map_in(dir.path(), "s.phm", &crate::synthetic::uniform_square(300, 12, 1.0));
    if constrained {
        let d = detect_to(&map, dir.path(), "d.phm");
        let c = dir.path().join("c.phm");
        collapse(&d.view()).unwrap().write(crate::format::Output::Path(c.clone())).unwrap();
        map = crate::format::PhotonMap::open_path(&c).unwrap();
    }
    let p = RelaxParams { iterations, ..Default::default() };
    let r = relax_map(&map.view(), &p, |_| {})?;
    assert_eq!(r.space, RelaxSpace::World);
    Ok(r.positions)
}

/// Issue 5, stability (b): 1000 iterations on 300 photons in world space, free and with a
/// constraint basis, and on a map of 3 photons: positions stay finite and on the plane, and
/// no photon travels farther than [`Scratch`]'s guarantee, 1000 × step_limit × its first
/// spacing r_K·sqrt(π/Kf) (r_K by brute force on the input). Before the cap the border
/// moved out geometrically (≈ ×1.1 per iteration: box 1.5e18 after 400 iterations, then
/// non-finite positions).
#[test]
fn a_thousand_iterations_stay_finite_on_the_plane_and_bounded() {
    let m = crate::synthetic::uniform_square(300, 12, 1.0);
    let p = RelaxParams::default();
    let first_spacing = |pos: &[[f32; 3]]| -> Vec<f32> {
        (0..pos.len())
            .map(|i| {
                let mut d: Vec<f32> = (0..pos.len())
                    .filter(|&j| j != i)
                    .map(|j| Vec3::from(pos[i]).distance(Vec3::from(pos[j])))
                    .collect();
                d.sort_by(f32::total_cmp);
                let k = p.kf.min(d.len());
                d[k - 1] * (std::f32::consts::PI / k as f32).sqrt()
            })
            .collect()
    };
    let cap = first_spacing(&m.position);
    for constrained in [true, false] {
        let pos = long_run(constrained, 1000).expect("relax_map failed");
        assert!(all_finite(&pos) && pos.iter().all(|p| p[2] == 0.0));
        for (i, (a, b)) in pos.iter().zip(&m.position).enumerate() {
            let moved = Vec3::from(*a).distance(Vec3::from(*b));
            assert!(moved <= 1000.0 * p.step_limit * cap[i] * 1.0001, "photon {i} moved {moved}");
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let three = map_in(dir.path(), "t.phm", &crate::synthetic::uniform_square(3, 9, 1.0));
    let r = relax_map(&three.view(), &RelaxParams { iterations: 1000, ..Default::default() }, |_| {})
        .expect("relax_map failed");
    assert!(all_finite(&r.positions));
}

/// Issue 5, stability (c): the force and step limit are relative to r_K, so scaling the map
/// scales the result. Measured (300 photons, 7 iterations, positions in [0, 1], largest
/// move 0.58): max |x/s − x| 1.1e-6 at s = 1e-6 and 9.8e-7 at s = 1e6 (≈ 10 f32 ulps: the
/// scaled input is itself rounded). Tolerance 1e-5; an absolute ε or step limit would be
/// off by a photon spacing (≈ 0.06).
#[test]
fn relaxing_is_scale_invariant() {
    let dir = tempfile::tempdir().unwrap();
    let m = crate::synthetic::uniform_square(300, 12, 1.0);
    let p = RelaxParams::default();
    let base = relax_map(&map_in(dir.path(), "s.phm", &m).view(), &p, |_| {}).unwrap();
    for s in [1e-6f32, 1e6] {
        let r = relax_map(&map_in(dir.path(), "x.phm", &scaled(&m, s)).view(), &p, |_| {}).unwrap();
        assert!(all_finite(&r.positions));
        let err = r
            .positions
            .iter()
            .zip(&base.positions)
            .map(|(a, b)| (Vec3::from(*a) / s - Vec3::from(*b)).length() as f64)
            .fold(0.0, f64::max);
        let moved = base
            .positions
            .iter()
            .zip(&m.position)
            .map(|(a, b)| Vec3::from(*a).distance(Vec3::from(*b)) as f64)
            .fold(0.0, f64::max);
        assert!(err < 1e-5, "scale {s:e}: max |x/s − x| {err:e}");
        assert!(moved > 0.1, "the unscaled run barely moved ({moved})");
    }
}

/// Detect and relax work on photons relabelled in spatial order: the order of the photons
/// in the file must not matter. Fig. 3's map and the same map stored in reverse, detected
/// and relaxed in parameter space: every photon ends where its twin does. Measured: exactly
/// (both runs work in the same Z-order; only photons sharing a Z-order cell could be
/// visited in another order, and then sums round differently), so the tolerance 1e-5
/// against moves of ≈ 0.1 is only for that.
#[test]
fn results_do_not_depend_on_the_order_photons_are_stored_in() {
    let dir = tempfile::tempdir().unwrap();
    let m = fig3(2000, 31);
    let mut r = m.clone();
    let n = m.len();
    let d = m.param_dims as usize;
    let back = |i: usize| n - 1 - i;
    for i in 0..n {
        r.position[i] = m.position[back(i)];
        r.normal[i] = m.normal[back(i)];
        r.flux[i] = m.flux[back(i)];
        r.incident[i] = m.incident[back(i)];
        r.path_length[i] = m.path_length[back(i)];
        r.bounces[i] = m.bounces[back(i)];
        r.emission_index[i] = m.emission_index[back(i)];
        r.params[i * d..][..d].copy_from_slice(&m.params[back(i) * d..][..d]);
    }
    let p = RelaxParams::default();
    let a = detect_to(&map_in(dir.path(), "a.phm", &m), dir.path(), "ad.phm");
    let b = detect_to(&map_in(dir.path(), "b.phm", &r), dir.path(), "bd.phm");
    let (ra, rb) = (relax_map(&a.view(), &p, |_| {}).unwrap(), relax_map(&b.view(), &p, |_| {}).unwrap());
    assert_eq!(ra.space, RelaxSpace::WorldParams);
    let (mut err, mut moved) = (0f32, 0f32);
    for i in 0..n {
        err = err.max(Vec3::from(ra.positions[i]).distance(Vec3::from(rb.positions[back(i)])));
        moved = moved.max(Vec3::from(ra.positions[i]).distance(Vec3::from(m.position[i])));
    }
    assert!(err < 1e-5, "largest difference {err:e}");
    assert!(moved > 0.01, "relaxation barely moved ({moved})");
}

/// Issue 7: returning a photon to its surface uses no absolute length. A floor at z = 0
/// between two parallel shelves 2 µm above and below it, at scales 1e-6 (the shelves 2 µm
/// away) and 1 (2 m away), and a photon moved 10 nm (10 mm) in the floor's plane: the
/// search reaches a quarter step beyond it, so it finds the floor and not a shelf. (With the former
/// margin of 1e-5 m, the search at 1e-6 met a shelf first in both directions and refused.)
#[test]
fn return_to_surface_holds_at_micrometre_scale() {
    use crate::scene::{Material, Scene, Shape, Surface, SurfaceGeometry};
    for s in [1e-6f32, 1.0] {
        let rect = |z: f32| {
            let o = Vec3::new(-10.0, -10.0, z) * s;
            Shape::rectangle(o, Vec3::X * 20.0 * s, Vec3::Y * 20.0 * s).unwrap()
        };
        let surfaces = [0.0, 2.0, -2.0]
            .iter()
            .enumerate()
            .map(|(i, &z)| Surface {
                name: format!("s{i}"),
                material: 0,
                geometry: SurfaceGeometry::Analytic(rect(z)),
            })
            .collect();
        let emitter = crate::scene::Emitter {
            kind: crate::scene::EmitterShape::Point { position: Vec3::new(0.0, 0.0, 1.0) * s },
            power_w: 1.0,
            colour: Vec3::ONE,
        };
        let scene = Scene::new(
            vec![("floor".into(), Material::Diffuse { albedo: Vec3::ONE })],
            vec![emitter],
            surfaces,
        );
        let moved = Vec3::new(0.01, 0.0, 0.0) * s;
        let (at, n) = return_to_surface(&scene, 0, moved, Vec3::Z, 0.01 * s).expect("floor found");
        assert!(at.z.abs() <= 1e-6 * s && (at.x - moved.x).abs() <= 1e-6 * s && n == Vec3::Z, "{s}: {at}");
    }
}

/// A photon on a sphere of radius 1 stepped along its tangent plane returns to the sphere
/// when the step is small against the radius (it leaves the sphere by about s²/2), and its
/// move is refused when the sphere lies farther than [`surface::RETURN_REACH`] steps from where
/// the step ends: so no move, returned, takes a photon farther than (1 + that) steps, which a
/// tile's move bounds rely on (docs/tiles.md).
#[test]
fn a_return_to_a_surface_stays_within_its_reach() {
    use crate::scene::{Material, Scene, Shape, Surface, SurfaceGeometry};
    let sphere = Surface {
        name: "ball".into(),
        material: 0,
        geometry: SurfaceGeometry::Analytic(Shape::Sphere { center: Vec3::ZERO, radius: 1.0 }),
    };
    let emitter = crate::scene::Emitter {
        kind: crate::scene::EmitterShape::Point { position: Vec3::new(0.0, 0.0, 3.0) },
        power_w: 1.0,
        colour: Vec3::ONE,
    };
    let scene = Scene::new(
        vec![("ball".into(), Material::Diffuse { albedo: Vec3::ONE })],
        vec![emitter],
        vec![sphere],
    );
    let reach = surface::RETURN_REACH;
    for s in [0.01f32, 0.1, 0.3, 0.45, 0.55, 1.0] {
        let moved = Vec3::new(s, 0.0, 1.0);
        let off = moved.length() - 1.0;
        match return_to_surface(&scene, 0, moved, Vec3::Z, s) {
            Some((at, n)) => {
                assert!((at.length() - 1.0).abs() < 1e-5 && n.dot(at) > 0.99, "step {s}: {at}");
                assert!(
                    at.distance(moved) <= reach * s * 1.0001,
                    "step {s}: returned {} away",
                    at.distance(moved)
                );
            }
            None => assert!(off > reach * s, "step {s}: refused, the sphere {off} away"),
        }
        // Accepted exactly when the sphere along the normal is within the reach.
        let along = 1.0 - (1.0 - s * s).max(0.0).sqrt();
        let found = return_to_surface(&scene, 0, moved, Vec3::Z, s).is_some();
        assert_eq!(found, s < 1.0 && along <= reach * s, "step {s}: the sphere {along} along the normal");
    }
}

mod spectral;
mod tiles;

/// A tile's photons put in file order, with where each is among them, against a search.
#[test]
fn file_order_places_every_photon() {
    let work: Vec<u32> = (0..5000u32).map(|k| (k.wrapping_mul(2_654_435_761) >> 7) % 100_000).collect();
    let mut distinct = work.clone();
    distinct.sort_unstable();
    distinct.dedup();
    // Distinct photons in a scattered order, as a tile's labels give them.
    let work: Vec<u32> = {
        let mut seen = std::collections::HashSet::new();
        work.into_iter().filter(|i| seen.insert(*i)).collect()
    };
    let (rows, within) = super::file_order(&work);
    assert_eq!(rows, distinct);
    for (k, &i) in work.iter().enumerate() {
        assert_eq!(rows[within[k] as usize], i, "photon {k}");
    }
    assert!(work.windows(2).any(|w| w[0] > w[1]), "the test's order is not already ascending");
    assert_eq!(super::file_order(&[]), (vec![], vec![]));
}
