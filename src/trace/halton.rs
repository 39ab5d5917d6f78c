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
        let raw = [
            (index.reverse_bits() >> 11) as f64 * (1.0 / (1u64 << 53) as f64),
            radical_inverse::<3>(index),
            radical_inverse::<5>(index),
            radical_inverse::<7>(index),
        ];
        std::array::from_fn(|d| {
            let x = raw[d] + self.offsets[d];
            let x = if x >= 1.0 { x - 1.0 } else { x };
            // Rounding to f32 may reach 1.0: stay inside [0, 1).
            (x as f32).min(1.0 - f32::EPSILON / 2.0)
        })
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
