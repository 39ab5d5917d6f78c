//! Every query checked against the brute-force scan on seeded random and adversarial inputs.

use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::*;

/// Owned photon data for building a [`PointSet`].
struct Owned {
    pos: Vec<[f32; 3]>,
    params: Vec<f32>,
    stride: usize,
    dims: Vec<u32>,
    emitters: Option<Vec<u16>>,
}

impl Owned {
    fn set(&self) -> PointSet<'_> {
        PointSet {
            positions: &self.pos,
            params: (self.stride > 0).then_some(ParamColumn {
                values: &self.params,
                stride: self.stride,
                dims: &self.dims,
            }),
            emitters: self.emitters.as_deref(),
        }
    }
}

/// Checks `k`-NN of every photon (and of some off-photon points) in `space` against the scan.
fn check_all(o: &Owned, space: Space, ks: &[usize], radii: &[Option<f32>], rng: &mut Pcg64Mcg) {
    let set = o.set();
    let index = SpatialIndex::build(&set, space).unwrap();
    let mut out = Neighbours::default();
    let mut far = Neighbours::farthest_only(0);
    let n = set.len();
    let mut queries: Vec<Query> = (0..n).map(|i| set.query(i, None)).collect();
    // Off-photon queries: jittered copies of photons, and one with its own photon excluded.
    for _ in 0..n.min(20) {
        let i = rng.random_range(0..n);
        let mut q = set.query(i, None);
        for c in &mut q.position {
            *c += rng.random::<f32>() - 0.5;
        }
        queries.push(q);
        let mut q = set.query(i, None);
        q.exclude = Some(i as u32);
        queries.push(q);
    }
    for q in &mut queries {
        for &radius in radii {
            q.radius = radius;
            for &k in ks {
                index.knn(q, k, &mut out);
                let want = brute_force_knn(&set, space, q, k);
                assert_eq!(
                    out.as_slice(),
                    &want[..],
                    "space {space:?}, k {k}, radius {radius:?}, query {q:?}"
                );
                index.knn(q, k, &mut far);
                assert_eq!((far.len(), far.max_dist2()), (want.len(), want.last().map(|n| n.dist2)));
                assert!(far.as_slice().is_empty());
            }
        }
    }
}

fn random_points(n: usize, rng: &mut Pcg64Mcg) -> Vec<[f32; 3]> {
    (0..n).map(|_| [rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>()]).collect()
}

fn unit(rng: &mut Pcg64Mcg) -> [f32; 3] {
    loop {
        let v = [
            rng.random::<f32>() * 2.0 - 1.0,
            rng.random::<f32>() * 2.0 - 1.0,
            rng.random::<f32>() * 2.0 - 1.0,
        ];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.1 && l <= 1.0 {
            return v.map(|c| c / l);
        }
    }
}

#[test]
fn world_knn_equals_brute_force_on_random_points() {
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    // Around one, two and three leaves' worth (16 records each), and larger.
    for n in [0, 1, 5, 15, 16, 17, 31, 32, 33, 48, 49, 100, 700] {
        let o = Owned {
            pos: random_points(n, &mut rng),
            params: vec![],
            stride: 0,
            dims: vec![],
            emitters: None,
        };
        check_all(&o, Space::World, &[0, 1, 7, 50, 1000], &[None], &mut rng);
    }
}

#[test]
fn constrained_knn_equals_brute_force_with_two_three_and_four_parameter_emitters() {
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let n = 800;
    // Emitter 0: (u, v) in the unit square; emitter 1: no parameters; emitter 2: directions;
    // emitter 3: (u, v, scaled wavelength); emitter 4: direction and scaled wavelength.
    let emitters: Vec<u16> = (0..n).map(|_| rng.random_range(0..5u16)).collect();
    let mut params = Vec::with_capacity(4 * n);
    for &e in &emitters {
        match e {
            0 => params.extend([rng.random::<f32>(), rng.random::<f32>(), 0.0, 0.0]),
            1 => params.extend([0.0; 4]),
            2 => params.extend(unit(&mut rng).into_iter().chain([0.0])),
            3 => params.extend([rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>(), 0.0]),
            _ => params.extend(unit(&mut rng).into_iter().chain([rng.random::<f32>()])),
        }
    }
    let o = Owned {
        pos: random_points(n, &mut rng),
        params,
        stride: 4,
        dims: vec![2, 0, 3, 3, 4],
        emitters: Some(emitters),
    };
    let radii = [None, Some(0.0), Some(0.05), Some(0.3), Some(10.0), Some(-1.0), Some(f32::NAN)];
    check_all(&o, Space::WorldParams, &[1, 16, 50], &radii, &mut rng);
    check_all(&o, Space::Params, &[1, 16, 50], &[None], &mut rng);
    check_all(&o, Space::World, &[16], &[Some(0.1)], &mut rng);
}

#[test]
fn one_dimensional_parameters_are_supported() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let n = 300;
    let params: Vec<f32> = (0..n).map(|_| rng.random::<f32>()).collect();
    let o = Owned { pos: random_points(n, &mut rng), params, stride: 1, dims: vec![], emitters: None };
    check_all(&o, Space::WorldParams, &[10], &[Some(0.1), None], &mut rng);
    check_all(&o, Space::Params, &[10], &[None], &mut rng);
}

#[test]
fn coincident_photons_tie_break_by_index() {
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    let n = 200;
    let o = Owned {
        pos: vec![[0.25, -3.0, 7.5]; n],
        params: vec![0.5; 2 * n],
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    let index = SpatialIndex::build(&o.set(), Space::WorldParams).unwrap();
    let mut out = Neighbours::default();
    index.knn(&o.set().query(150, Some(0.0)), 10, &mut out);
    assert_eq!(out.indices().collect::<Vec<_>>(), (0..10).collect::<Vec<u32>>());
    assert!(out.as_slice().iter().all(|n| n.dist2 == 0.0));
    check_all(&o, Space::WorldParams, &[1, 10, 300], &[Some(0.0), None], &mut rng);
    check_all(&o, Space::Params, &[10], &[None], &mut rng);
}

#[test]
fn photons_on_a_line_and_on_a_grid_with_many_equal_distances() {
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    // A line with duplicated points: every distance appears at least twice.
    let pos: Vec<[f32; 3]> = (0..400).map(|i| [(i / 2) as f32 * 0.5, 0.0, 0.0]).collect();
    let params: Vec<f32> = (0..400).flat_map(|i| [(i % 7) as f32, 0.0]).collect();
    let o = Owned { pos, params, stride: 2, dims: vec![], emitters: None };
    check_all(&o, Space::World, &[3, 16], &[None], &mut rng);
    check_all(&o, Space::WorldParams, &[3, 16], &[Some(1.0), Some(0.0)], &mut rng);
    // An integer grid on the plane z = 0: the z axis has no extent and must never be split.
    let pos: Vec<[f32; 3]> = (0..30).flat_map(|x| (0..30).map(move |y| [x as f32, y as f32, 0.0])).collect();
    let params: Vec<f32> = pos.iter().flat_map(|p| [p[1] * 0.1, p[0] * 0.1]).collect();
    let o = Owned { pos, params, stride: 2, dims: vec![], emitters: None };
    check_all(&o, Space::WorldParams, &[4, 9, 25], &[Some(0.25), None], &mut rng);
}

#[test]
fn one_parameter_value_for_all_and_fewer_candidates_than_k() {
    let mut rng = Pcg64Mcg::seed_from_u64(6);
    let n = 500;
    let o = Owned {
        pos: random_points(n, &mut rng),
        params: vec![0.3; 2 * n],
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    check_all(&o, Space::WorldParams, &[50], &[Some(0.0), Some(1e-9)], &mut rng);
    // Parameters spread on a line: tiny radii admit fewer photons than k.
    let params: Vec<f32> = (0..n).flat_map(|i| [i as f32 / n as f32, 0.0]).collect();
    let o = Owned { pos: random_points(n, &mut rng), params, stride: 2, dims: vec![], emitters: None };
    let set = o.set();
    let index = SpatialIndex::build(&set, Space::WorldParams).unwrap();
    let mut out = Neighbours::default();
    index.knn(&set.query(250, Some(3.5 / n as f32)), 50, &mut out);
    assert_eq!(out.len(), 7, "photons 247..=253 lie within the radius");
    check_all(&o, Space::WorldParams, &[50], &[Some(3.5 / n as f32), Some(0.02)], &mut rng);
}

#[test]
fn emitters_never_mix_in_parameter_aware_spaces() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let n = 300;
    let pos = random_points(n, &mut rng);
    let emitters: Vec<u16> = (0..n).map(|i| (i % 2) as u16 * 5).collect();
    let o =
        Owned { pos, params: vec![0.0; 2 * n], stride: 2, dims: vec![], emitters: Some(emitters.clone()) };
    let set = o.set();
    let index = SpatialIndex::build(&set, Space::WorldParams).unwrap();
    let mut out = Neighbours::default();
    for i in 0..n {
        index.knn(&set.query(i, None), 20, &mut out);
        assert!(out.indices().all(|j| emitters[j as usize] == emitters[i]));
    }
    // An emitter with no photons has no neighbours to give.
    let mut q = set.query(0, None);
    q.emitter = 3;
    index.knn(&q, 5, &mut out);
    assert!(out.is_empty());
    check_all(&o, Space::WorldParams, &[20], &[None], &mut rng);
}

#[test]
fn rebuild_after_moving_photons_equals_a_fresh_build() {
    let mut rng = Pcg64Mcg::seed_from_u64(8);
    let n = 2000;
    let mut o = Owned {
        pos: random_points(n, &mut rng),
        params: (0..2 * n).map(|_| rng.random::<f32>()).collect(),
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    let mut index = SpatialIndex::build(&o.set(), Space::WorldParams).unwrap();
    for p in &mut o.pos {
        p[0] += 0.01 * (rng.random::<f32>() - 0.5);
    }
    index.rebuild(&o.set()).unwrap();
    let fresh = SpatialIndex::build(&o.set(), Space::WorldParams).unwrap();
    let (mut a, mut b) = (Neighbours::default(), Neighbours::default());
    for i in (0..n).step_by(7) {
        let q = o.set().query(i, Some(0.1));
        index.knn(&q, 16, &mut a);
        fresh.knn(&q, 16, &mut b);
        assert_eq!(a.as_slice(), b.as_slice());
        assert_eq!(a.as_slice(), &brute_force_knn(&o.set(), Space::WorldParams, &q, 16)[..]);
    }
    let mut order = index.order();
    order.sort_unstable();
    assert_eq!(order, (0..n as u32).collect::<Vec<_>>());
}

#[test]
fn bad_inputs_are_refused_with_the_photon() {
    let pos = vec![[0.0f32; 3], [f32::NAN, 0.0, 0.0]];
    let e = SpatialIndex::build(&PointSet::world(&pos), Space::World).unwrap_err();
    assert!(matches!(e, SpatialError::NonFinite { index: 1, what: "position" }), "{e}");
    let pos = vec![[0.0f32; 3]; 2];
    let params = [0.0, 0.0, 1.0, f32::INFINITY];
    let set = PointSet {
        positions: &pos,
        params: Some(ParamColumn { values: &params, stride: 2, dims: &[] }),
        emitters: None,
    };
    let e = SpatialIndex::build(&set, Space::WorldParams).unwrap_err();
    assert!(matches!(e, SpatialError::NonFinite { index: 1, what: "params" }), "{e}");
    // World space never reads parameters, so they may be anything there.
    assert!(SpatialIndex::build(&set, Space::World).is_ok());
    let short = [0.0f32; 3];
    let set = PointSet {
        positions: &pos,
        params: Some(ParamColumn { values: &short, stride: 2, dims: &[] }),
        emitters: None,
    };
    assert!(matches!(SpatialIndex::build(&set, Space::World), Err(SpatialError::Length { .. })));
}

/// Photons on a plane: a tree that cycled axes would split on z, which has no extent.
#[test]
fn plane_photons_build_a_balanced_useful_tree() {
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let pos: Vec<[f32; 3]> = (0..5000).map(|_| [rng.random::<f32>(), rng.random::<f32>(), 1.0]).collect();
    let o = Owned { pos, params: vec![], stride: 0, dims: vec![], emitters: None };
    check_all(&o, Space::World, &[16], &[None], &mut rng);
}

mod props {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Small sets on a coarse grid: many exact ties in both spaces.
        #[test]
        fn grid_sets_match_brute_force(
            pts in prop::collection::vec((0i8..4, 0i8..4, 0i8..2, 0i8..3, 0i8..3, 0u16..2), 0..80),
            k in 0usize..20,
            radius in prop::option::of(0.0f32..3.0),
        ) {
            let pos: Vec<[f32; 3]> = pts.iter().map(|p| [p.0 as f32, p.1 as f32, p.2 as f32]).collect();
            let params: Vec<f32> = pts.iter().flat_map(|p| [p.3 as f32, p.4 as f32]).collect();
            let emitters: Vec<u16> = pts.iter().map(|p| p.5).collect();
            let o = Owned { pos, params, stride: 2, dims: vec![], emitters: Some(emitters) };
            let set = o.set();
            for space in [Space::World, Space::WorldParams, Space::Params] {
                let index = SpatialIndex::build(&set, space).unwrap();
                let mut out = Neighbours::default();
                for i in 0..set.len() {
                    let q = set.query(i, radius);
                    index.knn(&q, k, &mut out);
                    prop_assert_eq!(out.as_slice(), &brute_force_knn(&set, space, &q, k)[..]);
                }
            }
        }
    }
}

/// `n` photons with parameters (u, v) uniform in the unit square, whose two halves land on
/// overlapping strips of the plane z = 0 (Fig. 3's fold): world and parameter neighbours differ.
fn folded_sheet(n: usize, rng: &mut Pcg64Mcg) -> Owned {
    let mut pos = Vec::with_capacity(n);
    let mut params = Vec::with_capacity(2 * n);
    for _ in 0..n {
        let (u, v) = (rng.random::<f32>(), rng.random::<f32>());
        let x = if u < 0.5 { 1.2 * u } else { 0.4 + 1.2 * (u - 0.5) };
        pos.push([x, v, 0.0]);
        params.extend([u, v]);
    }
    Owned { pos, params, stride: 2, dims: vec![2], emitters: None }
}

/// The stages' pattern: one result buffer reused over every photon in the index's order (so
/// most queries start from the previous result's bound), each photon with its own radius,
/// on a folded sheet where world neighbours and parameter neighbours differ. Every result
/// equals the scan's, and `coords` are the returned photons' positions.
#[test]
fn queries_in_leaf_order_with_a_reused_buffer_equal_brute_force_and_return_positions() {
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let n = 1500;
    let o = folded_sheet(n, &mut rng);
    let radius: Vec<f32> = (0..n).map(|_| 0.02 + 0.1 * rng.random::<f32>()).collect();
    let set = o.set();
    for (space, k) in
        [(Space::WorldParams, 17), (Space::WorldParams, 50), (Space::Params, 50), (Space::World, 17)]
    {
        let index = SpatialIndex::build(&set, space).unwrap();
        let (mut out, mut set_only) = (Neighbours::default(), Neighbours::unordered(k));
        let mut bare = Neighbours::unordered(k).without_coords();
        let mut far = Neighbours::farthest_only(k);
        for i in index.order() {
            let i = i as usize;
            let q = set.query(i, Some(radius[i]));
            index.knn(&q, k, &mut out);
            let want = brute_force_knn(&set, space, &q, k);
            assert_eq!(out.as_slice(), &want[..], "space {space:?}, k {k}, photon {i}");
            if space != Space::Params {
                let at: Vec<[f32; 3]> = out.indices().map(|j| o.pos[j as usize]).collect();
                assert_eq!(out.coords(), &at[..]);
            }
            // An unordered buffer: the same neighbours, and the same farthest.
            index.knn(&q, k, &mut set_only);
            let mut got = set_only.as_slice().to_vec();
            got.sort_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
            assert_eq!(got, want, "unordered, space {space:?}, k {k}, photon {i}");
            assert_eq!(set_only.max_dist2(), want.last().map(|n| n.dist2));
            // Without coordinates: the same neighbours in the same order, and no coordinates.
            index.knn(&q, k, &mut bare);
            assert_eq!(bare.as_slice(), set_only.as_slice(), "bare, space {space:?}, k {k}, photon {i}");
            assert!(bare.coords().is_empty());
            // Only the count and the farthest: as the scan's, and no neighbours.
            index.knn(&q, k, &mut far);
            assert_eq!((far.len(), far.max_dist2()), (want.len(), want.last().map(|n| n.dist2)));
            assert!(far.as_slice().is_empty() && far.coords().is_empty());
        }
        assert!(
            far.group_answers > out.group_answers / 2,
            "{space:?}, k {k}: {} from groups",
            far.group_answers
        );
        // Queries were answered from their leaf's gathered candidates, not a search: most of
        // them where every ball holds k photons; fewer where the random radii (the stages'
        // vary smoothly) often admit fewer than k (691 and 109 of 1500 when written).
        let least = if space == Space::WorldParams { n / 20 } else { n / 2 };
        assert!(out.group_answers > least as u64, "{space:?}, k {k}: {} from groups", out.group_answers);
    }
}

/// A buffer reused across a rebuild (relaxation's pattern) never answers from the old
/// build's candidates or bound: after photons move, results equal the scan's.
#[test]
fn a_buffer_reused_across_rebuilds_sees_the_moved_photons() {
    let mut rng = Pcg64Mcg::seed_from_u64(12);
    let n = 3000;
    let mut o = Owned {
        pos: random_points(n, &mut rng).into_iter().map(|p| [p[0], p[1], 0.0]).collect(),
        params: (0..2 * n).map(|_| rng.random::<f32>()).collect(),
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    for space in [Space::World, Space::WorldParams] {
        let mut index = SpatialIndex::build(&o.set(), space).unwrap();
        let mut out = Neighbours::default();
        for round in 0..3 {
            let order = index.order();
            // The last photon of the previous round first: its query lies in the boxes of
            // the group the buffer holds from the old build.
            for &i in order.iter().rev().take(1).chain(&order) {
                let q = o.set().query(i as usize, Some(0.3));
                index.knn(&q, 17, &mut out);
                let want = brute_force_knn(&o.set(), space, &q, 17);
                assert_eq!(out.as_slice(), &want[..], "{space:?}, round {round}, photon {i}");
            }
            // Move every photon a little (far less than a leaf), then rebuild in place.
            for p in &mut o.pos {
                p[0] += 1e-4 * (rng.random::<f32>() - 0.5);
                p[1] += 1e-4 * (rng.random::<f32>() - 0.5);
            }
            index.rebuild(&o.set()).unwrap();
            let last = *order.last().unwrap();
            let q = o.set().query(last as usize, Some(0.3));
            index.knn(&q, 17, &mut out);
            assert_eq!(
                out.as_slice(),
                &brute_force_knn(&o.set(), space, &q, 17)[..],
                "{space:?}, after rebuild {round}"
            );
        }
        assert!(out.group_answers > 0);
    }
}

/// After [`Neighbours::forget`], an unordered buffer returns what a fresh one returns, order
/// included: the stages rely on it to give the same bits whatever the thread count.
#[test]
fn a_forgotten_buffer_answers_in_the_order_of_a_fresh_one() {
    let mut rng = Pcg64Mcg::seed_from_u64(13);
    let n = 4000;
    let o = Owned {
        pos: random_points(n, &mut rng).into_iter().map(|p| [p[0], p[1], 0.0]).collect(),
        params: vec![],
        stride: 0,
        dims: vec![],
        emitters: None,
    };
    let set = o.set();
    let index = SpatialIndex::build(&set, Space::World).unwrap();
    let order = index.order();
    let (mut used, mut fresh) = (Neighbours::unordered(17), Neighbours::unordered(17));
    let mut differs = 0;
    for cut in (100..n - 100).step_by(97) {
        // The used buffer answers the queries before `cut` (ending in the leaf where the
        // next run starts), forgets, and answers from `cut` on, as a fresh buffer does.
        for &i in &order[cut - 20..cut] {
            index.knn(&set.query(i as usize, None), 17, &mut used);
        }
        let mut unforgotten = used.clone();
        used.forget();
        fresh.forget();
        for &i in &order[cut - 1..cut + 20] {
            let q = set.query(i as usize, None);
            index.knn(&q, 17, &mut used);
            index.knn(&q, 17, &mut fresh);
            assert_eq!(used.as_slice(), fresh.as_slice(), "cut {cut}, photon {i}");
            index.knn(&q, 17, &mut unforgotten);
            differs += usize::from(unforgotten.as_slice() != fresh.as_slice());
        }
    }
    // Without forgetting, the order does depend on the earlier queries (the check above is
    // not vacuous).
    assert!(differs > 0);
}

/// A refitted index (photons moved, trees kept) answers every query exactly as the scan
/// does: after small moves, after moves of many leaf widths that scramble the leaves, and
/// through a buffer reused from before the refit; in world space and with parameter balls.
#[test]
fn a_refitted_index_equals_brute_force_after_small_and_large_moves() {
    let mut rng = Pcg64Mcg::seed_from_u64(13);
    let n = 2500;
    let mut o = folded_sheet(n, &mut rng);
    let radius: Vec<f32> = (0..n).map(|_| 0.03 + 0.1 * rng.random::<f32>()).collect();
    for (space, k) in [(Space::WorldParams, 17), (Space::WorldParams, 50), (Space::World, 17)] {
        let start = o.pos.clone();
        let mut index = SpatialIndex::build(&o.set(), space).unwrap();
        let mut out = Neighbours::unordered(k);
        for (round, step) in [1e-3f32, 1e-2, 2e-2, 0.2, 0.0].into_iter().enumerate() {
            let order = index.order();
            for &i in &order {
                let i = i as usize;
                let q = o.set().query(i, Some(radius[i]));
                index.knn(&q, k, &mut out);
                let mut got = out.as_slice().to_vec();
                got.sort_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
                let want = brute_force_knn(&o.set(), space, &q, k);
                assert_eq!(got, want, "{space:?}, k {k}, round {round}, photon {i}");
                assert_eq!(out.max_dist2(), want.last().map(|n| n.dist2));
            }
            for p in &mut o.pos {
                p[0] += step * (rng.random::<f32>() - 0.5);
                p[1] += step * (rng.random::<f32>() - 0.5);
                p[2] += 0.1 * step * (rng.random::<f32>() - 0.5);
            }
            index.refit(&o.set()).unwrap();
            let mut again = index.order();
            again.sort_unstable();
            assert_eq!(again, (0..n as u32).collect::<Vec<_>>());
        }
        o.pos = start;
    }
    // A refit with another photon count is refused.
    let mut index = SpatialIndex::build(&o.set(), Space::World).unwrap();
    o.pos.pop();
    o.params.truncate(2 * o.pos.len());
    assert!(index.refit(&o.set()).is_err());
}

/// The records per query a stage's pattern of queries scans (every photon in the index's
/// order, one reused buffer), each result checked against the scan for every 97th photon.
fn scanned_per_query(o: &Owned, index: &SpatialIndex, space: Space, k: usize, radius: Option<f32>) -> f64 {
    let set = o.set();
    let mut out = Neighbours::unordered(k);
    let order = index.order();
    for (j, &i) in order.iter().enumerate() {
        let q = set.query(i as usize, radius);
        index.knn(&q, k, &mut out);
        if j % 97 == 0 {
            let mut got = out.as_slice().to_vec();
            got.sort_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
            assert_eq!(got, brute_force_knn(&set, space, &q, k), "{space:?}, k {k}, photon {i}");
        }
    }
    out.records_scanned as f64 / order.len() as f64
}

/// Issue 31 item 5: photons that coincide (all at one point, two alternating points,
/// positions coinciding while parameters differ) cost a query about what an ordinary
/// neighbourhood costs, not a scan of the crowd; results stay exact. (Not covered: photons
/// that come to coincide after the build, through a refit. The tree's leaves then hold them
/// in no index order and a query scans about a third of the crowd; relaxation never moves
/// photons onto one point, and rebuilds its index every few iterations.)
#[test]
fn crowds_of_coincident_photons_cost_what_ordinary_neighbourhoods_cost() {
    let mut rng = Pcg64Mcg::seed_from_u64(31);
    let n = 6000;
    let spread = |rng: &mut Pcg64Mcg| -> Vec<f32> { (0..2 * n).map(|_| rng.random::<f32>()).collect() };
    let ordinary = Owned {
        pos: random_points(n, &mut rng),
        params: spread(&mut rng),
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    let one_point = Owned {
        pos: vec![[0.5, -2.0, 3.0]; n],
        params: vec![0.25; 2 * n],
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    let two_points = Owned {
        pos: (0..n).map(|i| if i % 2 == 0 { [1e3, 0.0, 0.0] } else { [-1e3, 0.0, 0.0] }).collect(),
        params: vec![0.25; 2 * n],
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    let same_place = Owned {
        pos: vec![[0.5, -2.0, 3.0]; n],
        params: spread(&mut rng),
        stride: 2,
        dims: vec![],
        emitters: None,
    };
    for (space, k, radius) in
        [(Space::World, 17, None), (Space::WorldParams, 17, Some(0.05)), (Space::WorldParams, 51, Some(0.1))]
    {
        let cost = |o: &Owned| {
            scanned_per_query(o, &SpatialIndex::build(&o.set(), space).unwrap(), space, k, radius)
        };
        let base = cost(&ordinary);
        for (what, o) in [("one point", &one_point), ("two points", &two_points), ("one place", &same_place)]
        {
            if what == "one place" && space == Space::World {
                continue; // the same set as "one point" in world space
            }
            let c = cost(o);
            eprintln!("{what}, {space:?}, k {k}: {c:.0} records per query, ordinary {base:.0}");
            assert!(
                c <= 3.0 * base + 4.0 * k as f64,
                "{what}, {space:?}, k {k}: {c:.0} records per query, ordinary {base:.0}"
            );
        }
    }
}

/// A parameter ball much wider than the neighbourhoods it restricts (relaxation's spectral
/// window: photons on a plane, a wavelength spread over ten ball radii): built with a split
/// scale, the trees return every query's neighbours exactly as the default build and brute
/// force do, and scan fewer records to find them.
#[test]
fn a_split_scale_changes_the_cost_and_not_the_neighbours() {
    let mut rng = Pcg64Mcg::seed_from_u64(32);
    let n = 50_000;
    // As on a prism's floor: the wavelength rises along x, over 3.7 radii at any one place.
    let pos: Vec<[f32; 3]> = (0..n).map(|_| [rng.random::<f32>(), 0.6 * rng.random::<f32>(), 0.0]).collect();
    let params = pos.iter().map(|x| 6.0 * x[0] + 3.7 * rng.random::<f32>()).collect();
    let o = Owned { pos, params, stride: 1, dims: vec![1], emitters: None };
    let (set, k) = (o.set(), 16);
    let default = SpatialIndex::build(&set, Space::WorldParams).unwrap();
    // The radius holding k photons of the plane.
    let scale = (0.6 * k as f32 / (std::f32::consts::PI * n as f32)).sqrt();
    let split = SpatialIndex::build_split(&set, Space::WorldParams, Some(scale)).unwrap();
    let (mut a, mut b) = (Neighbours::default(), Neighbours::default());
    for i in 0..n {
        let q = set.query(i, Some(1.0));
        default.knn(&q, k, &mut a);
        split.knn(&q, k, &mut b);
        assert_eq!(a.as_slice(), b.as_slice(), "photon {i}");
    }
    let cost = |index: &SpatialIndex| scanned_per_query(&o, index, Space::WorldParams, k, Some(1.0));
    let (by_default, by_split) = (cost(&default), cost(&split));
    // 143 against 225 when written; relaxation's cost per photon on the prism is in BENCHMARKS.md.
    assert!(by_split < 0.8 * by_default, "{by_split:.0} records per query against {by_default:.0}");
}

/// `ball_split_scale` against its closed form: photons every h along a line with balls of
/// radius r, some infinite or zero (left out of the median), give h·√(k/π)/r; no finite ball,
/// or no two photons apart, give none.
#[test]
fn the_ball_split_scale_is_the_k_radius_per_ball_radius() {
    let (n, h, r, k) = (10_000usize, 0.01f32, 0.25f32, 16usize);
    let pos: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 * h, 0.0, 0.0]).collect();
    let radii: Vec<f32> = (0..n).map(|i| [r, r, f32::INFINITY, 0.0, r][i % 5]).collect();
    let want = h * (k as f32 / std::f32::consts::PI).sqrt() / r;
    let got = ball_split_scale(&pos, &radii, k).expect("a scale");
    assert!((got - want).abs() <= 1e-3 * want, "{got} against {want}");
    assert_eq!(ball_split_scale(&pos, &[f32::INFINITY; 8], k), None);
    assert_eq!(ball_split_scale(&[[1.0, 2.0, 3.0]; 8], &radii, k), None);
}
