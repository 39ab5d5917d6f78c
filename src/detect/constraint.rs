//! One photon's constraint from its neighbourhood (Eq. 2–7): the closed-form 2×2 eigen-
//! decomposition, the noise filter and its factor, PCA in the tangent plane, and the 2009
//! gradient baseline.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};
use serde::Serialize;

use super::NoiseModel;

/// Eigen-decomposition of the symmetric 2×2 matrix [[a, b], [b, c]].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eigen2 {
    /// The larger eigenvalue λ1.
    pub lambda1: f64,
    /// The smaller eigenvalue λ2 (≤ λ1).
    pub lambda2: f64,
    /// Unit eigenvector of λ1.
    pub p1: [f64; 2],
    /// Unit eigenvector of λ2: P1 turned by +90°.
    pub p2: [f64; 2],
}

/// Closed-form eigen-decomposition of [[a, b], [b, c]] (Eq. 2–7's PCA): λ = m ± d with
/// m = (a + c)/2 and d = √(h² + b²), h = (a − c)/2. P1 lies at half the angle φ of (h, b),
/// the direction of (h + d, b) — or, where h < 0 would make h + d cancel, of (b, d − h) —
/// by the half-angle identity tan(φ/2) = b/(d + h) = (d − h)/b: no trigonometric function and
/// no cancellation. P1 is taken with a non-negative first component (angle in (−90°, 90°]).
/// λ1 ≥ λ2; for a covariance λ2 is clamped at 0 against rounding. An isotropic matrix gives
/// P1 = (1, 0).
pub fn eigen2(a: f64, b: f64, c: f64) -> Eigen2 {
    let h = 0.5 * (a - c);
    let m = 0.5 * (a + c);
    let d = (h * h + b * b).sqrt();
    // Squares beyond f64's range (|h| or |b| ≳ 1e154): the slower, overflow-free form.
    let d = if d.is_finite() { d } else { h.hypot(b) };
    let (x, y) = if h >= 0.0 { (h + d, b) } else { (b, d - h) };
    let len = (x * x + y * y).sqrt();
    let len = if len.is_finite() { len } else { x.hypot(y) };
    let [co, s] = if len > 0.0 && len.is_finite() {
        let sign = if x < 0.0 { -1.0 } else { 1.0 };
        [sign * x / len, sign * y / len]
    } else {
        [1.0, 0.0]
    };
    Eigen2 { lambda1: m + d, lambda2: (m - d).max(0.0), p1: [co, s], p2: [-s, co] }
}

/// The error function, |error| < 1.2·10⁻⁷ (the Chebyshev fit of erfc in Numerical Recipes,
/// 2nd ed., §6.2): ample for Eq. 6, whose output is stored as f32.
pub fn erf(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * poly.exp();
    if x >= 0.0 { 1.0 - erfc } else { erfc - 1.0 }
}

/// Lower end of the clamp on λ2 before Eq. 2 and 6: 1/4 − 16/(9π²), where Eq. 7's factor
/// reaches 0 (the photon on the edge of a maximal discontinuity).
pub const LAMBDA2_MIN: f64 = 0.25 - 16.0 / (9.0 * PI * PI);

/// Eq. 2: the migration pressure M(λ2) = sqrt(1/4 − λ2).
pub fn migration(lambda2: f64) -> f64 {
    (0.25 - lambda2).max(0.0).sqrt()
}

/// Eq. 6: Φ(λ2) = ½·[1 − erf((λ2 − μ)/sqrt(2σ²))], the probability that λ2 is not explained
/// by the noise of an isotropic neighbourhood.
pub fn noise_filter(lambda2: f64, mu: f64, sigma: f64) -> f64 {
    if sigma > 0.0 {
        0.5 * (1.0 - erf((lambda2 - mu) / (2.0 * sigma * sigma).sqrt()))
    } else if lambda2 < mu {
        1.0
    } else {
        0.0
    }
}

/// Eq. 7's factor on v_b, 1 − (3π/4)·M(λ2)·Φ(λ2), with λ2 (normalised by r²) first clamped to
/// [[`LAMBDA2_MIN`], 1/4]; it lies in [0, 1]: 0 holds the photon on its line, 1 frees it.
pub fn v_factor(lambda2: f64, mu: f64, sigma: f64) -> f64 {
    let l = if lambda2.is_nan() { 0.25 } else { lambda2.clamp(LAMBDA2_MIN, 0.25) };
    (1.0 - 0.75 * PI * migration(l) * noise_filter(l, mu, sigma)).clamp(0.0, 1.0)
}

/// An orthonormal basis (t1, t2) of the plane orthogonal to the unit vector `n`, continuous
/// except where n.z changes sign (Duff et al. 2017, "Building an orthonormal basis, revisited").
pub fn tangent_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), DVec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// The unit normal from a stored normal of any length; `None` if it is zero or not finite.
pub(super) fn unit_normal(n: [f32; 3]) -> Option<DVec3> {
    DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64).try_normalize()
}

/// The direction of least spread of a neighbourhood (offsets from the photon): the normal of
/// a photon whose stored normal is unusable. +z when the offsets span no plane.
fn estimated_normal(offsets: &[DVec3]) -> DVec3 {
    let m = offsets.len().max(1) as f64;
    let mean = offsets.iter().sum::<DVec3>() / m;
    let mut c = nalgebra::Matrix3::<f64>::zeros();
    for o in offsets {
        let d = *o - mean;
        let v = nalgebra::Vector3::new(d.x, d.y, d.z);
        c += v * v.transpose();
    }
    if c.trace() <= 0.0 || !c.trace().is_finite() {
        return DVec3::Z;
    }
    let e = nalgebra::SymmetricEigen::new(c / c.trace());
    let k = e.eigenvalues.imin();
    let v = e.eigenvectors.column(k);
    DVec3::new(v[0], v[1], v[2]).try_normalize().unwrap_or(DVec3::Z)
}

/// How a photon's constraint was decided.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Computed from the neighbourhood.
    Measured,
    /// Fewer than 3 neighbours: free.
    TooFew,
    /// No extent in the tangent plane (r = 0 or all offsets along the normal): free.
    Coincident,
    /// Method `none`: free.
    #[default]
    Unconstrained,
}

impl Outcome {
    /// The outcome as one byte (a tile part's `detect_outcome` column): 0 measured, 1 too few,
    /// 2 coincident, 3 unconstrained.
    pub fn code(self) -> u8 {
        match self {
            Outcome::Measured => 0,
            Outcome::TooFew => 1,
            Outcome::Coincident => 2,
            Outcome::Unconstrained => 3,
        }
    }

    /// The outcome of [`Self::code`] `c`, `None` for a byte that is none.
    pub fn from_code(c: u8) -> Option<Outcome> {
        [Outcome::Measured, Outcome::TooFew, Outcome::Coincident, Outcome::Unconstrained]
            .get(c as usize)
            .copied()
    }
}

/// One photon's constraint (Eq. 7), in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotonConstraint {
    /// u_b: unit, along the structure.
    pub u: [f32; 3],
    /// v_b: unit direction times [`Self::factor`].
    pub v: [f32; 3],
    /// λ2 normalised by r² (not clamped); 1/4 when not measured.
    pub lambda2: f32,
    /// The factor on v_b, in [0, 1].
    pub factor: f32,
    /// How it was decided.
    pub outcome: Outcome,
}

impl PhotonConstraint {
    /// Free motion in the plane of (t1, t2).
    pub(super) fn free(t1: DVec3, t2: DVec3, outcome: Outcome) -> Self {
        PhotonConstraint {
            u: t1.as_vec3().into(),
            v: t2.as_vec3().into(),
            lambda2: 0.25,
            factor: 1.0,
            outcome,
        }
    }
}

/// A photon's neighbourhood as the kernels read it: offsets x_j − x_i (i itself included,
/// at zero), r² the squared world distance to the farthest, and the photon's stored normal.
pub struct Neighbourhood<'a> {
    /// x_j − x_i for each neighbour j, metres.
    pub offsets: &'a [DVec3],
    /// r²: the squared distance to the farthest neighbour, m².
    pub r2: f64,
    /// The photon's stored normal, if any (any non-zero length).
    pub normal: Option<[f32; 3]>,
}

impl Neighbourhood<'_> {
    /// The unit normal and tangent basis: from the stored normal, else estimated.
    pub(super) fn frame(&self) -> (DVec3, DVec3, DVec3) {
        let n = self.normal.and_then(unit_normal).unwrap_or_else(|| estimated_normal(self.offsets));
        let (t1, t2) = tangent_basis(n);
        (n, t1, t2)
    }

    /// Offsets in the tangent plane, written into `out`.
    fn project(&self, t1: DVec3, t2: DVec3, out: &mut Vec<DVec2>) {
        out.clear();
        out.extend(self.offsets.iter().map(|o| DVec2::new(o.dot(t1), o.dot(t2))));
    }
}

/// Normalised PCA of the offsets projected into the tangent plane (t1, t2): the eigen-
/// decomposition with λ divided by `r2`, or `None` if the points have no extent relative to
/// r. The covariance of the projected points is Tᵀ C T for the offsets' 3×3 covariance C and
/// T = [t1 t2], so C is summed in one pass over the offsets (as Σ o oᵀ − m·ō ōᵀ: every offset
/// lies within r of the photon, so what the subtraction cancels is at most about 1e-16 r²,
/// far below the 1e-12 r² under which a neighbourhood counts as having no extent) and
/// projected once.
fn normalised_pca(offsets: &[DVec3], t1: DVec3, t2: DVec3, r2: f64) -> Option<Eigen2> {
    let m = offsets.len() as f64;
    let mut sum = DVec3::ZERO;
    // The upper triangle of Σ o oᵀ: xx, xy, xz, yy, yz, zz.
    let mut c = [0.0f64; 6];
    for o in offsets {
        sum += *o;
        c[0] += o.x * o.x;
        c[1] += o.x * o.y;
        c[2] += o.x * o.z;
        c[3] += o.y * o.y;
        c[4] += o.y * o.z;
        c[5] += o.z * o.z;
    }
    let mean = sum / m;
    c[0] -= sum.x * mean.x;
    c[1] -= sum.x * mean.y;
    c[2] -= sum.x * mean.z;
    c[3] -= sum.y * mean.y;
    c[4] -= sum.y * mean.z;
    c[5] -= sum.z * mean.z;
    let times = |v: DVec3| {
        DVec3::new(
            c[0] * v.x + c[1] * v.y + c[2] * v.z,
            c[1] * v.x + c[3] * v.y + c[4] * v.z,
            c[2] * v.x + c[4] * v.y + c[5] * v.z,
        )
    };
    let (ct1, ct2) = (times(t1), times(t2));
    // Normalised by r² once, not each offset by r (a division per offset).
    let norm = m * r2;
    let e = eigen2(t1.dot(ct1) / norm, t1.dot(ct2) / norm, t2.dot(ct2) / norm);
    // Relative to r², an extent below 1e-12 is rounding of offsets along the normal.
    (e.lambda1 > 1e-12 && e.lambda1.is_finite()).then_some(e)
}

/// The tangent basis (t1, t2) and the normalised PCA of the neighbourhood projected into it,
/// or the free constraint of a degenerate neighbourhood (module docs).
fn tangent_pca(nb: &Neighbourhood) -> Result<(DVec3, DVec3, Eigen2), PhotonConstraint> {
    let (_, t1, t2) = nb.frame();
    if nb.offsets.len() < 3 {
        return Err(PhotonConstraint::free(t1, t2, Outcome::TooFew));
    }
    if !(nb.r2 > 0.0 && nb.r2.is_finite()) {
        return Err(PhotonConstraint::free(t1, t2, Outcome::Coincident));
    }
    match normalised_pca(nb.offsets, t1, t2, nb.r2) {
        Some(e) => Ok((t1, t2, e)),
        None => Err(PhotonConstraint::free(t1, t2, Outcome::Coincident)),
    }
}

/// Eq. 2–7: the PCA constraint of a photon from its neighbourhood.
pub fn pca_constraint(nb: &Neighbourhood, noise: NoiseModel) -> PhotonConstraint {
    let (t1, t2, e) = match tangent_pca(nb) {
        Ok(x) => x,
        Err(free) => return free,
    };
    let (mu, sigma) = noise.mu_sigma(nb.offsets.len());
    let factor = v_factor(e.lambda2, mu, sigma);
    let u = t1 * e.p1[0] + t2 * e.p1[1];
    let v = (t1 * e.p2[0] + t2 * e.p2[1]) * factor;
    PhotonConstraint {
        u: u.as_vec3().into(),
        v: v.as_vec3().into(),
        lambda2: e.lambda2 as f32,
        factor: factor as f32,
        outcome: Outcome::Measured,
    }
}

/// The 2009 baseline: a constraint along the estimated gradient of flux density.
///
/// With the Epanechnikov kernel of radius r over the neighbourhood, B̂ = Σ Φ_j w(d_j) and
/// ∇B̂ ∝ Σ Φ_j (x_j − x_i) (tangent plane). Its scale-free magnitude g = |∇B̂|·r / B̂
/// = 2·|Σ Φ_j o_j| / (r·Σ Φ_j (1 − d_j²/r²)) is ≈ 1.7 on a hard edge and ≈ 2.8/√Kc for
/// isotropic noise. The photon is held along the gradient in proportion to it:
/// u_b ⟂ ∇B̂, v_b = ∇B̂/|∇B̂| · max(0, 1 − gain·g). `weights` are the neighbours' fluxes
/// (any non-finite or negative weight counts as 0). λ2 is reported from the same PCA as
/// `world-pca`, for comparison.
pub fn gradient_constraint(
    nb: &Neighbourhood,
    weights: &[f64],
    gain: f64,
    scratch: &mut Vec<DVec2>,
) -> PhotonConstraint {
    let (t1, t2, e) = match tangent_pca(nb) {
        Ok(x) => x,
        Err(free) => return free,
    };
    nb.project(t1, t2, scratch);
    let r = nb.r2.sqrt();
    let (mut grad, mut density) = (DVec2::ZERO, 0.0);
    for ((p, o), &w) in scratch.iter().zip(nb.offsets).zip(weights) {
        let w = if w.is_finite() && w > 0.0 { w } else { 0.0 };
        grad += *p / r * w;
        density += w * (1.0 - o.length_squared() / nb.r2).max(0.0);
    }
    let g = if density > 0.0 { 2.0 * grad.length() / density } else { 0.0 };
    let Some(dir) = grad.try_normalize().filter(|_| g.is_finite()) else {
        let mut c = PhotonConstraint::free(t1, t2, Outcome::Measured);
        c.lambda2 = e.lambda2 as f32;
        return c;
    };
    let factor = (1.0 - gain * g).clamp(0.0, 1.0);
    let along = t1 * dir.x + t2 * dir.y;
    let across = t1 * -dir.y + t2 * dir.x;
    PhotonConstraint {
        u: across.as_vec3().into(),
        v: (along * factor).as_vec3().into(),
        lambda2: e.lambda2 as f32,
        factor: factor as f32,
        outcome: Outcome::Measured,
    }
}
