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

use std::mem::MaybeUninit;

use glam::{Vec3, Vec4};

use super::shape::Ray;

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

/// A child still to visit: its lane's `child` and `count` and the ray's entry distance into
/// its box.
#[derive(Clone, Copy)]
struct Pending {
    child: u32,
    count: u32,
    near: f32,
}

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

/// Four triangles of a leaf side by side (each row entry as four lanes), tested at once by
/// [`packet_intersect`]. Lanes past the leaf's end hold zero rows, which nothing hits.
#[derive(Clone, Copy, Debug)]
struct Packet {
    rows: [[Vec4; 4]; 3],
}

impl Packet {
    fn new(tris: &[Tri]) -> Packet {
        let lane = |r: usize, k: usize| {
            Vec4::from_array(std::array::from_fn(|l| tris.get(l).map_or(0.0, |t| t.rows[r][k])))
        };
        Packet { rows: std::array::from_fn(|r| std::array::from_fn(|k| lane(r, k))) }
    }
}

/// Two packets' rows side by side, lanes 0–3 the first packet's and 4–7 the second's: what
/// [`packet_pair_intersect`] loads into AVX registers as they are.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct PacketPair {
    rows: [[[f32; 8]; 4]; 3],
}

impl PacketPair {
    fn new(a: &Packet, b: &Packet) -> PacketPair {
        let side_by_side = |r: usize, k: usize| {
            let (a, b) = (a.rows[r][k].to_array(), b.rows[r][k].to_array());
            std::array::from_fn(|l| if l < 4 { a[l] } else { b[l - 4] })
        };
        PacketPair { rows: std::array::from_fn(|r| std::array::from_fn(|k| side_by_side(r, k))) }
    }
}

/// A ray's origin and direction, each coordinate repeated in four lanes.
struct RayLanes {
    o: [Vec4; 3],
    d: [Vec4; 3],
}

impl RayLanes {
    #[inline(always)]
    fn new(ray: &Ray) -> RayLanes {
        RayLanes {
            o: [Vec4::splat(ray.origin.x), Vec4::splat(ray.origin.y), Vec4::splat(ray.origin.z)],
            d: [Vec4::splat(ray.dir.x), Vec4::splat(ray.dir.y), Vec4::splat(ray.dir.z)],
        }
    }
}

/// A ray's nearest hit on the triangles: distance, the triangle's index in the input list and
/// barycentric coordinates (b1, b2) of the hit (weights of the second and third vertices).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriHit {
    pub t: f32,
    pub index: u32,
    pub b1: f32,
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

/// Pending children the traversal keeps on the call stack; a tree that may need more (deeper
/// than 64 levels, which no sample scene comes near) gets a stack on the heap per ray.
const INLINE_STACK: usize = 3 * 64;

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

    pub fn is_empty(&self) -> bool {
        self.index.is_empty() && self.pair_index.is_empty()
    }

    /// Whether the processor has AVX, which the scene's other eight-lane tests use too.
    pub(crate) fn avx(&self) -> bool {
        self.avx
    }

    /// The nearest triangle hit with `t` in (`t_min`, `t_max`).
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<TriHit> {
        match self.root_leaf {
            // The whole mesh is one leaf (a small one, such as the prism's 8 triangles): its box
            // would seldom reject a ray that the packet tests do not, so go straight to them, in
            // a function of their own that does not pay for the traversal's registers and stack.
            Some((first, count)) => self.intersect_root_leaf(first, count, ray, t_min, t_max),
            None if self.nodes.is_empty() => None,
            None => self.traverse(ray, t_min, t_max),
        }
    }

    /// The whole mesh as one leaf (see [`Bvh::test_leaf`]).
    #[inline(always)]
    fn intersect_root_leaf(
        &self,
        first: u32,
        count: u32,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
    ) -> Option<TriHit> {
        let mut best: Option<TriHit> = None;
        let mut t_best = t_max;
        self.test_leaf(first, count, ray, &RayLanes::new(ray), t_min, &mut t_best, &mut best);
        best
    }

    /// [`Bvh::intersect`] through the hierarchy: at each node the four children's boxes are
    /// tested at once, and the children the ray enters are visited nearest first; a pending
    /// child is dropped when the best hit so far lies before its box.
    #[inline(never)]
    fn traverse(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<TriHit> {
        // Left uninitialised (zeroing it slowed mesh scenes; measured by benches/trace.rs):
        // only the entries below the stack pointer are read, and each was written first.
        if self.stack_need <= INLINE_STACK {
            let mut stack = [MaybeUninit::<Pending>::uninit(); INLINE_STACK];
            self.traverse_with(&mut stack, ray, t_min, t_max)
        } else {
            let mut stack = vec![MaybeUninit::<Pending>::uninit(); self.stack_need];
            self.traverse_with(&mut stack, ray, t_min, t_max)
        }
    }

    /// [`Bvh::traverse`] with a stack of at least [`Bvh::stack_need`] entries.
    #[inline(always)]
    fn traverse_with(
        &self,
        stack: &mut [MaybeUninit<Pending>],
        ray: &Ray,
        t_min: f32,
        t_max: f32,
    ) -> Option<TriHit> {
        let lanes = RayLanes::new(ray);
        let mut best: Option<TriHit> = None;
        let mut t_best = t_max;
        let slabs = Slabs::new(ray);
        let mut sp = 0usize;
        // The node or leaf in hand.
        let mut current = Pending { child: 0, count: 0, near: t_min };
        loop {
            if current.count > 0 {
                self.test_leaf(current.child, current.count, ray, &lanes, t_min, &mut t_best, &mut best);
            } else {
                let node = &self.nodes[current.child as usize];
                let (near, mask) = slabs.enter4(node, t_min, t_best);
                if mask != 0 {
                    let near = near.to_array();
                    let pending = |lane: usize| Pending {
                        child: node.child[lane],
                        count: node.count[lane] as u32,
                        near: near[lane],
                    };
                    if mask.count_ones() == 1 {
                        current = pending(mask.trailing_zeros() as usize);
                        continue;
                    }
                    // Two to four children entered: push them farthest first, visit the nearest.
                    let mut order = [0usize; 4];
                    let mut k = 0;
                    for lane in 0..4 {
                        if mask & (1 << lane) != 0 {
                            // Insertion by entry distance, farthest first; equal distances keep
                            // lane order (the lower lane visited first).
                            let mut j = k;
                            while j > 0 && near[order[j - 1]] <= near[lane] {
                                order[j] = order[j - 1];
                                j -= 1;
                            }
                            order[j] = lane;
                            k += 1;
                        }
                    }
                    for &lane in &order[..k - 1] {
                        // Within the stack by `stack_need` (an index past it would panic,
                        // never drop a child).
                        stack[sp].write(pending(lane));
                        sp += 1;
                    }
                    current = pending(order[k - 1]);
                    continue;
                }
            }
            // Pop the next child still in front of the best hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                // SAFETY: entries below the stack pointer have been written (above).
                let p = unsafe { stack[sp].assume_init() };
                if still_ahead(p.near, t_best) {
                    current = p;
                    break;
                }
            }
        }
    }
}

/// A ray as the four-wide slab test wants it: origin and inverse direction in four lanes each,
/// and which axes the ray runs parallel to.
struct Slabs {
    o: [Vec4; 3],
    inv: [Vec4; 3],
    /// Axes along which the direction is zero (or so small that its inverse is infinite).
    parallel: [bool; 3],
}

impl Slabs {
    #[inline(always)]
    fn new(ray: &Ray) -> Slabs {
        let inv = ray.dir.recip();
        Slabs {
            o: [Vec4::splat(ray.origin.x), Vec4::splat(ray.origin.y), Vec4::splat(ray.origin.z)],
            inv: [Vec4::splat(inv.x), Vec4::splat(inv.y), Vec4::splat(inv.z)],
            parallel: [!inv.x.is_finite(), !inv.y.is_finite(), !inv.z.is_finite()],
        }
    }

    /// The ray's entry distances into the four boxes of `node` and the mask of those it enters
    /// within (`t_min`, `t_max`): the slab test, four lanes at once. Along an axis the ray runs
    /// parallel to, a box is entered only if the origin lies between its bounds (bounds
    /// included), which the distances (bound − origin)·∞ cannot tell where they are 0·∞.
    #[inline(always)]
    fn enter4(&self, node: &Node4, t_min: f32, t_max: f32) -> (Vec4, u32) {
        let mut near = Vec4::splat(t_min);
        let mut far = Vec4::splat(t_max);
        let mut inside = node.used;
        for axis in 0..3 {
            let (lo, hi, o) = (node.bounds[axis], node.bounds[3 + axis], self.o[axis]);
            if self.parallel[axis] {
                inside &= (lo.cmple(o) & o.cmple(hi)).bitmask();
            } else {
                let t0 = (lo - o) * self.inv[axis];
                let t1 = (hi - o) * self.inv[axis];
                near = near.max(t0.min(t1));
                far = far.min(t0.max(t1));
            }
        }
        (near, near.cmple(far * SLAB_SLACK).bitmask() & inside)
    }
}

/// The slab test's margin, 1 + 2⁻¹⁶ (128 ulp): a box's entry distance (bound − origin)·(1/d)
/// and a triangle's hit distance (its frame's distance to the plane over the direction's
/// component along the normal) are rounded differently, the latter with a relative error of
/// about u·(|origin| + |vertex|)/(t·|cos θ|), so the box holding a triangle hit at t could come
/// out entered a few ulps after t, and the traversal skip the nearest hit when one farther by
/// an ulp had been found first (2 of 200 000 rays on the water's height field, against brute
/// force). The margin covers rays more than about a degree off the triangle's plane at the
/// sample scenes' distances (`a_box_is_entered_wherever_its_triangle_is_hit`); a box entered
/// within it beyond the best hit is visited for nothing, which is rare.
const SLAB_SLACK: f32 = 1.0 + 1.0 / 65536.0;

/// Whether a box entered at `near` may still hold a hit nearer than `t_best` (with the slab
/// test's margin).
#[inline(always)]
fn still_ahead(near: f32, t_best: f32) -> bool {
    near <= t_best * SLAB_SLACK
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

impl Bvh {
    /// Tests the leaf of `count` triangles from packet (or pair) `first` in order, keeping the
    /// nearest hit in `best`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn test_leaf(
        &self,
        first: u32,
        count: u32,
        ray: &Ray,
        lanes: &RayLanes,
        t_min: f32,
        t_best: &mut f32,
        best: &mut Option<TriHit>,
    ) {
        let first = first as usize;
        #[cfg(not(target_arch = "x86_64"))]
        let _ = ray; // only the AVX pair test reads the ray itself
        #[cfg(target_arch = "x86_64")]
        if self.avx && count > 4 {
            const _: () = assert!(MAX_LEAF <= 8, "a leaf of more than four triangles is one pair");
            // SAFETY: `avx` says the processor has AVX; with it, a leaf of more than four
            // triangles is the pair at `first`.
            if let Some((lane, t, b1, b2)) =
                unsafe { packet_pair_intersect(&self.pairs[first], ray, t_min, *t_best) }
            {
                *t_best = t;
                *best = Some(TriHit { t, index: self.pair_index[first * 8 + lane], b1, b2 });
            }
            return;
        }
        for k in 0..(count as usize).div_ceil(4) {
            if let Some((lane, t, b1, b2)) = packet_intersect(&self.packets[first + k], lanes, t_min, *t_best)
            {
                *t_best = t;
                *best = Some(TriHit { t, index: self.index[(first + k) * 4 + lane], b1, b2 });
            }
        }
    }
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

/// Entry distance of the ray from `o` with inverse direction `inv` into the box
/// [`min`, `max`], if it enters within (`t_min`, `t_max`). Along an axis the ray runs parallel
/// to (an infinite inverse), the box is entered only if the origin lies between the bounds,
/// bounds included (as in [`Slabs::enter4`]): the distances (bound − origin)·∞ are NaN when
/// the origin lies in a bound's plane.
#[inline(always)]
pub(crate) fn ray_box(min: Vec3, max: Vec3, o: Vec3, inv: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    let (mut near, mut far) = (t_min, t_max);
    for a in 0..3 {
        if inv[a].is_finite() {
            let (t0, t1) = ((min[a] - o[a]) * inv[a], (max[a] - o[a]) * inv[a]);
            near = near.max(t0.min(t1));
            far = far.min(t0.max(t1));
        } else if !(min[a] <= o[a] && o[a] <= max[a]) {
            return None;
        }
    }
    (near <= far).then_some(near)
}

/// Ray–triangle intersection in the triangle's frame ([`Tri`]): (t, b1, b2), two-sided.
#[inline(always)]
fn tri_intersect(tri: &Tri, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
    let (o, d) = (ray.origin, ray.dir);
    let point = |r: &[f32; 4]| r[0] * o.x + r[1] * o.y + r[2] * o.z + r[3];
    let dir = |r: &[f32; 4]| r[0] * d.x + r[1] * d.y + r[2] * d.z;
    let [rx, ry, rz] = &tri.rows;
    let t = -(point(rz) / dir(rz));
    if !(t > t_min && t < t_max) {
        return None;
    }
    let b1 = point(rx) + t * dir(rx);
    let b2 = point(ry) + t * dir(ry);
    (b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0).then_some((t, b1, b2))
}

/// [`tri_intersect`] on the four triangles of a packet at once, with the same operations in
/// the same order on each lane, so the same roundings: the nearest hit with `t` in (`t_min`,
/// `t_max`) as (lane, t, b1, b2), the first lane of the packet among equally near ones (as
/// testing the triangles in turn would find).
#[inline(always)]
fn packet_intersect(p: &Packet, r: &RayLanes, t_min: f32, t_max: f32) -> Option<(usize, f32, f32, f32)> {
    let point = |w: &[Vec4; 4]| w[0] * r.o[0] + w[1] * r.o[1] + w[2] * r.o[2] + w[3];
    let dir = |w: &[Vec4; 4]| w[0] * r.d[0] + w[1] * r.d[1] + w[2] * r.d[2];
    let [rx, ry, rz] = &p.rows;
    let t = -(point(rz) / dir(rz));
    // NaN (a degenerate or padding lane, a ray in the plane) fails both comparisons.
    let in_range = t.cmpgt(Vec4::splat(t_min)) & t.cmplt(Vec4::splat(t_max));
    if in_range.bitmask() == 0 {
        return None;
    }
    let b1 = point(rx) + t * dir(rx);
    let b2 = point(ry) + t * dir(ry);
    let hit = in_range & b1.cmpge(Vec4::ZERO) & b2.cmpge(Vec4::ZERO) & (b1 + b2).cmple(Vec4::ONE);
    let mask = hit.bitmask();
    if mask == 0 {
        return None;
    }
    let (t, b1, b2) = (t.to_array(), b1.to_array(), b2.to_array());
    let mut best: Option<usize> = None;
    for lane in 0..4 {
        if mask & (1 << lane) != 0 && best.is_none_or(|b| t[lane] < t[b]) {
            best = Some(lane);
        }
    }
    best.map(|k| (k, t[k], b1[k], b2[k]))
}

/// Whether [`packet_pair_intersect`] may run: the processor has AVX.
pub(crate) fn avx_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`packet_intersect`] on two packets (eight triangles) at once, in the 256-bit registers of
/// AVX: the same operations in the same order on each lane (no fused multiply-add), so the
/// same roundings; lanes 4–7 are the second packet's, and the nearest hit, the first lane
/// among equally near ones, is what testing the first packet and then the second with the
/// first's hit as `t_max` finds.
///
/// # Safety
/// The processor must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
unsafe fn packet_pair_intersect(
    pair: &PacketPair,
    ray: &Ray,
    t_min: f32,
    t_max: f32,
) -> Option<(usize, f32, f32, f32)> {
    use std::arch::x86_64::*;
    // SAFETY: `PacketPair` is 32-byte aligned, so each row of eight f32 is.
    let row = |k: usize, e: usize| unsafe { _mm256_load_ps(pair.rows[k][e].as_ptr()) };
    let o = [_mm256_set1_ps(ray.origin.x), _mm256_set1_ps(ray.origin.y), _mm256_set1_ps(ray.origin.z)];
    let d = [_mm256_set1_ps(ray.dir.x), _mm256_set1_ps(ray.dir.y), _mm256_set1_ps(ray.dir.z)];
    let (mul, add) = (|x, y| _mm256_mul_ps(x, y), |x, y| _mm256_add_ps(x, y));
    let point =
        |k: usize| add(add(add(mul(row(k, 0), o[0]), mul(row(k, 1), o[1])), mul(row(k, 2), o[2])), row(k, 3));
    let dir = |k: usize| add(add(mul(row(k, 0), d[0]), mul(row(k, 1), d[1])), mul(row(k, 2), d[2]));
    let t = _mm256_xor_ps(_mm256_div_ps(point(2), dir(2)), _mm256_set1_ps(-0.0));
    let in_range = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GT_OQ>(t, _mm256_set1_ps(t_min)),
        _mm256_cmp_ps::<_CMP_LT_OQ>(t, _mm256_set1_ps(t_max)),
    );
    if _mm256_movemask_ps(in_range) == 0 {
        return None;
    }
    let b1 = add(point(0), mul(t, dir(0)));
    let b2 = add(point(1), mul(t, dir(1)));
    let zero = _mm256_setzero_ps();
    let hit = _mm256_and_ps(
        _mm256_and_ps(in_range, _mm256_cmp_ps::<_CMP_GE_OQ>(b1, zero)),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(b2, zero),
            _mm256_cmp_ps::<_CMP_LE_OQ>(add(b1, b2), _mm256_set1_ps(1.0)),
        ),
    );
    let mask = _mm256_movemask_ps(hit);
    if mask == 0 {
        return None;
    }
    // The nearest hit lane, the first among equally near ones: the only one, or the least t
    // over the hit lanes (the others +∞; a hit lane's t is finite), then the lowest lane
    // holding it.
    let k = if mask.count_ones() == 1 {
        mask.trailing_zeros() as usize
    } else {
        let th = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), t, hit);
        let m = _mm256_min_ps(th, _mm256_permute_ps::<0b10_11_00_01>(th));
        let m = _mm256_min_ps(m, _mm256_permute_ps::<0b01_00_11_10>(m));
        let m = _mm256_min_ps(m, _mm256_permute2f128_ps::<1>(m, m));
        (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(th, m)) & mask).trailing_zeros() as usize
    };
    let lanes = |v: __m256| {
        let mut out = [0f32; 8];
        // SAFETY: `out` holds eight f32.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    };
    Some((k, lanes(t)[k], lanes(b1)[k], lanes(b2)[k]))
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn v(rng: &mut Pcg64Mcg, s: f32) -> Vec3 {
        Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5) * s
    }

    #[test]
    fn triangle_hit_matches_closed_form() {
        let t = [Vec3::new(0.0, 0.0, 1.0), Vec3::new(2.0, 0.0, 1.0), Vec3::new(0.0, 2.0, 1.0)];
        let ray = Ray::new(Vec3::new(0.5, 0.25, 3.0), Vec3::NEG_Z);
        let h = brute_force(&[t], &ray, 0.0, f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        assert!((h.b1 - 0.25).abs() < 1e-6 && (h.b2 - 0.125).abs() < 1e-6);
        let miss = Ray::new(Vec3::new(1.5, 1.5, 3.0), Vec3::NEG_Z);
        assert!(brute_force(&[t], &miss, 0.0, f32::INFINITY).is_none());
    }

    /// `n` random triangles about the origin; now and then a degenerate one, or a copy of the
    /// previous one (equal t: the first lane must win, as the first tested does).
    fn random_leaf(rng: &mut Pcg64Mcg, n: usize) -> Vec<Tri> {
        let mut tris: Vec<Tri> = Vec::new();
        for _ in 0..n {
            let c = v(rng, 1.0);
            let tri = match (rng.random::<u32>() % 8, tris.last()) {
                (0, _) => Tri::new(c, c, c + v(rng, 1.0)),
                (1, Some(&prev)) => prev,
                _ => Tri::new(c, c + v(rng, 1.0), c + v(rng, 1.0)),
            };
            tris.push(tri);
        }
        tris
    }

    /// A random ray towards the origin's neighbourhood and a `t_max` (∞ or 3).
    fn random_ray(rng: &mut Pcg64Mcg) -> (Ray, f32) {
        let o = v(rng, 4.0);
        let ray = Ray::new(o, (v(rng, 0.5) - o).normalize());
        (ray, if rng.random::<bool>() { f32::INFINITY } else { 3.0 })
    }

    /// The scalar test on each triangle in turn, as (triangle, t, b1, b2) bits.
    fn scalar_nearest(tris: &[Tri], ray: &Ray, t_max: f32) -> Option<(usize, u32, u32, u32)> {
        let mut want = None;
        let mut t_best = t_max;
        for (k, tri) in tris.iter().enumerate() {
            if let Some((t, b1, b2)) = tri_intersect(tri, ray, 1e-4, t_best) {
                t_best = t;
                want = Some((k, t, b1, b2));
            }
        }
        bits(want)
    }

    fn bits(h: Option<(usize, f32, f32, f32)>) -> Option<(usize, u32, u32, u32)> {
        h.map(|(k, t, b1, b2)| (k, t.to_bits(), b1.to_bits(), b2.to_bits()))
    }

    #[test]
    fn packet_test_equals_the_scalar_test_bit_for_bit() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let mut hits = 0;
        for _ in 0..20_000 {
            let n = 1 + (rng.random::<u32>() % 4) as usize;
            let tris = random_leaf(&mut rng, n);
            let (ray, t_max) = random_ray(&mut rng);
            let want = scalar_nearest(&tris, &ray, t_max);
            let got = packet_intersect(&Packet::new(&tris), &RayLanes::new(&ray), 1e-4, t_max);
            assert_eq!(bits(got), want, "{tris:?} {ray:?}");
            hits += want.is_some() as u32;
        }
        assert!(hits > 1000, "{hits}");
    }

    /// The AVX test of two packets finds what the scalar test of the eight triangles in turn
    /// finds, bit for bit (ties between equal triangles included); skipped without AVX.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn packet_pair_test_equals_the_scalar_test_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx") {
            eprintln!("no AVX: packet_pair_intersect not tested");
            return;
        }
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        let mut hits = [0u32; 2];
        for _ in 0..20_000 {
            let n = 5 + (rng.random::<u32>() % 4) as usize;
            let tris = random_leaf(&mut rng, n);
            let (ray, t_max) = random_ray(&mut rng);
            let want = scalar_nearest(&tris, &ray, t_max);
            let pair = PacketPair::new(&Packet::new(&tris[..4]), &Packet::new(&tris[4..]));
            // SAFETY: AVX was detected above.
            let got = unsafe { packet_pair_intersect(&pair, &ray, 1e-4, t_max) };
            assert_eq!(bits(got), want, "{tris:?} {ray:?}");
            if let Some((k, ..)) = want {
                hits[(k >= 4) as usize] += 1;
            }
        }
        assert!(hits[0] > 1000 && hits[1] > 1000, "hits in the first and second packet: {hits:?}");
    }

    #[test]
    fn bvh_equals_brute_force_on_random_triangles() {
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        // (count, spread of the centres): 5 to 8 overlapping triangles make one root leaf of
        // two packets (as the prism's), tested by a path of its own.
        for &(n, spread) in &[(1usize, 4.0), (3, 4.0), (5, 0.0), (8, 0.0), (8, 4.0), (40, 4.0), (2000, 4.0)] {
            let tris: Vec<[Vec3; 3]> = (0..n)
                .map(|_| {
                    let c = v(&mut rng, spread);
                    [c + v(&mut rng, 0.6), c + v(&mut rng, 0.6), c + v(&mut rng, 0.6)]
                })
                .collect();
            // With pairs where the processor has AVX, and the portable layout.
            let bvh = Bvh::build(&tris);
            let portable = Bvh::build_for(&tris, false);
            if spread == 0.0 {
                assert_eq!(bvh.root_leaf.map(|(_, c)| c as usize), Some(n), "one leaf");
            }
            let mut hits = 0;
            for k in 0..3000 {
                let o = v(&mut rng, 10.0);
                // Every other ray aimed near a triangle, so small sets are hit too.
                let [p, q, r] = tris[k % n];
                let target = if k % 2 == 0 { (p + q + r) / 3.0 + v(&mut rng, 0.1) } else { v(&mut rng, 3.0) };
                let ray = Ray::new(o, (target - o).normalize());
                let (a, b) =
                    (bvh.intersect(&ray, 1e-4, f32::INFINITY), brute_force(&tris, &ray, 1e-4, f32::INFINITY));
                // The packet tests equal the scalar test bit for bit: the same triangle, the same t.
                assert_eq!(a, b, "n = {n}: {ray:?}");
                assert_eq!(portable.intersect(&ray, 1e-4, f32::INFINITY), b, "n = {n}, portable: {ray:?}");
                hits += a.is_some() as u32;
            }
            assert!(hits > 300, "n = {n}: {hits} hits are too few to test anything");
        }
    }

    /// A ray that hits a triangle at t (the leaf test's value) enters the triangle's own box
    /// within t and passes the stack's test against t, so the traversal never skips the box of
    /// the nearest hit. Half the triangles lie in a plane z = const (a flat box, entered where
    /// the triangle is hit), the others anywhere.
    #[test]
    fn a_box_is_entered_wherever_its_triangle_is_hit() {
        let mut rng = Pcg64Mcg::seed_from_u64(13);
        let mut hits = 0;
        for k in 0..200_000 {
            let c = v(&mut rng, 8.0);
            let mut tri = [c + v(&mut rng, 1.0), c + v(&mut rng, 1.0), c + v(&mut rng, 1.0)];
            if k % 2 == 0 {
                tri.iter_mut().for_each(|p| p.z = c.z);
            }
            let (b1, b2) = (rng.random::<f32>(), rng.random::<f32>());
            let (b1, b2) = if b1 + b2 > 1.0 { (1.0 - b1, 1.0 - b2) } else { (b1, b2) };
            let target = tri[0] + (tri[1] - tri[0]) * b1 + (tri[2] - tri[0]) * b2;
            let o = v(&mut rng, 30.0);
            let ray = Ray::new(o, (target - o).normalize());
            // Not at grazing incidence (within about a degree of the plane), where the
            // triangle's own t carries an error beyond the margin (see `SLAB_SLACK`).
            let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            if normal.dot(ray.dir).abs() < 0.02 {
                continue;
            }
            let Some((t, _, _)) = tri_intersect(&Tri::new(tri[0], tri[1], tri[2]), &ray, 0.0, f32::INFINITY)
            else {
                continue;
            };
            let (lo, hi) = (tri[0].min(tri[1]).min(tri[2]), tri[0].max(tri[1]).max(tri[2]));
            let mut node = Node4 { bounds: [Vec4::ZERO; 6], child: [0; 4], count: [1, 0, 0, 0], used: 1 };
            for axis in 0..3 {
                node.bounds[axis][0] = lo[axis];
                node.bounds[3 + axis][0] = hi[axis];
            }
            let (near, mask) = Slabs::new(&ray).enter4(&node, 0.0, t);
            assert_eq!(mask, 1, "box not entered within t = {t}: {tri:?} {ray:?}");
            assert!(still_ahead(near.x, t), "entered at {} after the hit at {t}: {tri:?} {ray:?}", near.x);
            hits += 1;
        }
        assert!(hits > 100_000, "{hits}");
    }

    /// The traversal never has more children pending than `stack_need` (three per level): run
    /// with a stack of exactly that many entries (on the heap, as for a tree deeper than the
    /// inline stack allows), a push past it would panic; and the hits equal brute force.
    #[test]
    fn the_traversal_stack_bound_holds() {
        let mut rng = Pcg64Mcg::seed_from_u64(17);
        for n in [40usize, 3000] {
            let tris: Vec<[Vec3; 3]> = (0..n)
                .map(|_| {
                    let c = v(&mut rng, 4.0);
                    [c + v(&mut rng, 0.6), c + v(&mut rng, 0.6), c + v(&mut rng, 0.6)]
                })
                .collect();
            let bvh = Bvh::build(&tris);
            assert!(bvh.stack_need >= 3 && bvh.stack_need.is_multiple_of(3), "{}", bvh.stack_need);
            let mut hits = 0;
            for _ in 0..3000 {
                let o = v(&mut rng, 10.0);
                let ray = Ray::new(o, (v(&mut rng, 3.0) - o).normalize());
                let mut stack = vec![MaybeUninit::uninit(); bvh.stack_need];
                let a = bvh.traverse_with(&mut stack, &ray, 1e-4, f32::INFINITY);
                assert_eq!(a, brute_force(&tris, &ray, 1e-4, f32::INFINITY), "n = {n}: {ray:?}");
                hits += a.is_some() as u32;
            }
            assert!(hits > 150, "n = {n}: {hits}");
        }
    }

    /// The single-box test: entry distance, misses, and rays parallel to a slab lying in a
    /// bound's plane (with +0 and −0 direction components), inside and just outside.
    #[test]
    fn ray_box_enters_where_a_closed_box_is_met() {
        let (lo, hi) = (Vec3::ZERO, Vec3::ONE);
        let hit = |o: Vec3, d: Vec3| ray_box(lo, hi, o, d.recip(), 0.0, f32::INFINITY);
        assert_eq!(hit(Vec3::new(0.5, 0.5, 5.0), Vec3::NEG_Z), Some(4.0));
        assert_eq!(hit(Vec3::new(0.5, 0.5, 5.0), Vec3::Z), None);
        assert_eq!(hit(Vec3::new(0.5, 0.5, 0.5), Vec3::Z), Some(0.0));
        for x in [0.0, 1.0] {
            for sign in [0.0f32, -0.0] {
                for (y, want) in [(0.0, Some(4.0)), (0.5, Some(4.0)), (1.0, Some(4.0)), (1.0001, None)] {
                    let (o, d) = (Vec3::new(x, y, 5.0), Vec3::new(sign, sign, -1.0));
                    assert_eq!(hit(o, d), want, "{o:?} {d:?}");
                }
            }
        }
    }

    #[test]
    fn bvh_handles_axis_aligned_rays_and_coincident_centroids() {
        // A grid of floor triangles hit by rays straight down (zero direction components).
        let mut tris = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let p = Vec3::new(i as f32, j as f32, 0.0);
                tris.push([p, p + Vec3::X, p + Vec3::Y]);
                tris.push([p + Vec3::X, p + Vec3::X + Vec3::Y, p + Vec3::Y]);
            }
        }
        // Many copies of one triangle: centroids coincide, the build must still terminate.
        tris.extend(std::iter::repeat_n(
            [Vec3::splat(30.0), Vec3::new(31.0, 30.0, 30.0), Vec3::new(30.0, 31.0, 30.0)],
            50,
        ));
        let bvh = Bvh::build(&tris);
        for k in 0..200 {
            let ray = Ray::new(Vec3::new(0.05 + k as f32 * 0.097, 0.03 + k as f32 * 0.093, 5.0), Vec3::NEG_Z);
            let (a, b) =
                (bvh.intersect(&ray, 0.0, f32::INFINITY), brute_force(&tris, &ray, 0.0, f32::INFINITY));
            assert_eq!(a.map(|h| h.t), b.map(|h| h.t));
            assert!(a.is_some());
        }
        let ray = Ray::new(Vec3::new(30.2, 30.2, 40.0), Vec3::NEG_Z);
        assert!((bvh.intersect(&ray, 0.0, f32::INFINITY).unwrap().t - 10.0).abs() < 1e-5);
        // Rays parallel to the x slabs lying exactly in a box's bound plane (x = 0, the grid's
        // left edge; 7, between columns; 20, its right edge), with +0 and −0 as x direction:
        // the triangles' edges there are hit exactly (their frames are exact), so each such
        // ray hits, and the boxes must let it through on either side.
        for x in [0.0, 7.0, 20.0] {
            for sign in [0.0f32, -0.0] {
                for j in 0..20 {
                    let ray =
                        Ray { origin: Vec3::new(x, j as f32 + 0.5, 5.0), dir: Vec3::new(sign, 0.0, -1.0) };
                    let (a, b) = (
                        bvh.intersect(&ray, 0.0, f32::INFINITY),
                        brute_force(&tris, &ray, 0.0, f32::INFINITY),
                    );
                    assert!(b.is_some(), "{ray:?}");
                    assert_eq!(a.map(|h| h.t), b.map(|h| h.t), "{ray:?}");
                }
            }
        }
    }
}
