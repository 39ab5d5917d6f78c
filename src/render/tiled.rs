//! The k-NN estimate of a map too large to hold, tile by tile (docs/tiles.md, "Render").
//!
//! A render looks the caustic up at a few million diffuse hits ([`super::Lookup`]), whatever
//! the map's size; the photons are what does not fit. So the hits stay in memory, each with
//! the k best photons found so far, and the map streams past them one spatial tile at a time
//! ([`crate::tiles::Tiling`]): a tile's photons are copied out of the file, indexed, and
//! searched from every hit whose k nearest it may hold. Before any tile is read, each hit's k-th
//! nearest among a sample of the map (one photon in [`SAMPLE_EVERY`]) bounds its search: a
//! subset's k-th nearest is never nearer than the map's. One sweep over the tiles then reads
//! each tile at most once, skipping a tile whose photons' box lies beyond the reach of every
//! hit. No halo: a hit far from any light (most of a floor) searches the tiles near it, not
//! the whole map. A tile can also be searched alone, as a job of its own
//! ([`StreamedMap::candidates`], [`estimate_from_candidates`]).
//!
//! The result is exact: a hit's k nearest by (distance², photon index) are the k smallest of
//! the per-tile k nearest within the current k-th distance, merged in that order, and the
//! estimate sums them nearest first as [`super::PhotonLookup`] does, so the image is the
//! untiled one byte for byte (tested).

use glam::Vec3;
use rayon::prelude::*;

use super::estimate::knn_radius2;
use super::{Kernel, Lookup, RenderError};
use crate::format::{MapView, name};
use crate::spatial::{BoxTree, Neighbours};
use crate::tiles::{MemoryModel, Tiling};

/// What the streamed estimate keeps in memory per photon: the map's photons in tile order
/// (4 bytes, and as much again while they are sorted), and per photon of the tile in hand its
/// position, flux and normal (36 bytes), its index (4), and the tile's k-NN index (about 42,
/// with the build's scratch). Tiles hold no halo; they hold equal shares of the photons give
/// or take two, and 5 % covers that with the index's rounding of node counts.
pub const MEMORY: MemoryModel = MemoryModel { per_photon: 8.0, per_working_photon: 82.0, halo_growth: 1.05 };

/// Bytes a lookup of a chunk holds while the map streams past, for an estimate of `k`
/// photons: its own tile, how many it found, and its k best so far (distance², index and flux
/// each).
pub fn lookup_bytes(k: usize) -> u64 {
    (4 + 4 + size_of::<Candidate>() * k) as u64
}

/// What the process holds besides the photons, the lookups and the image (the program, the
/// scene and its index, the worker threads) where it cannot be measured
/// ([`crate::tiles::resident_bytes`]); measured: 10 MB on the default scene, 30 MB on the
/// water's.
pub const BASELINE: u64 = 40 << 20;

/// Room for the worker threads' scratch and the allocator's slack, over what the process held
/// when the render began.
pub const HEADROOM: u64 = 8 << 20;

/// Bytes per photon of the render that holds the whole map: its k-NN index and its columns.
pub const WHOLE_PER_PHOTON: f64 = 86.0;

/// The fewest lookups a chunk holds (below it, passes over the map would cost more than the
/// lookups save).
pub const MIN_CHUNK_LOOKUPS: usize = 4096;

/// What a render asks of memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Demand {
    /// The map's photons.
    pub photons: usize,
    /// The diffuse hits the caustic is looked up at.
    pub lookups: usize,
    /// Photons per estimate.
    pub k: usize,
    /// The image with what it keeps for the preview, bytes.
    pub image_bytes: u64,
    /// What the process holds besides: the program, the scene ([`Demand::baseline_now`]).
    pub baseline: u64,
}

impl Demand {
    /// The baseline of a render that begins now: what the process holds and [`HEADROOM`], or
    /// [`BASELINE`] where that cannot be measured.
    pub fn baseline_now() -> u64 {
        crate::tiles::resident_bytes().map_or(BASELINE, |r| r + HEADROOM)
    }
}

/// How a streamed estimate fits a budget: the map cut into `tiles`, the lookups into `chunks`
/// that each stream the map once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plan {
    /// Spatial tiles of the map.
    pub tiles: usize,
    /// Runs of lookups, each a pass over the map.
    pub chunks: usize,
}

impl Plan {
    /// The whole map held at once: no streaming.
    pub const WHOLE: Plan = Plan { tiles: 1, chunks: 1 };
}

/// Whether the render that holds the whole map fits `budget` bytes.
pub fn whole_fits(d: &Demand, budget: u64) -> bool {
    d.baseline + (WHOLE_PER_PHOTON * d.photons as f64) as u64 + d.image_bytes <= budget
}

/// How to stream the map of `d` within `budget` bytes, or the bytes the least plan needs
/// (chunks of [`MIN_CHUNK_LOOKUPS`], tiles of [`crate::tiles::MIN_TILE_PHOTONS`]).
///
/// A pass reads every photon once, and each tile it reads scans the chunk's lookups, so the
/// plan takes the fewest chunks whose tiling ([`crate::tiles::tiles_for_budget`]) has at most
/// [`MAX_TILES_PER_PASS`] tiles, or failing that the one with the fewest tiles (measured on
/// the 10⁷ water under 600M: one pass in 1 406 tiles took 28 s, two passes in 6 tiles 6 s).
/// The peak is the largest of four phases: recording the lookups (64 bytes each while they
/// are collected), cutting the map into tiles (8 bytes a photon besides the lookups), the
/// estimate (the lookups as recorded, up to 48 bytes each with their vectors' slack, their
/// estimates, a chunk's search state and copy, the photons' order and one tile), and the
/// image (the estimates and the image).
pub fn plan(d: &Demand, budget: u64) -> Result<Plan, u64> {
    let lookups = d.lookups as u64;
    // What the estimate holds whatever the chunks: the lookups as recorded.
    let fixed = d.baseline + 60 * lookups;
    // The phases around the estimate: recording the lookups, cutting the map into tiles while
    // they are held (each finite photon's two coordinates: [`Tiling::new_releasing`]), and the
    // image.
    let around = (d.baseline + 64 * lookups)
        .max(fixed + 8 * d.photons as u64)
        .max(d.baseline + 12 * lookups + d.image_bytes);
    let per = lookup_bytes(d.k) + 24;
    let most = d.lookups.div_ceil(MIN_CHUNK_LOOKUPS).max(1);
    let mut chunks = 1;
    let mut fitted: Option<Plan> = None;
    loop {
        let held = fixed + d.lookups.div_ceil(chunks) as u64 * per;
        match crate::tiles::tiles_for_budget(d.photons, budget.saturating_sub(held), &MEMORY) {
            Ok(tiles) => {
                let p = Plan { tiles, chunks };
                if tiles <= MAX_TILES_PER_PASS {
                    fitted = Some(p);
                    break;
                }
                if fitted.is_none_or(|f| tiles < f.tiles) {
                    fitted = Some(p);
                }
            }
            Err(needed) if chunks >= most && fitted.is_none() => return Err((needed + held).max(around)),
            Err(_) => {}
        }
        if chunks >= most {
            break;
        }
        // Halve what a chunk holds.
        chunks = (chunks * 2).min(most);
    }
    match fitted {
        Some(_) if around > budget => Err(around),
        Some(p) => Ok(p),
        None => unreachable!("the loop returns when no chunking fits"),
    }
}

/// The most tiles a pass should read before more passes are cheaper ([`plan`]).
pub const MAX_TILES_PER_PASS: usize = 64;

/// The k-NN estimate's settings ([`super::Estimator::Knn`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Knn {
    /// Photons per estimate.
    pub k: usize,
    /// The kernel over them.
    pub kernel: Kernel,
    /// Largest kernel radius, metres.
    pub max_radius: Option<f32>,
}

/// Progress of [`StreamedMap::estimate`]: the steps (per chunk of lookups, one sweep over the
/// tiles), then each done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// This many steps to go.
    Start(u64),
    /// One more step done.
    Step,
}

/// A photon among a lookup's k best so far.
#[derive(Clone, Copy, Debug, Default)]
struct Candidate {
    dist2: f32,
    index: u32,
    /// Its flux when it faces the lookup's normal, zero when it does not: added, a zero leaves
    /// the sum as skipping the photon does.
    flux: [f32; 3],
}

impl Candidate {
    /// The order of [`crate::spatial::Neighbour::before`]: distance², then index.
    fn before(&self, o: &Candidate) -> bool {
        self.dist2 < o.dist2 || (self.dist2 == o.dist2 && self.index < o.index)
    }
}

/// Squared distance from `q` to the box `lo`–`hi`: never more than the distance to any point
/// inside, as the index computes it (differences and squares are monotone in floating point).
fn box_dist2(lo: &[f32; 3], hi: &[f32; 3], q: &[f32; 3]) -> f32 {
    let mut s = 0.0f32;
    for a in 0..3 {
        let d = (lo[a] - q[a]).max(q[a] - hi[a]).max(0.0);
        s += d * d;
    }
    s
}

/// A map cut into spatial tiles for streaming: its photons' indices in tile order, and each
/// tile's box.
pub struct StreamedMap<'m> {
    map: &'m MapView<'m>,
    file: String,
    tiling: Tiling,
    /// Photon indices, tile by tile, each tile's ascending.
    by_tile: Vec<u32>,
    /// Where each tile starts in `by_tile` (and the end).
    start: Vec<usize>,
    /// Each tile's photons' box (empty tiles: an inverted box).
    boxes: Vec<([f32; 3], [f32; 3])>,
    /// Every [`SAMPLE_EVERY`]-th photon, indexed: a lookup's k-th nearest among them bounds
    /// its k-th nearest in the map (a subset's k-th nearest is never nearer).
    sample: BoxTree,
}

/// One photon in this many, in file order, makes the sample that bounds each lookup's search
/// before any tile is read.
pub const SAMPLE_EVERY: usize = 64;

impl<'m> StreamedMap<'m> {
    /// `map` cut by `tiling`; refuses a map with no photon or a non-finite position. `file`
    /// names the map in errors.
    pub fn new(map: &'m MapView<'m>, file: &str, tiling: Tiling) -> Result<Self, RenderError> {
        let positions = map.positions();
        if positions.is_empty() {
            return Err(RenderError::EmptyMap { file: file.to_string() });
        }
        // The positions are read a stretch at a time, each stretch's pages released once read
        // (all resident at once, they would count against the memory budget).
        const STRETCH: usize = SAMPLE_EVERY << 14;
        let pages = map.pages();
        let tiles = tiling.len();
        let mut tile: Vec<u32> = Vec::with_capacity(positions.len());
        let mut start = vec![0usize; tiles + 1];
        let mut boxes = vec![([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]); tiles];
        // Every SAMPLE_EVERY-th photon (a stretch starts at a multiple of it).
        let mut sample: Vec<[f32; 3]> = Vec::new();
        for (k, s) in positions.chunks(STRETCH).enumerate() {
            if let Some(i) = s.par_iter().position_first(|x| !x.iter().all(|c| c.is_finite())) {
                return Err(RenderError::NonFinite {
                    file: file.to_string(),
                    column: "position".into(),
                    index: (k * STRETCH + i) as u64,
                });
            }
            tile.par_extend(s.par_iter().map(|x| tiling.tile_of(*x) as u32));
            for (&t, x) in tile[k * STRETCH..].iter().zip(s) {
                start[t as usize + 1] += 1;
                let (lo, hi) = &mut boxes[t as usize];
                for a in 0..3 {
                    lo[a] = lo[a].min(x[a]);
                    hi[a] = hi[a].max(x[a]);
                }
            }
            sample.extend(s.iter().step_by(SAMPLE_EVERY).copied());
            pages.release_range(bytemuck::cast_slice(s));
        }
        // A counting sort, stable: each tile's photons in file order.
        for t in 0..tiles {
            start[t + 1] += start[t];
        }
        let mut by_tile = vec![0u32; positions.len()];
        let mut next = start.clone();
        for (i, &t) in tile.iter().enumerate() {
            by_tile[next[t as usize]] = i as u32;
            next[t as usize] += 1;
        }
        let sample = BoxTree::build(&sample);
        Ok(StreamedMap { map, file: file.to_string(), tiling, by_tile, start, boxes, sample })
    }

    /// How many tiles.
    pub fn tiles(&self) -> usize {
        self.tiling.len()
    }

    /// The caustic irradiance at each of `lookups` (per image tile, as
    /// [`super::Renderer::lookups`] records them), estimated with `knn` as
    /// [`super::PhotonLookup::irradiance`] does, in about `chunks` runs of whole image tiles
    /// that each stream the map's tiles through memory (module docs).
    pub fn estimate(
        &self,
        lookups: &[Vec<Lookup>],
        knn: Knn,
        chunks: usize,
        progress: &(dyn Fn(Progress) + Sync),
    ) -> Result<Vec<Vec<Vec3>>, RenderError> {
        let total: usize = lookups.iter().map(Vec::len).sum();
        let share = total.div_ceil(chunks.max(1)).max(1);
        // Runs of image tiles of about `share` lookups each.
        let mut runs = vec![0usize];
        let mut held = 0;
        for (t, l) in lookups.iter().enumerate() {
            held += l.len();
            if held >= share && t + 1 < lookups.len() {
                runs.push(t + 1);
                held = 0;
            }
        }
        runs.push(lookups.len());
        progress(Progress::Start(((runs.len() - 1) * self.tiles()) as u64));
        let mut out = Vec::with_capacity(lookups.len());
        for run in runs.windows(2) {
            let tiles = &lookups[run[0]..run[1]];
            let flat: Vec<Lookup> = tiles.iter().flatten().copied().collect();
            out.extend(per_image_tile(&self.estimate_chunk(&flat, knn, progress)?, tiles));
        }
        Ok(out)
    }

    /// Each lookup's search radius² before any tile is read: its k-th nearest distance²
    /// among the sample (at most the limit `max2`), which bounds its k-th nearest in the map.
    fn bounds(&self, lookups: &[Lookup], k: usize, max2: f32) -> Vec<f32> {
        lookups
            .par_iter()
            .map_init(Neighbours::default, |nb, l| {
                self.sample.knn(l.point.to_array(), k, max2, nb);
                match nb.last() {
                    Some(last) if nb.len() == k => last.dist2,
                    _ => max2,
                }
            })
            .collect()
    }

    /// Tile `t`'s photons taken out of the file, checked and indexed.
    fn load(&self, t: usize) -> Result<LoadedTile<'_>, RenderError> {
        let map = self.map;
        let members = &self.by_tile[self.start[t]..self.start[t + 1]];
        let bad = |column: &str, index: u32| RenderError::NonFinite {
            file: self.file.clone(),
            column: column.to_string(),
            index: index as u64,
        };
        let finite = |x: &[f32; 3]| x.iter().all(|c| c.is_finite());
        // Copied out of the file, whose pages are let go block by block.
        let pages = map.pages();
        let pos = pages.gather(map.positions(), members);
        let flux = pages.gather(map.flux(), members);
        let normals = map.column::<[f32; 3]>(name::NORMAL)?.map(|ns| pages.gather(ns, members));
        if let Some(j) = flux.par_iter().position_first(|x| !finite(x)) {
            return Err(bad("flux", members[j]));
        }
        if let Some(j) = normals.as_ref().and_then(|ns| ns.par_iter().position_first(|x| !finite(x))) {
            return Err(bad("normal", members[j]));
        }
        let tree = BoxTree::build(&pos);
        let (lo, hi) = self.boxes[t];
        Ok(LoadedTile { members, flux, normals, tree, lo, hi })
    }

    fn estimate_chunk(
        &self,
        lookups: &[Lookup],
        knn: Knn,
        progress: &(dyn Fn(Progress) + Sync),
    ) -> Result<Vec<Vec3>, RenderError> {
        let k = knn.k.max(1);
        let max2 = knn.max_radius.map_or(f32::INFINITY, |m| m * m);
        let bound = self.bounds(lookups, k, max2);
        let mut best = vec![Candidate::default(); lookups.len() * k];
        let mut found = vec![0u32; lookups.len()];
        // The search radius² of a lookup: its k-th best so far, or the sample's bound.
        let reach2 = |found: u32, list: &[Candidate], bound: f32| {
            if found as usize == k { list[k - 1].dist2 } else { bound }
        };
        for t in 0..self.tiles() {
            let (lo, hi) = self.boxes[t];
            // Whether some lookup could find one of its k nearest in this tile.
            let wanted = |(i, l): (usize, &Lookup)| {
                box_dist2(&lo, &hi, &l.point.to_array())
                    <= reach2(found[i], &best[i * k..(i + 1) * k], bound[i])
            };
            if self.start[t] == self.start[t + 1] || !lookups.par_iter().enumerate().any(wanted) {
                progress(Progress::Step);
                continue;
            }
            let tile = self.load(t)?;
            best.par_chunks_mut(k)
                .zip(found.par_iter_mut())
                .zip(lookups.par_iter().zip(bound.par_iter()))
                .for_each_init(
                    || (Neighbours::default(), Vec::with_capacity(k)),
                    |(nb, merged), ((list, found), (lookup, &bound))| {
                        let have = *found as usize;
                        if !tile.find(lookup, k, reach2(*found, list, bound), nb) {
                            return;
                        }
                        merge_best(&list[..have], tile.found(lookup, nb), k, merged);
                        list[..merged.len()].copy_from_slice(merged);
                        *found = merged.len() as u32;
                    },
                );
            progress(Progress::Step);
        }

        // E(x) = Σ Φ_p w(d_p) over the k nearest, nearest first, as the untiled estimate sums
        // it (a photon facing away adds zero, as the untiled sum skips it).
        Ok(best
            .par_chunks(k)
            .zip(found.par_iter())
            .map(|(list, &found)| kernel_sum(&list[..found as usize], k, max2, knn.kernel))
            .collect())
    }

    /// Tile `tile`'s share of the estimate, for a job of its own (`render --tile`): for each
    /// lookup, the k photons of the tile nearest it within the sample's bound on its k-th
    /// nearest in the map. The k nearest of the map are among the union of every tile's
    /// ([`estimate_from_candidates`]).
    pub fn candidates(
        &self,
        lookups: &[Lookup],
        knn: Knn,
        tile: usize,
    ) -> Result<TileCandidates, RenderError> {
        let k = knn.k.max(1);
        let max2 = knn.max_radius.map_or(f32::INFINITY, |m| m * m);
        let mut out = TileCandidates::default();
        if tile >= self.tiles() || self.start[tile] == self.start[tile + 1] {
            return Ok(out);
        }
        let bound = self.bounds(lookups, k, max2);
        let t = self.load(tile)?;
        let rows: Vec<Vec<(u32, f32)>> = lookups
            .par_iter()
            .zip(bound.par_iter())
            .map_init(Neighbours::default, |nb, (lookup, &bound)| {
                t.find(lookup, k, bound, nb);
                t.found(lookup, nb).map(|c| (c.index, c.dist2)).collect()
            })
            .collect();
        for (i, r) in rows.into_iter().enumerate() {
            for (photon, dist2) in r {
                out.lookup.push(i as u32);
                out.photon.push(photon);
                out.dist2.push(dist2);
            }
        }
        Ok(out)
    }
}

/// One tile's photons in memory: their indices in the map, flux, normals, index and box.
struct LoadedTile<'s> {
    members: &'s [u32],
    flux: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    tree: BoxTree,
    lo: [f32; 3],
    hi: [f32; 3],
}

impl LoadedTile<'_> {
    /// Finds into `nb` the tile's photons among the k nearest `lookup` within distance²
    /// `reach2`, nearest first (none when the tile's box lies beyond the reach); whether any.
    fn find(&self, lookup: &Lookup, k: usize, reach2: f32, nb: &mut Neighbours) -> bool {
        let q = lookup.point.to_array();
        let far = box_dist2(&self.lo, &self.hi, &q) > reach2;
        // k = 0 finds nothing: it empties `nb`.
        self.tree.knn(q, if far { 0 } else { k }, reach2, nb);
        !nb.is_empty()
    }

    /// The photons [`Self::find`] found, as candidates with their indices in the map.
    fn found<'a>(&'a self, lookup: &Lookup, nb: &'a Neighbours) -> impl Iterator<Item = Candidate> + 'a {
        let n = lookup.normal;
        nb.as_slice().iter().map(move |c| {
            let j = c.index as usize;
            let faces = self.normals.as_ref().is_none_or(|ns| Vec3::from_array(ns[j]).dot(n) > 0.0);
            Candidate {
                dist2: c.dist2,
                index: self.members[j],
                flux: if faces { self.flux[j] } else { [0.0; 3] },
            }
        })
    }
}

/// One map tile's share of a streamed estimate ([`StreamedMap::candidates`]): per row, a
/// lookup (its place among the image's lookups in order), a photon of the tile (its index in
/// the map) and their squared distance; rows by lookup, each lookup's nearest first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TileCandidates {
    /// The lookup of each row.
    pub lookup: Vec<u32>,
    /// The photon of each row, its index in the map.
    pub photon: Vec<u32>,
    /// Their squared distance, as the index computes it.
    pub dist2: Vec<f32>,
}

/// A row of [`estimate_from_candidates`]: a lookup's candidate photon with what its estimate
/// needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CandidateRow {
    /// The lookup.
    pub lookup: u32,
    /// The photon's index in the map.
    pub photon: u32,
    /// Their squared distance.
    pub dist2: f32,
    /// The photon's flux.
    pub flux: [f32; 3],
    /// The photon's normal, when the map has normals.
    pub normal: Option<[f32; 3]>,
}

/// The estimate at each of `lookups` from every tile's candidates (in any order): the k first
/// by (distance², photon index) of each lookup's rows, summed as the untiled estimate sums
/// them. The same values, bit for bit, as [`StreamedMap::estimate`] when the rows are every
/// tile's [`StreamedMap::candidates`].
pub fn estimate_from_candidates(lookups: &[Lookup], mut rows: Vec<CandidateRow>, knn: Knn) -> Vec<Vec3> {
    let k = knn.k.max(1);
    let max2 = knn.max_radius.map_or(f32::INFINITY, |m| m * m);
    rows.par_sort_unstable_by(|a, b| {
        a.lookup.cmp(&b.lookup).then(a.dist2.total_cmp(&b.dist2)).then(a.photon.cmp(&b.photon))
    });
    let mut start = vec![0usize; lookups.len() + 1];
    for r in &rows {
        if (r.lookup as usize) < lookups.len() {
            start[r.lookup as usize + 1] += 1;
        }
    }
    for i in 0..lookups.len() {
        start[i + 1] += start[i];
    }
    lookups
        .par_iter()
        .enumerate()
        .map(|(i, l)| {
            let mine = &rows[start[i]..start[i + 1]];
            let list: Vec<Candidate> = mine
                .iter()
                .take(k)
                .map(|r| {
                    let faces = r.normal.is_none_or(|nm| Vec3::from_array(nm).dot(l.normal) > 0.0);
                    Candidate { dist2: r.dist2, index: r.photon, flux: if faces { r.flux } else { [0.0; 3] } }
                })
                .collect();
            kernel_sum(&list, k, max2, knn.kernel)
        })
        .collect()
}

/// E = Σ Φ_p w(d_p) over a lookup's k nearest `list`, nearest first, r² the k-th's distance²
/// (the limit `max2` when fewer were found): the untiled estimate's sum, term for term.
fn kernel_sum(list: &[Candidate], k: usize, max2: f32, kernel: Kernel) -> Vec3 {
    let Some(last) = list.last() else { return Vec3::ZERO };
    let Some(r2) = knn_radius2(list.len(), k, last.dist2, max2) else { return Vec3::ZERO };
    let mut e = Vec3::ZERO;
    for c in list {
        if c.dist2 <= r2 {
            e += Vec3::from_array(c.flux) * kernel.weight(c.dist2, r2);
        }
    }
    e
}

/// `values`, one per lookup in the order of `lookups` flattened, split back into image tiles
/// as `lookups` holds them (what [`super::Renderer::render_given`] takes).
pub(crate) fn per_image_tile<T: Copy>(values: &[T], lookups: &[Vec<Lookup>]) -> Vec<Vec<T>> {
    let mut at = 0;
    lookups
        .iter()
        .map(|l| {
            at += l.len();
            values[at - l.len()..at].to_vec()
        })
        .collect()
}

/// The `k` first of two lists each sorted by [`Candidate::before`], into `out`.
fn merge_best(a: &[Candidate], b: impl Iterator<Item = Candidate>, k: usize, out: &mut Vec<Candidate>) {
    out.clear();
    let mut b = b.peekable();
    let mut a = a.iter().peekable();
    while out.len() < k {
        let take_a = match (a.peek(), b.peek()) {
            (Some(x), Some(y)) => !y.before(x),
            (Some(_), None) => true,
            (None, Some(_)) => false,
            (None, None) => break,
        };
        if take_a {
            out.push(*a.next().expect("peeked"));
        } else {
            out.push(b.next().expect("peeked"));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::PhotonTable;
    use crate::render::{Estimator, PhotonData, PhotonLookup, Scratch};
    use crate::synthetic::uniform_square;
    use crate::tiles::TileSpec;

    /// A square of photons with a crowd of 24 on one point, a band lit from the other side
    /// (normals −z), and fluxes that differ photon to photon.
    fn map(n: usize) -> crate::synthetic::SyntheticMap {
        let mut m = uniform_square(n, 7, 1.0);
        for (i, (x, (f, nl))) in m.position.iter_mut().zip(m.flux.iter_mut().zip(&mut m.normal)).enumerate() {
            *f = [f[0] * (1.0 + (i % 7) as f32), f[1], f[2] * (1.0 + (i % 3) as f32)];
            if x[0] > 0.6 && x[0] < 0.7 {
                *nl = [0.0, 0.0, -1.0];
            }
            if i % 97 == 0 && i < 24 * 97 {
                *x = [0.25, 0.75, 0.0];
            }
        }
        m
    }

    /// Lookups on a grid over the square and beyond it, facing both ways, and on the crowd.
    fn lookups() -> Vec<Vec<Lookup>> {
        let mut all = Vec::new();
        for row in 0..9 {
            let tile: Vec<Lookup> = (0..40)
                .map(|j| {
                    let (x, y) = (-0.3 + 1.6 * j as f32 / 39.0, -0.2 + 1.4 * row as f32 / 8.0);
                    let up = if (row + j) % 5 == 0 { -1.0 } else { 1.0 };
                    Lookup { point: Vec3::new(x, y, 0.0), normal: Vec3::new(0.0, 0.0, up) }
                })
                .chain([Lookup { point: Vec3::new(0.25, 0.75, 0.0), normal: Vec3::Z }])
                .collect();
            all.push(tile);
        }
        all.push(Vec::new());
        all
    }

    #[test]
    fn streamed_estimates_equal_the_whole_maps_bit_for_bit() {
        for n in [3_000, 10] {
            let m = map(n);
            let info = m.info("test", 1, "2026-01-01T00:00:00Z");
            let table = PhotonTable::from_columns("square", info, &m.columns()).unwrap();
            let view = table.view();
            let data = PhotonData { positions: &m.position, flux: &m.flux, normals: Some(&m.normal) };
            let whole = PhotonLookup::new("square", data).unwrap();
            let lookups = lookups();
            for (k, max_radius) in [(15, None), (1, None), (40, None), (15, Some(0.02))] {
                let knn = Knn { k, kernel: Kernel::Epanechnikov, max_radius };
                let est = Estimator::Knn { k, kernel: Kernel::Epanechnikov, max_radius };
                let mut s = Scratch::default();
                let expected: Vec<Vec<Vec3>> = lookups
                    .iter()
                    .map(|t| t.iter().map(|l| whole.irradiance(&est, l.point, l.normal, &mut s)).collect())
                    .collect();
                let lit = expected.iter().flatten().filter(|e| e.x > 0.0).count();
                assert!(n < 100 || k == 1 || lit > 50, "n {n}, k {k}: {lit} lookups see light");
                for count in [1, 2, 4, 9] {
                    let tiling = Tiling::new(&m.position, TileSpec { index: 0, count }.grid());
                    let streamed = StreamedMap::new(&view, "square", tiling).unwrap();
                    for chunks in [1, 3] {
                        let got = streamed.estimate(&lookups, knn, chunks, &|_| {}).unwrap();
                        let bits = |v: &Vec<Vec<Vec3>>| -> Vec<u32> {
                            v.iter().flatten().flat_map(|e| e.to_array().map(f32::to_bits)).collect()
                        };
                        assert_eq!(
                            bits(&got),
                            bits(&expected),
                            "n {n}, k {k}, {count} tiles, {chunks} chunks"
                        );
                    }
                    // Every tile as a job of its own, the candidates put together.
                    let flat: Vec<Lookup> = lookups.iter().flatten().copied().collect();
                    let mut rows = Vec::new();
                    for t in (0..count).rev() {
                        let c = streamed.candidates(&flat, knn, t).unwrap();
                        for ((&lookup, &photon), &dist2) in c.lookup.iter().zip(&c.photon).zip(&c.dist2) {
                            let p = photon as usize;
                            let normal = Some(m.normal[p]);
                            rows.push(CandidateRow { lookup, photon, dist2, flux: m.flux[p], normal });
                        }
                    }
                    let from_jobs = estimate_from_candidates(&flat, rows, knn);
                    let flat_bits: Vec<u32> =
                        from_jobs.iter().flat_map(|e| e.to_array().map(f32::to_bits)).collect();
                    let whole_bits: Vec<u32> =
                        expected.iter().flatten().flat_map(|e| e.to_array().map(f32::to_bits)).collect();
                    assert_eq!(flat_bits, whole_bits, "n {n}, k {k}, {count} tile jobs");
                }
            }
        }
    }

    #[test]
    fn a_map_with_a_non_finite_photon_is_refused_with_its_index() {
        let mut m = map(100);
        m.flux[42][1] = f32::NAN;
        let info = m.info("test", 1, "2026-01-01T00:00:00Z");
        let table = PhotonTable::from_columns("square", info, &m.columns()).unwrap();
        let view = table.view();
        let streamed = StreamedMap::new(&view, "square", Tiling::new(&m.position, [2, 1])).unwrap();
        let knn = Knn { k: 15, kernel: Kernel::Epanechnikov, max_radius: None };
        let e = streamed.estimate(&lookups(), knn, 1, &|_| {}).unwrap_err();
        assert!(matches!(e, RenderError::NonFinite { index: 42, .. }), "{e}");
        m.position[7][0] = f32::INFINITY;
        let info = m.info("test", 1, "2026-01-01T00:00:00Z");
        let table = PhotonTable::from_columns("square", info, &m.columns()).unwrap();
        let view = table.view();
        let e = StreamedMap::new(&view, "square", Tiling::new(&m.position, [2, 1])).err().unwrap();
        assert!(matches!(e, RenderError::NonFinite { index: 7, .. }), "{e}");
    }

    #[test]
    fn the_plan_holds_the_map_whole_when_it_fits_and_streams_it_the_fewest_times() {
        let d = Demand {
            photons: 10_000_000,
            lookups: 1_200_000,
            k: 15,
            image_bytes: 40 << 20,
            baseline: 30 << 20,
        };
        let whole = d.baseline + (WHOLE_PER_PHOTON * 1e7) as u64 + d.image_bytes;
        assert!(whole_fits(&d, whole) && !whole_fits(&d, whole - 1));
        // Within a plan's budget: the phases' peaks as the plan counts them.
        let peak = |p: Plan| {
            let l = d.lookups as u64;
            let chunk = d.lookups.div_ceil(p.chunks) as u64 * (lookup_bytes(d.k) + 24);
            let tile = MEMORY.per_working_photon * MEMORY.halo_growth * d.photons.div_ceil(p.tiles) as f64;
            let estimate = d.baseline + 60 * l + chunk + (MEMORY.per_photon * d.photons as f64 + tile) as u64;
            estimate.max(d.baseline + 12 * l + d.image_bytes).max(d.baseline + 64 * l)
        };
        for budget in [800u64 << 20, 600 << 20, 400 << 20, 300 << 20] {
            let p = plan(&d, budget).unwrap();
            assert!(peak(p) <= budget, "{p:?} at {budget}: {}", peak(p));
            assert!(p.tiles <= MAX_TILES_PER_PASS, "{p:?} at {budget}");
            if p.chunks > 1 {
                // Half the chunks would need more tiles than a pass should read, or not fit.
                let fewer = p.chunks / 2;
                let held = d.baseline
                    + 60 * d.lookups as u64
                    + d.lookups.div_ceil(fewer) as u64 * (lookup_bytes(d.k) + 24);
                let t = crate::tiles::tiles_for_budget(d.photons, budget.saturating_sub(held), &MEMORY);
                assert!(t.is_err() || t.unwrap() > MAX_TILES_PER_PASS, "{p:?} at {budget}");
            }
        }
        let needed = plan(&d, 100 << 20).unwrap_err();
        assert!(needed > 100 << 20, "{needed}");
        assert!(
            plan(&d, needed + (needed >> 4)).is_ok(),
            "the size named suffices (give or take the chunking)"
        );
    }

    #[test]
    fn merging_keeps_the_k_first_by_distance_then_index() {
        let c = |dist2: f32, index: u32| Candidate { dist2, index, flux: [index as f32; 3] };
        let a = [c(1.0, 5), c(2.0, 1), c(2.0, 9)];
        let b = [c(0.5, 3), c(2.0, 4), c(3.0, 0)];
        let mut out = Vec::new();
        merge_best(&a, b.into_iter(), 4, &mut out);
        let got: Vec<(f32, u32)> = out.iter().map(|c| (c.dist2, c.index)).collect();
        assert_eq!(got, [(0.5, 3), (1.0, 5), (2.0, 1), (2.0, 4)]);
        merge_best(&[], b.into_iter(), 5, &mut out);
        assert_eq!(out.len(), 3);
    }
}
