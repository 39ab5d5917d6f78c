//! World-space k-NN with a tight bounding box on every node, for rendering lookups.
//!
//! The renderer asks for the K nearest photons at every diffuse point the camera sees, and
//! most of those points lie far from any photon (a caustic covers a small part of the floor).
//! A kd-tree that prunes by split planes alone visits many unbounded boundary cells for such
//! a query; pruning by the distance to each node's box of actual points keeps a far query as
//! cheap as a near one. Results are exact and equal [`super::brute_force_knn`] in
//! [`super::Space::World`]: the k smallest by (distance², photon index).

use rayon::prelude::*;

use super::{Neighbour, Neighbours};

/// Points per leaf.
const LEAF: usize = 8;
/// Up to this k the candidates are kept in a sorted list (cheapest for photon-map k); above
/// it, in a binary max-heap sorted at the end (the diffusion estimator asks for 500).
const SORTED_MAX: usize = 32;
/// Subtrees larger than this are built in parallel.
const PARALLEL_BUILD: usize = 1 << 14;

#[derive(Clone, Copy, Debug, Default)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    /// Index of the right child (the left child follows the node); 0 for a leaf.
    right: u32,
    /// The node's points: `start..end` of the leaf-ordered arrays.
    start: u32,
    end: u32,
    /// The smallest photon index below the node: a subtree whose box distance ties the k-th
    /// best is skipped when it ranks after it (ties rank by index), so that a crowd of
    /// coincident photons costs a few leaves (issue 31).
    min_idx: u32,
}

/// A k-NN index over 3-D points with per-node bounding boxes.
#[derive(Clone, Debug, Default)]
pub struct BoxTree {
    nodes: Vec<Node>,
    /// Points in leaf order, and the caller's index of each.
    points: Vec<[f32; 3]>,
    index: Vec<u32>,
}

fn bounds(p: &[([f32; 3], u32)]) -> ([f32; 3], [f32; 3]) {
    let (lo, hi) = p.iter().fold((glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY), |(lo, hi), (q, _)| {
        let q = glam::Vec3::from_array(*q);
        (lo.min(q), hi.max(q))
    });
    (lo.to_array(), hi.to_array())
}

fn count_nodes(m: usize) -> usize {
    if m <= LEAF { 1 } else { 1 + count_nodes(m / 2) + count_nodes(m - m / 2) }
}

fn build(recs: &mut [([f32; 3], u32)], nodes: &mut [Node], base: usize, start: usize) {
    let (lo, hi) = bounds(recs);
    let m = recs.len();
    let (head, rest) = nodes.split_first_mut().expect("every subtree has a node");
    *head = Node { lo, hi, right: 0, start: start as u32, end: (start + m) as u32, min_idx: 0 };
    if m <= LEAF {
        head.min_idx = recs.iter().map(|r| r.1).min().unwrap_or(u32::MAX);
        return;
    }
    let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
    let mid = m / 2;
    // Ties by index: coincident photons lie in index order across the leaves.
    recs.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]).then(a.1.cmp(&b.1)));
    let left_nodes = count_nodes(mid);
    head.right = (base + 1 + left_nodes) as u32;
    let (lrecs, rrecs) = recs.split_at_mut(mid);
    let (lnodes, rnodes) = rest.split_at_mut(left_nodes);
    if m >= PARALLEL_BUILD {
        rayon::join(
            || build(lrecs, lnodes, base + 1, start),
            || build(rrecs, rnodes, base + 1 + left_nodes, start + mid),
        );
    } else {
        build(lrecs, lnodes, base + 1, start);
        build(rrecs, rnodes, base + 1 + left_nodes, start + mid);
    }
    head.min_idx = lnodes[0].min_idx.min(rnodes[0].min_idx);
}

/// Squared distance from `q` to the box, summed in axis order: never more than the distance
/// to any point inside (subtraction and squaring are monotone in floating point).
#[inline(always)]
fn box_dist2(n: &Node, q: &[f32; 3]) -> f32 {
    let mut s = 0.0f32;
    for ((lo, hi), x) in n.lo.iter().zip(&n.hi).zip(q) {
        let d = (lo - x).max(x - hi).max(0.0);
        s += d * d;
    }
    s
}

#[inline(always)]
fn dist2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    let mut s = 0.0f32;
    for i in 0..3 {
        let d = a[i] - b[i];
        s += d * d;
    }
    s
}

impl BoxTree {
    /// Builds the tree over `points` (point i has index i in the results). Non-finite
    /// coordinates are the caller's to refuse: they would sort arbitrarily.
    pub fn build(points: &[[f32; 3]]) -> BoxTree {
        let mut recs: Vec<([f32; 3], u32)> =
            points.par_iter().enumerate().map(|(i, p)| (*p, i as u32)).collect();
        if recs.is_empty() {
            return BoxTree::default();
        }
        let mut nodes = vec![Node::default(); count_nodes(recs.len())];
        build(&mut recs, &mut nodes, 0, 0);
        let (points, index) = recs.into_iter().unzip();
        BoxTree { nodes, points, index }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether it holds no point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The `k` points nearest `q` within distance² `max_dist2` (inclusive; ∞ for no limit),
    /// nearest first, ties by index.
    pub fn knn(&self, q: [f32; 3], k: usize, max_dist2: f32, out: &mut Neighbours) {
        out.clear();
        if k == 0 || self.nodes.is_empty() || max_dist2.is_nan() {
            return;
        }
        let mut s = Search {
            tree: self,
            q,
            k,
            heap: &mut out.items,
            worst: Neighbour { dist2: max_dist2, index: u32::MAX },
            scanned: 0,
        };
        if box_dist2(&self.nodes[0], &q) <= max_dist2 {
            s.visit(0);
        }
        out.records_scanned += s.scanned;
        if k > SORTED_MAX {
            out.items.sort_unstable_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
        }
        out.far2 = out.items.iter().map(|n| n.dist2).fold(0.0, f32::max);
        out.found = out.items.len();
    }
}

impl BoxTree {
    /// Calls `visit(index, dist²)` for every point within distance² `r2` of `q` (inclusive),
    /// in no particular order: a fixed-radius gather whose count has no cap.
    pub fn within(&self, q: [f32; 3], r2: f32, visit: &mut dyn FnMut(u32, f32)) {
        self.any_within(q, r2, &mut |i, d| {
            visit(i, d);
            false
        });
    }

    /// Whether `found(index, dist²)` holds for some point within distance² `r2` of `q`
    /// (inclusive): [`Self::within`] that stops at the first.
    pub fn any_within(&self, q: [f32; 3], r2: f32, found: &mut dyn FnMut(u32, f32) -> bool) -> bool {
        if self.nodes.is_empty() || r2.is_nan() || r2 < 0.0 {
            return false;
        }
        // A stack on the stack (a balanced tree of 2^32 points is 32 deep); a deeper one spills.
        let mut stack = [0usize; 64];
        let mut spill = Vec::new();
        let mut top = 1;
        loop {
            let node = if let Some(n) = spill.pop() {
                n
            } else if top > 0 {
                top -= 1;
                stack[top]
            } else {
                return false;
            };
            let n = &self.nodes[node];
            if box_dist2(n, &q) > r2 {
                continue;
            }
            if n.right == 0 {
                for i in n.start as usize..n.end as usize {
                    let d = dist2(&self.points[i], &q);
                    if d <= r2 && found(self.index[i], d) {
                        return true;
                    }
                }
            } else {
                for child in [n.right as usize, node + 1] {
                    if top < stack.len() {
                        stack[top] = child;
                        top += 1;
                    } else {
                        spill.push(child);
                    }
                }
            }
        }
    }
}

struct Search<'a> {
    tree: &'a BoxTree,
    q: [f32; 3],
    k: usize,
    heap: &'a mut Vec<Neighbour>,
    /// The k-th best so far, or the distance limit while fewer than k are held.
    worst: Neighbour,
    /// Points scanned (see `Neighbours::records_scanned`).
    scanned: u64,
}

impl Search<'_> {
    fn visit(&mut self, node: usize) {
        let n = &self.tree.nodes[node];
        if n.right == 0 {
            self.scanned += (n.end - n.start) as u64;
            for i in n.start as usize..n.end as usize {
                let d = dist2(&self.tree.points[i], &self.q);
                let idx = self.tree.index[i];
                if d < self.worst.dist2 || (d == self.worst.dist2 && idx < self.worst.index) {
                    self.push(Neighbour { dist2: d, index: idx });
                }
            }
            return;
        }
        // Each child ranks as its box distance and smallest index would (no photon below it
        // ranks before that): the nearer first, the one of lower indices on a tie, and either
        // skipped when it ranks after the k-th best.
        let child = |c: usize| {
            let n = &self.tree.nodes[c];
            Neighbour { dist2: box_dist2(n, &self.q), index: n.min_idx }
        };
        let (l, r) = (node + 1, n.right as usize);
        let (dl, dr) = (child(l), child(r));
        let ((a, da), (b, db)) = if !dr.before(&dl) { ((l, dl), (r, dr)) } else { ((r, dr), (l, dl)) };
        // (While fewer than k are held, `worst` is the distance limit with index u32::MAX.)
        if da.before(&self.worst) {
            self.visit(a);
        }
        if db.before(&self.worst) {
            self.visit(b);
        }
    }

    #[inline(always)]
    fn push(&mut self, c: Neighbour) {
        let h = &mut *self.heap;
        if self.k > SORTED_MAX {
            heap_push(h, self.k, c);
        } else {
            if h.len() == self.k {
                h.pop();
            }
            let at = h.partition_point(|x| x.before(&c));
            h.insert(at, c);
        }
        if h.len() == self.k {
            self.worst = if self.k > SORTED_MAX { h[0] } else { h[self.k - 1] };
        }
    }
}

/// Adds `c` to the max-heap `h` (the root is the last in (dist², index) order) of at most `k`,
/// replacing the root when full (`c` is known to come before it).
fn heap_push(h: &mut Vec<Neighbour>, k: usize, c: Neighbour) {
    if h.len() < k {
        h.push(c);
        let mut i = h.len() - 1;
        while i > 0 {
            let parent = (i - 1) / 2;
            if h[parent].before(&h[i]) {
                h.swap(parent, i);
                i = parent;
            } else {
                break;
            }
        }
        return;
    }
    h[0] = c;
    let mut i = 0;
    loop {
        let (l, r) = (2 * i + 1, 2 * i + 2);
        let mut top = i;
        if l < h.len() && h[top].before(&h[l]) {
            top = l;
        }
        if r < h.len() && h[top].before(&h[r]) {
            top = r;
        }
        if top == i {
            break;
        }
        h.swap(i, top);
        i = top;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::halton::PhotonRng;
    use crate::spatial::{PointSet, Query, Space, brute_force_knn};

    #[test]
    fn within_equals_brute_force() {
        let mut rng = PhotonRng::new(7, 1);
        let pts: Vec<[f32; 3]> = (0..3000)
            .map(|i| if i % 10 == 0 { [0.5, 0.5, 0.0] } else { [rng.next_f32(), rng.next_f32(), 0.0] })
            .collect();
        let tree = BoxTree::build(&pts);
        for (q, r) in [
            ([0.5f32, 0.5, 0.0], 0.05f32),
            ([0.0, 0.0, 0.0], 0.2),
            ([3.0, 3.0, 0.0], 0.1),
            ([0.3, 0.7, 0.0], 0.0),
        ] {
            let mut got = Vec::new();
            tree.within(q, r * r, &mut |i, d| got.push((i, d)));
            got.sort_by_key(|g| g.0);
            let want: Vec<(u32, f32)> = (0..pts.len() as u32)
                .map(|i| (i, dist2(&pts[i as usize], &q)))
                .filter(|&(_, d)| d <= r * r)
                .collect();
            assert_eq!(got, want, "query {q:?} radius {r}");
            // The early-stopping form finds a point that passes a test when one does.
            for (label, test) in [("odd", 1u32), ("multiple of 7", 7)] {
                let any =
                    tree.any_within(q, r * r, &mut |i, _| if test == 1 { i % 2 == 1 } else { i % 7 == 0 });
                let brute = want.iter().any(|&(i, _)| if test == 1 { i % 2 == 1 } else { i % 7 == 0 });
                assert_eq!(any, brute, "query {q:?} radius {r}: {label}");
            }
        }
    }

    #[test]
    fn equals_brute_force_near_far_and_with_ties() {
        // A dense filament, a sparse cloud and exact duplicates; queries inside, near and far
        // away (where the box pruning matters).
        let mut rng = PhotonRng::new(1, 2);
        let mut pts: Vec<[f32; 3]> =
            (0..3000).map(|_| [rng.next_f32() * 0.1, rng.next_f32() * 2.0, 0.0]).collect();
        pts.extend((0..1000).map(|_| [rng.next_f32() * 5.0, rng.next_f32() * 5.0, rng.next_f32() * 0.01]));
        pts.extend(std::iter::repeat_n([0.05, 1.0, 0.0], 20));
        let tree = BoxTree::build(&pts);
        let set = PointSet::world(&pts);
        let mut out = Neighbours::default();
        for j in 0..300 {
            let s = [1.0, 1.0, 30.0][j % 3];
            let q = [rng.next_f32() * s - 0.2 * s, rng.next_f32() * s, (j % 7) as f32 * 0.1];
            let q = if j % 10 == 0 { [0.05, 1.0, 0.0] } else { q };
            for k in [1, 15, 40, 300] {
                let query = Query { position: q, params: &[], radius: None, emitter: 0, exclude: None };
                let want = brute_force_knn(&set, Space::World, &query, k);
                tree.knn(q, k, f32::INFINITY, &mut out);
                assert_eq!(out.as_slice(), &want[..], "query {q:?} k {k}");
                // With a distance limit: the prefix of the unlimited result within it.
                let lim = want.get(k / 2).map_or(1.0, |n| n.dist2);
                tree.knn(q, k, lim, &mut out);
                let within: Vec<_> = want.iter().copied().filter(|n| n.dist2 <= lim).collect();
                assert_eq!(out.as_slice(), &within[..]);
            }
        }
        assert!(BoxTree::build(&[]).is_empty());
        // Around one, two and three leaves' worth: every point's neighbours, every k.
        for n in [1, LEAF - 1, LEAF, LEAF + 1, 2 * LEAF, 2 * LEAF + 1, 3 * LEAF + 2] {
            let pts: Vec<[f32; 3]> = (0..n).map(|_| [rng.next_f32(), rng.next_f32(), 0.0]).collect();
            let (tree, set) = (BoxTree::build(&pts), PointSet::world(&pts));
            for (i, &q) in pts.iter().enumerate() {
                for k in 1..=n {
                    let query = Query { position: q, params: &[], radius: None, emitter: 0, exclude: None };
                    tree.knn(q, k, f32::INFINITY, &mut out);
                    assert_eq!(
                        out.as_slice(),
                        &brute_force_knn(&set, Space::World, &query, k)[..],
                        "n {n} i {i} k {k}"
                    );
                }
            }
        }
    }

    /// Issue 31 item 5: a crowd of photons on one point (20 000 beside 2 000 spread ones)
    /// costs a render lookup, in it, beside it or far from it, about what an ordinary
    /// neighbourhood costs, and results equal the scan's.
    #[test]
    fn a_crowd_on_one_point_costs_a_few_leaves_per_lookup() {
        let mut rng = PhotonRng::new(3, 2);
        let mut pts: Vec<[f32; 3]> = (0..2000).map(|_| [rng.next_f32(), rng.next_f32(), 0.0]).collect();
        pts.extend(std::iter::repeat_n([0.5, 0.5, 0.0], 20_000));
        let (tree, set) = (BoxTree::build(&pts), PointSet::world(&pts));
        let spread = BoxTree::build(&pts[..2000]);
        let mut out = Neighbours::default();
        let mut ordinary = Neighbours::default();
        let queries: Vec<[f32; 3]> = (0..200)
            .map(|j| {
                [[0.5, 0.5, 0.0], [0.52, 0.5, 0.0], [0.5, 0.5, 3.0], [rng.next_f32(), rng.next_f32(), 0.0]]
                    [j % 4]
            })
            .collect();
        for &q in &queries {
            for k in [15, 40] {
                tree.knn(q, k, f32::INFINITY, &mut out);
                spread.knn(q, k, f32::INFINITY, &mut ordinary);
                let query = Query { position: q, params: &[], radius: None, emitter: 0, exclude: None };
                assert_eq!(
                    out.as_slice(),
                    &brute_force_knn(&set, Space::World, &query, k)[..],
                    "query {q:?} k {k}"
                );
            }
        }
        let (crowd, base) = (out.records_scanned, ordinary.records_scanned);
        assert!(crowd <= 3 * base + 400 * 8, "{crowd} points scanned against {base} without the crowd");
    }
}
