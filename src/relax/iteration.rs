//! One Jacobi iteration of relaxation over a neighbour index: every photon's step from one
//! snapshot of positions, the index kept up to date between iterations, and what each
//! iteration measured.

use crate::tiles::ExactSum;
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use super::RelaxParams;
use super::force::{clamp_step, nudge, project_on_basis, project_on_tangent, repulsion};

/// What one iteration did, for the per-iteration report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct IterationMeasure {
    /// Which iteration, from 0.
    pub iteration: usize,
    /// Coefficient of variation (sd/mean) of nearest-neighbour distances before the move; it
    /// falls from ≈ 0.52 (uniform random points in 2-D) toward ≈ 0.1–0.2 for blue noise.
    pub nn_cv: f64,
    /// Coefficient of variation of each photon's nearest-neighbour distance divided by its
    /// distance to the Kf-th (photons with r_K > 0): the same measure made local, so density
    /// variation (a caustic's bright core beside its sparse tail) does not swamp it.
    pub local_nn_cv: f64,
    /// Mean distance a photon moved, metres.
    pub mean_displacement: f64,
    /// Largest distance a photon moved, metres.
    pub max_displacement: f64,
    /// Photons that sat on another photon and were moved apart ([`iterate`]): an index built
    /// over them no longer fits the moved photons, and is rebuilt ([`index_positions`]).
    #[serde(skip)]
    pub separated: usize,
}

/// Coefficient of variation of a set of distances (0 for fewer than two).
pub fn coefficient_of_variation(d: &[f32]) -> f64 {
    if d.len() < 2 {
        return 0.0;
    }
    let n = d.len() as f64;
    let mean = d.iter().map(|&x| x as f64).sum::<f64>() / n;
    let var = d.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n;
    if mean > 0.0 { var.sqrt() / mean } else { 0.0 }
}

/// A neighbour index over one snapshot of photon positions.
pub trait NeighbourSearch: Sync {
    /// Replaces `out` with the indices of up to `k` nearest neighbours of photon `i`, not
    /// counting `i` itself, nearest first, as the current space defines them.
    fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>);

    /// The positions of the same neighbours as [`Self::neighbours`], in `xs` (by default read
    /// from `positions`, the snapshot the index was built over), in an order that may differ
    /// from nearest first but depends only on the queries made with `scratch` since it was
    /// made (so results never depend on the thread count). `scratch` is the search's reusable
    /// buffer: one per run of queries.
    fn neighbours_at(
        &self,
        i: usize,
        k: usize,
        positions: &[[f32; 3]],
        scratch: &mut crate::spatial::Neighbours,
        xs: &mut Vec<Vec3>,
    ) {
        let _ = scratch;
        let mut ids = Vec::with_capacity(k);
        self.neighbours(i, k, &mut ids);
        xs.clear();
        xs.extend(ids.iter().map(|&j| Vec3::from(positions[j as usize])));
    }

    /// Starts loading what a search for photon `i` will read (a hint; no effect by default).
    fn prefetch(&self, _i: usize) {}

    /// An order to visit photons in that keeps successive queries in nearby memory (every
    /// photon once); `None` for index order.
    fn order(&self) -> Option<Vec<u32>> {
        None
    }
}

/// The per-photon constraint: a basis (after `detect`) or just the surface normal.
#[derive(Clone, Copy, Debug)]
pub enum Constraint<'a> {
    /// Eq. 9 with the `basis_u` and `basis_v` columns.
    Basis {
        /// u_b per photon (Eq. 7).
        u: &'a [[f32; 3]],
        /// v_b per photon, scaled by its factor (Eq. 7).
        v: &'a [[f32; 3]],
    },
    /// Unconstrained motion in the tangent plane of the `normal` column.
    Tangent {
        /// The unit surface normal per photon.
        normal: &'a [[f32; 3]],
    },
}

pub(super) const CHUNK: usize = 4096;

/// Buffers [`iterate`] reuses from one iteration to the next, and the one thing it remembers:
/// each photon's first positive local spacing, which caps its step for the rest of the run.
/// Without that cap a photon on the edge of a set, whose neighbours all lie on one side, is
/// pushed outward every iteration by a step proportional to its growing r_K, and the set
/// grows geometrically (1000 iterations overflow f32); with it, an edge can still widen (plain
/// relaxation's known flaw) but by at most a fixed distance per iteration.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    step: Vec<[f32; 3]>,
    nn: Vec<f32>,
    ratio: Vec<f32>,
    /// Local spacing per slot of the last iteration.
    spacing: Vec<f32>,
    /// The farthest distance each slot's computation read (∞: it found fewer photons than it
    /// asked for).
    read: Vec<f32>,
    /// Per photon: the first positive spacing seen (∞ until then).
    limit: Vec<f32>,
    /// Per photon, of the last iteration: what [`PerPhoton`] describes.
    per_photon: PerPhoton,
}

/// What the last iteration measured of each photon, in photon order: the per-iteration
/// report is a function of these alone ([`IterationMeasure::of`]), so the parts of a tiled
/// run give the whole map's report (docs/tiles.md).
#[derive(Clone, Debug, Default)]
pub struct PerPhoton {
    /// Distance to the nearest neighbour (0 with none).
    pub nn: Vec<f32>,
    /// That distance over the distance to the Kf-th (NaN where r_K = 0).
    pub ratio: Vec<f32>,
    /// Length of the step (before any return to a surface).
    pub step: Vec<f32>,
    /// The farthest distance from the photon its step read (its Kf-th neighbour, or the 4 Kf-th
    /// when those all sat on it); ∞ when its search found fewer photons than it asked for.
    pub read: Vec<f32>,
}

impl Scratch {
    /// Each photon's step cap (metres) as remembered so far: `step_limit` times this.
    pub fn first_spacing(&self) -> &[f32] {
        &self.limit
    }

    /// What the last iteration measured of each photon.
    pub fn per_photon(&self) -> &PerPhoton {
        &self.per_photon
    }
}

/// What an iteration reads of the whole map besides a photon's neighbours, computed once from
/// the whole map so that a tile's photons move exactly as in the whole map (docs/tiles.md).
#[derive(Clone, Copy, Debug)]
pub struct MapWide<'a> {
    /// Each photon's label in the whole map's working order (its Z-order rank), which fixes
    /// the direction coincident photons are pushed apart in; `None`: the photon's index.
    pub labels: Option<&'a [u32]>,
    /// The whole map's mean photon spacing ([`map_spacing`]), metres.
    pub spacing: f32,
    /// Whether every photon of the map sits on one point (nothing moves).
    pub coincident: bool,
}

impl MapWide<'_> {
    /// The quantities of the map `positions` (the whole map, labelled by index).
    pub fn of(positions: &[[f32; 3]]) -> MapWide<'static> {
        MapWide {
            labels: None,
            spacing: map_spacing(positions),
            coincident: positions.iter().all(|x| *x == positions[0]),
        }
    }
}

impl IterationMeasure {
    /// The measures of iteration `iteration` from each photon's nearest-neighbour distance,
    /// its ratio to r_K (NaN: none) and its step length, in any order ([`MeasureSums`]).
    pub fn of(iteration: usize, nn: &[f32], ratio: &[f32], step: &[f32]) -> IterationMeasure {
        let mut sums = vec![MeasureSums::default()];
        MeasureSums::add_series(&mut sums, nn, ratio, step);
        sums[0].measure(iteration)
    }
}

/// The sums an [`IterationMeasure`] is formed from, added photon by photon in any order and
/// merged across tiles: the measure does not depend on either.
#[derive(Clone, Debug, Default)]
pub struct MeasureSums {
    photons: usize,
    nn: ExactSum,
    nn2: ExactSum,
    ratios: usize,
    ratio: ExactSum,
    ratio2: ExactSum,
    step: ExactSum,
    max_step: f32,
    on_another: usize,
}

impl MeasureSums {
    /// Adds one photon's nearest-neighbour distance, its ratio to r_K (NaN: none) and its step.
    pub fn add(&mut self, nn: f32, ratio: f32, step: f32) {
        self.photons += 1;
        // Squares of f32 values are exact in f64.
        self.nn.add(nn as f64);
        self.nn2.add(nn as f64 * nn as f64);
        if !ratio.is_nan() {
            self.ratios += 1;
            self.ratio.add(ratio as f64);
            self.ratio2.add(ratio as f64 * ratio as f64);
        }
        self.step.add(step as f64);
        self.max_step = self.max_step.max(step);
        self.on_another += usize::from(nn == 0.0);
    }

    /// Adds photons' series to `sums`, one per iteration: `nn`, `ratio` and `step` hold
    /// `sums.len()` values per photon (photon-major), added in parallel stretches of photons
    /// (the sums do not depend on the order).
    pub fn add_series(sums: &mut [MeasureSums], nn: &[f32], ratio: &[f32], step: &[f32]) {
        let r = sums.len();
        if r == 0 {
            return;
        }
        let stretch = r * (1 << 16);
        let parts: Vec<Vec<MeasureSums>> = nn
            .par_chunks(stretch)
            .zip(ratio.par_chunks(stretch))
            .zip(step.par_chunks(stretch))
            .map(|((nn, ratio), step)| {
                let mut part = vec![MeasureSums::default(); r];
                for (k, ((&d, &q), &l)) in nn.iter().zip(ratio).zip(step).enumerate() {
                    part[k % r].add(d, q, l);
                }
                part
            })
            .collect();
        for part in &parts {
            for (sum, p) in sums.iter_mut().zip(part) {
                sum.merge(p);
            }
        }
    }

    /// Adds another set of photons' sums.
    pub fn merge(&mut self, other: &MeasureSums) {
        self.photons += other.photons;
        self.ratios += other.ratios;
        for (a, b) in [
            (&mut self.nn, &other.nn),
            (&mut self.nn2, &other.nn2),
            (&mut self.ratio, &other.ratio),
            (&mut self.ratio2, &other.ratio2),
            (&mut self.step, &other.step),
        ] {
            a.merge(b);
        }
        self.max_step = self.max_step.max(other.max_step);
        self.on_another += other.on_another;
    }

    /// The measures of iteration `iteration` (displacements in the units the steps were in).
    pub fn measure(&self, iteration: usize) -> IterationMeasure {
        let n = self.photons;
        IterationMeasure {
            iteration,
            nn_cv: cv_of(n, &self.nn, &self.nn2),
            local_nn_cv: cv_of(self.ratios, &self.ratio, &self.ratio2),
            mean_displacement: if n > 0 { self.step.total() / n as f64 } else { 0.0 },
            max_displacement: self.max_step as f64,
            separated: if n > 1 { self.on_another } else { 0 },
        }
    }
}

/// Coefficient of variation from a count, a sum and a sum of squares (0 for fewer than two).
fn cv_of(n: usize, sum: &ExactSum, squares: &ExactSum) -> f64 {
    if n < 2 {
        return 0.0;
    }
    let mean = sum.total() / n as f64;
    let var = (squares.total() / n as f64 - mean * mean).max(0.0);
    if mean > 0.0 { var.sqrt() / mean } else { 0.0 }
}

/// One Jacobi iteration: computes every photon's step from `pos` with neighbours from `index`,
/// then moves all photons. Returns the measures of the iteration. The map-wide quantities are
/// taken from `pos` ([`MapWide::of`]); [`iterate_in`] is given them.
pub fn iterate(
    pos: &mut [[f32; 3]],
    index: &dyn NeighbourSearch,
    constraint: Constraint<'_>,
    p: &RelaxParams,
    iteration: usize,
    scratch: &mut Scratch,
) -> IterationMeasure {
    let wide = MapWide::of(pos);
    iterate_in(pos, index, constraint, p, iteration, scratch, &wide)
}

/// [`iterate`] for photons that are all or part of a map whose map-wide quantities are `wide`:
/// Eq. 8's repulsion over each photon's Kf nearest neighbours (summed nearest first, ties by
/// label, so the sum does not depend on the index), projected by Eq. 9 and clamped.
// Long because the per-photon step is computed inside one parallel loop over chunks whose
// buffers, prefetches and constraint a separate function would take a dozen arguments for.
#[allow(clippy::too_many_arguments)]
pub fn iterate_in(
    pos: &mut [[f32; 3]],
    index: &dyn NeighbourSearch,
    constraint: Constraint<'_>,
    p: &RelaxParams,
    iteration: usize,
    scratch: &mut Scratch,
    wide: &MapWide,
) -> IterationMeasure {
    let n = pos.len();
    // Kf as asked (capped at the whole map by the caller): a search that finds fewer did not
    // see all it needed, which a tile must know.
    let wanted = p.kf;
    let p = &p.capped(n);
    let Scratch { step, nn, ratio, spacing: spacing_slot, read, limit, per_photon } = scratch;
    step.resize(n, [0.0; 3]);
    nn.resize(n, 0.0);
    ratio.clear();
    ratio.resize(n, f32::NAN);
    spacing_slot.resize(n, 0.0);
    read.resize(n, 0.0);
    if limit.len() != n {
        limit.clear();
        limit.resize(n, f32::INFINITY);
    }
    let out = per_photon;
    for v in [&mut out.nn, &mut out.step, &mut out.read] {
        v.clear();
        v.resize(n, 0.0);
    }
    out.ratio.clear();
    out.ratio.resize(n, f32::NAN);
    // Photons that all sit on one point have no length to be separated by: nothing moves.
    if wide.coincident {
        return IterationMeasure { iteration, ..Default::default() };
    }
    let limit_of: &[f32] = limit;
    let snapshot: &[[f32; 3]] = pos;
    let label = |i: usize| wide.labels.map_or(i, |l| l[i] as usize);
    // Steps are computed in the index's order (slot k is photon order[k]), then applied.
    let order = index.order().filter(|o| o.len() == n).unwrap_or_else(|| (0..n as u32).collect());
    step.par_chunks_mut(CHUNK)
        .zip(nn.par_chunks_mut(CHUNK))
        .zip(ratio.par_chunks_mut(CHUNK))
        .zip(spacing_slot.par_chunks_mut(CHUNK))
        .zip(read.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, ((((steps, nns), ratios), spacings), reads))| {
            let mut xs = Vec::with_capacity(p.kf + 1);
            // Ordered: neighbours nearest first, ties by label, whatever the index.
            let mut found = crate::spatial::Neighbours::with_capacity(p.kf + 1);
            for (o, ((((s, d1), q), sp), rd)) in steps
                .iter_mut()
                .zip(nns.iter_mut())
                .zip(ratios.iter_mut())
                .zip(spacings.iter_mut())
                .zip(reads.iter_mut())
                .enumerate()
            {
                let i = order[c * CHUNK + o] as usize;
                // The photon arrays are in Z-order, not the index's: start loading a photon a
                // few places ahead, whose data could otherwise be a cache miss when its turn comes.
                if let Some(&a) = order.get(c * CHUNK + o + crate::spatial::PREFETCH_AHEAD) {
                    let a = a as usize;
                    index.prefetch(a);
                    crate::spatial::prefetch(&snapshot[a]);
                    crate::spatial::prefetch(&limit_of[a]);
                    match constraint {
                        Constraint::Basis { u, v } => {
                            crate::spatial::prefetch(&u[a]);
                            crate::spatial::prefetch(&v[a]);
                        }
                        Constraint::Tangent { normal } => crate::spatial::prefetch(&normal[a]),
                    }
                }
                index.neighbours_at(i, p.kf, snapshot, &mut found, &mut xs);
                let xi = Vec3::from(snapshot[i]);
                // The farthest and nearest neighbour.
                let (near, far) = xs.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &x| {
                    let d = xi.distance_squared(x);
                    (lo.min(d), hi.max(d))
                });
                let r_k = far.sqrt();
                *rd = if xs.len() < wanted { f32::INFINITY } else { r_k };
                *d1 = if xs.is_empty() { 0.0 } else { near.sqrt() };
                if r_k > 0.0 {
                    *q = *d1 / r_k;
                }
                let mut f = repulsion(xi, &xs, r_k, p.epsilon);
                if *d1 == 0.0 {
                    // Photons stacked on one point feel identical forces and would stay stacked:
                    // give each its own direction (fixed by its label, so runs are reproducible
                    // and a tile pushes it as the whole map does), scaled by the nearest
                    // distinct photon (looking a little further if all Kf coincide, then taking
                    // the map's mean spacing: a crowd of any size costs a bounded search per
                    // photon).
                    let scale = if r_k > 0.0 {
                        r_k
                    } else {
                        let (d, farthest) = distinct_distance(index, i, xi, snapshot, p.kf, wanted);
                        *rd = rd.max(farthest);
                        d.unwrap_or(wide.spacing)
                    };
                    f += nudge(label(i)) * (0.25 * scale);
                }
                let fb = match constraint {
                    Constraint::Basis { u, v } => project_on_basis(f, u[i].into(), v[i].into()),
                    Constraint::Tangent { normal } => project_on_tangent(f, normal[i].into()),
                };
                // The step limit: a fraction of the local photon spacing, never more than of
                // the first spacing this photon had (see [`Scratch`]).
                let spacing = r_k * (std::f32::consts::PI / xs.len().max(1) as f32).sqrt();
                *sp = spacing;
                let reach = if r_k > 0.0 { spacing.min(limit_of[i]) } else { limit_of[i] };
                *s = if reach.is_finite() { clamp_step(fb, p.step_limit * reach).into() } else { fb.into() };
            }
        });
    for (k, &i) in order.iter().enumerate() {
        let i = i as usize;
        let l = &mut limit[i];
        if *l == f32::INFINITY && spacing_slot[k] > 0.0 {
            *l = spacing_slot[k];
        }
        let s = Vec3::from(step[k]);
        out.step[i] = s.length();
        out.nn[i] = nn[k];
        out.ratio[i] = ratio[k];
        out.read[i] = read[k];
        let x = &mut pos[i];
        *x = (Vec3::from(*x) + s).into();
    }
    IterationMeasure::of(iteration, &out.nn, &out.ratio, &out.step)
}

/// [`NeighbourSearch`] over a [`crate::spatial::SpatialIndex`] built over `points`, excluding
/// the query photon; `radius` holds each photon's parameter-space radius (r_param) when the
/// index searches world + parameter space. Neighbour positions come from the index, so
/// `points.positions` must be the snapshot [`iterate`] is given.
pub struct IndexSearch<'a> {
    /// The index over `points`.
    pub index: &'a crate::spatial::SpatialIndex,
    /// The photons as this iteration sees them.
    pub points: &'a crate::spatial::PointSet<'a>,
    /// r_param per photon (Eq. 1), for an index over world + parameter space.
    pub radius: Option<&'a [f32]>,
}

thread_local! {
    static FOUND: std::cell::RefCell<crate::spatial::Neighbours> = Default::default();
}

impl IndexSearch<'_> {
    /// Searches the k nearest photons other than `i` through the buffer `found`, which then
    /// holds k + 1 (in its order: nearest first if it is ordered); returns the place of the
    /// one that is not among the k. The search asks for k + 1 *including* `i`, and the one
    /// left out is `i` if present, else the last of the k + 1 by (distance², index): the same
    /// k photons (i is either among the k + 1, or ranks after all of them), and the previous
    /// query's result then holds k + 1 candidates of this one, which gives the search its
    /// starting bound ([`crate::spatial::SpatialIndex::knn`]).
    fn search(&self, found: &mut crate::spatial::Neighbours, i: usize, k: usize) -> Option<usize> {
        let q = self.points.query(i, self.radius.map(|r| r[i]));
        self.index.knn(&q, k + 1, found);
        let items = found.as_slice();
        items.iter().position(|n| n.index as usize == i).or_else(|| {
            (items.len() > k)
                .then(|| (0..items.len()).reduce(|a, b| if items[a].before(&items[b]) { b } else { a }))
                .flatten()
        })
    }
}

impl NeighbourSearch for IndexSearch<'_> {
    fn prefetch(&self, i: usize) {
        self.points.prefetch(i);
        if let Some(r) = self.radius.and_then(|r| r.get(i)) {
            crate::spatial::prefetch(r);
        }
    }

    fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>) {
        out.clear();
        FOUND.with_borrow_mut(|found| {
            let left_out = self.search(found, i, k);
            out.extend(found.indices());
            if let Some(at) = left_out {
                out.remove(at);
            }
        });
    }

    fn neighbours_at(
        &self,
        i: usize,
        k: usize,
        _: &[[f32; 3]],
        found: &mut crate::spatial::Neighbours,
        xs: &mut Vec<Vec3>,
    ) {
        let left_out = self.search(found, i, k);
        // All k + 1 in one pass of known length, then the one left out (order kept).
        xs.clear();
        xs.extend(found.coords().iter().map(|&x| Vec3::from(x)));
        if let Some(at) = left_out {
            xs.remove(at);
        }
    }

    fn order(&self) -> Option<Vec<u32>> {
        Some(self.index.order())
    }
}

/// Iterations between full rebuilds of relaxation's index; in between, the index is refitted
/// to the moved photons ([`crate::spatial::SpatialIndex::refit`]), which is exact but lets
/// boxes overlap as photons drift. With the default 7 iterations per stage, each stage builds
/// once; measured by benches/stages.rs; see BENCHMARKS.md.
pub const REBUILD_EVERY: usize = 7;

/// Makes `index` hold `points` for relaxation's iteration `it`: built on the first,
/// rebuilt every [`REBUILD_EVERY`] iterations and after an iteration that moved photons
/// apart from a shared point (`separated`, [`IterationMeasure::separated`]: a tree built over
/// a crowd on one point has leaves that all overlap once it spreads, and a query would scan
/// the crowd), refitted otherwise (photons only move, by a fraction of their spacing). A new
/// index chooses its split axes with `split_scale` ([`crate::spatial::SpatialIndex::build_split`]).
pub fn index_positions(
    index: &mut Option<crate::spatial::SpatialIndex>,
    points: &crate::spatial::PointSet,
    space: crate::spatial::Space,
    split_scale: Option<f32>,
    it: usize,
    separated: bool,
) -> Result<(), crate::spatial::SpatialError> {
    match index {
        Some(ix) if !separated && !it.is_multiple_of(REBUILD_EVERY) => ix.refit(points),
        Some(ix) => ix.rebuild(points),
        None => {
            crate::spatial::SpatialIndex::build_split(points, space, split_scale).map(|ix| *index = Some(ix))
        }
    }
}

/// Flux diffusion (photon relaxation, 2009): every photon's flux moves the fraction `rate` of
/// the way toward the mean flux of its `kf` nearest neighbours, all from the same snapshot;
/// then each channel is rescaled (in f64) so its total is what it was, because k-nearest
/// neighbourhoods are not symmetric and the exchange alone would not conserve flux.
pub fn diffuse_flux(flux: &mut [[f32; 3]], search: &dyn NeighbourSearch, kf: usize, rate: f32) {
    let total = |f: &[[f32; 3]]| {
        f.iter().fold([0f64; 3], |t, x| [t[0] + x[0] as f64, t[1] + x[1] as f64, t[2] + x[2] as f64])
    };
    let before = total(flux);
    let snapshot = flux.to_vec();
    flux.par_iter_mut().enumerate().for_each_init(Vec::new, |ids, (i, f)| {
        search.neighbours(i, kf, ids);
        if ids.is_empty() {
            return;
        }
        let mut mean = [0f32; 3];
        for &j in ids.iter() {
            for c in 0..3 {
                mean[c] += snapshot[j as usize][c];
            }
        }
        for c in 0..3 {
            f[c] += rate * (mean[c] / ids.len() as f32 - f[c]);
        }
    });
    let after = total(flux);
    for c in 0..3 {
        if after[c] > 0.0 {
            let k = before[c] / after[c];
            flux.par_iter_mut().for_each(|f| f[c] = (f[c] as f64 * k) as f32);
        }
    }
}

/// Distance from photon `i` to the nearest photon not on top of it among its 4 Kf nearest;
/// `None` when all of those sit on it (a crowd, which would otherwise cost a search as large
/// as itself per photon: issue 31). Also the farthest distance the search read (∞ when it
/// found fewer than 4 `wanted`).
fn distinct_distance(
    index: &dyn NeighbourSearch,
    i: usize,
    xi: Vec3,
    pos: &[[f32; 3]],
    kf: usize,
    wanted: usize,
) -> (Option<f32>, f32) {
    let mut ids = Vec::new();
    index.neighbours(i, kf.max(1) * 4, &mut ids);
    let d: Vec<f32> = ids.iter().map(|&j| xi.distance(pos[j as usize].into())).collect();
    let farthest =
        if ids.len() < wanted.max(1) * 4 { f32::INFINITY } else { d.iter().fold(0.0f32, |m, &x| m.max(x)) };
    (d.iter().copied().find(|&d| d > 0.0), farthest)
}

/// The mean photon spacing of a map, √(A / n), with A the area of the bounding box's two
/// largest extents (photons lie on surfaces); the largest extent / n when the photons lie on
/// a line, and 0 when they all sit on one point (which leaves nothing to separate them by).
pub fn map_spacing(pos: &[[f32; 3]]) -> f32 {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in pos {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let mut e: Vec<f64> = (0..3).map(|a| (hi[a] as f64 - lo[a] as f64).max(0.0)).collect();
    e.sort_by(|a, b| b.total_cmp(a));
    let n = pos.len().max(1) as f64;
    let s = if e[1] > 0.0 { (e[0] * e[1] / n).sqrt() } else { e[0] / n };
    if s.is_finite() { s as f32 } else { 0.0 }
}
