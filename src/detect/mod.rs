//! Feature detection (Eq. 1–7): a constraint basis per photon from the shape of its
//! neighbourhood, found where overlapping caustic filaments come apart.
//!
//! For each photon i (method `param-pca`, the paper's):
//!
//! 1. **Parameter-space density** (Eq. 1): ρ(i) = k / (π r_k²), r_k the distance in parameter
//!    space to i's k-th nearest photon of the same emitter (k = Kc unless set; i counts as its
//!    own first neighbour). The search radius is r_param(i) = β·sqrt(Kc / (π ρ(i))), which for
//!    k = Kc is simply β·r_Kc. Parameter distances are Euclidean in the `params` column: the
//!    (u, v) square of a `rect_uv` emitter, and for a `direction` emitter the unit sphere
//!    embedded in 3-D, whose Euclidean distance is the chord 2·sin(θ/2) (ρ is then per unit
//!    chord area, equal to per steradian for small radii, and there is no seam).
//! 2. **Neighbourhood**: the Kc nearest photons by world-space distance among those of the
//!    same emitter with parameters within r_param(i) of i's ([`crate::spatial`]); i is one of
//!    them. r is the world-space distance to the farthest (the Kc-th). *Not in the paper:* a
//!    photon held by step 3 whose ball binds from both sides (two neighbours in its outer
//!    fifth on opposite sides of it: a stretched map from parameters to the surface, not an
//!    edge) is measured again with r_param doubled, up to [`DetectParams::growths`] times; the
//!    `r_param` column holds the radius finally used (docs/parameter-ball.md).
//! 3. **PCA** in i's tangent plane (Eq. 2–7): the neighbours' offsets are projected onto an
//!    orthonormal basis of the plane orthogonal to the normal, their covariance (mean removed,
//!    divided by the count m) decomposed in closed form ([`eigen2`]), λ1 ≥ λ2 normalised by r²,
//!    and [`v_factor`] turns λ2 into the constraint: u_b = P1, v_b = P2·[1 − (3π/4)·M·Φ],
//!    re-embedded in world space. An isotropic neighbourhood gives λ2 near 1/4 and a factor
//!    near 1 (free motion); a hard edge gives a factor near 0 across it.
//!
//! The other methods measure one ingredient at a time: `world-pca` is step 3 over plain
//! world-space neighbours; `gradient` is the 2009 photon-relaxation baseline
//! ([`gradient_constraint`]); `none` leaves every photon free in its tangent plane.
//!
//! **Degenerate neighbourhoods** get a free constraint (u_b, v_b an orthonormal tangent basis,
//! factor 1, λ2 = 1/4), because nothing about the illumination's structure can be measured:
//! fewer than 3 neighbours, all neighbours on top of the photon (r = 0), or all of them
//! displaced only along the normal (no extent in the tangent plane). A collinear
//! neighbourhood is *not* degenerate: λ2 = 0 and the photon is held on its line. A normal
//! that is missing, zero or not finite is estimated from the neighbourhood (the direction
//! of least spread); normals of any non-zero length are normalised. Every output is finite.
//!
//! The noise filter Φ (Eq. 6) uses μ(m), σ(m) for the m neighbours actually found (m = Kc
//! unless fewer photons qualify), from [`NoiseModel`].

mod constraint;
mod map;
mod noise;
mod part;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use constraint::unit_normal;
pub use constraint::{
    Eigen2, LAMBDA2_MIN, Neighbourhood, Outcome, PhotonConstraint, eigen2, erf, gradient_constraint,
    migration, noise_filter, pca_constraint, tangent_basis, v_factor,
};
pub use map::{
    PreparedInput, choose_method, detect_map, detect_map_tile, detect_map_tiled, detected_map,
    detected_map_with, map_input, memory, record_parameters, spectral_scales,
};
pub use noise::{NoiseModel, Row, SIMULATED, in_disc, lambda2_of, simulate};
pub use part::{FACTOR, OUTCOME, PHOTON_INDEX, merge_parts, tile_part};

use crate::format::FormatError;
use crate::spatial::{Neighbours, ParamColumn, PointSet, Space, SpatialError, SpatialIndex};

/// How constraints are computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The paper: PCA over world-space neighbours restricted in parameter space (Eq. 1–7).
    #[default]
    ParamPca,
    /// PCA over plain world-space neighbours (Eq. 2–7 without Eq. 1).
    WorldPca,
    /// Photon relaxation 2009: constraint along the flux-density gradient, with a gain.
    Gradient,
    /// No constraint: free motion in the tangent plane.
    None,
}

impl Method {
    /// The method's name on the command line and in stage records.
    pub fn name(self) -> &'static str {
        match self {
            Method::ParamPca => "param-pca",
            Method::WorldPca => "world-pca",
            Method::Gradient => "gradient",
            Method::None => "none",
        }
    }
}

/// Detection parameters; the defaults are the paper's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DetectParams {
    /// How constraints are computed.
    pub method: Method,
    /// Kc: neighbours in the PCA (and gradient) kernel.
    pub kc: usize,
    /// β of Eq. 1: the parameter-space radius in units of the mean photon spacing sqrt(Kc/(πρ)).
    pub beta: f32,
    /// k of the parameter-space density estimate ρ = k/(π r_k²); `None` means Kc.
    pub k_density: Option<usize>,
    /// Gain of the `gradient` method: the factor along the gradient is 1 − gain·g ([`gradient_constraint`]).
    pub gain: f32,
    /// μ(K), σ(K) of Eq. 4–6.
    pub noise: NoiseModel,
    /// Times a photon's parameter ball may be doubled when it binds from both sides (the
    /// module docs, step 2); 0 keeps the paper's fixed ball.
    pub growths: u32,
    /// S: the visible spectrum's length in parameter space, in units of the spread of an
    /// emitter's other parameters ([`spectral_scales`]; docs/spectral.md). Used only for maps
    /// whose emitters carry a wavelength, and recorded only for them.
    #[serde(skip)]
    pub spectral_scale: f32,
}

impl Default for DetectParams {
    fn default() -> Self {
        DetectParams {
            method: Method::ParamPca,
            kc: 50,
            beta: 3.0,
            k_density: None,
            gain: DEFAULT_GAIN,
            noise: NoiseModel::Simulated,
            growths: DEFAULT_GROWTHS,
            spectral_scale: DEFAULT_SPECTRAL_SCALE,
        }
    }
}

/// The default [`DetectParams::spectral_scale`] (docs/spectral.md has the measurements).
pub const DEFAULT_SPECTRAL_SCALE: f32 = 0.03;

/// The default [`DetectParams::growths`]: twice, to 4β (docs/parameter-ball.md).
pub const DEFAULT_GROWTHS: u32 = 2;

/// The `gradient` method's default gain: a hard edge (g ≈ 1.7) is held fully, isotropic noise
/// (g ≈ 2.8/√Kc, 0.4 at Kc = 50) keeps most of its freedom.
pub const DEFAULT_GAIN: f32 = 0.6;

/// What can stop feature detection.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DetectError {
    /// Reading the map's columns failed.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The photons can not be indexed (a non-finite position, say), photon indices in the
    /// caller's order.
    #[error(transparent)]
    Spatial(#[from] SpatialError),
    /// `param-pca` asked of a map without trajectory parameters.
    #[error(
        "{file}: method param-pca needs trajectory parameters (a 'params' column and emitters with \
         param_dims > 0); this map has none: use --method world-pca or gradient"
    )]
    NoParameters {
        /// The map as named to the user.
        file: String,
    },
    /// A column detection reads is not as it needs it.
    #[error("{file}: {message}")]
    Input {
        /// The map as named to the user.
        file: String,
        /// What is wrong with the column.
        message: String,
    },
    /// A [`DetectParams`] value out of its range.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// A map's photons can not be indexed.
    #[error("{file}: {source}")]
    Photons {
        /// The map as named to the user.
        file: String,
        /// Why, photon indices in the map's order.
        source: SpatialError,
    },
}

// ---------------------------------------------------------------------------------------------
// Over a photon set.

/// The photons detection reads (photon i at `positions[i]`).
#[derive(Clone, Copy, Debug)]
pub struct DetectInput<'a> {
    /// Photon positions, metres.
    pub positions: &'a [[f32; 3]],
    /// Surface normals (any non-zero length); missing or unusable ones are estimated.
    pub normals: Option<&'a [[f32; 3]]>,
    /// RGB flux, for the `gradient` method's weights (without it every photon weighs 1).
    pub flux: Option<&'a [[f32; 3]]>,
    /// Trajectory parameters; without them only the world-space methods run.
    pub params: Option<ParamColumn<'a>>,
    /// Each photon's emitter; `None`: all of emitter 0.
    pub emitters: Option<&'a [u16]>,
    /// The pages of the file the columns are mapped from, released once a tile has copied its
    /// photons (docs/tiles.md); `Pages::default()` for columns in memory.
    pub pages: crate::format::Pages<'a>,
}

/// A [`DetectInput`]'s columns copied in another order (only the flux the method reads):
/// detection works on photons in spatial order ([`crate::spatial::order`]).
struct Permuted {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    flux: Option<Vec<[f32; 3]>>,
    emitters: Option<Vec<u16>>,
    values: Option<Vec<f32>>,
}

impl Permuted {
    /// `input`'s photons `rows[0], rows[1], …`, each column's pages released once it is copied;
    /// with `within`, `rows` ascending and the photons `rows[within[0]], rows[within[1]], …`,
    /// copied from the file in blocks whose pages are released as they are read
    /// ([`crate::format::Pages::gather_rows`]: a tile's photons lie all over the file).
    fn of(input: &DetectInput, rows: &[u32], within: Option<&[u32]>, method: Method) -> Permuted {
        fn copy<T: bytemuck::Pod + Default + Send + Sync>(
            input: &DetectInput,
            v: &[T],
            stride: usize,
            rows: &[u32],
            within: Option<&[u32]>,
        ) -> Vec<T> {
            use crate::spatial::order::permuted;
            match within {
                Some(order) => permuted(&input.pages.gather_rows(v, stride, rows), order, stride),
                None => input.pages.released(permuted(v, rows, stride)),
            }
        }
        let (r, w) = (rows, within);
        Permuted {
            positions: copy(input, input.positions, 1, r, w),
            normals: input.normals.map(|v| copy(input, v, 1, r, w)),
            // Only the gradient method weighs neighbours by their flux.
            flux: input.flux.filter(|_| method == Method::Gradient).map(|v| copy(input, v, 1, r, w)),
            emitters: input.emitters.map(|v| copy(input, v, 1, r, w)),
            values: input.params.map(|c| copy(input, c.values, c.stride, r, w)),
        }
    }

    /// The permuted photons as an input, with `input`'s parameter layout.
    fn input<'a>(&'a self, input: &DetectInput<'a>) -> DetectInput<'a> {
        DetectInput {
            positions: &self.positions,
            normals: self.normals.as_deref(),
            flux: self.flux.as_deref(),
            params: input.params.zip(self.values.as_deref()).map(|(c, values)| ParamColumn { values, ..c }),
            emitters: self.emitters.as_deref(),
            pages: Default::default(),
        }
    }
}

impl<'a> DetectInput<'a> {
    fn points(&self, with_params: bool) -> PointSet<'a> {
        PointSet {
            positions: self.positions,
            params: if with_params { self.params } else { None },
            emitters: if with_params { self.emitters } else { None },
        }
    }

    /// True when some photon's emitter has trajectory parameters.
    pub fn has_params(&self) -> bool {
        match self.params {
            None => false,
            Some(p) => match self.emitters {
                Some(e) => e.iter().any(|&e| p.dims_of(e) > 0),
                None => p.dims_of(0) > 0,
            },
        }
    }
}

/// Constraint columns for every photon, and what happened.
#[derive(Clone, Debug, Default)]
pub struct Detection {
    /// u_b (Eq. 7): unit, in the tangent plane.
    pub basis_u: Vec<[f32; 3]>,
    /// v_b (Eq. 7): orthogonal to u_b in the tangent plane, its length the factor in [0, 1].
    pub basis_v: Vec<[f32; 3]>,
    /// The normalised second eigenvalue λ2 of each photon's neighbourhood (Eq. 2–6).
    pub lambda2: Vec<f32>,
    /// Eq. 1's r_param per photon for method `param-pca` (0 for photons of an emitter
    /// without parameters, whose search ignores it); `None` for the world-space methods.
    pub r_param: Option<Vec<f32>>,
    /// Per emitter, the scale its wavelength component was given ([`spectral_scales`]), for
    /// the emitters that have one; empty when the input's parameters were used as given.
    pub spectral_scales: Vec<Option<f32>>,
    /// Counts for the stage's report.
    pub summary: Summary,
}

/// Counts for the stage's report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    /// Photons detected.
    pub photons: usize,
    /// Photons whose neighbourhood was measured.
    pub measured: usize,
    /// Photons with fewer than 3 neighbours: left free.
    pub too_few: usize,
    /// Photons whose neighbours all lie on top of them, or only along the normal: left free.
    pub coincident: usize,
    /// Photons with a factor on v_b below [`HELD_FACTOR`].
    pub constrained: usize,
    /// The mean factor on v_b (Eq. 7) over every photon.
    pub mean_factor: f64,
}

impl Summary {
    /// [`Summary::constrained`] as a fraction of the photons (0 for none).
    pub fn constrained_fraction(&self) -> f64 {
        if self.photons == 0 { 0.0 } else { self.constrained as f64 / self.photons as f64 }
    }
}

/// The factor on v_b (Eq. 7) below which a photon counts as held along its line (the
/// report's constrained fraction; relax's spectral window leaves such a photon every
/// wavelength, [`crate::relax::RelaxSpace::WorldSpectral`]).
pub const HELD_FACTOR: f32 = 0.5;

/// Photons per parallel work item (and per progress tick).
const CHUNK: usize = 2048;

/// Progress units [`detect`] reports in total for `n` photons: one per photon per pass.
pub fn work_units(input: &DetectInput, method: Method) -> u64 {
    let passes = 1 + usize::from(input.has_params() && method == Method::ParamPca);
    (input.positions.len() * passes) as u64
}

impl DetectParams {
    /// These parameters with Kc and the density's k capped at `photons` (at least their
    /// minimums): a search for more neighbours than there are photons finds them all anyway,
    /// so the result is the same, without buffers sized for the request (issue 31, item 6:
    /// `--kc 100000000` hung).
    pub fn capped(&self, photons: usize) -> DetectParams {
        DetectParams {
            kc: self.kc.min(photons.max(3)),
            k_density: self.k_density.map(|k| k.min(photons.max(2))),
            ..*self
        }
    }
}

fn check_params(p: &DetectParams) -> Result<(), DetectError> {
    let bad = |m: &str| Err(DetectError::Parameter(m.to_string()));
    if p.kc < 3 {
        return bad("Kc must be at least 3 (a plane needs three points)");
    }
    if !(p.beta.is_finite() && p.beta > 0.0) {
        return bad("β must be finite and positive");
    }
    if p.k_density.is_some_and(|k| k < 2) {
        return bad("the density's k must be at least 2");
    }
    if !(p.gain.is_finite() && p.gain >= 0.0) {
        return bad("the gain must be finite and ≥ 0");
    }
    if !(p.spectral_scale.is_finite() && p.spectral_scale > 0.0) {
        return bad("the spectral scale must be finite and positive");
    }
    Ok(())
}

/// Eq. 1: r_param(i) = β·sqrt(Kc/(πρ(i))), ρ(i) = k/(π r_k²) from the k nearest photons of the
/// same emitter in parameter space (i included), so r_param = β·r_k·sqrt(Kc/k). With fewer
/// than k photons in the emitter, k is their count. 0 for emitters without parameters.
pub fn param_radius(
    points: &PointSet,
    kc: usize,
    k_density: usize,
    beta: f32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<f32>, DetectError> {
    let index = SpatialIndex::build(points, Space::Params)?;
    let order = index.order();
    let mut radius = vec![0f32; points.len()];
    let mut found = vec![0f32; order.len()];
    found.par_chunks_mut(CHUNK).zip(order.par_chunks(CHUNK)).for_each(|(out, ids)| {
        // Only the k-th distance is needed: no coordinates.
        let mut nb = Neighbours::farthest_only(k_density);
        for (o, (r, &i)) in out.iter_mut().zip(ids).enumerate() {
            if let Some(&a) = ids.get(o + crate::spatial::PREFETCH_AHEAD) {
                points.prefetch(a as usize);
            }
            index.knn(&points.query(i as usize, None), k_density, &mut nb);
            *r = radius_of(&nb, kc, beta);
        }
        progress(ids.len() as u64);
    });
    for (&i, &r) in order.iter().zip(&found) {
        radius[i as usize] = r;
    }
    Ok(radius)
}

/// Eq. 1's r_param from the result of a photon's parameter-space k-NN search: β·r_k·sqrt(Kc/m)
/// for m neighbours found, 0 when none was, `f32::MAX` when not finite.
fn radius_of(nb: &Neighbours, kc: usize, beta: f32) -> f32 {
    let r = match nb.max_dist2() {
        Some(d2) => {
            let rk = (d2 as f64).sqrt();
            (beta as f64 * rk * (kc as f64 / nb.len() as f64).sqrt()) as f32
        }
        _ => 0.0,
    };
    if r.is_finite() { r } else { f32::MAX }
}

/// Runs feature detection over `input` (see the module docs). `progress` receives increments
/// summing to [`work_units`]. The photons are worked on in spatial order
/// ([`crate::spatial::order`]); the results come back in `input`'s order.
pub fn detect(
    input: &DetectInput,
    p: &DetectParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Detection, DetectError> {
    use crate::spatial::order::{locality_order, unpermuted};
    check_params(p)?;
    let p = &p.capped(input.positions.len());
    let order = locality_order(input.positions);
    let columns = Permuted::of(input, &order, None, p.method);
    input.pages.release();
    let sorted = columns.input(input);
    let (d, factors, outcomes) = detect_in_order(&sorted, p, progress).map_err(|e| match e {
        DetectError::Spatial(e) => DetectError::Spatial(e.in_file_order(&order)),
        e => e,
    })?;
    Ok(Detection {
        basis_u: unpermuted(&d.basis_u, &order),
        basis_v: unpermuted(&d.basis_v, &order),
        lambda2: unpermuted(&d.lambda2, &order),
        r_param: d.r_param.map(|r| unpermuted(&r, &order)),
        spectral_scales: Vec::new(),
        summary: summarise(&factors, &outcomes),
    })
}

/// The [`Summary`] of photons with these factors and outcomes ([`SummarySums`]).
pub fn summarise(factors: &[f32], outcomes: &[Outcome]) -> Summary {
    let mut sums = SummarySums::default();
    sums.add(factors, outcomes);
    sums.summary()
}

/// The sums a [`Summary`] is formed from, added tile by tile in any order: the summary does
/// not depend on it (its mean factor comes from an exact sum), so a map detected tile by tile
/// reports what the whole map does without keeping every photon's factor.
#[derive(Clone, Debug, Default)]
pub struct SummarySums {
    counts: Summary,
    factor: crate::tiles::ExactSum,
}

impl SummarySums {
    /// Adds photons with these factors and outcomes.
    pub fn add(&mut self, factors: &[f32], outcomes: &[Outcome]) {
        let s = &mut self.counts;
        for (&f, o) in factors.iter().zip(outcomes) {
            s.photons += 1;
            self.factor.add(f as f64);
            match o {
                Outcome::Measured => s.measured += 1,
                Outcome::TooFew => s.too_few += 1,
                Outcome::Coincident => s.coincident += 1,
                Outcome::Unconstrained => {}
            }
            if f < HELD_FACTOR {
                s.constrained += 1;
            }
        }
    }

    /// The summary of every photon added.
    pub fn summary(&self) -> Summary {
        let n = self.counts.photons;
        Summary {
            mean_factor: if n > 0 { self.factor.total() / n as f64 } else { 0.0 },
            ..self.counts.clone()
        }
    }
}

/// Photons whose factor is below this are measured again in a grown ball when theirs binds.
const GROWN_BELOW: f32 = 0.9;

/// Whether photon i's parameter ball of radius `radius` binds its neighbourhood `nb` from both
/// sides: two neighbours lie in its outer fifth on opposite sides of i (their offsets from i
/// in parameter space have a negative dot product). Where the map from parameters to the
/// surface stretches one way far more than the other (rays grazing a sphere's rim), the Kc
/// nearest photons in world space within the ball are a band right across it, whatever the
/// illumination: the band is the ball's image, and measuring it would hold the photon on a line
/// in smooth light. A ball that does not bind holds the Kc nearest photons well inside it
/// (within about 1/β of its radius when the map is isotropic), and one reached on one side
/// only is the edge of another set of photons that the ball is there to keep out (Fig. 3).
fn ball_binds(points: &PointSet, i: usize, nb: &Neighbours, radius: f32, outer: &mut Vec<[f64; 3]>) -> bool {
    let pi = points.params_of(i);
    let limit = (0.8 * radius as f64).powi(2);
    outer.clear();
    for j in nb.indices() {
        let pj = points.params_of(j as usize);
        let mut q = [0.0f64; 3];
        for (k, (a, b)) in pi.iter().zip(pj).enumerate().take(3) {
            q[k] = (*b - *a) as f64;
        }
        if q.iter().map(|x| x * x).sum::<f64>() > limit {
            if outer.iter().any(|o| o.iter().zip(&q).map(|(a, b)| a * b).sum::<f64>() < 0.0) {
                return true;
            }
            outer.push(q);
        }
    }
    false
}

/// [`detect`] on photons in the order given, with each photon's factor and outcome (in the
/// same order) for the report.
fn detect_in_order(
    input: &DetectInput,
    p: &DetectParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(Detection, Vec<f32>, Vec<Outcome>), DetectError> {
    let n = input.positions.len();
    let has_params = input.has_params();
    if p.method == Method::ParamPca && !has_params {
        return Err(DetectError::NoParameters { file: "<input>".into() });
    }
    // Only the paper's method searches in parameter space; the world-space methods (and the
    // 2009 baseline) leave no r_param, so `relax` runs them in world space throughout.
    let r_param = if has_params && p.method == Method::ParamPca {
        let points = input.points(true);
        Some(param_radius(&points, p.kc, p.k_density.unwrap_or(p.kc), p.beta, progress)?)
    } else {
        None
    };
    let normals_ok = input.normals.is_some_and(|ns| ns.iter().all(|&n| unit_normal(n).is_some()));
    let (points, index) = world_index(input, p.method, normals_ok)?;
    let order: Vec<u32> = index.as_ref().map_or_else(|| (0..n as u32).collect(), |ix| ix.order());
    let results =
        measure(input, &points, index.as_ref(), &order, r_param.as_deref(), p, &|_, _| true, progress);
    let mut d = Detection {
        basis_u: vec![[0.0; 3]; n],
        basis_v: vec![[0.0; 3]; n],
        lambda2: vec![0.0; n],
        r_param,
        spectral_scales: Vec::new(),
        summary: Summary::default(),
    };
    let mut factors = vec![0f32; n];
    let mut outcomes = vec![Outcome::Unconstrained; n];
    for (&i, m) in order.iter().zip(&results) {
        let i = i as usize;
        if let Some(r) = &mut d.r_param {
            r[i] = m.radius;
        }
        d.basis_u[i] = m.constraint.u;
        d.basis_v[i] = m.constraint.v;
        d.lambda2[i] = m.constraint.lambda2;
        factors[i] = m.constraint.factor;
        outcomes[i] = m.constraint.outcome;
    }
    Ok((d, factors, outcomes))
}

/// The point set the neighbourhood search of `method` runs over, and its index (`None` for
/// method `none` with usable normals: nothing is searched).
fn world_index<'a>(
    input: &DetectInput<'a>,
    method: Method,
    normals_ok: bool,
) -> Result<(PointSet<'a>, Option<SpatialIndex>), DetectError> {
    let (points, space) = match method {
        Method::ParamPca => (input.points(true), Some(Space::WorldParams)),
        Method::WorldPca | Method::Gradient => (input.points(false), Some(Space::World)),
        Method::None if normals_ok => (input.points(false), None),
        Method::None => (input.points(false), Some(Space::World)),
    };
    let index = match space {
        Some(s) => Some(SpatialIndex::build(&points, s)?),
        None => None,
    };
    Ok((points, index))
}

/// One photon's measurement: its constraint, the parameter radius finally used (0 without
/// one), and whether every search it made was certified.
#[derive(Clone, Copy, Debug)]
struct Measured {
    constraint: PhotonConstraint,
    radius: f32,
    certified: bool,
}

/// A certificate for one search: given the photon and the neighbours found, whether they are
/// the ones the whole map gives (always, over the whole map; docs/tiles.md in a tile).
type Certify<'c> = &'c (dyn Fn(usize, &Neighbours) -> bool + Sync);

/// Steps 2–3 of the module docs for the photons `queries` of `input` (labels of `points`,
/// which `index` is built over), each with the radius `r_param[i]` when given: the
/// constraint, the radius finally used, and whether `certify` accepted every search.
///
/// The neighbours are taken sorted by (distance, label), so every sum over them runs in an
/// order that depends only on the photons, not on the tree or the queries before: a tile
/// whose labels keep the whole map's order gets the same bits (docs/tiles.md).
// Long because each photon's search, constraint and ball growth run inside one parallel loop
// over chunks that shares its buffers and prefetches between them.
#[allow(clippy::too_many_arguments)]
fn measure(
    input: &DetectInput,
    points: &PointSet,
    index: Option<&SpatialIndex>,
    queries: &[u32],
    r_param: Option<&[f32]>,
    p: &DetectParams,
    certify: Certify,
    progress: &(dyn Fn(u64) + Sync),
) -> Vec<Measured> {
    let free = PhotonConstraint::free(DVec3::X, DVec3::Y, Outcome::Unconstrained);
    let mut results = vec![Measured { constraint: free, radius: 0.0, certified: true }; queries.len()];
    results.par_chunks_mut(CHUNK).zip(queries.par_chunks(CHUNK)).for_each(|(out, ids)| {
        let mut nb = Neighbours::with_capacity(p.kc);
        let (mut offsets, mut weights, mut scratch) = (Vec::new(), Vec::new(), Vec::new());
        let mut outer = Vec::new();
        for (o, (res, &i)) in out.iter_mut().zip(ids).enumerate() {
            let i = i as usize;
            // The photon arrays are in Z-order, not the index's: start loading a photon a few
            // places ahead, whose data could otherwise be a cache miss when its turn comes.
            if let Some(&a) = ids.get(o + crate::spatial::PREFETCH_AHEAD) {
                let a = a as usize;
                points.prefetch(a);
                if let Some(n) = input.normals.and_then(|ns| ns.get(a)) {
                    crate::spatial::prefetch(n);
                }
                if let Some(r) = r_param.and_then(|r| r.get(a)) {
                    crate::spatial::prefetch(r);
                }
            }
            let normal = input.normals.map(|ns| ns[i]);
            let Some(index) = index else {
                let (t1, t2) = tangent_basis(normal.and_then(unit_normal).unwrap_or(DVec3::Z));
                res.constraint = PhotonConstraint::free(t1, t2, Outcome::Unconstrained);
                continue;
            };
            let mut radius = r_param.map(|r| r[i]);
            let mut growths = 0;
            let mut certified = true;
            loop {
                index.knn(&points.query(i, radius), p.kc, &mut nb);
                certified &= certify(i, &nb);
                let xi = input.positions[i];
                offsets.clear();
                // The index's copy of the neighbours' positions, already in cache from the search.
                offsets.extend(nb.coords().iter().map(|xj| {
                    DVec3::new((xj[0] - xi[0]) as f64, (xj[1] - xi[1]) as f64, (xj[2] - xi[2]) as f64)
                }));
                let r2 = offsets.iter().map(|o| o.length_squared()).fold(0.0, f64::max);
                let hood = Neighbourhood { offsets: &offsets, r2, normal };
                let c = match p.method {
                    Method::ParamPca | Method::WorldPca => pca_constraint(&hood, p.noise),
                    Method::Gradient => {
                        weights.clear();
                        weights.extend(nb.indices().map(|j| {
                            input.flux.map_or(1.0, |f| f[j as usize].iter().map(|&c| c as f64).sum())
                        }));
                        gradient_constraint(&hood, &weights, p.gain as f64, &mut scratch)
                    }
                    Method::None => {
                        let (_, t1, t2) = hood.frame();
                        PhotonConstraint::free(t1, t2, Outcome::Unconstrained)
                    }
                };
                // A constrained photon whose ball binds measures the ball's shape, not the
                // illumination's: measure again in a ball twice as wide.
                match radius {
                    Some(r)
                        if growths < p.growths
                            && c.factor < GROWN_BELOW
                            && ball_binds(points, i, &nb, r, &mut outer) =>
                    {
                        radius = Some(r * 2.0);
                        growths += 1;
                    }
                    _ => {
                        *res = Measured { constraint: c, radius: radius.unwrap_or(0.0), certified };
                        break;
                    }
                }
            }
        }
        progress(ids.len() as u64);
    });
    results
}

mod tiled;
pub use tiled::{
    Assembly, RADIUS_PASS_BYTES, Radius, TileDetection, assemble, detect_tile, tiled, tiled_with,
};

#[cfg(test)]
pub(crate) mod tests;
