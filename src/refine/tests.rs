use glam::Vec3;

use super::*;
use crate::format::{Output, PhotonMap};
use crate::sampling::halton::PhotonRng;
use crate::spatial::BoxTree;

/// `n` fresh photons uniform on the unit square of the floor, facing up, `watts` in all.
fn uniform_fresh(n: usize, seed: u64, watts: f32) -> crate::trace::Photons {
    let mut rng = PhotonRng::new(seed, 3);
    let mut p = crate::trace::Photons::default();
    for _ in 0..n {
        p.position.push([rng.next_f32(), rng.next_f32(), 0.0]);
        p.normal.push([0.0, 0.0, 1.0]);
        p.flux.push([watts / 3.0 / n as f32; 3]);
    }
    p
}

fn grid_primal(side: usize) -> Primal {
    let positions: Vec<[f32; 3]> = (0..side * side)
        .map(|i| [((i % side) as f32 + 0.5) / side as f32, ((i / side) as f32 + 0.5) / side as f32, 0.0])
        .collect();
    let n = positions.len();
    Primal {
        flux: vec![[1.0 / 3.0 / n as f32; 3]; n],
        normals: Some(vec![[0.0, 0.0, 1.0]; n]),
        positions,
        basis: None,
    }
}

/// Asserts that the map after `pass` carries `total` flux per channel (energy is kept).
fn assert_energy(t: &crate::format::PhotonTable, total: [f64; 3], pass: u64) {
    let got = Primal::from_map(&t.view()).unwrap().total_flux();
    for c in 0..3 {
        assert!((got[c] / total[c] - 1.0).abs() < 1e-5, "pass {pass}: {got:?} against {total:?}");
    }
}

#[test]
fn gather_gives_each_fresh_photon_to_its_nearest_primal_photon_on_its_side() {
    let mut primal = grid_primal(20);
    // Every seventh primal photon faces down: the fresh photons nearest to it go to their
    // nearest one facing up.
    let facing_down = |i: usize| i % 7 == 3;
    for (i, n) in primal.normals.as_mut().unwrap().iter_mut().enumerate() {
        if facing_down(i) {
            *n = [0.0, 0.0, -1.0];
        }
    }
    let mut stats = Statistics::start(&primal.flux, 0.0);
    let mut fresh = uniform_fresh(5000, 1, 1.0);
    // A few photons on a surface facing another way belong to no primal photon.
    for j in 0..50 {
        fresh.normal[j] = [1.0, 0.0, 0.0];
    }
    let gathered = gather(&mut stats, &primal, &BoxTree::build(&primal.positions), &fresh);
    let mut want = vec![0.0f64; primal.len()];
    for j in 50..fresh.len() {
        let x = Vec3::from(fresh.position[j]);
        let nearest = (0..primal.len())
            .filter(|&i| !facing_down(i))
            .min_by(|&a, &b| {
                let d = |i: usize| x.distance_squared(primal.positions[i].into());
                d(a).total_cmp(&d(b)).then(a.cmp(&b))
            })
            .unwrap();
        want[nearest] += fresh.flux[j][0] as f64;
    }
    assert!(want.iter().enumerate().all(|(i, &w)| !facing_down(i) || w == 0.0));
    for (i, w) in want.iter().enumerate() {
        assert!((stats.tau[i][0] as f64 - w).abs() < 1e-6, "photon {i}: {} against {w}", stats.tau[i][0]);
        assert_eq!(stats.passes[i], 1.0);
    }
    assert!((gathered - 4950.0 / 400.0).abs() < 1e-9, "{gathered}");
}

#[test]
fn the_cell_flux_converges_to_the_closed_form() {
    // 1 W per pass uniformly over the unit square: each of the 24² grid cells receives
    // (1/3)/576 W per channel. The error of the estimate falls as passes accumulate.
    let primal = grid_primal(24);
    let mut stats = Statistics::start(&primal.flux, 0.0);
    let tree = BoxTree::build(&primal.positions);
    let exact = 1.0 / 3.0 / 576.0;
    let rms = |s: &Statistics| {
        let e2: f64 = (0..primal.len()).map(|i| (s.cell_flux(i).x as f64 / exact - 1.0).powi(2)).sum::<f64>()
            / primal.len() as f64;
        e2.sqrt()
    };
    let mut errors = Vec::new();
    for pass in 0..64 {
        gather(&mut stats, &primal, &tree, &uniform_fresh(5000, 100 + pass, 1.0));
        if [0, 7, 63].contains(&pass) {
            errors.push(rms(&stats));
        }
    }
    // About 8.7 photons per cell per pass: Poisson noise 1/sqrt(8.7 P).
    assert!(errors[0] > 0.2, "one pass is noisy: {errors:?}");
    assert!(errors[1] < 0.5 * errors[0] && errors[2] < 0.5 * errors[1], "{errors:?}");
    assert!(errors[2] < 0.05, "{errors:?}");
}

#[test]
fn the_map_s_own_flux_is_a_prior_worth_w_passes() {
    // Each cell's estimate is (w·φ_i + τ_i)/(w + P). The same passes gathered without a prior
    // give τ_i/P, so the two must agree with that formula; with the exact flux as φ the first
    // pass's error falls to a fifth (w = 4); a prior 30 % too high fades as 0.3·w/(w + P).
    let primal = grid_primal(24);
    let tree = BoxTree::build(&primal.positions);
    let exact = 1.0f32 / 3.0 / 576.0;
    let w = 4.0;
    let run = |phi: f32, passes: u64| {
        let mut plain = Statistics::start(&primal.flux, 0.0);
        let mut prior = Statistics::start(&vec![[phi; 3]; primal.len()], w);
        for pass in 0..passes {
            let fresh = uniform_fresh(5000, 100 + pass, 1.0);
            gather(&mut plain, &primal, &tree, &fresh);
            gather(&mut prior, &primal, &tree, &fresh);
        }
        let p = passes as f32;
        let (mut e_plain, mut e_prior, mut bias) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..primal.len() {
            let want = (w * phi + p * plain.cell_flux(i).x) / (w + p);
            let got = prior.cell_flux(i).x;
            assert!((got / want - 1.0).abs() < 1e-5, "photon {i}: {got} against {want}");
            e_plain += ((plain.cell_flux(i).x / exact - 1.0) as f64).powi(2);
            e_prior += ((got / exact - 1.0) as f64).powi(2);
            bias += (got / exact - 1.0) as f64;
        }
        let n = primal.len() as f64;
        ((e_plain / n).sqrt(), (e_prior / n).sqrt(), bias / n)
    };
    let (plain, prior, _) = run(exact, 1);
    assert!(prior < 0.25 * plain, "one pass: {prior} with the prior against {plain}");
    let (_, _, bias) = run(1.3 * exact, 60);
    let want = 0.3 * 4.0 / 64.0;
    assert!((bias - want).abs() < 0.01, "bias {bias} against {want}");
}

/// `n` fresh photons on the unit square with irradiance 1 on the left half and 3 on the right.
fn two_level_fresh(n: usize, seed: u64) -> crate::trace::Photons {
    let mut p = uniform_fresh(n, seed, 2.0);
    for x in &mut p.position {
        // Three quarters of the photons land on the right half.
        x[0] = if x[0] < 0.25 { 2.0 * x[0] } else { 0.5 + (x[0] - 0.25) * 2.0 / 3.0 };
    }
    p
}

#[test]
fn relaxation_draws_photons_toward_the_brighter_side_and_evens_their_flux() {
    // Passes of photons from a field three times as bright on the right: with relaxation the
    // photons crowd to the right and the flux per photon evens out; without, they stay put and
    // carry the field's contrast.
    let run = |iterations: usize| {
        let mut primal = grid_primal(24);
        let mut stats = Statistics::start(&primal.flux, 0.0);
        let total = primal.total_flux();
        let p = RefineParams { iterations, ..RefineParams::default() };
        let mut cv = 0.0;
        for pass in 0..24 {
            gather(
                &mut stats,
                &primal,
                &BoxTree::build(&primal.positions),
                &two_level_fresh(20_000, 300 + pass),
            );
            for _ in 0..p.iterations {
                relax_toward_flux(&mut primal, &mut stats, &p);
            }
            let raw: Vec<Vec3> = (0..primal.len()).map(|i| stats.cell_flux(i)).collect();
            cv = set_flux(&mut primal, &raw, total);
            let after = primal.total_flux();
            for c in 0..3 {
                assert!((after[c] / total[c] - 1.0).abs() < 1e-5, "energy: {after:?} against {total:?}");
            }
        }
        let _ = cv;
        // Mean flux per photon in the bright interior over the dim one's.
        let mean = |lo: f32, hi: f32| {
            let f: Vec<f64> = (0..primal.len())
                .filter(|&i| (lo..hi).contains(&primal.positions[i][0]))
                .map(|i| primal.flux[i][0] as f64)
                .collect();
            f.iter().sum::<f64>() / f.len() as f64
        };
        let contrast = mean(0.6, 0.8) / mean(0.2, 0.4);
        (primal, contrast)
    };
    // The spacing (distance to the 16th neighbour) in the bright interior over the dim one's.
    let spacing_ratio = |p: &Primal| {
        let (r2, _) = super::pass::neighbourhoods(&p.positions, 16);
        let band = |lo: f32, hi: f32| {
            let r: Vec<f64> = (0..p.len())
                .filter(|&i| {
                    (lo..hi).contains(&p.positions[i][0]) && (0.25..0.75).contains(&p.positions[i][1])
                })
                .map(|i| (r2[i] as f64).sqrt())
                .collect();
            r.iter().sum::<f64>() / r.len() as f64
        };
        band(0.6, 0.8) / band(0.2, 0.4)
    };
    let (still, contrast_still) = run(0);
    let (moved, contrast_moved) = run(2);
    assert!((spacing_ratio(&still) - 1.0).abs() < 1e-3, "{}", spacing_ratio(&still));
    assert!(spacing_ratio(&moved) < 0.95, "bright/dim spacing {}", spacing_ratio(&moved));
    assert!(
        (contrast_still - 3.0).abs() < 0.15,
        "still photons carry the field's contrast: {contrast_still}"
    );
    assert!(
        contrast_moved < 0.8 * contrast_still,
        "bright/dim flux per photon {contrast_moved}, still {contrast_still}"
    );
}

/// A traced map of the default scene, written to `dir`.
fn traced_map(dir: &std::path::Path) -> (PhotonMap, Scene) {
    let scene = Scene::default_scene();
    let opts = TraceOptions { budget: crate::trace::Budget::Emitted(60_000), ..TraceOptions::default() };
    let traced = trace::trace(&scene, &opts, &|_, _| {}).unwrap();
    let info = trace::map_info(
        &scene,
        &opts,
        &traced,
        crate::scene::DEFAULT_SCENE_NAME,
        crate::scene::DEFAULT_SCENE.as_bytes(),
    );
    let path = dir.join("traced.phm");
    traced.write(Output::Path(path.clone()), info).unwrap();
    (PhotonMap::open_path(&path).unwrap(), scene)
}

#[test]
fn refinement_keeps_the_energy_and_resumes_to_the_same_map() {
    let dir = tempfile::tempdir().unwrap();
    let (map, scene) = traced_map(dir.path());
    let total = Primal::from_map(&map.view()).unwrap().total_flux();
    let p = RefineParams {
        passes: 3,
        photons_per_pass: Some(30_000),
        iterations: 1,
        growth: 0.0,
        ..RefineParams::default()
    };
    let mut seen = Vec::new();
    let whole = refine(&map.view(), &scene, &p, None, &mut |done| {
        let (m, t) = (done.measure, done.table()?);
        assert_energy(t, total, m.pass);
        seen.push(m.pass);
        Ok(true)
    })
    .unwrap();
    assert_eq!(seen, [1, 2, 3]);
    // Without growth the map renders as any other (no radius map of its first photons).
    assert_eq!(first_photons(&whole.view()), None);
    let rec = RefineRecord::of(&whole.view()).unwrap();
    assert_eq!((rec.passes_done, rec.next_emission), (3, 60_000 + 3 * 30_000));
    assert!(rec.measures.iter().all(|m| m.gathered_per_photon > 0.3), "{:?}", rec.measures);

    // One pass, written; then the rest from the file.
    let first =
        refine(&map.view(), &scene, &RefineParams { passes: 1, ..p }, None, &mut |_| Ok(true)).unwrap();
    let path = dir.path().join("one.phm");
    first.write(Output::Path(path.clone())).unwrap();
    let one = PhotonMap::open_path(&path).unwrap();
    let resumed = refine(&one.view(), &scene, &p, None, &mut |_| Ok(true)).unwrap();
    for column in [name::POSITION, name::FLUX, column::TAU, column::PASSES] {
        assert_eq!(
            resumed.view().column_bytes(column),
            whole.view().column_bytes(column),
            "{column} differs after resuming"
        );
    }
    // Other settings do not resume.
    let other = RefineParams { photons_per_pass: Some(10_000), ..p };
    let e = refine(&one.view(), &scene, &other, None, &mut |_| Ok(true)).unwrap_err();
    assert!(e.to_string().contains("other settings"), "{e}");
}

/// Runs `passes` passes of `fresh(pass)` over a grid of 10 × 10 root photons on the unit
/// square, growing the photons as N₀·p^γ: the photons, their cells, and the leaf estimates.
fn grown_grid(
    passes: u64,
    growth: f32,
    fresh: impl Fn(u64) -> crate::trace::Photons,
) -> (Primal, Cells, Statistics, Vec<Vec3>) {
    let mut primal = grid_primal(10);
    let roots = primal.len();
    let mut stats = Statistics::start(&primal.flux, 0.0);
    let mut cells = Cells::new(&primal.positions);
    let tree = BoxTree::build(&primal.positions);
    let mut estimate = Vec::new();
    for pass in 1..=passes {
        let f = fresh(pass);
        let (_, root) = gather_cells(&mut stats, &primal, &tree, &f);
        cells.descend(&f, &root);
        estimate = cells.leaf_flux(&stats);
        let target = target_count(roots, pass, growth);
        if target > primal.len() {
            let add = target - primal.len();
            let promoted = cells.split_brightest(&mut primal, &estimate, add);
            stats.tau.resize(primal.len(), [0.0; 3]);
            stats.passes.resize(primal.len(), 0.0);
            // `refine` halves the split cells' estimates instead of a pass over every region.
            let mut halved = estimate.clone();
            super::grow::halve_split_cells(&mut halved, &promoted);
            estimate = cells.leaf_flux(&stats);
            assert_eq!(halved, estimate, "pass {pass}: the halves are the hierarchy's estimate");
        }
    }
    (primal, cells, stats, estimate)
}

/// Each photon's cell in the hierarchy, measured by brute force: a 400 × 400 lattice of points
/// on the unit square, each sent to its nearest root site and down the splits. Returns per
/// photon its cell's area and the integral of `irradiance` over it.
fn cell_integrals(cells: &Cells, photons: usize, irradiance: impl Fn(f32) -> f64) -> (Vec<f64>, Vec<f64>) {
    let side = 400;
    let sites = cells.root_sites();
    let mut probe = crate::trace::Photons::default();
    let mut root = Vec::new();
    for k in 0..side * side {
        let x = [((k % side) as f32 + 0.5) / side as f32, ((k / side) as f32 + 0.5) / side as f32, 0.0];
        let nearest = (0..sites.len())
            .min_by(|&a, &b| {
                let d = |i: usize| Vec3::from(x).distance_squared(sites[i].into());
                d(a).total_cmp(&d(b)).then(a.cmp(&b))
            })
            .unwrap();
        probe.position.push(x);
        probe.flux.push([0.0; 3]);
        root.push(Some(nearest as u32));
    }
    let owner = cells.owners(&probe, &root);
    let (mut area, mut integral) = (vec![0.0; photons], vec![0.0; photons]);
    let da = 1.0 / (side * side) as f64;
    for (k, o) in owner.iter().enumerate() {
        let i = o.unwrap() as usize;
        area[i] += da;
        integral[i] += da * irradiance(probe.position[k][0]);
    }
    (area, integral)
}

#[test]
fn split_cells_estimate_the_flux_of_their_part_of_the_parent() {
    // Irradiance 1/3 W/m² per channel on the left half of the square and 1 on the right
    // (two_level_fresh: 2 W in all). The photons grow from 100 to 100·40^0.5 ≈ 632, the
    // brightest cells first; every photon's estimate must match the integral of the
    // irradiance over its cell, which the brute force measures.
    let (primal, cells, _, estimate) = grown_grid(40, 0.5, |pass| two_level_fresh(20_000, 900 + pass));
    assert_eq!(primal.len(), 632);
    let e = |x: f32| if x < 0.5 { 1.0 / 3.0 } else { 1.0 };
    let (area, exact) = cell_integrals(&cells, primal.len(), e);
    let (mut e2, mut bias) = (0.0, 0.0);
    for i in 0..primal.len() {
        assert!(area[i] > 0.0, "photon {i} has an empty cell");
        let rel = estimate[i].x as f64 / exact[i] - 1.0;
        e2 += rel * rel;
        bias += rel;
    }
    let n = primal.len() as f64;
    let (rms, bias) = ((e2 / n).sqrt(), bias / n);
    assert!(rms < 0.08, "relative RMS error {rms}");
    assert!(bias.abs() < 0.01, "mean relative error {bias}");
    // Each photon lies in its own cell (it moved to its site when split).
    let owner = {
        let sites = cells.root_sites();
        let mut probe = crate::trace::Photons::default();
        let mut root = Vec::new();
        for x in &primal.positions {
            let nearest = (0..sites.len())
                .min_by(|&a, &b| {
                    let d = |i: usize| Vec3::from(*x).distance_squared(sites[i].into());
                    d(a).total_cmp(&d(b)).then(a.cmp(&b))
                })
                .unwrap();
            probe.position.push(*x);
            probe.flux.push([0.0; 3]);
            root.push(Some(nearest as u32));
        }
        cells.owners(&probe, &root)
    };
    let home = owner.iter().enumerate().filter(|(i, o)| **o == Some(*i as u32)).count();
    assert!(home as f64 > 0.98 * n, "{home} of {n} photons lie in their own cell");
    // The bright right half holds more photons: about three times as many per area.
    let right = (0..primal.len()).filter(|&i| primal.positions[i][0] > 0.5).count() as f64;
    assert!(right / (n - right) > 2.0, "{right} of {n} on the bright half");
    // The children partition their parent: the leaves' estimates add up to the roots'.
    let sum: f32 = estimate.iter().map(|f| f.x).sum();
    let total: f64 = exact.iter().sum();
    assert!((sum as f64 / total - 1.0).abs() < 0.01, "{sum} against {total}");
}

#[test]
fn the_cells_rebuild_from_their_columns() {
    let (_, cells, stats, _) = grown_grid(9, 1.0 / 3.0, |pass| uniform_fresh(5000, 700 + pass, 1.0));
    assert!(cells.roots() < stats.tau.len());
    let columns = cells.columns(&stats);
    assert_eq!(Cells::rebuild(cells.roots(), &columns), Some(cells.clone()));
    // A photon that names a later photon as the one it split is refused, and so is a root
    // that names one.
    let mut bad = columns.clone();
    bad.split_of[cells.roots()] = cells.roots() as u32 + 1;
    assert_eq!(Cells::rebuild(cells.roots(), &bad), None);
    let mut bad = columns.clone();
    bad.split_of[0] = 1;
    assert_eq!(Cells::rebuild(cells.roots(), &bad), None);
}

#[test]
fn the_photon_count_grows_as_the_power_law() {
    assert_eq!(target_count(1000, 1, 1.0 / 3.0), 1000);
    assert_eq!(target_count(1000, 8, 1.0 / 3.0), 2000);
    assert_eq!(target_count(1000, 64, 1.0 / 3.0), 4000);
    assert_eq!(target_count(1000, 64, 0.0), 1000);
    assert_eq!(target_count(1000, 0, 0.5), 1000);
}

#[test]
fn a_growing_refinement_keeps_the_energy_and_resumes_to_the_same_map() {
    let dir = tempfile::tempdir().unwrap();
    let (map, scene) = traced_map(dir.path());
    let n0 = map.len();
    let total = Primal::from_map(&map.view()).unwrap().total_flux();
    let p =
        RefineParams { passes: 4, photons_per_pass: Some(200_000), growth: 0.5, ..RefineParams::default() };
    let mut counts = Vec::new();
    let whole = refine(&map.view(), &scene, &p, None, &mut |done| {
        let (m, t) = (done.measure, done.table()?);
        assert_energy(t, total, m.pass);
        counts.push(t.len());
        Ok(true)
    })
    .unwrap();
    // A cell splits once it has gathered enough fresh photons, so the count grows toward
    // N₀·p^γ, no faster.
    assert_eq!(counts[0], n0);
    assert!(counts.windows(2).all(|w| w[0] <= w[1]), "{counts:?}");
    assert!(counts[3] > n0 && counts[3] <= 2 * n0, "{counts:?}");
    // The added photons carry every column of the map (their split photon's) and the
    // hierarchy's.
    let view = whole.view();
    assert_eq!(view.columns().len(), map.view().columns().len() + 7);
    let split_of = view.column::<u32>(column::SPLIT_OF).unwrap().unwrap();
    assert!(split_of[..n0].iter().all(|&s| s == u32::MAX));
    assert!(split_of[n0..].iter().enumerate().all(|(k, &s)| (s as usize) < n0 + k));
    // Render's radius map: the map's photons before it grew; none before refinement.
    assert_eq!(first_photons(&view).map(<[_]>::len), Some(n0));
    assert_eq!(first_photons(&map.view()), None);

    let first =
        refine(&map.view(), &scene, &RefineParams { passes: 2, ..p }, None, &mut |_| Ok(true)).unwrap();
    let path = dir.path().join("two.phm");
    first.write(Output::Path(path.clone())).unwrap();
    let two = PhotonMap::open_path(&path).unwrap();
    let resumed = refine(&two.view(), &scene, &p, None, &mut |_| Ok(true)).unwrap();
    for (spec, bytes) in view.columns() {
        assert_eq!(
            resumed.view().column_bytes(&spec.name),
            Some(*bytes),
            "{} differs after resuming",
            spec.name
        );
    }
    // Growth moves no photon: it does not combine with relaxation toward flux.
    let e = refine(&map.view(), &scene, &RefineParams { iterations: 1, ..p }, None, &mut |_| Ok(true));
    assert!(e.unwrap_err().to_string().contains("does not combine"));
    let e = refine(&map.view(), &scene, &RefineParams { prior_hold: -1.0, ..p }, None, &mut |_| Ok(true));
    assert!(e.unwrap_err().to_string().contains("non-negative"));
}

#[test]
fn a_held_photon_s_prior_weighs_more_by_its_freedom() {
    // w / f^a with f = |v_b| floored at 10⁻³; no basis, or a = 0: w for every photon.
    let v = [[0.0, 1.0, 0.0], [0.3, 0.4, 0.0], [0.0, 0.0, 0.0], [0.0, 1e-5, 0.0]];
    let w = prior_weights(4, 4.0, 2.0, Some(&v), None);
    let want = [4.0, 4.0 / 0.25, 4.0e6, 4.0e6];
    for (g, e) in w.iter().zip(want) {
        assert!((g / e - 1.0).abs() < 1e-5, "{w:?}");
    }
    assert_eq!(prior_weights(4, 4.0, 0.0, Some(&v), None), vec![4.0; 4]);
    assert_eq!(prior_weights(3, 4.0, 2.0, None, None), vec![4.0; 3]);
    // The statistics start from those weights: a photon's estimate is
    // (w_i·φ_i + τ_i)/(w_i + P_i), so after a pass the held one keeps its own flux and the
    // free one moves most of the way to its cell's.
    let primal = grid_primal(8);
    let tree = BoxTree::build(&primal.positions);
    let phi = [[1.0f32; 3]; 64];
    let mut weights = vec![0.0f32; 64];
    weights[0] = 4.0e6;
    let mut stats = Statistics::start_weighted(&phi, &weights);
    gather(&mut stats, &primal, &tree, &uniform_fresh(6400, 7, 3.0 * 64.0 / 1000.0));
    assert!((stats.cell_flux(0).x - 1.0).abs() < 1e-4, "held: {}", stats.cell_flux(0));
    let free = stats.cell_flux(9).x;
    assert!((free / 0.001 - 1.0).abs() < 0.5, "free: its cell's flux, about 1 mW: {free}");
}

/// A grown map's kernel narrows at features only: its factor is 1 at a free photon and
/// P^(−1/6) at a held one after P passes (PPM's radius), in closed form; refined from a detected
/// map, every first photon gets the factor its freedom |basis_v| gives, and a map without a
/// constraint basis keeps its kernel.
#[test]
fn a_grown_map_s_kernel_narrows_at_held_photons_only() {
    assert_eq!(radius_factor(64, 1.0), 1.0);
    // Held on its line: the radius as P^(−1/3), the area as P^(−2/3).
    assert!((radius_factor(64, 0.0) - 0.25).abs() < 1e-6);
    // Half-way and above: the radius as P^(−(1 − f)/6).
    assert!((radius_factor(64, 0.5) - 64f32.powf(-1.0 / 12.0)).abs() < 1e-6);
    assert!((radius_factor(64, 0.8) - 64f32.powf(-0.2 / 6.0)).abs() < 1e-6);
    // Between: (1 − f) + (1 − 2f) = 1.25 at f = 1/4.
    assert!((radius_factor(64, 0.25) - 64f32.powf(-1.25 / 6.0)).abs() < 1e-6);
    assert_eq!(radius_factor(1, 0.0), 1.0);
    assert_eq!(radius_factor(64, 7.0), 1.0, "freedom is at most 1");

    let dir = tempfile::tempdir().unwrap();
    let (traced, scene) = traced_map(dir.path());
    let p = RefineParams { passes: 3, photons_per_pass: Some(100_000), ..RefineParams::default() };
    let grown = refine(&traced.view(), &scene, &p, None, &mut |_| Ok(true)).unwrap();
    let n0 = traced.len();
    assert!(grown.len() > n0);
    assert_eq!(radius_factors(&grown.view()), vec![1.0; n0], "no basis: every factor 1");
    assert!(radius_factors(&traced.view()).is_empty(), "a map that did not grow");

    let dp = crate::detect::DetectParams::default();
    let d = crate::detect::detect_map(&traced.view(), &dp, &|_| {}).unwrap();
    let path = dir.path().join("detected.phm");
    crate::detect::detected_map(&traced.view(), d, &dp, 0.0)
        .unwrap()
        .write(Output::Path(path.clone()))
        .unwrap();
    let detected = PhotonMap::open_path(&path).unwrap();
    let grown = refine(&detected.view(), &scene, &p, None, &mut |_| Ok(true)).unwrap();
    let view = grown.view();
    let factors = radius_factors(&view);
    let v = view.column::<[f32; 3]>(name::BASIS_V).unwrap().unwrap();
    assert_eq!(factors.len(), n0);
    for (i, &c) in factors.iter().enumerate() {
        let f = glam::Vec3::from(v[i]).length().min(1.0);
        let n = (1.0 - f) + (1.0 - 2.0 * f).max(0.0);
        assert!((c - 3f32.powf(-n / 6.0)).abs() < 1e-6, "photon {i}: {c} at freedom {f}");
    }
    let held = factors.iter().filter(|&&c| c < 0.95).count();
    assert!(held > 0 && held < n0 / 2, "{held} of {n0} photons narrowed");
}

/// The border score against its closed forms on photons uniform on the emitter's square: the
/// mean offset of 32 neighbours spread over a disc, E|m| = sqrt(π/2)·r/sqrt(4·32) ≈ 0.11·r
/// (a Rayleigh length with σ² = r²/(4·32) per axis), inside; a half disc's centroid,
/// 4r/(3π) ≈ 0.42·r, on a straight border.
#[test]
fn the_border_score_is_a_half_disc_s_centroid_on_the_border_and_small_inside() {
    let dir = tempfile::tempdir().unwrap();
    let m = crate::synthetic::uniform_square(40_000, 3, 1.0);
    let scores = border_scores(&m.written_to(&dir.path().join("synthetic.phm")).view()).unwrap().unwrap();
    let uv = |i: usize| (m.params[2 * i], m.params[2 * i + 1]);
    let mean = |keep: &dyn Fn(f32, f32) -> bool| {
        let s: Vec<f32> = (0..m.len()).filter(|&i| keep(uv(i).0, uv(i).1)).map(|i| scores[i]).collect();
        (s.iter().sum::<f32>() / s.len() as f32, s.len())
    };
    let inside = |x: f32| (0.2..0.8).contains(&x);
    let (s_in, n_in) = mean(&|u, v| inside(u) && inside(v));
    let want_in = (std::f32::consts::PI / 2.0).sqrt() / (4.0f32 * 32.0).sqrt();
    assert!(
        n_in > 10_000 && (s_in / want_in - 1.0).abs() < 0.1,
        "inside: {s_in} over {n_in}, want {want_in}"
    );
    let (s_border, n_border) = mean(&|u, v| u < 0.001 && inside(v));
    let want_border = 4.0 / (3.0 * std::f32::consts::PI);
    assert!(
        n_border > 10 && (s_border / want_border - 1.0).abs() < 0.1,
        "border: {s_border} over {n_border}, want {want_border}"
    );
    assert!(border_weight(s_in) < 0.05 && border_weight(s_border) == 1.0);
}

/// The border score against a brute-force scan of every photon's 32 nearest in parameter
/// space; and at a fold (where the cusp map's dx/du = 0, photons of both sides in parameter
/// space meet in world space) it is the interior's, not a border's.
#[test]
fn the_border_score_matches_brute_force_and_tells_a_fold_from_a_border() {
    let dir = tempfile::tempdir().unwrap();
    let m = crate::synthetic::collimated_cusp(3000, 5);
    let scores = border_scores(&m.written_to(&dir.path().join("synthetic.phm")).view()).unwrap().unwrap();
    let p = |i: usize| [m.params[2 * i], m.params[2 * i + 1]];
    for i in (0..m.len()).step_by(7) {
        let mut d: Vec<(f32, usize)> = (0..m.len())
            .filter(|&j| j != i)
            .map(|j| ((p(j)[0] - p(i)[0]).powi(2) + (p(j)[1] - p(i)[1]).powi(2), j))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let near = &d[..BORDER_NEIGHBOURS];
        let c = near.iter().fold([0f64; 2], |c, &(_, j)| {
            [c[0] + (p(j)[0] - p(i)[0]) as f64, c[1] + (p(j)[1] - p(i)[1]) as f64]
        });
        let k = BORDER_NEIGHBOURS as f64;
        let want = ((c[0] / k).powi(2) + (c[1] / k).powi(2)).sqrt() / (near[near.len() - 1].0 as f64).sqrt();
        assert!(
            (scores[i] as f64 - want).abs() < 1e-4 * want.max(1e-3),
            "photon {i}: {} against {want}",
            scores[i]
        );
    }
    // The fold: dx/du = 0.6 − 0.5π·cos(2π(u − ½)) = 0 at u − ½ = ±acos(0.6/(0.5π))/(2π).
    let s_fold = (0.6 / (0.5 * std::f64::consts::PI)).acos() / (2.0 * std::f64::consts::PI);
    let at_fold: Vec<f32> = (0..m.len())
        .filter(|&i| {
            let (u, v) = (p(i)[0] as f64, p(i)[1] as f64);
            ((u - 0.5).abs() - s_fold).abs() < 0.01 && (0.2..0.8).contains(&v)
        })
        .map(|i| scores[i])
        .collect();
    let at_border: Vec<f32> = (0..m.len())
        .filter(|&i| p(i)[0] < 0.005 && (0.2..0.8).contains(&p(i)[1]))
        .map(|i| scores[i])
        .collect();
    let mean = |s: &[f32]| s.iter().sum::<f32>() / s.len() as f32;
    assert!(at_fold.len() > 50 && at_border.len() > 5, "{} {}", at_fold.len(), at_border.len());
    assert!(mean(&at_fold) < BORDER_SCORES[0] + 0.02, "fold: {}", mean(&at_fold));
    assert!(mean(&at_border) > BORDER_SCORES[1], "border: {}", mean(&at_border));
}

#[test]
fn a_held_photon_on_its_domain_s_border_weighs_as_a_free_one() {
    // Held (f = 0.1, a = 1): w / f inside the domain, w on its border, between in between.
    let v = [[0.0, 0.1, 0.0]; 3];
    let border = [0.0, 0.5, 0.17];
    let w = prior_weights(3, 4.0, 1.0, Some(&v), Some(&border));
    let between = 4.0 / 0.1f32.powf(1.0 - border_weight(0.17));
    assert!((w[0] / 40.0 - 1.0).abs() < 1e-5 && (w[1] / 4.0 - 1.0).abs() < 1e-5, "{w:?}");
    assert!((w[2] / between - 1.0).abs() < 1e-5 && w[2] > 4.0 && w[2] < 40.0, "{w:?}");
    assert!((border_weight(0.17) - 0.5).abs() < 1e-5);
}
