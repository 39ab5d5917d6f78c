//! Rays, hits and the analytic shapes: sphere, infinite plane, rectangle, disc, open cylinder.
//!
//! Every shape has an outward normal (the side a dielectric's outside medium is on); surfaces are
//! two-sided for intersection, and the hit reports the outward normal whichever side was struck.

use glam::Vec3;

/// A ray `origin + t·dir` with `dir` a unit vector; distances `t` are in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Where it starts, metres.
    pub origin: Vec3,
    /// Its unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// The ray from `origin` along unit `dir`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir }
    }

    /// The point at distance `t` along it.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// Where a ray met a surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray, metres.
    pub t: f32,
    /// Unit outward geometric normal of the surface at the hit.
    pub normal: Vec3,
    /// Unit outward shading normal (interpolated on smooth meshes; equal to `normal` otherwise).
    pub shading: Vec3,
    /// Index of the shape in the scene's shape list (the PHM `surface` id).
    pub shape: u32,
}

/// An analytic shape.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// A sphere; the outward normal points away from its centre.
    Sphere {
        /// Its centre.
        center: Vec3,
        /// Its radius, metres.
        radius: f32,
    },
    /// The plane through `point` with unit `normal`.
    Plane {
        /// A point of the plane.
        point: Vec3,
        /// The unit outward normal.
        normal: Vec3,
    },
    /// The parallelogram `origin + a·edge_u + b·edge_v`, a, b ∈ [0, 1]; normal edge_u × edge_v.
    /// Made by [`Shape::rectangle`], which works out the normal and the dual vectors.
    Rectangle {
        /// The corner at (a, b) = (0, 0).
        origin: Vec3,
        /// The edge along a.
        edge_u: Vec3,
        /// The edge along b.
        edge_v: Vec3,
        /// The unit outward normal, edge_u × edge_v normalised.
        normal: Vec3,
        /// (p − origin)·dual_u = a for a point p of the plane.
        dual_u: Vec3,
        /// (p − origin)·dual_v = b for a point p of the plane.
        dual_v: Vec3,
    },
    /// A flat disc.
    Disc {
        /// Its centre.
        center: Vec3,
        /// The unit outward normal.
        normal: Vec3,
        /// Its radius, metres.
        radius: f32,
    },
    /// The side wall of a cylinder of `radius` around the unit `axis` from `base` to
    /// `base + height·axis`, with no caps; the outward normal points away from the axis.
    Cylinder {
        /// The centre of the bottom rim.
        base: Vec3,
        /// The unit axis, from bottom to top.
        axis: Vec3,
        /// Its radius, metres.
        radius: f32,
        /// Its length along the axis, metres.
        height: f32,
    },
}

impl Shape {
    /// A parallelogram; `None` when the edges are parallel or zero.
    pub fn rectangle(origin: Vec3, edge_u: Vec3, edge_v: Vec3) -> Option<Shape> {
        let n = edge_u.cross(edge_v);
        if n.length_squared() <= f32::EPSILON * edge_u.length_squared() * edge_v.length_squared()
            || n.length_squared() == 0.0
        {
            return None;
        }
        // Dual vectors: (p − origin)·dual_u = a and ·dual_v = b for p in the plane.
        let dual_u = edge_v.cross(n) / edge_u.dot(edge_v.cross(n));
        let dual_v = n.cross(edge_u) / edge_v.dot(n.cross(edge_u));
        Some(Shape::Rectangle { origin, edge_u, edge_v, normal: n.normalize(), dual_u, dual_v })
    }

    /// The shape with every length multiplied by `f` > 0 (about the origin).
    pub fn scaled(&self, f: f32) -> Shape {
        match *self {
            Shape::Sphere { center, radius } => Shape::Sphere { center: center * f, radius: radius * f },
            Shape::Plane { point, normal } => Shape::Plane { point: point * f, normal },
            Shape::Rectangle { origin, edge_u, edge_v, .. } => {
                Shape::rectangle(origin * f, edge_u * f, edge_v * f).unwrap_or_else(|| self.clone())
            }
            Shape::Disc { center, normal, radius } => {
                Shape::Disc { center: center * f, normal, radius: radius * f }
            }
            Shape::Cylinder { base, axis, radius, height } => {
                Shape::Cylinder { base: base * f, axis, radius: radius * f, height: height * f }
            }
        }
    }

    /// Points whose bounding box is the shape's (an infinite plane gives only its `point`).
    pub fn extent_points(&self) -> Vec<Vec3> {
        match *self {
            Shape::Sphere { center, radius } | Shape::Disc { center, radius, .. } => {
                vec![center - Vec3::splat(radius), center + Vec3::splat(radius)]
            }
            Shape::Plane { point, .. } => vec![point],
            Shape::Rectangle { origin, edge_u, edge_v, .. } => {
                vec![origin, origin + edge_u, origin + edge_v, origin + edge_u + edge_v]
            }
            Shape::Cylinder { base, axis, radius, height } => {
                let top = base + axis * height;
                let r = Vec3::splat(radius);
                vec![base - r, base + r, top - r, top + r]
            }
        }
    }

    /// The nearest intersection with `t` in (`t_min`, `t_max`): distance and outward normal.
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, Vec3)> {
        match *self {
            Shape::Sphere { center, radius } => {
                // Solve |o + t d − c|² = r² with the stable form of the quadratic.
                let oc = ray.origin - center;
                let b = oc.dot(ray.dir);
                // Hearn–Baker: r² − |oc − b d|² is more accurate than b² − (|oc|² − r²).
                let perp = oc - b * ray.dir;
                let disc = radius * radius - perp.length_squared();
                if disc < 0.0 {
                    return None;
                }
                let c = oc.length_squared() - radius * radius;
                let q = -b - b.signum() * disc.sqrt();
                let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
                let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
                let t = if t0 > t_min && t0 < t_max {
                    t0
                } else if t1 > t_min && t1 < t_max {
                    t1
                } else {
                    return None;
                };
                // Normalised, not divided by the radius: the hit point is off the sphere by
                // rounding, and a normal a little short or long feeds back (a reflection off it
                // changes the direction's length, which moves the next hit point further off):
                // inside a sphere the error grew tenfold per internal reflection.
                Some((t, (ray.at(t) - center).normalize()))
            }
            Shape::Plane { point, normal } => {
                let t = plane_t(ray, point, normal, t_min, t_max)?;
                Some((t, normal))
            }
            Shape::Rectangle { origin, normal, dual_u, dual_v, .. } => {
                let t = plane_t(ray, origin, normal, t_min, t_max)?;
                let q = ray.at(t) - origin;
                let (a, b) = (q.dot(dual_u), q.dot(dual_v));
                ((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)).then_some((t, normal))
            }
            Shape::Disc { center, normal, radius } => {
                let t = plane_t(ray, center, normal, t_min, t_max)?;
                ((ray.at(t) - center).length_squared() <= radius * radius).then_some((t, normal))
            }
            Shape::Cylinder { base, axis, radius, height } => {
                // Work in the plane perpendicular to the axis.
                let oc = ray.origin - base;
                let d_perp = ray.dir - axis * ray.dir.dot(axis);
                let o_perp = oc - axis * oc.dot(axis);
                let a = d_perp.length_squared();
                if a == 0.0 {
                    return None; // parallel to the axis: runs along the wall, never crosses it
                }
                let b = o_perp.dot(d_perp);
                // Distance of the axis from the ray's closest approach, squared, for stability.
                let closest = o_perp - d_perp * (b / a);
                let disc = a * (radius * radius - closest.length_squared());
                if disc < 0.0 {
                    return None;
                }
                let q = -b - b.signum() * disc.sqrt();
                if q == 0.0 {
                    return None;
                }
                let c = o_perp.length_squared() - radius * radius;
                let (r0, r1) = (q / a, c / q);
                let (r0, r1) = if r0 <= r1 { (r0, r1) } else { (r1, r0) };
                for t in [r0, r1] {
                    if t > t_min && t < t_max {
                        let p = ray.at(t) - base;
                        let h = p.dot(axis);
                        if (0.0..=height).contains(&h) {
                            // Normalised for the reason given for the sphere.
                            return Some((t, (p - axis * h).normalize()));
                        }
                    }
                }
                None
            }
        }
    }
}

/// Distance along the ray to the plane through `point` with `normal`, if in (`t_min`, `t_max`).
fn plane_t(ray: &Ray, point: Vec3, normal: Vec3, t_min: f32, t_max: f32) -> Option<f32> {
    let denom = ray.dir.dot(normal);
    if denom == 0.0 {
        return None;
    }
    let num = (point - ray.origin).dot(normal);
    // A ray leaving the plane behind it (the quotient ≤ 0) needs no division when t_min ≥ 0:
    // the case of every photon heading away from the floor.
    if t_min >= 0.0 && (num > 0.0) != (denom > 0.0) {
        return None;
    }
    let t = num / denom;
    (t > t_min && t < t_max).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn random_unit(rng: &mut Pcg64Mcg) -> Vec3 {
        loop {
            let v = Vec3::new(
                rng.random::<f32>() * 2.0 - 1.0,
                rng.random::<f32>() * 2.0 - 1.0,
                rng.random::<f32>() * 2.0 - 1.0,
            );
            if v.length_squared() > 0.01 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }

    #[test]
    fn sphere_hit_from_outside_and_inside_matches_closed_form() {
        let s = Shape::Sphere { center: Vec3::new(1.0, 2.0, 3.0), radius: 2.0 };
        let r = Ray::new(Vec3::new(1.0, 2.0, -7.0), Vec3::Z);
        let (t, n) = s.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!((t - 8.0).abs() < 1e-5 && (n - Vec3::NEG_Z).length() < 1e-6);
        // From the centre: the far wall at distance r, outward normal along the ray.
        let r = Ray::new(Vec3::new(1.0, 2.0, 3.0), Vec3::X);
        let (t, n) = s.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!((t - 2.0).abs() < 1e-6 && (n - Vec3::X).length() < 1e-6);
        // Offset ray: t = 10 − sqrt(r² − h²).
        let r = Ray::new(Vec3::new(1.0, 3.5, -7.0), Vec3::Z);
        let (t, _) = s.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!((t - (10.0 - (4.0f32 - 2.25).sqrt())).abs() < 1e-5);
        assert!(s.intersect(&Ray::new(Vec3::new(1.0, 4.5, -7.0), Vec3::Z), 1e-4, f32::INFINITY).is_none());
    }

    #[test]
    fn sphere_hits_lie_on_the_sphere_for_random_rays() {
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let c = Vec3::new(0.3, -0.2, 0.5);
        let s = Shape::Sphere { center: c, radius: 0.7 };
        let mut hits = 0;
        for _ in 0..2000 {
            let o = random_unit(&mut rng) * 3.0;
            let target = c + random_unit(&mut rng) * 0.9;
            let r = Ray::new(o, (target - o).normalize());
            // Brute force: march the closest-approach distance.
            let tc = (c - o).dot(r.dir);
            let dmin = (r.at(tc) - c).length();
            match s.intersect(&r, 1e-4, f32::INFINITY) {
                Some((t, n)) => {
                    hits += 1;
                    assert!(((r.at(t) - c).length() - 0.7).abs() < 1e-5);
                    assert!((n.length() - 1.0).abs() < 1e-5);
                    assert!(t <= tc + 1e-4, "nearest root first");
                }
                None => assert!(dmin >= 0.7 - 1e-5, "missed at distance {dmin}"),
            }
        }
        assert!(hits > 500);
    }

    /// A ray reflected 200 times inside a sphere (and a cylinder) keeps a unit direction to
    /// rounding: the normals are unit, so the rounding of each hit point does not feed back
    /// into the direction's length (with the normal as offset / radius, the error grew
    /// tenfold per reflection: 1.4e-3 after 7 inside the default scene's sphere).
    #[test]
    fn repeated_internal_reflections_keep_directions_unit() {
        let shapes = [
            Shape::Sphere { center: Vec3::new(0.0, 0.0, 0.8), radius: 0.5 },
            Shape::Cylinder { base: Vec3::new(0.1, 0.0, -5.0), axis: Vec3::Z, radius: 0.5, height: 1e4 },
        ];
        for s in &shapes {
            let mut ray = Ray::new(Vec3::new(0.05, 0.02, 0.8), Vec3::new(0.3, 0.2, 0.05).normalize());
            for k in 0..200 {
                let (t, n) =
                    s.intersect(&ray, 1e-4, f32::INFINITY).unwrap_or_else(|| panic!("{s:?}: lost at {k}"));
                assert!((n.length() - 1.0).abs() < 3e-7, "{s:?}: |n| = {} at {k}", n.length());
                let d = crate::scene::material::reflect(ray.dir, n);
                ray = Ray::new(ray.at(t) - n * 1e-5, d);
                // Rounding alone: at most about an ulp per reflection (linear, not growing).
                let err = (d.length() - 1.0).abs();
                assert!(err < 2.5e-7 * (k + 1) as f32, "{s:?}: |d| off by {err} after {} reflections", k + 1);
            }
        }
    }

    #[test]
    fn plane_rectangle_and_disc_against_closed_forms() {
        let p = Shape::Plane { point: Vec3::new(0.0, 0.0, 1.0), normal: Vec3::Z };
        let r = Ray::new(Vec3::new(0.5, 0.5, 3.0), Vec3::new(0.0, 0.6, -0.8));
        let (t, n) = p.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!((t - 2.5).abs() < 1e-6 && n == Vec3::Z);
        assert!(p.intersect(&Ray::new(r.origin, Vec3::X), 1e-4, f32::INFINITY).is_none());
        assert!(p.intersect(&r, 1e-4, 2.0).is_none());

        let rect = Shape::rectangle(Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)).unwrap();
        let down = |x: f32, y: f32| Ray::new(Vec3::new(x, y, 1.0), Vec3::NEG_Z);
        assert!(rect.intersect(&down(1.5, 0.5), 0.0, 9.0).is_some());
        assert!(rect.intersect(&down(0.2, 0.5), 0.0, 9.0).is_none()); // left of the slanted edge
        assert!(rect.intersect(&down(2.8, 0.9), 0.0, 9.0).is_some());
        assert!(rect.intersect(&down(1.0, 1.1), 0.0, 9.0).is_none());
        assert!(Shape::rectangle(Vec3::ZERO, Vec3::X, Vec3::X * 2.0).is_none());

        let disc = Shape::Disc { center: Vec3::ZERO, normal: Vec3::Z, radius: 1.0 };
        assert!(disc.intersect(&down(0.7, 0.7), 0.0, 9.0).is_some());
        assert!(disc.intersect(&down(0.71, 0.71), 0.0, 9.0).is_none());
    }

    #[test]
    fn open_cylinder_against_closed_forms() {
        let c = Shape::Cylinder { base: Vec3::ZERO, axis: Vec3::Z, radius: 1.0, height: 0.5 };
        // From outside along x at mid height: hits the near wall at x = −1.
        let r = Ray::new(Vec3::new(-3.0, 0.0, 0.25), Vec3::X);
        let (t, n) = c.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!((t - 2.0).abs() < 1e-5 && (n - Vec3::NEG_X).length() < 1e-5);
        // From inside: the far wall, normal outward.
        let r = Ray::new(Vec3::new(0.0, 0.5, 0.25), Vec3::X);
        let (t, n) = c.intersect(&r, 1e-4, f32::INFINITY).unwrap();
        assert!(
            (t - 0.75f32.sqrt()).abs() < 1e-5 && (n - Vec3::new(0.75f32.sqrt(), 0.5, 0.0)).length() < 1e-5
        );
        // Above the rim: nothing; steep ray entering through the open top hits the inside wall.
        assert!(c.intersect(&Ray::new(Vec3::new(-3.0, 0.0, 0.6), Vec3::X), 1e-4, f32::INFINITY).is_none());
        let steep = Vec3::new(1.0, 0.0, -1.0).normalize(); // meets x = 1 at z = −0.1, below the base
        assert!(c.intersect(&Ray::new(Vec3::new(0.0, 0.0, 0.9), steep), 1e-4, f32::INFINITY).is_none());
        let d = Vec3::new(1.0, 0.0, -0.7);
        let (t, n) =
            c.intersect(&Ray::new(Vec3::new(0.0, 0.0, 0.9), d.normalize()), 1e-4, f32::INFINITY).unwrap();
        assert!((t - d.length()).abs() < 1e-5 && (n - Vec3::X).length() < 1e-5);
    }
}
