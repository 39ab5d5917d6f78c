//! The selection of a search's k nearest candidates: a histogram of their distances in
//! buckets, falling back to `select_nth_unstable` where the histogram cannot decide.

use super::{Cand, larger};

/// Buckets of [`nearest_first`]'s histogram.
const BUCKETS: usize = 64;

/// Most candidates [`nearest_first`] sorts into buckets (more go to `select_nth_unstable`).
pub(super) const BUCKETED: usize = 256;

/// Most candidates of the k-th's bucket [`nearest_first`] selects among (more, as when many
/// photons lie at one distance, go to `select_nth_unstable`).
const EDGE: usize = 32;

/// Moves the `k` candidates of lowest rank to the front of `s` (in any order; what lies behind
/// them is unspecified); every candidate's distance² is at most `reach`. A histogram of the
/// distances² in [`BUCKETS`] equal parts of 0..reach finds the bucket that holds the k-th (a
/// bucket's distances are all below the next one's: scaling and rounding keep the order);
/// the candidates of lower buckets are kept and the few of that bucket selected among by
/// rank. One pass to count and one to keep, without a branch per candidate, where
/// `select_nth_unstable`'s partitions and final insertion sort mispredict about half their
/// comparisons on candidates in no particular order; it still decides where the histogram
/// cannot (see [`by_buckets`]). Returns the largest distance² of the k (the k-th's), which
/// the selection finds on the way.
pub(super) fn nearest_first(s: &mut [Cand], k: usize, reach: f32) -> f32 {
    if s.len() <= k {
        return farthest(s);
    }
    match by_buckets(s, k, reach) {
        Some(far2) => far2,
        None => s.select_nth_unstable_by_key(k - 1, |c| c.key).1.dist2(),
    }
}

/// The largest distance² among `s` (0 when empty).
pub(super) fn farthest(s: &[Cand]) -> f32 {
    s.iter().fold(0.0, |m, c| larger(m, c.dist2()))
}

/// The histogram of [`nearest_first`] over `s` (k < `s.len()`): each candidate's bucket, the
/// bucket that holds the k-th and how many lie below it; `None` when it does not apply: too
/// many candidates, a reach of 0 (or not finite), or more than [`EDGE`] in the k-th's bucket
/// (as when many photons lie at one distance).
#[inline(always)]
fn histogram(s: &[Cand], k: usize, reach: f32) -> Option<([u8; BUCKETED], usize, usize)> {
    if s.len() > BUCKETED || !(reach > 0.0 && reach.is_finite()) {
        return None;
    }
    let scale = BUCKETS as f32 / reach;
    let mut bucket = [0u8; BUCKETED];
    let mut count = [0u32; 2 * BUCKETS];
    for (b, c) in bucket.iter_mut().zip(s.iter()) {
        // d² · scale lies in 0..=BUCKETS (just above, by rounding, at d² = reach); adding
        // 2²³ rounds it to an integer in the float's low mantissa bits: rounding is monotone
        // too, and cheaper than a saturating conversion.
        let x = ((c.dist2() * scale + 8_388_608.0).to_bits() & (2 * BUCKETS as u32 - 1)) as usize;
        *b = x as u8;
        count[x] += 1;
    }
    // The bucket of the k-th, and how many lie below it, counted down from the top bucket
    // (d² ≤ reach puts every candidate at most there): the surplus over k is usually small,
    // so that bucket lies a few from the top.
    let (mut edge, mut above) = (BUCKETS, 0);
    while edge > 0 && s.len() - above - count[edge] as usize >= k {
        above += count[edge] as usize;
        edge -= 1;
    }
    let below = s.len() - above - count[edge] as usize;
    (count[edge] as usize <= EDGE && below < k).then_some((bucket, edge, below))
}

/// [`nearest_first`] by the [`histogram`], for k < `s.len()`, returning the k-th's distance²;
/// `None` (and `s` untouched) when the histogram does not apply.
fn by_buckets(s: &mut [Cand], k: usize, reach: f32) -> Option<f32> {
    let (bucket, edge, below) = histogram(s, k, reach)?;
    // Lower buckets to the front (`kept ≤ i`: the write never overtakes the read), the
    // edge bucket aside.
    let mut aside = [Cand::default(); EDGE + 1];
    let (mut kept, mut on_edge) = (0, 0);
    for i in 0..s.len() {
        let (c, b) = (s[i], bucket[i] as usize);
        s[kept] = c;
        kept += (b < edge) as usize;
        aside[on_edge] = c;
        on_edge += (b == edge) as usize;
    }
    let aside = &mut aside[..on_edge];
    let need = k - below;
    // The k-th: the need-th of its bucket (all of them when all are needed).
    let far2 = if need < on_edge {
        aside.select_nth_unstable_by_key(need - 1, |c| c.key).1.dist2()
    } else {
        farthest(aside)
    };
    s[below..k].copy_from_slice(&aside[..need]);
    Some(far2)
}

/// The k-th lowest rank among the candidates `s` (at least k, every distance² at most
/// `reach`), whose order it may change: as [`nearest_first`], but only the k-th's bucket is
/// gathered and selected among.
pub(super) fn kth_rank(s: &mut [Cand], k: usize, reach: f32) -> u64 {
    if s.len() == k {
        return s.iter().fold(0, |m, c| m.max(c.key));
    }
    if let Some((bucket, edge, below)) = histogram(s, k, reach) {
        let mut aside = [Cand::default(); EDGE + 1];
        let mut on_edge = 0;
        for (&c, &b) in s.iter().zip(&bucket) {
            aside[on_edge] = c;
            on_edge += (b as usize == edge) as usize;
        }
        return aside[..on_edge].select_nth_unstable_by_key(k - below - 1, |c| c.key).1.key;
    }
    s.select_nth_unstable_by_key(k - 1, |c| c.key).1.key
}
