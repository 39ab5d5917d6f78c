//! One pass of progressive refinement: the gather of fresh photons into the primal photons'
//! statistics, the relaxation toward constant flux, and the flux it assigns.

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{RefineError, RefineParams, column};
use crate::format::{MapView, name};
use crate::relax::{clamp_step, project_on_basis, project_on_tangent};
use crate::scene::material::luminance;
use crate::spatial::{BoxTree, Neighbours};
use crate::trace::Photons;

/// The constraint basis vectors (u_b, v_b) of Eq. 7, one pair per photon.
pub type Basis = (Vec<[f32; 3]>, Vec<[f32; 3]>);

/// The primal photons: the map's photons that refinement moves and re-weights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Primal {
    /// World-space positions, metres.
    pub positions: Vec<[f32; 3]>,
    /// Watts per RGB channel.
    pub flux: Vec<[f32; 3]>,
    /// Unit normals (gather only from fresh photons on the same side; move in the tangent
    /// plane when there is no basis).
    pub normals: Option<Vec<[f32; 3]>>,
    /// The constraint basis (u_b, v_b) of Eq. 7, when the map was detected.
    pub basis: Option<Basis>,
}

impl Primal {
    /// The photons of `map`.
    pub fn from_map(map: &MapView) -> Result<Primal, RefineError> {
        let u = map.column::<[f32; 3]>(name::BASIS_U)?;
        let v = map.column::<[f32; 3]>(name::BASIS_V)?;
        Ok(Primal {
            positions: map.positions().to_vec(),
            flux: map.flux().to_vec(),
            normals: map.column::<[f32; 3]>(name::NORMAL)?.map(<[_]>::to_vec),
            basis: u.zip(v).map(|(u, v)| (u.to_vec(), v.to_vec())),
        })
    }

    /// Number of primal photons.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Total flux per channel, W (summed in f64).
    pub fn total_flux(&self) -> [f64; 3] {
        self.flux.iter().fold([0.0; 3], |s, f| [s[0] + f[0] as f64, s[1] + f[1] as f64, s[2] + f[2] as f64])
    }
}

/// Each primal photon's accumulated statistics: the flux of the fresh photons that fell in its
/// cell, and the passes that flux stands for.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Statistics {
    /// Accumulated flux τ_i, W per channel, summed over passes.
    pub tau: Vec<[f32; 3]>,
    /// Passes P_i the flux stands for (fewer than the run's after the photon moved).
    pub passes: Vec<f32>,
}

impl Statistics {
    /// The statistics before the first pass: each photon's own flux φ_i standing for
    /// `prior_passes` passes (τ_i = w·φ_i, P_i = w; none when w is 0).
    pub fn start(flux: &[[f32; 3]], prior_passes: f32) -> Statistics {
        Self::start_weighted(flux, &vec![prior_passes; flux.len()])
    }

    /// [`Self::start`] with a weight per photon: τ_i = w_i·φ_i, P_i = w_i.
    pub fn start_weighted(flux: &[[f32; 3]], weights: &[f32]) -> Statistics {
        Statistics {
            tau: flux.iter().zip(weights).map(|(f, &w)| f.map(|c| c * w)).collect(),
            passes: weights.to_vec(),
        }
    }

    /// The statistics a refined map carries, if it has them.
    pub fn from_map(map: &MapView) -> Result<Option<Statistics>, RefineError> {
        let (Some(tau), Some(passes)) =
            (map.column::<[f32; 3]>(column::TAU)?, map.column::<f32>(column::PASSES)?)
        else {
            return Ok(None);
        };
        Ok(Some(Statistics { tau: tau.to_vec(), passes: passes.to_vec() }))
    }

    /// The flux estimate of primal photon i's cell, W per channel: τ_i / P_i (zero before any
    /// pass).
    pub fn cell_flux(&self, i: usize) -> Vec3 {
        if self.passes[i] > 0.0 { Vec3::from(self.tau[i]) / self.passes[i] } else { Vec3::ZERO }
    }
}

/// The measures of one pass (kept in the refine record).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PassMeasure {
    /// Passes done in all.
    pub pass: u64,
    /// Fresh photons this pass stored.
    pub fresh_stored: u64,
    /// Mean number of fresh photons a primal photon gathered.
    pub gathered_per_photon: f64,
    /// Mean step of the relaxation, metres (per iteration).
    pub mean_step: f64,
    /// Coefficient of variation of the primal photons' flux (luminance) after the pass: 0 when
    /// every photon carries the same flux, the goal of the relaxation.
    pub flux_cv: f64,
    /// Seconds (absent under SOURCE_DATE_EPOCH).
    pub seconds: Option<f64>,
}

/// Neighbours a fresh photon's nearest-primal search looks at for one on its side of the
/// surface.
const SIDE_SEARCH: usize = 8;

/// Step 2 of a pass: every fresh photon adds its flux to the primal photon nearest to it (among
/// the 8 nearest, the first on its side of the surface): each primal photon
/// gathers the flux that fell in its Voronoi cell, whose mean over passes converges to the
/// cell's exact flux ∫ E dA. `tree` indexes `primal.positions` (built once, and again only
/// after the photons move). Returns the mean number of fresh photons a primal photon gathered.
pub fn gather(stats: &mut Statistics, primal: &Primal, tree: &BoxTree, fresh: &Photons) -> f64 {
    gather_cells(stats, primal, tree, fresh).0
}

/// [`gather`], also returning each fresh photon's primal photon (`None`: none on its side).
pub fn gather_cells(
    stats: &mut Statistics,
    primal: &Primal,
    tree: &BoxTree,
    fresh: &Photons,
) -> (f64, Vec<Option<u32>>) {
    let normals = primal.normals.as_deref();
    let n = primal.len();
    // Queried in Z-order of the fresh photons, so consecutive searches walk the same leaves
    // (in emission order each one misses the cache); the owners do not depend on the order.
    let order = crate::spatial::order::locality_order(&fresh.position);
    let in_order: Vec<Option<u32>> = order
        .par_iter()
        .map(|&j| j as usize)
        .map_init(
            || Neighbours::with_capacity(SIDE_SEARCH),
            |nb, j| {
                let side = Vec3::from(fresh.normal[j]);
                let on_side = |i: &u32| normals.is_none_or(|nm| Vec3::from(nm[*i as usize]).dot(side) > 0.5);
                // The nearest alone first: almost always on the same side, and a 1-NN search
                // costs a fraction of an 8-NN one.
                tree.knn(fresh.position[j], 1, f32::INFINITY, nb);
                if let Some(i) = nb.indices().next().filter(on_side) {
                    return Some(i);
                }
                tree.knn(fresh.position[j], SIDE_SEARCH, f32::INFINITY, nb);
                nb.indices().find(on_side)
            },
        )
        .collect();
    let mut owner = vec![None; fresh.len()];
    for (&j, o) in order.iter().zip(in_order) {
        owner[j as usize] = o;
    }
    let mut sum = vec![[0.0f64; 3]; n];
    let mut gathered = 0u64;
    for (j, o) in owner.iter().enumerate() {
        if let Some(i) = o {
            let f = fresh.flux[j];
            let s = &mut sum[*i as usize];
            for c in 0..3 {
                s[c] += f[c] as f64;
            }
            gathered += 1;
        }
    }
    for ((t, s), passes) in stats.tau.iter_mut().zip(&sum).zip(&mut stats.passes) {
        for c in 0..3 {
            t[c] = (t[c] as f64 + s[c]) as f32;
        }
        *passes += 1.0;
    }
    (gathered as f64 / n.max(1) as f64, owner)
}

/// Each primal photon's squared distance to its Kf-th neighbour, and its neighbours, from one
/// tree over the current positions.
pub(super) fn neighbourhoods(positions: &[[f32; 3]], kf: usize) -> (Vec<f32>, Vec<Vec<u32>>) {
    let tree = BoxTree::build(positions);
    let k = kf.min(positions.len().saturating_sub(1)).max(1);
    positions
        .par_iter()
        .enumerate()
        .map_init(
            || Neighbours::with_capacity(k + 1),
            |nb, (i, &x)| {
                tree.knn(x, k + 1, f32::INFINITY, nb);
                let ids: Vec<u32> = nb.indices().filter(|&j| j as usize != i).take(k).collect();
                let r2 = ids
                    .iter()
                    .map(|&j| Vec3::from(positions[j as usize]).distance_squared(x.into()))
                    .fold(0.0, f32::max);
                (r2, ids)
            },
        )
        .unzip()
}

/// Step 3 of a pass, one iteration: Eq. 8's repulsion over the Kf nearest primal photons
/// with the pairwise rest length s_ij = (s_i + s_j)/2, s_i = r_i·sqrt(φ̄/φ_i) (φ_i the cell
/// flux's luminance, r_i the distance to the Kf-th neighbour, s_i bounded to [½, 2]·r_i),
/// projected onto the constraint basis (Eq. 9) or the tangent plane, the step at most
/// `step_limit` of the local spacing. A photon that moves by δ keeps the share
/// max(0, 1 − |δ|/spacing) of its statistics. Returns the mean step, metres.
pub fn relax_toward_flux(primal: &mut Primal, stats: &mut Statistics, p: &RefineParams) -> f64 {
    let n = primal.len();
    let (r2, ids) = neighbourhoods(&primal.positions, p.kf);
    let phi: Vec<f32> = (0..n).map(|i| luminance(stats.cell_flux(i))).collect();
    let mean = phi.iter().map(|&f| f as f64).sum::<f64>() / n.max(1) as f64;
    if mean <= 0.0 {
        return 0.0;
    }
    let rest: Vec<f32> = (0..n)
        .map(|i| {
            let r = r2[i].sqrt();
            let ratio = if phi[i] > 0.0 { (mean as f32 / phi[i]).sqrt() } else { 2.0 };
            r * ratio.clamp(0.5, 2.0)
        })
        .collect();
    let snapshot = &primal.positions;
    let steps: Vec<Vec3> = (0..n)
        .into_par_iter()
        .map(|i| {
            let xi = Vec3::from(snapshot[i]);
            let nb = &ids[i];
            if nb.is_empty() || r2[i] <= 0.0 {
                return Vec3::ZERO;
            }
            // Eq. 8 with each pair's own rest length in place of r_K.
            let f = nb
                .iter()
                .map(|&j| {
                    let d = xi - Vec3::from(snapshot[j as usize]);
                    let l = d.length();
                    let s = 0.5 * (rest[i] + rest[j as usize]);
                    if l > 0.0 { d * (s / (l + 1e-3 * s) - 1.0) } else { Vec3::ZERO }
                })
                .sum::<Vec3>()
                / nb.len() as f32;
            let fb = match (&primal.basis, &primal.normals) {
                (Some((u, v)), _) => project_on_basis(f, u[i].into(), v[i].into()),
                (None, Some(normal)) => project_on_tangent(f, normal[i].into()),
                (None, None) => f,
            };
            let spacing = r2[i].sqrt() * (std::f32::consts::PI / nb.len() as f32).sqrt();
            clamp_step(fb, p.step_limit * spacing)
        })
        .collect();
    let mut sum = 0.0f64;
    for (i, s) in steps.iter().enumerate() {
        let l = s.length();
        sum += l as f64;
        primal.positions[i] = (Vec3::from(primal.positions[i]) + *s).into();
        // The cell moved by l; about l/(spacing) of its area is another's now.
        let spacing = r2[i].sqrt() * (std::f32::consts::PI / p.kf as f32).sqrt();
        let keep = if spacing > 0.0 { (1.0 - l / spacing).max(0.0) } else { 1.0 };
        stats.passes[i] *= keep;
        stats.tau[i] = (Vec3::from(stats.tau[i]) * keep).into();
    }
    sum / n.max(1) as f64
}

/// Step 4 of a pass: each primal photon's flux is its cell's estimate `raw[i]` (τ_i / P_i, or
/// the hierarchy's: [`super::Cells::leaf_flux`]), scaled per
/// channel so the total is `total` (a channel with no estimate keeps its flux). Returns the
/// coefficient of variation of the photons' flux luminance.
pub fn set_flux(primal: &mut Primal, raw: &[Vec3], total: [f64; 3]) -> f64 {
    let sums = raw.iter().fold([0.0f64; 3], |s, f| [s[0] + f.x as f64, s[1] + f.y as f64, s[2] + f.z as f64]);
    for c in 0..3 {
        if sums[c] > 0.0 {
            let scale = total[c] / sums[c];
            for (f, r) in primal.flux.iter_mut().zip(raw) {
                f[c] = (r[c] as f64 * scale) as f32;
            }
        }
    }
    let lum: Vec<f64> = primal.flux.iter().map(|f| luminance(Vec3::from(*f)) as f64).collect();
    let mean = lum.iter().sum::<f64>() / lum.len().max(1) as f64;
    if mean <= 0.0 {
        return 0.0;
    }
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64;
    var.sqrt() / mean
}
