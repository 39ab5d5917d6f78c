//! A compact kd-tree over `W` distance dimensions and `P` range-constrained dimensions.
//!
//! Records are stored in leaf order (one contiguous slice per leaf); the internal nodes are
//! in depth-first order, each holding only its split axis, split value and the index of its
//! right child (the left child follows it). Every node splits its points along the axis of
//! widest *weighted* extent: cycling axes would waste a level in three on photons that lie on
//! a plane, and the weights let world-space metres and parameter-space units compete fairly
//! (see [`Weights`]). The split lies at the median rounded to whole leaves, so every leaf but
//! the last is full ([`left_size`]).
//!
//! A query finds the k records nearest the query in the `W` distance dimensions among those
//! within a Euclidean ball in the `P` dimensions, with the ball test inside the traversal: a
//! subtree is skipped when either its distance lower bound exceeds the current k-th best or
//! its ball lower bound exceeds the radius. On constrained trees each node's bounding box
//! gives a second pair of bounds (positions and parameters are correlated, so a subtree can
//! lie wholly outside the ball though no split on the path says so). Lower bounds are sums of
//! per-axis squared offsets in the same order as the distances themselves, so in floating
//! point a bound never exceeds the distance of any record below it and the search is exact,
//! ties included.
//!
//! A search may also start with an upper bound on its k-th distance, taken from k of its
//! candidates that the previous result of the same buffer holds (see `KdTree::seed`).
//!
//! Neighbours rank by (distance², index), so records that coincide are told apart by index:
//! the build orders ties by index, every node keeps its smallest index, and a subtree whose
//! lower bound ties the k-th best is skipped when its smallest index ranks after it. A crowd
//! of coincident photons then costs a search a few leaves, not the crowd (issue 31).
//!
//! Stages query every photon in leaf order, so successive queries come from one leaf. The
//! first query of a leaf is searched; then the buffer gathers, in one traversal, the leaves
//! that may hold a record within the first query's k-th distance (plus a margin) of the
//! leaf's box and within a slightly larger ball of the leaf's parameter box ([`Group`]). The
//! leaf's other queries scan those leaves instead of descending the tree: each leaf's box is
//! tested first, then its records four at a time from a block that holds them by axis; a
//! query that finds fewer than k within the gathered reach is searched. Results are exact
//! either way.

use super::{Neighbour, Neighbours};

use std::sync::atomic::Ordering;

use glam::Vec4;
use rayon::prelude::*;

/// Records per leaf (every leaf but the last holds exactly this many); measured by
/// benches/stages.rs; see BENCHMARKS.md.
pub(crate) const LEAF: usize = 16;

/// Blocks of four records a leaf's scan reads (the last may be partly empty).
const BLOCKS: usize = LEAF.div_ceil(4);

/// Record lanes per leaf in [`KdTree::axes`].
const SLOTS: usize = 4 * BLOCKS;

/// Subtrees larger than this are built in parallel.
const PARALLEL_BUILD: usize = 1 << 14;

/// One point: its distance coordinates, its ball coordinates and its index in the caller's set.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(crate) struct Rec<const W: usize, const P: usize> {
    pub w: [f32; W],
    pub p: [f32; P],
    pub idx: u32,
}

impl<const W: usize, const P: usize> Rec<W, P> {
    #[inline(always)]
    fn coord(&self, axis: usize) -> f32 {
        if axis < W { self.w[axis] } else { self.p[axis - W] }
    }
}

/// An internal node: its split, its right child, and the bounding box of all its records
/// (distance and ball dimensions), which prunes far better than the split planes alone when
/// the records are correlated across dimensions, as photon positions and parameters are.
#[derive(Clone, Copy, Debug)]
struct Node<const W: usize, const P: usize> {
    split: f32,
    axis: u32,
    right: u32,
    /// The first leaf of the right child's subtree (leaves are numbered in leaf order; the
    /// left child's first leaf is this node's).
    right_leaf: u32,
    /// The smallest record index below the node: neighbours rank by (distance², index), so
    /// a subtree whose lower bound ties the k-th best is pruned by it ([`Search::visit`]).
    min_idx: u32,
    lo_w: [f32; W],
    hi_w: [f32; W],
    lo_p: [f32; P],
    hi_p: [f32; P],
}

impl<const W: usize, const P: usize> Default for Node<W, P> {
    fn default() -> Self {
        Node {
            split: 0.0,
            axis: 0,
            right: 0,
            right_leaf: 0,
            min_idx: 0,
            lo_w: [0.0; W],
            hi_w: [0.0; W],
            lo_p: [0.0; P],
            hi_p: [0.0; P],
        }
    }
}

/// A leaf: its records `lo..hi` and their bounding box.
#[derive(Clone, Copy, Debug)]
struct Leaf<const W: usize, const P: usize> {
    lo: u32,
    hi: u32,
    /// The smallest record index of the leaf.
    min_idx: u32,
    lo_w: [f32; W],
    hi_w: [f32; W],
    lo_p: [f32; P],
    hi_p: [f32; P],
}

/// Squared distance from `q` to the box [lo, hi], summed in axis order: for any point x in the
/// box each axis's offset is at most |x − q| (rounding is monotone), so in floating point the
/// bound never exceeds the distance of a record inside. Each axis's offset is the largest of
/// lo − q, q − hi and 0 (at most one is positive), without branches: whether a query lies
/// inside a box is not predictable.
#[inline(always)]
fn box_dist2<const N: usize>(q: &[f32; N], lo: &[f32; N], hi: &[f32; N]) -> f32 {
    let mut s = 0.0f32;
    for i in 0..N {
        let d = larger(larger(lo[i] - q[i], q[i] - hi[i]), 0.0);
        s += d * d;
    }
    s
}

/// The larger of two numbers that are not NaN (one `maxss`; `f32::max` also handles NaN).
#[inline(always)]
fn larger(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// Per-axis factors applied to extents when choosing a split axis (never to distances).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Weights {
    pub w: f32,
    pub p: f32,
}

/// Squared Euclidean distance, summed in axis order (the order every bound uses too).
#[inline(always)]
pub(crate) fn dist2<const N: usize>(a: &[f32; N], b: &[f32; N]) -> f32 {
    let mut s = 0.0f32;
    for i in 0..N {
        let d = a[i] - b[i];
        s += d * d;
    }
    s
}

#[inline(always)]
fn sum_sq<const N: usize>(o: &[f32; N]) -> f32 {
    let mut s = 0.0f32;
    for &x in o {
        s += x * x;
    }
    s
}

/// The ranking of neighbours, distance² then photon index, as one integer: a distance² is
/// never negative or NaN, and the bits of non-negative floats order as the floats do.
#[inline(always)]
fn rank(dist2: f32, index: u32) -> u64 {
    ((dist2.to_bits() as u64) << 32) | index as u64
}

/// Writes a block's four candidates — distances² `d`, photon indices `ids`, slots `slot`,
/// `slot + 1`, … — to `cands` from `*n` on, each whole, and advances `*n` past those whose bit
/// in `pass` is set and whose index is not `exclude` (see [`KdTree::scan_leaf`]). With SSE2
/// the four are built in registers, each one store; elsewhere one field at a time.
#[inline(always)]
fn write_block(
    d: Vec4,
    ids: [u32; 4],
    slot: u32,
    pass: u32,
    exclude: u32,
    cands: &mut [Cand],
    n: &mut usize,
) {
    #[cfg(target_arch = "x86_64")]
    let (four, keep): ([Cand; 4], u32) = {
        use std::arch::x86_64::*;
        let idv: __m128i = bytemuck::cast(ids);
        // SAFETY: SSE2 is part of every x86-64 target; these only compute on registers.
        let (four, excluded) = unsafe {
            let dv = _mm_castps_si128(d.into());
            let sv = _mm_add_epi32(_mm_set1_epi32(slot as i32), _mm_setr_epi32(0, 1, 2, 3));
            let zero = _mm_setzero_si128();
            // (index, distance² bits) pairs are the little-endian u64 ranks of `rank`.
            let (klo, khi) = (_mm_unpacklo_epi32(idv, dv), _mm_unpackhi_epi32(idv, dv));
            let (slo, shi) = (_mm_unpacklo_epi32(sv, zero), _mm_unpackhi_epi32(sv, zero));
            let four = [
                _mm_unpacklo_epi64(klo, slo),
                _mm_unpackhi_epi64(klo, slo),
                _mm_unpacklo_epi64(khi, shi),
                _mm_unpackhi_epi64(khi, shi),
            ];
            (four, _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(idv, _mm_set1_epi32(exclude as i32)))))
        };
        (four.map(bytemuck::cast), pass & !(excluded as u32))
    };
    #[cfg(not(target_arch = "x86_64"))]
    let (four, keep): ([Cand; 4], u32) = {
        let d = d.to_array();
        let excluded = (0..4).fold(0, |m, j| m | ((ids[j] == exclude) as u32) << j);
        (std::array::from_fn(|j| Cand::new(rank(d[j], ids[j]), slot + j as u32)), pass & !excluded)
    };
    // One bounds check for the block; `off` never exceeds 3 (the mask tells the compiler).
    let out = cands[*n..].first_chunk_mut::<4>().expect("room for a block past the last candidate");
    let mut off = 0;
    for (j, c) in four.into_iter().enumerate() {
        out[off & 3] = c;
        off += (keep >> j) as usize & 1;
    }
    *n += off;
}

/// A candidate of a search: its rank and its place among the tree's records. Laid out as
/// four 32-bit words (photon index, distance² bits, slot, 0) so that a leaf's scan builds it
/// in one vector register ([`KdTree::scan_leaf`]).
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub(crate) struct Cand {
    key: u64,
    slot: u32,
    pad: u32,
}

impl Cand {
    fn new(key: u64, slot: u32) -> Self {
        Cand { key, slot, pad: 0 }
    }

    fn dist2(&self) -> f32 {
        f32::from_bits((self.key >> 32) as u32)
    }
}

/// Records in the left subtree of a node over `m` > [`LEAF`] records: half the subtree's
/// leaves (rounded up), each full, so that every leaf but the tree's last holds exactly
/// `LEAF` records whatever the photon count (halving `m` would fill leaves anywhere from half
/// to wholly, as the count falls between powers of two).
#[inline(always)]
fn left_size(m: usize) -> usize {
    LEAF * m.div_ceil(LEAF).div_ceil(2)
}

/// Internal nodes of a subtree of `m` records: one fewer than its leaves.
fn count_nodes(m: usize) -> usize {
    m.div_ceil(LEAF).saturating_sub(1)
}

#[derive(Clone, Debug, Default)]
pub(crate) struct KdTree<const W: usize, const P: usize> {
    recs: Vec<Rec<W, P>>,
    nodes: Vec<Node<W, P>>,
    /// The leaves in leaf order, with their boxes.
    leaves: Vec<Leaf<W, P>>,
    /// Each leaf's records again, by axis: `W + P` entries per leaf (distance axes, then
    /// ball axes), each holding that coordinate of the leaf's records in [`SLOTS`] lanes,
    /// NaN past the leaf's records, so that a scan reads four records at a time from memory
    /// that is contiguous per leaf, in fixed-size arrays the compiler sees the bounds of.
    axes: Vec<[Vec4; BLOCKS]>,
    /// Each leaf's records' indices, in the lanes of [`Self::axes`].
    ids: Vec<[u32; SLOTS]>,
    /// Which build this is: unique across every tree and rebuild of the process, so that a
    /// result buffer never takes a bound or a group from another tree or an older build.
    build: u64,
    /// Whether the distance coordinates moved since the build ([`Self::refit`]): the split
    /// planes of distance axes then no longer separate the records, and searches prune by
    /// the (refitted) boxes alone on those axes.
    refitted: bool,
}

/// The source of [`KdTree::build`] numbers (0 is never a build).
static BUILDS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl<const W: usize, const P: usize> KdTree<W, P> {
    /// Builds over `recs`, reusing this tree's allocations.
    pub fn rebuild(&mut self, fill: impl FnOnce(&mut Vec<Rec<W, P>>), weights: Option<Weights>) {
        const { assert!(W + P > 0, "a tree has at least one axis") };
        self.build = BUILDS.fetch_add(1, Ordering::Relaxed);
        self.refitted = false;
        self.recs.clear();
        fill(&mut self.recs);
        let n = self.recs.len();
        self.nodes.clear();
        self.nodes.resize(count_nodes(n), Node::default());
        if n > LEAF {
            let weights = weights.unwrap_or_else(|| default_weights(&self.recs));
            let per_axis: Vec<f32> = (0..W + P).map(|a| if a < W { weights.w } else { weights.p }).collect();
            build_node(&mut self.recs, &mut self.nodes, 0, 0, &per_axis);
        }
        // The leaves and the records by axis, which groups scan (module docs).
        self.leaves.clear();
        leaf_ranges(0, n, &mut self.leaves);
        self.axes.clear();
        self.axes.resize(self.leaves.len() * (W + P), [Vec4::NAN; BLOCKS]);
        self.ids.clear();
        self.ids.resize(self.leaves.len(), [u32::MAX; SLOTS]);
        let recs = &self.recs;
        self.leaves
            .par_iter_mut()
            .zip(self.axes.par_chunks_mut(W + P))
            .zip(self.ids.par_iter_mut())
            .for_each(|((l, axes), ids)| {
                let leaf = &recs[l.lo as usize..l.hi as usize];
                fit_leaf(l, leaf, axes);
                for (id, r) in ids.iter_mut().zip(leaf) {
                    *id = r.idx;
                }
                l.min_idx = leaf.iter().map(|r| r.idx).min().unwrap_or(u32::MAX);
            });
        if !self.nodes.is_empty() {
            min_index_node(&mut self.nodes, &self.leaves, 0, 0, n, 0);
        }
    }

    /// Moves every record to new distance coordinates, `w_of(index)`, keeping its ball
    /// coordinates and its place: the leaves keep their records, and every leaf and node box
    /// is recomputed (a node's from its children's). Much cheaper than a rebuild, and exact
    /// all the same, since searches then prune distance axes by boxes only; but as records
    /// drift the boxes overlap more and queries slow down, so callers rebuild now and then.
    pub fn refit(&mut self, w_of: impl Fn(u32) -> [f32; W] + Sync) {
        self.build = BUILDS.fetch_add(1, Ordering::Relaxed);
        self.refitted = true;
        self.recs.par_iter_mut().for_each(|r| r.w = w_of(r.idx));
        let recs = &self.recs;
        self.leaves
            .par_iter_mut()
            .zip(self.axes.par_chunks_mut(W + P))
            .for_each(|(l, axes)| fit_leaf(l, &recs[l.lo as usize..l.hi as usize], axes));
        if !self.nodes.is_empty() {
            refit_node(&mut self.nodes, &self.leaves, 0, 0, self.recs.len(), 0);
        }
    }

    /// The records' indices in leaf order.
    pub fn order(&self) -> impl Iterator<Item = u32> + '_ {
        self.recs.iter().map(|r| r.idx)
    }

    /// The `k` records nearest `qw` with `|p − qp|² ≤ r2` (`r2 = None`: no ball), skipping
    /// the record whose index is `exclude`; sorted by (distance², index) into `out`, with
    /// their coordinates and places. `out`'s previous result, if it came from this tree,
    /// gives the search its starting bound ([`super::SpatialIndex::knn`]).
    pub fn knn(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: Option<f32>,
        exclude: Option<u32>,
        k: usize,
        out: &mut Neighbours,
    ) {
        let id = self.build;
        let r2v = r2.unwrap_or(f32::INFINITY);
        let ball = r2.is_some() && P > 0;
        let exclude = exclude.unwrap_or(u32::MAX);
        // A NaN radius admits nothing; so does a negative one (no distance is below it).
        if k == 0 || self.recs.is_empty() || (ball && (r2v.is_nan() || r2v < 0.0)) {
            out.clear();
            return;
        }
        let grouped = !self.nodes.is_empty();
        // Whether the group was gathered for this query, at an estimated reach, in vain.
        let mut estimated = false;
        if grouped {
            let mut serves = out.group.serves(id, k, qw, qp, r2v, ball);
            // A new leaf: gather its group at the reach of the previous result (a query
            // nearby, in leaf order), and answer this query from it too when it can.
            if !serves
                && out.tree == id
                && out.len() == k
                && let Some(kth) = out.max_dist2()
            {
                self.gather(qw, qp, r2v, ball, k, kth, out);
                serves = out.group.serves(id, k, qw, qp, r2v, ball);
                estimated = true;
            }
            if serves && self.answer_from_group(qw, qp, r2v, exclude, k, out) {
                out.group_answers += 1;
                return;
            }
        }
        self.search(qw, qp, r2v, ball, exclude, k, out);
        if grouped
            && (estimated || !out.group.serves(id, k, qw, qp, r2v, ball))
            && out.len() == k
            && let Some(kth) = out.max_dist2()
        {
            self.gather(qw, qp, r2v, ball, k, kth, out);
        }
    }

    /// The search of [`Self::knn`] through the tree.
    #[allow(clippy::too_many_arguments)]
    fn search(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2v: f32,
        ball: bool,
        exclude: u32,
        k: usize,
        out: &mut Neighbours,
    ) {
        let id = self.build;
        let (mut bound, mut worst) = (f32::INFINITY, u64::MAX);
        if out.tree == id
            && !out.slots.is_empty()
            && let Some(d) = self.seed(qw, qp, r2v, ball, exclude, k, &out.slots, &mut out.cands)
        {
            // Every record ranked at most (d, any index) can still be among the k.
            bound = d;
            worst = rank(d, u32::MAX);
        }
        out.cands.clear();
        let mut s = Search {
            tree: self,
            qw,
            qp,
            r2: r2v,
            ball,
            exclude,
            k,
            heap: &mut out.cands,
            worst,
            bound,
            // Boxes pay for themselves on constrained trees, where they bound the parameter
            // ball; on unconstrained ones the split planes prune about as well for less work.
            boxes: P > 0 || self.refitted,
            scanned: 0,
        };
        let (mut ow, mut op) = ([0.0f32; W], [0.0f32; P]);
        s.visit(0, 0, self.recs.len(), 0, &mut ow, &mut op);
        if s.heap.len() < k && s.worst != u64::MAX {
            // Unreachable in exact arithmetic (the bound has k candidates within it); kept so
            // that a wrong bound could only cost time, never change a result.
            s.heap.clear();
            (s.worst, s.bound) = (u64::MAX, f32::INFINITY);
            let (mut ow, mut op) = ([0.0f32; W], [0.0f32; P]);
            s.visit(0, 0, self.recs.len(), 0, &mut ow, &mut op);
        }
        s.finish(out.ordered);
        out.records_scanned += s.scanned;
        out.tree = id;
        let items = (!out.farthest_only).then_some(&mut out.items);
        let coords = out.with_coords.then_some(&mut out.coords);
        self.emit(&out.cands, items, coords, &mut out.slots);
        out.far2 = farthest(&out.cands);
        out.found = out.cands.len();
    }

    /// Writes the candidates `cands` as a result (the caller sets its largest distance², which
    /// the selection already knows): the neighbours unless `items` is `None` (a buffer made
    /// `farthest_only`, whose list stays empty), their coordinates unless `coords` is, and
    /// their slots. Each list is filled in one pass over a slice of known length (no capacity
    /// check per item); a candidate's photon index is the low half of its rank.
    fn emit(
        &self,
        cands: &[Cand],
        items: Option<&mut Vec<Neighbour>>,
        coords: Option<&mut Vec<[f32; 3]>>,
        slots: &mut Vec<u32>,
    ) {
        if let Some(items) = items {
            items.clear();
            items.extend(cands.iter().map(|c| Neighbour { dist2: c.dist2(), index: c.key as u32 }));
        }
        if let Some(coords) = coords {
            coords.clear();
            coords.extend(cands.iter().map(|c| {
                let r = &self.recs[c.slot as usize];
                std::array::from_fn(|a| if a < W { r.w[a] } else { 0.0 })
            }));
        }
        slots.clear();
        slots.extend(cands.iter().map(|c| c.slot));
    }

    /// An upper bound on the k-th distance² of a query: the k-th among the records at `slots`
    /// that are its candidates, or `None` when fewer than k of them are. Distances and the
    /// ball test are computed exactly as the search computes them, so the bound is exact.
    #[allow(clippy::too_many_arguments)]
    fn seed(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: f32,
        ball: bool,
        exclude: u32,
        k: usize,
        slots: &[u32],
        scratch: &mut Vec<Cand>,
    ) -> Option<f32> {
        if slots.len() < k {
            return None;
        }
        scratch.clear();
        let mut max = 0.0f32;
        for &slot in slots {
            let Some(r) = self.recs.get(slot as usize) else { continue };
            if r.idx == exclude || (ball && dist2(&r.p, qp) > r2) {
                continue;
            }
            let d = dist2(&r.w, qw);
            max = max.max(d);
            scratch.push(Cand::new(rank(d, r.idx), slot));
        }
        match scratch.len().cmp(&k) {
            std::cmp::Ordering::Less => None,
            std::cmp::Ordering::Equal => Some(max),
            std::cmp::Ordering::Greater => {
                let (_, kth, _) = scratch.select_nth_unstable_by_key(k - 1, |c| c.key);
                Some(kth.dist2())
            }
        }
    }
}

/// Candidates gathered once for the queries of one leaf (module docs): the leaves that hold
/// every record within distance² `g2` of the box `lo_w..hi_w` and, on a constrained search,
/// within ball distance² `r2` of the box `lo_p..hi_p`. A query inside both boxes, with a ball no larger
/// and the same k, finds among them every record within `g2` of itself that its ball admits
/// (each axis's offset to a box that holds the query is at most its offset to the query, and
/// rounding keeps that order): when at least k are, its k nearest are exact.
/// Axes of a [`Group`]'s boxes: the most of either kind a tree has ([`super::MAX_PARAM_DIMS`]).
const GROUP_AXES: usize = super::MAX_PARAM_DIMS;

#[derive(Clone, Debug, Default)]
pub(crate) struct Group {
    /// The tree build the candidates came from (0: none).
    build: u64,
    k: usize,
    ball: bool,
    // Sized for the widest tree: 4 distance axes (parameters alone), 4 ball axes.
    lo_w: [f32; GROUP_AXES],
    hi_w: [f32; GROUP_AXES],
    lo_p: [f32; GROUP_AXES],
    hi_p: [f32; GROUP_AXES],
    g2: f32,
    r2: f32,
    /// The leaves that may hold candidates (their records are scanned from the tree).
    leaves: Vec<u32>,
    /// Their boxes, four leaves at a time and by axis: per four leaves, the low then high
    /// corner of each distance axis, then of each ball axis (lanes past the last leaf empty:
    /// low +∞, high −∞), so a query tests four leaf boxes at once.
    boxes: Vec<Vec4>,
}

impl Group {
    /// Drops the candidates (keeping the allocations).
    pub(crate) fn forget(&mut self) {
        self.build = 0;
    }

    /// Whether a query may be answered from these candidates.
    #[inline]
    fn serves<const W: usize, const P: usize>(
        &self,
        build: u64,
        k: usize,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: f32,
        ball: bool,
    ) -> bool {
        self.build == build
            && self.k == k
            && self.ball == ball
            && (0..W).all(|a| qw[a] >= self.lo_w[a] && qw[a] <= self.hi_w[a])
            && (!ball || (r2 <= self.r2 && (0..P).all(|a| qp[a] >= self.lo_p[a] && qp[a] <= self.hi_p[a])))
    }
}

/// Squared distance between two boxes, summed in axis order: at most [`box_dist2`] of any
/// point of the first box to the second (the same monotone-rounding argument).
#[inline(always)]
fn box_box_dist2<const N: usize>(lo: &[f32; N], hi: &[f32; N], glo: &[f32], ghi: &[f32]) -> f32 {
    let mut s = 0.0f32;
    for i in 0..N {
        let d = larger(larger(glo[i] - hi[i], lo[i] - ghi[i]), 0.0);
        s += d * d;
    }
    s
}

impl<const W: usize, const P: usize> KdTree<W, P> {
    /// Gathers the candidates of the leaf that holds the query, whose k nearest `out` holds,
    /// into `out`'s group: within the query's k-th distance plus [`GROUP_SLACK`] of the
    /// diagonal of the leaf's box, and within 1.2 times the query's ball radius
    /// ([`BALL_SLACK`]) of the leaf's parameter box. (On an unconstrained search another query
    /// of the leaf has its k-th within the first's plus their distance, at most the diagonal.)
    /// A query outside the group's reach is searched as before: the reach changes speed, never
    /// results.
    #[allow(clippy::too_many_arguments)]
    fn gather(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: f32,
        ball: bool,
        k: usize,
        kth: f32,
        out: &mut Neighbours,
    ) {
        // The leaf the query descends to (its box and the query's make the group's boxes),
        // and the internal nodes on the way, to start the gathering at the deepest whose box
        // holds the whole reach (no record outside a node's subtree lies in its box).
        let mut path = [(0u32, 0u32, 0u32, 0u32); 64];
        let mut depth = 0;
        let (mut node, mut lo, mut hi, mut leaf) = (0usize, 0usize, self.recs.len(), 0u32);
        while hi - lo > LEAF {
            path[depth] = (node as u32, lo as u32, hi as u32, leaf);
            depth += 1;
            let n = &self.nodes[node];
            let axis = n.axis as usize;
            let q = if axis < W { qw[axis] } else { qp[axis - W] };
            let mid = lo + left_size(hi - lo);
            if q - n.split < 0.0 {
                (node, hi) = (node + 1, mid);
            } else {
                (node, lo, leaf) = (n.right as usize, mid, n.right_leaf);
            }
        }
        let g = &mut out.group;
        let l = self.leaves[leaf as usize];
        g.lo_w = [0.0; GROUP_AXES];
        g.hi_w = [0.0; GROUP_AXES];
        g.lo_p = [0.0; GROUP_AXES];
        g.hi_p = [0.0; GROUP_AXES];
        for (a, &q) in qw.iter().enumerate() {
            (g.lo_w[a], g.hi_w[a]) = (l.lo_w[a].min(q), l.hi_w[a].max(q));
        }
        for (a, &q) in qp.iter().enumerate() {
            (g.lo_p[a], g.hi_p[a]) = (l.lo_p[a].min(q), l.hi_p[a].max(q));
        }
        let diag2: f32 = (0..W).map(|a| (g.hi_w[a] - g.lo_w[a]).powi(2)).sum();
        let reach = kth.sqrt() + GROUP_SLACK * diag2.sqrt();
        g.g2 = reach * reach * 1.000_01;
        g.r2 = if ball { r2 * BALL_SLACK } else { f32::INFINITY };
        if !(g.g2.is_finite() && g.r2 >= r2) {
            g.build = 0;
            return;
        }
        g.build = self.build;
        g.k = k;
        g.ball = ball;
        g.leaves.clear();
        // Where a record within reach can lie, with a margin for the rounding of distances.
        let (gw, gp) = (g.g2.sqrt() * 1.001, if ball { g.r2.sqrt() * 1.001 } else { f32::INFINITY });
        let holds = |n: &Node<W, P>| {
            (0..W).all(|a| n.lo_w[a] < g.lo_w[a] - gw && g.hi_w[a] + gw < n.hi_w[a])
                && (P == 0
                    || (ball && (0..P).all(|a| n.lo_p[a] < g.lo_p[a] - gp && g.hi_p[a] + gp < n.hi_p[a])))
        };
        // After a refit, sibling boxes overlap and a box may hold another subtree's records:
        // gather from the root.
        let start = if self.refitted {
            0
        } else {
            (0..depth).rev().find(|&d| holds(&self.nodes[path[d].0 as usize])).unwrap_or(0)
        };
        let (node, lo, hi, leaf) = if depth == 0 {
            (0, 0, self.recs.len(), 0)
        } else {
            let (node, lo, hi, leaf) = path[start];
            (node as usize, lo as usize, hi as usize, leaf)
        };
        // A crowd (many records within the reach, as when photons coincide) would make every
        // query of the leaf scan all of it: the group is then left empty, so that the leaf's
        // queries search the tree instead, where a crowd costs a few leaves.
        let cap = GROUP_CAP * (k.div_ceil(LEAF) + 16);
        if !self.collect(node, lo, hi, leaf, g, cap) {
            g.leaves.clear();
        }
        // Empty lanes first (low +∞, high −∞), then each leaf's box in its lane.
        let per = 2 * (W + P);
        g.boxes.clear();
        g.boxes.extend(
            (0..g.leaves.len().div_ceil(4) * per)
                .map(|i| if i % 2 == 0 { Vec4::INFINITY } else { Vec4::NEG_INFINITY }),
        );
        for (j, &l) in g.leaves.iter().enumerate() {
            let leaf = &self.leaves[l as usize];
            let b = &mut g.boxes[j / 4 * per..][..per];
            let lane = j % 4;
            for a in 0..W {
                b[2 * a][lane] = leaf.lo_w[a];
                b[2 * a + 1][lane] = leaf.hi_w[a];
            }
            for a in 0..P {
                b[2 * (W + a)][lane] = leaf.lo_p[a];
                b[2 * (W + a) + 1][lane] = leaf.hi_p[a];
            }
        }
    }

    /// Appends to `g` every leaf below `node` (whose first leaf is `leaf`) that may hold a
    /// record within its reach; false (and the leaves so far) as soon as there are more than
    /// `cap`.
    fn collect(&self, node: usize, lo: usize, hi: usize, leaf: u32, g: &mut Group, cap: usize) -> bool {
        // A leaf under a node within reach is taken whole: its box is tested by each query
        // that scans the group instead.
        if hi - lo <= LEAF {
            g.leaves.push(leaf);
            return g.leaves.len() <= cap;
        }
        let n = &self.nodes[node];
        if box_box_dist2(&n.lo_w, &n.hi_w, &g.lo_w, &g.hi_w) > g.g2
            || (g.ball && box_box_dist2(&n.lo_p, &n.hi_p, &g.lo_p, &g.hi_p) > g.r2)
        {
            return true;
        }
        let mid = lo + left_size(hi - lo);
        self.collect(node + 1, lo, mid, leaf, g, cap)
            && self.collect(n.right as usize, mid, hi, n.right_leaf, g, cap)
    }

    /// Writes to `cands[..n]`, returning n, the group's candidates within distance² `reach`
    /// of `qw` that the ball of radius² `r2` about `qp` admits, except `exclude`: leaf by
    /// leaf, skipping a leaf whose box lies beyond either (its box distance is at most any
    /// record's), four records at a time, distances summed in axis order as [`dist2`] sums
    /// them. `cands` is scratch, lengthened when it must be to hold every record of the group
    /// and never shortened (its entries past n are left as they are), so that it is not
    /// written twice.
    #[allow(clippy::too_many_arguments)]
    fn scan_group(
        &self,
        g: &Group,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: f32,
        exclude: u32,
        reach: f32,
        cands: &mut Vec<Cand>,
        scanned: &mut u64,
    ) -> usize {
        // Room for every record of the group, and four past the last (a block is written
        // whole).
        let room = g.leaves.len() * SLOTS + 4;
        if cands.len() < room {
            cands.resize(room, Cand::default());
        }
        let mut n = 0;
        let qwv: [Vec4; W] = std::array::from_fn(|a| Vec4::splat(qw[a]));
        let qpv: [Vec4; P] = std::array::from_fn(|a| Vec4::splat(qp[a]));
        let (reachv, r2v) = (Vec4::splat(reach), Vec4::splat(r2));
        // Four leaf boxes at a time: the lanes compute what [`box_dist2`] computes for each.
        let box_dist2v = |q: &[Vec4], b: &[Vec4]| {
            let mut s = Vec4::ZERO;
            for (a, q) in q.iter().enumerate() {
                let d = (b[2 * a] - *q).max(*q - b[2 * a + 1]).max(Vec4::ZERO);
                s += d * d;
            }
            s
        };
        for (four, b) in g.leaves.chunks(4).zip(g.boxes.chunks_exact(2 * (W + P))) {
            let mut pass = box_dist2v(&qwv, &b[..2 * W]).cmple(reachv).bitmask();
            if g.ball {
                pass &= box_dist2v(&qpv, &b[2 * W..]).cmple(r2v).bitmask();
            }
            while pass != 0 {
                let j = pass.trailing_zeros() as usize;
                pass &= pass - 1;
                if let Some(&leaf) = four.get(j) {
                    let l = &self.leaves[leaf as usize];
                    *scanned += (l.hi - l.lo) as u64;
                    self.scan_leaf(leaf, &qwv, &qpv, g.ball, reachv, r2v, exclude, cands, &mut n);
                }
            }
        }
        n
    }

    /// The records of leaf `leaf` within distance² `reachv` (splatted) of `qwv` that the
    /// ball `r2v` about `qpv` admits (when `ball`), except `exclude`, into `cands` from
    /// `*n` on. Each block's four records are written whether they pass or not, and `*n`
    /// advanced past those that do: which records of a block pass is not predictable, and
    /// a branch per record (or per block) costs more in mispredictions than the writes.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn scan_leaf(
        &self,
        leaf: u32,
        qwv: &[Vec4; W],
        qpv: &[Vec4; P],
        ball: bool,
        reachv: Vec4,
        r2v: Vec4,
        exclude: u32,
        cands: &mut [Cand],
        n: &mut usize,
    ) {
        let l = &self.leaves[leaf as usize];
        let leaf = leaf as usize;
        let axes = &self.axes[leaf * (W + P)..][..W + P];
        let ids = &self.ids[leaf];
        // Every block, also past the last leaf's records (whose lanes are NaN and never
        // pass): a loop of fixed length, without a test per block.
        for b in 0..BLOCKS {
            let mut d = Vec4::ZERO;
            for (a, q) in qwv.iter().enumerate() {
                let o = axes[a][b] - *q;
                d += o * o;
            }
            // Past the leaf's records the coordinates are NaN, which never pass.
            let mut pass = d.cmple(reachv).bitmask();
            if ball {
                let mut e = Vec4::ZERO;
                for (a, q) in qpv.iter().enumerate() {
                    let o = axes[W + a][b] - *q;
                    e += o * o;
                }
                pass &= e.cmple(r2v).bitmask();
            }
            let block: [u32; 4] = std::array::from_fn(|j| ids[4 * b + j]);
            write_block(d, block, l.lo + 4 * b as u32, pass, exclude, cands, n);
        }
    }

    /// Answers a query its group serves from the group's candidates that its ball admits:
    /// the k nearest among those within a guessed reach (1 + 1.24/√k times the previous
    /// result's k-th distance²), or within the group's reach when fewer than k lie in the
    /// guess. Either reach is at most the group's, so every record within it is a candidate
    /// and the k found are exact. Returns false when fewer than k lie within the group's
    /// reach (the caller then searches).
    fn answer_from_group(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: f32,
        exclude: u32,
        k: usize,
        out: &mut Neighbours,
    ) -> bool {
        // First within a tighter reach guessed from the previous result (a nearby query of
        // the same tree), which leaves fewer candidates to select from; if fewer than k lie
        // within it, again within the group's whole reach.
        let guess = if out.tree == self.build && out.len() == k {
            // Neighbouring queries' k-th distances differ by a relative amount that shrinks
            // like 1/√k (measured by benches/stages.rs; see BENCHMARKS.md).
            let factor = 1.0 + 1.24 / (k as f32).sqrt();
            out.max_dist2().map_or(f32::INFINITY, |d| d * factor)
        } else {
            f32::INFINITY
        };
        let g = &out.group;
        let mut n = 0;
        let mut scanned_reach = g.g2;
        for reach in [guess, g.g2] {
            if reach > g.g2 && reach != g.g2 {
                continue;
            }
            n = self.scan_group(g, qw, qp, r2, exclude, reach, &mut out.scanned, &mut out.records_scanned);
            scanned_reach = reach;
            if n >= k {
                break;
            }
        }
        if n < k {
            return false;
        }
        let cands = &mut out.scanned[..n];
        out.tree = self.build;
        out.found = k;
        if out.farthest_only {
            // The k-th's distance² alone; the slots of the last search stay, as k candidates
            // that still bound the next search (`seed`).
            out.far2 = f32::from_bits((kth_rank(cands, k, scanned_reach) >> 32) as u32);
            return true;
        }
        let far2 = nearest_first(cands, k, scanned_reach);
        let cands = &mut cands[..k];
        if out.ordered {
            cands.sort_unstable_by_key(|c| c.key);
        }
        let coords = out.with_coords.then_some(&mut out.coords);
        self.emit(cands, Some(&mut out.items), coords, &mut out.slots);
        out.far2 = far2;
        true
    }
}

/// Buckets of [`nearest_first`]'s histogram.
const BUCKETS: usize = 64;

/// Most candidates [`nearest_first`] sorts into buckets (more go to `select_nth_unstable`).
const BUCKETED: usize = 256;

/// Most candidates of the k-th's bucket [`nearest_first`] selects among (more, as when many
/// photons lie at one distance, go to `select_nth_unstable`).
const EDGE: usize = 32;

/// Moves the `k` candidates of lowest rank to the front of `s` (in any order; what lies behind
/// them is unspecified); every candidate's distance² is at most `reach`. A histogram of the
/// distances² in [`BUCKETS`] equal parts of 0..reach finds the bucket that holds the k-th (a
/// bucket's distances are all below the next one's: scaling and rounding keep the order);
/// the candidates of lower buckets are kept and the few of that bucket selected among by
/// rank. One pass to count and one to keep, without a branch per candidate, where
/// `select_nth_unstable`'s partitions and final insertion sort mispredict about half their
/// comparisons on candidates in no particular order; it still decides where the histogram
/// cannot (see [`by_buckets`]). Returns the largest distance² of the k (the k-th's), which
/// the selection finds on the way.
fn nearest_first(s: &mut [Cand], k: usize, reach: f32) -> f32 {
    if s.len() <= k {
        return farthest(s);
    }
    match by_buckets(s, k, reach) {
        Some(far2) => far2,
        None => s.select_nth_unstable_by_key(k - 1, |c| c.key).1.dist2(),
    }
}

/// The largest distance² among `s` (0 when empty).
fn farthest(s: &[Cand]) -> f32 {
    s.iter().fold(0.0, |m, c| larger(m, c.dist2()))
}

/// The histogram of [`nearest_first`] over `s` (k < `s.len()`): each candidate's bucket, the
/// bucket that holds the k-th and how many lie below it; `None` when it does not apply: too
/// many candidates, a reach of 0 (or not finite), or more than [`EDGE`] in the k-th's bucket
/// (as when many photons lie at one distance).
#[inline(always)]
fn histogram(s: &[Cand], k: usize, reach: f32) -> Option<([u8; BUCKETED], usize, usize)> {
    if s.len() > BUCKETED || !(reach > 0.0 && reach.is_finite()) {
        return None;
    }
    let scale = BUCKETS as f32 / reach;
    let mut bucket = [0u8; BUCKETED];
    let mut count = [0u32; 2 * BUCKETS];
    for (b, c) in bucket.iter_mut().zip(s.iter()) {
        // d² · scale lies in 0..=BUCKETS (just above, by rounding, at d² = reach); adding
        // 2²³ rounds it to an integer in the float's low mantissa bits: rounding is monotone
        // too, and cheaper than a saturating conversion.
        let x = ((c.dist2() * scale + 8_388_608.0).to_bits() & (2 * BUCKETS as u32 - 1)) as usize;
        *b = x as u8;
        count[x] += 1;
    }
    // The bucket of the k-th, and how many lie below it, counted down from the top bucket
    // (d² ≤ reach puts every candidate at most there): the surplus over k is usually small,
    // so that bucket lies a few from the top.
    let (mut edge, mut above) = (BUCKETS, 0);
    while edge > 0 && s.len() - above - count[edge] as usize >= k {
        above += count[edge] as usize;
        edge -= 1;
    }
    let below = s.len() - above - count[edge] as usize;
    (count[edge] as usize <= EDGE && below < k).then_some((bucket, edge, below))
}

/// [`nearest_first`] by the [`histogram`], for k < `s.len()`, returning the k-th's distance²;
/// `None` (and `s` untouched) when the histogram does not apply.
fn by_buckets(s: &mut [Cand], k: usize, reach: f32) -> Option<f32> {
    let (bucket, edge, below) = histogram(s, k, reach)?;
    // Lower buckets to the front (`kept ≤ i`: the write never overtakes the read), the
    // edge bucket aside.
    let mut aside = [Cand::default(); EDGE + 1];
    let (mut kept, mut on_edge) = (0, 0);
    for i in 0..s.len() {
        let (c, b) = (s[i], bucket[i] as usize);
        s[kept] = c;
        kept += (b < edge) as usize;
        aside[on_edge] = c;
        on_edge += (b == edge) as usize;
    }
    let aside = &mut aside[..on_edge];
    let need = k - below;
    // The k-th: the need-th of its bucket (all of them when all are needed).
    let far2 = if need < on_edge {
        aside.select_nth_unstable_by_key(need - 1, |c| c.key).1.dist2()
    } else {
        farthest(aside)
    };
    s[below..k].copy_from_slice(&aside[..need]);
    Some(far2)
}

/// The k-th lowest rank among the candidates `s` (at least k, every distance² at most
/// `reach`), whose order it may change: as [`nearest_first`], but only the k-th's bucket is
/// gathered and selected among.
fn kth_rank(s: &mut [Cand], k: usize, reach: f32) -> u64 {
    if s.len() == k {
        return s.iter().fold(0, |m, c| m.max(c.key));
    }
    if let Some((bucket, edge, below)) = histogram(s, k, reach) {
        let mut aside = [Cand::default(); EDGE + 1];
        let mut on_edge = 0;
        for (&c, &b) in s.iter().zip(&bucket) {
            aside[on_edge] = c;
            on_edge += (b as usize == edge) as usize;
        }
        return aside[..on_edge].select_nth_unstable_by_key(k - below - 1, |c| c.key).1.key;
    }
    s.select_nth_unstable_by_key(k - 1, |c| c.key).1.key
}

/// The margin of a leaf group's reach, as a fraction of the diagonal of the leaf's box
/// ([`KdTree::gather`]); measured by benches/stages.rs; see BENCHMARKS.md.
const GROUP_SLACK: f32 = 0.15;

/// A leaf group's ball radius², as a multiple of the query's (1.2²; [`KdTree::gather`]).
const BALL_SLACK: f32 = 1.44;

/// Most leaves a group holds, per (k / LEAF + 16) ([`KdTree::gather`]).
const GROUP_CAP: usize = 4;

/// Weights that normalise each group of axes by its largest extent, so world space and
/// parameter space shrink at the same relative rate down the tree whatever the scene's scale.
fn default_weights<const W: usize, const P: usize>(recs: &[Rec<W, P>]) -> Weights {
    let (lo, hi) = bounds(recs);
    let ext = |r: std::ops::Range<usize>| r.map(|a| hi[a] - lo[a]).fold(0.0f32, f32::max);
    let inv = |e: f32| if e > 0.0 && e.is_finite() { 1.0 / e } else { 1.0 };
    Weights { w: inv(ext(0..W)), p: inv(ext(W..W + P)) }
}

/// The records' bounding box, axis by axis (distance axes, then ball axes; the first W + P
/// entries are used): called for every node of every build, so without allocation, and with
/// one `minss`/`maxss` per coordinate (the records are finite).
fn bounds<const W: usize, const P: usize>(recs: &[Rec<W, P>]) -> ([f32; AXES], [f32; AXES]) {
    let mut lo = [f32::INFINITY; AXES];
    let mut hi = [f32::NEG_INFINITY; AXES];
    for r in recs {
        for a in 0..W + P {
            let c = r.coord(a);
            lo[a] = if c < lo[a] { c } else { lo[a] };
            hi[a] = larger(c, hi[a]);
        }
    }
    (lo, hi)
}

/// Room for every axis of a tree: three distance axes and at most three ball axes.
const AXES: usize = 3 + super::MAX_PARAM_DIMS;

/// Builds the subtree over `recs`, whose first node is `base` and first leaf `leaf`.
fn build_node<const W: usize, const P: usize>(
    recs: &mut [Rec<W, P>],
    nodes: &mut [Node<W, P>],
    base: usize,
    leaf: usize,
    weights: &[f32],
) {
    let m = recs.len();
    if m <= LEAF {
        return;
    }
    let (lo, hi) = bounds(recs);
    let mut axis = 0;
    let mut best = -1.0f32;
    for a in 0..W + P {
        let e = (hi[a] - lo[a]) * weights[a];
        if e > best {
            best = e;
            axis = a;
        }
    }
    let mid = left_size(m);
    // Records are finite (the index refuses others), so `<` orders them totally but for
    // −0 = +0, which either side of the split may hold. Ties go by index, so records that
    // coincide lie in index order across the leaves and a search finds the k of lowest
    // index among them in a few leaves ([`Search::visit`]).
    recs.select_nth_unstable_by(mid, |a, b| {
        a.coord(axis).partial_cmp(&b.coord(axis)).unwrap_or(std::cmp::Ordering::Equal).then(a.idx.cmp(&b.idx))
    });
    let split = recs[mid].coord(axis);
    let left_nodes = count_nodes(mid);
    let (head, rest) = nodes.split_first_mut().expect("a subtree of more than LEAF records has a node");
    *head = Node {
        split,
        axis: axis as u32,
        right: (base + 1 + left_nodes) as u32,
        // A subtree has one leaf more than it has internal nodes.
        right_leaf: (leaf + left_nodes + 1) as u32,
        min_idx: 0,
        lo_w: std::array::from_fn(|a| lo[a]),
        hi_w: std::array::from_fn(|a| hi[a]),
        lo_p: std::array::from_fn(|a| lo[W + a]),
        hi_p: std::array::from_fn(|a| hi[W + a]),
    };
    let (lrecs, rrecs) = recs.split_at_mut(mid);
    let (lnodes, rnodes) = rest.split_at_mut(left_nodes);
    if m >= PARALLEL_BUILD {
        rayon::join(
            || build_node(lrecs, lnodes, base + 1, leaf, weights),
            || build_node(rrecs, rnodes, base + 1 + left_nodes, leaf + left_nodes + 1, weights),
        );
    } else {
        build_node(lrecs, lnodes, base + 1, leaf, weights);
        build_node(rrecs, rnodes, base + 1 + left_nodes, leaf + left_nodes + 1, weights);
    }
}

/// Sets leaf `l`'s box from its records `recs` and writes their coordinates into the leaf's
/// lanes `axes` (one entry per axis, [`KdTree::axes`]).
fn fit_leaf<const W: usize, const P: usize>(
    l: &mut Leaf<W, P>,
    recs: &[Rec<W, P>],
    axes: &mut [[Vec4; BLOCKS]],
) {
    let (lo, hi) = bounds(recs);
    l.lo_w = std::array::from_fn(|a| lo[a]);
    l.hi_w = std::array::from_fn(|a| hi[a]);
    l.lo_p = std::array::from_fn(|a| lo[W + a]);
    l.hi_p = std::array::from_fn(|a| hi[W + a]);
    for (i, r) in recs.iter().enumerate() {
        for (a, lanes) in axes.iter_mut().enumerate() {
            lanes[i / 4][i % 4] = r.coord(a);
        }
    }
}

/// Recomputes the distance-axis boxes of the subtree at `node` (records `lo..hi`, first
/// leaf `leaf`) from its leaves' boxes, and returns its box.
fn refit_node<const W: usize, const P: usize>(
    nodes: &mut [Node<W, P>],
    leaves: &[Leaf<W, P>],
    node: usize,
    lo: usize,
    hi: usize,
    leaf: usize,
) -> ([f32; W], [f32; W]) {
    if hi - lo <= LEAF {
        let l = &leaves[leaf];
        return (l.lo_w, l.hi_w);
    }
    let (right, right_leaf) = (nodes[node].right as usize, nodes[node].right_leaf as usize);
    let mid = lo + left_size(hi - lo);
    let (alo, ahi) = refit_node(nodes, leaves, node + 1, lo, mid, leaf);
    let (blo, bhi) = refit_node(nodes, leaves, right, mid, hi, right_leaf);
    let n = &mut nodes[node];
    n.lo_w = std::array::from_fn(|a| alo[a].min(blo[a]));
    n.hi_w = std::array::from_fn(|a| ahi[a].max(bhi[a]));
    (n.lo_w, n.hi_w)
}

/// Sets the smallest record index of the subtree at `node` (records `lo..hi`, first leaf
/// `leaf`) and of every node below it, and returns it.
fn min_index_node<const W: usize, const P: usize>(
    nodes: &mut [Node<W, P>],
    leaves: &[Leaf<W, P>],
    node: usize,
    lo: usize,
    hi: usize,
    leaf: usize,
) -> u32 {
    if hi - lo <= LEAF {
        return leaves[leaf].min_idx;
    }
    let (right, right_leaf) = (nodes[node].right as usize, nodes[node].right_leaf as usize);
    let mid = lo + left_size(hi - lo);
    let a = min_index_node(nodes, leaves, node + 1, lo, mid, leaf);
    let b = min_index_node(nodes, leaves, right, mid, hi, right_leaf);
    nodes[node].min_idx = a.min(b);
    a.min(b)
}

/// Appends the leaves of a subtree over records `lo..hi` in leaf order (boxes unset), split
/// as [`build_node`] splits.
fn leaf_ranges<const W: usize, const P: usize>(lo: usize, hi: usize, out: &mut Vec<Leaf<W, P>>) {
    if hi - lo <= LEAF {
        let z = Leaf {
            lo: lo as u32,
            hi: hi as u32,
            min_idx: 0,
            lo_w: [0.0; W],
            hi_w: [0.0; W],
            lo_p: [0.0; P],
            hi_p: [0.0; P],
        };
        out.push(z);
        return;
    }
    let mid = lo + left_size(hi - lo);
    leaf_ranges(lo, mid, out);
    leaf_ranges(mid, hi, out);
}

struct Search<'a, const W: usize, const P: usize> {
    tree: &'a KdTree<W, P>,
    qw: &'a [f32; W],
    qp: &'a [f32; P],
    r2: f32,
    ball: bool,
    exclude: u32,
    k: usize,
    heap: &'a mut Vec<Cand>,
    /// The rank of the k-th best so far (`u64::MAX` while fewer than k are held and no bound
    /// was given): a record ranked at or above it cannot enter.
    worst: u64,
    /// The distance² part of `worst` (+∞ while unset): subtrees beyond it are skipped.
    bound: f32,
    boxes: bool,
    /// Records scanned (see `Neighbours::records_scanned`).
    scanned: u64,
}

impl<const W: usize, const P: usize> Search<'_, W, P> {
    /// Visits the subtree at `node` over records `lo..hi`, whose first leaf is `leaf`; `ow`
    /// and `op` hold the query's offsets to the split planes on the path (a lower bound on
    /// every record's distance² below, and on its ball distance²).
    fn visit(
        &mut self,
        node: usize,
        lo: usize,
        hi: usize,
        leaf: usize,
        ow: &mut [f32; W],
        op: &mut [f32; P],
    ) {
        if hi - lo <= LEAF {
            self.scan(lo, hi);
            return;
        }
        let tree = self.tree;
        let n = &tree.nodes[node];
        // Records that coincide in the distance dimensions are all equally far from any
        // query; their box is a point and gives their exact distance.
        let tied = n.lo_w == n.hi_w;
        // The node's box: a subtree is skipped when all its records are too far, or all lie
        // outside the parameter ball, which the split planes on the path may not show. A
        // subtree whose lower bound ties the k-th best is skipped when its smallest index
        // ranks after the k-th's (ties rank by index), so that a crowd of coincident records
        // costs a few leaves, not all of them.
        let lb = if self.boxes || tied { box_dist2(self.qw, &n.lo_w, &n.hi_w) } else { sum_sq(ow) };
        if rank(lb, n.min_idx) >= self.worst
            || (self.boxes && self.ball && box_dist2(self.qp, &n.lo_p, &n.hi_p) > self.r2)
        {
            return;
        }
        let axis = n.axis as usize;
        let mid = lo + left_size(hi - lo);
        let q = if axis < W { self.qw[axis] } else { self.qp[axis - W] };
        let diff = q - n.split;
        let left = (node + 1, lo, mid, leaf);
        let right = (n.right as usize, mid, hi, n.right_leaf as usize);
        let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
        // Among coincident records the lower indices first (the build puts them left of the
        // split), whichever side of the split the query lies.
        let min_of = |(node, lo, hi, leaf): (usize, usize, usize, usize)| {
            if hi - lo <= LEAF { tree.leaves[leaf].min_idx } else { tree.nodes[node].min_idx }
        };
        if tied && min_of(far) < min_of(near) {
            self.visit_far(axis, diff, far, ow, op);
            self.visit(near.0, near.1, near.2, near.3, ow, op);
        } else {
            self.visit(near.0, near.1, near.2, near.3, ow, op);
            self.visit_far(axis, diff, far, ow, op);
        }
    }

    /// Visits the child `far` of a node split at offset `diff` from the query along `axis`
    /// unless the split plane shows it too far (the child lies at least |diff| away along the axis).
    fn visit_far(
        &mut self,
        axis: usize,
        diff: f32,
        (far, flo, fhi, fleaf): (usize, usize, usize, usize),
        ow: &mut [f32; W],
        op: &mut [f32; P],
    ) {
        if axis < W && self.tree.refitted {
            // The split no longer separates the children: their boxes prune instead.
            self.visit(far, flo, fhi, fleaf, ow, op);
        } else if axis < W {
            let old = ow[axis];
            ow[axis] = diff.abs();
            if sum_sq(ow) <= self.bound && (!self.ball || sum_sq(op) <= self.r2) {
                self.visit(far, flo, fhi, fleaf, ow, op);
            }
            ow[axis] = old;
        } else {
            let a = axis - W;
            let old = op[a];
            op[a] = diff.abs();
            if (!self.ball || sum_sq(op) <= self.r2) && sum_sq(ow) <= self.bound {
                self.visit(far, flo, fhi, fleaf, ow, op);
            }
            op[a] = old;
        }
    }

    #[inline(always)]
    fn scan(&mut self, lo: usize, hi: usize) {
        self.scanned += (hi - lo) as u64;
        for (slot, r) in self.tree.recs[lo..hi].iter().enumerate() {
            let key = rank(dist2(&r.w, self.qw), r.idx);
            if key >= self.worst {
                continue;
            }
            if r.idx == self.exclude || (self.ball && dist2(&r.p, self.qp) > self.r2) {
                continue;
            }
            self.push(Cand::new(key, (lo + slot) as u32));
        }
    }

    /// Adds a candidate known to beat the current k-th best. Candidates are appended to a
    /// buffer of up to 2k and, when it fills, cut to the k best with one selection (linear
    /// time), which sets the bound: far fewer comparisons than keeping the list sorted on
    /// every insert (the bound lags a little, which costs less than it saves; measured by
    /// benches/spatial.rs; see BENCHMARKS.md).
    #[inline(always)]
    fn push(&mut self, c: Cand) {
        self.heap.push(c);
        // The first k set the first bound (unless one was given); after that the buffer runs
        // to 2k between cuts.
        let len = self.heap.len();
        if len == 2 * self.k || (len == self.k && self.worst == u64::MAX) {
            self.cut();
        }
    }

    /// Keeps the k best candidates (unordered) and makes the k-th the bound.
    fn cut(&mut self) {
        let k = self.k;
        let (_, kth, _) = self.heap.select_nth_unstable_by_key(k - 1, |c| c.key);
        self.worst = kth.key;
        self.bound = kth.dist2();
        self.heap.truncate(k);
    }

    /// The final list: the k best, sorted by (distance², index) when `ordered`.
    fn finish(&mut self, ordered: bool) {
        if self.heap.len() > self.k {
            self.cut();
        }
        if ordered {
            self.heap.sort_unstable_by_key(|c| c.key);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every leaf but the last is full, whatever the record count, and the nodes and leaves
    /// of each subtree add up as the traversals assume (a binary tree: one leaf more than
    /// internal nodes).
    #[test]
    fn leaves_are_full_but_the_last() {
        for n in [0, 1, LEAF - 1, LEAF, LEAF + 1, 2 * LEAF, 2 * LEAF + 1, 5 * LEAF + 3, 1000, 4097] {
            let mut leaves: Vec<Leaf<3, 0>> = Vec::new();
            leaf_ranges(0, n, &mut leaves);
            let sizes: Vec<u32> = leaves.iter().map(|l| l.hi - l.lo).collect();
            let full = sizes.len().saturating_sub(1);
            assert!(sizes[..full].iter().all(|&m| m as usize == LEAF), "n = {n}: {sizes:?}");
            assert!(sizes.last().is_none_or(|&m| m >= 1 || n == 0), "n = {n}: {sizes:?}");
            assert_eq!(sizes.iter().sum::<u32>() as usize, n);
            assert_eq!(leaves.len(), n.div_ceil(LEAF).max(1), "n = {n}");
            assert_eq!(count_nodes(n), leaves.len() - 1, "n = {n}");
        }
    }

    /// `nearest_first` keeps exactly the k lowest ranks, checked against a full sort: sets of
    /// distinct, tied (few distinct distances, many in one bucket) and coincident distances,
    /// every k, and reaches at and above the largest distance.
    #[test]
    fn nearest_first_keeps_the_k_lowest_ranks_and_kth_rank_finds_the_kth() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
        for trial in 0..300 {
            let m = rng.random_range(1..=BUCKETED + 20);
            let levels = [0usize, 3, 40, 1_000_000][trial % 4];
            let cands: Vec<Cand> = (0..m as u32)
                .map(|i| {
                    let d =
                        if levels == 0 { 0.0 } else { rng.random_range(0..levels) as f32 / levels as f32 };
                    Cand::new(rank(d, rng.random_range(0..10 * m as u32) * 16 + i % 16), i)
                })
                .collect();
            let far = cands.iter().map(|c| c.dist2()).fold(0.0, f32::max);
            let mut sorted: Vec<u64> = cands.iter().map(|c| c.key).collect();
            sorted.sort_unstable();
            sorted.dedup();
            if sorted.len() != m {
                continue; // ranks are unique in the tree (they hold the photon index)
            }
            for k in 1..=m {
                for reach in [far, far * 1.5 + 1e-3] {
                    let mut s = cands.clone();
                    let far2 = nearest_first(&mut s, k, reach);
                    assert_eq!(far2, f32::from_bits((sorted[k - 1] >> 32) as u32), "m = {m}, k = {k}");
                    let mut got: Vec<u64> = s[..k].iter().map(|c| c.key).collect();
                    got.sort_unstable();
                    assert_eq!(got, sorted[..k], "m = {m}, k = {k}, levels = {levels}, reach = {reach}");
                    let mut s = cands.clone();
                    assert_eq!(kth_rank(&mut s, k, reach), sorted[k - 1], "k-th, m = {m}, k = {k}");
                }
            }
        }
    }
}
