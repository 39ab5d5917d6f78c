//! Detection tile by tile against the whole map (the oracle): bit for bit on collimated and
//! point emitters, two emitters, a dispersed map and the sample files, for 1×1 to 3×3 tilings,
//! with empty tiles and photons exactly on the cuts (docs/tiles.md).

use super::*;
use crate::detect::tiled::{Options, Radius, detect_tile_with};
use crate::tiles::Tiling;

const GRIDS: [[usize; 2]; 4] = [[1, 1], [2, 1], [2, 2], [3, 3]];

/// Asserts two detections are the same bits, photon by photon, and the same report.
fn assert_same(want: &Detection, got: &Detection, what: &str) {
    let bits3 = |v: &[[f32; 3]]| v.iter().map(|x| x.map(f32::to_bits)).collect::<Vec<_>>();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let n = want.basis_u.len();
    assert_eq!(got.basis_u.len(), n, "{what}");
    for (name, a, b) in [
        ("basis_u", bits3(&want.basis_u), bits3(&got.basis_u)),
        ("basis_v", bits3(&want.basis_v), bits3(&got.basis_v)),
    ] {
        if let Some(i) = (0..n).find(|&i| a[i] != b[i]) {
            panic!("{what}: {name} of photon {i}: {:?} vs {:?}", want.basis_u[i], got.basis_u[i]);
        }
    }
    assert_eq!(bits(&want.lambda2), bits(&got.lambda2), "{what}: lambda2");
    assert_eq!(want.r_param.as_deref().map(bits), got.r_param.as_deref().map(bits), "{what}: r_param");
    assert_eq!(want.summary, got.summary, "{what}: summary");
    assert_eq!(want.summary.mean_factor.to_bits(), got.summary.mean_factor.to_bits(), "{what}");
}

/// The whole map's detection and every tiling's, compared; returns the most rounds any tile
/// needed (world, parameter space).
fn check_tilings(inp: &DetectInput, p: &DetectParams, what: &str) -> (u32, u32) {
    let want = detect(inp, p, &|_| {}).unwrap();
    let mut most = (0, 0);
    for grid in GRIDS {
        let tiling = Tiling::new(inp.positions, grid);
        let parts: Vec<TileDetection> =
            (0..tiling.len()).map(|t| detect_tile(inp, p, &tiling, t, &|_| {}).unwrap()).collect();
        for t in &parts {
            most = (most.0.max(t.rounds), most.1.max(t.param_rounds));
        }
        let got = assemble(inp.positions.len(), &parts).unwrap();
        assert_same(&want, &got, &format!("{what}, {}×{}", grid[0], grid[1]));
        // Every tile in one process, Eq. 1's radius found tile by tile or for the whole map.
        for radius in [Radius::PerTile, Radius::Whole] {
            let got = crate::detect::tiled(inp, p, &tiling, radius, &|_| {}).unwrap();
            assert_same(&want, &got, &format!("{what}, {}×{} in one run, {radius:?}", grid[0], grid[1]));
        }
    }
    most
}

#[test]
fn tiles_equal_the_whole_map_on_synthetic_maps() {
    let p = DetectParams::default();
    for (name, m) in [
        ("collimated cusp", crate::synthetic::collimated_cusp(4000, 31)),
        ("point ring", crate::synthetic::point_ring(4000, 32)),
        ("two emitters", crate::synthetic::two_emitters(4000, 33)),
        ("dispersed beam", crate::synthetic::dispersed_beam(3000, 34)),
    ] {
        let (dims, stride) = owned_input(&m);
        let inp = input(&m, &dims, stride);
        let rounds = check_tilings(&inp, &p, name);
        assert!(rounds.0 >= 1 && rounds.1 >= 1, "{name}: {rounds:?}");
    }
}

#[test]
fn tiles_equal_the_whole_map_for_every_method_and_option() {
    let m = crate::synthetic::two_emitters(2500, 35);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let no_normals = DetectInput { normals: None, ..inp };
    for (what, inp, p) in [
        ("world-pca", inp, DetectParams { method: Method::WorldPca, ..Default::default() }),
        ("gradient", inp, DetectParams { method: Method::Gradient, kc: 20, ..Default::default() }),
        ("none", inp, DetectParams { method: Method::None, ..Default::default() }),
        ("none, no normals", no_normals, DetectParams { method: Method::None, ..Default::default() }),
        ("param-pca, no normals", no_normals, DetectParams::default()),
        (
            "fixed ball, k 10",
            inp,
            DetectParams { growths: 0, k_density: Some(10), kc: 12, ..Default::default() },
        ),
        ("Kc beyond the map", inp, DetectParams { kc: 100_000, ..Default::default() }),
    ] {
        check_tilings(&inp, &p, what);
    }
}

/// A collimated map with more than half its photons on the line x = 0 (a strip of parameters
/// folded onto it), so that the first column's cut is the box's low side and the tiles of that
/// column are empty; an L with a fold (two sheets over one strip) so that the parameter ball
/// matters; and rows of photons on x = ½ and y = ½ (ties).
pub(crate) fn bordered_map() -> crate::synthetic::SyntheticMap {
    let mut m = crate::synthetic::SyntheticMap {
        param_dims: 2,
        emitters: vec![crate::synthetic::collimated_emitter(0, 1.0)],
        ..Default::default()
    };
    let mut r = rng(36);
    let mut push = |x: f32, y: f32, u: f32, v: f32| {
        m.position.push([x, y, 0.0]);
        m.normal.push([0.0, 0.0, 1.0]);
        m.flux.push([1e-4; 3]);
        m.emitter.push(0);
        m.params.extend_from_slice(&[u, v]);
    };
    // The box's corners (0, 0) and (1, 1) in x, y come from (1, 0) and (0, 1) and the L below.
    push(1.0, 0.0, 0.99, 0.0);
    push(0.0, 1.0, 0.0, 0.99);
    for _ in 0..3000 {
        let (u, v): (f32, f32) = (r.random(), r.random());
        // An L: the lower half, and the left half of the upper one; u ≥ 0.8 folds back.
        let x = if u < 0.8 { u } else { 1.6 - u };
        let y = if x >= 0.5 { 0.5 * v } else { v };
        push(x, y, u, v);
    }
    for k in 0..60 {
        let t = k as f32 / 60.0;
        push(0.5, 0.5 * t, 0.5, 0.5 * t);
        push(0.5 * t, 0.5, 0.5 * t, 0.5);
    }
    for _ in 0..3400 {
        let (w, v): (f32, f32) = (r.random(), r.random());
        push(0.0, v, -0.05 * w, v);
    }
    m
}

#[test]
fn empty_tiles_and_photons_on_cuts() {
    let m = bordered_map();
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    for grid in [[2, 2], [3, 3]] {
        let tiling = Tiling::new(&m.position, grid);
        let mut counts = vec![0usize; tiling.len()];
        m.position.iter().for_each(|&x| counts[tiling.tile_of(x)] += 1);
        // The first column ([0, 0)) is empty: the photons on its cut, x = 0, are in the next.
        assert_eq!(tiling.cell(0).1[0], 0.0);
        for iy in 0..grid[1] {
            assert_eq!(counts[iy * grid[0]], 0, "{grid:?}: {counts:?}");
        }
        // Every photon lies in its tile's cell, half-open (the box's high side closed); some lie
        // exactly on their cell's lower cut inside the box (the ones a cut goes through).
        assert_eq!(tiling.axes, [0, 1]);
        let mut on_cuts = 0;
        for &x in &m.position {
            let (lo, hi) = tiling.cell(tiling.tile_of(x));
            for k in 0..2 {
                let v = x[k] as f64;
                assert!(lo[k] <= v && (v < hi[k] || v == 1.0), "{grid:?} {x:?}");
                on_cuts += usize::from(v == lo[k] && v > 0.0);
            }
        }
        assert!(on_cuts > 0, "{grid:?}");
        let empty = detect_tile(&inp, &DetectParams::default(), &tiling, 0, &|_| {}).unwrap();
        assert!(empty.indices.is_empty() && empty.r_param.as_ref().is_some_and(|r| r.is_empty()));
    }
    check_tilings(&inp, &DetectParams::default(), "bordered");
    check_tilings(&inp, &DetectParams { method: Method::WorldPca, ..Default::default() }, "bordered, world");
}

/// Halos far too small are still exact (the certificate sends the photons round again), and
/// the certificate is what makes them so: without it the same halos give other results.
#[test]
fn certificates_make_small_halos_exact_and_are_needed() {
    let m = crate::synthetic::two_emitters(3000, 37);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let p = DetectParams::default();
    let want = detect(&inp, &p, &|_| {}).unwrap();
    let tiling = Tiling::new(&m.position, [3, 3]);
    let run = |opts: Options| {
        let parts: Vec<TileDetection> =
            (0..9).map(|t| detect_tile_with(&inp, &p, &tiling, t, opts, None, &|_| {}).unwrap()).collect();
        let rounds = parts
            .iter()
            .map(|t| (t.rounds, t.param_rounds))
            .fold((0, 0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        (assemble(m.len(), &parts).unwrap(), rounds)
    };
    let (small, rounds) = run(Options { halo_scale: 0.05, certify: true });
    assert_same(&want, &small, "small halos");
    assert!(rounds.0 > 2 && rounds.1 > 2, "{rounds:?}");
    let (blind, _) = run(Options { halo_scale: 0.05, certify: false });
    let differ = (0..m.len()).filter(|&i| blind.basis_v[i] != want.basis_v[i]).count();
    let r_differ = (0..m.len())
        .filter(|&i| blind.r_param.as_ref().unwrap()[i] != want.r_param.as_ref().unwrap()[i])
        .count();
    assert!(differ > 50 && r_differ > 50, "{differ} bases, {r_differ} radii differ");
}

/// A 40 × 40 lattice turned by `angle`, some photons doubled, given in a scrambled order.
fn lattice(angle: f64) -> crate::synthetic::SyntheticMap {
    let mut m = crate::synthetic::SyntheticMap {
        param_dims: 2,
        emitters: vec![crate::synthetic::collimated_emitter(0, 1.0)],
        ..Default::default()
    };
    let (s, c) = angle.sin_cos();
    for k in 0..2500u32 {
        let j = (k.wrapping_mul(2_654_435_761) >> 3) % 1600;
        let (a, b) = ((j % 40) as f64 * 0.025, (j / 40) as f64 * 0.025);
        let (x, y) = ((c * a - s * b) as f32, (s * a + c * b) as f32);
        m.position.push([x, y, 0.0]);
        m.normal.push([0.0, 0.0, 1.0]);
        m.flux.push([1e-4; 3]);
        m.emitter.push(0);
        m.params.extend_from_slice(&[a as f32, b as f32]);
    }
    m
}

/// Ties: photons on a lattice (many equal distances, coincident photons), where the tie-break
/// by label decides the neighbourhoods; tiles keep the whole map's labels. And a turned
/// lattice, whose neighbourhoods are isotropic up to rounding, so that P1 is decided by the
/// rounding of the covariance sums: tiles sum the neighbours in the whole map's order.
#[test]
fn ties_and_rounding_go_the_same_way_in_tiles() {
    for (name, angle) in [("lattice", 0.0), ("turned lattice", 0.3)] {
        let m = lattice(angle);
        let (dims, stride) = owned_input(&m);
        let inp = input(&m, &dims, stride);
        for kc in [5, 9, 13, 50] {
            for method in [Method::ParamPca, Method::WorldPca] {
                let p = DetectParams { kc, method, ..Default::default() };
                check_tilings(&inp, &p, &format!("{name}, {method:?}, Kc {kc}"));
            }
        }
    }
}

#[test]
fn sample_maps_detected_by_tiles_equal_the_whole_map() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples");
    for name in
        ["collimated-cusp.phm", "point-ring.phm", "two-emitters.phm", "dispersed-beam.phm", "minimal.phm"]
    {
        let map = crate::format::PhotonMap::open(dir.join(name).to_str().unwrap()).unwrap();
        let view = map.view();
        let (method, _) = choose_method(&view, None).unwrap();
        let p = DetectParams { method, ..Default::default() };
        let want = detect_map(&view, &p, &|_| {}).unwrap();
        for grid in GRIDS {
            let tiling = Tiling::new(view.positions(), grid);
            let parts: Vec<TileDetection> =
                (0..tiling.len()).map(|t| detect_map_tile(&view, &p, &tiling, t, &|_| {}).unwrap()).collect();
            let mut got = assemble(view.len(), &parts).unwrap();
            got.spectral_scales = want.spectral_scales.clone();
            assert_same(&want, &got, &format!("{name}, {}×{}", grid[0], grid[1]));
        }
    }
}

#[test]
fn bad_tiles_and_bad_parts_are_refused() {
    let m = crate::synthetic::collimated_cusp(500, 38);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    let p = DetectParams::default();
    let tiling = Tiling::new(&m.position, [2, 1]);
    assert!(detect_tile(&inp, &p, &tiling, 2, &|_| {}).is_err());
    let a = detect_tile(&inp, &p, &tiling, 0, &|_| {}).unwrap();
    let b = detect_tile(&inp, &p, &tiling, 1, &|_| {}).unwrap();
    assert!(assemble(m.len(), std::slice::from_ref(&a)).unwrap_err().to_string().contains("in no tile"));
    assert!(
        assemble(m.len(), &[a.clone(), a.clone(), b.clone()]).unwrap_err().to_string().contains("two tiles")
    );
    assert!(assemble(10, &[a, b]).unwrap_err().to_string().contains("not in a map"));
    // A non-finite position fails in a tile as in the whole map, with its index in the file.
    let mut bad = m.clone();
    bad.position[123][0] = f32::NAN;
    let inp = input(&bad, &dims, stride);
    let whole = detect(&inp, &p, &|_| {}).unwrap_err().to_string();
    let tile =
        detect_tile(&inp, &p, &Tiling::new(&bad.position, [2, 2]), 0, &|_| {}).unwrap_err().to_string();
    assert_eq!(whole, tile);
    assert!(whole.contains("123"), "{whole}");
}

#[test]
fn tiles_report_the_whole_maps_work_units() {
    // With parameters: a pass in parameter space and one in world space, as the whole map.
    let m = crate::synthetic::collimated_cusp(3000, 19);
    let (dims, stride) = owned_input(&m);
    let inp = input(&m, &dims, stride);
    for (p, radius) in [
        (DetectParams::default(), Radius::PerTile),
        (DetectParams::default(), Radius::Whole),
        (DetectParams { method: Method::WorldPca, ..DetectParams::default() }, Radius::Whole),
    ] {
        let done = std::sync::atomic::AtomicU64::new(0);
        let add = |k| {
            done.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
        };
        crate::detect::tiled(&inp, &p, &Tiling::new(inp.positions, [2, 2]), radius, &add).unwrap();
        assert_eq!(done.into_inner(), work_units(&inp, p.method), "{:?}, {radius:?}", p.method);
    }
}

#[test]
fn the_whole_maps_radius_pass_is_chosen_only_where_it_fits_the_budget() {
    // 10⁷ photons of 52 bytes each need 520 MB; the pass 24 bytes a photon more (240 MB).
    let model = crate::detect::tiled::memory(None);
    let n = 10_000_000;
    let need = ((model.per_photon + crate::detect::RADIUS_PASS_BYTES) * n as f64) as u64;
    assert_eq!(need, 760_000_000);
    assert_eq!(Radius::for_budget(n, need, 0, &model), Radius::Whole);
    assert_eq!(Radius::for_budget(n, need - 1, 0, &model), Radius::PerTile);
    // What the process holds already counts against the budget.
    assert_eq!(Radius::for_budget(n, need, 1, &model), Radius::PerTile);
    assert_eq!(Radius::for_budget(n, 1_000_000_000, 200_000_000, &model), Radius::Whole);
    assert_eq!(Radius::for_budget(n, 1_000_000_000, 300_000_000, &model), Radius::PerTile);
}
