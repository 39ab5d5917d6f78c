//! A closed convex mesh as the intersection of the half-spaces behind its faces' planes.
//!
//! A ray meets such a body where it enters the last of the half-spaces or, starting inside,
//! where it leaves the first (the slab test of a box, for any convex polyhedron): one
//! division per plane and two extremes, with no triangle edges to test and no cracks between
//! triangles. The planes are tested eight at a time (AVX where the processor has it; the same
//! operations in the same order otherwise, so the same hits).

use glam::Vec3;

use crate::scene::shape::Ray;

/// Eight planes as rows nx, ny, nz, c (a point x is inside when n·x ≤ c). Unused lanes are
/// n = 0, c = 1: every ray runs parallel to them and inside, so they constrain nothing.
#[derive(Clone, Debug)]
#[repr(C, align(32))]
struct PlaneGroup {
    rows: [[f32; 8]; 4],
}

/// The half-spaces of a closed convex mesh ([`Hull::new`]).
#[derive(Clone, Debug)]
pub(crate) struct Hull {
    groups: Vec<PlaneGroup>,
    /// The unit outward normal of each plane, in lane order.
    normals: Vec<Vec3>,
}

impl Hull {
    /// The hull of a mesh given by its triangles and their unit outward normals, if the mesh
    /// is closed (every edge, by exact vertex positions, shared by exactly two triangles)
    /// and every normal is non-zero; `tol` is how far apart (in the plane offset) two
    /// triangles with the same normal may be and still share a plane. The caller has
    /// checked convexity (every vertex behind every triangle's plane).
    pub(crate) fn new(triangles: &[[Vec3; 3]], normals: &[Vec3], tol: f32) -> Option<Hull> {
        let key = |v: Vec3| v.to_array().map(f32::to_bits);
        let mut edges = std::collections::HashMap::new();
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
                *edges.entry(if a < b { (a, b) } else { (b, a) }).or_insert(0u32) += 1;
            }
        }
        if triangles.is_empty() || edges.values().any(|&n| n != 2) {
            return None;
        }
        let mut planes: Vec<(Vec3, f32)> = Vec::new();
        for (t, &n) in triangles.iter().zip(normals) {
            if n == Vec3::ZERO || !n.is_finite() {
                return None;
            }
            let c = n.dot(t[0]);
            if !planes.iter().any(|&(m, d)| m.dot(n) > 1.0 - 1e-6 && (d - c).abs() <= tol) {
                planes.push((n, c));
            }
        }
        let groups = planes
            .chunks(8)
            .map(|chunk| {
                let mut rows = [[0.0; 8], [0.0; 8], [0.0; 8], [1.0; 8]];
                for (lane, &(n, c)) in chunk.iter().enumerate() {
                    rows[0][lane] = n.x;
                    rows[1][lane] = n.y;
                    rows[2][lane] = n.z;
                    rows[3][lane] = c;
                }
                PlaneGroup { rows }
            })
            .collect();
        Some(Hull { groups, normals: planes.into_iter().map(|(n, _)| n).collect() })
    }

    /// Number of distinct face planes.
    #[cfg(test)]
    pub(crate) fn planes(&self) -> usize {
        self.normals.len()
    }

    /// The nearest point of the body's surface with `t` in (`t_min`, `t_max`): distance and
    /// the unit outward normal of the face there. Where faces meet at the same distance,
    /// the first plane's.
    #[inline(always)]
    pub(crate) fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32, avx: bool) -> Option<(f32, Vec3)> {
        #[cfg(target_arch = "x86_64")]
        let span = if avx {
            // SAFETY: `avx` says the processor has AVX.
            unsafe { self.span_avx(ray) }
        } else {
            self.span(ray)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let span = {
            let _ = avx;
            self.span(ray)
        };
        let Span { enter, enter_plane, exit, exit_plane } = span?;
        if enter > exit {
            return None;
        }
        // From outside, the entry; from inside (the entry behind t_min), the exit.
        let (t, plane) = if enter > t_min { (enter, enter_plane) } else { (exit, exit_plane) };
        (t > t_min && t < t_max).then(|| (t, self.normals[plane]))
    }

    /// The ray's parameter interval inside every half-space, with the planes that bound it;
    /// `None` when it runs parallel to a plane outside it.
    fn span(&self, ray: &Ray) -> Option<Span> {
        let mut s = Span::EVERYWHERE;
        for (g, group) in self.groups.iter().enumerate() {
            let [nx, ny, nz, c] = &group.rows;
            for lane in 0..8 {
                let denom = (nx[lane] * ray.dir.x + ny[lane] * ray.dir.y) + nz[lane] * ray.dir.z;
                let dist =
                    c[lane] - ((nx[lane] * ray.origin.x + ny[lane] * ray.origin.y) + nz[lane] * ray.origin.z);
                let t = dist / denom;
                if denom < 0.0 {
                    if t > s.enter {
                        (s.enter, s.enter_plane) = (t, g * 8 + lane);
                    }
                } else if denom > 0.0 {
                    if t < s.exit {
                        (s.exit, s.exit_plane) = (t, g * 8 + lane);
                    }
                } else if dist < 0.0 {
                    return None;
                }
            }
        }
        Some(s)
    }

    /// [`Hull::span`] eight planes at a time in AVX registers.
    ///
    /// # Safety
    /// The processor must have AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    #[inline]
    unsafe fn span_avx(&self, ray: &Ray) -> Option<Span> {
        use std::arch::x86_64::*;
        // Each component broadcast from its own place: a ray just written is not read back
        // as one wider load, which the processor could not forward from the narrower stores.
        let o = [
            _mm256_broadcast_ss(&ray.origin.x),
            _mm256_broadcast_ss(&ray.origin.y),
            _mm256_broadcast_ss(&ray.origin.z),
        ];
        let d = [
            _mm256_broadcast_ss(&ray.dir.x),
            _mm256_broadcast_ss(&ray.dir.y),
            _mm256_broadcast_ss(&ray.dir.z),
        ];
        let (mul, add) = (|x, y| _mm256_mul_ps(x, y), |x, y| _mm256_add_ps(x, y));
        let zero = _mm256_setzero_ps();
        let mut s = Span::EVERYWHERE;
        for (g, group) in self.groups.iter().enumerate() {
            // SAFETY: `PlaneGroup` is 32-byte aligned, so each row of eight f32 is.
            let row = |k: usize| unsafe { _mm256_load_ps(group.rows[k].as_ptr()) };
            let (nx, ny, nz) = (row(0), row(1), row(2));
            let denom = add(add(mul(nx, d[0]), mul(ny, d[1])), mul(nz, d[2]));
            let dist = _mm256_sub_ps(row(3), add(add(mul(nx, o[0]), mul(ny, o[1])), mul(nz, o[2])));
            let t = _mm256_div_ps(dist, denom);
            let entering = _mm256_cmp_ps::<_CMP_LT_OQ>(denom, zero);
            let exiting = _mm256_cmp_ps::<_CMP_GT_OQ>(denom, zero);
            let parallel_outside = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_EQ_OQ>(denom, zero),
                _mm256_cmp_ps::<_CMP_LT_OQ>(dist, zero),
            );
            if _mm256_movemask_ps(parallel_outside) != 0 {
                return None;
            }
            let t_enter = _mm256_blendv_ps(_mm256_set1_ps(f32::NEG_INFINITY), t, entering);
            let t_exit = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), t, exiting);
            let (hi, hi_lane) = extreme::<true>(t_enter);
            if hi > s.enter {
                (s.enter, s.enter_plane) = (hi, g * 8 + hi_lane);
            }
            let (lo, lo_lane) = extreme::<false>(t_exit);
            if lo < s.exit {
                (s.exit, s.exit_plane) = (lo, g * 8 + lo_lane);
            }
        }
        Some(s)
    }
}

/// The largest (`MAX`) or least lane value and the first lane holding it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
fn extreme<const MAX: bool>(v: std::arch::x86_64::__m256) -> (f32, usize) {
    use std::arch::x86_64::*;
    let pick = |a, b| if MAX { _mm256_max_ps(a, b) } else { _mm256_min_ps(a, b) };
    let m = pick(v, _mm256_permute_ps::<0b10_11_00_01>(v));
    let m = pick(m, _mm256_permute_ps::<0b01_00_11_10>(m));
    let m = pick(m, _mm256_permute2f128_ps::<1>(m, m));
    let lane = (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(v, m)) as u32 | 0x100).trailing_zeros();
    (_mm_cvtss_f32(_mm256_castps256_ps128(m)), lane as usize & 7)
}

/// A ray's parameter interval inside the body ([`Hull::span`]).
#[derive(Clone, Copy, Debug)]
struct Span {
    enter: f32,
    enter_plane: usize,
    exit: f32,
    exit_plane: usize,
}

impl Span {
    const EVERYWHERE: Span =
        Span { enter: f32::NEG_INFINITY, enter_plane: 0, exit: f32::INFINITY, exit_plane: 0 };
}
