//! Feature detection's kernels against closed forms and brute force; whole maps in [`maps`].

use std::f64::consts::PI;

use glam::DVec2;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::*;

mod maps;
pub(crate) mod tiles;

fn rng(seed: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(seed)
}

fn stats(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt())
}

#[test]
fn eigen2_matches_nalgebra_and_its_own_definition() {
    let mut r = rng(1);
    let mut cases: Vec<[f64; 3]> =
        vec![[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    // Beyond the range of the squares, and h < 0 with b of either sign.
    cases.extend([[1e300, 3e299, -1e300], [-2.0, 1.0, 3.0], [-2.0, -1.0, 3.0], [1.0, -0.0, 5.0]]);
    cases.extend((0..500).map(|_| {
        let s = 10f64.powf(r.random_range(-8.0..8.0));
        [r.random_range(-1.0..1.0) * s, r.random_range(-1.0..1.0) * s, r.random_range(-1.0..1.0) * s]
    }));
    for [a, b, c] in cases {
        let e = eigen2(a, b, c);
        let m = nalgebra::Matrix2::new(a, b, b, c);
        let ne = nalgebra::SymmetricEigen::new(m);
        let (lo, hi) = (ne.eigenvalues.min(), ne.eigenvalues.max());
        let scale = a.abs().max(b.abs()).max(c.abs()).max(f64::MIN_POSITIVE);
        assert!((e.lambda1 - hi).abs() <= 1e-12 * scale, "{a} {b} {c}: {e:?} vs {hi}");
        assert!((e.lambda2 - lo.max(0.0)).abs() <= 1e-12 * scale, "{a} {b} {c}: {e:?} vs {lo}");
        // M·P = λ·P, unit and orthogonal.
        // λ2 is clamped at 0 (it is a covariance's); an indefinite test matrix's P2 still
        // belongs to the true (negative) eigenvalue.
        let l2 = if lo < 0.0 { lo } else { e.lambda2 };
        for (l, p) in [(e.lambda1, e.p1), (l2, e.p2)] {
            let mp = [a * p[0] + b * p[1], b * p[0] + c * p[1]];
            assert!((mp[0] - l * p[0]).abs() <= 1e-12 * scale && (mp[1] - l * p[1]).abs() <= 1e-12 * scale);
            assert!((p[0].hypot(p[1]) - 1.0).abs() < 1e-12);
        }
        assert!((e.p1[0] * e.p2[0] + e.p1[1] * e.p2[1]).abs() < 1e-12);
        // P1 at an angle in (−90°, 90°], and (1, 0) when the matrix is isotropic.
        assert!(e.p1[0] > 0.0 || (e.p1[0] == 0.0 && e.p1[1] > 0.0), "{a} {b} {c}: {e:?}");
        if a == c && b == 0.0 {
            assert_eq!(e.p1, [1.0, 0.0]);
        }
    }
}

#[test]
fn erf_matches_tabulated_values() {
    // Abramowitz & Stegun, Table 7.1.
    for (x, want) in [
        (0.0, 0.0),
        (0.1, 0.112_462_916),
        (0.5, 0.520_499_878),
        (1.0, 0.842_700_793),
        (2.0, 0.995_322_265),
        (3.0, 0.999_977_910),
    ] {
        assert!((erf(x) - want).abs() < 2e-7, "erf({x}) = {} not {want}", erf(x));
        assert!((erf(-x) + want).abs() < 2e-7);
    }
}

#[test]
fn eq7_factor_spans_zero_to_one_and_grows_with_lambda2() {
    let (mu, sigma) = NoiseModel::Paper.mu_sigma(50);
    // On the clamp's lower end M = 4/(3π), so with Φ ≈ 1 the factor is 0.
    assert!((migration(LAMBDA2_MIN) - 4.0 / (3.0 * PI)).abs() < 1e-12);
    assert!(v_factor(LAMBDA2_MIN, mu, sigma) < 1e-6);
    assert!(v_factor(0.0, mu, sigma) < 1e-6, "a collinear neighbourhood is held");
    assert_eq!(v_factor(0.25, mu, sigma), 1.0);
    assert_eq!(v_factor(0.4, mu, sigma), 1.0, "λ2 above 1/4 clamps to free");
    let mut last = 0.0;
    for i in 0..=1000 {
        let l = 0.3 * i as f64 / 1000.0;
        let f = v_factor(l, mu, sigma);
        assert!((0.0..=1.0).contains(&f) && f >= last - 1e-12, "λ2 {l}: {f} after {last}");
        last = f;
    }
    assert!(v_factor(f64::NAN, mu, sigma).is_finite());
    // Φ at μ is ½ by definition.
    assert!((noise_filter(mu, mu, sigma) - 0.5).abs() < 1e-7);
}

/// The paper's Fig. 7a, and the normalisation note of method.md.
#[test]
fn uniform_disc_lambda2_matches_the_papers_fig_7a() {
    let mut r = rng(2);
    let (mut disc, mut far) = (Vec::new(), Vec::new());
    let mut pts = Vec::with_capacity(100);
    for _ in 0..50_000 {
        pts.clear();
        pts.extend((0..100).map(|_| in_disc(&mut r)));
        let l = lambda2_of(&pts);
        let r2 = pts.iter().map(|p| p[0] * p[0] + p[1] * p[1]).fold(0.0, f64::max);
        disc.push(l);
        far.push(l / r2);
    }
    let (m, s) = stats(&disc);
    assert!((m / 0.2219 - 1.0).abs() < 0.01, "mean {m}");
    assert!((s / 0.0188 - 1.0).abs() < 0.01, "sd {s}");
    let (fm, _) = stats(&far);
    assert!((fm - 0.224).abs() < 0.001, "farthest-point mean {fm}");
}

#[test]
fn simulated_table_agrees_with_a_fresh_simulation_and_the_paper_in_the_limit() {
    let mut r = rng(3);
    for k in [3usize, 7, 16, 50, 100] {
        let sets = 20_000;
        let (m, s) = simulate(k, sets, &mut r);
        let (tm, ts) = NoiseModel::Simulated.mu_sigma(k);
        let se = s / (sets as f64).sqrt();
        assert!((m - tm).abs() < 4.0 * se, "K {k}: simulated mean {m}, table {tm}");
        assert!((s / ts - 1.0).abs() < 0.03, "K {k}: simulated sd {s}, table {ts}");
    }
    // Exact at the table's rows, between its neighbours elsewhere, and the paper's law beyond.
    for w in SIMULATED.windows(2) {
        let (a, b) = (w[0], w[1]);
        assert_eq!(NoiseModel::Simulated.mu_sigma(a.0 as usize), (a.1, a.2));
        assert!(a.1 < b.1, "μ rises with K: {a:?} {b:?}");
        assert!(a.0 < 6 || a.2 > b.2, "σ falls with K beyond its peak at 6: {a:?} {b:?}");
        if b.0 > a.0 + 1 {
            let (m, s) = NoiseModel::Simulated.mu_sigma((a.0 + 1) as usize);
            assert!(a.1 < m && m < b.1 && a.2.min(b.2) <= s && s <= a.2.max(b.2));
        }
    }
    let (m4, s4) = NoiseModel::Simulated.mu_sigma(4000);
    let last = SIMULATED[SIMULATED.len() - 1];
    assert!(((0.25 - m4) * 2.0 - (0.25 - last.1)).abs() < 1e-12 && (s4 * 2.0 - last.2).abs() < 1e-12);
    // The paper's model, Eq. 4–5, at its own K.
    let (pm, ps) = NoiseModel::Paper.mu_sigma(100);
    assert!((pm - 0.22191).abs() < 1e-9 && (ps - 0.0188).abs() < 1e-12);
}

#[test]
fn tangent_basis_is_orthonormal_for_every_normal() {
    let mut r = rng(4);
    let mut normals = vec![DVec3::Z, -DVec3::Z, DVec3::X, DVec3::new(0.0, 1e-9, -1.0).normalize()];
    normals.extend((0..200).map(|_| {
        DVec3::new(r.random_range(-1.0..1.0), r.random_range(-1.0..1.0), r.random_range(-1.0..1.0))
            .normalize()
    }));
    for n in normals {
        let (t1, t2) = tangent_basis(n);
        for (a, b, want) in [(t1, t1, 1.0), (t2, t2, 1.0), (t1, t2, 0.0), (t1, n, 0.0), (t2, n, 0.0)] {
            assert!((a.dot(b) - want).abs() < 1e-12, "{n}");
        }
        assert!((t1.cross(t2) - n).length() < 1e-12, "right-handed: {n}");
    }
}

/// The photon at the origin and `pts` around it, as offsets (the photon included).
fn hood(pts: &[[f64; 2]], map: impl Fn([f64; 2]) -> DVec3) -> (Vec<DVec3>, f64) {
    let mut offsets = vec![DVec3::ZERO];
    offsets.extend(pts.iter().map(|&p| map(p)));
    let r2 = offsets.iter().map(|o| o.length_squared()).fold(0.0, f64::max);
    (offsets, r2)
}

fn disc_points(n: usize, seed: u64, keep: impl Fn([f64; 2]) -> bool) -> Vec<[f64; 2]> {
    let mut r = rng(seed);
    let mut v = Vec::new();
    while v.len() < n {
        let p = in_disc(&mut r);
        if keep(p) {
            v.push(p);
        }
    }
    v
}

fn flat(p: [f64; 2]) -> DVec3 {
    DVec3::new(p[0], p[1], 0.0)
}

#[test]
fn pca_holds_a_half_disc_across_its_edge_and_frees_a_full_disc() {
    let z = Some([0.0f32, 0.0, 1.0]);
    // A photon on the straight edge x = 0 of a lit half-plane x < 0.
    let (o, r2) = hood(&disc_points(49, 5, |p| p[0] < 0.0), flat);
    let c = pca_constraint(&Neighbourhood { offsets: &o, r2, normal: z }, NoiseModel::Simulated);
    assert_eq!(c.outcome, Outcome::Measured);
    assert!(c.factor < 0.1, "edge factor {}", c.factor);
    assert!(c.u[1].abs() > 0.95, "u_b along the edge: {:?}", c.u);
    // A photon inside a uniform region.
    let (o, r2) = hood(&disc_points(49, 6, |_| true), flat);
    let c = pca_constraint(&Neighbourhood { offsets: &o, r2, normal: z }, NoiseModel::Simulated);
    assert!(c.factor > 0.8, "uniform factor {} (λ2 {})", c.factor, c.lambda2);
    let v = DVec3::from(c.v.map(|x| x as f64));
    assert!((v.length() - c.factor as f64).abs() < 1e-6, "|v_b| is the factor");
    assert!(DVec3::from(c.u.map(|x| x as f64)).dot(v).abs() < 1e-6);
}

#[test]
fn degenerate_neighbourhoods_get_documented_finite_constraints() {
    let mut s = Vec::new();
    let z = Some([0.0f32, 0.0, 2.5]);
    let run = |o: &[DVec3], normal: Option<[f32; 3]>, s: &mut Vec<DVec2>| {
        let r2 = o.iter().map(|o| o.length_squared()).fold(0.0, f64::max);
        let c = pca_constraint(&Neighbourhood { offsets: o, r2, normal }, NoiseModel::Simulated);
        let g = gradient_constraint(&Neighbourhood { offsets: o, r2, normal }, &vec![1.0; o.len()], 0.6, s);
        for x in [&c, &g] {
            assert!(x.u.iter().chain(&x.v).chain([&x.lambda2, &x.factor]).all(|v| v.is_finite()), "{x:?}");
        }
        c
    };
    // Coincident photons: r = 0.
    let c = run(&[DVec3::ZERO; 50], z, &mut s);
    assert_eq!((c.outcome, c.factor, c.lambda2), (Outcome::Coincident, 1.0, 0.25));
    // Displaced only along the normal: no extent in the tangent plane.
    let o: Vec<DVec3> = (0..50).map(|i| DVec3::new(0.0, 0.0, i as f64)).collect();
    assert_eq!(run(&o, z, &mut s).outcome, Outcome::Coincident);
    // Fewer than three.
    assert_eq!(run(&[DVec3::ZERO, DVec3::X], z, &mut s).outcome, Outcome::TooFew);
    assert_eq!(run(&[], z, &mut s).outcome, Outcome::TooFew);
    // Collinear: held across the line (factor 0), free along it.
    let o: Vec<DVec3> = (0..50).map(|i| DVec3::new(0.0, i as f64 - 20.0, 0.0)).collect();
    let c = run(&o, z, &mut s);
    assert_eq!(c.outcome, Outcome::Measured);
    assert!(c.lambda2 == 0.0 && c.factor < 1e-6 && c.u[1].abs() > 0.999, "{c:?}");
    // Unusable normals: estimated from the neighbourhood (here the plane x = 0).
    let o: Vec<DVec3> = disc_points(49, 7, |_| true).iter().map(|p| DVec3::new(0.0, p[0], p[1])).collect();
    for bad in [None, Some([0.0f32; 3]), Some([f32::NAN, 0.0, 1.0])] {
        let c = run(&o, bad, &mut s);
        assert_eq!(c.outcome, Outcome::Measured);
        assert!(c.u[0].abs() < 1e-6 && c.v[0].abs() < 1e-6, "basis in the plane x = 0: {c:?}");
    }
}

#[test]
fn pca_ignores_the_normals_length_and_the_scenes_scale() {
    let pts = disc_points(49, 8, |p| p[0] + 0.3 * p[1] < 0.2);
    let (o, r2) = hood(&pts, flat);
    let base = pca_constraint(
        &Neighbourhood { offsets: &o, r2, normal: Some([0.0, 0.0, 1.0]) },
        NoiseModel::Simulated,
    );
    for (scale, len) in [(1e-6, 1.0f32), (1e6, 1.0), (1.0, 1e-3), (1.0, 1e4)] {
        let o: Vec<DVec3> = o.iter().map(|x| *x * scale).collect();
        let c = pca_constraint(
            &Neighbourhood { offsets: &o, r2: r2 * scale * scale, normal: Some([0.0, 0.0, len]) },
            NoiseModel::Simulated,
        );
        assert!(
            (c.lambda2 - base.lambda2).abs() < 1e-6 && (c.factor - base.factor).abs() < 1e-6,
            "{scale} {len}"
        );
        for k in 0..3 {
            assert!((c.u[k] - base.u[k]).abs() < 1e-6 && (c.v[k] - base.v[k]).abs() < 1e-6);
        }
    }
}

#[test]
fn gradient_baseline_holds_an_edge_along_its_gradient_and_frees_a_uniform_region() {
    let mut s = Vec::new();
    let z = Some([0.0f32, 0.0, 1.0]);
    let (o, r2) = hood(&disc_points(49, 9, |p| p[0] < 0.0), flat);
    let c = gradient_constraint(
        &Neighbourhood { offsets: &o, r2, normal: z },
        &[1.0; 50],
        DEFAULT_GAIN as f64,
        &mut s,
    );
    assert!(c.factor < 0.05, "edge {c:?}");
    assert!(c.u[1].abs() > 0.95, "u_b along the edge {c:?}");
    let (o, r2) = hood(&disc_points(49, 10, |_| true), flat);
    let c = gradient_constraint(
        &Neighbourhood { offsets: &o, r2, normal: z },
        &[1.0; 50],
        DEFAULT_GAIN as f64,
        &mut s,
    );
    assert!(c.factor > 0.6, "uniform {c:?}");
    // Gain 0 frees everything.
    let c = gradient_constraint(&Neighbourhood { offsets: &o, r2, normal: z }, &[1.0; 50], 0.0, &mut s);
    assert_eq!(c.factor, 1.0);
}

// ---- Over photon sets.

fn owned_input(m: &crate::synthetic::SyntheticMap) -> (Vec<u32>, usize) {
    (m.emitters.iter().map(|e| e.param_dims).collect(), m.param_dims as usize)
}

fn input<'a>(m: &'a crate::synthetic::SyntheticMap, dims: &'a [u32], stride: usize) -> DetectInput<'a> {
    DetectInput {
        positions: &m.position,
        normals: Some(&m.normal),
        flux: Some(&m.flux),
        params: (stride > 0).then_some(ParamColumn { values: &m.params, stride, dims }),
        emitters: (m.emitters.len() > 1).then_some(&m.emitter[..]),
        pages: Default::default(),
    }
}

fn all_finite(d: &Detection) -> bool {
    d.basis_u.iter().chain(&d.basis_v).flatten().chain(&d.lambda2).all(|x| x.is_finite())
        && d.r_param.as_ref().is_none_or(|r| r.iter().all(|x| x.is_finite() && *x >= 0.0))
}

#[test]
fn r_param_is_beta_times_the_kth_parameter_distance_by_brute_force() {
    let m = crate::synthetic::two_emitters(1500, 11);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let p = DetectParams { kc: 20, k_density: Some(10), ..Default::default() };
    let d = detect(&inp, &p, &|_| {}).unwrap();
    let r = d.r_param.as_ref().unwrap();
    let points = inp.points(true);
    for i in (0..m.len()).step_by(13) {
        let want = crate::spatial::brute_force_knn(&points, Space::Params, &points.query(i, None), 10);
        let rk = (want.last().unwrap().dist2 as f64).sqrt();
        let expect = 3.0 * rk * (20.0f64 / 10.0).sqrt();
        assert!((r[i] as f64 - expect).abs() <= 1e-6 * expect, "photon {i}: {} vs {expect}", r[i]);
        // Eq. 1 spelled out: β·sqrt(Kc/(πρ)), ρ = k/(π r_k²).
        let rho = 10.0 / (PI * rk * rk);
        assert!((expect - 3.0 * (20.0 / (PI * rho)).sqrt()).abs() < 1e-9 * expect);
    }
    assert!(all_finite(&d));
}

#[test]
fn param_pca_neighbourhoods_equal_a_brute_force_gather() {
    // Recompute a sample of photons' constraints from brute-force neighbourhoods.
    let m = crate::synthetic::collimated_cusp(3000, 12);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let p = DetectParams::default();
    let d = detect(&inp, &p, &|_| {}).unwrap();
    let points = inp.points(true);
    let r = d.r_param.as_ref().unwrap();
    for i in (0..m.len()).step_by(37) {
        let nb =
            crate::spatial::brute_force_knn(&points, Space::WorldParams, &points.query(i, Some(r[i])), p.kc);
        let xi = m.position[i];
        let o: Vec<DVec3> = nb
            .iter()
            .map(|n| {
                let xj = m.position[n.index as usize];
                DVec3::new((xj[0] - xi[0]) as f64, (xj[1] - xi[1]) as f64, (xj[2] - xi[2]) as f64)
            })
            .collect();
        let r2 = o.iter().map(|x| x.length_squared()).fold(0.0, f64::max);
        let c = pca_constraint(&Neighbourhood { offsets: &o, r2, normal: Some(m.normal[i]) }, p.noise);
        assert_eq!((c.u, c.v, c.lambda2), (d.basis_u[i], d.basis_v[i], d.lambda2[i]), "photon {i}");
    }
}

#[test]
fn adversarial_photon_sets_give_finite_constraints_for_every_method() {
    let mut maps = Vec::new();
    // Tiny maps: 0, 1, 2 photons, and fewer than Kc.
    for n in [0, 1, 2, 7] {
        maps.push(crate::synthetic::collimated_cusp(n, 13));
    }
    // All photons on one point with one parameter value.
    let mut m = crate::synthetic::collimated_cusp(300, 14);
    m.position.iter_mut().for_each(|p| *p = [0.1, 0.2, 0.0]);
    m.params.iter_mut().for_each(|p| *p = 0.5);
    maps.push(m);
    // Photons on a line, normals of odd lengths and a zero normal.
    let mut m = crate::synthetic::collimated_cusp(300, 15);
    for (i, p) in m.position.iter_mut().enumerate() {
        *p = [i as f32 * 1e-3, 0.0, 0.0];
    }
    m.normal.iter_mut().enumerate().for_each(|(i, n)| *n = [0.0, 0.0, (i % 5) as f32 * 3.0]);
    maps.push(m);
    for m in &maps {
        let (dims, stride) = owned_input(m);
        let inp = input(m, &dims, stride);
        for method in [Method::ParamPca, Method::WorldPca, Method::Gradient, Method::None] {
            for kc in [3, 50] {
                let p = DetectParams { method, kc, ..Default::default() };
                let d = detect(&inp, &p, &|_| {}).unwrap();
                assert_eq!(d.basis_u.len(), m.len());
                assert!(all_finite(&d), "{method:?} Kc {kc} on {} photons", m.len());
                for (u, v) in d.basis_u.iter().zip(&d.basis_v) {
                    let (u, v) = (DVec3::from(u.map(|x| x as f64)), DVec3::from(v.map(|x| x as f64)));
                    assert!(
                        (u.length() - 1.0).abs() < 1e-5 && v.length() <= 1.0 + 1e-5 && u.dot(v).abs() < 1e-5
                    );
                }
            }
        }
    }
}

#[test]
fn results_do_not_change_with_the_scenes_scale() {
    let m = crate::synthetic::collimated_cusp(2000, 16);
    let (dims, stride) = owned_input(&m);
    let base = detect(&input(&m, &dims, stride), &DetectParams::default(), &|_| {}).unwrap();
    for (scale, exact) in [(2f32.powi(-20), true), (2f32.powi(20), true), (1e-6, false), (1e6, false)] {
        let mut s = m.clone();
        s.position.iter_mut().for_each(|p| *p = p.map(|c| c * scale));
        let d = detect(&input(&s, &dims, stride), &DetectParams::default(), &|_| {}).unwrap();
        assert!(all_finite(&d));
        let mut off = 0;
        for i in 0..m.len() {
            let dl = (d.lambda2[i] - base.lambda2[i]).abs();
            let dv: f32 = (0..3).map(|k| (d.basis_v[i][k] - base.basis_v[i][k]).abs()).sum();
            if exact {
                assert!(dl < 1e-6 && dv < 1e-5, "scale {scale}, photon {i}: Δλ2 {dl}, Δv {dv}");
            } else if dl > 1e-4 || dv > 1e-3 {
                off += 1;
            }
        }
        // Rounding of scaled positions may swap a Kc-th neighbour at an exact tie.
        assert!(off <= m.len() / 200, "scale {scale}: {off} photons differ");
    }
}

#[test]
fn progress_reports_every_photon_of_every_pass() {
    let m = crate::synthetic::collimated_cusp(5000, 17);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let done = std::sync::atomic::AtomicU64::new(0);
    detect(&inp, &DetectParams::default(), &|k| {
        done.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(done.into_inner(), work_units(&inp, Method::ParamPca));
    assert_eq!(work_units(&inp, Method::ParamPca), 10_000);
}

#[test]
fn bad_parameters_and_missing_parameters_are_refused() {
    let m = crate::synthetic::collimated_cusp(100, 18);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    for p in [
        DetectParams { kc: 2, ..Default::default() },
        DetectParams { beta: 0.0, ..Default::default() },
        DetectParams { beta: f32::NAN, ..Default::default() },
        DetectParams { k_density: Some(1), ..Default::default() },
        DetectParams { gain: -1.0, ..Default::default() },
    ] {
        assert!(matches!(detect(&inp, &p, &|_| {}), Err(DetectError::Parameter(_))), "{p:?}");
    }
    let no_params = input(&m, &dims, 0);
    assert!(matches!(
        detect(&no_params, &DetectParams::default(), &|_| {}),
        Err(DetectError::NoParameters { .. })
    ));
    let p = DetectParams { method: Method::WorldPca, ..Default::default() };
    let d = detect(&no_params, &p, &|_| {}).unwrap();
    assert!(d.r_param.is_none() && all_finite(&d));
    let mut bad = m.clone();
    bad.position[5][1] = f32::NAN;
    let e = detect(&input(&bad, &dims, stride), &DetectParams::default(), &|_| {}).unwrap_err();
    assert!(matches!(e, DetectError::Spatial(SpatialError::NonFinite { index: 5, .. })), "{e}");
}

/// The report's sums do not depend on how the photons are split or in which order the parts
/// come: factors spread over sixteen orders of magnitude (whose f64 sum in one order rounds
/// differently from another's) summed in three parts, in two orders, give the whole map's
/// summary bit for bit, and its mean agrees with both orders' f64 sums to their rounding.
#[test]
fn summary_sums_do_not_depend_on_the_split_or_its_order() {
    let mut r = rng(41);
    let factors: Vec<f32> = (0..30_000).map(|_| 10f32.powf(r.random_range(-16.0..0.0))).collect();
    let outcomes: Vec<Outcome> = (0..factors.len())
        .map(|i| [Outcome::Measured, Outcome::TooFew, Outcome::Coincident, Outcome::Unconstrained][i % 4])
        .collect();
    let whole = summarise(&factors, &outcomes);
    let cuts = [0, 7_001, 19_999, factors.len()];
    let parts: Vec<std::ops::Range<usize>> = cuts.windows(2).map(|w| w[0]..w[1]).collect();
    for order in [[0, 1, 2], [2, 0, 1]] {
        let mut sums = SummarySums::default();
        for k in order {
            sums.add(&factors[parts[k].clone()], &outcomes[parts[k].clone()]);
        }
        assert_eq!(sums.summary(), whole);
    }
    // The naive f64 sum in two orders differs; the exact mean lies within both's rounding.
    let forward: f64 = factors.iter().map(|&f| f as f64).sum();
    let backward: f64 = factors.iter().rev().map(|&f| f as f64).sum();
    assert_ne!(forward, backward, "the naive sums should differ for this test to show anything");
    let n = factors.len() as f64;
    assert!((whole.mean_factor - forward / n).abs() <= 1e-12 * whole.mean_factor);
    assert!((whole.mean_factor - backward / n).abs() <= 1e-12 * whole.mean_factor);
    assert_eq!(
        (whole.photons, whole.measured, whole.too_few, whole.coincident),
        (30_000, 7_500, 7_500, 7_500)
    );
    assert_eq!(whole.constrained, factors.iter().filter(|&&f| f < 0.5).count());
}
