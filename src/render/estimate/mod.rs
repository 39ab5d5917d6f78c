//! Density estimation: the irradiance the photons near a point stand for.
//!
//! A photon carries flux Φ_p (W per RGB channel). The irradiance at x is the flux density
//!
//! ```text
//!     E(x) = Σ_p Φ_p · w(d_p)        [W/m²]
//! ```
//!
//! with a kernel w that integrates to one over the plane, so the flux is only redistributed,
//! never created. The radiance a Lambertian surface of albedo ρ sends towards the eye is then
//! L = (ρ/π)·E (method.md, "Rendering": L = Σ f_r Φ_p w(d_p)).
//!
//! Three estimators: the classical k-nearest-neighbour estimate (r = distance to the K-th
//! photon) with an Epanechnikov, disc or cone kernel; diffusion-based photon mapping (Schjøth,
//! Olsen, Sporring 2008), whose kernel is an ellipse shaped by the structure tensor of the
//! density estimate so it smooths along a caustic's edges and not across them; and a fixed
//! radius, for progressive photon mapping ([`crate::eval::reference`]).
//!
//! Neighbours come from a [`BoxTree`]; each search starts from a bound given by the previous
//! query of the same thread (exact, see [`PhotonLookup::irradiance`]), which makes the
//! coherent queries of an image tile cheap.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::RenderError;
use crate::spatial::{BoxTree, Neighbour, Neighbours};

/// A radially symmetric kernel of radius r, normalised so ∫ w dA = 1 over the disc.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// w(d) = 2/(π r²) · (1 − d²/r²) (method.md; the paper's choice).
    Epanechnikov,
    /// w(d) = 1/(π r²): the plain disc (Jensen's original estimate).
    Disc,
    /// w(d) = 3/(π r²) · (1 − d/r): Jensen's cone filter with k = 1.
    Cone,
}

impl Kernel {
    /// w(d) from d² and r² (zero outside the disc; the disc kernel includes its rim, where the
    /// K-th photon lies).
    #[inline]
    pub fn weight(self, d2: f32, r2: f32) -> f32 {
        if d2 > r2 {
            return 0.0;
        }
        match self {
            Kernel::Epanechnikov => 2.0 / (PI * r2) * (1.0 - d2 / r2),
            Kernel::Disc => 1.0 / (PI * r2),
            Kernel::Cone => 3.0 / (PI * r2) * (1.0 - (d2 / r2).sqrt()),
        }
    }

    /// The kernel's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Epanechnikov => "epanechnikov",
            Kernel::Disc => "disc",
            Kernel::Cone => "cone",
        }
    }
}

/// How the irradiance at a point is estimated from the photons.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Estimator {
    /// E = Σ Φ_p w(d_p) over the `k` nearest photons, r the distance to the k-th; with
    /// `max_radius`, r is at most that (and only photons within it count).
    Knn {
        /// K: photons per estimate.
        k: usize,
        /// The kernel w.
        kernel: Kernel,
        /// Largest r, metres.
        max_radius: Option<f32>,
    },
    /// Diffusion-based photon mapping: `k` neighbours (the paper compares with 500), and the
    /// Perona–Malik control `q` of the diffusivity c(g) = 1/(1 + (g/q)²) (the paper: 0.02).
    Diffusion {
        /// Photons gathered per estimate.
        k: usize,
        /// q of the diffusivity.
        q: f32,
    },
    /// E = Σ Φ_p w(d_p) over every photon within the fixed `radius` (progressive photon
    /// mapping); needs a lookup made by [`PhotonLookup::for_radius`].
    Radius {
        /// The gather radius, metres.
        radius: f32,
        /// The kernel w.
        kernel: Kernel,
    },
    /// E = Σ Φ_p w(d_p) over every photon within r = `scale` · r_k(x), r_k(x) the distance
    /// from x to the `k`-th nearest photon of the lookup's radius map (progressive photon
    /// mapping with an initial radius from the local photon density, Hachisuka & Jensen's
    /// advice; the map is the first pass's photons); needs a lookup made by
    /// [`PhotonLookup::with_radius_map`].
    LocalRadius {
        /// Which nearest photon of the radius map sets r_k(x).
        k: usize,
        /// The factor on r_k(x).
        scale: f32,
        /// The kernel w.
        kernel: Kernel,
    },
    /// The variable-kernel estimate (Breiman, Meisel & Purcell 1977; Silverman 1986 §5.3):
    /// E = Σ Φ_p w_{r_p}(d_p), each photon's kernel radius r_p the distance from the photon
    /// to its own `k`-th nearest photon. Unbiased on uniform photons of any arrangement
    /// (Campbell's theorem: each kernel integrates to one and its radius belongs to the
    /// photon, not to x), where [`Estimator::Knn`] is low on stratified photons (docs/truth.md);
    /// needs a lookup made [`PhotonLookup::prepared_for`] it.
    Variable {
        /// Which nearest photon sets each photon's radius.
        k: usize,
        /// The kernel w.
        kernel: Kernel,
    },
}

impl Estimator {
    /// The paper's setting: K = 15 with the Epanechnikov kernel.
    pub const DEFAULT: Estimator = Estimator::Knn { k: 15, kernel: Kernel::Epanechnikov, max_radius: None };

    /// A one-line description for reports and image headers.
    pub fn describe(&self) -> String {
        match *self {
            Estimator::Knn { k, kernel, max_radius: None } => {
                format!("k-NN, K = {k}, {} kernel", kernel.name())
            }
            Estimator::Knn { k, kernel, max_radius: Some(r) } => {
                format!("k-NN, K = {k}, {} kernel, r ≤ {r} m", kernel.name())
            }
            Estimator::Diffusion { k, q } => format!("diffusion, {k} neighbours, q = {q}"),
            Estimator::Radius { radius, kernel } => format!("radius {radius} m, {} kernel", kernel.name()),
            Estimator::LocalRadius { k, scale, kernel } => {
                format!(
                    "radius {scale} × the {k}-NN distance of the radius map (a progressive reference's first pass, or a grown map's photons before it grew, narrowed where detection held them), {} kernel",
                    kernel.name()
                )
            }
            Estimator::Variable { k, kernel } => {
                format!("variable kernel, each photon's radius its {k}-NN distance, {} kernel", kernel.name())
            }
        }
    }

    /// Neighbours fetched per lookup.
    pub fn k(&self) -> usize {
        match *self {
            Estimator::Knn { k, .. } | Estimator::Diffusion { k, .. } | Estimator::Variable { k, .. } => k,
            Estimator::Radius { .. } | Estimator::LocalRadius { .. } => 1,
        }
    }
}

/// Shortest ellipse axis of the diffusion kernel as a fraction of the gather radius, so a
/// kernel squeezed by noise still holds photons.
pub const DIFFUSION_MIN_AXIS: f32 = 0.05;

/// The photon columns an estimate reads (photon i at index i of each).
#[derive(Clone, Copy, Debug)]
pub struct PhotonData<'a> {
    /// Photon positions, metres.
    pub positions: &'a [[f32; 3]],
    /// W per RGB channel.
    pub flux: &'a [[f32; 3]],
    /// Surface normal at each photon, facing the side it arrived from; when present, photons
    /// on surfaces facing away from the query's normal are left out.
    pub normals: Option<&'a [[f32; 3]]>,
}

/// Photons with their k-NN index (or, for fixed-radius lookups, a grid), ready for lookups.
pub struct PhotonLookup<'a> {
    /// The photons looked up, in the caller's order.
    pub data: PhotonData<'a>,
    index: Option<BoxTree>,
    grid: Option<Grid>,
    /// The photons whose k-th nearest distance sets [`Estimator::LocalRadius`]'s radius.
    radius_map: Option<RadiusMap<'a>>,
    /// Each photon's own kernel radius, for [`Estimator::Variable`].
    variable: Option<VariableKernels>,
}

/// The photons that set [`Estimator::LocalRadius`]'s radius: the caller's (a progressive
/// reference's first pass, kept across passes) or the lookup's own (a grown map's photons as
/// they were before it grew, each with a factor on the radius,
/// [`PhotonLookup::with_own_radius_map`]).
enum RadiusMap<'a> {
    Borrowed(&'a BoxTree),
    Owned(BoxTree, Vec<f32>),
}

impl RadiusMap<'_> {
    fn tree(&self) -> &BoxTree {
        match self {
            RadiusMap::Borrowed(t) => t,
            RadiusMap::Owned(t, _) => t,
        }
    }

    /// The factor on the radius at a point whose k nearest sites are `near`: the mean of
    /// theirs (1 for a borrowed map).
    fn factor(&self, near: &[Neighbour]) -> f32 {
        match self {
            RadiusMap::Owned(_, factors) if !near.is_empty() => {
                near.iter().map(|nb| factors[nb.index as usize]).sum::<f32>() / near.len() as f32
            }
            _ => 1.0,
        }
    }
}

/// Per-thread buffers reused across lookups.
#[derive(Default)]
pub struct Scratch {
    pub(crate) nb: Neighbours,
    /// Tangent-plane offsets, flux and luminance of the gathered photons (diffusion).
    local: Vec<(Vec2, Vec3, f32)>,
    /// The previous k-NN query: its point, k and the distance to its k-th photon.
    last: Option<(Vec3, usize, f32)>,
}

/// The k-NN kernel's radius² from a search that found `found` photons, the last at distance²
/// `last_dist2`: the k-th's, or the whole limit `max2` when fewer than k lie within it;
/// `None` when the kernel is empty (r² ≤ 0: the photons sit on the point).
pub(crate) fn knn_radius2(found: usize, k: usize, last_dist2: f32, max2: f32) -> Option<f32> {
    let r2 = if found < k { max2 } else { last_dist2 };
    (r2 > 0.0).then_some(r2)
}

impl<'a> PhotonLookup<'a> {
    /// Checks the photons (at least one; finite positions, flux and normals) and builds the
    /// world-space index. `file` names the map in errors.
    pub fn new(file: &str, data: PhotonData<'a>) -> Result<Self, RenderError> {
        Self::check(file, &data)?;
        let index = BoxTree::build(data.positions);
        Ok(PhotonLookup { data, index: Some(index), grid: None, radius_map: None, variable: None })
    }

    /// Photons for [`Estimator::LocalRadius`] lookups, whose radius at a point comes from the
    /// photons of `radius_map`. An empty set is allowed (a progressive pass may store none).
    pub fn with_radius_map(
        file: &str,
        data: PhotonData<'a>,
        radius_map: &'a BoxTree,
    ) -> Result<Self, RenderError> {
        if !data.positions.is_empty() {
            Self::check(file, &data)?;
        }
        let index = BoxTree::build(data.positions);
        Ok(PhotonLookup {
            data,
            index: Some(index),
            grid: None,
            radius_map: Some(RadiusMap::Borrowed(radius_map)),
            variable: None,
        })
    }

    /// These photons, for [`Estimator::LocalRadius`] lookups whose radius at a point comes from
    /// the points `sites` (a map grown by refinement: its photons before it grew,
    /// [`crate::refine::first_photons`]): the distance to the k-th nearest site, times the mean
    /// of those k sites' `factors` (one per site, [`crate::refine::radius_factors`]; empty: 1
    /// for every site).
    pub fn with_own_radius_map(mut self, sites: &[[f32; 3]], factors: &[f32]) -> Self {
        debug_assert!(factors.is_empty() || factors.len() == sites.len(), "one factor per site");
        let factors = match factors.len() == sites.len() {
            true => factors.to_vec(),
            false => vec![1.0; sites.len()],
        };
        self.radius_map = Some(RadiusMap::Owned(BoxTree::build(sites), factors));
        self
    }

    /// Photons for fixed-radius lookups of `radius` ([`Estimator::Radius`]) only: a uniform
    /// grid of cells `radius` wide, cheaper to build than the k-NN tree. An empty set is
    /// allowed (a progressive pass may store no photon).
    pub fn for_radius(file: &str, data: PhotonData<'a>, radius: f32) -> Result<Self, RenderError> {
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(RenderError::Invalid(format!("gather radius {radius}: must be positive")));
        }
        if !data.positions.is_empty() {
            Self::check(file, &data)?;
        }
        Ok(PhotonLookup {
            grid: Some(Grid::build(data.positions, radius)),
            data,
            index: None,
            radius_map: None,
            variable: None,
        })
    }

    /// The same lookup, with what `est` needs beyond the k-NN index: for
    /// [`Estimator::Variable`], every photon's kernel radius (one k-NN query per photon).
    pub fn prepared_for(mut self, est: &Estimator) -> Self {
        if let (Estimator::Variable { k, .. }, Some(index)) = (*est, &self.index)
            && self.variable.as_ref().is_none_or(|v| v.k != k)
        {
            self.variable = Some(VariableKernels::build(self.data.positions, index, k));
        }
        self
    }

    fn check(file: &str, data: &PhotonData) -> Result<(), RenderError> {
        if data.positions.is_empty() {
            return Err(RenderError::EmptyMap { file: file.to_string() });
        }
        let bad = |column: &str, index: usize| RenderError::NonFinite {
            file: file.to_string(),
            column: column.to_string(),
            index: index as u64,
        };
        let finite = |v: &[[f32; 3]]| v.iter().position(|x| x.iter().any(|c| !c.is_finite()));
        if let Some(i) = finite(data.positions) {
            return Err(bad("position", i));
        }
        if let Some(i) = finite(data.flux) {
            return Err(bad("flux", i));
        }
        if let Some(i) = data.normals.and_then(finite) {
            return Err(bad("normal", i));
        }
        Ok(())
    }

    /// Number of photons.
    pub fn len(&self) -> usize {
        self.data.positions.len()
    }

    /// Whether it holds no photon.
    pub fn is_empty(&self) -> bool {
        self.data.positions.is_empty()
    }

    /// The `k` photons nearest `x` within distance² `max_dist2` (∞ for no limit) into `out`,
    /// nearest first (none for a fixed-radius lookup).
    pub fn nearest(&self, x: Vec3, k: usize, max_dist2: f32, out: &mut Neighbours) {
        match &self.index {
            Some(index) => index.knn(x.to_array(), k, max_dist2, out),
            None => *out = Neighbours::default(),
        }
    }

    /// [`Self::nearest`] into `s.nb`, starting from a bound given by the previous query.
    /// Successive queries are close (samples of one pixel, pixels of one tile): the previous
    /// query's k photons lie within r_prev + |x − x_prev| of x (triangle inequality), so the
    /// search may start with that bound, slightly widened for rounding. The result is the same
    /// as without it whenever k photons lie within it, which they do.
    fn nearest_from_last(&self, x: Vec3, k: usize, max2: f32, s: &mut Scratch) {
        let hint = match s.last {
            Some((p, pk, r)) if pk == k => {
                let b = (r + (x - p).length()) * (1.0 + 1e-5) + 1e-30;
                b * b
            }
            _ => f32::INFINITY,
        };
        self.nearest(x, k, max2.min(hint), &mut s.nb);
        if s.nb.len() < k && hint < max2 {
            self.nearest(x, k, max2, &mut s.nb);
        }
        s.last = match s.nb.last() {
            Some(l) if s.nb.len() == k => Some((x, k, l.dist2.sqrt())),
            _ => None,
        };
    }

    /// Whether this lookup serves `est` (fixed-radius lookups need their grid, the others
    /// the k-NN tree).
    pub fn serves(&self, est: &Estimator) -> bool {
        match est {
            Estimator::Radius { radius, .. } => self.grid.as_ref().is_some_and(|g| g.cell >= *radius),
            Estimator::LocalRadius { .. } => self.radius_map.is_some() && self.index.is_some(),
            Estimator::Variable { k, .. } => self.variable.as_ref().is_some_and(|v| v.k == *k),
            _ => self.index.is_some(),
        }
    }

    #[inline]
    fn faces(&self, i: usize, n: Vec3) -> bool {
        self.data.normals.is_none_or(|ns| Vec3::from_array(ns[i]).dot(n) > 0.0)
    }

    /// Irradiance at `x` on a surface with unit normal `n`, W/m² per channel. `s` carries the
    /// previous query's bound between calls; the result does not depend on it.
    pub fn irradiance(&self, est: &Estimator, x: Vec3, n: Vec3, s: &mut Scratch) -> Vec3 {
        match *est {
            Estimator::Knn { k, kernel, max_radius } => self.knn_irradiance(k, kernel, max_radius, x, n, s),
            Estimator::Diffusion { k, q } => self.diffusion_irradiance(k, q, x, n, s),
            Estimator::Radius { radius, kernel } => self.radius_irradiance(radius, kernel, x, n),
            Estimator::LocalRadius { k, scale, kernel } => {
                self.local_radius_irradiance(k, scale, kernel, x, n, s)
            }
            Estimator::Variable { kernel, .. } => self.variable_irradiance(kernel, x, n, s),
        }
    }

    /// E(x) = Σ Φ_p w(d_p) over the photons within r = scale · c(x) · (the k-th nearest
    /// distance of the radius map's photons from x), c(x) the mean factor of those k (1 but
    /// for a grown map's own sites); zero where the map has fewer than k photons or they sit
    /// on x.
    fn local_radius_irradiance(
        &self,
        k: usize,
        scale: f32,
        kernel: Kernel,
        x: Vec3,
        n: Vec3,
        s: &mut Scratch,
    ) -> Vec3 {
        let (Some(map_of), Some(index)) = (self.radius_map.as_ref(), &self.index) else {
            return Vec3::ZERO;
        };
        let map = map_of.tree();
        s.last = None;
        map.knn(x.to_array(), k, f32::INFINITY, &mut s.nb);
        let Some(kth) = s.nb.last().filter(|_| s.nb.len() == k) else { return Vec3::ZERO };
        let r = kth.dist2.sqrt() * scale * map_of.factor(s.nb.as_slice());
        let r2 = r * r;
        if !(r2 > 0.0 && r2.is_finite()) {
            return Vec3::ZERO;
        }
        // Every photon of this pass within r (a k-NN query without a count limit).
        index.knn(x.to_array(), usize::MAX, r2, &mut s.nb);
        let mut e = Vec3::ZERO;
        for nb in s.nb.as_slice() {
            let i = nb.index as usize;
            if self.faces(i, n) {
                e += Vec3::from_array(self.data.flux[i]) * kernel.weight(nb.dist2, r2);
            }
        }
        e
    }

    /// E(x) = Σ Φ_p w_{r_p}(d_p) over the photons whose own kernel reaches x.
    fn variable_irradiance(&self, kernel: Kernel, x: Vec3, n: Vec3, s: &mut Scratch) -> Vec3 {
        let Some(v) = &self.variable else { return Vec3::ZERO };
        s.last = None;
        let mut e = Vec3::ZERO;
        for class in &v.classes {
            class.tree.knn(x.to_array(), usize::MAX, class.reach2, &mut s.nb);
            for nb in s.nb.as_slice() {
                let i = class.photons[nb.index as usize] as usize;
                if self.faces(i, n) {
                    e += Vec3::from_array(self.data.flux[i]) * kernel.weight(nb.dist2, v.radius2[i]);
                }
            }
        }
        e
    }

    /// E(x) = Σ Φ_p w(d_p) over the photons within the fixed radius r.
    fn radius_irradiance(&self, r: f32, kernel: Kernel, x: Vec3, n: Vec3) -> Vec3 {
        let Some(grid) = &self.grid else { return Vec3::ZERO };
        let r2 = r * r;
        let mut e = Vec3::ZERO;
        grid.within(self.data.positions, x, r2, |i, d2| {
            if self.faces(i as usize, n) {
                e += Vec3::from_array(self.data.flux[i as usize]) * kernel.weight(d2, r2);
            }
        });
        e
    }

    /// E(x) = Σ Φ_p w(d_p) over the k nearest photons, r = distance to the k-th (method.md).
    fn knn_irradiance(
        &self,
        k: usize,
        kernel: Kernel,
        max_r: Option<f32>,
        x: Vec3,
        n: Vec3,
        s: &mut Scratch,
    ) -> Vec3 {
        let max2 = max_r.map_or(f32::INFINITY, |m| m * m);
        self.nearest_from_last(x, k, max2, s);
        let Some(last) = s.nb.last() else { return Vec3::ZERO };
        let Some(r2) = knn_radius2(s.nb.len(), k, last.dist2, max2) else { return Vec3::ZERO };
        let mut e = Vec3::ZERO;
        for nb in s.nb.as_slice() {
            let i = nb.index as usize;
            if nb.dist2 <= r2 && self.faces(i, n) {
                e += Vec3::from_array(self.data.flux[i]) * kernel.weight(nb.dist2, r2);
            }
        }
        e
    }

    /// Diffusion-based photon mapping (Schjøth, Olsen, Sporring 2008). The k nearest photons
    /// (radius r) are projected into the tangent plane. The structure tensor J is the mean of
    /// ∇E ∇Eᵀ over five points (x and x ± r/2 along the tangent axes), ∇E the gradient of an
    /// Epanechnikov estimate of radius r/2 (so every kernel stays inside the gathered disc):
    /// ∇E(y) = Σ Φ_p · 4/(π h⁴) · (x_p − y). Along each eigenvector e_i of J, with the relative
    /// gradient g_i = sqrt(μ_i)·h/E, the Perona–Malik diffusivity c_i = 1/(1 + (g_i/q)²) sets
    /// the ellipse's semi-axis a_i = r·sqrt(c_i) (at least [`DIFFUSION_MIN_AXIS`]·r). The
    /// estimate is the Epanechnikov kernel on that ellipse, normalised by its area:
    /// E = Σ Φ_p · 2/(π a₁ a₂) · (1 − ρ²), ρ² = Σ_i ((x_p − x)·e_i / a_i)².
    fn diffusion_irradiance(&self, k: usize, q: f32, x: Vec3, n: Vec3, s: &mut Scratch) -> Vec3 {
        self.nearest_from_last(x, k, f32::INFINITY, s);
        let Some(last) = s.nb.last() else { return Vec3::ZERO };
        let r2 = last.dist2;
        if r2 <= 0.0 {
            return Vec3::ZERO;
        }
        let r = r2.sqrt();
        let (t1, t2) = n.any_orthonormal_pair();
        s.local.clear();
        for nb in s.nb.as_slice() {
            let i = nb.index as usize;
            if self.faces(i, n) {
                let d = Vec3::from_array(self.data.positions[i]) - x;
                let f = Vec3::from_array(self.data.flux[i]);
                s.local.push((Vec2::new(d.dot(t1), d.dot(t2)), f, f.element_sum()));
            }
        }
        // Scalar (summed over RGB) estimate and gradient with the half-radius kernel.
        let h = 0.5 * r;
        let h2 = h * h;
        let grad_at = |y: Vec2| -> Vec2 {
            let mut g = Vec2::ZERO;
            for &(p, _, lum) in &s.local {
                let d = p - y;
                if d.length_squared() < h2 {
                    g += d * lum;
                }
            }
            g * (4.0 / (PI * h2 * h2))
        };
        let mut e0 = 0.0;
        for &(p, _, lum) in &s.local {
            e0 += lum * Kernel::Epanechnikov.weight(p.length_squared(), r2);
        }
        if e0 <= 0.0 {
            return Vec3::ZERO;
        }
        let (mut jxx, mut jxy, mut jyy) = (0.0f32, 0.0f32, 0.0f32);
        for y in [Vec2::ZERO, Vec2::new(h, 0.0), Vec2::new(-h, 0.0), Vec2::new(0.0, h), Vec2::new(0.0, -h)] {
            let g = grad_at(y);
            jxx += g.x * g.x / 5.0;
            jxy += g.x * g.y / 5.0;
            jyy += g.y * g.y / 5.0;
        }
        let (mu1, mu2, e1) = eigen_sym2(jxx, jxy, jyy);
        let e2 = e1.perp();
        let axis = |mu: f32| {
            let g = mu.max(0.0).sqrt() * h / e0;
            let c = 1.0 / (1.0 + (g / q) * (g / q));
            r * c.sqrt().max(DIFFUSION_MIN_AXIS)
        };
        let (a1, a2) = (axis(mu1), axis(mu2));
        let norm = 2.0 / (PI * a1 * a2);
        let mut e = Vec3::ZERO;
        for &(p, f, _) in &s.local {
            let (u, v) = (p.dot(e1) / a1, p.dot(e2) / a2);
            let rho2 = u * u + v * v;
            if rho2 < 1.0 {
                e += f * (norm * (1.0 - rho2));
            }
        }
        e
    }
}

/// Every photon's kernel radius for [`Estimator::Variable`], and the photons grouped by
/// radius so a lookup visits only those whose kernel can reach it: class c holds the radii
/// within a factor of two below r_max/2^c, each class has its own tree, searched within the
/// class's largest radius.
struct VariableKernels {
    k: usize,
    /// r_p² per photon: the distance² to its k-th nearest other photon (0 where k others
    /// coincide with it: such a photon's kernel is a point and reaches no lookup; with fewer
    /// than k others, the farthest of them).
    radius2: Vec<f32>,
    classes: Vec<RadiusClass>,
}

struct RadiusClass {
    /// The largest r² of the class.
    reach2: f32,
    tree: BoxTree,
    /// The photon of each tree point.
    photons: Vec<u32>,
}

impl VariableKernels {
    /// Radius classes: enough for radii spanning 2⁶⁴; smaller radii share the last.
    const MAX_CLASSES: usize = 64;

    fn build(positions: &[[f32; 3]], index: &BoxTree, k: usize) -> VariableKernels {
        use rayon::prelude::*;
        let radius2: Vec<f32> = positions
            .par_iter()
            .map_init(
                || Neighbours::with_capacity(k + 1),
                |nb, p| {
                    // The photon itself is among its k + 1 nearest (at distance 0).
                    index.knn(*p, k + 1, f32::INFINITY, nb);
                    nb.last().map_or(0.0, |l| l.dist2)
                },
            )
            .collect();
        let max2 = radius2.iter().copied().filter(|r| r.is_finite()).fold(0.0f32, f32::max);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); Self::MAX_CLASSES];
        for (i, &r2) in radius2.iter().enumerate() {
            if r2 > 0.0 && r2.is_finite() {
                // r² within (max²/4^(c+1), max²/4^c].
                let c = (0.5 * (max2 as f64 / r2 as f64).log2()).floor() as usize;
                members[c.min(Self::MAX_CLASSES - 1)].push(i as u32);
            }
        }
        let classes = members
            .into_iter()
            .filter(|m| !m.is_empty())
            .map(|photons| {
                let points: Vec<[f32; 3]> = photons.iter().map(|&i| positions[i as usize]).collect();
                let reach2 = photons.iter().map(|&i| radius2[i as usize]).fold(0.0f32, f32::max);
                RadiusClass { reach2, tree: BoxTree::build(&points), photons }
            })
            .collect();
        VariableKernels { k, radius2, classes }
    }
}

/// A uniform grid of cubic cells over the photons: the fixed-radius gather of progressive
/// photon mapping visits the 27 cells around the query.
struct Grid {
    cell: f32,
    /// Cell key → range of `order`.
    cells: std::collections::HashMap<[i32; 3], (u32, u32)>,
    /// Photon indices grouped by cell.
    order: Vec<u32>,
}

impl Grid {
    fn key(cell: f32, p: [f32; 3]) -> [i32; 3] {
        p.map(|c| (c / cell).floor() as i32)
    }

    fn build(positions: &[[f32; 3]], cell: f32) -> Grid {
        let mut order: Vec<u32> = (0..positions.len() as u32).collect();
        order.sort_unstable_by_key(|&i| Self::key(cell, positions[i as usize]));
        let mut cells = std::collections::HashMap::new();
        let mut start = 0;
        while start < order.len() {
            let k = Self::key(cell, positions[order[start] as usize]);
            let mut end = start + 1;
            while end < order.len() && Self::key(cell, positions[order[end] as usize]) == k {
                end += 1;
            }
            cells.insert(k, (start as u32, end as u32));
            start = end;
        }
        Grid { cell, cells, order }
    }

    /// Calls `f(photon, d²)` for every photon within √`r2` (≤ the cell size) of `x`.
    fn within(&self, positions: &[[f32; 3]], x: Vec3, r2: f32, mut f: impl FnMut(u32, f32)) {
        let c = Self::key(self.cell, x.to_array());
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let k = [c[0].saturating_add(dx), c[1].saturating_add(dy), c[2].saturating_add(dz)];
                    let Some(&(a, b)) = self.cells.get(&k) else { continue };
                    for &i in &self.order[a as usize..b as usize] {
                        let d2 = (Vec3::from_array(positions[i as usize]) - x).length_squared();
                        if d2 <= r2 {
                            f(i, d2);
                        }
                    }
                }
            }
        }
    }
}

/// Eigenvalues μ1 ≥ μ2 of the symmetric matrix [[a, b], [b, c]] and the unit eigenvector of μ1.
fn eigen_sym2(a: f32, b: f32, c: f32) -> (f32, f32, Vec2) {
    let mean = 0.5 * (a + c);
    let diff = 0.5 * (a - c);
    let rad = (diff * diff + b * b).sqrt();
    let (mu1, mu2) = (mean + rad, mean - rad);
    // (b, μ1 − a) and (μ1 − c, b) are both eigenvectors; take the better conditioned.
    let v = if a >= c { Vec2::new(mu1 - c, b) } else { Vec2::new(b, mu1 - a) };
    (mu1, mu2, v.try_normalize().unwrap_or(Vec2::X))
}

#[cfg(test)]
mod tests;
