//! Photons relabelled in spatial order for the length of a stage.
//!
//! Files keep photons in emission order, where neighbours in space lie far apart in memory;
//! a stage that queries every photon in the index's leaf order then reads each photon's own
//! data (position, parameters, basis, radius) with a cache miss. Detect and relax therefore
//! work on copies of their columns in Z-order (Morton order) of the positions and put their
//! results back in file order at the end. Nothing but speed depends on it: ties between
//! equally distant neighbours are broken by the working label, so results are the same as on
//! the file's order except where two neighbours tie exactly.

use rayon::prelude::*;

/// A permutation of `0..positions.len()` that visits the positions in Z-order of their
/// bounding box (21 bits per axis), ties by index: `order[k]` is the k-th photon visited.
/// Non-finite coordinates are placed as if at the box's low corner (the stages reject them
/// before they matter).
pub fn locality_order(positions: &[[f32; 3]]) -> Vec<u32> {
    let (lo, hi) = finite_bounds(positions);
    locality_order_in(positions, lo, hi)
}

/// The box (low and high corners) of the finite coordinates of `positions`, per axis
/// (+∞ and −∞ on an axis without any).
pub fn finite_bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            if p[a].is_finite() {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    (lo, hi)
}

/// [`locality_order`] with the Z-order keys taken on the box `lo`–`hi` instead of the
/// positions' own. A subset of a map listed in file order and ordered on the *map's* box
/// ([`finite_bounds`] of the map) is visited in the order the whole map's [`locality_order`]
/// visits those photons: a tile labels its photons as the whole map does (docs/tiles.md).
pub fn locality_order_in(positions: &[[f32; 3]], lo: [f32; 3], hi: [f32; 3]) -> Vec<u32> {
    const CELLS: f64 = ((1u32 << 21) - 1) as f64;
    let scale: [f64; 3] = std::array::from_fn(|a| {
        let e = hi[a] as f64 - lo[a] as f64;
        if e > 0.0 && e.is_finite() { CELLS / e } else { 0.0 }
    });
    let mut keyed: Vec<(u64, u32)> = positions
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let cell = |a: usize| {
                let t = (p[a] as f64 - lo[a] as f64) * scale[a];
                if t.is_finite() { t.clamp(0.0, CELLS) as u64 } else { 0 }
            };
            (spread(cell(0)) | spread(cell(1)) << 1 | spread(cell(2)) << 2, i as u32)
        })
        .collect();
    // A stable radix sort on the key keeps ties in index order (the order sorting by (key,
    // index) gives), in a fixed number of linear passes: several times fewer cycles than a
    // comparison sort on a million photons.
    radsort::sort_by_key(&mut keyed, |&(key, _)| key);
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// The 21 low bits of `x` moved to every third bit (bit b to bit 3b).
fn spread(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// `values` in `order` (`values[order[k]]` at k), `stride` values per photon.
pub fn permuted<T: Copy + Default + Send + Sync>(values: &[T], order: &[u32], stride: usize) -> Vec<T> {
    if stride == 1 {
        return order.par_iter().map(|&i| values[i as usize]).collect();
    }
    let mut out = vec![T::default(); order.len() * stride];
    out.par_chunks_mut(stride.max(1)).zip(order).for_each(|(o, &i)| {
        o.copy_from_slice(&values[i as usize * stride..][..stride]);
    });
    out
}

/// The inverse of [`permuted`] with stride 1: `values[k]` back at `order[k]`.
pub fn unpermuted<T: Copy + Default>(values: &[T], order: &[u32]) -> Vec<T> {
    let mut out = vec![T::default(); values.len()];
    for (&i, &v) in order.iter().zip(values) {
        out[i as usize] = v;
    }
    out
}

impl super::SpatialError {
    /// The error with a working label turned back into the photon's label in the file.
    pub fn in_file_order(self, order: &[u32]) -> Self {
        match self {
            Self::NonFinite { index, what } => {
                Self::NonFinite { index: order.get(index).map_or(index, |&i| i as usize), what }
            }
            e => e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute-force interleave, bit by bit.
    fn spread_slow(x: u64) -> u64 {
        (0..21).map(|b| ((x >> b) & 1) << (3 * b)).fold(0, |a, v| a | v)
    }

    #[test]
    fn spread_matches_bit_by_bit_interleave() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            assert_eq!(spread(x), spread_slow(x & 0x1f_ffff));
        }
        assert_eq!(spread(0x1f_ffff), 0x1249_2492_4924_9249);
    }

    #[test]
    fn order_is_a_permutation_in_z_order_and_round_trips() {
        // A 4 × 4 grid given in reverse: Z-order visits (0,0), (1,0), (0,1), (1,1), (2,0), …
        let pos: Vec<[f32; 3]> = (0..16).rev().map(|k| [(k % 4) as f32, (k / 4) as f32, 0.0]).collect();
        let order = locality_order(&pos);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..16).collect::<Vec<u32>>());
        let visited: Vec<[f32; 2]> =
            order.iter().map(|&i| [pos[i as usize][0], pos[i as usize][1]]).collect();
        assert_eq!(&visited[..5], &[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [2.0, 0.0]]);
        let values: Vec<u32> = (100..116).collect();
        let p = permuted(&values, &order, 1);
        assert_eq!(unpermuted(&p, &order), values);
        let pairs: Vec<u32> = (0..32).collect();
        let p2 = permuted(&pairs, &order, 2);
        assert_eq!(p2[0..2], [2 * order[0], 2 * order[0] + 1]);
    }

    /// Photons at the same place (equal keys) are visited in index order, as sorting by
    /// (key, index) visits them, and the places themselves in Z-order.
    #[test]
    fn ties_are_visited_in_index_order() {
        let places: Vec<[f32; 3]> =
            (0..7u32).map(|k| [(k % 2) as f32, (k / 2 % 2) as f32, (k / 4) as f32]).collect();
        let pos: Vec<[f32; 3]> =
            (0..3000u32).map(|i| places[(i.wrapping_mul(2_654_435_761) >> 7) as usize % 7]).collect();
        let order = locality_order(&pos);
        for w in order.windows(2) {
            let (a, b) = (pos[w[0] as usize], pos[w[1] as usize]);
            if a == b {
                assert!(w[0] < w[1], "{w:?}");
            }
        }
        // Each place's photons in one run: (x, y, z) bits interleaved x lowest.
        let key = |p: [f32; 3]| p[0] as u32 | (p[1] as u32) << 1 | (p[2] as u32) << 2;
        let keys: Vec<u32> = order.iter().map(|&i| key(pos[i as usize])).collect();
        assert!(keys.windows(2).all(|k| k[0] <= k[1]));
    }

    #[test]
    fn degenerate_sets_have_an_order() {
        assert!(locality_order(&[]).is_empty());
        assert_eq!(locality_order(&[[1.0, 1.0, 1.0]; 5]), [0, 1, 2, 3, 4]);
        let odd = [[f32::NAN, 0.0, 0.0], [1e30, -1e30, 0.0], [0.0, 0.0, 0.0]];
        let mut o = locality_order(&odd);
        o.sort_unstable();
        assert_eq!(o, [0, 1, 2]);
    }
}
