//! A bounding volume hierarchy over triangles: binned surface-area-heuristic build of a binary
//! tree, collapsed into a four-wide one (each node holds its up to four children's boxes side
//! by side, so one node visit tests four boxes at once), ordered stack traversal, leaves tested
//! four triangles at a time, or a leaf of five to eight all at once where the processor has
//! AVX (such a leaf is then stored as one pair of packets).
//!
//! Our own rather than a crate's: its closest-hit queries are faster per core than those of
//! the `obvhs` and `bvh` crates on the sample scenes' meshes, with the same triangle and
//! distance on every ray but for ties and the crates' own misses (measured by benches/bvh.rs;
//! see BENCHMARKS.md). The traversal is
//! ordered and prunes by the best hit so far, and the triangles are kept in leaf order next to
//! the nodes, which is what makes photon tracing cache-friendly.

mod simd;
#[cfg(test)]
mod tests;
mod traverse;

use glam::{Vec3, Vec4};

use crate::scene::shape::Ray;

pub(crate) use simd::avx_available;
use simd::{Packet, PacketPair, tri_intersect};
pub(crate) use traverse::ray_box;

/// Triangles per leaf at most (larger leaves are split even when SAH prefers not to).
const MAX_LEAF: usize = 8;
/// SAH bins per axis.
const BINS: usize = 16;
/// Cost of testing one packet of four triangles relative to one node visit. The SAH counts
/// packets, not triangles: a leaf of one to four triangles costs one test.
const PACKET_COST: f32 = 1.0;
const NODE_COST: f32 = 1.0;

/// A node of the binary tree the builder makes, which [`collapse`] turns into [`Node4`]s.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C)]
struct Node {
    min: Vec3,
    /// Interior: index of the left child (the right child follows it). Leaf: first packet.
    first: u32,
    max: Vec3,
    /// Number of triangles; 0 for an interior node.
    count: u32,
}

/// A node of the four-wide tree: its children's boxes side by side (`bounds[axis]` the
/// minima and `bounds[3 + axis]` the maxima along that axis, one lane per child), what each
/// child is, and how many lanes are used (two to four).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node4 {
    bounds: [Vec4; 6],
    /// Per lane: an interior child's node index, or a leaf's first packet (or pair).
    child: [u32; 4],
    /// Per lane: a leaf's triangle count (at most [`MAX_LEAF`]), 0 for an interior child.
    count: [u8; 4],
    /// Lanes in use, as a bit mask (the first two to four).
    used: u32,
}

// Two cache lines per node.
const _: () = assert!(std::mem::size_of::<Node4>() == 128 && MAX_LEAF <= u8::MAX as usize);

/// A triangle in the form the intersection test wants: the affine map taking world space to
/// the triangle's own frame (Baldwin & Weber, "Fast ray-triangle intersections by coordinate
/// transformation", JCGT 2016), three rows (x, y, z, w) applied as `row · (p, 1)`. It sends
/// the vertices to (0, 0, 0), (1, 0, 0) and (0, 1, 0) and the normal e1 × e2 to (0, 0, 1), so a
/// ray meets the triangle's plane where the frame's z is zero and the frame's x and y there are
/// the barycentric weights (b1, b2) of the second and third vertices. Precomputed once, it
/// saves the edge cross products of Möller–Trumbore at every test. A degenerate triangle gets
/// zero rows, which give t = NaN: never a hit.
#[derive(Clone, Copy, Debug)]
pub struct Tri {
    rows: [[f32; 4]; 3],
}

impl Tri {
    /// The frame of the triangle with vertices `a`, `b`, `c`.
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> Tri {
        // In f64, so each entry is the exact map's rounded once.
        let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let n = e1.cross(e2);
        let n2 = n.length_squared();
        if !(n2 > 0.0 && n2.is_finite()) {
            return Tri { rows: [[0.0; 4]; 3] };
        }
        // The inverse of the matrix with columns e1, e2, n, whose determinant is n · n.
        let row = |r: glam::DVec3| {
            let r = r / n2;
            [r.x as f32, r.y as f32, r.z as f32, -r.dot(a) as f32]
        };
        Tri { rows: [row(e2.cross(n)), row(n.cross(e1)), row(n)] }
    }

    /// The ray's hit with `t` in (`t_min`, `t_max`) as (t, b1, b2): the test the hierarchy's
    /// leaves do (for comparisons such as `benches/bvh.rs`).
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
        tri_intersect(self, ray, t_min, t_max)
    }
}

/// A ray's nearest hit on the triangles: distance, the triangle's index in the input list and
/// barycentric coordinates (b1, b2) of the hit (weights of the second and third vertices).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriHit {
    /// Distance along the ray, metres.
    pub t: f32,
    /// The triangle's index in the list the BVH was built from.
    pub index: u32,
    /// Weight of the second vertex.
    pub b1: f32,
    /// Weight of the third vertex.
    pub b2: f32,
}

/// The hierarchy and the triangles reordered to follow its leaves, in packets of four.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// The four-wide tree, root first; empty when the whole mesh is one leaf (`root_leaf`).
    nodes: Vec<Node4>,
    /// The box around every triangle.
    bounds: Option<(Vec3, Vec3)>,
    /// The whole mesh as one leaf (first packet or pair, triangle count), when it is one.
    root_leaf: Option<(u32, u32)>,
    /// Each leaf's packets from its `first` on; with AVX, only the leaves of one packet.
    packets: Vec<Packet>,
    /// Input index of the triangle in each lane of each packet (`u32::MAX` for padding).
    index: Vec<u32>,
    /// With AVX, the leaves of two packets (five to eight triangles), each one pair at its
    /// `first`; empty without AVX.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pairs: Vec<PacketPair>,
    /// Input index of the triangle in each lane of each pair (`u32::MAX` for padding).
    pair_index: Vec<u32>,
    /// Whether the processor has AVX, so a leaf's two packets are tested at once
    /// ([`packet_pair_intersect`]).
    avx: bool,
    /// The most children the traversal can have pending at once: three per level of the
    /// four-wide tree below the root (a node pushes all but the one it visits).
    stack_need: usize,
}

#[derive(Clone, Copy)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };

    fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    fn union(&mut self, o: &Aabb) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }

    fn area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }
}

impl Bvh {
    /// Builds the hierarchy over `triangles` (each three vertices), with the leaves of two
    /// packets stored as pairs where the processor has AVX.
    pub fn build(triangles: &[[Vec3; 3]]) -> Bvh {
        Bvh::build_for(triangles, avx_available())
    }

    /// [`Bvh::build`], with pairs and their AVX test or not (`avx`, which the processor must
    /// have if true): the portable layout is tested on processors with AVX too.
    fn build_for(triangles: &[[Vec3; 3]], avx: bool) -> Bvh {
        let n = triangles.len();
        if n == 0 {
            return Bvh::default();
        }
        let mut bounds: Vec<Aabb> = Vec::with_capacity(n);
        let mut centroids: Vec<Vec3> = Vec::with_capacity(n);
        for t in triangles {
            let mut b = Aabb::EMPTY;
            t.iter().for_each(|&p| b.grow(p));
            bounds.push(b);
            centroids.push((t[0] + t[1] + t[2]) / 3.0);
        }
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity(2 * n);
        nodes.push(Node::default());
        let mut b = Builder { bounds: &bounds, centroids: &centroids, order: &mut order, nodes: &mut nodes };
        b.split(0, 0, n);
        let tris: Vec<Tri> = order
            .iter()
            .map(|&i| {
                let [a, b, c] = triangles[i as usize];
                Tri::new(a, b, c)
            })
            .collect();
        // Each leaf's triangles, in the same order, go into packets of their own; with AVX, a
        // leaf of two packets is stored as one pair instead.
        let (mut packets, mut index, mut pairs, mut pair_index) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let order = &order;
        let lanes = |from: usize, to: usize, end: usize| {
            (from..to).map(move |j| if j < end { order[j] } else { u32::MAX })
        };
        for node in nodes.iter_mut().filter(|n| n.count > 0) {
            let (first, count) = (node.first as usize, node.count as usize);
            let end = first + count;
            if avx && count > 4 {
                node.first = pairs.len() as u32;
                pairs.push(PacketPair::new(
                    &Packet::new(&tris[first..first + 4]),
                    &Packet::new(&tris[first + 4..end]),
                ));
                pair_index.extend(lanes(first, first + 8, end));
            } else {
                node.first = packets.len() as u32;
                for k in (first..end).step_by(4) {
                    packets.push(Packet::new(&tris[k..(k + 4).min(end)]));
                    index.extend(lanes(k, k + 4, end));
                }
            }
        }
        let bounds = Some((nodes[0].min, nodes[0].max));
        let (wide, root_leaf) = if nodes[0].count > 0 {
            (Vec::new(), Some((nodes[0].first, nodes[0].count)))
        } else {
            let mut wide = Vec::with_capacity(nodes.len() / 2);
            collapse(&nodes, 0, &mut wide);
            (wide, None)
        };
        let stack_need = 3 * wide_depth(&wide);
        Bvh { nodes: wide, bounds, root_leaf, packets, index, pairs, pair_index, avx, stack_need }
    }

    /// The box around every triangle (the binary tree's root's), or `None` without triangles.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// Whether it holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty() && self.pair_index.is_empty()
    }

    /// Whether the processor has AVX, which the scene's other eight-lane tests use too.
    pub(crate) fn avx(&self) -> bool {
        self.avx
    }
}

/// Levels of interior nodes in the four-wide tree (0 for none), without recursion.
fn wide_depth(nodes: &[Node4]) -> usize {
    let mut deepest = 0;
    let mut todo = if nodes.is_empty() { vec![] } else { vec![(0usize, 1usize)] };
    while let Some((n, d)) = todo.pop() {
        deepest = deepest.max(d);
        let node = &nodes[n];
        for lane in (0..4).filter(|&l| node.used & (1 << l) != 0 && node.count[l] == 0) {
            todo.push((node.child[lane] as usize, d + 1));
        }
    }
    deepest
}

/// Writes the four-wide node for binary interior node `n` (and, depth first, those below it)
/// into `out`; returns its index. Each of the node's children is replaced by its own two
/// children, largest box first, until four are gathered or only leaves remain.
fn collapse(bin: &[Node], n: usize, out: &mut Vec<Node4>) -> u32 {
    let l = bin[n].first as usize;
    let mut kids = vec![l, l + 1];
    while kids.len() < 4 {
        let area = |k: usize| Aabb { min: bin[k].min, max: bin[k].max }.area();
        let Some(at) = (0..kids.len())
            .filter(|&j| bin[kids[j]].count == 0)
            .max_by(|&a, &b| area(kids[a]).total_cmp(&area(kids[b])).then(b.cmp(&a)))
        else {
            break;
        };
        let g = bin[kids[at]].first as usize;
        kids.splice(at..=at, [g, g + 1]);
    }
    let me = out.len();
    out.push(Node4 { bounds: [Vec4::ZERO; 6], child: [0; 4], count: [0; 4], used: (1 << kids.len()) - 1 });
    for (lane, &k) in kids.iter().enumerate() {
        let b = &bin[k];
        let child = if b.count > 0 { b.first } else { collapse(bin, k, out) };
        let node = &mut out[me];
        for axis in 0..3 {
            node.bounds[axis][lane] = b.min[axis];
            node.bounds[3 + axis][lane] = b.max[axis];
        }
        node.child[lane] = child;
        node.count[lane] = b.count as u8;
    }
    me as u32
}

struct Builder<'a> {
    bounds: &'a [Aabb],
    centroids: &'a [Vec3],
    order: &'a mut [u32],
    nodes: &'a mut Vec<Node>,
}

impl Builder<'_> {
    fn split(&mut self, node: usize, first: usize, count: usize) {
        let mut bb = Aabb::EMPTY;
        let mut cb = Aabb::EMPTY;
        for &i in &self.order[first..first + count] {
            bb.union(&self.bounds[i as usize]);
            cb.grow(self.centroids[i as usize]);
        }
        self.nodes[node].min = bb.min;
        self.nodes[node].max = bb.max;
        let leaf = |nodes: &mut Vec<Node>| {
            nodes[node].first = first as u32;
            nodes[node].count = count as u32;
        };
        if count <= 4 {
            return leaf(self.nodes);
        }

        // Binned SAH over the centroid bounds.
        let extent = cb.max - cb.min;
        let mut best: Option<(f32, usize, f32)> = None; // (cost, axis, split position)
        for axis in 0..3 {
            if extent[axis] <= 0.0 {
                continue;
            }
            let scale = BINS as f32 / extent[axis];
            let mut bins = [(Aabb::EMPTY, 0usize); BINS];
            for &i in &self.order[first..first + count] {
                let b = (((self.centroids[i as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1);
                bins[b].0.union(&self.bounds[i as usize]);
                bins[b].1 += 1;
            }
            let mut right_area = [0.0f32; BINS];
            let mut right_count = [0usize; BINS];
            let mut acc = Aabb::EMPTY;
            let mut c = 0;
            for b in (1..BINS).rev() {
                acc.union(&bins[b].0);
                c += bins[b].1;
                right_area[b] = acc.area();
                right_count[b] = c;
            }
            let mut acc = Aabb::EMPTY;
            let mut c = 0;
            for b in 0..BINS - 1 {
                acc.union(&bins[b].0);
                c += bins[b].1;
                if c == 0 || right_count[b + 1] == 0 {
                    continue;
                }
                let cost = acc.area() * c.div_ceil(4) as f32
                    + right_area[b + 1] * right_count[b + 1].div_ceil(4) as f32;
                if best.is_none_or(|(bc, _, _)| cost < bc) {
                    best = Some((cost, axis, cb.min[axis] + (b + 1) as f32 / scale));
                }
            }
        }
        let leaf_cost = count.div_ceil(4) as f32 * PACKET_COST;
        let mid = match best {
            Some((cost, axis, pos)) => {
                let split_cost = NODE_COST + PACKET_COST * cost / bb.area().max(f32::MIN_POSITIVE);
                if split_cost >= leaf_cost && count <= MAX_LEAF {
                    return leaf(self.nodes);
                }
                let centroids = self.centroids;
                let m =
                    partition(&mut self.order[first..first + count], |i| centroids[i as usize][axis] < pos);
                if m == 0 || m == count { count / 2 } else { m }
            }
            None if count <= MAX_LEAF => return leaf(self.nodes),
            // All centroids coincide: split in the middle of the list.
            None => count / 2,
        };
        let left = self.nodes.len();
        self.nodes.push(Node::default());
        self.nodes.push(Node::default());
        self.nodes[node].first = left as u32;
        self.nodes[node].count = 0;
        self.split(left, first, mid);
        self.split(left + 1, first + mid, count - mid);
    }
}

/// Moves the elements satisfying `pred` to the front; returns how many there are.
fn partition(v: &mut [u32], pred: impl Fn(u32) -> bool) -> usize {
    let mut m = 0;
    for k in 0..v.len() {
        if pred(v[k]) {
            v.swap(m, k);
            m += 1;
        }
    }
    m
}

/// Every triangle tested in turn: the oracle the hierarchy is checked against.
pub fn brute_force(triangles: &[[Vec3; 3]], ray: &Ray, t_min: f32, t_max: f32) -> Option<TriHit> {
    let mut best: Option<TriHit> = None;
    let mut t_best = t_max;
    for (i, [a, b, c]) in triangles.iter().enumerate() {
        if let Some((t, b1, b2)) = tri_intersect(&Tri::new(*a, *b, *c), ray, t_min, t_best) {
            t_best = t;
            best = Some(TriHit { t, index: i as u32, b1, b2 });
        }
    }
    best
}
