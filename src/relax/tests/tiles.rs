//! Relaxation tile by tile against the whole map (the oracle): bit for bit on collimated and
//! point emitters, two emitters and a dispersed beam, before collapse (parameter-restricted
//! neighbours) and after (world space; within the spectral window for the beam), for 2×1, 2×2 and 3×3 tilings, with empty tiles and photons exactly on the
//! cuts (docs/tiles.md); a halo too small and not certified differs.

use super::*;
use crate::format::{MapView, PhotonMap};
use crate::relax::tiled::{Options, relax_tile_with};
use crate::tiles::{TileSpec, Tiling};

const GRIDS: [[usize; 2]; 3] = [[2, 1], [2, 2], [3, 3]];

/// The merge of every tile of `grid` relaxed with `opts`, through the part files' tables.
fn tiled(map: &MapView, p: &RelaxParams, grid: [usize; 2], opts: Options) -> (Relaxed, Vec<TileRelaxed>) {
    let tiling = Tiling::new(map.positions(), grid);
    let tiles: Vec<TileRelaxed> =
        (0..tiling.len()).map(|t| relax_tile_with(map, p, None, &tiling, t, opts).unwrap()).collect();
    let parts: Vec<_> = tiles
        .iter()
        .enumerate()
        .map(|(t, r)| tile_part(map, r, p, TileSpec { index: t, count: tiling.len() }, 0.0).unwrap())
        .collect();
    let views: Vec<MapView> = parts.iter().map(|t| t.view()).collect();
    let (_, merged) = merge_parts(map, &views).unwrap();
    (merged, tiles)
}

/// The whole map's per-iteration series of every photon (by index in the map, R values each):
/// nearest-neighbour distance, its ratio to r_K, and step, in working units.
fn whole_series(map: &MapView, p: &RelaxParams) -> [Vec<u32>; 3] {
    use crate::spatial::order::locality_order;
    let setup = Setup::of(map, p, false).unwrap();
    let order = locality_order(map.positions());
    let mut columns = Columns::of(map, &order, &setup).unwrap();
    let wide = MapWide { labels: None, spacing: setup.spacing, coincident: setup.coincident };
    let r = setup.p.iterations;
    let mut series = [(); 3].map(|_| vec![0u32; map.len() * r]);
    let mut t = 0;
    run(map, &mut columns, &setup, None, &wide, &order, |scratch, _, _| {
        let per = scratch.per_photon();
        for (k, &i) in order.iter().enumerate() {
            for (s, v) in series.iter_mut().zip([&per.nn, &per.ratio, &per.step]) {
                s[i as usize * r + t] = v[k].to_bits();
            }
        }
        t += 1;
        true
    })
    .unwrap();
    series
}

/// Asserts every tile's per-photon series are the whole map's, bit for bit, photon by photon.
fn check_series(map: &MapView, p: &RelaxParams, tiles: &[TileRelaxed], what: &str) {
    let want = whole_series(map, p);
    let r = p.iterations;
    for (t, tile) in tiles.iter().enumerate() {
        let ordered = [&tile.nn, &tile.ratio, &tile.step].map(|v| tile.in_interior_order(v));
        for (k, &i) in tile.indices.iter().enumerate() {
            for (c, got) in ordered.iter().enumerate() {
                let got: Vec<u32> = got[k * r..][..r].iter().map(|v| v.to_bits()).collect();
                assert_eq!(got, want[c][i as usize * r..][..r], "{what}: tile {t}, photon {i}, series {c}");
            }
        }
    }
}

/// The first photon whose position differs in its bits, if any.
fn first_difference(a: &Relaxed, b: &Relaxed) -> Option<usize> {
    let bits = |x: &[f32; 3]| x.map(f32::to_bits);
    (0..a.positions.len()).find(|&i| bits(&a.positions[i]) != bits(&b.positions[i]))
}

/// Asserts every tiling of `map` relaxes to the whole map's bits and report; returns the most
/// rounds a tile took.
fn check_tilings(map: &MapView, p: &RelaxParams, what: &str) -> u32 {
    let want = relax_map(map, p, |_| {}).unwrap();
    let mut rounds = 0;
    for grid in GRIDS {
        let (got, tiles) = tiled(map, p, grid, Options::default());
        let what = format!("{what}, {}×{}", grid[0], grid[1]);
        assert_eq!(got.positions.len(), want.positions.len(), "{what}");
        if let Some(i) = first_difference(&want, &got) {
            panic!("{what}: photon {i}: {:?} vs {:?}", want.positions[i], got.positions[i]);
        }
        assert_eq!(got.measures, want.measures, "{what}: measures");
        check_series(map, p, &tiles, &what);
        assert_eq!((got.space, got.constrained), (want.space, want.constrained), "{what}");
        // Every tile in one process, as `relax --memory` runs them.
        let mut calls = 0;
        let one = relax_tiled(map, p, None, &Tiling::new(map.positions(), grid), |tile, of, _| {
            assert_eq!((tile, of), (calls, grid[0] * grid[1]));
            calls += 1;
        })
        .unwrap();
        assert_eq!(calls, grid[0] * grid[1]);
        assert_eq!(first_difference(&want, &one), None, "{what}: in one process");
        assert_eq!(
            (&one.measures, one.space, one.constrained),
            (&want.measures, want.space, want.constrained)
        );
        rounds = tiles.iter().map(|t| t.rounds).fold(rounds, u32::max);
    }
    rounds
}

/// `m` written, detected (param-pca), and collapsed, in `dir`: the maps of both phases.
fn phases(dir: &std::path::Path, name: &str, m: &crate::synthetic::SyntheticMap) -> [PhotonMap; 2] {
    let raw = map_in(dir, &format!("{name}.phm"), m);
    let detected = detect_to(&raw, dir, &format!("{name}-d.phm"));
    let path = dir.join(format!("{name}-c.phm"));
    collapse(&detected.view()).unwrap().write(crate::format::Output::Path(path.clone())).unwrap();
    [detected, PhotonMap::open_path(&path).unwrap()]
}

#[test]
fn tiles_equal_the_whole_map_in_both_phases() {
    let dir = tempfile::tempdir().unwrap();
    let p = RelaxParams::default();
    for (name, m) in [
        ("collimated", crate::synthetic::collimated_cusp(2500, 41)),
        ("point", crate::synthetic::point_ring(2500, 42)),
        ("two", crate::synthetic::two_emitters(2500, 43)),
        ("spectral", crate::synthetic::dispersed_beam(2500, 44)),
    ] {
        let [detected, collapsed] = phases(dir.path(), name, &m);
        assert_eq!(relax_map(&detected.view(), &p, |_| {}).unwrap().space, RelaxSpace::WorldParams);
        check_tilings(&detected.view(), &p, &format!("{name}, before collapse"));
        // After the collapse, photons with a wavelength keep to their spectral window.
        let after = if name == "spectral" { RelaxSpace::WorldSpectral } else { RelaxSpace::World };
        assert_eq!(relax_map(&collapsed.view(), &p, |_| {}).unwrap().space, after);
        check_tilings(&collapsed.view(), &p, &format!("{name}, after collapse"));
    }
}

#[test]
fn empty_tiles_and_photons_on_cuts() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = crate::detect::tests::tiles::bordered_map();
    let n = m.position.len();
    // The columns a traced map has and the detect oracle's map leaves out.
    m.incident = vec![[0.0, 0.0, -1.0]; n];
    m.path_length = vec![1.0; n];
    m.bounces = vec![1; n];
    m.emission_index = (0..n as u64).collect();
    let [detected, collapsed] = phases(dir.path(), "bordered", &m);
    for map in [&detected, &collapsed] {
        let map = map.view();
        for grid in [[2, 2], [3, 3]] {
            let tiling = Tiling::new(map.positions(), grid);
            let mut counts = vec![0usize; tiling.len()];
            map.positions().iter().for_each(|&x| counts[tiling.tile_of(x)] += 1);
            assert_eq!(counts[0], 0, "{grid:?}: {counts:?}");
            let on_cut = map.positions().iter().filter(|x| {
                (0..tiling.len()).any(|t| {
                    let (lo, _) = tiling.cell(t);
                    (0..2).any(|k| x[tiling.axes[k]] as f64 == lo[k])
                })
            });
            assert!(on_cut.count() > 0);
        }
        check_tilings(&map, &RelaxParams::default(), "bordered");
    }
}

#[test]
fn a_small_first_halo_is_grown_until_certified_and_without_certificate_differs() {
    let dir = tempfile::tempdir().unwrap();
    let [detected, collapsed] = phases(dir.path(), "cusp", &crate::synthetic::collimated_cusp(3000, 44));
    let p = RelaxParams::default();
    for map in [&detected, &collapsed] {
        let map = map.view();
        let want = relax_map(&map, &p, |_| {}).unwrap();
        let small = Options { halo_scale: 0.02, certify: true };
        let (got, tiles) = tiled(&map, &p, [2, 2], small);
        assert_eq!(first_difference(&want, &got), None);
        check_series(&map, &p, &tiles, "a small first halo");
        assert!(
            tiles.iter().any(|t| t.rounds > 1),
            "{:?}",
            tiles.iter().map(|t| t.rounds).collect::<Vec<_>>()
        );
        let (wrong, _) = tiled(&map, &p, [2, 2], Options { certify: false, ..small });
        assert!(
            first_difference(&want, &wrong).is_some(),
            "an uncertified small halo gave the whole map's result"
        );
    }
}

#[test]
fn flux_diffusion_and_bad_parts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let [detected, _] = phases(dir.path(), "small", &crate::synthetic::point_ring(600, 45));
    let map = detected.view();
    let tiling = Tiling::new(map.positions(), [2, 1]);
    let p = RelaxParams { flux_diffusion: 0.1, ..Default::default() };
    assert!(relax_tile(&map, &p, None, &tiling, 0).is_err());
    let p = RelaxParams::default();
    let part = |t: usize, p: &RelaxParams| {
        let r = relax_tile(&map, p, None, &tiling, t).unwrap();
        tile_part(&map, &r, p, TileSpec { index: t, count: 2 }, 0.0).unwrap()
    };
    let (a, b) = (part(0, &p), part(1, &p));
    let other = part(1, &RelaxParams { kf: 12, ..p });
    assert!(merge_parts(&map, &[a.view(), b.view()]).is_ok());
    for (what, parts) in [
        ("missing", vec![a.view()]),
        ("twice", vec![a.view(), a.view()]),
        ("other parameters", vec![a.view(), other.view()]),
    ] {
        assert!(merge_parts(&map, &parts).is_err(), "{what}");
    }
}

/// A map with a sparse surround (an annulus 10-20 times the caustic's size away, its photons'
/// spacing several times the caustic's size): every tiling is exact, and the middle tile of
/// the caustic is certified in its first halo (a photon is held back only by photons that could
/// have come within its reach).
#[test]
fn a_sparse_surround_does_not_hold_back_a_dense_tile() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = crate::synthetic::collimated_cusp(3000, 46);
    let dense = m.position.len();
    let (lo, hi) = m.position.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), x| {
        (std::array::from_fn(|k| lo[k].min(x[k])), std::array::from_fn(|k| hi[k].max(x[k])))
    });
    let c: [f32; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let size = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let dims = m.param_dims as usize;
    let halton = crate::sampling::halton::Halton::new(7);
    for j in 0..400usize {
        // Uniform on the annulus (Halton points in radius² and angle).
        let [a, b, _, _] = halton.point(j as u64);
        let r = size * (100.0 + 300.0 * a).sqrt();
        let phi = std::f32::consts::TAU * b;
        let mut x = c;
        x[0] += r * phi.cos();
        x[1] += r * phi.sin();
        let from = j % dense;
        m.position.push(x);
        m.normal.push(m.normal[from]);
        m.flux.push(m.flux[from]);
        m.params.extend_from_within(from * dims..(from + 1) * dims);
        m.emitter.push(m.emitter[from]);
        m.incident.push(m.incident[from]);
        m.path_length.push(m.path_length[from]);
        m.bounces.push(m.bounces[from]);
        m.emission_index.push(10_000_000 + j as u64);
    }
    let [_, collapsed] = phases(dir.path(), "surround", &m);
    let map = collapsed.view();
    let p = RelaxParams::default();
    check_tilings(&map, &p, "surround");
    // The caustic's photons fill the middle tile of a 3×3 tiling cut at quantiles.
    let tiling = Tiling::new(map.positions(), [3, 3]);
    let r = relax_tile(&map, &p, None, &tiling, 4).unwrap();
    let after_first = r.per_round.get(1).map_or(0, |x| x[0]);
    assert!(
        after_first * 20 <= r.indices.len(),
        "{after_first} of {} photons left after the first halo ({:?})",
        r.indices.len(),
        r.per_round
    );
}

/// The move bounds' one search per photon (`first_spacings`) against the first iteration of the
/// whole map's relaxation (the oracle): the same first spacings bit for bit, and the same reads
/// except where a crowd's photon reads farther to be nudged, in both phases.
#[test]
fn first_spacings_are_what_the_first_iteration_sets() {
    use crate::spatial::order::locality_order;
    let dir = tempfile::tempdir().unwrap();
    let p = RelaxParams::default();
    let mut crowd = crate::synthetic::collimated_cusp(600, 48);
    // Photons stacked on one point: their Kf nearest sit on them, so they have no first spacing.
    let x = crowd.position[0];
    crowd.position[..40].fill(x);
    for (name, m) in [
        ("collimated", crate::synthetic::collimated_cusp(1500, 45)),
        ("two", crate::synthetic::two_emitters(1500, 46)),
        ("spectral", crate::synthetic::dispersed_beam(1500, 47)),
        ("crowd", crowd),
    ] {
        for map in &phases(dir.path(), name, &m) {
            let map = map.view();
            let setup = Setup::of(&map, &p, false).unwrap();
            let order = locality_order(map.positions());
            let mut columns = Columns::of(&map, &order, &setup).unwrap();
            let (first, read) = crate::relax::first_spacings(&map, &columns, &setup, &order).unwrap();
            let wide = MapWide { labels: None, spacing: setup.spacing, coincident: setup.coincident };
            let mut want = (Vec::new(), Vec::new());
            run(&map, &mut columns, &setup, None, &wide, &order, |scratch, _, _| {
                want = (scratch.first_spacing().to_vec(), scratch.per_photon().read.clone());
                false
            })
            .unwrap();
            let what = format!("{name}, {:?}", setup.space);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
            assert_eq!(bits(&first), bits(&want.0), "{what}: first spacings");
            // A crowd's photon reads beyond its Kf to be nudged; its first spacing is ∞ either way.
            for (k, (&a, &b)) in read.iter().zip(&want.1).enumerate() {
                assert!(
                    a.to_bits() == b.to_bits() || first[k] == f32::INFINITY,
                    "{what}: photon {k} read {a} against {b}"
                );
            }
            let crowded = first.iter().filter(|f| f.is_infinite()).count();
            assert_eq!(crowded > 0, name == "crowd", "{what}: {crowded} without a first spacing");
        }
    }
}

/// A tile run finds the photons of a halo box through the cells of each tile's grid as a scan
/// of the map finds them: those in the box (in label order), and those outside it that can
/// come within a reach of it in the run (by their move bounds), for 1×1, 2×2 and 3×3 tilings
/// (tiles of one to nine cells) and halos from none to most of the map.
#[test]
fn halo_photons_found_through_cells_are_a_scans() {
    use crate::relax::tiled::{TiledRun, depth_in};
    use crate::spatial::order::locality_order;
    let dir = tempfile::tempdir().unwrap();
    let [detected, _] = phases(dir.path(), "cells", &crate::synthetic::collimated_cusp(20000, 48));
    let map = detected.view();
    let p = RelaxParams::default();
    let pos = map.positions();
    let order = locality_order(pos);
    let setup = Setup::of(&map, &p, false).unwrap();
    let scale = setup.scale as f64;
    for grid in [[1, 1], [2, 2], [3, 3]] {
        let tiling = Tiling::new(pos, grid);
        let extent = tiling.axes.iter().map(|&a| (tiling.hi[a] - tiling.lo[a]) as f64).fold(0.0, f64::max);
        let run = TiledRun::new(&map, &p, None, &tiling, None).unwrap();
        let mut found = (0, 0);
        for tile in 0..tiling.len() {
            for h in [0.0, 0.02, 0.1, 0.5] {
                let halo = tiling.halo_box(tile, h * extent);
                let want: Vec<u32> =
                    order.iter().copied().filter(|&i| halo.contains(pos[i as usize])).collect();
                assert_eq!(run.members(&halo), want, "{grid:?}, tile {tile}, halo {h}");
                for reach in [0.0, 0.01 * extent * scale] {
                    let r = p.iterations;
                    let key = |x: [f32; 3]| x.map(f32::to_bits);
                    let mut got: Vec<_> = run.outside(&halo, r, reach).iter().map(|(x, _)| key(*x)).collect();
                    let mut want: Vec<_> = (0..pos.len())
                        .filter(|&i| !halo.contains(pos[i]))
                        .map(|i| (pos[i].map(|v| v * setup.scale), run.moves()[i] as f64))
                        .filter(|(x, b)| -depth_in(&halo, *x, scale) < r as f64 * b + reach)
                        .map(|(x, _)| key(x))
                        .collect();
                    got.sort_unstable();
                    want.sort_unstable();
                    assert_eq!(got, want, "{grid:?}, tile {tile}, halo {h}, reach {reach}");
                    found = (found.0 + want.len(), found.1 + (!want.is_empty()) as usize);
                }
            }
        }
        // (One tile's box holds the whole map: nothing is outside it.)
        assert!(tiling.len() == 1 || found.1 > tiling.len(), "{grid:?}: {found:?}");
    }
}

/// The move bounds a tile job computes tile by tile, against the whole map's relaxation (the
/// oracle): no photon moves farther in any iteration than its bound, for 1×1, 2×2 and 3×3
/// tilings; the bounds are finite, and a tiling's bounds are the untiled ones for most photons
/// (a photon's halo box holds its Kf nearest).
#[test]
fn move_bounds_hold_every_move_of_the_whole_map() {
    use crate::relax::tiled::TiledRun;
    use crate::spatial::order::locality_order;
    let dir = tempfile::tempdir().unwrap();
    let [detected, collapsed] = phases(dir.path(), "bounds", &crate::synthetic::collimated_cusp(3000, 47));
    let p = RelaxParams { iterations: 12, ..Default::default() };
    for map in [&detected, &collapsed] {
        let map = map.view();
        let setup = Setup::of(&map, &p, false).unwrap();
        let order = locality_order(map.positions());
        // The whole map's moves per iteration, by label (the run is in label order).
        let mut columns = Columns::of(&map, &order, &setup).unwrap();
        let wide = MapWide { labels: None, spacing: setup.spacing, coincident: setup.coincident };
        let mut starts: Vec<Vec<[f32; 3]>> = Vec::new();
        run(&map, &mut columns, &setup, None, &wide, &order, |_, _, before| {
            starts.push(before.to_vec());
            true
        })
        .unwrap();
        starts.push(columns.positions.clone());
        // By label, as the whole map's moves are.
        let bounds_of = |tiling: &Tiling| {
            let run = TiledRun::new(&map, &p, None, tiling, None).unwrap();
            order.iter().map(|&i| run.moves()[i as usize]).collect::<Vec<f32>>()
        };
        let untiled = bounds_of(&Tiling::new(map.positions(), [1, 1]));
        for grid in [[1, 1], [2, 2], [3, 3]] {
            let tiling = Tiling::new(map.positions(), grid);
            let bounds = bounds_of(&tiling);
            assert!(bounds.iter().all(|b| b.is_finite() && *b > 0.0), "{grid:?}");
            let mut tightest = 0f64;
            for (t, w) in starts.windows(2).enumerate() {
                for (l, (a, b)) in w[0].iter().zip(&w[1]).enumerate() {
                    let moved = (0..3).map(|c| (b[c] as f64 - a[c] as f64).powi(2)).sum::<f64>().sqrt();
                    assert!(
                        moved <= bounds[l] as f64,
                        "{grid:?}: iteration {t}, photon {l}: {moved} > {}",
                        bounds[l]
                    );
                    tightest = tightest.max(moved / bounds[l] as f64);
                }
            }
            // Some photon takes a clamped step: the bound is the step limit, not a loose guess.
            assert!(tightest > 0.99, "{grid:?}: the largest move is {tightest} of its bound");
            let same = bounds.iter().zip(&untiled).filter(|(a, b)| a == b).count();
            assert!(same * 10 >= 9 * bounds.len(), "{grid:?}: {same} of {} as untiled", bounds.len());
            assert!(
                bounds.iter().zip(&untiled).all(|(a, b)| a >= b),
                "{grid:?}: a tiled bound below the untiled one"
            );
        }
    }
}
