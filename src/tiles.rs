//! Spatial tiles with halos: a map cut into axis-aligned cells of its world-space bounding box,
//! each processed with the photons around it, so that a stage can run tile by tile (or tile
//! per machine) and give each photon exactly the result it gets from the whole map
//! (docs/tiles.md; [`crate::detect::detect_tile`]).
//!
//! A [`Tiling`] is nx × ny cells over the two longest axes of the map's box. Cell k of an axis
//! spans [b_k, b_{k+1}) (the last one closed), so a photon exactly on a border belongs to one
//! tile only. A [`HaloBox`] is a tile's cell grown by a halo width on each side; the
//! [`HaloBox::margin`] of a photon inside the cell bounds from below the distance to any photon
//! outside the grown box, which is what a stage's certificate compares its search radius with.
//!
//! ```
//! use photonkit::tiles::{TileSpec, Tiling};
//! let positions = [[0.0f32, 0.0, 0.0], [0.5, 0.2, 0.0], [1.0, 1.0, 0.0]];
//! let spec: TileSpec = "1/2".parse().unwrap();
//! let tiling = Tiling::new(&positions, spec.grid());
//! // The photon at x = 0.5, exactly on the border, is in the upper tile.
//! let tiles: Vec<usize> = positions.iter().map(|&x| tiling.tile_of(x)).collect();
//! assert_eq!(tiles, [0, 1, 1]);
//! ```

use std::str::FromStr;

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

/// An nx × ny grid of cells over a map's bounding box, in its two longest axes (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Tiling {
    /// The map's box: low corner (of its finite positions).
    pub lo: [f32; 3],
    /// The map's box: high corner.
    pub hi: [f32; 3],
    /// The two axes cut, the longer first.
    pub axes: [usize; 2],
    /// Cells along each of [`Self::axes`].
    pub counts: [usize; 2],
    /// Cell borders along each axis: `counts[a] + 1` values from lo to hi.
    borders: [Vec<f64>; 2],
}

impl Tiling {
    /// The grid of `grid` = [nx, ny] cells over the box of `positions`' finite coordinates.
    pub fn new(positions: &[[f32; 3]], grid: [usize; 2]) -> Self {
        let (lo, hi) = crate::spatial::order::finite_bounds(positions);
        Tiling::over(lo, hi, grid)
    }

    /// The grid of `grid` = [nx, ny] cells (each at least 1) over the box `lo`–`hi`.
    pub fn over(lo: [f32; 3], hi: [f32; 3], grid: [usize; 2]) -> Self {
        let extent = |a: usize| {
            let e = hi[a] as f64 - lo[a] as f64;
            if e.is_finite() { e.max(0.0) } else { 0.0 }
        };
        let mut axes = [0usize, 1, 2];
        // Longest first; ties keep the lower axis first (a stable sort).
        axes.sort_by(|&a, &b| extent(b).total_cmp(&extent(a)));
        let axes = [axes[0], axes[1]];
        let counts = [grid[0].max(1), grid[1].max(1)];
        let borders = std::array::from_fn(|k| {
            let (a, n) = (axes[k], counts[k]);
            let (l, e) = (lo[a] as f64, extent(a));
            (0..=n).map(|c| if c == n { hi[a] as f64 } else { l + e * c as f64 / n as f64 }).collect()
        });
        Tiling { lo, hi, axes, counts, borders }
    }

    /// How many tiles (nx·ny).
    pub fn len(&self) -> usize {
        self.counts[0] * self.counts[1]
    }

    /// Whether there are none (never: a tiling has at least one cell).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell of coordinate `x` along cut axis `k`: the c with b_c ≤ x < b_{c+1}, the last
    /// cell closed; coordinates outside the box go to the nearest end cell.
    fn cell(&self, k: usize, x: f32) -> usize {
        let b = &self.borders[k];
        // Borders b_1 … b_{n−1} at or below x.
        b[1..b.len() - 1].partition_point(|&v| v <= x as f64)
    }

    /// The tile holding position `x`: iy·nx + ix.
    pub fn tile_of(&self, x: [f32; 3]) -> usize {
        let ix = self.cell(0, x[self.axes[0]]);
        let iy = self.cell(1, x[self.axes[1]]);
        iy * self.counts[0] + ix
    }

    /// Tile `tile`'s cell grown by `halo` (metres, ≥ 0; ∞ for the whole map) in the cut axes.
    ///
    /// # Panics
    /// If `tile` is not below [`Self::len`].
    pub fn halo_box(&self, tile: usize, halo: f64) -> HaloBox {
        assert!(tile < self.len(), "tile {tile} of {}", self.len());
        let cells = [tile % self.counts[0], tile / self.counts[0]];
        let mut lo = [f64::NEG_INFINITY; 2];
        let mut hi = [f64::INFINITY; 2];
        for k in 0..2 {
            let (a, c) = (self.axes[k], cells[k]);
            let l = self.borders[k][c] - halo;
            let h = self.borders[k][c + 1] + halo;
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
    fn every_photon_is_in_one_tile_and_borders_go_up() {
        // Box [0, 3] × [0, 1.5] × [0, 0.1]: x is cut first, then y.
        let mut pos = vec![[0.0f32, 0.0, 0.0], [3.0, 1.5, 0.1]];
        for (x, y) in [(1.0, 0.5), (2.0, 1.0), (0.999, 0.499), (3.0, 0.0), (1.5, 0.75)] {
            pos.push([x, y, 0.05]);
        }
        let t = Tiling::new(&pos, [3, 3]);
        assert_eq!(t.axes, [0, 1]);
        let tiles: Vec<usize> = pos.iter().map(|&x| t.tile_of(x)).collect();
        // (1, 0.5) on two borders: cell (1, 1); (2, 1): (2, 2); (3, 1.5), the far corner: (2, 2).
        assert_eq!(tiles, [0, 8, 4, 8, 0, 2, 4]);
        // y longer than x: y is cut first.
        let t = Tiling::new(&[[0.0, 0.0, 0.0], [1.0, 2.0, 0.0]], [2, 1]);
        assert_eq!((t.axes, t.tile_of([0.9, 1.0, 0.0]), t.tile_of([0.9, 0.99, 0.0])), ([1, 0], 1, 0));
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
