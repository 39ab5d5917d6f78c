//! The glass sphere's caustic as a 1-D radial quadrature (the radially symmetric check on the
//! 2-D floor truth), and the Fresnel reflectance in angle form.

use std::f64::consts::PI;

/// A glass sphere above a floor under a vertical collimated beam (the default scene): the
/// radially symmetric caustic of the light refracted once in and once out of the sphere.
///
/// A ray at impact parameter b (distance from the axis through the sphere's centre) meets the
/// sphere at incidence θi = asin(b/R), refracts to θt = asin(b/(nR)), leaves at the same angle
/// after a chord, and is deviated by 2(θi − θt) toward the axis; it lands on the floor at a
/// signed radius ρ(b). The flux of the annulus [b, b + db], E0·T(b)·2πb·db, lands on the
/// annulus at |ρ(b)|, so the floor irradiance is E(|ρ|) = Σ E0·T·b / (|ρ|·|dρ/db|) over the
/// rays that land there, infinite on the fold where dρ/db = 0. Cell-averaged irradiance is
/// finite everywhere: [`SphereCaustic::radial`] integrates the flux into annuli by the
/// midpoint rule over b.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SphereCaustic {
    /// Sphere radius, metres.
    pub radius: f64,
    /// Height of the sphere's centre above the floor, metres.
    pub centre_height: f64,
    /// Index of refraction of the glass (the air's is 1).
    pub ior: f64,
    /// Irradiance of the beam, W/m² (power over the emitter's area).
    pub beam_irradiance: f64,
    /// Whether the two interfaces transmit the Fresnel fraction (false: an ideal dielectric
    /// that transmits everything).
    pub fresnel: bool,
}

/// Fresnel reflectance of unpolarised light from incidence angle `ti` to transmission angle
/// `tt` (radians, either side): the mean of the s and p reflectances in angle form.
pub fn fresnel_reflectance(ti: f64, tt: f64) -> f64 {
    if ti.abs() < 1e-12 {
        // Normal incidence: ((n1 − n2)/(n1 + n2))², from the limit of the angle form.
        let n = ti.sin().abs().max(1e-300) / tt.sin().abs().max(1e-300);
        let n = if n.is_finite() { n } else { 1.0 };
        return ((n - 1.0) / (n + 1.0)).powi(2);
    }
    let rs = (ti - tt).sin() / (ti + tt).sin();
    let rp = (ti - tt).tan() / (ti + tt).tan();
    0.5 * (rs * rs + rp * rp)
}

impl SphereCaustic {
    /// The signed landing radius ρ(b) on the floor and the transmittance T(b) of the path for
    /// the ray at impact parameter `b` (0 ≤ b < R); `None` if it does not reach the floor.
    pub fn landing(&self, b: f64) -> Option<(f64, f64)> {
        let (r, n) = (self.radius, self.ior);
        if !(0.0..r).contains(&b) {
            return None;
        }
        let ti = (b / r).asin();
        let tt = (b / (n * r)).asin();
        // Work in the (radial, height) plane with the sphere's centre at the origin. Entry
        // point on the upper hemisphere; the refracted ray turns toward the axis by ti − tt.
        let entry = (b, (r * r - b * b).sqrt());
        let dev = ti - tt;
        let d_in = (-dev.sin(), -dev.cos());
        // Second intersection with the circle: t = −2·(p·d).
        let t = -2.0 * (entry.0 * d_in.0 + entry.1 * d_in.1);
        let exit = (entry.0 + t * d_in.0, entry.1 + t * d_in.1);
        // Leaving, the ray turns toward the axis by the same angle again: 2(ti − tt) in all.
        let d_out = (-(2.0 * dev).sin(), -(2.0 * dev).cos());
        let floor = -self.centre_height;
        if d_out.1 >= 0.0 || exit.1 < floor {
            return None;
        }
        let s = (floor - exit.1) / d_out.1;
        let rho = exit.0 + s * d_out.0;
        let t_path = if self.fresnel {
            let f = fresnel_reflectance(ti, tt);
            (1.0 - f) * (1.0 - f)
        } else {
            1.0
        };
        Some((rho, t_path))
    }

    /// Cell-averaged irradiance (W/m²) on the floor in the annuli between consecutive `edges`
    /// (radii, increasing), from `samples` midpoint-rule steps over the impact parameter.
    pub fn radial(&self, edges: &[f64], samples: usize) -> Vec<f64> {
        let mut flux = vec![0.0; edges.len().saturating_sub(1)];
        let db = self.radius / samples as f64;
        for k in 0..samples {
            let b = (k as f64 + 0.5) * db;
            let Some((rho, t)) = self.landing(b) else { continue };
            let at = rho.abs();
            let bin = edges.partition_point(|&e| e <= at);
            if bin >= 1 && bin < edges.len() {
                flux[bin - 1] += self.beam_irradiance * t * 2.0 * PI * b * db;
            }
        }
        flux.iter()
            .enumerate()
            .map(|(i, f)| f / (PI * (edges[i + 1] * edges[i + 1] - edges[i] * edges[i])))
            .collect()
    }

    /// Total flux (W) carried to the floor by the paths through the sphere, by the same
    /// quadrature.
    pub fn total_flux(&self, samples: usize) -> f64 {
        let db = self.radius / samples as f64;
        (0..samples)
            .filter_map(|k| {
                let b = (k as f64 + 0.5) * db;
                self.landing(b).map(|(_, t)| self.beam_irradiance * t * 2.0 * PI * b * db)
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paraxial_rays_land_at_the_closed_form_focus() {
        // A ball lens focuses paraxial rays n·R/(2(n − 1)) beyond its centre.
        let s = SphereCaustic {
            radius: 0.5,
            centre_height: 0.75,
            ior: 1.5,
            beam_irradiance: 1.0,
            fresnel: false,
        };
        let (rho, t) = s.landing(1e-4).unwrap();
        assert!(rho.abs() < 1e-6, "paraxial ray lands at {rho}");
        assert_eq!(t, 1.0);
        // Beyond the focus, a paraxial ray lands at ρ ≈ b·(1 − z/f), z below the centre (both
        // principal planes of a ball lens pass through its centre): twice as far, mirrored.
        let s2 = SphereCaustic { centre_height: 1.5, ..s };
        let (rho, _) = s2.landing(1e-3).unwrap();
        assert!((rho - 1e-3 * (1.0 - 1.5 / 0.75)).abs() < 1e-8, "{rho}");
    }

    #[test]
    fn ideal_total_flux_is_the_beam_through_the_disc_and_fresnel_matches_normal_incidence() {
        let s = SphereCaustic {
            radius: 0.5,
            centre_height: 0.8,
            ior: 1.5,
            beam_irradiance: 10.0,
            fresnel: false,
        };
        // Rays deviated by more than 90° (b near R) leave upward and never reach the floor:
        // the floor receives the beam through the disc of radius b*, where 2(θi − θt) = π/2.
        let (mut lo, mut hi) = (0.0, 0.5);
        for _ in 0..100 {
            let b = 0.5 * (lo + hi);
            let dev = 2.0 * ((b / 0.5f64).asin() - (b / 0.75f64).asin());
            if dev < PI / 2.0 { lo = b } else { hi = b }
        }
        let want = 10.0 * PI * lo * lo;
        assert!((s.total_flux(100_000) / want - 1.0).abs() < 1e-4, "{} vs {want}", s.total_flux(100_000));
        assert!(lo > 0.45 && lo < 0.5, "b* = {lo}");
        // ((n − 1)/(n + 1))² = 0.04 at normal incidence for n = 1.5.
        assert!((fresnel_reflectance(1e-13, 1e-13 / 1.5) - 0.04).abs() < 1e-9);
        assert!((fresnel_reflectance(0.1, (0.1f64.sin() / 1.5).asin()) - 0.04).abs() < 1e-3);
        // The annuli hold exactly the flux of the rays landing inside the last edge (near-90°
        // rays land farther out).
        let edges: Vec<f64> = (0..=400).map(|i| i as f64 * 0.005).collect();
        let e = s.radial(&edges, 200_000);
        let sum: f64 =
            e.iter().enumerate().map(|(i, x)| x * PI * (edges[i + 1].powi(2) - edges[i].powi(2))).sum();
        let db = 0.5 / 200_000.0;
        let inside: f64 = (0..200_000)
            .filter_map(|k| {
                let b = (k as f64 + 0.5) * db;
                s.landing(b).filter(|(rho, _)| rho.abs() < 2.0).map(|_| 10.0 * 2.0 * PI * b * db)
            })
            .sum();
        assert!((sum / inside - 1.0).abs() < 1e-9, "{sum} vs {inside}");
        assert!(inside > 0.9 * s.total_flux(200_000));
    }
}
