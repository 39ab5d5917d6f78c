//! Eye paths through specular surfaces to the first diffuse hit, and direct light there.
//!
//! An eye ray is followed through mirrors (weight × reflectance) and dielectrics (Fresnel
//! reflectance F for unpolarised light: either split into a reflected branch of weight F and a
//! refracted one of weight (1 − F)·tint, or one of them chosen with probability F) until it
//! meets a diffuse surface, where a [`DiffuseHit`] records the point, the normal
//! facing the eye, the albedo and the path's weight. Radiance is not rescaled by n² at a
//! refraction: the factors cancel on paths that start and end in air, as every path from a
//! camera in air to a floor in air does.
//!
//! Direct light is the irradiance straight from the emitters, with a shadow ray to each
//! (anything in the way blocks it, glass included: light through glass is the caustic):
//!
//! | emitter | irradiance on a surface with normal n at distance d |
//! | --- | --- |
//! | point, power P | E = P/(4π) · cos θ / d² |
//! | spot, half-angle θm | E = P·cos θₑ/(π sin²θm) · cos θ / d² within the cone (θₑ off its axis) |
//! | collimated, rectangle A, direction ω | E = P/(A·|n_A·ω|) · cos θ inside the beam |
//!
//! with P each RGB channel's share of `power_w`, and cos θ = n·(direction to the light).

use std::f32::consts::PI;

use glam::Vec3;

use super::environment::Environment;
use crate::sampling::halton::PhotonRng;
use crate::scene::material::{fresnel, reflect, refract};
use crate::scene::{EmitterShape, Material, Ray, Scene, Shape};

/// How an eye ray meeting a dielectric continues.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Specular {
    /// Follow both the reflected (weight F) and the refracted (weight 1 − F) rays.
    Split,
    /// Follow one: reflected with probability F, refracted otherwise, weight 1.
    Sample,
}

/// Limits on eye paths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeOptions {
    /// How a path continues at a dielectric.
    pub specular: Specular,
    /// Specular interactions after which a path is dropped.
    pub max_depth: u32,
    /// Split branches whose weight falls below this (in every channel) are dropped.
    pub min_weight: f32,
    /// Pass straight through specular surfaces, unbent (measurement views of a receiver).
    pub see_through: bool,
}

impl Default for EyeOptions {
    fn default() -> Self {
        EyeOptions { specular: Specular::Split, max_depth: 16, min_weight: 1e-3, see_through: false }
    }
}

/// Where an eye path reached a diffuse surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiffuseHit {
    /// The hit point, metres.
    pub point: Vec3,
    /// Unit geometric normal on the side the eye ray came from.
    pub normal: Vec3,
    /// The surface's albedo ρ per RGB channel.
    pub albedo: Vec3,
    /// Product of the specular reflectances and transmittances along the path.
    pub weight: Vec3,
    /// The eye ray's direction at the hit.
    pub dir: Vec3,
}

/// Follows `ray` through specular surfaces and appends its diffuse hits to `out`. Returns the
/// radiance of `background` that its branches see where they leave the scene, each times its
/// path's weight (zero without a background).
pub fn eye_path(
    scene: &Scene,
    ray: Ray,
    opts: &EyeOptions,
    background: Option<&Environment>,
    rng: &mut PhotonRng,
    out: &mut Vec<DiffuseHit>,
) -> Vec3 {
    let mut stack = vec![(ray, Vec3::ONE, 0u32)];
    let mut escaped = Vec3::ZERO;
    while let Some((ray, weight, depth)) = stack.pop() {
        let Some(hit) = scene.intersect(&ray, 0.0, f32::INFINITY) else {
            if let Some(env) = background {
                escaped += weight * env.radiance(ray.dir);
            }
            continue;
        };
        let p = ray.at(hit.t);
        let front = ray.dir.dot(hit.normal) < 0.0;
        let ng = if front { hit.normal } else { -hit.normal };
        let ns = if front { hit.shading } else { -hit.shading };
        let material = scene.material(hit.shape);
        if opts.see_through && material.is_specular() {
            stack.push((Ray::new(p - ng * scene.ray_offset(), ray.dir), weight, depth));
            continue;
        }
        if depth >= opts.max_depth && material.is_specular() {
            continue;
        }
        let alive = |w: Vec3| w.max_element() >= opts.min_weight;
        match material {
            Material::Diffuse { albedo } => {
                out.push(DiffuseHit { point: p, normal: ng, albedo: *albedo, weight, dir: ray.dir });
            }
            Material::Absorber => {}
            Material::Mirror { reflectance } => {
                let w = weight * *reflectance;
                if alive(w) {
                    stack.push((
                        Ray::new(p + ng * scene.ray_offset(), mirror(ray.dir, ns, ng)),
                        w,
                        depth + 1,
                    ));
                }
            }
            Material::Dielectric(di) => {
                let n = di.ior;
                let eta = if front { 1.0 / n } else { n };
                let mut normal = ns;
                let mut refracted = refract(ray.dir, normal, eta);
                if refracted.is_some_and(|t| t.dot(ng) >= 0.0) || ray.dir.dot(normal) >= 0.0 {
                    normal = ng; // the shading normal disagrees with the geometry
                    refracted = refract(ray.dir, normal, eta);
                }
                let f = match refracted {
                    None => 1.0,
                    Some(_) if di.ideal => 0.0,
                    Some(_) => fresnel(-ray.dir.dot(normal), eta),
                };
                let reflected = Ray::new(p + ng * scene.ray_offset(), mirror(ray.dir, normal, ng));
                let transmitted = refracted.map(|t| Ray::new(p - ng * scene.ray_offset(), t));
                match opts.specular {
                    Specular::Split => {
                        if alive(weight * f) {
                            stack.push((reflected, weight * f, depth + 1));
                        }
                        if let Some(t) = transmitted
                            && alive(weight * (1.0 - f) * di.tint)
                        {
                            stack.push((t, weight * (1.0 - f) * di.tint, depth + 1));
                        }
                    }
                    Specular::Sample => match transmitted {
                        Some(t) if rng.next_f32() >= f => {
                            if alive(weight * di.tint) {
                                stack.push((t, weight * di.tint, depth + 1));
                            }
                        }
                        _ => stack.push((reflected, weight, depth + 1)),
                    },
                }
            }
        }
    }
    escaped
}

/// Mirror direction about the shading normal, or the geometric one when the shading normal
/// would send the ray into the surface.
fn mirror(d: Vec3, ns: Vec3, ng: Vec3) -> Vec3 {
    let r = reflect(d, ns);
    if r.dot(ng) > 0.0 { r } else { reflect(d, ng) }
}

/// One emitter, prepared for direct lighting.
#[derive(Clone, Debug)]
enum Light {
    Point {
        position: Vec3,
        intensity: Vec3,
    },
    /// `norm` = P/(π sin²θm): intensity per unit cos θₑ.
    Spot {
        position: Vec3,
        axis: Vec3,
        cos_max: f32,
        norm: Vec3,
    },
    /// `irradiance` across the beam (normal to `direction`), W/m² per channel.
    Collimated {
        rect: Shape,
        direction: Vec3,
        irradiance: Vec3,
    },
}

/// The scene's emitters, prepared for direct lighting.
#[derive(Clone, Debug)]
pub struct Lights {
    lights: Vec<Light>,
}

impl Lights {
    /// The emitters of `scene` as lights (a degenerate collimated rectangle gives none), each
    /// one's power split over RGB in proportion to its colour.
    pub fn new(scene: &Scene) -> Lights {
        let lights = scene
            .emitters()
            .iter()
            .filter_map(|e| {
                let sum = e.colour.element_sum();
                let power = if sum > 0.0 { e.colour / sum * e.power_w as f32 } else { Vec3::ZERO };
                Some(match e.kind {
                    EmitterShape::Point { position } => {
                        Light::Point { position, intensity: power / (4.0 * PI) }
                    }
                    EmitterShape::Spot { position, axis, half_angle_rad } => {
                        let s = half_angle_rad.sin();
                        Light::Spot {
                            position,
                            axis,
                            cos_max: half_angle_rad.cos(),
                            norm: power / (PI * s * s),
                        }
                    }
                    EmitterShape::Collimated { origin, edge_u, edge_v, direction } => {
                        let rect = Shape::rectangle(origin, edge_u, edge_v)?;
                        let area_across = edge_u.cross(edge_v).dot(direction).abs();
                        Light::Collimated { rect, direction, irradiance: power / area_across }
                    }
                })
            })
            .collect();
        Lights { lights }
    }

    /// Direct irradiance at `p` on a surface with unit normal `n` (facing the side lit),
    /// W/m² per channel; see the module docs for the closed forms.
    pub fn irradiance(&self, scene: &Scene, p: Vec3, n: Vec3) -> Vec3 {
        let origin = p + n * scene.ray_offset();
        let mut e = Vec3::ZERO;
        for light in &self.lights {
            // Distances from the surface point itself; only the shadow ray starts off it.
            let (to_light, intensity, target) = match *light {
                Light::Point { position, intensity } => {
                    let d = position - p;
                    (d.normalize(), intensity / d.length_squared(), position)
                }
                Light::Spot { position, axis, cos_max, norm } => {
                    let d = position - p;
                    let cos_e = -d.normalize().dot(axis);
                    if cos_e < cos_max {
                        continue;
                    }
                    (d.normalize(), norm * cos_e / d.length_squared(), position)
                }
                Light::Collimated { ref rect, direction, irradiance } => {
                    let back = Ray::new(origin, -direction);
                    let Some((t, _)) = rect.intersect(&back, 0.0, f32::INFINITY) else { continue };
                    (-direction, irradiance, back.at(t))
                }
            };
            let cos = n.dot(to_light);
            let dist = (target - origin).length();
            if cos.is_nan() || cos <= 0.0 || !dist.is_finite() {
                continue;
            }
            if scene
                .intersect(&Ray::new(origin, (target - origin) / dist), 0.0, dist * (1.0 - 1e-5))
                .is_some()
            {
                continue;
            }
            e += intensity * cos;
        }
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn scene(src: &str) -> Scene {
        Scene::parse(src, "test.toml", Path::new(".")).unwrap()
    }

    const FLOOR: &str = r#"
[materials.floor]
kind = "diffuse"
albedo = [0.5, 0.5, 0.5]
[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
"#;

    #[test]
    fn point_light_follows_the_inverse_square_cosine_law() {
        // P = 12 W white at height h = 2: E(x) = P/3/(4π) · h / (h² + x²)^{3/2} per channel.
        let s =
            scene(&format!("{FLOOR}\n[[emitters]]\nkind = \"point\"\nposition = [0, 0, 2]\npower_w = 12\n"));
        let lights = Lights::new(&s);
        for x in [0.0f32, 0.5, 1.0, 3.0, 10.0] {
            let e = lights.irradiance(&s, Vec3::new(x, 0.0, 0.0), Vec3::Z);
            let expected = 4.0 / (4.0 * PI) * 2.0 / (4.0 + x * x).powf(1.5);
            assert!((e.x / expected - 1.0).abs() < 1e-5, "x = {x}: {e} vs {expected}");
            assert_eq!(e.x, e.y);
        }
        // The underside of the floor sees nothing.
        assert_eq!(lights.irradiance(&s, Vec3::ZERO, -Vec3::Z), Vec3::ZERO);
    }

    #[test]
    fn shadow_rays_are_blocked_by_any_surface_glass_included() {
        let src = format!(
            "{FLOOR}\n[materials.glass]\nkind = \"dielectric\"\nior = 1.5\n[[emitters]]\nkind = \"point\"\n\
             position = [0, 0, 2]\npower_w = 12\n[[shapes]]\nkind = \"sphere\"\ncenter = [0, 0, 1]\n\
             radius = 0.2\nmaterial = \"glass\"\n"
        );
        let s = scene(&src);
        let lights = Lights::new(&s);
        assert_eq!(lights.irradiance(&s, Vec3::ZERO, Vec3::Z), Vec3::ZERO);
        assert!(lights.irradiance(&s, Vec3::new(1.0, 0.0, 0.0), Vec3::Z).x > 0.0);
    }

    #[test]
    fn spot_and_collimated_closed_forms() {
        // Spot straight down, half-angle 30°, P = 3 W (1 W per channel): on axis at h = 1,
        // E = 1/(π sin²30°) = 4/π; at 45° off axis it is outside the cone.
        let spot = format!(
            "{FLOOR}\n[[emitters]]\nkind = \"spot\"\nposition = [0, 0, 1]\ndirection = [0, 0, -1]\n\
             half_angle_deg = 30\npower_w = 3\n"
        );
        let s = scene(&spot);
        let l = Lights::new(&s);
        let e = l.irradiance(&s, Vec3::ZERO, Vec3::Z).x;
        assert!((e - 4.0 / PI).abs() < 1e-4, "{e} vs {}", 4.0 / PI);
        // 20° off axis: cos θₑ = cos θ = cos 20°, 1/d² = cos²20°: E = 4/π · cos⁴20°.
        let x = 20f32.to_radians().tan();
        let c = 20f32.to_radians().cos();
        assert!((l.irradiance(&s, Vec3::new(x, 0.0, 0.0), Vec3::Z).x - 4.0 / PI * c.powi(4)).abs() < 1e-4);
        assert_eq!(l.irradiance(&s, Vec3::new(1.0, 0.0, 0.0), Vec3::Z), Vec3::ZERO);
        // Collimated 2 m × 1 m beam of 6 W straight down: 1 W/m² per channel inside, 0 outside;
        // on a plane tilted by 60° the cosine halves it.
        let beam = format!(
            "{FLOOR}\n[[emitters]]\nkind = \"collimated\"\ncenter = [0, 0, 3]\nsize = [2, 1]\n\
             direction = [0, 0, -1]\npower_w = 6\n"
        );
        let s = scene(&beam);
        let l = Lights::new(&s);
        assert!((l.irradiance(&s, Vec3::new(0.9, 0.4, 0.0), Vec3::Z).x - 1.0).abs() < 1e-5);
        assert_eq!(l.irradiance(&s, Vec3::new(1.1, 0.0, 0.0), Vec3::Z), Vec3::ZERO);
        let tilted = Vec3::new(60f32.to_radians().sin(), 0.0, 60f32.to_radians().cos());
        assert!((l.irradiance(&s, Vec3::new(0.0, 0.0, 0.5), tilted).x - 0.5).abs() < 1e-5);
    }

    #[test]
    fn eye_paths_split_at_glass_with_fresnel_weights() {
        // Looking straight down through a slab of glass (n = 1.5) onto the floor: the refracted
        // branch reaches the floor with weight (1 − R)² plus the inner reflections'
        // (1 − R)²R², …; the reflected branch goes up and is lost. R = 0.04.
        let src = format!(
            "{FLOOR}\n[materials.glass]\nkind = \"dielectric\"\nior = 1.5\n[[shapes]]\nkind = \"extrusion\"\n\
             outline = [[-5, -5], [5, -5], [5, 5], [-5, 5]]\nz_range = [0.5, 0.7]\nmaterial = \"glass\"\n\
             [[emitters]]\nkind = \"point\"\nposition = [0, 0, 9]\npower_w = 1\n"
        );
        let s = scene(&src);
        let mut out = Vec::new();
        let mut rng = PhotonRng::new(1, 1);
        let opts = EyeOptions { min_weight: 1e-9, ..Default::default() };
        // A white background: what the paths that leave upwards see.
        let white = Environment::Uniform(Vec3::ONE);
        let escaped = eye_path(
            &s,
            Ray::new(Vec3::new(0.0, 0.0, 2.0), -Vec3::Z),
            &opts,
            Some(&white),
            &mut rng,
            &mut out,
        );
        let total: f32 = out.iter().map(|h| h.weight.x).sum();
        let r = 0.04f32;
        // Geometric series over the inner bounces: (1 − R)² / (1 − R²) = (1 − R)/(1 + R).
        assert!((total - (1.0 - r) / (1.0 + r)).abs() < 1e-4, "{total}");
        // The rest leaves upwards and sees the background: 2R/(1 + R); nothing is lost.
        assert!((escaped.x - 2.0 * r / (1.0 + r)).abs() < 1e-4, "{escaped}");
        assert!((escaped.x + total - 1.0).abs() < 1e-4);
        assert!(
            out.iter().all(|h| h.point.z.abs() < 1e-4 && h.normal == Vec3::Z && h.albedo == Vec3::splat(0.5))
        );
        // Sampling: the mean weight over many paths is the same.
        let opts = EyeOptions { specular: Specular::Sample, ..Default::default() };
        let n = 20_000;
        let mut hits = 0;
        for i in 0..n {
            out.clear();
            let mut rng = PhotonRng::new(2, i);
            eye_path(&s, Ray::new(Vec3::new(0.0, 0.0, 2.0), -Vec3::Z), &opts, None, &mut rng, &mut out);
            hits += out.len();
        }
        assert!((hits as f32 / n as f32 - (1.0 - r) / (1.0 + r)).abs() < 0.01);
        // Seeing through: one hit of weight 1, straight below.
        let opts = EyeOptions { see_through: true, ..Default::default() };
        out.clear();
        eye_path(&s, Ray::new(Vec3::new(0.3, 0.2, 2.0), -Vec3::Z), &opts, None, &mut rng, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].weight, Vec3::ONE);
        assert!((out[0].point - Vec3::new(0.3, 0.2, 0.0)).length() < 1e-4);
    }
}
