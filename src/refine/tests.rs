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
    let mut stats = Statistics::start(primal.len());
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
    let mut stats = Statistics::start(primal.len());
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
        let mut stats = Statistics::start(primal.len());
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
            cv = set_flux(&mut primal, &stats, total);
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
    let p =
        RefineParams { passes: 3, photons_per_pass: Some(30_000), iterations: 1, ..RefineParams::default() };
    let mut seen = Vec::new();
    let whole = refine(&map.view(), &scene, &p, None, &mut |m, t| {
        let got = Primal::from_map(&t.view()).unwrap().total_flux();
        for c in 0..3 {
            assert!((got[c] / total[c] - 1.0).abs() < 1e-5, "pass {}: {got:?} against {total:?}", m.pass);
        }
        seen.push(m.pass);
        Ok(true)
    })
    .unwrap();
    assert_eq!(seen, [1, 2, 3]);
    let rec = RefineRecord::of(&whole.view()).unwrap();
    assert_eq!((rec.passes_done, rec.next_emission), (3, 60_000 + 3 * 30_000));
    assert!(rec.measures.iter().all(|m| m.gathered_per_photon > 0.3), "{:?}", rec.measures);

    // One pass, written; then the rest from the file.
    let first =
        refine(&map.view(), &scene, &RefineParams { passes: 1, ..p }, None, &mut |_, _| Ok(true)).unwrap();
    let path = dir.path().join("one.phm");
    first.write(Output::Path(path.clone())).unwrap();
    let one = PhotonMap::open_path(&path).unwrap();
    let resumed = refine(&one.view(), &scene, &p, None, &mut |_, _| Ok(true)).unwrap();
    for column in [name::POSITION, name::FLUX, column::TAU, column::PASSES] {
        assert_eq!(
            resumed.view().column_bytes(column),
            whole.view().column_bytes(column),
            "{column} differs after resuming"
        );
    }
    // Other settings do not resume.
    let other = RefineParams { photons_per_pass: Some(10_000), ..p };
    let e = refine(&one.view(), &scene, &other, None, &mut |_, _| Ok(true)).unwrap_err();
    assert!(e.to_string().contains("other settings"), "{e}");
}
