//! Materials and the optics they need: reflection, Snell refraction, Fresnel, dispersion and
//! the folding of a photon's wavelength into RGB flux.

use glam::Vec3;

/// How a surface treats a photon.
#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    /// Lambertian diffuse with an RGB `albedo`: where caustic photons are stored.
    Diffuse {
        /// Fraction of irradiance reflected per RGB channel.
        albedo: Vec3,
    },
    /// A perfect mirror reflecting the fraction `reflectance` per RGB channel.
    Mirror {
        /// Fraction of flux reflected per RGB channel.
        reflectance: Vec3,
    },
    /// A smooth dielectric interface: outside (the normal's side) has index 1, inside `ior`.
    Dielectric(Dielectric),
    /// Absorbs every photon that reaches it.
    Absorber,
}

impl Material {
    /// Whether photons continue from it (a mirror or a dielectric): the S of an L S+ D path.
    pub fn is_specular(&self) -> bool {
        matches!(self, Material::Mirror { .. } | Material::Dielectric(_))
    }
}

/// A smooth refracting interface (glass, water).
#[derive(Clone, Debug, PartialEq)]
pub struct Dielectric {
    /// Index of refraction without dispersion (and the value reported for it).
    pub ior: f32,
    /// Wavelength-dependent index, when the material disperses.
    pub dispersion: Option<Dispersion>,
    /// No Fresnel reflection: every photon refracts unless it is totally internally reflected.
    pub ideal: bool,
    /// Fraction of flux passed per RGB channel at each refraction.
    pub tint: Vec3,
}

impl Dielectric {
    /// Index of refraction at `wavelength_nm` (or the plain index without a wavelength).
    pub fn ior_at(&self, wavelength_nm: Option<f32>) -> f32 {
        match (&self.dispersion, wavelength_nm) {
            (Some(d), Some(l)) => d.ior(l),
            _ => self.ior,
        }
    }
}

/// A wavelength-dependent index of refraction; wavelengths in micrometres inside the formulas.
#[derive(Clone, Debug, PartialEq)]
pub enum Dispersion {
    /// n(λ) = A + B/λ² + C/λ⁴ with λ in µm.
    Cauchy {
        /// A, dimensionless.
        a: f64,
        /// B, µm².
        b: f64,
        /// C, µm⁴.
        c: f64,
    },
    /// n²(λ) = 1 + Σ Bᵢ λ² / (λ² − Cᵢ) with λ in µm and Cᵢ in µm².
    Sellmeier {
        /// The Bᵢ, dimensionless.
        b: Vec<f64>,
        /// The Cᵢ, µm², one per Bᵢ.
        c: Vec<f64>,
    },
}

impl Dispersion {
    /// Index of refraction at `wavelength_nm`.
    pub fn ior(&self, wavelength_nm: f32) -> f32 {
        let l = wavelength_nm as f64 * 1e-3;
        let l2 = l * l;
        let n = match self {
            Dispersion::Cauchy { a, b, c } => a + b / l2 + c / (l2 * l2),
            Dispersion::Sellmeier { b, c } => {
                (1.0 + b.iter().zip(c).map(|(b, c)| b * l2 / (l2 - c)).sum::<f64>()).max(0.0).sqrt()
            }
        };
        n as f32
    }
}

/// Mirror reflection of direction `d` about unit normal `n` (either side).
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Snell refraction of unit `d` through the interface with unit normal `n` facing the incoming
/// side (d·n < 0), with `eta` = n_incident / n_transmitted; `None` on total internal reflection.
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    refract_unnormalised(d, n, eta).map(|r| r.dir.normalize())
}

/// A refracted direction with the cosines of incidence and transmission that gave it (the
/// Fresnel reflectance at the same interface needs them too: [`fresnel_cosines`]).
#[derive(Clone, Copy, Debug)]
pub struct Refraction {
    /// The refracted direction.
    pub dir: Vec3,
    /// cos θi, of the angle of incidence (≥ 0).
    pub cos_i: f32,
    /// cos θt, of the angle of refraction (≥ 0).
    pub cos_t: f32,
}

/// [`refract`] without the final normalisation (the tracer's): the vector is unit in exact
/// arithmetic (|t|² = sin²θt + cos²θt = 1), so this skips only a rounding-level correction,
/// and with it a square root and a division on each photon's chain of dependent operations.
#[inline]
pub fn refract_unnormalised(d: Vec3, n: Vec3, eta: f32) -> Option<Refraction> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(Refraction { dir: eta * d + (eta * cos_i - cos_t) * n, cos_i, cos_t })
}

/// Fresnel reflectance of unpolarised light at a dielectric interface (the mean of the s and p
/// reflectances), for incidence cosine `cos_i` ≥ 0 and `eta` = n_incident / n_transmitted;
/// 1 under total internal reflection.
pub fn fresnel(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    fresnel_cosines(cos_i, (1.0 - sin2_t).sqrt(), eta)
}

/// [`fresnel`] from both cosines, as a [`Refraction`] carries them: the same value without
/// computing the transmission cosine again.
#[inline]
pub fn fresnel_cosines(cos_i: f32, cos_t: f32, eta: f32) -> f32 {
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// The visible range photons' wavelengths are drawn from, nm (the range a spectral parameter
/// dimension records in the format).
pub use crate::format::meta::WAVELENGTH_RANGE_NM;

/// Rec. 709 luminance weights of linear sRGB: the luminance of (r, g, b) is their dot product
/// with these (tone mapping, the error measures, the flux spread of refinement).
pub const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// The luminance of a linear sRGB colour ([`LUMA`]).
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(LUMA[0] as f32, LUMA[1] as f32, LUMA[2] as f32))
}

/// Linear sRGB weight of a wavelength, scaled so that each channel averages 1 over
/// [`WAVELENGTH_RANGE_NM`]: a white photon that takes a uniformly drawn wavelength and
/// multiplies its flux by this keeps its expected RGB flux (so white light stays white).
pub fn wavelength_rgb(wavelength_nm: f32) -> Vec3 {
    raw_rgb(wavelength_nm) / *RGB_MEAN
}

static RGB_MEAN: std::sync::LazyLock<Vec3> = std::sync::LazyLock::new(|| {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    let n = 4000;
    let sum: glam::DVec3 =
        (0..n).map(|k| raw_rgb(lo + (hi - lo) * (k as f32 + 0.5) / n as f32).as_dvec3()).sum();
    (sum / n as f64).as_vec3()
});

/// Intervals of [`WAVELENGTH_RANGE_NM`] in the table of [`wavelength_rgb_tabulated`].
const RGB_TABLE_INTERVALS: usize = 8192;

/// [`wavelength_rgb`] by linear interpolation in a table (the tracer's: one table look-up
/// instead of eight exponentials per photon). The table holds the colour before the negative
/// lobes are clipped, a smooth function, and the clipping follows the interpolation, so the
/// kinks where a channel reaches zero stay sharp. Over the whole range each channel is within
/// 1e-4 of the formula relative to its value, or 1e-6 absolute where it is near zero (the
/// channels average 1); a unit test checks this. Outside the range: the formula itself.
pub fn wavelength_rgb_tabulated(wavelength_nm: f32) -> Vec3 {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    // In f64: the position between two nodes is then exact to f32 rounding (in f32 the
    // product's rounding alone would shift it by up to 1e-5 nm).
    let x = (wavelength_nm - lo) as f64 * (RGB_TABLE_INTERVALS as f64 / (hi - lo) as f64);
    if !(x >= 0.0 && x < RGB_TABLE_INTERVALS as f64) {
        return wavelength_rgb(wavelength_nm);
    }
    // Through i64, whose conversions to and from f64 are single instructions (usize's are
    // not); x is in [0, 8192), so the value is the same.
    let i = x as i64;
    let f = glam::Vec4::splat((x - i as f64) as f32);
    let table: &[glam::Vec4] = &RGB_TABLE;
    let (a, b) = (table[i as usize], table[i as usize + 1]);
    (a + (b - a) * f).truncate().max(Vec3::ZERO)
}

/// The unclipped colour of [`wavelength_rgb`] at the table's nodes.
static RGB_TABLE: std::sync::LazyLock<Vec<glam::Vec4>> = std::sync::LazyLock::new(|| {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    (0..=RGB_TABLE_INTERVALS)
        .map(|k| {
            // Exact in f32: 380 + k·85/2048 nm has at most 21 significant bits.
            let l = lo + (hi - lo) / RGB_TABLE_INTERVALS as f32 * k as f32;
            (unclipped_rgb(l) / *RGB_MEAN).extend(0.0)
        })
        .collect()
});

/// CIE 1931 colour matching functions by the multi-lobe Gaussian fit of Wyman, Sloan and
/// Shirley (JCGT 2013), converted to linear sRGB with negative lobes clipped.
fn raw_rgb(l: f32) -> Vec3 {
    unclipped_rgb(l).max(Vec3::ZERO)
}

/// [`raw_rgb`] before the clipping: smooth in the wavelength.
fn unclipped_rgb(l: f32) -> Vec3 {
    let g = |mu: f32, s1: f32, s2: f32| {
        let t = (l - mu) / if l < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    };
    let x = 1.056 * g(599.8, 37.9, 31.0) + 0.362 * g(442.0, 16.0, 26.7) - 0.065 * g(501.1, 20.4, 26.2);
    let y = 0.821 * g(568.8, 46.9, 40.5) + 0.286 * g(530.9, 16.3, 31.1);
    let z = 1.217 * g(437.0, 11.8, 36.0) + 0.681 * g(459.0, 26.0, 13.8);
    Vec3::new(
        3.2406 * x - 1.5372 * y - 0.4986 * z,
        -0.9689 * x + 1.8758 * y + 0.0415 * z,
        0.0557 * x - 0.2040 * y + 1.0570 * z,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_matches_closed_form_values() {
        // Normal incidence: ((n1 − n2)/(n1 + n2))² = 0.04 for glass (n = 1.5).
        assert!((fresnel(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel(1.0, 1.5) - 0.04).abs() < 1e-6);
        // Brewster's angle: p-polarised reflectance vanishes, R = Rs/2.
        let tb = 1.5f32.atan();
        let (ci, ct) = (tb.cos(), (1.0 / 1.5 * tb.sin()).asin().cos());
        let rs = ((ci - 1.5 * ct) / (ci + 1.5 * ct)).powi(2);
        assert!((fresnel(ci, 1.0 / 1.5) - 0.5 * rs).abs() < 1e-6);
        // 45° air→glass: Rs = 0.0920, Rp = 0.00847 (textbook values), mean 0.0502.
        assert!((fresnel(45f32.to_radians().cos(), 1.0 / 1.5) - 0.0502).abs() < 2e-4);
        // Grazing incidence reflects everything; beyond the critical angle, TIR.
        assert!((fresnel(0.0, 1.0 / 1.5) - 1.0).abs() < 1e-6);
        let crit = (1.0f32 / 1.5).asin();
        assert_eq!(fresnel((crit + 0.01).cos(), 1.5), 1.0);
        assert!(fresnel((crit - 0.01).cos(), 1.5) < 1.0);
    }

    #[test]
    fn snell_refraction_and_total_internal_reflection() {
        let n = Vec3::Z;
        let theta = 30f32.to_radians();
        let d = Vec3::new(theta.sin(), 0.0, -theta.cos());
        let t = refract(d, n, 1.0 / 1.5).unwrap();
        // n1 sin θ1 = n2 sin θ2.
        assert!((t.x - theta.sin() / 1.5).abs() < 1e-6 && t.z < 0.0 && (t.length() - 1.0).abs() < 1e-6);
        // Glass → air beyond the critical angle 41.81°: total internal reflection.
        let g = 42f32.to_radians();
        assert!(refract(Vec3::new(g.sin(), 0.0, -g.cos()), n, 1.5).is_none());
        let g = 41f32.to_radians();
        let t = refract(Vec3::new(g.sin(), 0.0, -g.cos()), n, 1.5).unwrap();
        assert!((t.x - 1.5 * g.sin()).abs() < 1e-5);
        let r = reflect(d, n);
        assert!((r - Vec3::new(d.x, 0.0, -d.z)).length() < 1e-7);
    }

    #[test]
    fn dispersion_formulas_give_catalogue_indices() {
        // Schott N-BK7 Sellmeier coefficients: n_d (587.6 nm) = 1.5168, n_F (486.1) = 1.5224.
        let bk7 = Dispersion::Sellmeier {
            b: vec![1.03961212, 0.231792344, 1.01046945],
            c: vec![0.00600069867, 0.0200179144, 103.560653],
        };
        assert!((bk7.ior(587.6) - 1.5168).abs() < 1e-4);
        assert!((bk7.ior(486.1) - 1.5224).abs() < 1e-4);
        let cauchy = Dispersion::Cauchy { a: 1.5046, b: 0.00420, c: 0.0 };
        assert!((cauchy.ior(500.0) - (1.5046 + 0.0042 / 0.25)).abs() < 1e-6);
        assert!(cauchy.ior(400.0) > cauchy.ior(700.0));
    }

    #[test]
    fn wavelength_weights_keep_white_light_white() {
        let (lo, hi) = WAVELENGTH_RANGE_NM;
        let n = 10_000;
        let mean: Vec3 =
            (0..n).map(|k| wavelength_rgb(lo + (hi - lo) * (k as f32 + 0.5) / n as f32)).sum::<Vec3>()
                / n as f32;
        assert!((mean - Vec3::ONE).abs().max_element() < 1e-3, "{mean}");
        // Hue order: red at 650 nm, green at 540 nm, blue at 450 nm dominate.
        let (r, g, b) = (wavelength_rgb(650.0), wavelength_rgb(540.0), wavelength_rgb(450.0));
        assert!(r.x > r.y && r.x > r.z);
        assert!(g.y > g.x && g.y > g.z);
        assert!(b.z > b.x && b.z > b.y);
    }

    #[test]
    fn tabulated_wavelength_weights_match_the_formula() {
        // Every wavelength of the range on a grid far finer than the table's, plus the ends:
        // each channel within 1e-4 of the formula relative to its value, or 1e-6 absolute
        // where the channel is near zero (the mean of each channel is 1).
        let (lo, hi) = WAVELENGTH_RANGE_NM;
        let n = 1_000_000;
        for k in 0..=n {
            let l = (lo + (hi - lo) * (k as f64 / n as f64) as f32).min(hi);
            let (want, got) = (wavelength_rgb(l), wavelength_rgb_tabulated(l));
            for c in 0..3 {
                let err = (got[c] - want[c]).abs();
                assert!(err <= 1e-4 * want[c].abs() + 1e-6, "{l} nm, channel {c}: {} vs {}", got[c], want[c]);
            }
        }
        // Outside the range: the formula itself.
        for l in [300.0, 379.9, 720.0, 800.0] {
            assert_eq!(wavelength_rgb_tabulated(l), wavelength_rgb(l));
        }
    }
}
