//! The closest-hit traversal of the four-wide tree: slab tests of four boxes at once,
//! children visited nearest first from a stack, and each leaf's triangles tested by packet.

use std::mem::MaybeUninit;

use glam::{Vec3, Vec4};

#[cfg(target_arch = "x86_64")]
use super::MAX_LEAF;
#[cfg(target_arch = "x86_64")]
use super::simd::packet_pair_intersect;
use super::simd::{RayLanes, packet_intersect};
use super::{Bvh, Node4, TriHit};
use crate::scene::shape::Ray;

/// A child still to visit: its lane's `child` and `count` and the ray's entry distance into
/// its box.
#[derive(Clone, Copy)]
pub(super) struct Pending {
    child: u32,
    count: u32,
    near: f32,
}

/// Pending children the traversal keeps on the call stack; a tree that may need more (deeper
/// than 64 levels, which no sample scene comes near) gets a stack on the heap per ray.
const INLINE_STACK: usize = 3 * 64;

impl Bvh {
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
    pub(super) fn traverse_with(
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
pub(super) struct Slabs {
    o: [Vec4; 3],
    inv: [Vec4; 3],
    /// Axes along which the direction is zero (or so small that its inverse is infinite).
    parallel: [bool; 3],
}

impl Slabs {
    #[inline(always)]
    pub(super) fn new(ray: &Ray) -> Slabs {
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
    pub(super) fn enter4(&self, node: &Node4, t_min: f32, t_max: f32) -> (Vec4, u32) {
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
pub(super) fn still_ahead(near: f32, t_best: f32) -> bool {
    near <= t_best * SLAB_SLACK
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
