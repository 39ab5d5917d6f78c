//! The k-nearest search through the tree ([`KdTree::knn`]): the tree descent with its
//! distance, ball and box bounds, the bound seeded from the previous result, and the writing
//! of the result.

use super::select::farthest;
use super::{Cand, KdTree, LEAF, box_dist2, dist2, left_size, rank, sum_sq};
use crate::spatial::{Neighbour, Neighbours};

impl<const W: usize, const P: usize> KdTree<W, P> {
    /// The `k` records nearest `qw` with `|p − qp|² ≤ r2` (`r2 = None`: no ball), skipping
    /// the record whose index is `exclude`; sorted by (distance², index) into `out`, with
    /// their coordinates and places. `out`'s previous result, if it came from this tree,
    /// gives the search its starting bound ([`crate::spatial::SpatialIndex::knn`]).
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
    pub(super) fn emit(
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
