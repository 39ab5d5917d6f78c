//! The k-nearest-neighbour index every stage searches photons through.
//!
//! Feature detection (Eq. 1–7) and the first half of relaxation (Eq. 8–9) need the photons
//! nearest another by **world-space** distance among only those whose **trajectory
//! parameters** lie within a radius of the query's, and of the same emitter; density
//! estimation in parameter space needs the nearest by parameter distance alone; after
//! collapse, relaxation and the world-space baselines need plain world-space neighbours.
//! One [`SpatialIndex`] serves all three, chosen by its [`Space`]:
//!
//! | space | distance | restriction | emitters |
//! | --- | --- | --- | --- |
//! | [`Space::World`] | x, y, z | none (a query's radius is ignored) | all together |
//! | [`Space::WorldParams`] | x, y, z | params within the query's radius | separate |
//! | [`Space::Params`] | params | none | separate |
//!
//! Parameter distances are Euclidean in the `params` column's coordinates: for a
//! `rect_uv` emitter the (u, v) square, for a `direction` emitter the unit sphere embedded
//! in 3-D, where the Euclidean distance is the *chord* 2·sin(θ/2) of the angle θ between
//! two directions (within 1 % of θ for θ < 0.5 rad, and seam-free).
//!
//! Each emitter's photons go into their own compact kd-tree over {x, y, z, params}
//! (`kdtree/`), which does the parameter-space range test inside the traversal; the
//! choice against kiddo with over-fetch and filter was made by measurement (BENCHMARKS.md,
//! "Spatial index"). Results are exact and deterministic: the k smallest by (distance²,
//! photon index), equal to [`brute_force_knn`] bit for bit.
//!
//! Relaxation builds the index on its first iteration and then refits it to the moved photons
//! ([`SpatialIndex::refit`]), rebuilding it instead every 7 iterations
//! ([`crate::relax::REBUILD_EVERY`]) and after one that moved coincident photons apart
//! ([`crate::relax::index_positions`]). [`SpatialIndex::rebuild`] reuses its allocations, and
//! [`Neighbours`] is a reusable result buffer (one per worker thread).
//!
//! ```
//! use photonkit::spatial::{Neighbours, PointSet, SpatialIndex, Space};
//! let positions = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.1, 0.0, 0.0]];
//! let points = PointSet::world(&positions);
//! let index = SpatialIndex::build(&points, Space::World).unwrap();
//! let mut out = Neighbours::default();
//! index.knn(&points.query(0, None), 2, &mut out);
//! assert_eq!(out.indices().collect::<Vec<_>>(), [0, 2]);
//! ```

pub mod boxtree;
mod brute;
mod kdtree;
pub mod order;

pub use boxtree::BoxTree;
pub use brute::brute_force_knn;

use kdtree::{KdTree, Rec};

/// Asks the CPU to start loading `x` into cache. Stages loop over photons in the index's
/// order while their per-photon arrays are in another (Z-order, [`order`]: near, but not
/// the same), so a photon's own data can be a cache miss; prefetching the photon a few
/// places ahead hides it. A no-op off x86-64.
#[inline(always)]
pub fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint; it never faults and reads nothing into the program.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((x as *const T).cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// How many photons ahead the stages prefetch (see [`prefetch`]).
pub const PREFETCH_AHEAD: usize = 4;

/// Which distance a [`SpatialIndex`] measures and which restriction it honours.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Space {
    /// World-space distance over every photon; parameters and emitters play no part
    /// (after collapse, and for the world-space methods).
    World,
    /// World-space distance among photons of the query's emitter whose parameters lie
    /// within the query's radius (feature detection, relaxation before collapse).
    WorldParams,
    /// Parameter-space distance among photons of the query's emitter (density, Eq. 1).
    Params,
}

/// The `params` column as the index reads it.
#[derive(Clone, Copy, Debug)]
pub struct ParamColumn<'a> {
    /// `stride` values per photon.
    pub values: &'a [f32],
    /// Components per photon in `values` (the column's component count).
    pub stride: usize,
    /// How many leading components emitter `e` uses, at `dims[e]` (its `param_dims`);
    /// emitters beyond the slice use all `stride`. 0 means the emitter has no parameters:
    /// its photons are searched by world distance alone.
    pub dims: &'a [u32],
}

impl ParamColumn<'_> {
    /// Number of parameter components photons of `emitter` use.
    pub fn dims_of(&self, emitter: u16) -> usize {
        self.dims.get(emitter as usize).map_or(self.stride, |&d| (d as usize).min(self.stride))
    }

    /// A copy of the values with component c of a photon of emitter e (`emitters[i]`, or 0
    /// without them) multiplied by `factors[e][c]`: a weighted Euclidean distance (a
    /// wavelength's scale, docs/spectral.md) searched as a plain one. Components past an
    /// emitter's factors are unchanged.
    pub fn scaled(&self, emitters: Option<&[u16]>, factors: &[Vec<f32>]) -> Vec<f32> {
        let mut out = self.values.to_vec();
        for (i, q) in out.chunks_exact_mut(self.stride.max(1)).enumerate() {
            let e = emitters.map_or(0, |pe| pe[i] as usize);
            if let Some(f) = factors.get(e) {
                q.iter_mut().zip(f).for_each(|(x, f)| *x *= f);
            }
        }
        out
    }
}

/// The split scale ([`SpatialIndex::build_split`]) for searches of the `k` nearest photons
/// within parameter balls of radii `radii`: the world radius that holds k photons at the local
/// spacing, per unit of the balls' median radius. A ball much wider in its units than the
/// world neighbourhood it restricts then counts as wide as that neighbourhood when a tree
/// chooses its split axes. `positions` are in a locality order (Z-order), and the local spacing
/// is the median distance between photons next to each other in it, mostly neighbours: unlike
/// a mean spacing over the map's box it does not count the box's empty parts. Both medians are
/// over about 4096 evenly spread samples; `None` when either has no positive finite sample.
pub fn ball_split_scale(positions: &[[f32; 3]], radii: &[f32], k: usize) -> Option<f32> {
    let spacing: Vec<f32> = positions
        .windows(2)
        .step_by(positions.len().div_ceil(4096).max(1))
        .map(|w| glam::Vec3::from(w[0]).distance(glam::Vec3::from(w[1])))
        .collect();
    let radius: Vec<f32> = radii.iter().step_by(radii.len().div_ceil(4096).max(1)).copied().collect();
    Some(median_positive(spacing)? * (k as f32 / std::f32::consts::PI).sqrt() / median_positive(radius)?)
}

/// The median of the positive, finite values of `v`.
fn median_positive(mut v: Vec<f32>) -> Option<f32> {
    v.retain(|&x| x > 0.0 && x.is_finite());
    let mid = v.len() / 2;
    (!v.is_empty()).then(|| *v.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The photons an index is built over: positions, and optionally trajectory parameters and
/// emitter ids (photon `i` is at `positions[i]`).
#[derive(Clone, Copy, Debug)]
pub struct PointSet<'a> {
    /// Photon positions, metres.
    pub positions: &'a [[f32; 3]],
    /// Trajectory parameters, for [`Space::WorldParams`] and [`Space::Params`].
    pub params: Option<ParamColumn<'a>>,
    /// Emitter id per photon; `None` puts every photon in emitter 0.
    pub emitters: Option<&'a [u16]>,
}

impl<'a> PointSet<'a> {
    /// Positions only.
    pub fn world(positions: &'a [[f32; 3]]) -> Self {
        PointSet { positions, params: None, emitters: None }
    }

    /// Number of photons.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The emitter of photon `i`.
    pub fn emitter(&self, i: usize) -> u16 {
        self.emitters.map_or(0, |e| e[i])
    }

    /// The trajectory parameters photon `i`'s emitter uses (empty without parameters).
    pub fn params_of(&self, i: usize) -> &'a [f32] {
        match self.params {
            Some(p) => {
                let d = p.dims_of(self.emitter(i));
                &p.values[i * p.stride..i * p.stride + d]
            }
            None => &[],
        }
    }

    /// Prefetches photon `i`'s position and parameters ([`prefetch`]).
    #[inline(always)]
    pub fn prefetch(&self, i: usize) {
        if let Some(x) = self.positions.get(i) {
            prefetch(x);
        }
        if let Some(p) = self.params
            && let Some(v) = p.values.get(i * p.stride)
        {
            prefetch(v);
        }
        if let Some(e) = self.emitters.and_then(|e| e.get(i)) {
            prefetch(e);
        }
    }

    /// The query "neighbours of photon `i`" with parameter radius `radius` (photon `i`
    /// itself is among the results; set [`Query::exclude`] to leave it out).
    pub fn query(&self, i: usize, radius: Option<f32>) -> Query<'a> {
        Query {
            position: self.positions[i],
            params: self.params_of(i),
            radius,
            emitter: self.emitter(i),
            exclude: None,
        }
    }

    pub(crate) fn check(&self, space: Space) -> Result<(), SpatialError> {
        let n = self.positions.len();
        if n >= u32::MAX as usize {
            return Err(SpatialError::TooMany { count: n });
        }
        if let Some(e) = self.emitters
            && e.len() != n
        {
            return Err(SpatialError::Length { what: "emitters", expected: n, actual: e.len() });
        }
        if let Some(p) = self.params {
            let expected = n.saturating_mul(p.stride);
            if p.values.len() != expected {
                return Err(SpatialError::Length { what: "params", expected, actual: p.values.len() });
            }
        }
        if let Some(i) = self.positions.iter().position(|x| x.iter().any(|c| !c.is_finite())) {
            return Err(SpatialError::NonFinite { index: i, what: "position" });
        }
        if space != Space::World && self.params.is_some() {
            for i in 0..n {
                let p = self.params_of(i);
                if p.len() > MAX_PARAM_DIMS {
                    return Err(SpatialError::ParamDims { emitter: self.emitter(i), dims: p.len() });
                }
                if p.iter().any(|c| !c.is_finite()) {
                    return Err(SpatialError::NonFinite { index: i, what: "params" });
                }
            }
        }
        Ok(())
    }
}

/// Most parameter dimensions an emitter may use (the sphere embedded in 3-D, and a wavelength).
pub const MAX_PARAM_DIMS: usize = 4;

/// One k-NN request.
#[derive(Clone, Copy, Debug)]
pub struct Query<'a> {
    /// World position (the distance in [`Space::World`] and [`Space::WorldParams`]).
    pub position: [f32; 3],
    /// Trajectory parameters: the ball's centre in [`Space::WorldParams`], the point whose
    /// distance counts in [`Space::Params`]. Needs at least the emitter's dimensions.
    pub params: &'a [f32],
    /// Parameter-space radius (inclusive) in [`Space::WorldParams`]; `None` for no limit.
    /// A negative or NaN radius admits no photon. Ignored in the other spaces and for
    /// emitters without parameters.
    pub radius: Option<f32>,
    /// Only photons of this emitter are candidates (except in [`Space::World`]).
    pub emitter: u16,
    /// A photon never returned (e.g. the query photon itself, for relaxation).
    pub exclude: Option<u32>,
}

/// One neighbour found: its squared distance in the index's space and its photon index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    /// Squared distance to the query, in the index's space.
    pub dist2: f32,
    /// The photon's index in the [`PointSet`].
    pub index: u32,
}

impl Neighbour {
    /// The order results are ranked by: distance², then photon index (the tie-break).
    #[inline(always)]
    pub fn before(&self, o: &Neighbour) -> bool {
        self.dist2 < o.dist2 || (self.dist2 == o.dist2 && self.index < o.index)
    }
}

/// A reusable result buffer: after a query, the neighbours nearest first, with their
/// coordinates. Reusing one buffer for successive queries over the same index (in the index's
/// [`SpatialIndex::order`], as every stage does) also speeds the next query: the last result
/// gives it a starting bound (see [`SpatialIndex::knn`]).
#[derive(Clone, Debug)]
pub struct Neighbours {
    items: Vec<Neighbour>,
    /// How many neighbours the last result found: `items.len()`, except in a buffer made
    /// [`Self::farthest_only`], whose `items` stay empty.
    found: usize,
    /// The largest distance² found (meaningless when none was).
    far2: f32,
    /// The neighbours' coordinates in the tree's distance space, padded to three.
    coords: Vec<[f32; 3]>,
    /// The neighbours' places in the tree that answered, which `tree` identifies (0: none).
    slots: Vec<u32>,
    /// The tree build that answered (0: none).
    tree: u64,
    /// Candidate buffer of the search.
    cands: Vec<kdtree::Cand>,
    /// Candidates of a query answered from its group (scratch, only ever lengthened: see
    /// `KdTree::scan_group`).
    scanned: Vec<kdtree::Cand>,
    /// Candidates gathered for the queries of one leaf.
    group: kdtree::Group,
    /// Whether results are sorted (see [`Self::unordered`]).
    ordered: bool,
    /// Whether results carry coordinates (see [`Self::without_coords`]).
    with_coords: bool,
    /// Whether results are only the count and the farthest distance (see
    /// [`Self::farthest_only`]).
    farthest_only: bool,
    /// Queries answered from a group's candidates (for tests and tuning).
    pub(crate) group_answers: u64,
    /// Records whose distance the queries computed (for tests: the work of a search).
    pub(crate) records_scanned: u64,
}

impl Default for Neighbours {
    fn default() -> Self {
        Neighbours::with_capacity(0)
    }
}

impl Neighbours {
    /// An ordered buffer with coordinates, with room for `k` neighbours.
    pub fn with_capacity(k: usize) -> Self {
        Neighbours {
            items: Vec::with_capacity(k),
            found: 0,
            far2: 0.0,
            coords: Vec::with_capacity(k),
            slots: Vec::with_capacity(k),
            tree: 0,
            cands: Vec::with_capacity(2 * k),
            scanned: Vec::new(),
            group: Default::default(),
            ordered: true,
            with_coords: true,
            farthest_only: false,
            group_answers: 0,
            records_scanned: 0,
        }
    }

    /// A buffer whose results are the same neighbours in no particular order (deterministic
    /// for a given sequence of queries on one buffer), which saves sorting them: for callers
    /// that need only the set or the farthest ([`Self::max_dist2`]).
    pub fn unordered(k: usize) -> Self {
        Neighbours { ordered: false, ..Neighbours::with_capacity(k) }
    }

    /// The same buffer, but its results leave [`Self::coords`] empty: for callers that need
    /// only the neighbours' distances or indices (it saves copying k coordinates per query).
    pub fn without_coords(self) -> Self {
        Neighbours { with_coords: false, ..self }
    }

    /// A buffer whose results are only how many neighbours were found ([`Self::len`]) and
    /// the farthest one's distance ([`Self::max_dist2`]); the neighbours themselves
    /// ([`Self::as_slice`], [`Self::indices`], [`Self::coords`]) are left empty. For the
    /// density of Eq. 1, which needs only the k-th distance: a query answered from its group
    /// then finds it without moving the k nearest together or writing them out.
    pub fn farthest_only(k: usize) -> Self {
        Neighbours { farthest_only: true, ..Neighbours::unordered(k).without_coords() }
    }

    /// The largest squared distance found (the k-th nearest's when k were found).
    pub fn max_dist2(&self) -> Option<f32> {
        (self.found > 0).then_some(self.far2)
    }

    /// The neighbours found, nearest first in an ordered buffer.
    pub fn as_slice(&self) -> &[Neighbour] {
        &self.items
    }

    /// How many neighbours were found (also in a buffer made [`Self::farthest_only`]).
    pub fn len(&self) -> usize {
        self.found
    }

    /// Whether none was found.
    pub fn is_empty(&self) -> bool {
        self.found == 0
    }

    /// The neighbours' photon indices, in the order of [`Self::as_slice`].
    pub fn indices(&self) -> impl ExactSizeIterator<Item = u32> + '_ {
        self.items.iter().map(|n| n.index)
    }

    /// The neighbours' coordinates in the index's distance space, in the order of
    /// [`Self::as_slice`]: their world positions in [`Space::World`] and [`Space::WorldParams`]
    /// (the index's copy, already in cache: cheaper than looking photons up by index), their
    /// parameters (zero-padded) in [`Space::Params`]. Empty after a [`BoxTree`] query, and
    /// for a buffer made [`Self::without_coords`].
    pub fn coords(&self) -> &[[f32; 3]] {
        &self.coords
    }

    /// The farthest neighbour found (the k-th when k were found) of an ordered buffer.
    pub fn last(&self) -> Option<Neighbour> {
        self.items.last().copied()
    }

    /// Forgets the last result and any gathered candidates: the next queries then run as on a
    /// fresh buffer (the same results, in the same order, whatever came before).
    pub fn forget(&mut self) {
        self.clear();
        self.group.forget();
    }

    /// Empties the buffer and forgets the last result.
    fn clear(&mut self) {
        self.items.clear();
        self.found = 0;
        self.coords.clear();
        self.slots.clear();
        self.tree = 0;
    }
}

/// What can be wrong with the points an index is asked to hold.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SpatialError {
    /// A NaN or infinite position or parameter.
    #[error("photon {index} has a non-finite {what}")]
    NonFinite {
        /// The photon's index (0-based).
        index: usize,
        /// `position` or `params`.
        what: &'static str,
    },
    /// An emitter with more parameter dimensions than an index holds.
    #[error("emitter {emitter} uses {dims} parameter dimensions; at most {MAX_PARAM_DIMS} are supported")]
    ParamDims {
        /// The emitter's id.
        emitter: u16,
        /// Its parameter dimensions.
        dims: usize,
    },
    /// More photons than a `u32` index numbers.
    #[error("{count} photons: an index holds fewer than 2³² − 1")]
    TooMany {
        /// The photons given.
        count: usize,
    },
    /// A column whose length does not match the positions'.
    #[error("the {what} slice holds {actual} values, expected {expected}")]
    Length {
        /// `emitters` or `params`.
        what: &'static str,
        /// Values it should hold.
        expected: usize,
        /// Values it holds.
        actual: usize,
    },
}

/// One emitter's (or, in world space, every photon's) tree, by shape: `D` distance
/// dimensions and `B` ball dimensions.
#[derive(Clone, Debug)]
enum Tree {
    /// No dimensions to search (an emitter without parameters in [`Space::Params`]): its
    /// photons, which are never anyone's neighbours.
    Empty(Vec<u32>),
    D1(KdTree<1, 0>),
    D2(KdTree<2, 0>),
    D3(KdTree<3, 0>),
    D4(KdTree<4, 0>),
    D3B1(KdTree<3, 1>),
    D3B2(KdTree<3, 2>),
    D3B3(KdTree<3, 3>),
    D3B4(KdTree<3, 4>),
}

impl Tree {
    fn order(&self) -> Box<dyn Iterator<Item = u32> + '_> {
        match self {
            Tree::Empty(v) => Box::new(v.iter().copied()),
            Tree::D1(t) => Box::new(t.order()),
            Tree::D2(t) => Box::new(t.order()),
            Tree::D3(t) => Box::new(t.order()),
            Tree::D4(t) => Box::new(t.order()),
            Tree::D3B1(t) => Box::new(t.order()),
            Tree::D3B2(t) => Box::new(t.order()),
            Tree::D3B3(t) => Box::new(t.order()),
            Tree::D3B4(t) => Box::new(t.order()),
        }
    }
}

/// Exact k-NN over a photon set in one [`Space`]; see the module docs.
#[derive(Clone, Debug)]
pub struct SpatialIndex {
    space: Space,
    len: usize,
    /// Tree of each emitter id (`usize::MAX`: no photons).
    tree_of: Vec<usize>,
    trees: Vec<Tree>,
    /// Scratch for grouping photons by emitter, kept for rebuilds.
    members: Vec<u32>,
    /// The world length one unit of the parameter ball weighs as when a tree chooses its split
    /// axes ([`SpatialIndex::build_split`]); `None`: each group's extent normalised.
    split_scale: Option<f32>,
}

impl SpatialIndex {
    /// Builds the index over `points` in `space`.
    pub fn build(points: &PointSet, space: Space) -> Result<Self, SpatialError> {
        Self::build_split(points, space, None)
    }

    /// [`SpatialIndex::build`], with the trees choosing their split axes as if one unit of
    /// the parameter ball were `split_scale` in world space: for a ball much wider than the
    /// neighbourhoods it restricts (relaxation's spectral window), the trees then cut the
    /// parameters into slabs about a ball wide and the world into cells about a neighbourhood
    /// wide, so a query visits few cells. Only the speed depends on it; every search's result
    /// is the same.
    pub fn build_split(
        points: &PointSet,
        space: Space,
        split_scale: Option<f32>,
    ) -> Result<Self, SpatialError> {
        let mut index = SpatialIndex {
            space,
            len: 0,
            tree_of: Vec::new(),
            trees: Vec::new(),
            members: Vec::new(),
            split_scale,
        };
        index.rebuild(points)?;
        Ok(index)
    }

    /// Rebuilds over new points (moved photons) in the same space, reusing allocations.
    pub fn rebuild(&mut self, points: &PointSet) -> Result<(), SpatialError> {
        points.check(self.space)?;
        let n = points.len();
        self.len = n;
        // Group photon indices by emitter with a counting sort (world space: one group).
        let by_emitter = self.space != Space::World;
        let groups = if by_emitter {
            points.emitters.map_or(1, |e| e.iter().max().map_or(1, |&m| m as usize + 1))
        } else {
            1
        };
        let mut start = vec![0usize; groups + 1];
        for i in 0..n {
            let g = if by_emitter { points.emitter(i) as usize } else { 0 };
            start[g + 1] += 1;
        }
        for g in 0..groups {
            start[g + 1] += start[g];
        }
        self.members.clear();
        self.members.resize(n, 0);
        let mut fill = start.clone();
        for i in 0..n {
            let g = if by_emitter { points.emitter(i) as usize } else { 0 };
            self.members[fill[g]] = i as u32;
            fill[g] += 1;
        }
        let mut old: Vec<Tree> = std::mem::take(&mut self.trees);
        old.reverse();
        self.tree_of.clear();
        self.tree_of.resize(groups, usize::MAX);
        for g in 0..groups {
            let members = &self.members[start[g]..start[g + 1]];
            if members.is_empty() {
                continue;
            }
            let emitter = g as u16;
            let dims = points.params.map_or(0, |p| p.dims_of(emitter));
            let weights = self.split_scale.map(|p| kdtree::Weights { w: 1.0, p });
            let tree = build_tree(self.space, dims, points, members, old.pop(), weights);
            self.tree_of[g] = self.trees.len();
            self.trees.push(tree);
        }
        Ok(())
    }

    /// Moves the indexed photons to `points`' positions: the same photons (count, emitters,
    /// parameters) as the last build, with only their positions changed, as relaxation
    /// changes them. The trees keep their shape and recompute their boxes (cheaper than
    /// [`Self::rebuild`]; queries stay exact but slow down as photons drift from where the
    /// trees were built). In [`Space::Params`], where positions are not indexed, nothing changes.
    pub fn refit(&mut self, points: &PointSet) -> Result<(), SpatialError> {
        points.check(self.space)?;
        if points.len() != self.len {
            return Err(SpatialError::Length { what: "positions", expected: self.len, actual: points.len() });
        }
        if self.space == Space::Params {
            return Ok(());
        }
        let pos = points.positions;
        for t in &mut self.trees {
            match t {
                Tree::D3(t) => t.refit(|i| pos[i as usize]),
                Tree::D3B1(t) => t.refit(|i| pos[i as usize]),
                Tree::D3B2(t) => t.refit(|i| pos[i as usize]),
                Tree::D3B3(t) => t.refit(|i| pos[i as usize]),
                Tree::D3B4(t) => t.refit(|i| pos[i as usize]),
                Tree::Empty(_) | Tree::D1(_) | Tree::D2(_) | Tree::D4(_) => {}
            }
        }
        Ok(())
    }

    /// The distance this index measures.
    pub fn space(&self) -> Space {
        self.space
    }

    /// Number of photons indexed.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no photon.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Every photon index once, in the trees' leaf order: looping over photons in this
    /// order keeps successive queries in nearby memory (much faster than index order).
    pub fn order(&self) -> Vec<u32> {
        let mut v = Vec::with_capacity(self.len);
        for t in &self.trees {
            v.extend(t.order());
        }
        v
    }

    /// The `k` photons nearest `q` by this index's distance, among its candidates (module
    /// docs), nearest first, ties by photon index; fewer when fewer candidates exist.
    ///
    /// When `out` holds the previous result of a query on the same emitter's tree, the search
    /// starts with a bound: the k-th distance from `q` to those earlier neighbours that are
    /// candidates of `q` (an upper bound on `q`'s k-th, since they are k candidates). Results
    /// are the same with or without it; successive queries nearby (the index's order) are
    /// faster.
    ///
    /// # Panics
    /// If `q.params` holds fewer values than the query emitter's parameter dimensions.
    pub fn knn(&self, q: &Query, k: usize, out: &mut Neighbours) {
        let g = if self.space == Space::World { 0 } else { q.emitter as usize };
        let Some(&t) = self.tree_of.get(g).filter(|&&t| t != usize::MAX) else { return out.clear() };
        let radius = match q.radius {
            Some(r) if r.is_nan() || r < 0.0 => return out.clear(),
            r => r.map(|r| r * r),
        };
        fn arr<const N: usize>(s: &[f32]) -> [f32; N] {
            assert!(s.len() >= N, "the query has {} parameters; its emitter uses {N}", s.len());
            std::array::from_fn(|i| s[i])
        }
        let pos = &q.position;
        match (&self.trees[t], self.space) {
            (Tree::Empty(_), _) => out.clear(),
            (Tree::D3(tree), Space::World | Space::WorldParams) => {
                tree.knn(pos, &[], None, q.exclude, k, out)
            }
            (Tree::D3B1(tree), _) => tree.knn(pos, &arr(q.params), radius, q.exclude, k, out),
            (Tree::D3B2(tree), _) => tree.knn(pos, &arr(q.params), radius, q.exclude, k, out),
            (Tree::D3B3(tree), _) => tree.knn(pos, &arr(q.params), radius, q.exclude, k, out),
            (Tree::D3B4(tree), _) => tree.knn(pos, &arr(q.params), radius, q.exclude, k, out),
            (Tree::D1(tree), _) => tree.knn(&arr(q.params), &[], None, q.exclude, k, out),
            (Tree::D2(tree), _) => tree.knn(&arr(q.params), &[], None, q.exclude, k, out),
            (Tree::D3(tree), Space::Params) => tree.knn(&arr(q.params), &[], None, q.exclude, k, out),
            (Tree::D4(tree), _) => tree.knn(&arr(q.params), &[], None, q.exclude, k, out),
        }
    }
}

fn build_tree(
    space: Space,
    dims: usize,
    points: &PointSet,
    members: &[u32],
    old: Option<Tree>,
    weights: Option<kdtree::Weights>,
) -> Tree {
    let pos = points.positions;
    let par = |i: u32| points.params_of(i as usize);
    fn take<const W: usize, const P: usize>(
        old: Option<Tree>,
        pick: fn(Tree) -> Option<KdTree<W, P>>,
    ) -> KdTree<W, P> {
        old.and_then(pick).unwrap_or_default()
    }
    macro_rules! tree {
        ($variant:ident, $w:literal, $p:literal, |$i:ident| $wc:expr, $pc:expr) => {{
            let mut t: KdTree<$w, $p> = take(old, |o| if let Tree::$variant(t) = o { Some(t) } else { None });
            t.rebuild(
                |recs| {
                    recs.extend(members.iter().map(|&$i| Rec {
                        w: $wc,
                        p: std::array::from_fn(|a| $pc[a]),
                        idx: $i,
                    }))
                },
                weights,
            );
            Tree::$variant(t)
        }};
    }
    match (space, dims) {
        (Space::World, _) | (Space::WorldParams, 0) => tree!(D3, 3, 0, |i| pos[i as usize], [0.0f32; 0]),
        (Space::WorldParams, 1) => tree!(D3B1, 3, 1, |i| pos[i as usize], par(i)),
        (Space::WorldParams, 2) => tree!(D3B2, 3, 2, |i| pos[i as usize], par(i)),
        (Space::WorldParams, 3) => tree!(D3B3, 3, 3, |i| pos[i as usize], par(i)),
        (Space::WorldParams, _) => tree!(D3B4, 3, 4, |i| pos[i as usize], par(i)),
        (Space::Params, 0) => Tree::Empty(members.to_vec()),
        (Space::Params, 1) => tree!(D1, 1, 0, |i| std::array::from_fn(|a| par(i)[a]), [0.0f32; 0]),
        (Space::Params, 2) => tree!(D2, 2, 0, |i| std::array::from_fn(|a| par(i)[a]), [0.0f32; 0]),
        (Space::Params, 3) => tree!(D3, 3, 0, |i| std::array::from_fn(|a| par(i)[a]), [0.0f32; 0]),
        (Space::Params, _) => tree!(D4, 4, 0, |i| std::array::from_fn(|a| par(i)[a]), [0.0f32; 0]),
    }
}

#[cfg(test)]
mod tests;
