//! The scenes the ground truth knows, recognised from their contents, and the forward map of
//! each: a ray of the collimated beam, followed in f64 through the one specular object with
//! the expected (not sampled) Fresnel transmittance, to the floor. Independent of the tracer:
//! own ray–shape intersection, Snell's law and Fresnel equations.

use glam::DVec3;

use super::TruthError;
use super::splat::Landing;
use crate::scene::material::wavelength_rgb;
use crate::scene::{Dispersion, EmitterShape, Material, Scene, Shape, SurfaceGeometry};

/// The collimated beam: rays leave `origin + u·edge_u + v·edge_v`, (u, v) ∈ [0, 1]², along
/// `dir`, carrying `power_w` spread uniformly over (u, v), split over RGB by `share`.
#[derive(Clone, Debug)]
pub(crate) struct Beam {
    pub origin: DVec3,
    pub edge_u: DVec3,
    pub edge_v: DVec3,
    pub dir: DVec3,
    pub power_w: f64,
    pub share: [f64; 3],
}

/// The diffuse floor: the plane z = `z`, bounded by a parallelogram if it is a rectangle.
#[derive(Clone, Debug)]
pub(crate) struct Floor {
    pub z: f64,
    /// origin, and the dual vectors giving the (a, b) coordinates of a point.
    pub rect: Option<(DVec3, DVec3, DVec3)>,
}

impl Floor {
    fn contains(&self, p: DVec3) -> bool {
        match self.rect {
            None => true,
            Some((o, du, dv)) => {
                let (a, b) = ((p - o).dot(du), (p - o).dot(dv));
                (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)
            }
        }
    }

    /// Parameter of the ray's crossing of the floor plane, if ahead.
    fn t(&self, o: DVec3, d: DVec3) -> Option<f64> {
        if d.z == 0.0 {
            return None;
        }
        let t = (self.z - o.z) / d.z;
        (t > 1e-9).then_some(t)
    }

    /// The (x, y) extent of a rectangular floor.
    pub fn bounds(&self) -> Option<[f64; 4]> {
        let (o, du, dv) = self.rect?;
        // Recover the edges from the duals: [du dv n]⁻ᵀ.
        let n = du.cross(dv);
        let m = glam::DMat3::from_cols(du, dv, n).transpose().inverse();
        let (eu, ev) = (m.x_axis, m.y_axis);
        let corners = [o, o + eu, o + ev, o + eu + ev];
        let xs = corners.map(|c| c.x);
        let ys = corners.map(|c| c.y);
        let f = |v: [f64; 4], max: bool| {
            v.into_iter()
                .fold(if max { f64::MIN } else { f64::MAX }, |a, b| if max { a.max(b) } else { a.min(b) })
        };
        Some([f(xs, false), f(ys, false), f(xs, true), f(ys, true)])
    }
}

/// A dielectric's optical constants, in f64.
#[derive(Clone, Debug)]
pub(crate) struct Glass {
    pub ior: f64,
    pub dispersion: Option<Dispersion>,
    pub ideal: bool,
    pub tint: [f64; 3],
}

impl Glass {
    /// Index at `wavelength_nm`: Sellmeier n² = 1 + Σ Bᵢλ²/(λ² − Cᵢ) or Cauchy A + B/λ² + C/λ⁴
    /// (λ in µm), evaluated here in f64.
    pub fn ior_at(&self, wavelength_nm: Option<f64>) -> f64 {
        match (&self.dispersion, wavelength_nm) {
            (Some(Dispersion::Cauchy { a, b, c }), Some(l)) => {
                let l2 = (l * 1e-3).powi(2);
                a + b / l2 + c / (l2 * l2)
            }
            (Some(Dispersion::Sellmeier { b, c }), Some(l)) => {
                let l2 = (l * 1e-3).powi(2);
                (1.0 + b.iter().zip(c).map(|(b, c)| b * l2 / (l2 - c)).sum::<f64>()).max(0.0).sqrt()
            }
            _ => self.ior,
        }
    }
}

/// A regular height field as the tracer's mesh has it: vertices on an (nx + 1) × (ny + 1)
/// grid, each cell split along its (i, j)–(i + 1, j + 1) diagonal, flat facets with the
/// vertices' shading normals interpolated across them.
#[derive(Clone, Debug)]
pub(crate) struct HeightField {
    pub n: [usize; 2],
    pub x0: f64,
    pub y0: f64,
    pub dx: f64,
    pub dy: f64,
    pub z: Vec<f64>,
    pub normal: Vec<DVec3>,
    pub z_mid: f64,
}

/// A vertex and its shading normal.
type VertexNormal = (DVec3, DVec3);

/// A triangle of a flat-faceted solid, with its outward normal and the id of its plane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Facet {
    pub v: [DVec3; 3],
    pub normal: DVec3,
    pub plane: u64,
}

/// The one specular object of a scene with a known truth.
#[derive(Clone, Debug)]
pub(crate) enum Optic {
    Sphere {
        centre: DVec3,
        radius: f64,
        glass: Glass,
    },
    HeightField {
        field: HeightField,
        glass: Glass,
    },
    Facets {
        facets: Vec<Facet>,
        glass: Glass,
    },
    /// An open mirror cylinder (both sides reflect).
    Cylinder {
        base: DVec3,
        axis: DVec3,
        radius: f64,
        height: f64,
        reflectance: [f64; 3],
    },
}

/// A scene the truth can integrate: a collimated beam, a floor and one specular object.
#[derive(Clone, Debug)]
pub(crate) struct Setup {
    pub beam: Beam,
    pub floor: Floor,
    pub optic: Optic,
}

/// Most specular bounces followed in the mirror cylinder (the tracer's default limit).
const MAX_BOUNCES: u8 = 64;

fn d3(v: glam::Vec3) -> DVec3 {
    v.as_dvec3()
}

fn unsupported(why: impl Into<String>) -> TruthError {
    TruthError::Unsupported(why.into())
}

impl Setup {
    pub fn from_scene(scene: &Scene) -> Result<Setup, TruthError> {
        let [e] = scene.emitters() else {
            return Err(unsupported(format!(
                "{} emitters; the truth needs exactly one",
                scene.emitters().len()
            )));
        };
        let EmitterShape::Collimated { origin, edge_u, edge_v, direction } = e.kind else {
            return Err(unsupported("the emitter is not a collimated beam"));
        };
        let sum = e.colour.element_sum() as f64;
        let beam = Beam {
            origin: d3(origin),
            edge_u: d3(edge_u),
            edge_v: d3(edge_v),
            dir: d3(direction).normalize(),
            power_w: e.power_w,
            share: [e.colour.x as f64 / sum, e.colour.y as f64 / sum, e.colour.z as f64 / sum],
        };
        let mut floor = None;
        let mut optic = None;
        for s in scene.surfaces() {
            let m = &scene.materials()[s.material as usize];
            match (m, &s.geometry) {
                (Material::Diffuse { .. }, SurfaceGeometry::Analytic(g)) => {
                    if floor.is_some() {
                        return Err(unsupported("more than one diffuse surface"));
                    }
                    floor = Some(floor_of(g)?);
                }
                (Material::Diffuse { .. }, SurfaceGeometry::Mesh(_)) => {
                    return Err(unsupported(format!(
                        "the diffuse surface '{}' is a mesh, not a floor",
                        s.name
                    )));
                }
                (Material::Absorber, _) => return Err(unsupported(format!("absorber '{}'", s.name))),
                (m, g) => {
                    if optic.is_some() {
                        return Err(unsupported("more than one specular object"));
                    }
                    optic = Some(optic_of(&s.name, m, g)?);
                }
            }
        }
        let floor = floor.ok_or_else(|| unsupported("no diffuse floor"))?;
        let optic = optic.ok_or_else(|| unsupported("no specular object"))?;
        Ok(Setup { beam, floor, optic })
    }

    /// A short name of the scene's kind for the method description.
    pub fn kind(&self) -> &'static str {
        match self.optic {
            Optic::Sphere { .. } => "dielectric sphere",
            Optic::HeightField { .. } => "dielectric height field (triangle mesh, interpolated normals)",
            Optic::Facets { .. } => "flat-faceted dielectric solid (prism)",
            Optic::Cylinder { .. } => "open mirror cylinder",
        }
    }

    /// Whether the object's index depends on the wavelength (the tracer then draws one
    /// uniformly from the visible range and weights the RGB flux by it).
    pub fn dispersive(&self) -> bool {
        match &self.optic {
            Optic::Sphere { glass, .. } | Optic::HeightField { glass, .. } | Optic::Facets { glass, .. } => {
                glass.dispersion.is_some()
            }
            Optic::Cylinder { .. } => false,
        }
    }

    /// Where the beam ray with parameters (u, v) lands, at `wavelength_nm` for a dispersive
    /// object; `None` if it reaches the floor without a specular bounce, leaves, or takes a
    /// path the truth does not follow (a Fresnel reflection at a dielectric).
    pub fn land(&self, u: f64, v: f64, wavelength_nm: Option<f64>) -> Option<Landing> {
        let o = self.beam.origin + u * self.beam.edge_u + v * self.beam.edge_v;
        let d = self.beam.dir;
        let mut weight = self.beam.share;
        if let (true, Some(l)) = (self.dispersive(), wavelength_nm) {
            let rgb = wavelength_rgb(l as f32);
            weight = [weight[0] * rgb.x as f64, weight[1] * rgb.y as f64, weight[2] * rgb.z as f64];
        }
        match &self.optic {
            Optic::Cylinder { base, axis, radius, height, reflectance } => self.mirror_path(
                o,
                d,
                weight,
                |o, d| cylinder_hit(*base, *axis, *radius, *height, o, d),
                *reflectance,
            ),
            Optic::Sphere { glass, .. } | Optic::HeightField { glass, .. } | Optic::Facets { glass, .. } => {
                self.dielectric_path(o, d, weight, glass, glass.ior_at(wavelength_nm))
            }
        }
    }

    fn dielectric_hit(&self, o: DVec3, d: DVec3) -> Option<Hit> {
        match &self.optic {
            Optic::Sphere { centre, radius, .. } => sphere_hit(*centre, *radius, o, d),
            Optic::HeightField { field, .. } => field.hit(o, d),
            Optic::Facets { facets, .. } => facets_hit(facets, o, d),
            Optic::Cylinder { .. } => None,
        }
    }

    /// Refraction only, at every dielectric interface, to the floor: weight Π (1 − F)·tint.
    fn dielectric_path(
        &self,
        mut o: DVec3,
        mut d: DVec3,
        mut w: [f64; 3],
        glass: &Glass,
        n: f64,
    ) -> Option<Landing> {
        let mut bounces = 0u8;
        let mut class = 0u64;
        loop {
            let hit = self.dielectric_hit(o, d);
            let tf = self.floor.t(o, d);
            match (hit, tf) {
                (Some(h), tf) if tf.is_none_or(|tf| h.t < tf) => {
                    let p = o + h.t * d;
                    let front = d.dot(h.normal) < 0.0;
                    let (ng, ns) = if front { (h.normal, h.shading) } else { (-h.normal, -h.shading) };
                    let eta = if front { 1.0 / n } else { n };
                    // As the tracer: the shading normal unless it disagrees with the geometry.
                    let mut normal = ns;
                    let mut t = refract(d, normal, eta);
                    if t.is_some_and(|t| t.dot(ng) >= 0.0) || d.dot(normal) >= 0.0 {
                        normal = ng;
                        t = refract(d, normal, eta);
                    }
                    let t = t?; // total internal reflection: not a refraction-only path
                    let trans = if glass.ideal { 1.0 } else { 1.0 - fresnel(-d.dot(normal), eta) };
                    for (wc, tc) in w.iter_mut().zip(glass.tint) {
                        *wc *= trans * tc;
                    }
                    bounces += 1;
                    class = class.wrapping_mul(1 << 20).wrapping_add(h.id + 1);
                    if bounces > 8 {
                        return None;
                    }
                    o = p;
                    d = t;
                }
                (_, Some(tf)) => return self.arrive(o + tf * d, w, class, bounces),
                (_, None) => return None,
            }
        }
    }

    /// Mirror reflections (reflectance per channel) to the floor.
    fn mirror_path(
        &self,
        mut o: DVec3,
        mut d: DVec3,
        mut w: [f64; 3],
        hit: impl Fn(DVec3, DVec3) -> Option<Hit>,
        reflectance: [f64; 3],
    ) -> Option<Landing> {
        let mut bounces = 0u8;
        let mut class = 0u64;
        loop {
            let h = hit(o, d);
            let tf = self.floor.t(o, d);
            match (h, tf) {
                (Some(h), tf) if tf.is_none_or(|tf| h.t < tf) => {
                    let p = o + h.t * d;
                    d = d - 2.0 * d.dot(h.normal) * h.normal;
                    for (wc, rc) in w.iter_mut().zip(reflectance) {
                        *wc *= rc;
                    }
                    bounces += 1;
                    if bounces > MAX_BOUNCES {
                        return None;
                    }
                    class = class.wrapping_mul(4).wrapping_add(h.id + 1);
                    o = p;
                }
                (_, Some(tf)) => return self.arrive(o + tf * d, w, class, bounces),
                (_, None) => return None,
            }
        }
    }

    fn arrive(&self, p: DVec3, weight: [f64; 3], class: u64, bounces: u8) -> Option<Landing> {
        (bounces > 0 && self.floor.contains(p)).then_some(Landing { xy: [p.x, p.y], weight, class, bounces })
    }
}

/// A ray's hit: distance, outward geometric and shading normals, and which face or side.
#[derive(Clone, Copy, Debug)]
struct Hit {
    t: f64,
    normal: DVec3,
    shading: DVec3,
    id: u64,
}

const T_MIN: f64 = 1e-9;

fn floor_of(g: &Shape) -> Result<Floor, TruthError> {
    match *g {
        Shape::Plane { point, normal } if normal.x == 0.0 && normal.y == 0.0 => {
            Ok(Floor { z: point.z as f64, rect: None })
        }
        Shape::Rectangle { origin, normal, dual_u, dual_v, .. } if normal.x == 0.0 && normal.y == 0.0 => {
            Ok(Floor { z: origin.z as f64, rect: Some((d3(origin), d3(dual_u), d3(dual_v))) })
        }
        _ => Err(unsupported("the diffuse surface is not a horizontal plane or rectangle")),
    }
}

fn optic_of(name: &str, m: &Material, g: &SurfaceGeometry) -> Result<Optic, TruthError> {
    let glass = |m: &Material| match m {
        Material::Dielectric(d) => Some(Glass {
            ior: d.ior as f64,
            dispersion: d.dispersion.clone(),
            ideal: d.ideal,
            tint: d.tint.as_dvec3().to_array(),
        }),
        _ => None,
    };
    match (m, g) {
        (Material::Dielectric(_), SurfaceGeometry::Analytic(Shape::Sphere { center, radius })) => {
            Ok(Optic::Sphere {
                centre: d3(*center),
                radius: *radius as f64,
                glass: glass(m).expect("dielectric"),
            })
        }
        (
            Material::Mirror { reflectance },
            SurfaceGeometry::Analytic(Shape::Cylinder { base, axis, radius, height }),
        ) => Ok(Optic::Cylinder {
            base: d3(*base),
            axis: d3(*axis).normalize(),
            radius: *radius as f64,
            height: *height as f64,
            reflectance: reflectance.as_dvec3().to_array(),
        }),
        (Material::Dielectric(_), SurfaceGeometry::Mesh(mesh)) => {
            let glass = glass(m).expect("dielectric");
            if mesh.normals.is_some() {
                let field = HeightField::from_mesh(mesh).ok_or_else(|| {
                    unsupported(format!("'{name}': a smooth mesh that is not a regular height field"))
                })?;
                Ok(Optic::HeightField { field, glass })
            } else if mesh.indices.len() <= 64 {
                Ok(Optic::Facets { facets: facets_of(mesh), glass })
            } else {
                Err(unsupported(format!("'{name}': a flat mesh of {} triangles", mesh.indices.len())))
            }
        }
        _ => Err(unsupported(format!("'{name}': no truth for this shape and material"))),
    }
}

/// Triangles of a flat mesh with their outward normals, coplanar ones sharing a plane id.
fn facets_of(mesh: &crate::scene::Mesh) -> Vec<Facet> {
    let mut planes: Vec<(DVec3, f64)> = Vec::new();
    (0..mesh.indices.len())
        .filter_map(|i| {
            let v = mesh.triangle(i).map(d3);
            let normal = (v[1] - v[0]).cross(v[2] - v[0]).try_normalize()?;
            let off = normal.dot(v[0]);
            let plane = planes
                .iter()
                .position(|(n, o)| n.dot(normal) > 1.0 - 1e-9 && (o - off).abs() < 1e-6)
                .unwrap_or_else(|| {
                    planes.push((normal, off));
                    planes.len() - 1
                });
            Some(Facet { v, normal, plane: plane as u64 })
        })
        .collect()
}

impl HeightField {
    /// Recognises the tracer's height-field mesh (`scene::mesh::height_field`, perhaps
    /// translated): regular vertex grid, the fixed triangulation, normals facing up.
    fn from_mesh(m: &crate::scene::Mesh) -> Option<HeightField> {
        let p = &m.positions;
        let ns = m.normals.as_ref()?;
        let row = p.iter().position(|q| q.y != p[0].y)?;
        let (nx, ny) = (row.checked_sub(1)?, (p.len() / row).checked_sub(1)?);
        if nx == 0 || ny == 0 || row * (ny + 1) != p.len() || m.indices.len() != 2 * nx * ny {
            return None;
        }
        let (x0, y0) = (p[0].x as f64, p[0].y as f64);
        let dx = (p[nx].x as f64 - x0) / nx as f64;
        let dy = (p[ny * row].y as f64 - y0) / ny as f64;
        if !(dx > 0.0 && dy > 0.0) {
            return None;
        }
        for j in 0..=ny {
            for i in 0..=nx {
                let q = p[j * row + i];
                let tol = 1e-4 * dx.min(dy);
                if ((q.x as f64) - (x0 + i as f64 * dx)).abs() > tol
                    || ((q.y as f64) - (y0 + j as f64 * dy)).abs() > tol
                    || ns[j * row + i].z <= 0.0
                {
                    return None;
                }
            }
        }
        let at = |i: usize, j: usize| (j * row + i) as u32;
        for j in 0..ny {
            for i in 0..nx {
                let k = 2 * (j * nx + i);
                if m.indices[k] != [at(i, j), at(i + 1, j), at(i + 1, j + 1)]
                    || m.indices[k + 1] != [at(i, j), at(i + 1, j + 1), at(i, j + 1)]
                {
                    return None;
                }
            }
        }
        let z: Vec<f64> = p.iter().map(|q| q.z as f64).collect();
        let z_mid =
            0.5 * (z.iter().cloned().fold(f64::MAX, f64::min) + z.iter().cloned().fold(f64::MIN, f64::max));
        Some(HeightField {
            n: [nx, ny],
            x0,
            y0,
            dx,
            dy,
            z,
            normal: ns.iter().map(|n| d3(*n)).collect(),
            z_mid,
        })
    }

    fn vertex(&self, i: usize, j: usize) -> (DVec3, DVec3) {
        let k = j * (self.n[0] + 1) + i;
        (DVec3::new(self.x0 + i as f64 * self.dx, self.y0 + j as f64 * self.dy, self.z[k]), self.normal[k])
    }

    /// The facet under (x, y): its index, its vertices with their normals, and the
    /// barycentric weights of (x, y).
    fn facet_at(&self, x: f64, y: f64) -> Option<(usize, [VertexNormal; 3], [f64; 3])> {
        let fx = (x - self.x0) / self.dx;
        let fy = (y - self.y0) / self.dy;
        if !(fx >= 0.0 && fy >= 0.0 && fx <= self.n[0] as f64 && fy <= self.n[1] as f64) {
            return None;
        }
        let i = (fx.floor() as usize).min(self.n[0] - 1);
        let j = (fy.floor() as usize).min(self.n[1] - 1);
        let (lx, ly) = (fx - i as f64, fy - j as f64);
        let cell = 2 * (j * self.n[0] + i);
        if lx >= ly {
            let v = [self.vertex(i, j), self.vertex(i + 1, j), self.vertex(i + 1, j + 1)];
            Some((cell, v, [1.0 - lx, lx - ly, ly]))
        } else {
            let v = [self.vertex(i, j), self.vertex(i + 1, j + 1), self.vertex(i, j + 1)];
            Some((cell + 1, v, [1.0 - ly, lx, ly - lx]))
        }
    }

    /// First crossing of a downward ray with the faceted surface: start on the mean level,
    /// then move to the plane of the facet under the current point until the facet repeats.
    fn hit(&self, o: DVec3, d: DVec3) -> Option<Hit> {
        if d.z >= 0.0 {
            return None; // below the surface and going down after the refraction: no more hits
        }
        let mut t = (self.z_mid - o.z) / d.z;
        let mut last = usize::MAX;
        for _ in 0..64 {
            let p = o + t * d;
            let (id, v, _) = self.facet_at(p.x, p.y)?;
            if id == last {
                break;
            }
            last = id;
            let ng = (v[1].0 - v[0].0).cross(v[2].0 - v[0].0);
            t = (v[0].0 - o).dot(ng) / d.dot(ng);
        }
        if t <= T_MIN {
            return None;
        }
        let p = o + t * d;
        let (id, v, b) = self.facet_at(p.x, p.y)?;
        if id != last {
            return None; // did not settle on one facet
        }
        let normal = (v[1].0 - v[0].0).cross(v[2].0 - v[0].0).normalize();
        let shading = (v[0].1 * b[0] + v[1].1 * b[1] + v[2].1 * b[2]).try_normalize().unwrap_or(normal);
        Some(Hit { t, normal, shading, id: 0 })
    }
}

fn sphere_hit(c: DVec3, r: f64, o: DVec3, d: DVec3) -> Option<Hit> {
    let oc = o - c;
    let b = oc.dot(d);
    let perp = oc - b * d;
    let disc = r * r - perp.length_squared();
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = [-b - s, -b + s].into_iter().find(|&t| t > T_MIN)?;
    let n = (o + t * d - c) / r;
    Some(Hit { t, normal: n, shading: n, id: 0 })
}

/// Möller–Trumbore against every facet; the nearest hit.
fn facets_hit(facets: &[Facet], o: DVec3, d: DVec3) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    for f in facets {
        let (e1, e2) = (f.v[1] - f.v[0], f.v[2] - f.v[0]);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-300 {
            continue;
        }
        let s = o - f.v[0];
        let a = s.dot(p) / det;
        let q = s.cross(e1);
        let b = d.dot(q) / det;
        if a < 0.0 || b < 0.0 || a + b > 1.0 {
            continue;
        }
        let t = e2.dot(q) / det;
        if t > T_MIN && best.is_none_or(|h| t < h.t) {
            best = Some(Hit { t, normal: f.normal, shading: f.normal, id: f.plane });
        }
    }
    best
}

/// The wall of an open cylinder, either side; id 0 when struck from outside, 1 from inside.
fn cylinder_hit(base: DVec3, axis: DVec3, r: f64, h: f64, o: DVec3, d: DVec3) -> Option<Hit> {
    let oc = o - base;
    let dp = d - axis * d.dot(axis);
    let op = oc - axis * oc.dot(axis);
    let a = dp.length_squared();
    if a == 0.0 {
        return None;
    }
    let b = op.dot(dp) / a;
    let closest = op - dp * b;
    let disc = (r * r - closest.length_squared()) / a;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    for t in [-b - s, -b + s] {
        if t > T_MIN {
            let q = oc + t * d;
            let z = q.dot(axis);
            if (0.0..=h).contains(&z) {
                let n = (q - axis * z) / r;
                let id = u64::from(d.dot(n) >= 0.0);
                return Some(Hit { t, normal: n, shading: n, id });
            }
        }
    }
    None
}

/// Snell's law for unit `d` through the interface with unit normal `n` facing the incoming
/// side, `eta` = n_incident / n_transmitted; `None` on total internal reflection.
pub(crate) fn refract(d: DVec3, n: DVec3, eta: f64) -> Option<DVec3> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((eta * d + (eta * cos_i - cos_t) * n).normalize())
}

/// Fresnel reflectance of unpolarised light, cosine form: the mean of
/// rs = (η cos θi − cos θt)/(η cos θi + cos θt) and rp = (cos θi − η cos θt)/(cos θi + η cos θt)
/// squared, with η = n_incident / n_transmitted.
pub(crate) fn fresnel(cos_i: f64, eta: f64) -> f64 {
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}
