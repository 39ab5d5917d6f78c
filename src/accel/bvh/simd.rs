//! The triangle tests, with the same operations in the same order on every lane so every one
//! rounds alike: one triangle ([`tri_intersect`]), a packet of four side by side, and, where the
//! processor has AVX, a pair of packets at once.

use glam::Vec4;

use super::Tri;
use crate::scene::shape::Ray;

/// Four triangles of a leaf side by side (each row entry as four lanes), tested at once by
/// [`packet_intersect`]. Lanes past the leaf's end hold zero rows, which nothing hits.
#[derive(Clone, Copy, Debug)]
pub(super) struct Packet {
    rows: [[Vec4; 4]; 3],
}

impl Packet {
    pub(super) fn new(tris: &[Tri]) -> Packet {
        let lane = |r: usize, k: usize| {
            Vec4::from_array(std::array::from_fn(|l| tris.get(l).map_or(0.0, |t| t.rows[r][k])))
        };
        Packet { rows: std::array::from_fn(|r| std::array::from_fn(|k| lane(r, k))) }
    }
}

/// Two packets' rows side by side, lanes 0–3 the first packet's and 4–7 the second's: what
/// [`packet_pair_intersect`] loads into AVX registers as they are.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct PacketPair {
    rows: [[[f32; 8]; 4]; 3],
}

impl PacketPair {
    pub(super) fn new(a: &Packet, b: &Packet) -> PacketPair {
        let side_by_side = |r: usize, k: usize| {
            let (a, b) = (a.rows[r][k].to_array(), b.rows[r][k].to_array());
            std::array::from_fn(|l| if l < 4 { a[l] } else { b[l - 4] })
        };
        PacketPair { rows: std::array::from_fn(|r| std::array::from_fn(|k| side_by_side(r, k))) }
    }
}

/// A ray's origin and direction, each coordinate repeated in four lanes.
pub(super) struct RayLanes {
    o: [Vec4; 3],
    d: [Vec4; 3],
}

impl RayLanes {
    #[inline(always)]
    pub(super) fn new(ray: &Ray) -> RayLanes {
        RayLanes {
            o: [Vec4::splat(ray.origin.x), Vec4::splat(ray.origin.y), Vec4::splat(ray.origin.z)],
            d: [Vec4::splat(ray.dir.x), Vec4::splat(ray.dir.y), Vec4::splat(ray.dir.z)],
        }
    }
}

/// Ray–triangle intersection in the triangle's frame ([`Tri`]): (t, b1, b2), two-sided.
#[inline(always)]
pub(super) fn tri_intersect(tri: &Tri, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
    let (o, d) = (ray.origin, ray.dir);
    let point = |r: &[f32; 4]| r[0] * o.x + r[1] * o.y + r[2] * o.z + r[3];
    let dir = |r: &[f32; 4]| r[0] * d.x + r[1] * d.y + r[2] * d.z;
    let [rx, ry, rz] = &tri.rows;
    let t = -(point(rz) / dir(rz));
    if !(t > t_min && t < t_max) {
        return None;
    }
    let b1 = point(rx) + t * dir(rx);
    let b2 = point(ry) + t * dir(ry);
    (b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0).then_some((t, b1, b2))
}

/// [`tri_intersect`] on the four triangles of a packet at once, with the same operations in
/// the same order on each lane, so the same roundings: the nearest hit with `t` in (`t_min`,
/// `t_max`) as (lane, t, b1, b2), the first lane of the packet among equally near ones (as
/// testing the triangles in turn would find).
#[inline(always)]
pub(super) fn packet_intersect(
    p: &Packet,
    r: &RayLanes,
    t_min: f32,
    t_max: f32,
) -> Option<(usize, f32, f32, f32)> {
    let point = |w: &[Vec4; 4]| w[0] * r.o[0] + w[1] * r.o[1] + w[2] * r.o[2] + w[3];
    let dir = |w: &[Vec4; 4]| w[0] * r.d[0] + w[1] * r.d[1] + w[2] * r.d[2];
    let [rx, ry, rz] = &p.rows;
    let t = -(point(rz) / dir(rz));
    // NaN (a degenerate or padding lane, a ray in the plane) fails both comparisons.
    let in_range = t.cmpgt(Vec4::splat(t_min)) & t.cmplt(Vec4::splat(t_max));
    if in_range.bitmask() == 0 {
        return None;
    }
    let b1 = point(rx) + t * dir(rx);
    let b2 = point(ry) + t * dir(ry);
    let hit = in_range & b1.cmpge(Vec4::ZERO) & b2.cmpge(Vec4::ZERO) & (b1 + b2).cmple(Vec4::ONE);
    let mask = hit.bitmask();
    if mask == 0 {
        return None;
    }
    let (t, b1, b2) = (t.to_array(), b1.to_array(), b2.to_array());
    let mut best: Option<usize> = None;
    for lane in 0..4 {
        if mask & (1 << lane) != 0 && best.is_none_or(|b| t[lane] < t[b]) {
            best = Some(lane);
        }
    }
    best.map(|k| (k, t[k], b1[k], b2[k]))
}

/// Whether [`packet_pair_intersect`] may run: the processor has AVX.
pub(crate) fn avx_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`packet_intersect`] on two packets (eight triangles) at once, in the 256-bit registers of
/// AVX: the same operations in the same order on each lane (no fused multiply-add), so the
/// same roundings; lanes 4–7 are the second packet's, and the nearest hit, the first lane
/// among equally near ones, is what testing the first packet and then the second with the
/// first's hit as `t_max` finds.
///
/// # Safety
/// The processor must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn packet_pair_intersect(
    pair: &PacketPair,
    ray: &Ray,
    t_min: f32,
    t_max: f32,
) -> Option<(usize, f32, f32, f32)> {
    use std::arch::x86_64::*;
    // SAFETY: `PacketPair` is 32-byte aligned, so each row of eight f32 is.
    let row = |k: usize, e: usize| unsafe { _mm256_load_ps(pair.rows[k][e].as_ptr()) };
    let o = [_mm256_set1_ps(ray.origin.x), _mm256_set1_ps(ray.origin.y), _mm256_set1_ps(ray.origin.z)];
    let d = [_mm256_set1_ps(ray.dir.x), _mm256_set1_ps(ray.dir.y), _mm256_set1_ps(ray.dir.z)];
    let (mul, add) = (|x, y| _mm256_mul_ps(x, y), |x, y| _mm256_add_ps(x, y));
    let point =
        |k: usize| add(add(add(mul(row(k, 0), o[0]), mul(row(k, 1), o[1])), mul(row(k, 2), o[2])), row(k, 3));
    let dir = |k: usize| add(add(mul(row(k, 0), d[0]), mul(row(k, 1), d[1])), mul(row(k, 2), d[2]));
    let t = _mm256_xor_ps(_mm256_div_ps(point(2), dir(2)), _mm256_set1_ps(-0.0));
    let in_range = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(t, _mm256_set1_ps(t_min)),
        _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_set1_ps(t_max)),
    );
    if _mm256_movemask_ps(in_range) == 0 {
        return None;
    }
    let b1 = add(point(0), mul(t, dir(0)));
    let b2 = add(point(1), mul(t, dir(1)));
    let zero = _mm256_setzero_ps();
    let hit = _mm256_and_ps(
        _mm256_and_ps(in_range, _mm256_cmp_ps::<_CMP_GE_OQ>(b1, zero)),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(b2, zero),
            _mm256_cmp_ps::<_CMP_LE_OQ>(add(b1, b2), _mm256_set1_ps(1.0)),
        ),
    );
    let mask = _mm256_movemask_ps(hit);
    if mask == 0 {
        return None;
    }
    // The nearest hit lane, the first among equally near ones: the only one, or the least t
    // over the hit lanes (the others +∞; a hit lane's t is finite), then the lowest lane
    // holding it.
    let k = if mask.count_ones() == 1 {
        mask.trailing_zeros() as usize
    } else {
        let th = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), t, hit);
        let m = _mm256_min_ps(th, _mm256_permute_ps::<0b10_11_00_01>(th));
        let m = _mm256_min_ps(m, _mm256_permute_ps::<0b01_00_11_10>(m));
        let m = _mm256_min_ps(m, _mm256_permute2f128_ps::<1>(m, m));
        (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(th, m)) & mask).trailing_zeros() as usize
    };
    let lanes = |v: __m256| {
        let mut out = [0f32; 8];
        // SAFETY: `out` holds eight f32.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    };
    Some((k, lanes(t)[k], lanes(b1)[k], lanes(b2)[k]))
}
