use glam::Vec3;

use super::*;
use crate::format::{Output, PhotonMap};
use crate::sampling::halton::PhotonRng;

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
fn gather_follows_the_sppm_rule_against_brute_force() {
    let primal = grid_primal(20);
    let mut stats = Statistics::start(&primal.positions, 16);
    let before = stats.clone();
    let fresh = uniform_fresh(5000, 1, 1.0);
    gather(&mut stats, &primal, &fresh, 2.0 / 3.0);
    for i in 0..primal.len() {
        let x = Vec3::from(primal.positions[i]);
        let r = before.radius[i];
        let inside: Vec<usize> =
            (0..fresh.len()).filter(|&j| x.distance_squared(fresh.position[j].into()) <= r * r).collect();
        let m = inside.len() as f64;
        let phi: f32 = inside.iter().map(|&j| fresh.flux[j][0]).sum();
        let shrink2 = (2.0 / 3.0 * m) / m; // N = 0 before the first pass
        assert!((stats.count[i] as f64 - 2.0 / 3.0 * m).abs() < 1e-3, "photon {i}");
        assert!((stats.radius[i] as f64 - r as f64 * shrink2.sqrt()).abs() < 1e-6);
        assert!((stats.tau[i][0] as f64 - phi as f64 * shrink2).abs() < 1e-6 * (1.0 + phi as f64));
        assert_eq!(stats.passes[i], 1.0);
    }
}

#[test]
fn the_irradiance_estimate_converges_to_the_closed_form() {
    // 1 W per pass uniformly over the unit square: E = 1/3 W/m² per channel. The error of the
    // estimate at the photons away from the border falls as passes accumulate.
    let primal = grid_primal(24);
    let mut stats = Statistics::start(&primal.positions, 16);
    let interior: Vec<usize> = (0..primal.len())
        .filter(|&i| primal.positions[i][..2].iter().all(|&c| (0.2..=0.8).contains(&c)))
        .collect();
    let rms = |s: &Statistics| {
        let e2: f64 = interior.iter().map(|&i| (s.irradiance(i).x as f64 * 3.0 - 1.0).powi(2)).sum::<f64>()
            / interior.len() as f64;
        e2.sqrt()
    };
    let mut errors = Vec::new();
    for pass in 0..64 {
        gather(&mut stats, &primal, &uniform_fresh(2000, 100 + pass, 1.0), 2.0 / 3.0);
        if [0, 7, 63].contains(&pass) {
            errors.push(rms(&stats));
        }
    }
    assert!(errors[0] > 0.1, "one pass of ~50 photons per disc is noisy: {errors:?}");
    assert!(errors[1] < 0.7 * errors[0] && errors[2] < 0.5 * errors[1], "{errors:?}");
    assert!(errors[2] < 0.06, "{errors:?}");
}

#[test]
fn relaxation_draws_photons_toward_the_brighter_side_and_evens_their_flux() {
    // The estimates say the right half is three times as bright: photons move right, and
    // the spread of their flux falls.
    let mut primal = grid_primal(24);
    let mut stats = Statistics::start(&primal.positions, 16);
    for i in 0..primal.len() {
        let e = if primal.positions[i][0] > 0.5 { 3.0 } else { 1.0 };
        let area = std::f32::consts::PI * stats.radius[i] * stats.radius[i];
        stats.tau[i] = [e * area; 3];
        stats.passes[i] = 1.0;
    }
    let total = primal.total_flux();
    // The spacing (distance to the 16th neighbour) in the bright interior over the dim one's.
    let spacing_ratio = |p: &Primal| {
        let s = Statistics::start(&p.positions, 16);
        let band = |lo: f32, hi: f32| {
            let r: Vec<f64> = (0..p.len())
                .filter(|&i| {
                    (lo..hi).contains(&p.positions[i][0]) && (0.25..0.75).contains(&p.positions[i][1])
                })
                .map(|i| s.radius[i] as f64)
                .collect();
            r.iter().sum::<f64>() / r.len() as f64
        };
        band(0.6, 0.8) / band(0.2, 0.4)
    };
    let cv0 = set_flux(&mut primal.clone(), &stats, 16, total);
    let ratio0 = spacing_ratio(&primal);
    let p = RefineParams::default();
    for _ in 0..10 {
        // Keep the estimates as they were (a field, not statistics that move away).
        let mut s = stats.clone();
        relax_toward_flux(&mut primal, &mut s, &p);
    }
    let cv = set_flux(&mut primal, &stats, 16, total);
    let ratio = spacing_ratio(&primal);
    assert!((ratio0 - 1.0).abs() < 0.01 && ratio < 0.95, "bright/dim spacing {ratio} from {ratio0}");
    assert!(cv < cv0, "flux spread {cv} from {cv0}");
    let after = primal.total_flux();
    for c in 0..3 {
        assert!((after[c] / total[c] - 1.0).abs() < 1e-5, "energy: {after:?} against {total:?}");
    }
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
        crate::scene::DEFAULT_SCENE,
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
    let p = RefineParams { passes: 3, photons_per_pass: Some(30_000), ..RefineParams::default() };
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
    assert!(rec.measures.iter().all(|m| m.gathered_per_photon > 1.0), "{:?}", rec.measures);

    // One pass, written; then the rest from the file.
    let first =
        refine(&map.view(), &scene, &RefineParams { passes: 1, ..p }, None, &mut |_, _| Ok(true)).unwrap();
    let path = dir.path().join("one.phm");
    first.write(Output::Path(path.clone())).unwrap();
    let one = PhotonMap::open_path(&path).unwrap();
    let resumed = refine(&one.view(), &scene, &p, None, &mut |_, _| Ok(true)).unwrap();
    for column in [name::POSITION, name::FLUX, column::RADIUS, column::TAU] {
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
