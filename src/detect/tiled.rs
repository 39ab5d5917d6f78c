//! Detection tile by tile, exact against the whole map (docs/tiles.md).
//!
//! A tile's interior photons are measured over the tile's working set (the photons within a
//! halo around it); each search is certified (its farthest result closer than anything left
//! out), and the photons whose searches are not all certified are measured again with the halo
//! doubled, so every interior photon ends with exactly the whole map's result. Eq. 1's density
//! is found the same way in parameter space, where neighbours can lie anywhere on the surface.

use rayon::prelude::*;

use super::{
    CHUNK, DetectError, DetectInput, DetectParams, Detection, Measured, Method, Outcome, Permuted,
    check_params, measure, radius_of, unit_normal, world_index,
};
use crate::spatial::order::{locality_order_in, permuted};
use crate::spatial::{MAX_PARAM_DIMS, Neighbours, ParamColumn, PointSet, Space, SpatialIndex};
use crate::tiles::{Tiling, within_margin};

/// The detection of one tile's interior photons, in file order, with what the whole map's
/// report needs of each ([`assemble`] puts tiles together).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TileDetection {
    /// The interior photons' indices in the map, ascending.
    pub indices: Vec<u32>,
    /// u_b (Eq. 7) of each.
    pub basis_u: Vec<[f32; 3]>,
    /// v_b (Eq. 7) of each, its length the factor.
    pub basis_v: Vec<[f32; 3]>,
    /// λ2 of each.
    pub lambda2: Vec<f32>,
    /// r_param of each, for method `param-pca` on a map with parameters.
    pub r_param: Option<Vec<f32>>,
    /// The Eq. 7 factor of each, as the report sums it.
    pub factor: Vec<f32>,
    /// How each constraint was decided.
    pub outcome: Vec<Outcome>,
    /// Rounds of the world-space search (1: the first halo certified every photon).
    pub rounds: u32,
    /// Rounds of the parameter-space density (0 when there is none).
    pub param_rounds: u32,
    /// The most photons one round of the tile worked on (interior and halo).
    pub working_set: usize,
    /// Per round of the world-space search: how many interior photons it measured, and how
    /// many photons its working set held.
    pub per_round: Vec<[usize; 2]>,
}

/// What detection keeps in memory ([`crate::tiles::tiles_for_budget`]), measured with
/// `/usr/bin/time` on the water scene's maps (BENCHMARKS.md, "Tiles and the memory budget"): the map's
/// results per photon (the constraint basis, λ2 and r_param, which the written map takes over
/// without a copy, and its place in the run's tile index, `Shared`; with a wavelength among the
/// parameters, their scaled copy too: `spectral_params`, the parameters' components), and per
/// photon a tile works on its columns, indices and search scratch; the first halo takes in a
/// few times the tile's photons.
pub fn memory(spectral_params: Option<usize>) -> crate::tiles::MemoryModel {
    crate::tiles::MemoryModel {
        per_photon: 52.0 + spectral_params.map_or(0.0, |c| 4.0 * c as f64),
        per_working_photon: 200.0,
        halo_growth: 3.0,
    }
}

/// Rounds after which the halo is the whole map (a guard: doubling reaches it long before).
const MAX_ROUNDS: u32 = 48;

/// Detection of tile `tile` of `tiling` over `input` (the whole map, in file order): each
/// interior photon's result is bit for bit the one [`super::detect`] gives it over the whole
/// map (docs/tiles.md). The map-wide quantities (Kc capped at the map's photons, whether it
/// has parameters, whether all normals are usable) are taken from the whole input, and its
/// photons are checked as the whole map's are, so a tile fails where the whole map fails.
pub fn detect_tile(
    input: &DetectInput,
    p: &DetectParams,
    tiling: &Tiling,
    tile: usize,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<TileDetection, DetectError> {
    detect_tile_with(input, p, tiling, tile, Options::default(), None, progress)
}

/// What the tiles of one run share, computed once: each tile's photons, each emitter's
/// parameter range over the whole map, and the whole map's checks. Without it every tile scans
/// the whole map for these (a tile job, [`detect_tile`], reads the map once anyway).
pub(super) struct Shared {
    /// Each tile's photons, in cells.
    tiles: Vec<crate::tiles::TilePhotons>,
    ranges: Option<Vec<Range>>,
    normals_ok: bool,
}

/// What a tile of a run of every tile in one process is given: what the tiles share, and
/// Eq. 1's radius of every photon when it was found for the whole map first ([`Radius::Whole`]).
#[derive(Clone, Copy)]
pub(super) struct InRun<'a> {
    shared: &'a Shared,
    radius: Option<&'a [f32]>,
}

impl Shared {
    /// The tiles of `tiling` over `input`'s photons, checked for `p` ([`checked`]).
    pub(super) fn new(input: &DetectInput, tiling: &Tiling, p: &DetectParams) -> Result<Self, DetectError> {
        let normals_ok = checked(input, p)?;
        let tiles = tiling.tile_photons(input.positions);
        let ranges = input.params.map(|_| ranges(&input.points(true), None));
        Ok(Shared { tiles, ranges, normals_ok })
    }
}

/// The whole map's photons checked as [`super::detect`] checks them for `p`, so a tile fails
/// where the whole map fails; returns whether every normal is usable (a map-wide quantity).
fn checked(input: &DetectInput, p: &DetectParams) -> Result<bool, DetectError> {
    let has_params = input.has_params();
    if p.method == Method::ParamPca && !has_params {
        return Err(DetectError::NoParameters { file: "<input>".into() });
    }
    let normals_ok = input.normals.is_some_and(|ns| ns.iter().all(|&n| unit_normal(n).is_some()));
    if has_params && p.method == Method::ParamPca {
        input.points(true).check(Space::Params)?;
    } else if !(p.method == Method::None && normals_ok) {
        input.points(false).check(Space::World)?;
    }
    Ok(normals_ok)
}

/// How [`detect_tile_with`] sizes and checks its halos (for tests: the defaults are the only
/// exact choice of `certify`).
#[derive(Clone, Copy, Debug)]
pub(super) struct Options {
    /// The first halos' widths as multiples of the default ones.
    pub halo_scale: f64,
    /// Whether searches are certified; without, the first halo's results are kept, exact or
    /// not.
    pub certify: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options { halo_scale: 1.0, certify: true }
    }
}

/// [`detect_tile`] with [`Options`].
pub(super) fn detect_tile_with(
    input: &DetectInput,
    p: &DetectParams,
    tiling: &Tiling,
    tile: usize,
    opts: Options,
    run: Option<InRun>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<TileDetection, DetectError> {
    let shared = run.as_ref().map(|r| r.shared);
    let whole_radius = run.and_then(|r| r.radius);
    check_params(p)?;
    if tile >= tiling.len() {
        return Err(DetectError::Parameter(format!("tile {tile} of a tiling of {}", tiling.len())));
    }
    let n = input.positions.len();
    let p = &p.capped(n);
    let param_search = input.has_params() && p.method == Method::ParamPca;
    let normals_ok = match shared {
        Some(s) => s.normals_ok,
        None => checked(input, p)?,
    };
    let pos = input.positions;
    let interior: Vec<u32> = match shared {
        Some(s) => s.tiles[tile].ascending(),
        None => (0..n as u32).into_par_iter().filter(|&i| tiling.tile_of(pos[i as usize]) == tile).collect(),
    };
    let mut out = TileDetection { r_param: param_search.then(Vec::new), ..Default::default() };
    if interior.is_empty() {
        return Ok(out);
    }
    let (r_param, param_rounds) = match (param_search, whole_radius) {
        // Found for the whole map before the tiles (its progress reported then).
        (true, Some(r)) => (Some(interior.iter().map(|&i| r[i as usize]).collect()), 0),
        (true, None) => {
            let (r, rounds) =
                tile_radius(input, &interior, p, opts, shared.and_then(|s| s.ranges.as_deref()))?;
            // The parameter-space pass of [`super::work_units`].
            progress(interior.len() as u64);
            (Some(r), rounds)
        }
        (false, _) => (None, 0),
    };
    let extent = tiling.axes.iter().map(|&a| tiling.hi[a] as f64 - tiling.lo[a] as f64).fold(0.0, f64::max);
    let mut h = opts.halo_scale * 3.0 * extent * (p.kc as f64 / n as f64).sqrt();
    let mut pending: Vec<usize> = (0..interior.len()).collect();
    let mut done: Vec<Option<Measured>> = vec![None; interior.len()];
    let mut rounds = 0u32;
    while !pending.is_empty() {
        rounds += 1;
        let halo = tiling.halo_box(tile, if rounds >= MAX_ROUNDS { f64::INFINITY } else { h });
        let near = match (&r_param, rounds > 1) {
            (Some(r), true) => Some(ParamNear::new(input, &interior, &pending, r, p.growths)?),
            _ => None,
        };
        let member =
            |i: u32, x: [f32; 3]| halo.contains(x) && near.as_ref().is_none_or(|f| f.admits(i as usize));
        // The same photons either way, ascending, with their positions: from the cells near the
        // box of the tiles it meets (their positions gathered in blocks released as read), or
        // the map.
        let meeting = shared.map(|s| (s, tiling.tiles_meeting(&halo)));
        let (members, at): (Vec<u32>, Vec<[f32; 3]>) = match meeting {
            Some((s, tiles)) if tiles.len() < tiling.len() => {
                let (near, at) = crate::tiles::gather_cells(
                    input.pages,
                    pos,
                    tiles.iter().flat_map(|&t| s.tiles[t].near(&halo)),
                );
                near.into_par_iter().zip(at).filter(|&(i, x)| member(i, x)).unzip()
            }
            _ => (0..n as u32)
                .into_par_iter()
                .map(|i| (i, pos[i as usize]))
                .filter(|&(i, x)| member(i, x))
                .unzip(),
        };
        // Choosing the members read their positions (and parameters) across the file.
        input.pages.release();
        out.working_set = out.working_set.max(members.len());
        out.per_round.push([pending.len(), members.len()]);
        // Labelled as the whole map labels them: Z-order on the map's box, ties by file index.
        let local = locality_order_in(&at, tiling.lo, tiling.hi);
        drop(at);
        let work: Vec<u32> = local.iter().map(|&k| members[k as usize]).collect();
        let mut label_of_member = vec![0u32; members.len()];
        for (label, &k) in local.iter().enumerate() {
            label_of_member[k as usize] = label as u32;
        }
        let label = |g: u32| {
            members.binary_search(&g).map(|k| label_of_member[k]).expect("interior photons are members")
        };
        let columns = Permuted::of(input, &members, Some(&local), p.method);
        input.pages.release();
        let sorted = columns.input(input);
        let (points, index) = world_index(&sorted, p.method, normals_ok)?;
        // Searched in the index's leaf order, as the whole map's photons are: successive
        // queries then share the candidates gathered for their leaf (the results do not
        // depend on the order; in label order, 7 % more CPU time on the water at 10⁷).
        let queries: Vec<(u32, usize)> = match &index {
            Some(ix) => {
                let mut slot = vec![u32::MAX; work.len()];
                for &q in &pending {
                    slot[label(interior[q]) as usize] = q as u32;
                }
                ix.order()
                    .into_iter()
                    .filter(|&l| slot[l as usize] != u32::MAX)
                    .map(|l| (l, slot[l as usize] as usize))
                    .collect()
            }
            None => {
                let mut q: Vec<(u32, usize)> = pending.iter().map(|&q| (label(interior[q]), q)).collect();
                q.sort_unstable();
                q
            }
        };
        let labels: Vec<u32> = queries.iter().map(|&(l, _)| l).collect();
        let radius = r_param.as_ref().map(|r| {
            let mut v = vec![0f32; work.len()];
            for &(l, q) in &queries {
                v[l as usize] = r[q];
            }
            v
        });
        let whole = halo.is_whole();
        let certify = |i: usize, nb: &Neighbours| {
            whole
                || !opts.certify
                || (nb.len() == p.kc
                    && nb.max_dist2().is_some_and(|d2| within_margin(d2, halo.margin(columns.positions[i]))))
        };
        let results =
            measure(&sorted, &points, index.as_ref(), &labels, radius.as_deref(), p, &certify, &|_| {});
        pending.clear();
        for (&(_, q), m) in queries.iter().zip(results) {
            if m.certified {
                done[q] = Some(m);
            } else {
                pending.push(q);
            }
        }
        pending.sort_unstable();
        h *= 2.0;
    }
    progress(interior.len() as u64);
    let done: Vec<Measured> = done.into_iter().map(|m| m.expect("every photon certified")).collect();
    out.basis_u = done.iter().map(|m| m.constraint.u).collect();
    out.basis_v = done.iter().map(|m| m.constraint.v).collect();
    out.lambda2 = done.iter().map(|m| m.constraint.lambda2).collect();
    out.factor = done.iter().map(|m| m.constraint.factor).collect();
    out.outcome = done.iter().map(|m| m.constraint.outcome).collect();
    out.r_param = r_param.map(|_| done.iter().map(|m| m.radius).collect());
    out.indices = interior;
    out.rounds = rounds;
    out.param_rounds = param_rounds;
    Ok(out)
}

/// The photons that can be candidates of the pending photons' restricted searches: those of a
/// pending photon's emitter whose parameters lie within the emitter's largest grown ball
/// (r_param·2^growths over its pending photons) of some pending photon. The rest of the halo box
/// can never enter those searches, so leaving it out of later rounds changes no result
/// (docs/tiles.md): the certificate still holds, since every photon left out is either outside
/// the box or never a candidate.
struct ParamNear<'a> {
    points: PointSet<'a>,
    /// Per emitter: the largest grown ball of its pending photons, squared and widened for
    /// rounding (negative: no pending photon; ∞: an emitter without parameters, every photon).
    reach2: Vec<f64>,
    /// Per emitter: the box of its pending photons' parameters grown by the reach (a photon
    /// outside it is out of reach; a cheap test before the search).
    boxes: Vec<ParamBox>,
    /// The pending photons' parameters, indexed in parameter space.
    index: SpatialIndex,
}

impl<'a> ParamNear<'a> {
    fn new(
        input: &DetectInput<'a>,
        interior: &[u32],
        pending: &[usize],
        r_param: &[f32],
        growths: u32,
    ) -> Result<Self, DetectError> {
        let points = input.points(true);
        let column = input.params.expect("a parameter search has parameters");
        let emitters = points.emitters.map_or(1, |e| e.iter().max().map_or(1, |&m| m as usize + 1));
        let mut reach2 = vec![-1.0f64; emitters];
        let ids: Vec<u32> = pending.iter().map(|&q| interior[q]).collect();
        for (&q, &g) in pending.iter().zip(&ids) {
            let e = points.emitter(g as usize) as usize;
            let reach = if column.dims_of(e as u16) == 0 {
                f64::INFINITY
            } else {
                // The last growth's radius, r·2^growths, widened far beyond the rounding of the
                // f32 squared distances the searches compare.
                r_param[q] as f64 * 2f64.powi(growths.min(1000) as i32) * (1.0 + 1e-4) + 1e-30
            };
            reach2[e] = reach2[e].max(reach * reach);
        }
        let inner = ranges(&points, Some(&ids));
        let boxes = (0..emitters)
            .map(|e| {
                let d = column.dims_of(e as u16).min(MAX_PARAM_DIMS);
                let reach = if reach2[e] > 0.0 { reach2[e].sqrt() * (1.0 + 1e-4) } else { 0.0 };
                let mut b = ParamBox { dims: d, lo: [0.0; MAX_PARAM_DIMS], hi: [0.0; MAX_PARAM_DIMS] };
                for c in 0..d {
                    b.lo[c] = inner[e].lo[c] as f64 - reach;
                    b.hi[c] = inner[e].hi[c] as f64 + reach;
                }
                b
            })
            .collect();
        let pages = input.pages;
        let positions = pages.released(permuted(input.positions, &ids, 1));
        let values = pages.released(permuted(column.values, &ids, column.stride));
        let emitter_ids = pages.released(input.emitters.map(|e| permuted(e, &ids, 1)));
        let index = {
            let sub = PointSet {
                positions: &positions,
                params: Some(ParamColumn { values: &values, ..column }),
                emitters: emitter_ids.as_deref(),
            };
            SpatialIndex::build(&sub, Space::Params)?
        };
        Ok(ParamNear { points, reach2, boxes, index })
    }

    /// Whether photon `j` of the map may be a candidate of a pending photon's search.
    fn admits(&self, j: usize) -> bool {
        let reach2 = self.reach2[self.points.emitter(j) as usize];
        if reach2 < 0.0 {
            return false;
        }
        if reach2 == f64::INFINITY {
            return true;
        }
        if !self.boxes[self.points.emitter(j) as usize].contains(self.points.params_of(j)) {
            return false;
        }
        let mut nb = Neighbours::farthest_only(1);
        self.index.knn(&self.points.query(j, None), 1, &mut nb);
        nb.max_dist2().is_some_and(|d2| (d2 as f64) <= reach2)
    }
}

/// Per emitter: its photons' count and the range of each parameter component.
#[derive(Clone, Copy, Debug)]
struct Range {
    count: usize,
    lo: [f32; MAX_PARAM_DIMS],
    hi: [f32; MAX_PARAM_DIMS],
}

impl Default for Range {
    fn default() -> Self {
        Range { count: 0, lo: [f32::INFINITY; MAX_PARAM_DIMS], hi: [f32::NEG_INFINITY; MAX_PARAM_DIMS] }
    }
}

impl Range {
    fn add(&mut self, q: &[f32]) {
        self.count += 1;
        for (c, &v) in q.iter().enumerate() {
            self.lo[c] = self.lo[c].min(v);
            self.hi[c] = self.hi[c].max(v);
        }
    }
}

/// Each emitter's [`Range`] over `photons` (all of them when `None`).
fn ranges(points: &PointSet, photons: Option<&[u32]>) -> Vec<Range> {
    let emitters = points.emitters.map_or(1, |e| e.iter().max().map_or(1, |&m| m as usize + 1));
    let mut r = vec![Range::default(); emitters];
    let mut add = |i: usize| r[points.emitter(i) as usize].add(points.params_of(i));
    match photons {
        Some(ids) => ids.iter().for_each(|&i| add(i as usize)),
        None => (0..points.len()).for_each(add),
    }
    r
}

/// A box in one emitter's parameter space: the interior photons' range grown by a margin,
/// ±∞ on the sides beyond which the emitter has no photon.
#[derive(Clone, Copy, Debug)]
struct ParamBox {
    dims: usize,
    lo: [f64; MAX_PARAM_DIMS],
    hi: [f64; MAX_PARAM_DIMS],
}

impl ParamBox {
    fn grown(inner: &Range, all: &Range, dims: usize, h: f64) -> Self {
        let mut b =
            ParamBox { dims, lo: [f64::NEG_INFINITY; MAX_PARAM_DIMS], hi: [f64::INFINITY; MAX_PARAM_DIMS] };
        for c in 0..dims {
            let (l, u) = (inner.lo[c] as f64 - h, inner.hi[c] as f64 + h);
            if l > all.lo[c] as f64 {
                b.lo[c] = l;
            }
            if u < all.hi[c] as f64 {
                b.hi[c] = u;
            }
        }
        b
    }

    fn contains(&self, q: &[f32]) -> bool {
        q.iter().take(self.dims).enumerate().all(|(c, &v)| self.lo[c] <= v as f64 && v as f64 <= self.hi[c])
    }

    fn is_whole(&self) -> bool {
        (0..self.dims).all(|c| self.lo[c].is_infinite() && self.hi[c].is_infinite())
    }

    /// The distance from `q` (inside) to the outside: photons outside lie strictly farther.
    fn margin(&self, q: &[f32]) -> f64 {
        q.iter()
            .take(self.dims)
            .enumerate()
            .map(|(c, &v)| (v as f64 - self.lo[c]).min(self.hi[c] - v as f64))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Photons per stretch of [`tile_radius`]'s scan of the whole map's parameters.
const SCAN: usize = 1 << 20;

/// Eq. 1's r_param of each photon of `interior` (file indices of `input`), exactly as
/// [`super::param_radius`] over the whole map gives it: the k nearest in parameter space are
/// searched among the photons of the emitter whose parameters lie in the interior's box grown
/// by h_p, certified against that box's margin, and searched again with h_p doubled where not.
/// Also how many rounds that took.
fn tile_radius(
    input: &DetectInput,
    interior: &[u32],
    p: &DetectParams,
    opts: Options,
    map_ranges: Option<&[Range]>,
) -> Result<(Vec<f32>, u32), DetectError> {
    let points = input.points(true);
    let Some(column) = input.params else { return Ok((vec![0.0; interior.len()], 0)) };
    let k = p.k_density.unwrap_or(p.kc);
    let all = match map_ranges {
        Some(r) => r.to_vec(),
        None => ranges(&points, None),
    };
    let inner = ranges(&points, Some(interior));
    let dims = |e: usize| column.dims_of(e as u16).min(MAX_PARAM_DIMS);
    let mut radius = vec![0f32; interior.len()];
    // Photons of emitters without parameters keep r_param = 0, as the whole map gives them.
    let mut pending: Vec<usize> =
        (0..interior.len()).filter(|&q| dims(points.emitter(interior[q] as usize) as usize) > 0).collect();
    let mut rounds = 0u32;
    let mut scale = 2.0 * opts.halo_scale;
    while !pending.is_empty() {
        rounds += 1;
        let boxes: Vec<ParamBox> = (0..all.len())
            .map(|e| {
                let d = dims(e);
                let extent = (0..d).map(|c| all[e].hi[c] as f64 - all[e].lo[c] as f64).fold(0.0, f64::max);
                let h = if rounds >= MAX_ROUNDS {
                    f64::INFINITY
                } else {
                    scale * extent * (k as f64 / all[e].count.max(1) as f64).sqrt()
                };
                ParamBox::grown(&inner[e], &all[e], d, h)
            })
            .collect();
        let active: Vec<bool> = {
            let mut a = vec![false; all.len()];
            pending.iter().for_each(|&q| a[points.emitter(interior[q] as usize) as usize] = true);
            a
        };
        let pages = input.pages;
        // The scan reads every photon's parameters a stretch at a time, each stretch's pages
        // released once read; the gathers copy the members' rows in blocks released as read.
        let mut members: Vec<u32> = Vec::new();
        for start in (0..points.len()).step_by(SCAN) {
            let end = (start + SCAN).min(points.len());
            members.par_extend((start as u32..end as u32).into_par_iter().filter(|&j| {
                let e = points.emitter(j as usize) as usize;
                active[e] && boxes[e].contains(points.params_of(j as usize))
            }));
            pages.release_range(bytemuck::cast_slice(
                &column.values[start * column.stride..end * column.stride],
            ));
            if let Some(e) = input.emitters {
                pages.release_range(bytemuck::cast_slice(&e[start..end]));
            }
        }
        let positions = pages.gather(input.positions, &members);
        let values = pages.gather_rows(column.values, column.stride, &members);
        let emitters = input.emitters.map(|e| pages.gather(e, &members));
        let sub = PointSet {
            positions: &positions,
            params: Some(ParamColumn { values: &values, ..column }),
            emitters: emitters.as_deref(),
        };
        let index = SpatialIndex::build(&sub, Space::Params)?;
        // Queried in the index's order, so that consecutive queries share their candidates
        // (in file order they jump across parameter space); the results do not depend on it.
        let mut rank = vec![0u32; members.len()];
        for (r, &l) in index.order().iter().enumerate() {
            rank[l as usize] = r as u32;
        }
        let mut by_rank: Vec<(u32, usize, usize)> = pending
            .iter()
            .map(|&q| {
                let l = members.binary_search(&interior[q]).expect("interior photons are candidates");
                (rank[l], l, q)
            })
            .collect();
        by_rank.par_sort_unstable();
        let found: Vec<(usize, f32, bool)> = by_rank
            .par_chunks(CHUNK)
            .flat_map_iter(|qs| {
                let mut nb = Neighbours::farthest_only(k);
                qs.iter()
                    .enumerate()
                    .map(|(o, &(_, l, q))| {
                        if let Some(&(_, a, _)) = qs.get(o + crate::spatial::PREFETCH_AHEAD) {
                            sub.prefetch(a);
                        }
                        // The photon's values from the gathered copy (the map's pages are
                        // released).
                        index.knn(&sub.query(l, None), k, &mut nb);
                        let b = &boxes[sub.emitter(l) as usize];
                        let certified = b.is_whole()
                            || !opts.certify
                            || (nb.len() == k
                                && nb
                                    .max_dist2()
                                    .is_some_and(|d2| within_margin(d2, b.margin(sub.params_of(l)))));
                        (q, radius_of(&nb, p.kc, p.beta), certified)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        let mut next = Vec::new();
        for &(q, r, certified) in &found {
            if certified {
                radius[q] = r;
            } else {
                next.push(q);
            }
        }
        // The certificates read the interior photons' parameters across the file.
        pages.release();
        next.sort_unstable();
        pending = next;
        scale *= 2.0;
    }
    Ok((radius, rounds))
}

/// Detection of the whole map tile by tile: [`detect_tile`] for each tile of `tiling`, put
/// together by [`assemble`]. Bit for bit what [`super::detect`] gives (docs/tiles.md).
pub fn tiled(
    input: &DetectInput,
    p: &DetectParams,
    tiling: &Tiling,
    radius: Radius,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Detection, DetectError> {
    tiled_with(input, p, tiling, radius, progress, &mut |_, _, _| {})
}

/// Where a run of every tile finds Eq. 1's r_param.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Radius {
    /// Once for the whole map, before the tiles, as [`super::detect`] does: one index over
    /// every photon's parameters ([`RADIUS_PASS_BYTES`] a photon while it runs), and the
    /// cheapest, since each tile's own search also gathers and indexes the photons of its
    /// grown parameter box.
    Whole,
    /// Tile by tile, each over the photons of its grown parameter box (docs/tiles.md): for a
    /// budget that the whole map's index does not fit beside the map's results.
    PerTile,
}

impl Radius {
    /// [`Radius::Whole`] when its pass fits in `budget` bytes beside what a map of `photons`
    /// photons needs per photon in detection (`model`) and the `held` bytes the process holds
    /// already; [`Radius::PerTile`] otherwise.
    pub fn for_budget(photons: usize, budget: u64, held: u64, model: &crate::tiles::MemoryModel) -> Radius {
        match held as f64 + (model.per_photon + RADIUS_PASS_BYTES) * photons as f64 <= budget as f64 {
            true => Radius::Whole,
            false => Radius::PerTile,
        }
    }
}

/// What finding r_param for the whole map at once ([`Radius::Whole`]) holds per photon while
/// it runs, beyond [`memory`]'s per-photon part: the parameter index and the pages of the
/// parameters it reads. On the water at 10⁷ under `--memory 1G` the pass raised detect's peak
/// from 534 to 682 MB, 15 bytes a photon; this allows half as much again.
pub const RADIUS_PASS_BYTES: f64 = 24.0;

/// [`tiled`], calling `on_tile(tile, tiles, result)` after each tile and holding one tile's
/// results at a time besides the map's.
pub fn tiled_with(
    input: &DetectInput,
    p: &DetectParams,
    tiling: &Tiling,
    radius: Radius,
    progress: &(dyn Fn(u64) + Sync),
    on_tile: &mut dyn FnMut(usize, usize, &TileDetection),
) -> Result<Detection, DetectError> {
    check_params(p)?;
    let n = input.positions.len();
    let shared = Shared::new(input, tiling, p)?;
    // Checking and bucketing read every photon's columns: their pages are not the tiles' to hold.
    input.pages.release();
    let capped = p.capped(n);
    // Whether the tiles' parts carry r_param ([`detect_tile_with`]'s parameter search).
    let param_search = input.has_params() && capped.method == Method::ParamPca;
    let found_first = radius == Radius::Whole && param_search;
    let mut whole = if found_first {
        // Eq. 1 over the whole map: the very computation of the untiled detection, so every
        // radius is its radius; the assembly keeps it (the tiles' copies write the same values).
        let k = capped.k_density.unwrap_or(capped.kc);
        let r = super::param_radius(&input.points(true), capped.kc, k, capped.beta, progress)?;
        input.pages.release();
        Assembly::with_r_param(r)
    } else {
        Assembly::new(n, param_search)
    };
    for t in 0..tiling.len() {
        let known = whole.d.r_param.as_deref().filter(|_| found_first);
        let run = InRun { shared: &shared, radius: known };
        let part = detect_tile_with(input, p, tiling, t, Options::default(), Some(run), progress)?;
        whole.add(&part)?;
        on_tile(t, tiling.len(), &part);
    }
    whole.finish()
}

/// The detection of a map of `n` photons from its tiles' parts (in any order): an error unless
/// every photon is in exactly one part and the parts agree on having r_param.
pub fn assemble(n: usize, parts: &[TileDetection]) -> Result<Detection, DetectError> {
    let mut whole = Assembly::new(n, parts.first().is_some_and(|t| t.r_param.is_some()));
    for t in parts {
        whole.add(t)?;
    }
    whole.finish()
}

/// The whole map's detection put together tile by tile ([`assemble`]), so a run of every tile
/// in one process holds one tile's results at a time besides the map's columns: per photon its
/// basis, λ2 and r_param, and a bit for whether a tile gave it (the report's counts and factor
/// sum are summed as the tiles come, [`super::SummarySums`]).
pub struct Assembly {
    d: Detection,
    sums: super::SummarySums,
    /// One bit per photon: given by a tile.
    seen: Vec<u64>,
}

impl Assembly {
    /// An empty detection of `n` photons (with an r_param column when `with_r`).
    pub fn new(n: usize, with_r: bool) -> Assembly {
        Assembly {
            d: Detection {
                basis_u: vec![[0.0; 3]; n],
                basis_v: vec![[0.0; 3]; n],
                lambda2: vec![0.0; n],
                r_param: with_r.then(|| vec![0.0; n]),
                ..Default::default()
            },
            sums: Default::default(),
            seen: vec![0; n.div_ceil(64)],
        }
    }

    /// An empty detection whose r_param column is `r_param` already (found for the whole map;
    /// the tiles' parts must carry the same).
    pub fn with_r_param(r_param: Vec<f32>) -> Assembly {
        let mut a = Assembly::new(r_param.len(), false);
        a.d.r_param = Some(r_param);
        a
    }

    /// Adds one tile's photons.
    pub fn add(&mut self, t: &TileDetection) -> Result<(), DetectError> {
        let bad = |m: String| Err(DetectError::Parameter(m));
        let n = self.d.basis_u.len();
        let d = &mut self.d;
        if t.r_param.is_some() != d.r_param.is_some() {
            return bad("the tiles disagree on having r_param".into());
        }
        let len = t.indices.len();
        if [t.basis_u.len(), t.basis_v.len(), t.lambda2.len(), t.factor.len(), t.outcome.len()]
            .iter()
            .chain(t.r_param.as_ref().map(|r| r.len()).as_ref())
            .any(|&l| l != len)
        {
            return bad("a tile's columns differ in length".into());
        }
        for (k, &i) in t.indices.iter().enumerate() {
            let i = i as usize;
            if i >= n {
                return bad(format!("photon {i} is not in a map of {n}"));
            }
            let (word, bit) = (&mut self.seen[i / 64], 1u64 << (i % 64));
            if *word & bit != 0 {
                return bad(format!("photon {i} is in two tiles"));
            }
            *word |= bit;
            d.basis_u[i] = t.basis_u[k];
            d.basis_v[i] = t.basis_v[k];
            d.lambda2[i] = t.lambda2[k];
            if let (Some(r), Some(tr)) = (&mut d.r_param, &t.r_param) {
                r[i] = tr[k];
            }
        }
        self.sums.add(&t.factor, &t.outcome);
        Ok(())
    }

    /// The detection, once every photon was added.
    pub fn finish(mut self) -> Result<Detection, DetectError> {
        let n = self.d.basis_u.len();
        let missing = self.seen.iter().enumerate().find_map(|(w, &bits)| {
            // The last word's bits past the map's photons count as seen.
            let past = if (w + 1) * 64 > n { !0u64 << (n - w * 64) } else { 0 };
            let unseen = !(bits | past);
            (unseen != 0).then(|| w * 64 + unseen.trailing_zeros() as usize)
        });
        if let Some(i) = missing {
            return Err(DetectError::Parameter(format!("photon {i} is in no tile")));
        }
        self.d.summary = self.sums.summary();
        Ok(self.d)
    }
}
