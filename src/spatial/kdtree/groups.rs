//! Leaf groups (module docs of [`super`]): the candidates gathered once for the queries of
//! one leaf, and the answers scanned from them four records at a time.

use glam::Vec4;

#[cfg(not(target_arch = "x86_64"))]
use super::rank;
use super::select::{kth_rank, nearest_first};
use super::{BLOCKS, Cand, KdTree, LEAF, Node, SLOTS, larger, left_size};
use crate::spatial::Neighbours;

/// Axes of a [`Group`]'s boxes: the most of either kind a tree has
/// ([`crate::spatial::MAX_PARAM_DIMS`]).
const GROUP_AXES: usize = crate::spatial::MAX_PARAM_DIMS;

/// Candidates gathered once for the queries of one leaf (module docs): the leaves that hold
/// every record within distance² `g2` of the box `lo_w..hi_w` and, on a constrained search,
/// within ball distance² `r2` of the box `lo_p..hi_p`. A query inside both boxes, with a ball no larger
/// and the same k, finds among them every record within `g2` of itself that its ball admits
/// (each axis's offset to a box that holds the query is at most its offset to the query, and
/// rounding keeps that order): when at least k are, its k nearest are exact.
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
    pub(super) fn serves<const W: usize, const P: usize>(
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
    // Just over 100 lines: the descent, the reach and the packing of the leaves' boxes into
    // lanes are one sequence filling the same group.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn gather(
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
    pub(super) fn answer_from_group(
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

/// The margin of a leaf group's reach, as a fraction of the diagonal of the leaf's box
/// ([`KdTree::gather`]); measured by benches/stages.rs; see BENCHMARKS.md.
const GROUP_SLACK: f32 = 0.15;

/// A leaf group's ball radius², as a multiple of the query's (1.2²; [`KdTree::gather`]).
const BALL_SLACK: f32 = 1.44;

/// Most leaves a group holds, per (k / LEAF + 16) ([`KdTree::gather`]).
const GROUP_CAP: usize = 4;

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
