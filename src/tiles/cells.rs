//! A tile's photons in the cells of a grid over it, and the gather that reads a set of cells'
//! photons from the map in file order.

use super::HaloBox;

/// Each tile's photons ([`Tiling::buckets`](super::Tiling::buckets)): indices into the map,
/// ascending within a tile.
#[derive(Clone, Debug, PartialEq)]
pub struct Buckets {
    pub(super) photons: Vec<u32>,
    pub(super) start: Vec<usize>,
}

impl Buckets {
    /// Tile `tile`'s photons, ascending.
    pub fn tile(&self, tile: usize) -> &[u32] {
        &self.photons[self.start[tile]..self.start[tile + 1]]
    }
}

/// The photons of `cells` (each a list of indices in the map) in file order, with their
/// positions: one gather in blocks whose pages are released as read (a tile's cells hold
/// photons from all over the file; read cell by cell they would map every page of the
/// positions at once).
pub fn gather_cells<'c>(
    pages: crate::format::Pages,
    positions: &[[f32; 3]],
    cells: impl Iterator<Item = &'c [u32]>,
) -> (Vec<u32>, Vec<[f32; 3]>) {
    use rayon::slice::ParallelSliceMut;
    let mut photons: Vec<u32> = cells.flatten().copied().collect();
    photons.par_sort_unstable();
    let at = pages.gather(positions, &photons);
    (photons, at)
}

/// One tile's photons, in the cells of a grid over their box (about 4096 photons a cell, at
/// most 32 × 32 cells), so that a scan for the photons near a halo box reads only the cells
/// near it.
pub struct TilePhotons {
    /// The photons' indices in the map, cell by cell, ascending within each cell (a cell's scan
    /// reads the map's columns in file order).
    pub photons: Vec<u32>,
    /// The cells holding photons.
    pub cells: Vec<TileCell>,
}

/// A cell of a [`TilePhotons`]: the box of its photons' positions in the two cut axes
/// (metres; empty, lo > hi, for the photons not at a finite position), and where its photons
/// are in [`TilePhotons::photons`].
pub struct TileCell {
    /// The box's low corner (cut axes, metres).
    pub lo: [f64; 2],
    /// The box's high corner.
    pub hi: [f64; 2],
    /// Where the cell's photons are in [`TilePhotons::photons`].
    pub range: std::ops::Range<usize>,
}

impl TileCell {
    /// Whether the cell's box meets `halo` (never for the photons at no finite position).
    pub fn meets(&self, halo: &HaloBox) -> bool {
        (0..2).all(|k| self.lo[k] <= halo.hi[k] && self.hi[k] >= halo.lo[k])
    }
}

impl TilePhotons {
    /// `photons` (ascending indices of the map, positions `pos`) put in cells over the cut
    /// `axes`.
    pub fn of(photons: &[u32], pos: &[[f32; 3]], axes: [usize; 2]) -> TilePhotons {
        let finite = |x: [f32; 3]| axes.iter().all(|&a| x[a].is_finite());
        // A box in the cut axes grown to hold `x` (if at a finite position).
        let grow = |(lo, hi): &mut ([f64; 2], [f64; 2]), x: [f32; 3]| {
            if finite(x) {
                for k in 0..2 {
                    lo[k] = lo[k].min(x[axes[k]] as f64);
                    hi[k] = hi[k].max(x[axes[k]] as f64);
                }
            }
        };
        let mut whole = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        photons.iter().for_each(|&i| grow(&mut whole, pos[i as usize]));
        let (lo, hi) = whole;
        let g = ((photons.len() as f64 / 4096.0).sqrt().ceil() as usize).clamp(1, 32);
        // Cell g·g holds the photons at no finite position.
        let cell_of = |x: [f32; 3]| {
            if !finite(x) {
                return g * g;
            }
            let at = |k: usize| {
                let w = hi[k] - lo[k];
                if w > 0.0 { (((x[axes[k]] as f64 - lo[k]) / w * g as f64) as usize).min(g - 1) } else { 0 }
            };
            at(1) * g + at(0)
        };
        // Each photon's cell, and each cell's count and box.
        let mut boxes = vec![(0usize, ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2])); g * g + 1];
        let cell: Vec<u32> = photons
            .iter()
            .map(|&i| {
                let x = pos[i as usize];
                let c = cell_of(x);
                boxes[c].0 += 1;
                grow(&mut boxes[c].1, x);
                c as u32
            })
            .collect();
        // Where each cell's photons start; a stable placement keeps them ascending.
        let mut start = Vec::with_capacity(boxes.len() + 1);
        start.push(0);
        for b in &boxes {
            start.push(start.last().copied().unwrap_or(0) + b.0);
        }
        let mut next = start.clone();
        let mut placed = vec![0u32; photons.len()];
        for (&i, &c) in photons.iter().zip(&cell) {
            placed[next[c as usize]] = i;
            next[c as usize] += 1;
        }
        let cells = boxes
            .iter()
            .enumerate()
            .filter(|(_, b)| b.0 > 0)
            .map(|(c, &(_, (lo, hi)))| TileCell { lo, hi, range: start[c]..start[c + 1] })
            .collect();
        TilePhotons { photons: placed, cells }
    }

    /// The photons' indices in the map, ascending.
    pub fn ascending(&self) -> Vec<u32> {
        use rayon::prelude::*;
        let mut v = self.photons.clone();
        v.par_sort_unstable();
        v
    }

    /// The photons of cell `c`.
    pub fn of_cell(&self, c: &TileCell) -> &[u32] {
        &self.photons[c.range.clone()]
    }

    /// The photons of the cells whose box meets `halo`, and those at no finite position (which
    /// no box describes), cell by cell: every photon of the tile that `halo` may hold.
    pub fn near<'t>(&'t self, halo: &'t HaloBox) -> impl Iterator<Item = &'t [u32]> + 't {
        self.cells.iter().filter(|c| c.meets(halo) || c.lo[0] > c.hi[0]).map(|c| self.of_cell(c))
    }
}
