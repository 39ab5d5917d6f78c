//! Emitters and their parameterisations: where a photon leaves, in which direction, and the
//! trajectory parameters that record it.
//!
//! | emitter | sample (s, t) ∈ [0,1)² | trajectory parameters |
//! | --- | --- | --- |
//! | collimated rectangle | the point origin + s·edge_u + t·edge_v | (u, v) = (s, t), 2 dims |
//! | point | a uniform direction on the sphere | the unit direction, 3 dims |
//! | spot | a cosine-weighted direction in the cone | the unit direction, 3 dims |

use glam::Vec3;

use super::shape::Ray;
use crate::format::{self, EmitterKind, Parameterisation};

/// A light source with its power.
#[derive(Clone, Debug, PartialEq)]
pub struct Emitter {
    /// Where and in which directions it emits.
    pub kind: EmitterShape,
    /// Emitted power, watts, summed over RGB.
    pub power_w: f64,
    /// Relative RGB colour; a photon's flux is split over RGB in these proportions.
    pub colour: Vec3,
}

/// The geometry of an emitter, world space, metres.
#[derive(Clone, Debug, PartialEq)]
pub enum EmitterShape {
    /// A rectangle `origin + u·edge_u + v·edge_v` emitting parallel rays along the unit
    /// `direction` (not in the rectangle's plane; by default its normal edge_u × edge_v).
    Collimated {
        /// The corner at (u, v) = (0, 0).
        origin: Vec3,
        /// The edge along u.
        edge_u: Vec3,
        /// The edge along v.
        edge_v: Vec3,
        /// The unit direction of every ray.
        direction: Vec3,
    },
    /// An isotropic point light.
    Point {
        /// Where the light is.
        position: Vec3,
    },
    /// A Lambertian point light: cosine-weighted about `axis` within `half_angle_rad` (≤ π/2;
    /// π/2 is the whole hemisphere).
    Spot {
        /// Where the light is.
        position: Vec3,
        /// The unit axis of the cone.
        axis: Vec3,
        /// The cone's half angle, radians.
        half_angle_rad: f32,
    },
}

impl Emitter {
    /// The emission ray for a sample (s, t) ∈ [0,1)², and its trajectory parameters
    /// (trailing unused components zero).
    #[inline(always)]
    pub fn emit(&self, s: f32, t: f32) -> (Ray, [f32; 3]) {
        match self.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, direction } => {
                (Ray::new(origin + s * edge_u + t * edge_v, direction), [s, t, 0.0])
            }
            EmitterShape::Point { position } => {
                let z = 1.0 - 2.0 * s;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let (sin, cos) = (std::f32::consts::TAU * t).sin_cos();
                let d = Vec3::new(r * cos, r * sin, z);
                (Ray::new(position, d), d.to_array())
            }
            EmitterShape::Spot { position, axis, half_angle_rad } => {
                // Cosine-weighted in the cone: sin²θ is uniform on [0, sin²θmax].
                let sin_max = half_angle_rad.sin();
                let sin2 = s * sin_max * sin_max;
                let (st, ct) = (sin2.sqrt(), (1.0 - sin2).max(0.0).sqrt());
                let (sin, cos) = (std::f32::consts::TAU * t).sin_cos();
                let (b1, b2) = axis.any_orthonormal_pair();
                let d = (b1 * (st * cos) + b2 * (st * sin) + axis * ct).normalize();
                (Ray::new(position, d), d.to_array())
            }
        }
    }

    /// The emission ray a photon's stored trajectory parameters stand for.
    pub fn ray_from_params(&self, params: &[f32]) -> Option<Ray> {
        match self.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, direction } => {
                let [u, v] = [*params.first()?, *params.get(1)?];
                Some(Ray::new(origin + u * edge_u + v * edge_v, direction))
            }
            EmitterShape::Point { position } | EmitterShape::Spot { position, .. } => {
                let d = Vec3::new(*params.first()?, *params.get(1)?, *params.get(2)?);
                Some(Ray::new(position, d.try_normalize()?))
            }
        }
    }

    /// The emitter with every length multiplied by `f` > 0 (about the origin); its power in
    /// watts is kept.
    pub fn scaled(&self, f: f32) -> Emitter {
        let kind = match self.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, direction } => EmitterShape::Collimated {
                origin: origin * f,
                edge_u: edge_u * f,
                edge_v: edge_v * f,
                direction,
            },
            EmitterShape::Point { position } => EmitterShape::Point { position: position * f },
            EmitterShape::Spot { position, axis, half_angle_rad } => {
                EmitterShape::Spot { position: position * f, axis, half_angle_rad }
            }
        };
        Emitter { kind, ..self.clone() }
    }

    /// Points whose bounding box holds where the emitter's photons start.
    pub fn extent_points(&self) -> Vec<Vec3> {
        match self.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, .. } => {
                vec![origin, origin + edge_u, origin + edge_v, origin + edge_u + edge_v]
            }
            EmitterShape::Point { position } | EmitterShape::Spot { position, .. } => vec![position],
        }
    }

    /// Number of trajectory parameters: 2 ((u, v)) or 3 (a direction), plus the wavelength
    /// when `spectral` (the scene disperses light: docs/spectral.md).
    pub fn param_dims(&self, spectral: bool) -> u32 {
        let base = match self.kind {
            EmitterShape::Collimated { .. } => 2,
            _ => 3,
        };
        base + u32::from(spectral)
    }

    /// Area of the parameter manifold: the rectangle in m², or the emission solid angle in sr.
    pub fn param_measure(&self) -> f64 {
        match self.kind {
            EmitterShape::Collimated { edge_u, edge_v, .. } => edge_u.cross(edge_v).length() as f64,
            EmitterShape::Point { .. } => 4.0 * std::f64::consts::PI,
            EmitterShape::Spot { half_angle_rad, .. } => {
                std::f64::consts::TAU * (1.0 - (half_angle_rad as f64).cos())
            }
        }
    }

    /// The PHM metadata record of this emitter, with a wavelength dimension when `spectral`.
    pub fn record(&self, id: u32, spectral: bool) -> format::Emitter {
        let a = |v: Vec3| serde_json::json!([v.x, v.y, v.z]);
        let (kind, parameterisation, geometry) = match self.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, direction } => (
                EmitterKind::Collimated,
                Parameterisation::RectUv,
                serde_json::json!({ "origin": a(origin), "edge_u": a(edge_u), "edge_v": a(edge_v),
                                    "direction": a(direction) }),
            ),
            EmitterShape::Point { position } => (
                EmitterKind::Point,
                Parameterisation::Direction,
                serde_json::json!({ "position": a(position) }),
            ),
            EmitterShape::Spot { position, axis, half_angle_rad } => (
                EmitterKind::Spot,
                Parameterisation::Direction,
                serde_json::json!({ "position": a(position), "axis": a(axis), "half_angle_rad": half_angle_rad }),
            ),
        };
        let (parameterisation, dimensions) = if spectral {
            let p = parameterisation.with_wavelength();
            (p, p.dimensions())
        } else {
            (parameterisation, Vec::new())
        };
        format::Emitter {
            id,
            kind,
            parameterisation,
            param_dims: self.param_dims(spectral),
            power_w: self.power_w,
            colour: self.colour.to_array(),
            param_measure: Some(self.param_measure()),
            geometry,
            dimensions,
            extra: Default::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> impl Iterator<Item = (f32, f32)> {
        (0..n * n).map(move |k| (((k % n) as f32 + 0.5) / n as f32, ((k / n) as f32 + 0.5) / n as f32))
    }

    #[test]
    fn point_directions_are_uniform_on_the_sphere() {
        let e =
            Emitter { kind: EmitterShape::Point { position: Vec3::ONE }, power_w: 1.0, colour: Vec3::ONE };
        let (mut mean, mut upper, mut n) = (Vec3::ZERO, 0, 0);
        for (s, t) in grid(100) {
            let (r, p) = e.emit(s, t);
            assert!((r.dir.length() - 1.0).abs() < 1e-5 && r.origin == Vec3::ONE);
            assert_eq!(Vec3::from_array(p), r.dir);
            mean += r.dir;
            // Archimedes: the cap z > 0.5 holds a quarter of the sphere's area.
            upper += (r.dir.z > 0.5) as usize;
            n += 1;
        }
        assert!((mean / n as f32).length() < 1e-3);
        assert!((upper as f32 / n as f32 - 0.25).abs() < 2e-3);
        assert!((e.param_measure() - 4.0 * std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn spot_is_cosine_weighted_within_its_cone() {
        let axis = Vec3::new(0.0, 1.0, 1.0).normalize();
        let half = 40f32.to_radians();
        let e = Emitter {
            kind: EmitterShape::Spot { position: Vec3::ZERO, axis, half_angle_rad: half },
            power_w: 1.0,
            colour: Vec3::ONE,
        };
        let mut mean_cos = 0.0;
        let n = 200 * 200;
        for (s, t) in grid(200) {
            let c = e.emit(s, t).0.dir.dot(axis);
            assert!(c >= half.cos() - 1e-5);
            mean_cos += c as f64 / n as f64;
        }
        // E[cos θ] for pdf ∝ cos θ on θ ≤ θm: (2/3)(1 − cos³θm)/sin²θm.
        let (cm, sm) = ((half as f64).cos(), (half as f64).sin());
        assert!((mean_cos - 2.0 / 3.0 * (1.0 - cm.powi(3)) / (sm * sm)).abs() < 1e-4);
        assert!((e.param_measure() - std::f64::consts::TAU * (1.0 - cm)).abs() < 1e-9);
    }

    #[test]
    fn parameters_recreate_the_emission_ray() {
        let c = Emitter {
            kind: EmitterShape::Collimated {
                origin: Vec3::new(-1.0, -1.0, 3.0),
                edge_u: Vec3::X * 2.0,
                edge_v: Vec3::Y * 2.0,
                direction: Vec3::Z,
            },
            power_w: 1.0,
            colour: Vec3::ONE,
        };
        let (ray, p) = c.emit(0.25, 0.75);
        assert_eq!(ray.origin, Vec3::new(-0.5, 0.5, 3.0));
        assert_eq!(c.ray_from_params(&p[..2]), Some(ray));
        assert_eq!(c.param_measure(), 4.0);
        let rec = c.record(0, false);
        assert_eq!((rec.param_dims, rec.parameterisation), (2, Parameterisation::RectUv));
    }
}
