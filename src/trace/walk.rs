//! A photon's walk through the scene: emitted at its Halton point, reflected and refracted by
//! mirrors and dielectrics (Fresnel choices and Russian roulette from its own random stream)
//! until it lands on a diffuse surface or is lost.

use glam::Vec3;

use super::chunks::Scratch;
use super::halton::PhotonRng;
use super::{Landing, StorePolicy, Tracer};
use crate::scene::material::{
    WAVELENGTH_RANGE_NM, fresnel_cosines, reflect, refract_unnormalised, wavelength_rgb_tabulated,
};
use crate::scene::{Dielectric, Material, Ray, Reach};

impl Tracer<'_> {
    /// Traces photon `index`, appending it to `out` if it is stored. Returns whether it was
    /// dropped at the bounce limit. `point` is the Halton point of `index`. With `CULL`, a
    /// photon of an emitter marked in [`Tracer::cull`] whose emission ray cannot meet a
    /// specular surface stops at once.
    // Long because a photon's walk is one loop over its bounces sharing one state (ray, flux,
    // wavelength, the dielectric met last); it is inlined into the chunk loop compiled for AVX.
    #[inline(always)]
    pub(super) fn photon<const CULL: bool>(&self, index: u64, point: [f32; 4], out: &mut Scratch) -> bool {
        let scene = self.scene;
        let [u0, u1, u2, u3] = point;
        let e = self.table.cdf.iter().position(|&c| u0 < c).unwrap_or(self.table.cdf.len() - 1);
        let (mut ray, [p0, p1, p2]) = scene.emitters()[e].emit(u1, u2);
        let mut params = [p0, p1, p2, 0.0];
        if let Some(slot) = self.wavelength_slot[e] {
            params[slot] = wavelength_nm(u3);
        }
        if CULL && self.cull[e] && !scene.may_meet_specular(&ray) {
            return false; // it can never be a caustic photon
        }
        let mut flux = self.table.colour[e];
        let mut rng = PhotonRng::new(self.opts.seed, index);
        let mut wavelength: Option<f32> = None;
        // The dielectric met last, its index of refraction n at this photon's wavelength and
        // 1/n: a dispersion formula is evaluated once per photon and material, not per
        // interface, and the division off each entry's chain of dependent operations.
        // With one dispersive material in the scene its index is computed here, from the
        // Halton coordinate alone, where it overlaps the first ray's intersection instead of
        // following it (the same value as at the first hit: the same wavelength).
        let mut ior: Option<(&Dielectric, f32, f32)> =
            self.dispersive.map(|di| index_of_refraction(di, Some(wavelength_nm(u3))));
        let mut specular = 0u32;
        let mut path = 0.0f32;
        // Which shapes the ray can meet first (the emission ray: any).
        let mut reach = Reach::All;
        // The analytic surface the ray starts on (exactly, not offset), if any.
        let mut leaving: Option<u32> = None;
        loop {
            let found = match leaving {
                Some(s) => scene.intersect_leaving(&ray, reach, s, f32::INFINITY),
                None => scene.intersect_reach(&ray, reach, 0.0, f32::INFINITY),
            };
            let Some(hit) = found else { return false };
            path += hit.t;
            let p = ray.at(hit.t);
            // A continuing ray starts on an analytic surface exactly (a nearby surface, such
            // as the floor a sphere rests on, is then never skipped), on a mesh a ray offset
            // off it (`side` is the normal on the side it continues to).
            let analytic = scene.is_analytic(hit.shape);
            leaving = analytic.then_some(hit.shape);
            let start = |side: Vec3| if analytic { p } else { p + side * scene.ray_offset() };
            let front = ray.dir.dot(hit.normal) < 0.0;
            // Normals facing the side the photon came from.
            let ng = if front { hit.normal } else { -hit.normal };
            let ns = if front { hit.shading } else { -hit.shading };
            match scene.material(hit.shape) {
                Material::Diffuse { .. } => {
                    if specular > 0 || self.opts.store == StorePolicy::Direct {
                        out.push(Landing {
                            position: p,
                            normal: ng,
                            flux,
                            incident: ray.dir,
                            emitter: e as u16,
                            params,
                            path_length: path,
                            bounces: specular.min(255) as u8,
                            emission_offset: (index - out.first) as u16,
                            surface: hit.shape,
                        });
                    }
                    return false;
                }
                Material::Absorber => return false,
                Material::Mirror { reflectance } => {
                    if !roulette(&mut flux, *reflectance, &mut rng) {
                        return false;
                    }
                    let mut d = reflect(ray.dir, ns);
                    if d.dot(ng) <= 0.0 {
                        d = reflect(ray.dir, ng); // the shading normal would send it into the surface
                    }
                    // Renormalised: rounding would otherwise compound over the bounces.
                    ray = Ray::new(start(ng), d.normalize());
                    reach = scene.reach_after(hit.shape, p, ng, &ray);
                }
                Material::Dielectric(di) => {
                    if di.dispersion.is_some() && wavelength.is_none() {
                        let l = wavelength_nm(u3);
                        flux *= wavelength_rgb_tabulated(l);
                        wavelength = Some(l);
                    }
                    let (n, inv_n) = match ior {
                        Some((d, n, inv_n)) if std::ptr::eq(d, di) => (n, inv_n),
                        _ => {
                            let entry = index_of_refraction(di, wavelength);
                            ior = Some(entry);
                            (entry.1, entry.2)
                        }
                    };
                    let eta = if front { inv_n } else { n };
                    let mut normal = ns;
                    let mut refracted = refract_unnormalised(ray.dir, normal, eta);
                    if refracted.is_some_and(|r| r.dir.dot(ng) >= 0.0) || ray.dir.dot(normal) >= 0.0 {
                        // The shading normal disagrees with the geometry: use the facet's.
                        normal = ng;
                        refracted = refract_unnormalised(ray.dir, normal, eta);
                    }
                    let reflects = match refracted {
                        None => true,
                        Some(_) if di.ideal => false,
                        Some(r) => rng.next_f32() < fresnel_cosines(r.cos_i, r.cos_t, eta),
                    };
                    match refracted {
                        Some(r) if !reflects => {
                            if !roulette(&mut flux, di.tint, &mut rng) {
                                return false;
                            }
                            // Renormalised: rounding compounds over the interfaces otherwise
                            // (|d| off by 3e-3 after 8–10 bounces), and a stored direction
                            // must be unit.
                            ray = Ray::new(start(-ng), r.dir.normalize());
                            reach = scene.reach_after(hit.shape, p, -ng, &ray);
                        }
                        _ => {
                            let mut d = reflect(ray.dir, normal);
                            if d.dot(ng) <= 0.0 {
                                d = reflect(ray.dir, ng);
                            }
                            ray = Ray::new(start(ng), d.normalize());
                            reach = scene.reach_after(hit.shape, p, ng, &ray);
                        }
                    }
                }
            }
            specular += 1;
            if specular > self.opts.max_bounces {
                return true;
            }
        }
    }
}

/// The wavelength, nm, of a photon whose fourth Halton coordinate is `u3`: uniform on
/// [`WAVELENGTH_RANGE_NM`].
#[inline(always)]
fn wavelength_nm(u3: f32) -> f32 {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    lo + (hi - lo) * u3
}

/// A photon's cached entry for dielectric `di` at its wavelength: the material, n and 1/n.
#[inline(always)]
fn index_of_refraction(di: &Dielectric, wavelength_nm: Option<f32>) -> (&Dielectric, f32, f32) {
    let n = di.ior_at(wavelength_nm);
    (di, n, 1.0 / n)
}

/// Multiplies `flux` by the attenuation `a` and plays Russian roulette with survival
/// probability max(a), dividing the survivors' flux by it: the expected flux stays `flux·a`.
/// Returns whether the photon survives.
pub(super) fn roulette(flux: &mut Vec3, a: Vec3, rng: &mut PhotonRng) -> bool {
    let p = a.max_element();
    if p >= 1.0 {
        *flux *= a;
        return true;
    }
    if p <= 0.0 || rng.next_f32() >= p {
        return false;
    }
    *flux *= a / p;
    true
}
