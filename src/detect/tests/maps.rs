//! Detection over whole synthetic maps against what the paper shows and what a uniform
//! region should give: the paper's Fig. 3, a straight edge and Kc at its limits (issue 4), and
//! a stretched map from parameters to the surface, which is not an edge (issue 29).

use std::f64::consts::PI;

use rand::RngExt;

use super::*;

/// One collimated emitter's photons on the floor z = 0 from (params, position) pairs: flux
/// equal, normals +z, no emitter column.
fn collimated_map(photons: &[([f32; 2], [f32; 2])]) -> crate::synthetic::SyntheticMap {
    let mut m = crate::synthetic::SyntheticMap {
        param_dims: 2,
        emitters: vec![crate::synthetic::collimated_emitter(0, 1.0)],
        ..Default::default()
    };
    let f = 1.0 / 3.0 / photons.len().max(1) as f32;
    for (p, x) in photons {
        m.position.push([x[0], x[1], 0.0]);
        m.normal.push([0.0, 0.0, 1.0]);
        m.flux.push([f; 3]);
        m.emitter.push(0);
        m.params.extend_from_slice(p);
    }
    m
}

/// |v_b| of photon i: the factor of Eq. 7.
fn factor_of(d: &Detection, i: usize) -> f64 {
    DVec3::from(d.basis_v[i].map(|x| x as f64)).length()
}

/// Mean factor and mean |u_b · ŷ| (u_b along a vertical edge) over `sel`.
fn band_means(d: &Detection, sel: &[usize]) -> (f64, f64) {
    assert!(!sel.is_empty());
    let n = sel.len() as f64;
    let f = sel.iter().map(|&i| factor_of(d, i)).sum::<f64>() / n;
    let uy = sel.iter().map(|&i| (d.basis_u[i][1] as f64).abs()).sum::<f64>() / n;
    (f, uy)
}

/// The paper's Fig. 3: one collimated emitter, params (u, v) uniform in the unit square; set A
/// (u < ½) lands on x = 1.2·u ∈ [0, 0.6), set B (u ≥ ½) on x = 0.4 + 1.2·(u − ½) ∈ [0.4, 1],
/// y = v; both smooth and one-to-one, overlapping in the strip 0.4 ≤ x < 0.6.
fn fig3_map(n: usize, seed: u64) -> crate::synthetic::SyntheticMap {
    let mut r = rng(seed);
    let photons: Vec<([f32; 2], [f32; 2])> = (0..n)
        .map(|_| {
            let (u, v) = (r.random::<f64>(), r.random::<f64>());
            let x = if u < 0.5 { 1.2 * u } else { 0.4 + 1.2 * (u - 0.5) };
            ([u as f32, v as f32], [x as f32, v as f32])
        })
        .collect();
    collimated_map(&photons)
}

/// The mean Eq. 7 factor of isotropic neighbourhoods of k photons as detection sees them (the
/// photon at the centre, its k-th neighbour on the circle r = 1, k − 2 uniform in the disc;
/// see `noise.rs`): what a uniform region should give, by a simulation independent of detect().
fn isotropic_mean_factor(k: usize, sets: usize, seed: u64) -> f64 {
    let mut r = rng(seed);
    let (mu, sigma) = NoiseModel::Simulated.mu_sigma(k);
    let mut pts = Vec::with_capacity(k);
    let mut sum = 0.0;
    for _ in 0..sets {
        pts.clear();
        pts.push([0.0, 0.0]);
        let a: f64 = r.random_range(0.0..2.0 * PI);
        pts.push([a.cos(), a.sin()]);
        pts.extend((2..k).map(|_| in_disc(&mut r)));
        sum += v_factor(lambda2_of(&pts), mu, sigma);
    }
    sum / sets as f64
}

/// Issue 4, check 1: the paper's Fig. 3. With `param-pca` each set's boundary inside the
/// overlap is held across it; with `world-pca` the overlap hides it (the density there only
/// steps from 2 to 1, not to 0).
///
/// Measured (10 000 photons, Kc = 50; bands: A photons with x > 0.59 and B photons with
/// x < 0.41, i.e. within 0.23·r of the boundary, r ≈ 0.044 A's kernel radius; y ∈ [0.1, 0.9]):
/// seed 40: param-pca A 0.050, B 0.069 (mean |u_b·ŷ| 0.990, 0.993); world-pca A 0.604,
/// B 0.610; middle of A 0.711 under both (isotropic expectation 0.726). Seeds 41–44:
/// param-pca 0.028–0.076, world-pca 0.52–0.68, middle 0.72–0.76. Thresholds sit between:
/// < 0.15 and > 0.4. A param-pca that ignored the parameter restriction would give ≈ 0.6 at
/// the boundaries and fail; a world-pca that applied it would give ≈ 0.05 and fail.
#[test]
fn fig3_param_pca_constrains_each_sets_boundary_in_the_overlap_and_world_pca_does_not() {
    let m = fig3_map(10_000, 40);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let is_a = |i: usize| m.params[2 * i] < 0.5;
    let x = |i: usize| m.position[i][0] as f64;
    let y_ok = |i: usize| (0.1..0.9).contains(&(m.position[i][1] as f64));
    let a_edge: Vec<usize> = (0..m.len()).filter(|&i| is_a(i) && y_ok(i) && x(i) > 0.59).collect();
    let b_edge: Vec<usize> = (0..m.len()).filter(|&i| !is_a(i) && y_ok(i) && x(i) < 0.41).collect();
    let a_mid: Vec<usize> =
        (0..m.len()).filter(|&i| is_a(i) && y_ok(i) && (0.1..0.3).contains(&x(i))).collect();
    assert!(a_edge.len() > 40 && b_edge.len() > 40 && a_mid.len() > 1000);

    let pp = detect(&inp, &DetectParams::default(), &|_| {}).unwrap();
    let wp = detect(&inp, &DetectParams { method: Method::WorldPca, ..Default::default() }, &|_| {}).unwrap();
    assert!(all_finite(&pp) && all_finite(&wp));
    for (name, band) in [("A at x = 0.6", &a_edge), ("B at x = 0.4", &b_edge)] {
        let (f, uy) = band_means(&pp, band);
        assert!(f < 0.15, "param-pca, boundary of {name}: mean factor {f}");
        // u_b along the boundary (ŷ), so P2 (v_b's direction, ẑ × u_b) across it.
        assert!(uy > 0.95, "param-pca, boundary of {name}: mean |u_b·ŷ| {uy}");
        let (f, _) = band_means(&wp, band);
        assert!(f > 0.4, "world-pca, boundary of {name}: mean factor {f}");
    }
    // Far from every boundary (A's own at x = 0 and 0.6, B's at 0.4; kernel radius ≈ 0.044)
    // both methods gather the same neighbours, so give the same factors: those of noise.
    for &i in &a_mid {
        assert!((factor_of(&pp, i) - factor_of(&wp, i)).abs() < 1e-6, "photon {i}");
    }
    let (f, _) = band_means(&pp, &a_mid);
    let iso = isotropic_mean_factor(50, 4000, 1);
    assert!(f > 0.6 && (f - iso).abs() < 0.05, "middle of A: mean factor {f}, isotropic {iso}");
}

/// Issue 4, check 2: a lit half-plane (uniform photons on x < 0.5 of the unit square,
/// parameters = position), the whole map through detect().
///
/// Measured (4 911 photons, Kc = 50, kernel radius r ≈ 0.040 inside; edge band x > 0.49,
/// i.e. within 0.25·r of the edge, y ∈ [0.15, 0.85]): seed 41: 64 photons, mean factor 0.043,
/// max 0.128, mean |u_b·ŷ| 0.994, min 0.940; interior (x ∈ [0.15, 0.35]) mean 0.739 against
/// the isotropic expectation 0.726. Seeds 40–44: edge mean 0.029–0.050, max 0.106–0.169,
/// min |u_b·ŷ| 0.940–0.977, interior 0.704–0.744. world-pca gives the same (the parameter
/// map is the identity). Thresholds: edge mean < 0.1, max < 0.3, |u_b·ŷ| mean > 0.97 and
/// min > 0.9; interior within 0.05 of the isotropic expectation.
#[test]
fn straight_edge_is_held_across_and_the_uniform_interior_is_free() {
    let mut r = rng(41);
    let photons: Vec<([f32; 2], [f32; 2])> = (0..10_000)
        .map(|_| [r.random::<f32>(), r.random::<f32>()])
        .filter(|p| p[0] < 0.5)
        .map(|p| (p, p))
        .collect();
    let m = collimated_map(&photons);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let x = |i: usize| m.position[i][0] as f64;
    let y_ok = |i: usize| (0.15..0.85).contains(&(m.position[i][1] as f64));
    let edge: Vec<usize> = (0..m.len()).filter(|&i| y_ok(i) && x(i) > 0.49).collect();
    let inside: Vec<usize> = (0..m.len()).filter(|&i| y_ok(i) && (0.15..0.35).contains(&x(i))).collect();
    assert!(edge.len() > 40 && inside.len() > 1000);
    let iso = isotropic_mean_factor(50, 4000, 1);
    for method in [Method::ParamPca, Method::WorldPca] {
        let d = detect(&inp, &DetectParams { method, ..Default::default() }, &|_| {}).unwrap();
        assert!(all_finite(&d));
        let (f, uy) = band_means(&d, &edge);
        let max = edge.iter().map(|&i| factor_of(&d, i)).fold(0.0, f64::max);
        let uy_min = edge.iter().map(|&i| (d.basis_u[i][1] as f64).abs()).fold(1.0, f64::min);
        assert!(f < 0.1 && max < 0.3, "{method:?}: edge factor mean {f}, max {max}");
        // P2 = ẑ × u_b, so |P2·x̂| = |u_b·ŷ|: across the edge.
        assert!(uy > 0.97 && uy_min > 0.9, "{method:?}: |P2·x̂| mean {uy}, min {uy_min}");
        let (f, _) = band_means(&d, &inside);
        assert!((f - iso).abs() < 0.05, "{method:?}: interior mean factor {f}, isotropic {iso}");
    }
}

/// Every photon's basis: unit u_b, |v_b| ≤ 1, u_b ⟂ v_b, both in the floor's plane, and λ2 in
/// [0, ½] (the covariance of offsets no longer than r has trace ≤ r², so λ2 ≤ r²/2).
fn assert_valid_basis(d: &Detection) {
    assert!(all_finite(d));
    for i in 0..d.basis_u.len() {
        let u = DVec3::from(d.basis_u[i].map(|x| x as f64));
        let v = DVec3::from(d.basis_v[i].map(|x| x as f64));
        assert!((u.length() - 1.0).abs() < 1e-5 && v.length() <= 1.0 + 1e-5, "photon {i}: {u} {v}");
        assert!(u.dot(v).abs() < 1e-5 && u.z.abs() < 1e-6 && v.z.abs() < 1e-6, "photon {i}: {u} {v}");
        assert!((0.0..=0.5).contains(&d.lambda2[i]), "photon {i}: λ2 {}", d.lambda2[i]);
    }
}

/// Issue 4, check 3: Kc at its limits on 3 000 uniform photons of the unit square.
///
/// Kc = 3: measured mean factor 0.848 (seed 42) against the isotropic expectation 0.846; no
/// photon below 0.826 = v_factor(0, μ(3), σ(3)), because μ(3) = 0.035 lies below the clamp's
/// lower end 0.070: a 3-photon kernel never holds a photon (as specified; see the report).
///
/// Kc = 1000 (kernel radius ≈ 0.33): interior [0.33, 0.67]² (the kernel disc fits inside the
/// square) measured mean 0.901 (seed 42; 0.918 seed 43), minimum 0.68, against the isotropic
/// expectation 0.874, and 0.72 at Kc = 50 (where 18 % of the same interior falls below ½).
/// Photons within 0.05 of the square's boundary are held (mean 0.014; 0.011 seed 43).
/// Thresholds: interior mean > 0.8 with under 2 % below ½; boundary mean < 0.1.
#[test]
fn kc_at_its_limits_gives_valid_constraints_and_kc_1000_keeps_a_uniform_interior_free() {
    let m = crate::synthetic::uniform_square(3000, 42, 1.0);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let n = m.len();

    let d = detect(&inp, &DetectParams { kc: 3, ..Default::default() }, &|_| {}).unwrap();
    assert_valid_basis(&d);
    assert_eq!(d.summary.measured, n, "{:?}", d.summary);
    let iso = isotropic_mean_factor(3, 4000, 1);
    let f = d.summary.mean_factor;
    assert!((f - iso).abs() < 0.02, "Kc 3: mean factor {f}, isotropic {iso}");

    let d = detect(&inp, &DetectParams { kc: 1000, ..Default::default() }, &|_| {}).unwrap();
    assert_valid_basis(&d);
    assert_eq!(d.summary.measured, n, "{:?}", d.summary);
    let pos = |i: usize| m.position[i];
    let inside: Vec<usize> =
        (0..n).filter(|&i| pos(i)[..2].iter().all(|&c| (0.33..0.67).contains(&c))).collect();
    let rim: Vec<usize> =
        (0..n).filter(|&i| pos(i)[..2].iter().any(|&c| !(0.05..0.95).contains(&c))).collect();
    assert!(inside.len() > 250 && rim.len() > 400);
    let (f, _) = band_means(&d, &inside);
    let held = inside.iter().filter(|&&i| factor_of(&d, i) < 0.5).count();
    assert!(f > 0.8 && held * 50 < inside.len(), "Kc 1000 interior: mean {f}, {held} below ½");
    let (f, _) = band_means(&d, &rim);
    assert!(f < 0.1, "Kc 1000, within 0.05 of the square's boundary: mean {f}");
}

// A stretched map from parameters to the surface is not an edge (issue 29).

/// Params (u, v) uniform in the unit square landing at (u, v·`squash`): the map stretches u
/// against v by 1/`squash`, smooth and one-to-one, as rays grazing a sphere's rim do.
fn squashed_map(n: usize, squash: f32, seed: u64) -> crate::synthetic::SyntheticMap {
    let mut r = rng(seed);
    let photons: Vec<([f32; 2], [f32; 2])> = (0..n)
        .map(|_| {
            let (u, v) = (r.random::<f32>(), r.random::<f32>());
            ([u, v], [u, v * squash])
        })
        .collect();
    collimated_map(&photons)
}

/// Issue 29: with the paper's fixed ball, a smooth map stretched 40 to 1 (beyond β² = 9)
/// holds interior photons on lines along the stretch, which relaxation turns into streaks;
/// grown where it binds (twice, to 4β), the ball holds the Kc nearest photons of a uniform
/// region again and they are free as any uniform region's.
///
/// Measured (40 000 photons, the strip [0, 1] × [0, 0.025], world kernel radius ≈ 0.003;
/// interior x ∈ [0.2, 0.8], y ∈ [0.0075, 0.0175]): seed 7: fixed ball mean factor 0.03; grown
/// ball 0.72, the isotropic expectation 0.726.
#[test]
fn a_stretched_map_is_free_once_its_ball_grows() {
    let squash = 1.0 / 40.0;
    let m = squashed_map(40_000, squash, 7);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let inside: Vec<usize> = (0..m.len())
        .filter(|&i| {
            let [x, y, _] = m.position[i];
            (0.2..0.8).contains(&x) && (0.3 * squash..0.7 * squash).contains(&y)
        })
        .collect();
    assert!(inside.len() > 8000);
    let fixed = detect(&inp, &DetectParams { growths: 0, ..Default::default() }, &|_| {}).unwrap();
    let grown = detect(&inp, &DetectParams { growths: 2, ..Default::default() }, &|_| {}).unwrap();
    assert!(all_finite(&fixed) && all_finite(&grown));
    let (f_fixed, _) = band_means(&fixed, &inside);
    let (f_grown, _) = band_means(&grown, &inside);
    let iso = isotropic_mean_factor(50, 4000, 1);
    assert!(f_fixed < 0.2, "fixed ball: mean factor {f_fixed}");
    assert!((f_grown - iso).abs() < 0.05, "grown ball: mean factor {f_grown}, isotropic {iso}");
    // The radius recorded is the one measured in: β·r_Kc doubled where the ball grew.
    let (rf, rg) = (fixed.r_param.as_ref().unwrap(), grown.r_param.as_ref().unwrap());
    for &i in &inside {
        let ratio = rg[i] / rf[i];
        assert!([1.0, 2.0, 4.0].iter().any(|&k| (ratio - k).abs() < 1e-6), "photon {i}: ratio {ratio}");
    }
    assert!(inside.iter().filter(|&&i| rg[i] > rf[i]).count() > inside.len() / 2);
}

/// What a grown ball must keep: a caustic filament (the unit square of parameters landing on a
/// line 10⁻⁴ wide, far thinner than the kernel) stays held on its line, and the paper's Fig. 3
/// boundaries and a straight edge stay held across, with the interior free.
#[test]
fn a_grown_ball_keeps_filaments_and_edges_held() {
    let grown = DetectParams { growths: 2, ..Default::default() };
    let m = squashed_map(20_000, 1e-4, 8);
    let (dims, stride) = owned_input(&m);
    let d = detect(&input(&m, &dims, stride), &grown, &|_| {}).unwrap();
    let inside: Vec<usize> = (0..m.len()).filter(|&i| (0.1..0.9).contains(&m.position[i][0])).collect();
    let (f, ux) = (band_means(&d, &inside).0, {
        inside.iter().map(|&i| (d.basis_u[i][0] as f64).abs()).sum::<f64>() / inside.len() as f64
    });
    assert!(f < 0.1 && ux > 0.99, "filament: mean factor {f}, mean |u_b·x̂| {ux}");

    let m = fig3_map(10_000, 40);
    let (dims, stride) = owned_input(&m);
    let d = detect(&input(&m, &dims, stride), &grown, &|_| {}).unwrap();
    let is_a = |i: usize| m.params[2 * i] < 0.5;
    let x = |i: usize| m.position[i][0] as f64;
    let y_ok = |i: usize| (0.1..0.9).contains(&(m.position[i][1] as f64));
    let a_edge: Vec<usize> = (0..m.len()).filter(|&i| is_a(i) && y_ok(i) && x(i) > 0.59).collect();
    let b_edge: Vec<usize> = (0..m.len()).filter(|&i| !is_a(i) && y_ok(i) && x(i) < 0.41).collect();
    for (name, band) in [("A at x = 0.6", &a_edge), ("B at x = 0.4", &b_edge)] {
        let (f, uy) = band_means(&d, band);
        assert!(f < 0.15 && uy > 0.95, "grown ball, boundary of {name}: mean factor {f}, |u_b·ŷ| {uy}");
    }
}

/// A dispersed beam (issue 23): (u, v) uniform on the emitter, the wavelength λ uniform on
/// 380–720 nm; a photon lands at x = 0.1·u + 0.4·t, y = 0.02·v, t = (λ − 380)/340 (the
/// spectrum spreads a beam 0.1 m × 0.02 m over 0.4 m along x, as the prism does). Without the
/// wavelength among the parameters, a photon's (u, v) ball holds every wavelength, which lands
/// along a line 0.4 m long: a filament, so the smooth interior is held. With it (a
/// `rect_uv_spectral` emitter, at S = 50, which makes the spectrum 20 times as long as v's
/// range in parameter space, ℓ being about 0.41, as on the floor; both with the paper's fixed
/// ball), the ball holds nearby wavelengths only and the interior is free like
/// any uniform region; and the scale detect records is S·ℓ/340 with ℓ the RMS distance of
/// (u, v) from its mean, recomputed here by brute force.
#[test]
fn a_wavelength_parameter_frees_the_interior_of_a_dispersed_beam() {
    let m = crate::synthetic::dispersed_beam(12_000, 23);
    let n = m.len();
    let interior: Vec<usize> = (0..n)
        .filter(|&i| (0.15..0.35).contains(&m.position[i][0]) && (0.005..0.015).contains(&m.position[i][1]))
        .collect();
    assert!(interior.len() > 2000);
    let iso = isotropic_mean_factor(50, 4000, 1);

    // (u, v) alone: the first two of the three components.
    // The paper's fixed ball on both sides (a grown ball frees this filament for another reason:
    // docs/parameter-ball.md).
    let p = DetectParams { growths: 0, ..DetectParams::default() };
    let d = detect(&input(&m, &[2], 3), &p, &|_| {}).unwrap();
    let (f, _) = band_means(&d, &interior);
    assert!(f < 0.3, "without the wavelength the interior is a filament: mean factor {f}");

    let dir = tempfile::tempdir().unwrap();
    let map = m.written_to(&dir.path().join("dispersed.phm"));
    assert_eq!(map.version(), (1, 1), "a spectral dimension is a version 1.1 feature");
    let p = DetectParams { spectral_scale: 50.0, ..p };
    let d = detect_map(&map.view(), &p, &|_| {}).unwrap();
    let (f, _) = band_means(&d, &interior);
    assert!(
        (f - iso).abs() < 0.1,
        "with the wavelength the interior is free: mean factor {f}, isotropic {iso}"
    );
    let (mu, mv) =
        (0..n).fold((0.0, 0.0), |a, i| (a.0 + m.params[3 * i] as f64, a.1 + m.params[3 * i + 1] as f64));
    let (mu, mv) = (mu / n as f64, mv / n as f64);
    let l2 = (0..n)
        .map(|i| (m.params[3 * i] as f64 - mu).powi(2) + (m.params[3 * i + 1] as f64 - mv).powi(2))
        .sum::<f64>()
        / n as f64;
    let want = p.spectral_scale as f64 * l2.sqrt() / 340.0;
    let got = d.spectral_scales[0].unwrap() as f64;
    assert!((got / want - 1.0).abs() < 1e-5, "scale {got} against {want}");
}

/// Two wavelengths' filaments that cross (issue 23): each wavelength is focused onto its own
/// line, the two crossing at the origin, and photons of both leave every part of the emitter
/// ([`crate::synthetic::two_wavelength_lines`]). Near the crossing, without the wavelength among
/// the parameters, a photon's (u, v) ball holds both lines, and its Kc nearest form an X: no
/// basis follows the photon's own line, and the X is not held as a line is (measured over
/// seeds: mean factor 0.16–0.24, |u_b| along the own line 0.61–0.66). With it (S = 1: the two
/// wavelengths lie about 0.24 apart in parameter space, beyond the ball's 0.15), the ball holds
/// the photon's own line only, and it is held along it: the filaments are told apart, as the
/// paper's Fig. 3 tells sheets apart. Both with the paper's fixed ball.
#[test]
fn a_wavelength_parameter_tells_two_wavelengths_filaments_apart() {
    let m = crate::synthetic::two_wavelength_lines(12_000, 29);
    // Within 0.9 mm of the crossing.
    let crossing: Vec<usize> = (0..m.len()).filter(|&i| (m.params[3 * i] - 0.5).abs() < 0.003).collect();
    assert!(crossing.len() > 50);
    // |u_b| along the photon's own line.
    let along = |d: &Detection| {
        crossing
            .iter()
            .map(|&i| {
                let [ux, uy, _] = d.basis_u[i].map(|c| c as f64);
                if m.params[3 * i + 2] < 500.0 { uy.abs() } else { ux.abs() }
            })
            .sum::<f64>()
            / crossing.len() as f64
    };
    let p = DetectParams { growths: 0, ..DetectParams::default() };
    let d = detect(&input(&m, &[2], 3), &p, &|_| {}).unwrap();
    let (f, a) = (band_means(&d, &crossing).0, along(&d));
    assert!(f > 0.1 && a < 0.8, "without the wavelength the crossing is an X: mean factor {f}, along {a}");

    let dir = tempfile::tempdir().unwrap();
    let map = m.written_to(&dir.path().join("two-lines.phm"));
    let d = detect_map(&map.view(), &DetectParams { spectral_scale: 1.0, ..p }, &|_| {}).unwrap();
    let (f, _) = band_means(&d, &crossing);
    let a = along(&d);
    assert!(
        f < 0.15 && a > 0.95,
        "with the wavelength each line is held along itself: mean factor {f}, along {a}"
    );
}
