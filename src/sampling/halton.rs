//! The low-discrepancy emission sequence and the per-photon random stream.
//!
//! Photon i's emission is a function of i and the seed alone: the Halton point of index i
//! (bases 2, 3, 5, 7), shifted modulo 1 by seed-derived offsets (a Cranley–Patterson
//! rotation, so different seeds give different but equally uniform sets). Its stochastic
//! choices along the path (Fresnel, Russian roulette) come from a generator seeded by (seed, i).
//! So any range of emission numbers traces on its own, on any thread.

/// Bases of the dimensions: emitter choice, the emitter's two sample coordinates, wavelength.
pub const BASES: [u64; 4] = [2, 3, 5, 7];

/// The rotated Halton point of `index` in the four dimensions, each in [0, 1).
#[derive(Clone, Copy, Debug)]
pub struct Halton {
    offsets: [f64; 4],
}

impl Halton {
    /// The sequence rotated by offsets drawn from `seed`.
    pub fn new(seed: u64) -> Self {
        let mut s = seed ^ 0x005E_ED0F_4A17_0A5E;
        Halton {
            offsets: std::array::from_fn(|_| (splitmix64(&mut s) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)),
        }
    }

    /// The point of `index`: four coordinates in [0, 1).
    pub fn point(&self, index: u64) -> [f32; 4] {
        self.rotate([
            base2(index),
            radical_inverse::<3>(index),
            radical_inverse::<5>(index),
            radical_inverse::<7>(index),
        ])
    }

    /// The points of `start`, `start + 1`, … in turn, each equal to [`Halton::point`] of its
    /// index but cheaper: the digits are carried from one index to the next.
    pub fn run(&self, start: u64) -> HaltonRun<'_> {
        HaltonRun {
            halton: self,
            index: start,
            reversed: start.reverse_bits(),
            base3: Digits::new(start),
            base5: Digits::new(start),
            base7: Digits::new(start),
        }
    }

    #[inline]
    fn rotate(&self, raw: [f64; 4]) -> [f32; 4] {
        std::array::from_fn(|d| {
            let x = raw[d] + self.offsets[d];
            let x = if x >= 1.0 { x - 1.0 } else { x };
            // Rounding to f32 may reach 1.0: stay inside [0, 1).
            (x as f32).min(1.0 - f32::EPSILON / 2.0)
        })
    }
}

/// The base-2 radical inverse, by reversing the bits (53 of them survive in an f64, so the
/// integer converts exactly, through i64: one instruction on x86-64).
#[inline]
fn base2(index: u64) -> f64 {
    reversed_base2(index.reverse_bits())
}

/// [`base2`] of the index whose bits reversed are `reversed`.
#[inline]
fn reversed_base2(reversed: u64) -> f64 {
    (reversed >> 11) as i64 as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Consecutive points of the sequence, from [`Halton::run`].
pub struct HaltonRun<'a> {
    halton: &'a Halton,
    index: u64,
    /// The index's bits reversed, carried along (see [`HaltonRun::next_point`]).
    reversed: u64,
    base3: Digits<3, { mirrored_digits(3) }>,
    base5: Digits<5, { mirrored_digits(5) }>,
    base7: Digits<7, { mirrored_digits(7) }>,
}

impl HaltonRun<'_> {
    /// The point of the current index; then moves to the next index.
    #[inline]
    pub fn next_point(&mut self) -> [f32; 4] {
        let raw = [reversed_base2(self.reversed), self.base3.value(), self.base5.value(), self.base7.value()];
        self.index = self.index.wrapping_add(1);
        if self.index == 0 {
            // Wrapped past u64::MAX, like the index.
            (self.base3, self.base5, self.base7) = (Digits::new(0), Digits::new(0), Digits::new(0));
            self.reversed = 0;
        } else {
            // Adding 1 flips the index's trailing ones and the zero above them, the lowest
            // z + 1 bits (z = the new index's trailing zeros): in the mirror image, the top z + 1.
            self.reversed ^= !0u64 << (63 - self.index.trailing_zeros());
            self.base3.increment();
            self.base5.increment();
            self.base7.increment();
        }
        self.halton.rotate(raw)
    }
}

/// The number of base-B digits the radical inverse mirrors: the most whose mirror image,
/// an integer below B^L, fits a u64 (40 for base 3, 27 for 5, 22 for 7). Higher digits of an
/// index would add less than B^−L ≤ 2^−63 to the inverse, below an f64's resolution except
/// for the few indices whose lower L digits are all zero (beyond 10^18: never reached).
const fn mirrored_digits(b: u64) -> usize {
    let (mut l, mut p) = (0, 1u64);
    while let Some(q) = p.checked_mul(b) {
        p = q;
        l += 1;
    }
    l
}

/// B^L for L = [`mirrored_digits`] of B.
const fn mirror_span(b: u64) -> u64 {
    b.pow(mirrored_digits(b) as u32)
}

/// An index's lowest L base-B digits (L = [`mirrored_digits`]) and their mirror image
/// M = Σ d_k B^(L−1−k), kept up to date by integer steps as the index is incremented.
#[derive(Clone, Copy)]
struct Digits<const B: u64, const L: usize> {
    /// Digits, lowest first.
    digits: [u8; L],
    mirror: u64,
}

impl<const B: u64, const L: usize> Digits<B, L> {
    /// B^(L−1−k): what digit k adds to the mirror image.
    const PLACE: [u64; L] = {
        let mut place = [0; L];
        let mut k = 0;
        while k < L {
            place[k] = B.pow((L - 1 - k) as u32);
            k += 1;
        }
        place
    };

    fn new(mut i: u64) -> Self {
        let mut digits = [0; L];
        let mut mirror = 0;
        for (d, p) in digits.iter_mut().zip(Self::PLACE) {
            *d = (i % B) as u8;
            mirror += *d as u64 * p;
            i /= B;
        }
        Digits { digits, mirror }
    }

    #[inline]
    fn increment(&mut self) {
        for k in 0..L {
            if (self.digits[k] as u64) < B - 1 {
                self.digits[k] += 1;
                self.mirror += Self::PLACE[k];
                return;
            }
            self.mirror -= (B - 1) * Self::PLACE[k];
            self.digits[k] = 0;
        }
    }

    /// The radical inverse, as [`radical_inverse`] computes it. A mirror image below 2⁶³
    /// converts through i64 (one instruction on x86-64; the same value as through u64).
    #[inline]
    fn value(&self) -> f64 {
        let m =
            if mirror_span(B) <= i64::MAX as u64 { self.mirror as i64 as f64 } else { self.mirror as f64 };
        m * (1.0 / mirror_span(B) as f64)
    }
}

/// The base-B radical inverse: the index's base-B digits mirrored about the radix point.
/// Computed as the mirror image of its lowest L digits as an integer M < B^L (exact), times
/// 1/B^L: two roundings, so within a few f64 ulps of the exact value.
fn radical_inverse<const B: u64>(mut i: u64) -> f64 {
    let mut m = 0u64;
    for _ in 0..mirrored_digits(B) {
        m = m * B + i % B;
        i /= B;
    }
    m as f64 * (1.0 / mirror_span(B) as f64)
}

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The random stream of one photon (SplitMix64 seeded by seed and emission index).
pub struct PhotonRng(u64);

impl PhotonRng {
    /// The stream of photon `index` for `seed`.
    pub fn new(seed: u64, index: u64) -> Self {
        let mut s = seed.wrapping_mul(0xD1B5_4A32_D192_ED03) ^ index;
        PhotonRng(splitmix64(&mut s))
    }

    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        (splitmix64(&mut self.0) >> 40) as f32 * (1.0 / (1u32 << 24) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radical_inverse_mirrors_digits() {
        let close = |a: f64, b: f64| (a - b).abs() <= 4.0 * f64::EPSILON * b;
        assert!(close(radical_inverse::<3>(1), 1.0 / 3.0));
        assert!(close(radical_inverse::<3>(5), 2.0 / 3.0 + 1.0 / 9.0)); // 5 = 12₃ → 0.21₃
        assert!(close(radical_inverse::<7>(50), 1.0 / 7.0 + 1.0 / 343.0)); // 50 = 101₇ → 0.101₇
        // Against the digits summed in f64, on indices of every length.
        let summed = |mut i: u64, b: u64| {
            let (mut r, mut f) = (0.0, 1.0 / b as f64);
            while i > 0 {
                r += (i % b) as f64 * f;
                i /= b;
                f /= b as f64;
            }
            r
        };
        let mut i = 1u64;
        while i < u64::MAX / 3 {
            for j in [i, i + 1, i * 2 + 1] {
                assert!((radical_inverse::<3>(j) - summed(j, 3)).abs() < 1e-15, "{j}");
                assert!((radical_inverse::<5>(j) - summed(j, 5)).abs() < 1e-15, "{j}");
                assert!((radical_inverse::<7>(j) - summed(j, 7)).abs() < 1e-15, "{j}");
            }
            i = i * 3 + 1;
        }
        let h = Halton { offsets: [0.0; 4] };
        assert_eq!(h.point(6)[0], 0.375); // 6 = 110₂ → 0.011₂
        assert_eq!(h.point(0), [0.0; 4]);
    }

    #[test]
    fn runs_equal_points_bit_for_bit() {
        let h = Halton::new(7);
        // Starts just below carries of every base into a new digit, and arbitrary ones.
        for start in [0u64, 1, 48, 124, 242, 342, 2400, 6560, 15_624, 1_000_000, 4_782_968, 40_353_606] {
            let mut run = h.run(start);
            for i in start..start + 3000 {
                assert_eq!(run.next_point(), h.point(i), "index {i} (run from {start})");
            }
        }
        let mut run = h.run(u64::MAX - 5);
        for i in (u64::MAX - 5..=u64::MAX).chain(0..5) {
            assert_eq!(run.next_point(), h.point(i));
        }
    }

    #[test]
    fn rotated_points_stay_stratified() {
        // Any 2^k consecutive indices of the base-2 dimension fall one per stratum of width 2^−k,
        // rotation or not (the rotation shifts the strata, counted modulo 1).
        let h = Halton::new(42);
        let mut strata = [0u32; 64];
        for i in 1000..1064 {
            let x = h.point(i)[0] as f64 - h.offsets[0];
            strata[(x.rem_euclid(1.0) * 64.0) as usize] += 1;
        }
        assert!(strata.iter().all(|&c| c == 1));
        // Mean of each dimension over many points is 1/2.
        let n = 30_000;
        let mut mean = [0.0f64; 4];
        for i in 0..n {
            for (m, x) in mean.iter_mut().zip(h.point(i)) {
                assert!((0.0..1.0).contains(&x));
                *m += x as f64 / n as f64;
            }
        }
        assert!(mean.iter().all(|m| (m - 0.5).abs() < 1e-3), "{mean:?}");
        assert_ne!(Halton::new(1).point(5), Halton::new(2).point(5));
    }

    #[test]
    fn photon_streams_are_uniform_and_reproducible() {
        let mut a = PhotonRng::new(3, 17);
        let mut b = PhotonRng::new(3, 17);
        let mut sum = 0.0;
        for _ in 0..10_000 {
            let x = a.next_f32();
            assert_eq!(x, b.next_f32());
            assert!((0.0..1.0).contains(&x));
            sum += x as f64;
        }
        assert!((sum / 10_000.0 - 0.5).abs() < 0.01);
        assert_ne!(PhotonRng::new(3, 18).next_f32(), PhotonRng::new(3, 17).next_f32());
    }
}
