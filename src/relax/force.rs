//! The force on one photon: repulsion from its neighbours (Eq. 8), projected onto its
//! constraint basis (Eq. 9) or its tangent plane, and the step it is allowed to take.

use glam::Vec3;

/// Eq. 8: repulsion force on a photon at `xi` from its Kf nearest neighbours, where `r_k` is
/// the distance to the Kf-th. A neighbour at distance d pushes with magnitude ≈ r_K − d, so the
/// force vanishes when the neighbours sit evenly on the circle of radius r_K. A coincident
/// neighbour has no direction and adds nothing ([`iterate`](super::iterate) separates
/// coincident photons).
pub fn repulsion(xi: Vec3, neighbours: &[Vec3], r_k: f32, epsilon: f32) -> Vec3 {
    if neighbours.is_empty() || r_k <= 0.0 {
        return Vec3::ZERO;
    }
    let eps = epsilon * r_k;
    let sum: Vec3 = neighbours
        .iter()
        .map(|&xj| {
            let d = xi - xj;
            let l = d.length();
            if l > 0.0 { d * (r_k / (l + eps) - 1.0) } else { Vec3::ZERO }
        })
        .sum();
    sum / neighbours.len() as f32
}

/// Eq. 9: the force projected onto the constraint basis, f_b = û_b (u_b·f) + v̂_b (v_b·f).
/// `v_b` carries its factor (Eq. 7) in its length, so motion along P2 is scaled once.
pub fn project_on_basis(f: Vec3, u_b: Vec3, v_b: Vec3) -> Vec3 {
    let along = |b: Vec3| b.try_normalize().map_or(Vec3::ZERO, |bh| bh * b.dot(f));
    along(u_b) + along(v_b)
}

/// The force without constraints: its component in the tangent plane of the unit normal `n`.
pub fn project_on_tangent(f: Vec3, n: Vec3) -> Vec3 {
    f - n * n.dot(f)
}

/// Shortens `step` to at most `limit`.
pub fn clamp_step(step: Vec3, limit: f32) -> Vec3 {
    let l = step.length();
    if l > limit && l > 0.0 { step * (limit / l) } else { step }
}

/// A unit vector that depends only on `i` (a SplitMix64 hash mapped to the sphere).
pub(super) fn nudge(i: usize) -> Vec3 {
    let mut z = (i as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    let a = (z >> 40) as f32 / (1u64 << 24) as f32;
    let b = (z & 0xFF_FFFF) as f32 / (1u64 << 24) as f32;
    let cz = 2.0 * a - 1.0;
    let (s, c) = (std::f32::consts::TAU * b).sin_cos();
    let r = (1.0 - cz * cz).max(0.0).sqrt();
    Vec3::new(r * c, r * s, cz)
}
