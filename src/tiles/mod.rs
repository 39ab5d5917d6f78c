//! Spatial tiles with halos: a map cut into axis-aligned cells of its world-space bounding box,
//! each processed with the photons around it, so that a stage can run tile by tile (or tile
//! per machine) and give each photon exactly the result it gets from the whole map
//! (docs/tiles.md; [`crate::detect::detect_tile`]).
//!
//! A [`Tiling`] is nx × ny cells over the two longest axes of the map's box, balanced: the
//! first axis is cut at the nx-quantiles of the photons' coordinates (columns), then each
//! column's second axis at the ny-quantiles of its own photons (rows), so every tile holds about
//! n/(nx·ny) photons. A cut is a photon's coordinate; cell k of an axis spans [b_k, b_{k+1})
//! (the last one closed), so a photon exactly on a cut belongs to one tile only, the upper one.
//! A [`HaloBox`] is a tile's cell grown by a halo width on each side; the [`HaloBox::margin`]
//! of a photon inside the cell bounds from below the distance to any photon outside the grown
//! box, which is what a stage's certificate compares its search radius with.
//!
//! ```
//! use photonkit::tiles::{TileSpec, Tiling};
//! let positions = [[0.0f32, 0.0, 0.0], [0.5, 0.2, 0.0], [1.0, 1.0, 0.0]];
//! let spec: TileSpec = "1/2".parse().unwrap();
//! let tiling = Tiling::new(&positions, spec.grid());
//! // The cut is the median x, 0.5: the photon on it is in the upper tile.
//! let tiles: Vec<usize> = positions.iter().map(|&x| tiling.tile_of(x)).collect();
//! assert_eq!(tiles, [0, 1, 1]);
//! ```

use std::str::FromStr;

mod budget;
mod cells;
mod part;

pub use budget::{
    BudgetTooSmall, MIN_TILE_PHOTONS, MemoryModel, resident_bytes, tiles_for_budget, tiling_beside,
    tiling_for_budget,
};
pub use cells::{Buckets, TileCell, TilePhotons, gather_cells};
pub use part::{ExactSum, PartRecord, part_columns, part_record, part_report, position_crc};

/// What can be wrong with a tile request.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TileError {
    /// A `--tile` value that is not `i/n` with 0 ≤ i < n.
    #[error("'{spec}': {message}")]
    Spec {
        /// The value as given.
        spec: String,
        /// What is wrong with it.
        message: String,
    },
}

/// Tile `index` of `count` (`i/n` on the command line, 0 ≤ i < n).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileSpec {
    /// Which tile, from 0.
    pub index: usize,
    /// How many tiles.
    pub count: usize,
}

/// The most tiles a map may be cut into (a mistyped count is refused, not allocated).
pub const MAX_TILES: usize = 1 << 20;

impl FromStr for TileSpec {
    type Err = TileError;

    fn from_str(s: &str) -> Result<Self, TileError> {
        let bad = |message: &str| TileError::Spec { spec: s.to_string(), message: message.to_string() };
        let (i, n) = s.split_once('/').ok_or_else(|| bad("write the tile as i/n, e.g. 0/4"))?;
        let index: usize = i.trim().parse().map_err(|_| bad("the tile index is not a whole number"))?;
        let count: usize = n.trim().parse().map_err(|_| bad("the tile count is not a whole number"))?;
        if count == 0 {
            return Err(bad("the tile count must be at least 1"));
        }
        if count > MAX_TILES {
            return Err(bad(&format!("at most {MAX_TILES} tiles")));
        }
        if index >= count {
            return Err(bad(&format!("tiles are numbered 0 to {} of {count}", count - 1)));
        }
        Ok(TileSpec { index, count })
    }
}

impl std::fmt::Display for TileSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl TileSpec {
    /// The grid (nx, ny) of [`Self::count`] tiles: ny the largest divisor of the count not above
    /// its square root, nx = count / ny (2 → 2×1, 4 → 2×2, 6 → 3×2, 9 → 3×3).
    pub fn grid(&self) -> [usize; 2] {
        let n = self.count.max(1);
        let ny = (1..=n).take_while(|d| d * d <= n).filter(|d| n.is_multiple_of(*d)).last().unwrap_or(1);
        [n / ny, ny]
    }
}

/// An nx × ny grid of cells over a map's bounding box, in its two longest axes, cut at the
/// quantiles of the photons' coordinates so that the tiles hold about equal numbers of photons
/// (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Tiling {
    /// The map's box: low corner (of its finite positions).
    pub lo: [f32; 3],
    /// The map's box: high corner.
    pub hi: [f32; 3],
    /// The two axes cut, the longer first.
    pub axes: [usize; 2],
    /// Cells along each of [`Self::axes`]: columns along the first, rows in each column along
    /// the second.
    pub counts: [usize; 2],
    /// Column borders along the first axis: `counts[0] + 1` values from lo to hi.
    columns: Vec<f64>,
    /// Per column, its row borders along the second axis: `counts[1] + 1` values from lo to hi.
    rows: Vec<Vec<f64>>,
}

/// The `n − 1` inner cuts of `n` cells over the (finite) coordinates `v`, sorted in place: cut c
/// is the ⌊c·m/n⌋-th smallest of the m values, so that cell c (b_c ≤ x < b_{c+1}) holds the
/// values ranked ⌊c·m/n⌋ to ⌊(c+1)·m/n⌋ − 1 when no two are equal. With no values, equal cells
/// of `lo`–`hi`. The ends are `lo` and `hi`.
fn quantile_borders(v: &mut [f32], n: usize, lo: f32, hi: f32) -> Vec<f64> {
    use rayon::slice::ParallelSliceMut;
    v.par_sort_unstable_by(f32::total_cmp);
    let m = v.len();
    let (l, h) = (lo as f64, hi as f64);
    (0..=n)
        .map(|c| {
            if c == 0 {
                l
            } else if c == n {
                h
            } else if m == 0 {
                if h > l { l + (h - l) * c as f64 / n as f64 } else { l }
            } else {
                v[((c as u128 * m as u128) / n as u128) as usize] as f64
            }
        })
        .collect()
}

/// Whether every coordinate of `x` is finite (the photons the box and the cuts are taken over).
fn finite(x: &[f32; 3]) -> bool {
    x.iter().all(|v| v.is_finite())
}

impl Tiling {
    /// The grid of `grid` = [nx, ny] cells (each at least 1) over `positions`: the first axis
    /// cut at the nx-quantiles of every finite photon's coordinate, then each column's second
    /// axis at the ny-quantiles of that column's photons (module docs). A pure function of the
    /// positions: every job that reads the same map computes the same tiling.
    pub fn new(positions: &[[f32; 3]], grid: [usize; 2]) -> Self {
        Self::new_releasing(positions, grid, crate::format::Pages::default())
    }

    /// [`Self::new`] over `positions`, a column of the mapped file of `pages`, read a stretch at a
    /// time and each stretch's pages released once read: the same tiling, without the whole
    /// column resident (a render under `--memory` cuts its map after recording its lookups).
    pub fn new_releasing(positions: &[[f32; 3]], grid: [usize; 2], pages: crate::format::Pages) -> Self {
        Self::cut(positions, grid, pages, 1 << 20)
    }

    /// [`Self::new_releasing`] reading `stretch` photons at a time.
    fn cut(positions: &[[f32; 3]], grid: [usize; 2], pages: crate::format::Pages, stretch: usize) -> Self {
        let stretches = || positions.chunks(stretch.max(1));
        let release = |s: &[[f32; 3]]| pages.release_range(bytemuck::cast_slice(s));
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for s in stretches() {
            let (l, h) = crate::spatial::order::finite_bounds(s);
            for a in 0..3 {
                (lo[a], hi[a]) = (lo[a].min(l[a]), hi[a].max(h[a]));
            }
            release(s);
        }
        let extent = |a: usize| {
            let e = hi[a] as f64 - lo[a] as f64;
            if e.is_finite() { e.max(0.0) } else { 0.0 }
        };
        let mut axes = [0usize, 1, 2];
        // Longest first; ties keep the lower axis first (a stable sort).
        axes.sort_by(|&a, &b| extent(b).total_cmp(&extent(a)));
        let axes = [axes[0], axes[1]];
        let counts = [grid[0].max(1), grid[1].max(1)];
        let (ax, ay) = (axes[0], axes[1]);
        // The quantiles do not depend on the order the coordinates are taken in.
        let mut xs: Vec<f32> = Vec::new();
        for s in stretches() {
            xs.extend(s.iter().filter(|x| finite(x)).map(|x| x[ax]));
            release(s);
        }
        let columns = quantile_borders(&mut xs, counts[0], lo[ax], hi[ax]);
        drop(xs);
        let mut per_column: Vec<Vec<f32>> = vec![Vec::new(); counts[0]];
        if counts[1] > 1 {
            for s in stretches() {
                for x in s.iter().filter(|x| finite(x)) {
                    per_column[cell_in(&columns, x[ax])].push(x[ay]);
                }
                release(s);
            }
        }
        let rows = per_column.iter_mut().map(|ys| quantile_borders(ys, counts[1], lo[ay], hi[ay])).collect();
        Tiling { lo, hi, axes, counts, columns, rows }
    }

    /// How many tiles (nx·ny).
    pub fn len(&self) -> usize {
        self.counts[0] * self.counts[1]
    }

    /// Whether there are none (never: a tiling has at least one cell).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The tile holding position `x`: iy·nx + ix, ix its column and iy its row in that column.
    pub fn tile_of(&self, x: [f32; 3]) -> usize {
        let ix = cell_in(&self.columns, x[self.axes[0]]);
        let iy = cell_in(&self.rows[ix], x[self.axes[1]]);
        iy * self.counts[0] + ix
    }

    /// Tile `tile`'s cell: its low and high borders in each cut axis (the cell holds the
    /// positions with low ≤ x < high, closed at the map's high side).
    ///
    /// # Panics
    /// If `tile` is not below [`Self::len`].
    pub fn cell(&self, tile: usize) -> ([f64; 2], [f64; 2]) {
        assert!(tile < self.len(), "tile {tile} of {}", self.len());
        let (ix, iy) = (tile % self.counts[0], tile / self.counts[0]);
        let rows = &self.rows[ix];
        ([self.columns[ix], rows[iy]], [self.columns[ix + 1], rows[iy + 1]])
    }

    /// The photons of each tile, ascending within each: a count and a placement pass over
    /// `positions` into one allocation (the tiles a run of every tile shares, so no tile scans
    /// the whole map for its own photons; one block, so freeing it returns it to the system).
    pub fn buckets(&self, positions: &[[f32; 3]]) -> Buckets {
        use rayon::prelude::*;
        let counts = positions
            .par_chunks(1 << 16)
            .map(|xs| {
                let mut c = vec![0usize; self.len()];
                xs.iter().for_each(|&x| c[self.tile_of(x)] += 1);
                c
            })
            .reduce(|| vec![0usize; self.len()], |a, b| a.iter().zip(&b).map(|(x, y)| x + y).collect());
        let mut start = Vec::with_capacity(self.len() + 1);
        start.push(0usize);
        for c in &counts {
            start.push(start.last().copied().unwrap_or(0) + c);
        }
        let mut next = start.clone();
        let mut photons = vec![0u32; positions.len()];
        for (i, &x) in positions.iter().enumerate() {
            let t = self.tile_of(x);
            photons[next[t]] = i as u32;
            next[t] += 1;
        }
        Buckets { photons, start }
    }

    /// The photons of each tile in cells ([`TilePhotons`]), from [`Self::buckets`].
    pub fn tile_photons(&self, positions: &[[f32; 3]]) -> Vec<TilePhotons> {
        use rayon::prelude::*;
        let buckets = self.buckets(positions);
        (0..self.len())
            .into_par_iter()
            .map(|t| TilePhotons::of(buckets.tile(t), positions, self.axes))
            .collect()
    }

    /// The tiles whose cells meet `b`, the end cells taken open outward (they hold whatever
    /// lies beyond the map's box): every photon that `b` contains is in one of them.
    pub fn tiles_meeting(&self, b: &HaloBox) -> Vec<usize> {
        let span = |borders: &[f64], c: usize| {
            let lo = if c == 0 { f64::NEG_INFINITY } else { borders[c] };
            let hi = if c + 2 == borders.len() { f64::INFINITY } else { borders[c + 1] };
            (lo, hi)
        };
        let mut out = Vec::new();
        for ix in 0..self.counts[0] {
            let (xl, xh) = span(&self.columns, ix);
            if !(xl <= b.hi[0] && b.lo[0] <= xh) {
                continue;
            }
            for iy in 0..self.counts[1] {
                let (yl, yh) = span(&self.rows[ix], iy);
                if yl <= b.hi[1] && b.lo[1] <= yh {
                    out.push(iy * self.counts[0] + ix);
                }
            }
        }
        out
    }

    /// Tile `tile`'s cell grown by `halo` (metres, ≥ 0; ∞ for the whole map) in the cut axes.
    ///
    /// # Panics
    /// If `tile` is not below [`Self::len`].
    pub fn halo_box(&self, tile: usize, halo: f64) -> HaloBox {
        let (cl, ch) = self.cell(tile);
        let mut lo = [f64::NEG_INFINITY; 2];
        let mut hi = [f64::INFINITY; 2];
        for k in 0..2 {
            let a = self.axes[k];
            let l = cl[k] - halo;
            let h = ch[k] + halo;
            // A side at or beyond the map's box has no photon past it.
            if l > self.lo[a] as f64 {
                lo[k] = l;
            }
            if h < self.hi[a] as f64 {
                hi[k] = h;
            }
        }
        HaloBox { axes: self.axes, lo, hi }
    }
}

/// The cell of coordinate `x` among `borders` (b_0 … b_n): the c with b_c ≤ x < b_{c+1}, the
/// last cell closed; coordinates outside the box (or NaN) go to an end cell.
fn cell_in(borders: &[f64], x: f32) -> usize {
    // Inner borders b_1 … b_{n−1} at or below x.
    borders[1..borders.len() - 1].partition_point(|&v| v <= x as f64)
}

/// A tile's cell grown by a halo, in the two cut axes (closed; ±∞ on sides that hold the rest
/// of the map).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HaloBox {
    /// The two axes cut.
    pub axes: [usize; 2],
    /// Low side per cut axis (−∞: nothing of the map lies beyond).
    pub lo: [f64; 2],
    /// High side per cut axis (+∞: nothing of the map lies beyond).
    pub hi: [f64; 2],
}

impl HaloBox {
    /// Whether position `x` lies in the box (the tile's working set).
    pub fn contains(&self, x: [f32; 3]) -> bool {
        (0..2).all(|k| {
            let v = x[self.axes[k]] as f64;
            self.lo[k] <= v && v <= self.hi[k]
        })
    }

    /// Whether the box holds the whole map (every side open).
    pub fn is_whole(&self) -> bool {
        self.lo.iter().all(|l| l.is_infinite()) && self.hi.iter().all(|h| h.is_infinite())
    }

    /// The distance from `x` (inside the box) to the outside of the box: every photon of the
    /// map outside the box lies strictly farther than this from `x` (∞ for a whole box).
    pub fn margin(&self, x: [f32; 3]) -> f64 {
        (0..2)
            .map(|k| {
                let v = x[self.axes[k]] as f64;
                (v - self.lo[k]).min(self.hi[k] - v)
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// Whether a search from a photon with margin `margin` whose farthest result lies at squared
/// distance `far2` (as the index computes it, f32) found only photons that lie inside the box,
/// closer than anything outside it. The factor 1 + 10⁻⁵ covers the rounding of the index's
/// f32 squared distances many times over (docs/tiles.md).
pub fn within_margin(far2: f32, margin: f64) -> bool {
    margin == f64::INFINITY || (far2 as f64).sqrt() * (1.0 + 1e-5) < margin
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(target_os = "linux")]
    fn the_resident_set_grows_by_what_is_touched() {
        let before = resident_bytes().expect("Linux has /proc/self/status");
        let touched = vec![1u8; 256 << 20];
        let after = resident_bytes().unwrap();
        assert!(after >= before + (128 << 20), "{before} → {after} after touching 256 MiB");
        drop(std::hint::black_box(touched));
    }

    /// The tile count for a budget is the fewest that fit, a near-square grid, and a budget
    /// below the per-photon part is refused with the bytes needed.
    #[test]
    fn budgets_choose_the_fewest_tiles_that_fit() {
        let m = MemoryModel { per_photon: 40.0, per_working_photon: 300.0, halo_growth: 1.5 };
        let n = 10_000_000;
        // The whole map: 400 MB + 4.5 GB.
        assert_eq!(tiles_for_budget(n, 5_000_000_000, &m), Ok(1));
        for budget in [1_000_000_000u64, 2_000_000_000, 4_000_000_000] {
            let t = tiles_for_budget(n, budget, &m).unwrap();
            let peak = |t: usize| 40.0 * n as f64 + 300.0 * 1.5 * n as f64 / t as f64;
            assert!(peak(t) <= budget as f64, "{budget}: {t}");
            let grid = TileSpec { index: 0, count: t }.grid();
            assert!(grid[0] - grid[1] <= 1, "{t}: {grid:?}");
            let fewer = (1..t).rev().find(|c| {
                let g = TileSpec { index: 0, count: *c }.grid();
                g[0] - g[1] <= 1
            });
            assert!(fewer.is_none_or(|c| peak(c) > budget as f64), "{budget}: {t} tiles, {fewer:?} would do");
        }
        assert_eq!(tiles_for_budget(n, 1_000_000_000, &m), Ok(9));
        let e = tiles_for_budget(n, 300_000_000, &m).unwrap_err();
        assert!(e > 400_000_000, "{e}");
        assert!(tiles_for_budget(n, 400_100_000, &m).is_err(), "tiles of fewer than 1000 photons");
    }

    /// A budget's tiling leaves room for what the process holds: none when the whole map fits
    /// beside it, the tiling [`tiles_for_budget`] chooses for the rest when it does not, and a
    /// refusal that states the least budget, the process's part included, when no tiling fits.
    #[test]
    fn a_budgets_tiling_leaves_room_for_what_the_process_holds() {
        let m = MemoryModel { per_photon: 40.0, per_working_photon: 300.0, halo_growth: 1.5 };
        let positions: Vec<[f32; 3]> =
            (0..20_000).map(|i| [(i % 200) as f32, (i / 200) as f32, 0.0]).collect();
        let whole = (40 + 450) * 20_000;
        let held = 100 << 20;
        assert_eq!(tiling_beside(&positions, held + whole, held, &m), Ok(None));
        // The same budget with the process holding more takes tiles, as many as the rest needs.
        let t = tiling_beside(&positions, held + whole, held + whole * 2 / 3, &m).unwrap().expect("tiles");
        assert_eq!(t.len(), tiles_for_budget(20_000, whole / 3, &m).unwrap());
        assert!(t.len() >= 4, "{}", t.len());
        assert_eq!(t, Tiling::new(&positions, t.counts));
        let e = tiling_beside(&positions, held, held, &m).unwrap_err();
        let alone = tiles_for_budget(20_000, 0, &m).unwrap_err();
        assert_eq!(e, BudgetTooSmall { budget: held, photons: 20_000, need: alone + held, held });
    }

    #[test]
    fn specs_parse_and_bad_ones_say_why() {
        assert_eq!("0/4".parse::<TileSpec>().unwrap(), TileSpec { index: 0, count: 4 });
        assert_eq!(" 3 / 9".parse::<TileSpec>().unwrap().grid(), [3, 3]);
        for (s, why) in [
            ("3/2", "numbered 0 to 1"),
            ("0/0", "at least 1"),
            ("2", "i/n"),
            ("a/2", "index"),
            ("1/-2", "count"),
            ("0/99999999999", "at most"),
        ] {
            let e = s.parse::<TileSpec>().unwrap_err().to_string();
            assert!(e.contains(why), "{s}: {e}");
        }
        let grid = |n| TileSpec { index: 0, count: n }.grid();
        assert_eq!(
            [grid(1), grid(2), grid(4), grid(6), grid(7), grid(12)],
            [[1, 1], [2, 1], [2, 2], [3, 2], [7, 1], [4, 3]]
        );
    }

    #[test]
    fn cuts_are_quantiles_and_photons_on_a_cut_go_up() {
        // x = 0 … 8 (y = x mod 3): 3 columns cut at x = 3 and 6, the photons on them go up.
        let pos: Vec<[f32; 3]> = (0..9).map(|i| [i as f32, (i % 3) as f32 * 0.1, 0.0]).collect();
        let t = Tiling::new(&pos, [3, 1]);
        assert_eq!(t.axes, [0, 1]);
        let tiles: Vec<usize> = pos.iter().map(|&x| t.tile_of(x)).collect();
        assert_eq!(tiles, [0, 0, 0, 1, 1, 1, 2, 2, 2]);
        // Ties at the cut all go to the upper cell: the median is 1, held by four photons.
        let xs = [0.0f32, 1.0, 1.0, 1.0, 1.0, 2.0];
        let pos: Vec<[f32; 3]> = xs.iter().map(|&x| [x, 0.0, 0.0]).collect();
        let t = Tiling::new(&pos, [2, 1]);
        assert_eq!(pos.iter().map(|&x| t.tile_of(x)).collect::<Vec<_>>(), [0, 1, 1, 1, 1, 1]);
        // More than half on the low side of the box: the cut is the box's low side and tile 0 is
        // empty; the map's high corner is in the last cell (closed).
        let xs = [0.0f32, 0.0, 0.0, 0.0, 1.0, 2.0];
        let pos: Vec<[f32; 3]> = xs.iter().map(|&x| [x, 0.0, 0.0]).collect();
        let t = Tiling::new(&pos, [2, 1]);
        assert_eq!(pos.iter().map(|&x| t.tile_of(x)).collect::<Vec<_>>(), [1; 6]);
        // Each column is cut in y at its own photons' quantiles; y longer than x is cut first.
        let pos: Vec<[f32; 3]> = (0..8)
            .map(|i| [(i % 2) as f32 * 0.5, if i % 2 == 0 { i as f32 } else { 10.0 - i as f32 }, 0.0])
            .collect();
        let t = Tiling::new(&pos, [2, 2]);
        assert_eq!(t.axes, [1, 0]);
        // y: 0, 9, 2, 7, 4, 5, 6, 3 → columns cut at the 4th of 8, y = 5: {0, 2, 3, 4} and
        // {5, 6, 7, 9}. The first's x are 0, 0, 0.5, 0: cut at the 2nd of 4, x = 0, so its
        // first row is empty (tile 0); the second's are 0.5, 0, 0.5, 0.5: cut at x = 0.5.
        let tiles: Vec<usize> = pos.iter().map(|&x| t.tile_of(x)).collect();
        for (tile, &x) in tiles.iter().zip(&pos) {
            let (lo, hi) = t.cell(*tile);
            let v = [x[1] as f64, x[0] as f64];
            assert!((0..2).all(|k| lo[k] <= v[k] && (v[k] < hi[k] || hi[k] == t.hi[t.axes[k]] as f64)));
        }
        assert_eq!(tiles, [2, 3, 2, 3, 2, 3, 1, 2]);
    }

    /// 3000 photons with coordinates on a coarse lattice: many ties, many photons on cuts.
    fn lattice_map() -> Vec<[f32; 3]> {
        (0..3000u32)
            .map(|i| {
                let h = i.wrapping_mul(2_654_435_761);
                [(h % 37) as f32 * 0.1, ((h >> 8) % 23) as f32 * 0.1, ((h >> 16) % 3) as f32 * 0.01]
            })
            .collect()
    }

    /// Every photon is in the tile whose cell holds it (half-open, closed at the map's high
    /// sides), and the cuts are the same whatever the order of the photons.
    #[test]
    fn tiles_partition_the_map_and_do_not_depend_on_its_order() {
        let mut pos = lattice_map();
        for grid in [[1, 1], [2, 1], [2, 2], [3, 3], [7, 1], [4, 3]] {
            let t = Tiling::new(&pos, grid);
            for &x in &pos {
                let (lo, hi) = t.cell(t.tile_of(x));
                for k in 0..2 {
                    let (v, top) = (x[t.axes[k]] as f64, t.hi[t.axes[k]] as f64);
                    assert!(lo[k] <= v && (v < hi[k] || (v == top && hi[k] == top)), "{grid:?} {x:?}");
                }
            }
            pos.reverse();
            assert_eq!(Tiling::new(&pos, grid), t);
        }
    }

    /// A tiling cut from positions read a stretch at a time is the one cut from all of them at
    /// once, whatever the stretch (bounds, quantiles and rows gathered across stretches), with
    /// non-finite positions among them.
    #[test]
    fn a_tiling_read_in_stretches_is_the_whole_reads() {
        let mut pos: Vec<[f32; 3]> = (0..5000)
            .map(|i| [(i * 37 % 1009) as f32, (i * 101 % 499) as f32 * 0.5, (i % 7) as f32])
            .collect();
        pos[17] = [f32::NAN, 0.0, 0.0];
        pos[4321] = [1.0, f32::INFINITY, 2.0];
        for grid in [[1, 1], [2, 1], [3, 3], [4, 5]] {
            let whole = Tiling::cut(&pos, grid, crate::format::Pages::default(), usize::MAX);
            for stretch in [1, 7, 1000, 4999] {
                assert_eq!(
                    Tiling::cut(&pos, grid, crate::format::Pages::default(), stretch),
                    whole,
                    "{grid:?}, {stretch}"
                );
            }
            assert_eq!(Tiling::new(&pos, grid), whole);
        }
    }

    /// Each tile's bucket is its photons, ascending, and the photons of the tiles a halo box
    /// meets include every photon the box contains, for boxes of every size (photons on cuts,
    /// one with a non-finite coordinate, boxes open to the map's sides).
    #[test]
    fn buckets_and_the_tiles_a_box_meets_hold_every_photon_it_contains() {
        let mut pos = lattice_map();
        pos.push([f32::NAN, 1.0, 0.0]);
        for grid in [[1, 1], [2, 1], [3, 3], [7, 1], [4, 3]] {
            let t = Tiling::new(&pos, grid);
            let buckets = t.buckets(&pos);
            for tile in 0..t.len() {
                let want: Vec<u32> =
                    (0..pos.len() as u32).filter(|&i| t.tile_of(pos[i as usize]) == tile).collect();
                assert_eq!(buckets.tile(tile), &want[..], "{grid:?} tile {tile}");
            }
            for tile in 0..t.len() {
                for halo in [0.0, 0.05, 0.1, 0.35, 1.0, f64::INFINITY] {
                    let b = t.halo_box(tile, halo);
                    let meeting = t.tiles_meeting(&b);
                    let mut got: Vec<u32> = meeting
                        .iter()
                        .flat_map(|&m| buckets.tile(m).iter().copied())
                        .filter(|&i| b.contains(pos[i as usize]))
                        .collect();
                    got.sort_unstable();
                    let want: Vec<u32> =
                        (0..pos.len() as u32).filter(|&i| b.contains(pos[i as usize])).collect();
                    assert_eq!(got, want, "{grid:?} tile {tile} halo {halo}");
                    assert!(meeting.contains(&tile));
                    if halo == 0.0 && tile == 0 && t.len() > 4 {
                        assert!(meeting.len() < t.len(), "{grid:?}: a bare corner cell meets every tile");
                    }
                }
            }
        }
    }

    /// On a skewed map (nine photons in ten in a blob a hundredth of the box wide) with no two
    /// photons sharing a coordinate, every tile of every grid holds n/t photons give or take 2;
    /// equal cells would put almost all of them in one tile.
    #[test]
    fn tiles_are_balanced_on_a_skewed_map() {
        let n = 20_000u32;
        let frac = |i: u32, a: f64| (i as f64 * a).fract();
        let pos: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let (u, v) = (frac(i, 0.618_033_988_749_895), frac(i, 0.754_877_666_246_693));
                if i % 10 == 0 {
                    [u as f32 * 4.0, v as f32 * 2.0, 0.0]
                } else {
                    [2.0 + u as f32 * 0.04, 1.0 + v as f32 * 0.02, 0.0]
                }
            })
            .collect();
        for a in 0..2 {
            let mut c: Vec<u32> = pos.iter().map(|x| x[a].to_bits()).collect();
            c.sort_unstable();
            c.dedup();
            assert_eq!(c.len(), n as usize, "axis {a} has ties");
        }
        for count in [2, 4, 6, 9, 16, 25] {
            let spec = TileSpec { index: 0, count };
            let t = Tiling::new(&pos, spec.grid());
            let mut counts = vec![0usize; count];
            pos.iter().for_each(|&x| counts[t.tile_of(x)] += 1);
            let mean = n as f64 / count as f64;
            assert!(counts.iter().all(|&c| (c as f64 - mean).abs() <= 2.0), "{count}: {counts:?}");
        }
    }

    #[test]
    fn halo_margins_bound_the_distance_to_everything_outside() {
        let pos: Vec<[f32; 3]> =
            (0..400).map(|i| [(i % 20) as f32 * 0.1, (i / 20) as f32 * 0.1, (i % 3) as f32 * 0.01]).collect();
        let t = Tiling::new(&pos, [2, 2]);
        for tile in 0..4 {
            for h in [0.0, 0.15, 0.5, f64::INFINITY] {
                let b = t.halo_box(tile, h);
                assert_eq!(b.is_whole(), h.is_infinite());
                for &x in pos.iter().filter(|&&x| t.tile_of(x) == tile) {
                    assert!(b.contains(x));
                    let m = b.margin(x);
                    for &y in pos.iter().filter(|&&y| !b.contains(y)) {
                        let d = (0..3).map(|a| (x[a] as f64 - y[a] as f64).powi(2)).sum::<f64>().sqrt();
                        assert!(d > m, "tile {tile} h {h}: {x:?} {y:?} {d} ≤ {m}");
                    }
                }
            }
        }
    }
}
