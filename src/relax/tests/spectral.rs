//! The spectral window ([`RelaxSpace::WorldSpectral`]): a photon's neighbours are the Kf
//! nearest in world space among the photons within the window of its wavelength, checked
//! against brute force, and what that does to two colours that are each already even.

use super::*;
use crate::synthetic::SyntheticMap;

/// `m` with each photon's wavelength (its third parameter) set by `lambda(i)`.
fn with_wavelengths(mut m: SyntheticMap, lambda: impl Fn(usize) -> f32) -> SyntheticMap {
    m.params.chunks_exact_mut(3).enumerate().for_each(|(i, q)| q[2] = lambda(i));
    m
}

/// For each photon: its nearest distance and its distance to the `kf`-th nearest among the
/// other photons whose wavelength is within `window` of its own (all of them for 0, or for a
/// photon `held`), by brute force in f64.
fn brute_force(
    pos: &[[f32; 3]],
    lambda: &[f32],
    held: &[bool],
    kf: usize,
    window: f32,
) -> (Vec<f32>, Vec<f32>) {
    let d = |i: usize, j: usize| {
        (0..3).map(|a| (pos[i][a] as f64 - pos[j][a] as f64).powi(2)).sum::<f64>().sqrt()
    };
    (0..pos.len())
        .map(|i| {
            let mut ds: Vec<f64> = (0..pos.len())
                .filter(|&j| j != i && (window == 0.0 || held[i] || (lambda[j] - lambda[i]).abs() <= window))
                .map(|j| d(i, j))
                .collect();
            ds.sort_by(f64::total_cmp);
            (ds[0] as f32, ds[kf.min(ds.len()) - 1] as f32)
        })
        .unzip()
}

/// On a dispersed beam whose wavelengths lie on a 10 nm grid (so no pair sits on the window's
/// edge), the nearest-neighbour spreads relax reports for its first iteration (computed from
/// the neighbours it found, before any move) equal brute force's over the photons within the
/// window, and differ from those over every photon: the window restricts, and only it. Once
/// detected and collapsed, the photons held at the band's ends take every wavelength.
#[test]
fn the_spectral_window_keeps_the_neighbours_brute_force_keeps() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = with_wavelengths(crate::synthetic::dispersed_beam(3000, 61), |i| {
        380.0 + 10.0 * ((i * 7) % 35) as f32
    });
    // Landing where `dispersed_beam` lands that wavelength.
    for (x, q) in m.position.iter_mut().zip(m.params.chunks_exact(3)) {
        *x = [0.1 * q[0] + 0.4 * (q[2] - 380.0) / 340.0, 0.02 * q[1], 0.0];
    }
    let lambda: Vec<f32> = m.params.chunks_exact(3).map(|q| q[2]).collect();
    let traced = m.written_to(&dir.path().join("beam.phm"));
    let detected = detect_to(&traced, dir.path(), "beam-d.phm");
    let path = dir.path().join("beam-c.phm");
    collapse(&detected.view()).unwrap().write(crate::format::Output::Path(path.clone())).unwrap();
    let collapsed = crate::format::PhotonMap::open_path(&path).unwrap();
    let held: Vec<bool> = collapsed
        .column::<[f32; 3]>(crate::format::name::BASIS_V)
        .unwrap()
        .unwrap()
        .iter()
        .map(|v| Vec3::from(*v).length() < crate::detect::HELD_FACTOR)
        .collect();
    let count = held.iter().filter(|&&h| h).count();
    assert!(count > 30 && count + 30 < held.len(), "{count} held");
    let kf = RelaxParams::default().kf;
    let mut spreads = Vec::new();
    for (map, held) in [(&traced, vec![false; held.len()]), (&collapsed, held)] {
        for (window, space) in [(25.0, RelaxSpace::WorldSpectral), (0.0, RelaxSpace::World)] {
            let p = RelaxParams { iterations: 1, spectral_window: window, ..Default::default() };
            let r = relax_map(&map.view(), &p, |_| {}).unwrap();
            assert_eq!(r.space, space, "window {window}");
            let (nn, rk) = brute_force(map.positions(), &lambda, &held, kf, window);
            let ratio: Vec<f32> = nn.iter().zip(&rk).map(|(a, b)| a / b).collect();
            let (want_nn, want_local) = (coefficient_of_variation(&nn), coefficient_of_variation(&ratio));
            let got = &r.measures[0];
            let what = format!("{}, window {window}", map.file_name());
            assert!(
                (got.nn_cv - want_nn).abs() <= 1e-5 * want_nn,
                "{what}: nn cv {} vs {want_nn}",
                got.nn_cv
            );
            assert!(
                (got.local_nn_cv - want_local).abs() <= 1e-5 * want_local,
                "{what}: local cv {} vs {want_local}",
                got.local_nn_cv
            );
            spreads.push((want_nn, want_local));
        }
    }
    // Each map's two neighbour sets' spreads differ by far more than the checks' tolerance, so
    // the checks above tell them apart.
    for pair in spreads.chunks(2) {
        let [(a, b), (c, d)] = pair[..] else { unreachable!() };
        assert!((a - c).abs() > 1e-3 * c && (b - d).abs() > 1e-3 * d, "{spreads:?}");
    }
}

/// Two colours, 450 and 650 nm, each on its own square lattice, the second shifted by a
/// fraction of the spacing: each colour is already even, their union is not. With a window
/// of 30 nm a photon's 12 neighbours (the lattice's three nearest rings, symmetric about it)
/// are all of its own colour and the interior does not move; relaxing every wavelength
/// together moves it (by over 1 % of the spacing, a hundred times the bound within the window).
#[test]
fn two_colours_each_even_stay_put_in_the_window_and_move_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let (side, s) = (24usize, 0.01f32);
    let mut m = with_wavelengths(crate::synthetic::dispersed_beam(2 * side * side, 62), |i| {
        if i < side * side { 450.0 } else { 650.0 }
    });
    for (i, x) in m.position.iter_mut().enumerate() {
        let (k, shift) = if i < side * side { (i, [0.0, 0.0]) } else { (i - side * side, [0.37, 0.21]) };
        *x = [((k % side) as f32 + shift[0]) * s, ((k / side) as f32 + shift[1]) * s, 0.0];
    }
    let map = m.written_to(&dir.path().join("lattices.phm"));
    let interior = |x: &[f32; 3]| x[..2].iter().all(|&c| (4.0 * s..(side as f32 - 5.0) * s).contains(&c));
    let moved = |window: f32| {
        let p = RelaxParams { iterations: 1, kf: 12, spectral_window: window, ..Default::default() };
        let r = relax_map(&map.view(), &p, |_| {}).unwrap();
        assert!(r.positions.iter().all(|x| x[2] == 0.0));
        map.positions()
            .iter()
            .zip(&r.positions)
            .filter(|(x, _)| interior(x))
            .map(|(a, b)| Vec3::from(*a).distance(Vec3::from(*b)))
            .fold(0.0f32, f32::max)
    };
    let (within, all) = (moved(30.0), moved(0.0));
    assert!(within <= 1e-4 * s, "moved {within} within the window");
    assert!(all >= 1e-2 * s, "moved only {all} with every wavelength");
}

/// A map without a wavelength relaxes in plain world space whatever the window, and its record
/// does not name the window (so its file is what it was before the window); a map with one
/// records it. A negative or non-finite window is refused.
#[test]
fn the_window_applies_only_to_wavelengths_and_must_be_a_length() {
    let dir = tempfile::tempdir().unwrap();
    let p = RelaxParams { iterations: 1, ..Default::default() };
    let plain = crate::synthetic::collimated_cusp(500, 63).written_to(&dir.path().join("cusp.phm"));
    let beam = crate::synthetic::dispersed_beam(500, 64).written_to(&dir.path().join("beam.phm"));
    for (map, space, window) in
        [(&plain, RelaxSpace::World, None), (&beam, RelaxSpace::WorldSpectral, Some(35.0))]
    {
        let r = relax_map(&map.view(), &p, |_| {}).unwrap();
        assert_eq!(r.space, space);
        let table = relaxed_map(&map.view(), r, &p, 0.0).unwrap();
        let recorded = &table.view().info().history.last().unwrap().parameters;
        assert_eq!(recorded.get("spectral_window").and_then(|w| w.as_f64()), window, "{space:?}");
        assert_eq!(recorded["kf"], 16);
    }
    for bad in [-1.0, f32::NAN, f32::INFINITY] {
        let p = RelaxParams { spectral_window: bad, ..Default::default() };
        let e = relax_map(&beam.view(), &p, |_| {}).err().expect("refused").to_string();
        assert!(e.contains("spectral window"), "{e}");
    }
}
