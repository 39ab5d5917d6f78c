//! Relaxation (Eq. 8–9) and collapse: photons repel their nearest neighbours until they form
//! a blue-noise set, each moving only within its constraint basis.
//!
//! One iteration is Jacobi style: every photon's force is computed from the same snapshot of
//! positions, then all photons move, then the neighbour index is brought up to date (refitted
//! to the moved photons, rebuilt every [`REBUILD_EVERY`] iterations). Motion lies in the
//! photon's tangent plane, so photons on planar receivers stay on them; flux never changes, so
//! the total flux is preserved exactly.

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

/// Relaxation parameters; defaults are the paper's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RelaxParams {
    /// R: number of iterations.
    pub iterations: usize,
    /// Kf: neighbours in the repulsion force.
    pub kf: usize,
    /// ε of Eq. 8, as a fraction of r_K so the force does not depend on the scene's scale.
    pub epsilon: f32,
    /// Largest step, as a fraction of the mean photon spacing r_K·sqrt(π/Kf) around the photon,
    /// so no photon jumps past its neighbours.
    pub step_limit: f32,
    /// The 2009 method's flux diffusion, per iteration: each photon's flux moves this fraction
    /// of the way toward the mean of its Kf neighbours' ([`diffuse_flux`]); 0 (the default)
    /// leaves every photon's flux untouched.
    pub flux_diffusion: f32,
}

impl Default for RelaxParams {
    fn default() -> Self {
        RelaxParams { iterations: 7, kf: 16, epsilon: 1e-3, step_limit: 0.5, flux_diffusion: 0.0 }
    }
}

/// Eq. 8: repulsion force on a photon at `xi` from its Kf nearest neighbours, where `r_k` is
/// the distance to the Kf-th. A neighbour at distance d pushes with magnitude ≈ r_K − d, so the
/// force vanishes when the neighbours sit evenly on the circle of radius r_K. A coincident
/// neighbour has no direction and adds nothing ([`iterate`] separates coincident photons).
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

/// What one iteration did, for the per-iteration report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct IterationMeasure {
    pub iteration: usize,
    /// Coefficient of variation (sd/mean) of nearest-neighbour distances before the move; it
    /// falls from ≈ 0.52 (uniform random points in 2-D) toward ≈ 0.1–0.2 for blue noise.
    pub nn_cv: f64,
    /// Coefficient of variation of each photon's nearest-neighbour distance divided by its
    /// distance to the Kf-th (photons with r_K > 0): the same measure made local, so density
    /// variation (a caustic's bright core beside its sparse tail) does not swamp it.
    pub local_nn_cv: f64,
    pub mean_displacement: f64,
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
    Basis { u: &'a [[f32; 3]], v: &'a [[f32; 3]] },
    /// Unconstrained motion in the tangent plane of the `normal` column.
    Tangent { normal: &'a [[f32; 3]] },
}

const CHUNK: usize = 4096;

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
    /// Local spacing per slot of the last iteration.
    spacing: Vec<f32>,
    /// Per photon: the first positive spacing seen (∞ until then).
    limit: Vec<f32>,
}

impl Scratch {
    /// Each photon's step cap (metres) as remembered so far: `step_limit` times this.
    pub fn first_spacing(&self) -> &[f32] {
        &self.limit
    }
}

/// One Jacobi iteration: computes every photon's step from `pos` with neighbours from `index`,
/// then moves all photons. Returns the measures of the iteration.
pub fn iterate(
    pos: &mut [[f32; 3]],
    index: &dyn NeighbourSearch,
    constraint: Constraint<'_>,
    p: &RelaxParams,
    iteration: usize,
    scratch: &mut Scratch,
) -> IterationMeasure {
    let n = pos.len();
    let p = &p.capped(n);
    let Scratch { step, nn, spacing: spacing_slot, limit } = scratch;
    step.resize(n, [0.0; 3]);
    nn.resize(n, 0.0);
    spacing_slot.resize(n, 0.0);
    if limit.len() != n {
        limit.clear();
        limit.resize(n, f32::INFINITY);
    }
    let limit_of: &[f32] = limit;
    let mut ratio = vec![f32::NAN; n];
    // Photons that all sit on one point have no length to be separated by: nothing moves.
    if pos.iter().all(|x| *x == pos[0]) {
        return IterationMeasure { iteration, ..Default::default() };
    }
    let snapshot: &[[f32; 3]] = pos;
    let mean_spacing = std::sync::OnceLock::new();
    // Steps are computed in the index's order (slot k is photon order[k]), then applied.
    let order = index.order().filter(|o| o.len() == n).unwrap_or_else(|| (0..n as u32).collect());
    step.par_chunks_mut(CHUNK)
        .zip(nn.par_chunks_mut(CHUNK))
        .zip(ratio.par_chunks_mut(CHUNK))
        .zip(spacing_slot.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, (((steps, nns), ratios), spacings))| {
            let mut xs = Vec::with_capacity(p.kf + 1);
            // A fresh buffer per chunk: the order neighbours come in depends only on the chunk.
            let mut found = crate::spatial::Neighbours::unordered(0);
            for (o, (((s, d1), q), sp)) in steps
                .iter_mut()
                .zip(nns.iter_mut())
                .zip(ratios.iter_mut())
                .zip(spacings.iter_mut())
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
                // The farthest and nearest neighbour (the search need not sort them).
                let (near, far) = xs.iter().fold((f32::INFINITY, 0.0f32), |(lo, hi), &x| {
                    let d = xi.distance_squared(x);
                    (lo.min(d), hi.max(d))
                });
                let r_k = far.sqrt();
                *d1 = if xs.is_empty() { 0.0 } else { near.sqrt() };
                if r_k > 0.0 {
                    *q = *d1 / r_k;
                }
                let mut f = repulsion(xi, &xs, r_k, p.epsilon);
                if *d1 == 0.0 {
                    // Photons stacked on one point feel identical forces and would stay stacked:
                    // give each its own direction (fixed by its index, so runs are reproducible),
                    // scaled by the nearest distinct photon (looking a little further if all Kf
                    // coincide, then taking the map's mean spacing: a crowd of any size costs
                    // a bounded search per photon).
                    let scale = if r_k > 0.0 {
                        r_k
                    } else {
                        distinct_distance(index, i, xi, snapshot, p.kf)
                            .unwrap_or_else(|| *mean_spacing.get_or_init(|| map_spacing(snapshot)))
                    };
                    f += nudge(i) * (0.25 * scale);
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
    for (&i, &sp) in order.iter().zip(spacing_slot.iter()) {
        let l = &mut limit[i as usize];
        if *l == f32::INFINITY && sp > 0.0 {
            *l = sp;
        }
    }
    ratio.retain(|q| !q.is_nan());
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for (&i, s) in order.iter().zip(step.iter()) {
        let l = Vec3::from(*s).length() as f64;
        sum += l;
        max = max.max(l);
        let x = &mut pos[i as usize];
        *x = (Vec3::from(*x) + Vec3::from(*s)).into();
    }
    IterationMeasure {
        iteration,
        nn_cv: coefficient_of_variation(nn),
        local_nn_cv: coefficient_of_variation(&ratio),
        mean_displacement: if n > 0 { sum / n as f64 } else { 0.0 },
        max_displacement: max,
        separated: if n > 1 { nn.iter().filter(|&&d| d == 0.0).count() } else { 0 },
    }
}

/// What can stop the relax or collapse stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RelaxError {
    #[error(transparent)]
    Format(#[from] crate::format::FormatError),
    #[error(transparent)]
    Spatial(#[from] crate::spatial::SpatialError),
    #[error("{file}: {message}")]
    Input { file: String, message: String },
    #[error("{file}: {source}")]
    Photons { file: String, source: crate::spatial::SpatialError },
}

/// The most iterations one `relax` runs. Relaxation settles within tens of iterations (the
/// paper runs 7 + 7), so more than this is a mistyped count: `-R 1000000000` is refused here
/// instead of aborting on its allocation (issue 31, item 4).
pub const MAX_ITERATIONS: usize = 10_000;

impl RelaxParams {
    /// These parameters with Kf capped at `photons` − 1 (at least 1): a photon has no more
    /// neighbours than that, so the result is the same without buffers sized for the request
    /// (issue 31, item 6).
    pub fn capped(&self, photons: usize) -> RelaxParams {
        RelaxParams { kf: self.kf.min(photons.saturating_sub(1).max(1)), ..*self }
    }
}

/// Which neighbours relaxation uses, from the map's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RelaxSpace {
    /// Before collapse: world-space neighbours within each photon's r_param in parameter
    /// space, exactly as `detect` restricted them.
    WorldParams,
    /// After collapse, or without trajectory parameters: plain world-space neighbours.
    World,
}

/// The outcome of relaxing a map: new positions and what each iteration did.
pub struct Relaxed {
    pub positions: Vec<[f32; 3]>,
    pub space: RelaxSpace,
    /// False when the map has no constraint basis and photons moved freely in their tangent plane.
    pub constrained: bool,
    pub measures: Vec<IterationMeasure>,
    /// New surface normals when photons were returned to curved surfaces ([`relax_map_on`]).
    pub normals: Option<Vec<[f32; 3]>>,
    /// Moves refused because the photon's surface was not found near the moved point.
    pub refused_moves: u64,
    /// Diffused flux, when `flux_diffusion` > 0.
    pub flux: Option<Vec<[f32; 3]>>,
}

/// [`NeighbourSearch`] over a [`crate::spatial::SpatialIndex`] built over `points`, excluding
/// the query photon; `radius` holds each photon's parameter-space radius (r_param) when the
/// index searches world + parameter space. Neighbour positions come from the index, so
/// `points.positions` must be the snapshot [`iterate`] is given.
pub struct IndexSearch<'a> {
    pub index: &'a crate::spatial::SpatialIndex,
    pub points: &'a crate::spatial::PointSet<'a>,
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
/// the crowd), refitted otherwise (photons only move, by a fraction of their spacing).
pub fn index_positions(
    index: &mut Option<crate::spatial::SpatialIndex>,
    points: &crate::spatial::PointSet,
    space: crate::spatial::Space,
    it: usize,
    separated: bool,
) -> Result<(), crate::spatial::SpatialError> {
    match index {
        Some(ix) if !separated && !it.is_multiple_of(REBUILD_EVERY) => ix.refit(points),
        Some(ix) => ix.rebuild(points),
        None => crate::spatial::SpatialIndex::build(points, space).map(|ix| *index = Some(ix)),
    }
}

/// Relaxes every photon of `map` for `p.iterations` iterations (Eq. 8–9), calling
/// `on_iteration` after each. The map's state picks the space ([`RelaxSpace`]); its
/// `basis_u`/`basis_v` columns constrain the motion, or, without them, its `normal` column
/// keeps photons in their tangent plane.
pub fn relax_map(
    map: &crate::format::MapView,
    p: &RelaxParams,
    on_iteration: impl FnMut(&IterationMeasure),
) -> Result<Relaxed, RelaxError> {
    relax_map_on(map, p, None, on_iteration)
}

/// [`relax_map`], and with a scene, photons that moved are returned to their surface (the
/// `surface` column names it) by [`return_to_surface`], and their normals follow: photons on
/// curved receivers stay on them. A move whose surface is not found is refused.
pub fn relax_map_on(
    map: &crate::format::MapView,
    p: &RelaxParams,
    scene: Option<&crate::scene::Scene>,
    mut on_iteration: impl FnMut(&IterationMeasure),
) -> Result<Relaxed, RelaxError> {
    use crate::format::{State, name};
    use crate::spatial::order::{locality_order, permuted, unpermuted};
    use crate::spatial::{ParamColumn, PointSet, Space, SpatialIndex};
    let input = |message: String| RelaxError::Input { file: map.file_name().to_string(), message };
    if p.kf == 0 {
        return Err(input("Kf must be at least 1".into()));
    }
    if p.iterations > MAX_ITERATIONS {
        return Err(input(format!(
            "{} iterations requested; at most {MAX_ITERATIONS} are allowed (relaxation settles within tens)",
            p.iterations
        )));
    }
    let p = &p.capped(map.len());
    let meta = map.info();
    // Photons are worked on in spatial order (see [`crate::spatial::order`]): every column
    // the iterations read is relabelled here, and what they change is put back at the end.
    let order = locality_order(map.positions());
    let sorted = |column: Option<&[[f32; 3]]>| column.map(|c| permuted(c, &order, 1));
    let basis_u = sorted(map.column::<[f32; 3]>(name::BASIS_U)?);
    let basis_v = sorted(map.column::<[f32; 3]>(name::BASIS_V)?);
    let normal = sorted(map.column::<[f32; 3]>(name::NORMAL)?);
    let (basis_u, basis_v, normal) = (basis_u.as_deref(), basis_v.as_deref(), normal.as_deref());
    let constraint = match (basis_u, basis_v, normal) {
        (Some(u), Some(v), _) => Constraint::Basis { u, v },
        (_, _, Some(normal)) => Constraint::Tangent { normal },
        _ => {
            return Err(input(
                "relax needs a constraint basis (run `photonkit detect`) or a 'normal' column to keep \
                 photons on their surfaces"
                    .into(),
            ));
        }
    };
    let r_param = map.column::<f32>(name::R_PARAM)?.map(|r| permuted(r, &order, 1));
    let r_param = r_param.as_deref();
    let params = match map.spec(name::PARAMS) {
        Some(c) => {
            let values = bytemuck::try_cast_slice::<u8, f32>(map.column_bytes(name::PARAMS).unwrap_or(&[]))
                .map_err(|e| input(format!("params column: {e}")))?;
            let stride = c.components as usize;
            if values.len() != stride * order.len() {
                return Err(input(format!(
                    "params column holds {} values, expected {}",
                    values.len(),
                    stride * order.len()
                )));
            }
            Some((permuted(values, &order, stride), stride))
        }
        None => None,
    };
    let dims: Vec<u32> = meta.emitters.iter().map(|e| e.param_dims).collect();
    let emitters = map.column::<u16>(name::EMITTER)?.map(|e| permuted(e, &order, 1));
    let emitters = emitters.as_deref();
    // A wavelength component enters distances with the scale detect gave it (the one its
    // r_param was measured in; docs/spectral.md).
    let params = match params {
        Some((values, stride)) if meta.emitters.iter().any(|e| e.is_spectral()) => {
            let factors: Vec<Vec<f32>> = meta.emitters.iter().map(|e| e.param_scales()).collect();
            let column = ParamColumn { values: &values, stride, dims: &dims };
            Some((column.scaled(emitters, &factors), stride))
        }
        p => p,
    };
    let params = params.as_ref().map(|(v, s)| (v.as_slice(), *s));
    let space = match (meta.state, r_param, params) {
        (State::Detected, Some(_), Some(_)) => RelaxSpace::WorldParams,
        _ => RelaxSpace::World,
    };
    let mut positions = permuted(map.positions(), &order, 1);
    // Coordinates far from 1 (near 1e30, or 1e-30) overflow or underflow squared distances in
    // f32; without a scene to return to, the photons are worked on scaled by a power of two
    // (exact) and scaled back at the end (issue 31, item 7).
    let scale = if scene.is_none() { working_scale(&positions) } else { 1.0 };
    if scale != 1.0 {
        positions.iter_mut().flatten().for_each(|x| *x *= scale);
    }
    let mut next = positions.clone();
    let surfaces = map.column::<u32>(name::SURFACE)?.map(|s| permuted(s, &order, 1));
    let surfaces = surfaces.as_deref();
    let mut normals: Option<Vec<[f32; 3]>> = match (scene, surfaces, normal) {
        (Some(_), Some(_), Some(n)) => Some(n.to_vec()),
        _ => None,
    };
    let mut refused_moves = 0u64;
    let mut flux: Option<Vec<[f32; 3]>> = (p.flux_diffusion > 0.0).then(|| permuted(map.flux(), &order, 1));
    let mut scratch = Scratch::default();
    let mut measures = Vec::with_capacity(p.iterations);
    let mut index: Option<SpatialIndex> = None;
    for it in 0..p.iterations {
        let points = PointSet {
            positions: &positions,
            params: match space {
                RelaxSpace::WorldParams => {
                    params.map(|(values, stride)| ParamColumn { values, stride, dims: &dims })
                }
                RelaxSpace::World => None,
            },
            emitters: if space == RelaxSpace::WorldParams { emitters } else { None },
        };
        let sp = if space == RelaxSpace::WorldParams { Space::WorldParams } else { Space::World };
        let separated = measures.last().is_some_and(|m: &IterationMeasure| m.separated > 0);
        index_positions(&mut index, &points, sp, it, separated).map_err(|e| RelaxError::Photons {
            file: map.file_name().to_string(),
            source: e.in_file_order(&order),
        })?;
        let search = IndexSearch {
            index: index.as_ref().expect("built above"),
            points: &points,
            radius: if space == RelaxSpace::WorldParams { r_param } else { None },
        };
        // The index borrows `positions`; `iterate` moves a copy, then the two swap.
        next.copy_from_slice(&positions);
        let m = iterate(&mut next, &search, constraint, p, it, &mut scratch);
        if let Some(f) = flux.as_mut() {
            diffuse_flux(f, &search, p.kf, p.flux_diffusion);
        }
        if let (Some(scene), Some(surf), Some(ns)) = (scene, surfaces, normals.as_mut()) {
            refused_moves += back_to_surfaces(scene, surf, &positions, &mut next, ns);
        }
        std::mem::swap(&mut positions, &mut next);
        let m = IterationMeasure {
            mean_displacement: m.mean_displacement / scale as f64,
            max_displacement: m.max_displacement / scale as f64,
            ..m
        };
        on_iteration(&m);
        measures.push(m);
    }
    if scale != 1.0 {
        positions.iter_mut().flatten().for_each(|x| *x /= scale);
    }
    Ok(Relaxed {
        positions: unpermuted(&positions, &order),
        space,
        constrained: matches!(constraint, Constraint::Basis { .. }),
        measures,
        normals: normals.map(|n| unpermuted(&n, &order)),
        refused_moves,
        flux: flux.map(|f| unpermuted(&f, &order)),
    })
}

/// The power of two relax scales `positions` by so that their largest coordinate lies within
/// 2^±40 of 1, where squared distances between them neither overflow nor underflow in f32
/// (1 when it already does, or when every coordinate is 0 or non-finite).
fn working_scale(positions: &[[f32; 3]]) -> f32 {
    let far = positions.iter().flatten().filter(|x| x.is_finite()).fold(0f32, |m, x| m.max(x.abs()));
    if far == 0.0 || (2f32.powi(-40)..=2f32.powi(40)).contains(&far) {
        return 1.0;
    }
    2f32.powi(-(far.log2().floor() as i32).clamp(-126, 126))
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

/// Returns every moved photon of `moved` to its surface, or back to `before` when its surface
/// is not found; updates `normals`. Returns the number of refused moves.
fn back_to_surfaces(
    scene: &crate::scene::Scene,
    surfaces: &[u32],
    before: &[[f32; 3]],
    moved: &mut [[f32; 3]],
    normals: &mut [[f32; 3]],
) -> u64 {
    moved
        .par_iter_mut()
        .zip(normals.par_iter_mut())
        .enumerate()
        .map(|(i, (x, n))| {
            let (old, new) = (Vec3::from(before[i]), Vec3::from(*x));
            let step = old.distance(new);
            if step == 0.0 {
                return 0;
            }
            match return_to_surface(scene, surfaces[i], new, Vec3::from(*n), step) {
                Some((at, normal)) => {
                    *x = at.into();
                    *n = normal.into();
                    0
                }
                None => {
                    *x = before[i];
                    1
                }
            }
        })
        .sum()
}

/// The point of surface `surface` nearest along the normal to a photon moved by `step` in its
/// tangent plane, and the surface's normal there (oriented like `normal`): the photon's
/// surface is searched along ±normal within 2·step plus a rounding margin (a tangent step of
/// length s leaves a surface of radius R by s²/2R, far less for any step the step limit
/// allows). `None` if another surface or none lies there, or if `step` is not positive.
pub fn return_to_surface(
    scene: &crate::scene::Scene,
    surface: u32,
    moved: Vec3,
    normal: Vec3,
    step: f32,
) -> Option<(Vec3, Vec3)> {
    let n = normal.try_normalize()?;
    // The margin covers the rounding of `moved` (relative to its size) and, at the origin, a
    // fraction of the step: no absolute length, so it holds at any scene scale.
    let reach = 2.0 * step + 1e-5 * moved.abs().max_element().max(step);
    for dir in [-n, n] {
        let ray = crate::scene::Ray::new(moved - dir * reach, dir);
        if let Some(hit) = scene.intersect(&ray, 0.0, 2.0 * reach)
            && hit.shape == surface
        {
            let hn = if hit.normal.dot(n) < 0.0 { -hit.normal } else { hit.normal };
            return Some((ray.at(hit.t), hn));
        }
    }
    None
}

/// The most per-iteration measures a relax record keeps (about 200 bytes each).
pub const MAX_ITERATION_RECORDS: usize = 1000;

/// `map` with its positions replaced by `relaxed` (and its normals and flux, where relaxation
/// changed them), every other column carried through (borrowed), and a stage record holding
/// the parameters and the per-iteration measures.
pub fn relaxed_map<'a>(
    map: &crate::format::MapView<'a>,
    relaxed: &Relaxed,
    p: &RelaxParams,
    seconds: f64,
) -> Result<crate::format::PhotonTable<'a>, RelaxError> {
    use crate::format::{PhotonTable, StageRecord, name};
    let mut info = map.info().clone();
    let mut rec = StageRecord::now("relax", serde_json::to_value(p).unwrap_or_default());
    // At most MAX_ITERATION_RECORDS per-iteration measures (every k-th and the last), so a
    // long run's history stays far below the metadata limit.
    let every = relaxed.measures.len().div_ceil(MAX_ITERATION_RECORDS).max(1);
    let kept: Vec<_> = relaxed
        .measures
        .iter()
        .enumerate()
        .filter(|(i, _)| i % every == 0 || i + 1 == relaxed.measures.len())
        .map(|(_, m)| m)
        .collect();
    rec.report = serde_json::json!({
        "space": relaxed.space,
        "constrained": relaxed.constrained,
        "seconds": crate::format::meta::reported_seconds(seconds),
        "iterations_recorded_every": every,
        "iterations": kept,
    });
    info.history.push(rec);
    let mut table = PhotonTable::carrying(map, info);
    table.set(name::POSITION, &relaxed.positions)?;
    if let Some(n) = &relaxed.normals
        && map.spec(name::NORMAL).is_some()
    {
        table.set(name::NORMAL, n)?;
    }
    if let Some(f) = &relaxed.flux {
        table.set(name::FLUX, f)?;
    }
    Ok(table)
}

/// Collapse: drops the parameter dimensions from the neighbour search by moving the map to the
/// `collapsed` state. Every column stays (the parameters remain for diagnostics).
pub fn collapse<'a>(map: &crate::format::MapView<'a>) -> Result<crate::format::PhotonTable<'a>, RelaxError> {
    use crate::format::{PhotonTable, StageRecord, State};
    let from = map.info().state;
    if from != State::Detected {
        return Err(RelaxError::Input {
            file: map.file_name().to_string(),
            message: format!(
                "collapse applies to a detected map (state 'detected'); this one is '{}'",
                from.name()
            ),
        });
    }
    let mut info = map.info().clone();
    info.state = State::Collapsed;
    info.history.push(StageRecord::now("collapse", serde_json::json!({ "from_state": from.name() })));
    Ok(PhotonTable::carrying(map, info))
}

/// Distance from photon `i` to the nearest photon not on top of it among its 4 Kf nearest;
/// `None` when all of those sit on it (a crowd, which would otherwise cost a search as large
/// as itself per photon: issue 31).
fn distinct_distance(
    index: &dyn NeighbourSearch,
    i: usize,
    xi: Vec3,
    pos: &[[f32; 3]],
    kf: usize,
) -> Option<f32> {
    let mut ids = Vec::new();
    index.neighbours(i, kf.max(1) * 4, &mut ids);
    ids.iter().map(|&j| xi.distance(pos[j as usize].into())).find(|&d| d > 0.0)
}

/// The mean photon spacing of a map, √(A / n), with A the area of the bounding box's two
/// largest extents (photons lie on surfaces); the largest extent / n when the photons lie on
/// a line, and 0 when they all sit on one point (which leaves nothing to separate them by).
fn map_spacing(pos: &[[f32; 3]]) -> f32 {
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

/// A unit vector that depends only on `i` (a SplitMix64 hash mapped to the sphere).
fn nudge(i: usize) -> Vec3 {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repulsion_vanishes_for_neighbours_evenly_on_the_kf_circle() {
        let r = 2.0;
        let ring: Vec<Vec3> = (0..16)
            .map(|k| (k as f32 * std::f32::consts::TAU / 16.0).sin_cos())
            .map(|(s, c)| Vec3::new(r * c, r * s, 0.0))
            .collect();
        let f = repulsion(Vec3::ZERO, &ring, r, 0.0);
        assert!(f.length() < 1e-5, "{f}");
    }

    #[test]
    fn repulsion_matches_eq8_by_hand_and_pushes_away_from_a_close_neighbour() {
        // Neighbours at (0.5,0,0) and (-2,0,0); r_K = 2, ε = 0:
        // (x_i − x_j)(r_K/|..| − 1): (−0.5,0,0)(4 − 1) = (−1.5,0,0); (2,0,0)(1 − 1) = 0; mean (−0.75,0,0).
        let f = repulsion(Vec3::ZERO, &[Vec3::new(0.5, 0.0, 0.0), Vec3::new(-2.0, 0.0, 0.0)], 2.0, 0.0);
        assert!((f - Vec3::new(-0.75, 0.0, 0.0)).length() < 1e-6, "{f}");
    }

    #[test]
    fn repulsion_is_finite_for_coincident_photons_and_scales_with_the_scene() {
        let f = repulsion(Vec3::ONE, &[Vec3::ONE, Vec3::ONE], 0.0, 1e-3);
        assert!(f.is_finite());
        let xs = [Vec3::new(0.3, 0.1, 0.0), Vec3::new(-0.2, 0.5, 0.0), Vec3::new(0.9, -0.4, 0.0)];
        let r = xs[2].length();
        let f1 = repulsion(Vec3::ZERO, &xs, r, 1e-3);
        for s in [1e-6f32, 1e6] {
            let fs = repulsion(Vec3::ZERO, &xs.map(|x| x * s), r * s, 1e-3);
            assert!((fs / s - f1).length() < 1e-5 * f1.length(), "scale {s}");
        }
    }

    #[test]
    fn a_zero_v_factor_never_moves_along_p2_and_a_unit_factor_moves_freely() {
        let (p1, p2) = (Vec3::X, Vec3::Y);
        let f = Vec3::new(0.3, -0.7, 0.0);
        let locked = project_on_basis(f, p1, p2 * 0.0);
        assert_eq!(locked.dot(p2), 0.0);
        assert!((locked - Vec3::new(0.3, 0.0, 0.0)).length() < 1e-7);
        let free = project_on_basis(f, p1, p2);
        assert!((free - f).length() < 1e-7);
        let half = project_on_basis(f, p1, p2 * 0.5);
        assert!((half.dot(p2) - 0.5 * f.dot(p2)).abs() < 1e-7);
    }

    #[test]
    fn tangent_projection_removes_the_normal_component_and_steps_are_clamped() {
        let n = Vec3::new(1.0, 1.0, 1.0).normalize();
        let t = project_on_tangent(Vec3::new(0.2, -3.0, 5.0), n);
        assert!(t.dot(n).abs() < 1e-6);
        assert!((clamp_step(Vec3::new(3.0, 4.0, 0.0), 1.0).length() - 1.0).abs() < 1e-6);
        assert_eq!(clamp_step(Vec3::new(0.3, 0.4, 0.0), 1.0), Vec3::new(0.3, 0.4, 0.0));
    }

    #[test]
    fn coefficient_of_variation_matches_closed_form() {
        // 1, 2, 3: mean 2, population sd sqrt(2/3).
        let cv = coefficient_of_variation(&[1.0, 2.0, 3.0]);
        assert!((cv - (2.0f64 / 3.0).sqrt() / 2.0).abs() < 1e-12);
        assert_eq!(coefficient_of_variation(&[5.0]), 0.0);
    }

    /// k nearest by brute force, ties broken by index.
    struct BruteForce<'a>(&'a [[f32; 3]]);

    impl NeighbourSearch for BruteForce<'_> {
        fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>) {
            let xi = Vec3::from(self.0[i]);
            let mut all: Vec<(f32, u32)> = (0..self.0.len())
                .filter(|&j| j != i)
                .map(|j| (xi.distance_squared(self.0[j].into()), j as u32))
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            out.clear();
            out.extend(all.iter().take(k).map(|&(_, j)| j));
        }
    }

    fn relax_plane(pos: &mut [[f32; 3]], iterations: usize) -> Vec<IterationMeasure> {
        let normal = vec![[0.0, 0.0, 1.0]; pos.len()];
        let p = RelaxParams::default();
        let mut scratch = Scratch::default();
        (0..iterations)
            .map(|it| {
                let snapshot = pos.to_vec();
                let index = BruteForce(&snapshot);
                iterate(pos, &index, Constraint::Tangent { normal: &normal }, &p, it, &mut scratch)
            })
            .collect()
    }

    /// Radially averaged power spectrum |Σ exp(−2πi f·x)|²/N of the points inside the square
    /// [lo, lo+side]², at f = k/side for integer vectors k with |k| in [kmin, kmax]. A uniform
    /// density has zero power there (the window's transform vanishes), white noise has 1.
    fn low_frequency_power(pos: &[[f32; 3]], lo: f64, side: f64, kmin: f64, kmax: f64) -> f64 {
        let inside: Vec<(f64, f64)> = pos
            .iter()
            .map(|p| ((p[0] as f64 - lo) / side, (p[1] as f64 - lo) / side))
            .filter(|&(x, y)| (0.0..1.0).contains(&x) && (0.0..1.0).contains(&y))
            .collect();
        let (mut sum, mut count) = (0.0, 0);
        let km = kmax.ceil() as i32;
        for kx in 0..=km {
            for ky in -km..=km {
                let k = ((kx * kx + ky * ky) as f64).sqrt();
                if k < kmin || k > kmax || (kx == 0 && ky < 0) {
                    continue;
                }
                let (mut re, mut im) = (0.0f64, 0.0f64);
                for &(x, y) in &inside {
                    let ph = -std::f64::consts::TAU * (kx as f64 * x + ky as f64 * y);
                    re += ph.cos();
                    im += ph.sin();
                }
                sum += (re * re + im * im) / inside.len() as f64;
                count += 1;
            }
        }
        sum / count as f64
    }

    /// Coefficient of variation of nearest-neighbour distances of photons in [0.2, 0.8]².
    fn interior_cv(pos: &[[f32; 3]]) -> f64 {
        let index = BruteForce(pos);
        let mut ids = Vec::new();
        let d: Vec<f32> = (0..pos.len())
            .filter(|&i| pos[i][..2].iter().all(|&x| (0.2..0.8).contains(&x)))
            .map(|i| {
                index.neighbours(i, 1, &mut ids);
                Vec3::from(pos[i]).distance(pos[ids[0] as usize].into())
            })
            .collect();
        coefficient_of_variation(&d)
    }

    fn uniform(n: usize, seed: u64) -> Vec<[f32; 3]> {
        crate::synthetic::uniform_square(n, seed, 1.0).position
    }

    /// Measured with seed 7: interior NN spread 0.49 → 0.095, low-frequency power 0.82 → 0.040.
    #[test]
    fn uniform_photons_relax_toward_blue_noise() {
        let mut pos = uniform(1200, 7);
        let start = pos.clone();
        let white = low_frequency_power(&pos, 0.2, 0.6, 1.0, 5.0);
        let m = relax_plane(&mut pos, 14);
        let blue = low_frequency_power(&pos, 0.2, 0.6, 1.0, 5.0);
        // Nearest-neighbour spread away from the border (photons at the border of a set drift
        // outward, which is what constraints are for): ≈ 0.52 for uniform random points.
        let (cv0, cv1) = (interior_cv(&start), interior_cv(&pos));
        assert!(cv0 > 0.45, "start cv {cv0}");
        assert!(cv1 < cv0 / 3.0, "cv {cv0} -> {cv1}");
        assert!(m[1].nn_cv < m[0].nn_cv);
        // The blue-noise dip: low-frequency power falls well below white noise's 1.
        assert!(white > 0.6, "white {white}");
        assert!(blue < white / 5.0, "power {white} -> {blue}");
        // Displacements shrink as the set settles, and everything stays on the plane.
        assert!(m[13].mean_displacement < m[0].mean_displacement);
        assert!(pos.iter().all(|p| p[2] == 0.0 && p[0].is_finite() && p[1].is_finite()));
    }

    #[test]
    fn coincident_photons_come_apart() {
        let mut pos = uniform(300, 3);
        for i in 0..20 {
            pos[100 + i] = pos[100];
        }
        relax_plane(&mut pos, 7);
        let p = Vec3::from(pos[100]);
        let min = (101..120).map(|i| p.distance(pos[i].into())).fold(f32::MAX, f32::min);
        assert!(min > 1e-4, "stack did not separate: {min}");
        assert!(pos.iter().all(|p| p.iter().all(|x| x.is_finite())));
    }

    /// A search that counts the neighbours asked for (the work a crowd makes).
    struct Counting<'a>(BruteForce<'a>, std::sync::atomic::AtomicUsize);

    impl NeighbourSearch for Counting<'_> {
        fn neighbours(&self, i: usize, k: usize, out: &mut Vec<u32>) {
            self.1.fetch_add(k, std::sync::atomic::Ordering::Relaxed);
            self.0.neighbours(i, k, out);
        }
    }

    /// Issue 31 item 5: a crowd of photons on one point (1 500 beside 300 spread ones) asks
    /// for a bounded number of neighbours per photon, not a search as large as the crowd,
    /// and still comes apart, by about the map's mean spacing; a map that is all one point
    /// has no length to separate its photons by and stays as it is, finite.
    #[test]
    fn a_crowd_on_one_point_costs_bounded_searches_and_comes_apart() {
        let mut pos = uniform(300, 5);
        pos.extend(std::iter::repeat_n([0.5, 0.5, 0.0], 1500));
        let n = pos.len();
        let normal = vec![[0.0, 0.0, 1.0]; n];
        let p = RelaxParams::default();
        let snapshot = pos.clone();
        let index = Counting(BruteForce(&snapshot), Default::default());
        iterate(&mut pos, &index, Constraint::Tangent { normal: &normal }, &p, 0, &mut Scratch::default());
        let asked = index.1.into_inner();
        assert!(asked <= n * 5 * p.kf, "{asked} neighbours asked for {n} photons (Kf {})", p.kf);
        let spacing = map_spacing(&snapshot);
        let crowd: Vec<Vec3> = pos[300..].iter().map(|&x| Vec3::from(x)).collect();
        let spread = crowd.iter().map(|x| x.distance(Vec3::new(0.5, 0.5, 0.0))).fold(0.0f32, f32::max);
        assert!(spread > 0.1 * spacing && spread < 2.0 * spacing, "spread {spread}, spacing {spacing}");
        let distinct: std::collections::HashSet<[u32; 3]> =
            crowd.iter().map(|x| x.to_array().map(f32::to_bits)).collect();
        assert_eq!(distinct.len(), crowd.len(), "every photon of the crowd moved its own way");

        let mut one = vec![[0.25f32, -1.0, 0.0]; 500];
        let normal = vec![[0.0, 0.0, 1.0]; one.len()];
        let snapshot = one.clone();
        let index = Counting(BruteForce(&snapshot), Default::default());
        iterate(&mut one, &index, Constraint::Tangent { normal: &normal }, &p, 0, &mut Scratch::default());
        assert!(index.1.into_inner() <= 500 * 5 * p.kf);
        assert_eq!(one, snapshot);
    }

    // ---- Issue 5: basis factors 0 and 1, the paper's Fig. 3 (e–f), stability.

    /// Runs `iterations` Jacobi iterations of `iterate` with the brute-force search under the
    /// same basis for every photon, returning the positions after each.
    fn relax_in_basis(
        pos: &mut [[f32; 3]],
        u: [f32; 3],
        v: [f32; 3],
        iterations: usize,
    ) -> Vec<Vec<[f32; 3]>> {
        let (bu, bv) = (vec![u; pos.len()], vec![v; pos.len()]);
        let p = RelaxParams::default();
        let mut scratch = Scratch::default();
        (0..iterations)
            .map(|it| {
                let snapshot = pos.to_vec();
                let index = BruteForce(&snapshot);
                iterate(pos, &index, Constraint::Basis { u: &bu, v: &bv }, &p, it, &mut scratch);
                pos.to_vec()
            })
            .collect()
    }

    /// Issue 5: Eq. 9 through `iterate`. Measured (300 uniform photons, 20 iterations): with
    /// v_b = 0 all 300 moved in x and none in y (to the bit); with v_b = ŷ all 300 moved in both
    /// (mean |Δy| 0.29).
    #[test]
    fn issue5_basis_factor_zero_never_moves_along_p2_and_factor_one_moves_along_both() {
        let start = uniform(300, 5);
        let mut locked = start.clone();
        let steps = relax_in_basis(&mut locked, [1.0, 0.0, 0.0], [0.0; 3], 20);
        let moved_x = |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).filter(|(p, q)| p[0] != q[0]).count();
        let moved_y = |a: &[[f32; 3]], b: &[[f32; 3]]| a.iter().zip(b).filter(|(p, q)| p[1] != q[1]).count();
        for (it, pos) in steps.iter().enumerate() {
            for (i, (p, q)) in pos.iter().zip(&start).enumerate() {
                assert_eq!(p[1].to_bits(), q[1].to_bits(), "photon {i} moved along P2 in iteration {it}");
                assert_eq!(p[2].to_bits(), q[2].to_bits(), "photon {i} left the plane in iteration {it}");
            }
        }
        let mx = moved_x(&locked, &start);
        let mut free = start.clone();
        relax_in_basis(&mut free, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], 20);
        let (fx, fy) = (moved_x(&free, &start), moved_y(&free, &start));
        assert!(mx > 290, "only {mx} of 300 photons moved along u_b");
        assert!(fx > 290 && fy > 290, "free: {fx} moved along x, {fy} along y");
        assert!(free.iter().all(|p| p[2] == 0.0));
    }

    /// Writes `m` into `dir` as `file` and opens it.
    fn map_in(
        dir: &std::path::Path,
        file: &str,
        m: &crate::synthetic::SyntheticMap,
    ) -> crate::format::PhotonMap {
        let path = dir.join(file);
        crate::format::write_map(
            crate::format::Output::Path(path.clone()),
            m.info("test", 0, "2026-11-23T00:00:00Z"),
            &m.columns(),
        )
        .unwrap();
        crate::format::PhotonMap::open_path(&path).unwrap()
    }

    /// Relaxes `map` and writes it to `dir/file`, returning the written map.
    fn relax_to(
        map: &crate::format::PhotonMap,
        p: &RelaxParams,
        dir: &std::path::Path,
        file: &str,
    ) -> crate::format::PhotonMap {
        let r = relax_map(&map.view(), p, |_| {}).unwrap();
        let path = dir.join(file);
        relaxed_map(&map.view(), &r, p, 0.0)
            .unwrap()
            .write(crate::format::Output::Path(path.clone()))
            .unwrap();
        crate::format::PhotonMap::open_path(&path).unwrap()
    }

    /// Detects (param-pca, defaults) and writes `map` to `dir/file`.
    fn detect_to(
        map: &crate::format::PhotonMap,
        dir: &std::path::Path,
        file: &str,
    ) -> crate::format::PhotonMap {
        let p = crate::detect::DetectParams::default();
        let d = crate::detect::detect_map(&map.view(), &p, &|_| {}).unwrap();
        let path = dir.join(file);
        let table = crate::detect::detected_map(&map.view(), &d, &p, 0.0).unwrap();
        table.write(crate::format::Output::Path(path.clone())).unwrap();
        crate::format::PhotonMap::open_path(&path).unwrap()
    }

    /// The paper's Fig. 3 (as in detect's tests): params (u, v) uniform; set A (u < ½) lands on
    /// x = 1.2·u, set B on x = 0.4 + 1.2·(u − ½), y = v, overlapping in 0.4 ≤ x < 0.6.
    fn fig3(n: usize, seed: u64) -> crate::synthetic::SyntheticMap {
        use rand::{RngExt, SeedableRng};
        let mut r = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut m = crate::synthetic::uniform_square(n, seed, 1.0);
        for i in 0..n {
            let (u, v) = (r.random::<f32>(), r.random::<f32>());
            let x = if u < 0.5 { 1.2 * u } else { 0.4 + 1.2 * (u - 0.5) };
            m.position[i] = [x, v, 0.0];
            m.params[2 * i] = u;
            m.params[2 * i + 1] = v;
        }
        m
    }

    /// Coefficient of variation of nearest-neighbour distances (over all photons, both sets)
    /// of the photons inside the overlap's interior x ∈ [0.44, 0.56], y ∈ [0.1, 0.9].
    fn overlap_cv(pos: &[[f32; 3]]) -> f64 {
        let index = BruteForce(pos);
        let mut ids = Vec::new();
        let d: Vec<f32> = (0..pos.len())
            .filter(|&i| (0.44..0.56).contains(&pos[i][0]) && (0.1..0.9).contains(&pos[i][1]))
            .map(|i| {
                index.neighbours(i, 1, &mut ids);
                Vec3::from(pos[i]).distance(pos[ids[0] as usize].into())
            })
            .collect();
        assert!(d.len() > 100, "{} photons in the overlap", d.len());
        coefficient_of_variation(&d)
    }

    /// Issue 5, Fig. 3 (e–f): detect (param-pca), relax in world+params space, collapse, relax
    /// in world space. In the params stage A and B relax each on its own, so in the overlap two
    /// independent blue-noise sets lie on top of each other; only after the collapse do they
    /// relax as one set.
    ///
    /// Measured (4000 photons, 7 + 7 iterations; NN-distance CV in x ∈ [0.44, 0.56],
    /// y ∈ [0.1, 0.9], both sets): seed 50: input 0.523, params stage 0.290, collapse + world
    /// 0.138. Seeds 51–54: input 0.48–0.52, params stage 0.20–0.26, final 0.10–0.13; final /
    /// params-stage ratio 0.47–0.54, params-stage / input 0.41–0.55. Thresholds: final < 0.75 ×
    /// params stage (a collapse that kept the parameter restriction leaves ≈ the params-stage
    /// value), params stage < 0.75 × input, input > 0.45 (uniform random points give ≈ 0.52).
    #[test]
    fn issue5_fig3_collapse_and_world_relax_even_out_the_overlap_of_two_sets() {
        let dir = tempfile::tempdir().unwrap();
        let p = RelaxParams::default();
        let input = map_in(dir.path(), "in.phm", &fig3(4000, 50));
        let detected = detect_to(&input, dir.path(), "d.phm");
        let r1 = relax_to(&detected, &p, dir.path(), "r1.phm");
        assert_eq!(r1.meta().history.last().unwrap().report["space"], "world_params");
        let c_path = dir.path().join("c.phm");
        collapse(&r1.view()).unwrap().write(crate::format::Output::Path(c_path.clone())).unwrap();
        let c = crate::format::PhotonMap::open_path(&c_path).unwrap();
        let r2 = relax_to(&c, &p, dir.path(), "r2.phm");
        assert_eq!(r2.meta().history.last().unwrap().report["space"], "world");
        let (cv0, cv1, cv2) =
            (overlap_cv(input.positions()), overlap_cv(r1.positions()), overlap_cv(r2.positions()));
        assert!(cv0 > 0.45, "input cv {cv0}");
        assert!(cv1 < 0.75 * cv0, "params stage cv {cv1} vs input {cv0}");
        assert!(cv2 < 0.75 * cv1, "collapse + world cv {cv2} vs params stage {cv1}");
        assert!(all_finite(r2.positions()) && r2.positions().iter().all(|q| q[2] == 0.0));
    }

    /// Detect and relax (both spaces) give the same bits on one thread and on three: the
    /// k-NN buffers are reused across queries (their gathered candidates and bounds change
    /// the order neighbours come in), so this holds only because each chunk starts afresh.
    #[test]
    fn detect_and_relax_are_the_same_on_one_and_three_threads() {
        let dir = tempfile::tempdir().unwrap();
        // Several chunks of photons, so that threads interleave chunks differently.
        let input = map_in(dir.path(), "in.phm", &fig3(5 * CHUNK + 123, 60));
        let p = RelaxParams { iterations: 2, ..RelaxParams::default() };
        let run = |threads: usize, tag: &str| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let d = detect_to(&input, dir.path(), &format!("d{tag}.phm"));
                let dp = crate::detect::detect_map(&input.view(), &Default::default(), &|_| {}).unwrap();
                let r1 = relax_map(&d.view(), &p, |_| {}).unwrap();
                let r1_file = relax_to(&d, &p, dir.path(), &format!("r{tag}.phm"));
                let c_path = dir.path().join(format!("c{tag}.phm"));
                collapse(&r1_file.view())
                    .unwrap()
                    .write(crate::format::Output::Path(c_path.clone()))
                    .unwrap();
                let c = crate::format::PhotonMap::open_path(&c_path).unwrap();
                let r2 = relax_map(&c.view(), &p, |_| {}).unwrap();
                (dp.basis_u, dp.basis_v, dp.lambda2, dp.r_param, r1.positions, r2.positions)
            })
        };
        let (one, three) = (run(1, "1"), run(3, "3"));
        assert!(one.0 == three.0 && one.1 == three.1 && one.2 == three.2 && one.3 == three.3, "detect");
        assert!(one.4 == three.4, "relax in world + params");
        assert!(one.5 == three.5, "relax in world");
        assert!(one.4 != input.positions(), "the photons moved");
    }

    /// `m` with every position scaled by `s`.
    fn scaled(m: &crate::synthetic::SyntheticMap, s: f32) -> crate::synthetic::SyntheticMap {
        let mut m = m.clone();
        for x in m.position.iter_mut() {
            *x = x.map(|c| c * s);
        }
        m
    }

    fn all_finite(pos: &[[f32; 3]]) -> bool {
        pos.iter().flatten().all(|x| x.is_finite())
    }

    /// A cluster of 100 uniform photons in the unit square and 5 far away (at x = 1000), with
    /// far-away parameters too.
    fn cluster_and_strays() -> crate::synthetic::SyntheticMap {
        let mut m = crate::synthetic::uniform_square(105, 8, 1.0);
        for k in 0..5 {
            let i = 100 + k;
            m.position[i] = [1000.0 + k as f32 * 0.01, 0.5, 0.0];
            m.params[2 * i] = 0.9 + 0.02 * k as f32;
            m.params[2 * i + 1] = 0.99;
        }
        m
    }

    /// Issue 5, stability (a): photons with few or far neighbours. Measured (7 iterations):
    /// the 5 strays at x ≈ 1000 end at x = 512 … 2375 (world) and 512 … 2375 (world+params),
    /// their r_K being the distance to the cluster; the 3-photon map grows from the unit square
    /// to a 5.9 × 3.1 box. Finite, but see the ignored test below for longer runs.
    #[test]
    fn issue5_isolated_photons_stay_finite() {
        let dir = tempfile::tempdir().unwrap();
        let p = RelaxParams::default();
        let m = cluster_and_strays();
        let world = relax_to(&map_in(dir.path(), "a.phm", &m), &p, dir.path(), "a1.phm");
        assert!(all_finite(world.positions()));
        let detected = detect_to(&map_in(dir.path(), "a.phm", &m), dir.path(), "ad.phm");
        let wp = relax_to(&detected, &p, dir.path(), "ad1.phm");
        assert!(all_finite(wp.positions()));
        let three = crate::synthetic::uniform_square(3, 9, 1.0);
        let t = relax_to(&map_in(dir.path(), "t.phm", &three), &p, dir.path(), "t1.phm");
        assert!(all_finite(t.positions()));
        let td = detect_to(&map_in(dir.path(), "t.phm", &three), dir.path(), "td.phm");
        let t2 = relax_to(&td, &p, dir.path(), "td1.phm");
        assert!(all_finite(t2.positions()));
    }

    /// Relaxes 300 uniform photons for `iterations` in world space: detected (param-pca) and
    /// collapsed when `constrained`, else free in their tangent plane. Returns the positions,
    /// or the error when the index refused them.
    fn long_run(constrained: bool, iterations: usize) -> Result<Vec<[f32; 3]>, RelaxError> {
        let dir = tempfile::tempdir().unwrap();
        let mut map = map_in(dir.path(), "s.phm", &crate::synthetic::uniform_square(300, 12, 1.0));
        if constrained {
            let d = detect_to(&map, dir.path(), "d.phm");
            let c = dir.path().join("c.phm");
            collapse(&d.view()).unwrap().write(crate::format::Output::Path(c.clone())).unwrap();
            map = crate::format::PhotonMap::open_path(&c).unwrap();
        }
        let p = RelaxParams { iterations, ..Default::default() };
        let r = relax_map(&map.view(), &p, |_| {})?;
        assert_eq!(r.space, RelaxSpace::World);
        Ok(r.positions)
    }

    /// Issue 5, stability (b): 1000 iterations on 300 photons in world space, free and with a
    /// constraint basis, and on a map of 3 photons: positions stay finite and on the plane, and
    /// no photon travels farther than [`Scratch`]'s guarantee, 1000 × step_limit × its first
    /// spacing r_K·sqrt(π/Kf) (r_K by brute force on the input). Before the cap the border
    /// moved out geometrically (≈ ×1.1 per iteration: box 1.5e18 after 400 iterations, then
    /// non-finite positions).
    #[test]
    fn issue5_a_thousand_iterations_stay_finite_on_the_plane_and_bounded() {
        let m = crate::synthetic::uniform_square(300, 12, 1.0);
        let p = RelaxParams::default();
        let first_spacing = |pos: &[[f32; 3]]| -> Vec<f32> {
            (0..pos.len())
                .map(|i| {
                    let mut d: Vec<f32> = (0..pos.len())
                        .filter(|&j| j != i)
                        .map(|j| Vec3::from(pos[i]).distance(Vec3::from(pos[j])))
                        .collect();
                    d.sort_by(f32::total_cmp);
                    let k = p.kf.min(d.len());
                    d[k - 1] * (std::f32::consts::PI / k as f32).sqrt()
                })
                .collect()
        };
        let cap = first_spacing(&m.position);
        for constrained in [true, false] {
            let pos = long_run(constrained, 1000).expect("relax_map failed");
            assert!(all_finite(&pos) && pos.iter().all(|p| p[2] == 0.0));
            for (i, (a, b)) in pos.iter().zip(&m.position).enumerate() {
                let moved = Vec3::from(*a).distance(Vec3::from(*b));
                assert!(moved <= 1000.0 * p.step_limit * cap[i] * 1.0001, "photon {i} moved {moved}");
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let three = map_in(dir.path(), "t.phm", &crate::synthetic::uniform_square(3, 9, 1.0));
        let r = relax_map(&three.view(), &RelaxParams { iterations: 1000, ..Default::default() }, |_| {})
            .expect("relax_map failed");
        assert!(all_finite(&r.positions));
    }

    /// Issue 5, stability (c): the force and step limit are relative to r_K, so scaling the map
    /// scales the result. Measured (300 photons, 7 iterations, positions in [0, 1], largest
    /// move 0.58): max |x/s − x| 1.1e-6 at s = 1e-6 and 9.8e-7 at s = 1e6 (≈ 10 f32 ulps: the
    /// scaled input is itself rounded). Tolerance 1e-5; an absolute ε or step limit would be
    /// off by a photon spacing (≈ 0.06).
    #[test]
    fn issue5_relaxing_is_scale_invariant() {
        let dir = tempfile::tempdir().unwrap();
        let m = crate::synthetic::uniform_square(300, 12, 1.0);
        let p = RelaxParams::default();
        let base = relax_map(&map_in(dir.path(), "s.phm", &m).view(), &p, |_| {}).unwrap();
        for s in [1e-6f32, 1e6] {
            let r = relax_map(&map_in(dir.path(), "x.phm", &scaled(&m, s)).view(), &p, |_| {}).unwrap();
            assert!(all_finite(&r.positions));
            let err = r
                .positions
                .iter()
                .zip(&base.positions)
                .map(|(a, b)| (Vec3::from(*a) / s - Vec3::from(*b)).length() as f64)
                .fold(0.0, f64::max);
            let moved = base
                .positions
                .iter()
                .zip(&m.position)
                .map(|(a, b)| Vec3::from(*a).distance(Vec3::from(*b)) as f64)
                .fold(0.0, f64::max);
            assert!(err < 1e-5, "scale {s:e}: max |x/s − x| {err:e}");
            assert!(moved > 0.1, "the unscaled run barely moved ({moved})");
        }
    }

    /// Detect and relax work on photons relabelled in spatial order: the order of the photons
    /// in the file must not matter. Fig. 3's map and the same map stored in reverse, detected
    /// and relaxed in parameter space: every photon ends where its twin does. Measured: exactly
    /// (both runs work in the same Z-order; only photons sharing a Z-order cell could be
    /// visited in another order, and then sums round differently), so the tolerance 1e-5
    /// against moves of ≈ 0.1 is only for that.
    #[test]
    fn results_do_not_depend_on_the_order_photons_are_stored_in() {
        let dir = tempfile::tempdir().unwrap();
        let m = fig3(2000, 31);
        let mut r = m.clone();
        let n = m.len();
        let d = m.param_dims as usize;
        let back = |i: usize| n - 1 - i;
        for i in 0..n {
            r.position[i] = m.position[back(i)];
            r.normal[i] = m.normal[back(i)];
            r.flux[i] = m.flux[back(i)];
            r.incident[i] = m.incident[back(i)];
            r.path_length[i] = m.path_length[back(i)];
            r.bounces[i] = m.bounces[back(i)];
            r.emission_index[i] = m.emission_index[back(i)];
            r.params[i * d..][..d].copy_from_slice(&m.params[back(i) * d..][..d]);
        }
        let p = RelaxParams::default();
        let a = detect_to(&map_in(dir.path(), "a.phm", &m), dir.path(), "ad.phm");
        let b = detect_to(&map_in(dir.path(), "b.phm", &r), dir.path(), "bd.phm");
        let (ra, rb) = (relax_map(&a.view(), &p, |_| {}).unwrap(), relax_map(&b.view(), &p, |_| {}).unwrap());
        assert_eq!(ra.space, RelaxSpace::WorldParams);
        let (mut err, mut moved) = (0f32, 0f32);
        for i in 0..n {
            err = err.max(Vec3::from(ra.positions[i]).distance(Vec3::from(rb.positions[back(i)])));
            moved = moved.max(Vec3::from(ra.positions[i]).distance(Vec3::from(m.position[i])));
        }
        assert!(err < 1e-5, "largest difference {err:e}");
        assert!(moved > 0.01, "relaxation barely moved ({moved})");
    }

    /// Issue 7: returning a photon to its surface uses no absolute length. A floor at z = 0
    /// between two parallel shelves 2 µm above and below it, at scales 1e-6 (the shelves 2 µm
    /// away) and 1 (2 m away), and a photon moved 10 nm (10 mm) in the floor's plane: the
    /// search reaches 2·step beyond it, so it finds the floor and not a shelf. (With the former
    /// margin of 1e-5 m, the search at 1e-6 met a shelf first in both directions and refused.)
    #[test]
    fn return_to_surface_holds_at_micrometre_scale() {
        use crate::scene::{Material, Scene, Shape, Surface, SurfaceGeometry};
        for s in [1e-6f32, 1.0] {
            let rect = |z: f32| {
                let o = Vec3::new(-10.0, -10.0, z) * s;
                Shape::rectangle(o, Vec3::X * 20.0 * s, Vec3::Y * 20.0 * s).unwrap()
            };
            let surfaces = [0.0, 2.0, -2.0]
                .iter()
                .enumerate()
                .map(|(i, &z)| Surface {
                    name: format!("s{i}"),
                    material: 0,
                    geometry: SurfaceGeometry::Analytic(rect(z)),
                })
                .collect();
            let emitter = crate::scene::Emitter {
                kind: crate::scene::EmitterShape::Point { position: Vec3::new(0.0, 0.0, 1.0) * s },
                power_w: 1.0,
                colour: Vec3::ONE,
            };
            let scene = Scene::new(
                vec![("floor".into(), Material::Diffuse { albedo: Vec3::ONE })],
                vec![emitter],
                surfaces,
            );
            let moved = Vec3::new(0.01, 0.0, 0.0) * s;
            let (at, n) = return_to_surface(&scene, 0, moved, Vec3::Z, 0.01 * s).expect("floor found");
            assert!(
                at.z.abs() <= 1e-6 * s && (at.x - moved.x).abs() <= 1e-6 * s && n == Vec3::Z,
                "{s}: {at}"
            );
        }
    }
}
