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
            digits: [Digits::new(3, start), Digits::new(5, start), Digits::new(7, start)],
        }
    }

    fn rotate(&self, raw: [f64; 4]) -> [f32; 4] {
        std::array::from_fn(|d| {
            let x = raw[d] + self.offsets[d];
            let x = if x >= 1.0 { x - 1.0 } else { x };
            // Rounding to f32 may reach 1.0: stay inside [0, 1).
            (x as f32).min(1.0 - f32::EPSILON / 2.0)
        })
    }
}

/// The base-2 radical inverse, by reversing the bits (53 of them survive in an f64).
fn base2(index: u64) -> f64 {
    (index.reverse_bits() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Consecutive points of the sequence, from [`Halton::run`].
pub struct HaltonRun<'a> {
    halton: &'a Halton,
    index: u64,
    digits: [Digits; 3],
}

impl HaltonRun<'_> {
    /// The point of the current index; then moves to the next index.
    pub fn next_point(&mut self) -> [f32; 4] {
        let raw = [base2(self.index), self.digits[0].value(), self.digits[1].value(), self.digits[2].value()];
        self.index = self.index.wrapping_add(1);
        for d in &mut self.digits {
            if self.index == 0 {
                *d = Digits::new(d.base, 0); // wrapped past u64::MAX, like the index
            } else {
                d.increment();
            }
        }
        self.halton.rotate(raw)
    }
}

/// Most base-B digits a u64 has (B ≥ 3).
const MAX_DIGITS: usize = 41;

/// An index as its base-B digits, lowest first, with each digit's term of the radical
/// inverse, d_k·B^−(k+1), kept ready.
struct Digits {
    base: u8,
    /// Digits in use: the highest non-zero one and those below.
    len: usize,
    digits: [u8; MAX_DIGITS],
    /// B^−(k+1), by repeated multiplication as in [`radical_inverse`].
    weight: [f64; MAX_DIGITS],
    term: [f64; MAX_DIGITS],
}

impl Digits {
    fn new(base: u8, mut i: u64) -> Self {
        let inv = 1.0 / base as f64;
        let mut weight = [0.0; MAX_DIGITS];
        let mut f = inv;
        for w in &mut weight {
            *w = f;
            f *= inv;
        }
        let mut d = Digits { base, len: 0, digits: [0; MAX_DIGITS], weight, term: [0.0; MAX_DIGITS] };
        while i > 0 {
            d.set(d.len, (i % base as u64) as u8);
            d.len += 1;
            i /= base as u64;
        }
        d
    }

    fn set(&mut self, k: usize, digit: u8) {
        self.digits[k] = digit;
        self.term[k] = digit as f64 * self.weight[k];
    }

    fn increment(&mut self) {
        let mut k = 0;
        while k < MAX_DIGITS {
            let d = self.digits[k] + 1;
            if d < self.base {
                self.set(k, d);
                self.len = self.len.max(k + 1);
                return;
            }
            self.set(k, 0);
            k += 1;
        }
    }

    /// The radical inverse: the terms summed lowest digit first, the order of
    /// [`radical_inverse`], so the same rounding. (Terms of zero digits add exact zeros.)
    fn value(&self) -> f64 {
        self.term[..self.len].iter().fold(0.0, |r, &t| r + t)
    }
}

/// The base-B radical inverse: index's base-B digits mirrored about the radix point.
fn radical_inverse<const B: u64>(mut i: u64) -> f64 {
    let inv = 1.0 / B as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += (i % B) as f64 * f;
        i /= B;
        f *= inv;
    }
    r
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
        assert_eq!(radical_inverse::<3>(1), 1.0 / 3.0);
        assert_eq!(radical_inverse::<3>(5), 2.0 / 3.0 + 1.0 / 9.0); // 5 = 12₃ → 0.21₃
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
