//! The hierarchy against brute force on random triangles, and each triangle test against the
//! scalar one bit for bit.

use std::mem::MaybeUninit;

#[cfg(target_arch = "x86_64")]
use super::simd::packet_pair_intersect;
use super::simd::{RayLanes, packet_intersect};
use super::traverse::{Slabs, still_ahead};
use super::*;
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn v(rng: &mut Pcg64Mcg, s: f32) -> Vec3 {
    Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5) * s
}

#[test]
fn triangle_hit_matches_closed_form() {
    let t = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(2.0, 0.0, 1.0), Vec3::new(0.0, 2.0, 1.0)];
    let ray = Ray::new(Vec3::new(0.5, 0.25, 3.0), Vec3::NEG_Z);
    let h = brute_force(&[t], &ray, 0.0, f32::INFINITY).unwrap();
    assert!((h.t - 2.0).abs() < 1e-6);
    assert!((h.b1 - 0.25).abs() < 1e-6 && (h.b2 - 0.125).abs() < 1e-6);
    let miss = Ray::new(Vec3::new(1.5, 1.5, 3.0), Vec3::NEG_Z);
    assert!(brute_force(&[t], &miss, 0.0, f32::INFINITY).is_none());
}

/// `n` random triangles about the origin; now and then a degenerate one, or a copy of the
/// previous one (equal t: the first lane must win, as the first tested does).
fn random_leaf(rng: &mut Pcg64Mcg, n: usize) -> Vec<Tri> {
    let mut tris: Vec<Tri> = Vec::new();
    for _ in 0..n {
        let c = v(rng, 1.0);
        let tri = match (rng.random::<u32>() % 8, tris.last()) {
            (0, _) => Tri::new(c, c, c + v(rng, 1.0)),
            (1, Some(&prev)) => prev,
            _ => Tri::new(c, c + v(rng, 1.0), c + v(rng, 1.0)),
        };
        tris.push(tri);
    }
    tris
}

/// A random ray towards the origin's neighbourhood and a `t_max` (∞ or 3).
fn random_ray(rng: &mut Pcg64Mcg) -> (Ray, f32) {
    let o = v(rng, 4.0);
    let ray = Ray::new(o, (v(rng, 0.5) - o).normalize());
    (ray, if rng.random::<bool>() { f32::INFINITY } else { 3.0 })
}

/// The scalar test on each triangle in turn, as (triangle, t, b1, b2) bits.
fn scalar_nearest(tris: &[Tri], ray: &Ray, t_max: f32) -> Option<(usize, u32, u32, u32)> {
    let mut want = None;
    let mut t_best = t_max;
    for (k, tri) in tris.iter().enumerate() {
        if let Some((t, b1, b2)) = tri_intersect(tri, ray, 1e-4, t_best) {
            t_best = t;
            want = Some((k, t, b1, b2));
        }
    }
    bits(want)
}

fn bits(h: Option<(usize, f32, f32, f32)>) -> Option<(usize, u32, u32, u32)> {
    h.map(|(k, t, b1, b2)| (k, t.to_bits(), b1.to_bits(), b2.to_bits()))
}

#[test]
fn packet_test_equals_the_scalar_test_bit_for_bit() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut hits = 0;
    for _ in 0..20_000 {
        let n = 1 + (rng.random::<u32>() % 4) as usize;
        let tris = random_leaf(&mut rng, n);
        let (ray, t_max) = random_ray(&mut rng);
        let want = scalar_nearest(&tris, &ray, t_max);
        let got = packet_intersect(&Packet::new(&tris), &RayLanes::new(&ray), 1e-4, t_max);
        assert_eq!(bits(got), want, "{tris:?} {ray:?}");
        hits += want.is_some() as u32;
    }
    assert!(hits > 1000, "{hits}");
}

/// The AVX test of two packets finds what the scalar test of the eight triangles in turn
/// finds, bit for bit (ties between equal triangles included); skipped without AVX.
#[cfg(target_arch = "x86_64")]
#[test]
fn packet_pair_test_equals_the_scalar_test_bit_for_bit() {
    if !std::arch::is_x86_feature_detected!("avx") {
        eprintln!("no AVX: packet_pair_intersect not tested");
        return;
    }
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut hits = [0u32; 2];
    for _ in 0..20_000 {
        let n = 5 + (rng.random::<u32>() % 4) as usize;
        let tris = random_leaf(&mut rng, n);
        let (ray, t_max) = random_ray(&mut rng);
        let want = scalar_nearest(&tris, &ray, t_max);
        let pair = PacketPair::new(&Packet::new(&tris[..4]), &Packet::new(&tris[4..]));
        // SAFETY: AVX was detected above.
        let got = unsafe { packet_pair_intersect(&pair, &ray, 1e-4, t_max) };
        assert_eq!(bits(got), want, "{tris:?} {ray:?}");
        if let Some((k, ..)) = want {
            hits[(k >= 4) as usize] += 1;
        }
    }
    assert!(hits[0] > 1000 && hits[1] > 1000, "hits in the first and second packet: {hits:?}");
}

#[test]
fn bvh_equals_brute_force_on_random_triangles() {
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    // (count, spread of the centres): 5 to 8 overlapping triangles make one root leaf of
    // two packets (as the prism's), tested by a path of its own.
    for &(n, spread) in &[(1usize, 4.0), (3, 4.0), (5, 0.0), (8, 0.0), (8, 4.0), (40, 4.0), (2000, 4.0)] {
        let tris: Vec<[Vec3; 3]> = (0..n)
            .map(|_| {
                let c = v(&mut rng, spread);
                [c + v(&mut rng, 0.6), c + v(&mut rng, 0.6), c + v(&mut rng, 0.6)]
            })
            .collect();
        // With pairs where the processor has AVX, and the portable layout.
        let bvh = Bvh::build(&tris);
        let portable = Bvh::build_for(&tris, false);
        if spread == 0.0 {
            assert_eq!(bvh.root_leaf.map(|(_, c)| c as usize), Some(n), "one leaf");
        }
        let mut hits = 0;
        for k in 0..3000 {
            let o = v(&mut rng, 10.0);
            // Every other ray aimed near a triangle, so small sets are hit too.
            let [p, q, r] = tris[k % n];
            let target = if k % 2 == 0 { (p + q + r) / 3.0 + v(&mut rng, 0.1) } else { v(&mut rng, 3.0) };
            let ray = Ray::new(o, (target - o).normalize());
            let (a, b) =
                (bvh.intersect(&ray, 1e-4, f32::INFINITY), brute_force(&tris, &ray, 1e-4, f32::INFINITY));
            // The packet tests equal the scalar test bit for bit: the same triangle, the same t.
            assert_eq!(a, b, "n = {n}: {ray:?}");
            assert_eq!(portable.intersect(&ray, 1e-4, f32::INFINITY), b, "n = {n}, portable: {ray:?}");
            hits += a.is_some() as u32;
        }
        assert!(hits > 300, "n = {n}: {hits} hits are too few to test anything");
    }
}

/// A ray that hits a triangle at t (the leaf test's value) enters the triangle's own box
/// within t and passes the stack's test against t, so the traversal never skips the box of
/// the nearest hit. Half the triangles lie in a plane z = const (a flat box, entered where
/// the triangle is hit), the others anywhere.
#[test]
fn a_box_is_entered_wherever_its_triangle_is_hit() {
    let mut rng = Pcg64Mcg::seed_from_u64(13);
    let mut hits = 0;
    for k in 0..200_000 {
        let c = v(&mut rng, 8.0);
        let mut tri = [c + v(&mut rng, 1.0), c + v(&mut rng, 1.0), c + v(&mut rng, 1.0)];
        if k % 2 == 0 {
            tri.iter_mut().for_each(|p| p.z = c.z);
        }
        let (b1, b2) = (rng.random::<f32>(), rng.random::<f32>());
        let (b1, b2) = if b1 + b2 > 1.0 { (1.0 - b1, 1.0 - b2) } else { (b1, b2) };
        let target = tri[0] + (tri[1] - tri[0]) * b1 + (tri[2] - tri[0]) * b2;
        let o = v(&mut rng, 30.0);
        let ray = Ray::new(o, (target - o).normalize());
        // Not at grazing incidence (within about a degree of the plane), where the
        // triangle's own t carries an error beyond the margin (see `SLAB_SLACK`).
        let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
        if normal.dot(ray.dir).abs() < 0.02 {
            continue;
        }
        let Some((t, _, _)) = tri_intersect(&Tri::new(tri[0], tri[1], tri[2]), &ray, 0.0, f32::INFINITY)
        else {
            continue;
        };
        let (lo, hi) = (tri[0].min(tri[1]).min(tri[2]), tri[0].max(tri[1]).max(tri[2]));
        let mut node = Node4 { bounds: [Vec4::ZERO; 6], child: [0; 4], count: [1, 0, 0, 0], used: 1 };
        for axis in 0..3 {
            node.bounds[axis][0] = lo[axis];
            node.bounds[3 + axis][0] = hi[axis];
        }
        let (near, mask) = Slabs::new(&ray).enter4(&node, 0.0, t);
        assert_eq!(mask, 1, "box not entered within t = {t}: {tri:?} {ray:?}");
        assert!(still_ahead(near.x, t), "entered at {} after the hit at {t}: {tri:?} {ray:?}", near.x);
        hits += 1;
    }
    assert!(hits > 100_000, "{hits}");
}

/// The traversal never has more children pending than `stack_need` (three per level): run
/// with a stack of exactly that many entries (on the heap, as for a tree deeper than the
/// inline stack allows), a push past it would panic; and the hits equal brute force.
#[test]
fn the_traversal_stack_bound_holds() {
    let mut rng = Pcg64Mcg::seed_from_u64(17);
    for n in [40usize, 3000] {
        let tris: Vec<[Vec3; 3]> = (0..n)
            .map(|_| {
                let c = v(&mut rng, 4.0);
                [c + v(&mut rng, 0.6), c + v(&mut rng, 0.6), c + v(&mut rng, 0.6)]
            })
            .collect();
        let bvh = Bvh::build(&tris);
        assert!(bvh.stack_need >= 3 && bvh.stack_need.is_multiple_of(3), "{}", bvh.stack_need);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = v(&mut rng, 10.0);
            let ray = Ray::new(o, (v(&mut rng, 3.0) - o).normalize());
            let mut stack = vec![MaybeUninit::uninit(); bvh.stack_need];
            let a = bvh.traverse_with(&mut stack, &ray, 1e-4, f32::INFINITY);
            assert_eq!(a, brute_force(&tris, &ray, 1e-4, f32::INFINITY), "n = {n}: {ray:?}");
            hits += a.is_some() as u32;
        }
        assert!(hits > 150, "n = {n}: {hits}");
    }
}

/// The single-box test: entry distance, misses, and rays parallel to a slab lying in a
/// bound's plane (with +0 and −0 direction components), inside and just outside.
#[test]
fn ray_box_enters_where_a_closed_box_is_met() {
    let (lo, hi) = (Vec3::ZERO, Vec3::ONE);
    let hit = |o: Vec3, d: Vec3| ray_box(lo, hi, o, d.recip(), 0.0, f32::INFINITY);
    assert_eq!(hit(Vec3::new(0.5, 0.5, 5.0), Vec3::NEG_Z), Some(4.0));
    assert_eq!(hit(Vec3::new(0.5, 0.5, 5.0), Vec3::Z), None);
    assert_eq!(hit(Vec3::new(0.5, 0.5, 0.5), Vec3::Z), Some(0.0));
    for x in [0.0, 1.0] {
        for sign in [0.0f32, -0.0] {
            for (y, want) in [(0.0, Some(4.0)), (0.5, Some(4.0)), (1.0, Some(4.0)), (1.0001, None)] {
                let (o, d) = (Vec3::new(x, y, 5.0), Vec3::new(sign, sign, -1.0));
                assert_eq!(hit(o, d), want, "{o:?} {d:?}");
            }
        }
    }
}

#[test]
fn bvh_handles_axis_aligned_rays_and_coincident_centroids() {
    // A grid of floor triangles hit by rays straight down (zero direction components).
    let mut tris = Vec::new();
    for i in 0..20 {
        for j in 0..20 {
            let p = Vec3::new(i as f32, j as f32, 0.0);
            tris.push([p, p + Vec3::X, p + Vec3::Y]);
            tris.push([p + Vec3::X, p + Vec3::X + Vec3::Y, p + Vec3::Y]);
        }
    }
    // Many copies of one triangle: centroids coincide, the build must still terminate.
    tris.extend(std::iter::repeat_n(
        [Vec3::splat(30.0), Vec3::new(31.0, 30.0, 30.0), Vec3::new(30.0, 31.0, 30.0)],
        50,
    ));
    let bvh = Bvh::build(&tris);
    for k in 0..200 {
        let ray = Ray::new(Vec3::new(0.05 + k as f32 * 0.097, 0.03 + k as f32 * 0.093, 5.0), Vec3::NEG_Z);
        let (a, b) = (bvh.intersect(&ray, 0.0, f32::INFINITY), brute_force(&tris, &ray, 0.0, f32::INFINITY));
        assert_eq!(a.map(|h| h.t), b.map(|h| h.t));
        assert!(a.is_some());
    }
    let ray = Ray::new(Vec3::new(30.2, 30.2, 40.0), Vec3::NEG_Z);
    assert!((bvh.intersect(&ray, 0.0, f32::INFINITY).unwrap().t - 10.0).abs() < 1e-5);
    // Rays parallel to the x slabs lying exactly in a box's bound plane (x = 0, the grid's
    // left edge; 7, between columns; 20, its right edge), with +0 and −0 as x direction:
    // the triangles' edges there are hit exactly (their frames are exact), so each such
    // ray hits, and the boxes must let it through on either side.
    for x in [0.0, 7.0, 20.0] {
        for sign in [0.0f32, -0.0] {
            for j in 0..20 {
                let ray = Ray { origin: Vec3::new(x, j as f32 + 0.5, 5.0), dir: Vec3::new(sign, 0.0, -1.0) };
                let (a, b) =
                    (bvh.intersect(&ray, 0.0, f32::INFINITY), brute_force(&tris, &ray, 0.0, f32::INFINITY));
                assert!(b.is_some(), "{ray:?}");
                assert_eq!(a.map(|h| h.t), b.map(|h| h.t), "{ray:?}");
            }
        }
    }
}
