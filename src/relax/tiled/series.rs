//! A tile round's per-iteration series, written in the order the round reads them.

use rayon::prelude::*;

use super::TileRelaxed;

/// A round's per-iteration series (nearest-neighbour distance, its ratio to r_K, step) of the
/// pending interior photons, one row of R values per photon in member order, so that an
/// iteration's values are read in member order and written along the rows. The first round,
/// which holds every interior photon, works in the tile's own series and leaves its rows in
/// member order ([`TileRelaxed::rows`] says where each photon's is); a later round (a few
/// photons along the tile's sides) copies the certified photons' rows into theirs.
pub(super) struct Series {
    rows: [Vec<f32>; 3],
    /// Whether `rows` are the tile's series (the first round).
    whole_tile: bool,
    r: usize,
}

impl Series {
    pub(super) fn for_round(out: &mut TileRelaxed, rows: usize, interior: usize) -> Series {
        let r = out.iterations;
        if out.rounds == 1 && rows == interior {
            let taken = [&mut out.nn, &mut out.ratio, &mut out.step].map(std::mem::take);
            Series { rows: taken, whole_tile: true, r }
        } else {
            Series {
                rows: [vec![0.0; rows * r], vec![f32::NAN; rows * r], vec![0.0; rows * r]],
                whole_tile: false,
                r,
            }
        }
    }

    /// Iteration `t`'s values of the photons of `rows` (member, interior place), from `per`
    /// (by member).
    pub(super) fn record(&mut self, rows: &[(u32, u32)], t: usize, per: &crate::relax::PerPhoton) {
        let r = self.r;
        let [nn, ratio, step] = &mut self.rows;
        nn.par_chunks_mut(r).zip(ratio.par_chunks_mut(r)).zip(step.par_chunks_mut(r)).zip(rows).for_each(
            |(((nn, ratio), step), &(k, _))| {
                let k = k as usize;
                (nn[t], ratio[t], step[t]) = (per.nn[k], per.ratio[k], per.step[k]);
            },
        );
    }

    /// Puts the rows in the tile's series: every row in the first round, in member order (an
    /// uncertified photon's is written again in a later round); after it, the rows of the
    /// photons `keep` keeps (by member), each in its photon's row.
    pub(super) fn place(self, out: &mut TileRelaxed, rows: &[(u32, u32)], keep: impl Fn(u32) -> bool) {
        let r = self.r;
        if self.whole_tile {
            for (j, &(_, q)) in rows.iter().enumerate() {
                out.rows[q as usize] = j as u32;
            }
            [out.nn, out.ratio, out.step] = self.rows;
        } else {
            for (from, to) in self.rows.iter().zip([&mut out.nn, &mut out.ratio, &mut out.step]) {
                for (j, &(k, q)) in rows.iter().enumerate() {
                    if keep(k) {
                        let row = out.rows[q as usize] as usize;
                        to[row * r..][..r].copy_from_slice(&from[j * r..][..r]);
                    }
                }
            }
        }
    }
}
