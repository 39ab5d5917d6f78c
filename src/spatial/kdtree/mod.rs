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

mod groups;
mod search;
mod select;

pub(crate) use groups::Group;

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
    /// a subtree whose lower bound ties the k-th best is pruned by it
    /// ([`Search::visit`](search::Search::visit)).
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
}

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

#[cfg(test)]
mod tests {
    use super::select::{BUCKETED, kth_rank, nearest_first};
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
