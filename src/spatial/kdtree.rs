//! A compact kd-tree over `W` distance dimensions and `P` range-constrained dimensions.
//!
//! Records are stored in leaf order (one contiguous slice per leaf); the internal nodes are
//! in depth-first order, each holding only its split axis, split value and the index of its
//! right child (the left child follows it). Every node splits its points at the median along
//! the axis of widest *weighted* extent: cycling axes would waste a level in three on photons
//! that lie on a plane, and the weights let world-space metres and parameter-space units
//! compete fairly (see [`Weights`]).
//!
//! A query finds the k records nearest the query in the `W` distance dimensions among those
//! within a Euclidean ball in the `P` dimensions, with the ball test inside the traversal: a
//! subtree is skipped when either its distance lower bound exceeds the current k-th best or
//! its ball lower bound exceeds the radius. Lower bounds are sums of per-axis squared offsets
//! in the same order as the distances themselves, so in floating point a bound never exceeds
//! the distance of any record below it and the search is exact, ties included.

use super::{Neighbour, Neighbours};

/// Records per leaf; chosen by measurement (BENCHMARKS.md, "Spatial index").
pub(crate) const LEAF: usize = 12;

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

#[derive(Clone, Copy, Debug, Default)]
struct Node {
    split: f32,
    axis: u32,
    right: u32,
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
fn rank(n: &Neighbour) -> u64 {
    ((n.dist2.to_bits() as u64) << 32) | n.index as u64
}

/// Internal nodes of a subtree of `m` records.
fn count_nodes(m: usize) -> usize {
    if m <= LEAF { 0 } else { 1 + count_nodes(m / 2) + count_nodes(m - m / 2) }
}

#[derive(Clone, Debug, Default)]
pub(crate) struct KdTree<const W: usize, const P: usize> {
    recs: Vec<Rec<W, P>>,
    nodes: Vec<Node>,
}

impl<const W: usize, const P: usize> KdTree<W, P> {
    /// Builds over `recs`, reusing this tree's allocations.
    pub fn rebuild(&mut self, fill: impl FnOnce(&mut Vec<Rec<W, P>>), weights: Option<Weights>) {
        self.recs.clear();
        fill(&mut self.recs);
        let n = self.recs.len();
        self.nodes.clear();
        self.nodes.resize(count_nodes(n), Node::default());
        if n <= LEAF {
            return;
        }
        let weights = weights.unwrap_or_else(|| default_weights(&self.recs));
        let per_axis: Vec<f32> = (0..W + P).map(|a| if a < W { weights.w } else { weights.p }).collect();
        build_node(&mut self.recs, &mut self.nodes, 0, &per_axis);
    }

    /// The records' indices in leaf order.
    pub fn order(&self) -> impl Iterator<Item = u32> + '_ {
        self.recs.iter().map(|r| r.idx)
    }

    /// The `k` records nearest `qw` with `|p − qp|² ≤ r2` (`r2 = None`: no ball), skipping
    /// the record whose index is `exclude`; sorted by (distance², index) into `out`.
    pub fn knn(
        &self,
        qw: &[f32; W],
        qp: &[f32; P],
        r2: Option<f32>,
        exclude: Option<u32>,
        k: usize,
        out: &mut Neighbours,
    ) {
        out.items.clear();
        if k == 0 || self.recs.is_empty() {
            return;
        }
        let mut s = Search {
            tree: self,
            qw,
            qp,
            r2: r2.unwrap_or(f32::INFINITY),
            ball: r2.is_some() && P > 0,
            exclude: exclude.unwrap_or(u32::MAX),
            k,
            heap: &mut out.items,
            worst: Neighbour { dist2: f32::INFINITY, index: u32::MAX },
        };
        // A NaN radius admits nothing; so does a negative one (no distance is below it).
        if s.ball && (s.r2.is_nan() || s.r2 < 0.0) {
            return;
        }
        let (mut ow, mut op) = ([0.0f32; W], [0.0f32; P]);
        s.visit(0, 0, self.recs.len(), &mut ow, &mut op);
        s.finish();
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

fn bounds<const W: usize, const P: usize>(recs: &[Rec<W, P>]) -> (Vec<f32>, Vec<f32>) {
    let mut lo = vec![f32::INFINITY; W + P];
    let mut hi = vec![f32::NEG_INFINITY; W + P];
    for r in recs {
        for a in 0..W {
            lo[a] = lo[a].min(r.w[a]);
            hi[a] = hi[a].max(r.w[a]);
        }
        for a in 0..P {
            lo[W + a] = lo[W + a].min(r.p[a]);
            hi[W + a] = hi[W + a].max(r.p[a]);
        }
    }
    (lo, hi)
}

fn build_node<const W: usize, const P: usize>(
    recs: &mut [Rec<W, P>],
    nodes: &mut [Node],
    base: usize,
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
    let mid = m / 2;
    recs.select_nth_unstable_by(mid, |a, b| a.coord(axis).total_cmp(&b.coord(axis)));
    let split = recs[mid].coord(axis);
    let left_nodes = count_nodes(mid);
    let (head, rest) = nodes.split_first_mut().expect("a subtree of more than LEAF records has a node");
    *head = Node { split, axis: axis as u32, right: (base + 1 + left_nodes) as u32 };
    let (lrecs, rrecs) = recs.split_at_mut(mid);
    let (lnodes, rnodes) = rest.split_at_mut(left_nodes);
    if m >= PARALLEL_BUILD {
        rayon::join(
            || build_node(lrecs, lnodes, base + 1, weights),
            || build_node(rrecs, rnodes, base + 1 + left_nodes, weights),
        );
    } else {
        build_node(lrecs, lnodes, base + 1, weights);
        build_node(rrecs, rnodes, base + 1 + left_nodes, weights);
    }
}

struct Search<'a, const W: usize, const P: usize> {
    tree: &'a KdTree<W, P>,
    qw: &'a [f32; W],
    qp: &'a [f32; P],
    r2: f32,
    ball: bool,
    exclude: u32,
    k: usize,
    heap: &'a mut Vec<Neighbour>,
    /// The k-th best so far, or +∞ while fewer than k are held.
    worst: Neighbour,
}

impl<const W: usize, const P: usize> Search<'_, W, P> {
    fn visit(&mut self, node: usize, lo: usize, hi: usize, ow: &mut [f32; W], op: &mut [f32; P]) {
        if hi - lo <= LEAF {
            self.scan(lo, hi);
            return;
        }
        let n = self.tree.nodes[node];
        let axis = n.axis as usize;
        let mid = lo + (hi - lo) / 2;
        let q = if axis < W { self.qw[axis] } else { self.qp[axis - W] };
        let diff = q - n.split;
        let ((near, nlo, nhi), (far, flo, fhi)) = if diff < 0.0 {
            ((node + 1, lo, mid), (n.right as usize, mid, hi))
        } else {
            ((n.right as usize, mid, hi), (node + 1, lo, mid))
        };
        self.visit(near, nlo, nhi, ow, op);
        // The far child lies at least |diff| away along `axis`.
        if axis < W {
            let old = ow[axis];
            ow[axis] = diff.abs();
            if sum_sq(ow) <= self.worst.dist2 && (!self.ball || sum_sq(op) <= self.r2) {
                self.visit(far, flo, fhi, ow, op);
            }
            ow[axis] = old;
        } else {
            let a = axis - W;
            let old = op[a];
            op[a] = diff.abs();
            if (!self.ball || sum_sq(op) <= self.r2) && sum_sq(ow) <= self.worst.dist2 {
                self.visit(far, flo, fhi, ow, op);
            }
            op[a] = old;
        }
    }

    #[inline(always)]
    fn scan(&mut self, lo: usize, hi: usize) {
        for r in &self.tree.recs[lo..hi] {
            let d = dist2(&r.w, self.qw);
            if d > self.worst.dist2 || (d == self.worst.dist2 && r.idx >= self.worst.index) {
                continue;
            }
            if r.idx == self.exclude || (self.ball && dist2(&r.p, self.qp) > self.r2) {
                continue;
            }
            self.push(Neighbour { dist2: d, index: r.idx });
        }
    }

    /// Adds a candidate known to beat the current k-th best. Candidates are appended to a
    /// buffer of up to 2k and, when it fills, cut to the k best with one selection (linear
    /// time), which sets the bound: far fewer comparisons than keeping the list sorted on
    /// every insert (the bound lags a little, which costs less than it saves; measured in
    /// BENCHMARKS.md, "Spatial index").
    #[inline(always)]
    fn push(&mut self, c: Neighbour) {
        self.heap.push(c);
        // The first k set the first bound; after that the buffer runs to 2k between cuts.
        let len = self.heap.len();
        if len == 2 * self.k || (len == self.k && self.worst.dist2 == f32::INFINITY) {
            self.cut();
        }
    }

    /// Keeps the k best candidates (unordered) and makes the k-th the bound.
    fn cut(&mut self) {
        let k = self.k;
        let (_, kth, _) = self.heap.select_nth_unstable_by_key(k - 1, rank);
        self.worst = *kth;
        self.heap.truncate(k);
    }

    /// The final list: the k best, sorted by (distance², index).
    fn finish(&mut self) {
        if self.heap.len() > self.k {
            self.cut();
        }
        self.heap.sort_unstable_by_key(rank);
    }
}
