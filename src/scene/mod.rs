//! Scenes: the camera, emitters, shapes and materials the tracer shoots photons through.
//!
//! A scene is read from a TOML file (`docs/scene.md`; units are metres and watts) by
//! [`Scene::load`] or [`Scene::parse`]. Shapes are numbered in file order: that number is the
//! `surface` id stored with each photon. Analytic shapes are intersected directly; every
//! triangle of every mesh goes into one [bounding volume hierarchy](bvh).

pub use crate::accel::bvh;
pub mod camera;
pub mod emitter;
mod file;
use crate::accel::hull;
#[cfg(test)]
mod hull_tests;
pub mod material;
pub mod mesh;
mod resolve;
pub mod shape;

use std::path::Path;

use glam::Vec3;

pub use camera::{Camera, Projection};
pub use emitter::{Emitter, EmitterShape};
pub use material::{Dielectric, Dispersion, Material};
pub use mesh::{Mesh, Transform};
pub use resolve::{ResolvedScene, for_map, scene_crc32};
pub use shape::{Hit, Ray, Shape};

/// The scene `photonkit trace` uses when given none: a glass sphere above a floor under a
/// vertical collimated beam (`samples/scenes/glass-sphere.toml`).
pub const DEFAULT_SCENE: &str = include_str!("../../samples/scenes/glass-sphere.toml");
/// The name the default scene goes by in messages and stage records.
pub const DEFAULT_SCENE_NAME: &str = "<default scene: glass-sphere.toml>";

/// The ray offset as a fraction of the scene's extent ([`Scene::ray_offset`]).
pub const RAY_OFFSET_REL: f32 = 2.5e-5;
/// The ray offset of a scene with no extent (a single point), metres.
const RAY_OFFSET_FALLBACK_M: f32 = 1e-4;
/// The pad, in ray offsets, of the boxes that must be disjoint for [`Reach::MeshFirst`].
const MESH_APART_PAD: f32 = 4.0;
/// Meshes up to this size are checked for convexity ([`Scene::leaves_convex_mesh`]).
const CONVEX_CHECK_MAX_TRIANGLES: usize = 1024;

/// Everything that can be wrong with a scene file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    #[error("{file}: {source}")]
    Io { file: String, source: std::io::Error },
    /// A syntax, type or value error at a place in the file (line and column 1-based).
    #[error("{file}:{line}:{column}: {field}: {message}")]
    Invalid { file: String, line: usize, column: usize, field: String, message: String },
    /// The scene file a map's trace record names is not where the record says.
    #[error("{map}: traced from the scene '{scene}', which is not found here: pass --scene FILE")]
    NotFound { map: String, scene: String },
}

/// The geometry of one surface, in world space.
#[derive(Clone, Debug, PartialEq)]
pub enum SurfaceGeometry {
    Analytic(Shape),
    Mesh(Mesh),
}

/// One shape of the scene: its name, material and geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    pub name: String,
    /// Index into [`Scene::materials`].
    pub material: u32,
    pub geometry: SurfaceGeometry,
}

/// What a hit needs of its triangle, in one record: looking it up costs one cache miss (the
/// photons of a run hit triangles all over the mesh), not one for this and another for the
/// vertex normals it points to.
#[derive(Clone, Copy, Debug)]
struct TriInfo {
    surface: u32,
    /// Unit geometric normal, (b − a) × (c − a) normalised.
    normal: Vec3,
    /// The vertices' shading normals; `None` for a flat facet.
    vertex_normals: Option<[Vec3; 3]>,
}

/// A scene ready to trace.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: Option<String>,
    pub camera: Option<Camera>,
    /// What eye rays that leave the scene see (docs/scene.md, `[background]`); `None`: black.
    /// It is seen, not a light: it sends no photons and lights no surface.
    pub background: Option<Background>,
    pub materials: Vec<Material>,
    pub material_names: Vec<String>,
    pub emitters: Vec<Emitter>,
    pub emitter_names: Vec<String>,
    pub surfaces: Vec<Surface>,
    analytic: Vec<(Shape, u32)>,
    triangles: Vec<[Vec3; 3]>,
    tri_info: Vec<TriInfo>,
    bvh: bvh::Bvh,
    /// See [`Scene::ray_offset`].
    ray_offset: f32,
    /// When every triangle belongs to one surface and that mesh is convex: the surface and
    /// the centroid of its vertices (see [`Scene::leaves_convex_mesh`]).
    convex_mesh: Option<(u32, Vec3)>,
    /// The convex mesh as the half-spaces of its faces, when it is closed and flat-shaded:
    /// rays are tested against its planes instead of its triangles ([`Scene::intersect_mesh`]).
    hull: Option<hull::Hull>,
    /// The box around every mirror and dielectric surface, padded by the ray offset; `None`
    /// when one is unbounded (see [`Scene::may_meet_specular`]).
    specular_box: Option<(Vec3, Vec3)>,
    /// Whether no analytic shape comes near the box around the triangles (see
    /// [`Scene::reach_after`]).
    mesh_apart: bool,
}

/// The background of a scene: seen by eye rays that escape, directly or through glass and
/// mirrors (docs/scene.md). Radiance in W/(m²·sr) per channel.
#[derive(Clone, Debug, PartialEq)]
pub enum Background {
    /// The same radiance in every direction.
    Uniform(Vec3),
    /// An equirectangular image (linear RGB OpenEXR), loaded by the renderer: the image's
    /// top row looks up (+z), its horizontal centre along +x turned by `rotate_deg` about z
    /// (anticlockwise seen from above), each pixel times `strength`.
    Image { path: std::path::PathBuf, strength: f32, rotate_deg: f32 },
}

/// Which shapes a ray continuing from a surface can meet first ([`Scene::reach_after`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reach {
    /// Any: [`Scene::intersect`].
    All,
    /// A triangle if it meets one, otherwise an analytic shape: [`Scene::intersect_mesh_first`].
    MeshFirst,
    /// Analytic shapes only: [`Scene::intersect_analytic`].
    Analytic,
}

impl Scene {
    fn empty() -> Scene {
        Scene {
            name: None,
            camera: None,
            background: None,
            materials: Vec::new(),
            material_names: Vec::new(),
            emitters: Vec::new(),
            emitter_names: Vec::new(),
            surfaces: Vec::new(),
            analytic: Vec::new(),
            triangles: Vec::new(),
            tri_info: Vec::new(),
            bvh: bvh::Bvh::default(),
            ray_offset: RAY_OFFSET_FALLBACK_M,
            convex_mesh: None,
            hull: None,
            specular_box: None,
            mesh_apart: false,
        }
    }

    /// A scene built in code: named materials, emitters and surfaces (whose `material` indexes
    /// `materials`). Panics if a surface names a material that does not exist.
    pub fn new(materials: Vec<(String, Material)>, emitters: Vec<Emitter>, surfaces: Vec<Surface>) -> Scene {
        let mut s = Scene::empty();
        (s.material_names, s.materials) = materials.into_iter().unzip();
        s.emitter_names = (0..emitters.len()).map(|i| format!("emitter{i}")).collect();
        s.emitters = emitters;
        for surf in surfaces {
            assert!((surf.material as usize) < s.materials.len(), "surface '{}' has no material", surf.name);
            s.add_surface(surf.name, surf.material, surf.geometry);
        }
        s.finish();
        s
    }

    /// Reads a scene file; relative paths inside it (OBJ files) are resolved beside it.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let file = path.display().to_string();
        crate::format::guard::register_input(path);
        let src =
            std::fs::read_to_string(path).map_err(|source| SceneError::Io { file: file.clone(), source })?;
        let dir = crate::format::folder_of(path);
        Scene::parse(&src, &file, dir)
    }

    /// Reads a scene from TOML text; `file` names it in errors, `dir` resolves relative paths.
    pub fn parse(src: &str, file: &str, dir: &Path) -> Result<Scene, SceneError> {
        file::parse(src, file, dir)
    }

    /// The embedded default scene.
    pub fn default_scene() -> Scene {
        Scene::parse(DEFAULT_SCENE, DEFAULT_SCENE_NAME, Path::new("."))
            .expect("the embedded default scene is valid")
    }

    fn add_surface(&mut self, name: String, material: u32, geometry: SurfaceGeometry) {
        let id = self.surfaces.len() as u32;
        match &geometry {
            SurfaceGeometry::Analytic(s) => self.analytic.push((s.clone(), id)),
            SurfaceGeometry::Mesh(m) => {
                for (i, t) in m.indices.iter().enumerate() {
                    let tri = m.triangle(i);
                    let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
                    let vertex_normals = m.normals.as_ref().map(|ns| t.map(|k| ns[k as usize]));
                    self.triangles.push(tri);
                    self.tri_info.push(TriInfo { surface: id, normal, vertex_normals });
                }
            }
        }
        self.surfaces.push(Surface { name, material, geometry });
    }

    fn finish(&mut self) {
        self.bvh = bvh::Bvh::build(&self.triangles);
        self.ray_offset = self.compute_ray_offset();
        self.convex_mesh = self.find_convex_mesh();
        self.hull = self.find_hull();
        self.specular_box = self.find_specular_box();
        self.mesh_apart = self.find_mesh_apart();
    }

    /// Whether the box around every triangle, padded by [`MESH_APART_PAD`] ray offsets, is
    /// disjoint from the box around each analytic shape (an infinite plane: the plane
    /// itself). False without triangles.
    fn find_mesh_apart(&self) -> bool {
        let Some((lo, hi)) = self.bvh.bounds() else { return false };
        let pad = Vec3::splat(MESH_APART_PAD * self.ray_offset);
        let (lo, hi) = (lo - pad, hi + pad);
        if !(lo.is_finite() && hi.is_finite()) {
            return false;
        }
        self.analytic.iter().all(|(shape, _)| match *shape {
            Shape::Plane { point, normal } => {
                // The plane misses the box when every corner is on one side.
                let centre_side = ((lo + hi) * 0.5 - point).dot(normal);
                centre_side.abs() > ((hi - lo) * 0.5).dot(normal.abs())
            }
            _ => {
                let pts = shape.extent_points();
                let slo = pts.iter().fold(Vec3::INFINITY, |a, &p| a.min(p));
                let shi = pts.iter().fold(Vec3::NEG_INFINITY, |a, &p| a.max(p));
                slo.cmpgt(hi).any() || shi.cmplt(lo).any()
            }
        })
    }

    /// Which shapes the ray continuing from `p` on surface `surface`, started off it along
    /// `offset_dir` (± the unit geometric normal there), can meet first:
    /// - [`Reach::Analytic`] when it [leaves the convex mesh](Scene::leaves_convex_mesh);
    /// - [`Reach::MeshFirst`] when `surface` is a mesh and no analytic shape comes near the
    ///   triangles' box: the ray starts within a ray offset of a triangle, so inside the box
    ///   padded by four ray offsets (`MESH_APART_PAD`), and the segment to any triangle it meets
    ///   stays inside that box, where no analytic shape is. So a triangle it meets is the
    ///   nearest hit, and analytic shapes need testing only when it meets none;
    /// - [`Reach::All`] otherwise.
    #[inline]
    pub fn reach_after(&self, surface: u32, p: Vec3, offset_dir: Vec3, ray: &Ray) -> Reach {
        if self.leaves_convex_mesh(surface, p, offset_dir, ray) {
            Reach::Analytic
        } else if self.mesh_apart
            && matches!(self.surfaces[surface as usize].geometry, SurfaceGeometry::Mesh(_))
        {
            Reach::MeshFirst
        } else {
            Reach::All
        }
    }

    /// The nearest hit among the shapes `reach` allows (see [`Scene::reach_after`]).
    #[inline(always)]
    pub fn intersect_reach(&self, ray: &Ray, reach: Reach, t_min: f32, t_max: f32) -> Option<Hit> {
        match reach {
            Reach::All => self.intersect(ray, t_min, t_max),
            Reach::MeshFirst => self.intersect_mesh_first(ray, t_min, t_max),
            Reach::Analytic => self.intersect_analytic(ray, t_min, t_max),
        }
    }

    /// See [`Self::specular_box`]. With no specular surface the box is empty (every ray
    /// misses it).
    fn find_specular_box(&self) -> Option<(Vec3, Vec3)> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for (shape, id) in &self.analytic {
            if !self.material(*id).is_specular() {
                continue;
            }
            if matches!(shape, Shape::Plane { .. }) {
                return None;
            }
            for p in shape.extent_points() {
                (lo, hi) = (lo.min(p), hi.max(p));
            }
        }
        for (tri, info) in self.triangles.iter().zip(&self.tri_info) {
            if self.material(info.surface).is_specular() {
                for &p in tri {
                    (lo, hi) = (lo.min(p), hi.max(p));
                }
            }
        }
        let pad = Vec3::splat(self.ray_offset);
        Some((lo - pad, hi + pad))
    }

    /// Whether the ray (from its origin on) may meet a mirror or dielectric surface: false
    /// only when it misses the box around all of them. The tracer stops a photon whose
    /// emission ray cannot meet one: its first hit is diffuse (or nothing), so it can never
    /// be a caustic photon.
    pub fn may_meet_specular(&self, ray: &Ray) -> bool {
        let Some((lo, hi)) = self.specular_box else { return true };
        if lo.cmpgt(hi).any() {
            return false; // no specular surface at all
        }
        bvh::ray_box(lo, hi, ray.origin, ray.dir.recip(), 0.0, f32::INFINITY).is_some()
    }

    /// The scene's only mesh surface and its vertices' centroid, if the mesh is convex: each
    /// triangle has every vertex of the mesh on one side of its plane (within a few f32 ulps,
    /// far below the ray offset). Meshes of more than [`CONVEX_CHECK_MAX_TRIANGLES`]
    /// triangles are not checked (the check compares every triangle with every vertex).
    fn find_convex_mesh(&self) -> Option<(u32, Vec3)> {
        let surface = self.tri_info.first()?.surface;
        if self.triangles.len() > CONVEX_CHECK_MAX_TRIANGLES
            || self.tri_info.iter().any(|t| t.surface != surface)
        {
            return None;
        }
        let vertices: Vec<Vec3> = self.triangles.iter().flatten().copied().collect();
        let tol = self.mesh_plane_tolerance();
        if !tol.is_finite() || 4.0 * tol >= self.ray_offset {
            return None;
        }
        for (tri, info) in self.triangles.iter().zip(&self.tri_info) {
            if info.normal == Vec3::ZERO {
                return None;
            }
            let (mut below, mut above) = (false, false);
            for v in &vertices {
                let d = (*v - tri[0]).dot(info.normal);
                below |= d < -tol;
                above |= d > tol;
                if below && above {
                    return None;
                }
            }
        }
        let centroid = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
        Some((surface, centroid))
    }

    /// The convex mesh's half-spaces ([`hull::Hull`]) when the mesh is closed and has no
    /// shading normals (a hit's normal is then its face's, which the planes give).
    fn find_hull(&self) -> Option<hull::Hull> {
        self.convex_mesh?;
        if self.tri_info.iter().any(|t| t.vertex_normals.is_some()) {
            return None;
        }
        let normals: Vec<Vec3> = self.tri_info.iter().map(|t| t.normal).collect();
        hull::Hull::new(&self.triangles, &normals, self.mesh_plane_tolerance())
    }

    /// How far from a triangle's plane a vertex may lie and still count as on it: 16 f32
    /// ulps of the mesh's largest coordinate (the convexity check's and the hull's).
    fn mesh_plane_tolerance(&self) -> f32 {
        let far = self.triangles.iter().flatten().map(|v| v.abs().max_element()).fold(0.0f32, f32::max);
        16.0 * f32::EPSILON * far
    }

    /// Whether `ray`, continuing from `p` on surface `surface` and started off it along
    /// `offset_dir` (± the unit geometric normal there), can meet no triangle of the scene:
    /// the surface is the scene's convex mesh, the ray starts on the side of the hit
    /// triangle's plane away from the mesh (every vertex lies on the other side, the
    /// centroid by more than the ray offset) and does not turn back towards that plane. Then
    /// [`Scene::intersect_analytic`] finds the same hit as [`Scene::intersect`]: a ray that
    /// leaves a convex body cannot meet it again.
    pub fn leaves_convex_mesh(&self, surface: u32, p: Vec3, offset_dir: Vec3, ray: &Ray) -> bool {
        // The three tests combined with `&`, not `&&`: one branch on the result instead of
        // three (measured by benches/trace.rs).
        self.convex_mesh.is_some_and(|(s, c)| {
            (s == surface) & ((c - p).dot(offset_dir) < -self.ray_offset) & (ray.dir.dot(offset_dir) >= 0.0)
        })
    }

    /// The scene with every length multiplied by `f` (finite, > 0) about the origin: shapes,
    /// meshes, emitter positions and sizes, the camera's eye and orthographic height. Powers
    /// stay in watts, so irradiance on the scaled scene is 1/f² times the original's.
    pub fn scaled(&self, f: f32) -> Scene {
        assert!(f > 0.0 && f.is_finite(), "scale factor {f}: must be finite and positive");
        let materials = self.material_names.iter().cloned().zip(self.materials.iter().cloned()).collect();
        let emitters = self.emitters.iter().map(|e| e.scaled(f)).collect();
        let surfaces = self
            .surfaces
            .iter()
            .map(|s| Surface {
                name: s.name.clone(),
                material: s.material,
                geometry: match &s.geometry {
                    SurfaceGeometry::Analytic(shape) => SurfaceGeometry::Analytic(shape.scaled(f)),
                    SurfaceGeometry::Mesh(m) => SurfaceGeometry::Mesh(Mesh {
                        positions: m.positions.iter().map(|p| *p * f).collect(),
                        ..m.clone()
                    }),
                },
            })
            .collect();
        let mut s = Scene::new(materials, emitters, surfaces);
        s.name = self.name.clone();
        s.emitter_names = self.emitter_names.clone();
        s.camera = self.camera.as_ref().map(|c| c.scaled(f));
        // The same power over areas f² as large: every radiance, the background's too, is
        // divided by f², so the scaled scene looks the same up to exposure.
        let k = 1.0 / (f * f);
        s.background = self.background.as_ref().map(|b| match b {
            Background::Uniform(c) => Background::Uniform(*c * k),
            Background::Image { path, strength, rotate_deg } => {
                Background::Image { path: path.clone(), strength: strength * k, rotate_deg: *rotate_deg }
            }
        });
        s
    }

    /// The side of the axis-aligned box around every finite shape, mesh and emitter, metres:
    /// the scene's length scale (an infinite plane counts by its anchor point only).
    pub fn extent(&self) -> f32 {
        let (lo, hi) = self.bounds();
        (hi - lo).max_element().max(0.0)
    }

    fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        let mut add = |p: Vec3| {
            lo = lo.min(p);
            hi = hi.max(p);
        };
        self.analytic.iter().flat_map(|(s, _)| s.extent_points()).for_each(&mut add);
        self.triangles.iter().flatten().copied().for_each(&mut add);
        self.emitters.iter().flat_map(|e| e.extent_points()).for_each(&mut add);
        (lo, hi)
    }

    /// How far a continuing ray starts off the surface it left (the tracer's and the eye
    /// paths' self-intersection guard), metres: [`RAY_OFFSET_REL`] of the scene's
    /// [extent](Scene::extent), so it scales with the scene (1e-4 m for the default 4 m
    /// scene), and never under 64 f32 ulps of the largest coordinate, so it still moves a
    /// point far from the origin.
    pub fn ray_offset(&self) -> f32 {
        self.ray_offset
    }

    fn compute_ray_offset(&self) -> f32 {
        let (lo, hi) = self.bounds();
        let extent = (hi - lo).max_element();
        if !(extent > 0.0 && extent.is_finite()) {
            return RAY_OFFSET_FALLBACK_M;
        }
        let far = lo.abs().max(hi.abs()).max_element();
        (RAY_OFFSET_REL * extent).max(64.0 * f32::EPSILON * far)
    }

    /// Number of mesh triangles in the scene.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The material of surface `id`.
    pub fn material(&self, surface: u32) -> &Material {
        &self.materials[self.surfaces[surface as usize].material as usize]
    }

    /// Whether any material disperses light (photons then take a wavelength).
    pub fn has_dispersion(&self) -> bool {
        self.materials.iter().any(|m| matches!(m, Material::Dielectric(d) if d.dispersion.is_some()))
    }

    /// Largest number of trajectory parameters of any emitter (the `params` column's width).
    pub fn param_dims(&self) -> u32 {
        let spectral = self.is_spectral();
        self.emitters.iter().map(|e| e.param_dims(spectral)).max().unwrap_or(0)
    }

    /// Whether photons carry their wavelength as a trajectory parameter: when some material
    /// disperses light (docs/spectral.md). Every emitter then has the spectral dimension.
    pub fn is_spectral(&self) -> bool {
        self.has_dispersion()
    }

    /// The PHM metadata records of the emitters.
    pub fn emitter_records(&self) -> Vec<crate::format::Emitter> {
        let spectral = self.is_spectral();
        self.emitters.iter().enumerate().map(|(i, e)| e.record(i as u32, spectral)).collect()
    }

    /// The nearest surface the ray meets with `t` in (`t_min`, `t_max`).
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let best = self.intersect_analytic(ray, t_min, t_max);
        let t_best = best.map_or(t_max, |h| h.t);
        self.intersect_mesh(ray, t_min, t_best).or(best)
    }

    /// The nearest triangle hit, else the nearest analytic one: the nearest hit of a ray
    /// that [`Reach::MeshFirst`] describes.
    #[inline(always)]
    pub fn intersect_mesh_first(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        self.intersect_mesh(ray, t_min, t_max).or_else(|| self.intersect_analytic(ray, t_min, t_max))
    }

    /// The nearest hit on the mesh triangles alone: against the convex mesh's face planes
    /// when it has a [`hull::Hull`] (the same hits to rounding, without cracks at edges),
    /// otherwise through the BVH.
    #[inline(always)]
    fn intersect_mesh(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        if let (Some(hull), Some((surface, _))) = (&self.hull, self.convex_mesh) {
            let (t, normal) = hull.intersect(ray, t_min, t_max, self.bvh.avx())?;
            return Some(Hit { t, normal, shading: normal, shape: surface });
        }
        let h = self.bvh.intersect(ray, t_min, t_max)?;
        let info = &self.tri_info[h.index as usize];
        let shading = match &info.vertex_normals {
            Some([n0, n1, n2]) => {
                (*n0 * (1.0 - h.b1 - h.b2) + *n1 * h.b1 + *n2 * h.b2).try_normalize().unwrap_or(info.normal)
            }
            None => info.normal,
        };
        Some(Hit { t: h.t, normal: info.normal, shading, shape: info.surface })
    }

    /// Whether surface `id` is an analytic shape (not a triangle mesh).
    #[inline(always)]
    pub fn is_analytic(&self, id: u32) -> bool {
        matches!(self.surfaces[id as usize].geometry, SurfaceGeometry::Analytic(_))
    }

    /// The nearest hit of a ray that starts *exactly* on the analytic surface `leaving` (a hit
    /// point, not offset from it): a hit on `leaving` itself counts only beyond
    /// [`Self::ray_offset`] (nearer, it is the point just left), every other surface from
    /// t > 0. An offset origin would instead miss a surface closer than the offset — a glass
    /// sphere resting on the floor sends the photons that leave it near the contact point
    /// straight through the floor.
    #[inline(always)]
    pub fn intersect_leaving(&self, ray: &Ray, reach: Reach, leaving: u32, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        if reach != Reach::Analytic {
            best = self.intersect_mesh(ray, 0.0, t_max);
            t_best = best.map_or(t_max, |h| h.t);
        }
        for (s, id) in &self.analytic {
            let t_min = if *id == leaving { self.ray_offset } else { 0.0 };
            if let Some((t, n)) = s.intersect(ray, t_min, t_best) {
                t_best = t;
                best = Some(Hit { t, normal: n, shading: n, shape: *id });
            }
        }
        best
    }

    /// The nearest hit on the analytic shapes alone (the mesh triangles skipped).
    #[inline(always)]
    pub fn intersect_analytic(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for (s, id) in &self.analytic {
            if let Some((t, n)) = s.intersect(ray, t_min, t_best) {
                t_best = t;
                best = Some(Hit { t, normal: n, shading: n, shape: *id });
            }
        }
        best
    }

    /// The nearest hit by testing every shape and triangle in turn (the oracle for tests).
    pub fn intersect_brute_force(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let mut best = self.intersect_analytic(ray, t_min, t_max);
        let t_best = best.map_or(t_max, |h| h.t);
        if let Some(h) = bvh::brute_force(&self.triangles, ray, t_min, t_best) {
            let info = &self.tri_info[h.index as usize];
            best = Some(Hit { t: h.t, normal: info.normal, shading: info.normal, shape: info.surface });
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(src: &str) -> Result<Scene, SceneError> {
        Scene::parse(src, "test.toml", Path::new("."))
    }

    const BASE: &str = r#"
[materials.floor]
kind = "diffuse"

[materials.glass]
kind = "dielectric"
ior = 1.5

[[emitters]]
kind = "point"
position = [0, 0, 2]
power_w = 10

[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
"#;

    /// (line of the error, field named, message) for BASE with `extra` appended.
    fn bad(extra: &str) -> (usize, String, String) {
        match parse(&format!("{BASE}{extra}")) {
            Err(SceneError::Invalid { line, field, message, .. }) => (line, field, message),
            Err(e) => panic!("unexpected error {e}"),
            Ok(_) => panic!("accepted:\n{extra}"),
        }
    }

    #[test]
    fn default_scene_parses() {
        let s = Scene::default_scene();
        assert!(!s.emitters.is_empty() && !s.surfaces.is_empty());
        assert!(s.camera.is_some());
    }

    #[test]
    fn errors_name_line_and_field() {
        // The appended text starts with a blank line: its header is line n + 2.
        let n = BASE.lines().count();
        let (l, f, _) = bad("\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\nradius = -1\n");
        assert_eq!((l, f.as_str()), (n + 5, "shapes[1].radius"));
        let (l, f, _) = bad("\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glas\"\nradius = 1\n");
        assert_eq!((l, f.as_str()), (n + 4, "shapes[1].material"));
        let (l, f, m) = bad("\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\nradus = 1\n");
        assert_eq!((l, f.as_str()), (n + 5, "shapes[1].radus"), "{m}");
        let (l, f, _) = bad("\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\nradius = \"big\"\n");
        assert_eq!((l, f.as_str()), (n + 5, "shapes[1].radius"));
        // Missing keys point at the table's header.
        let (l, f, _) = bad("\n[[shapes]]\nkind = \"disc\"\nmaterial = \"glass\"\n");
        assert_eq!((l, f.as_str()), (n + 2, "shapes[1].radius"));
        // Keys that do not apply to the kind.
        let (l, f, _) =
            bad("\n[[shapes]]\nkind = \"plane\"\nmaterial = \"glass\"\nnormal = [0,0,1]\nradius = 2\n");
        assert_eq!((l, f.as_str()), (n + 6, "shapes[1].radius"));
        // A non-uniform scale on a sphere.
        let (l, f, _) = bad(
            "\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\nradius = 1\ntransform = { scale = [1, 2, 1] }\n",
        );
        assert_eq!((l, f.as_str()), (n + 6, "shapes[1].transform"));
        // Syntax errors.
        let (l, _, _) = bad("\n[[shapes]]\nkind = \"sphere\n");
        assert_eq!(l, n + 3);
    }

    #[test]
    fn emitter_and_material_errors_name_their_fields() {
        let src = BASE.replace("power_w = 10", "power_w = 0");
        match parse(&src) {
            Err(SceneError::Invalid { field, line, .. }) => {
                assert_eq!(field, "emitters[0].power_w");
                assert_eq!(BASE.lines().nth(line - 1), Some("power_w = 10"));
            }
            other => panic!("{other:?}"),
        }
        let src = BASE.replace("ior = 1.5", "ior = 0.5");
        assert!(
            matches!(parse(&src), Err(SceneError::Invalid { field, .. }) if field == "materials.glass.ior")
        );
        let src = BASE.replace("kind = \"point\"", "kind = \"laser\"");
        assert!(matches!(parse(&src), Err(SceneError::Invalid { field, .. }) if field == "emitters[0].kind"));
    }

    #[test]
    fn intersection_uses_the_nearest_of_shapes_and_meshes() {
        let src = format!(
            "{BASE}\n[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[-1,-1],[1,-1],[1,1],[-1,1]]\n\
             z_range = [1, 1.5]\n\n[[shapes]]\nkind = \"sphere\"\nmaterial = \"glass\"\ncenter = [0, 0, 3]\nradius = 0.5\n"
        );
        let s = parse(&src).unwrap();
        assert_eq!(s.triangle_count(), 12);
        let down = |x: f32| Ray::new(Vec3::new(x, 0.0, 5.0), Vec3::NEG_Z);
        let h = s.intersect(&down(0.0), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t), (2, 1.5)); // the sphere's top at z = 3.5
        let h = s.intersect(&down(0.9), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t, h.normal), (1, 3.5, Vec3::Z)); // the slab's top at z = 1.5
        let h = s.intersect(&down(3.0), 1e-4, f32::INFINITY).unwrap();
        assert_eq!((h.shape, h.t), (0, 5.0)); // the floor
        for k in 0..100 {
            let r = Ray::new(
                Vec3::new(-2.0 + 0.04 * k as f32, 0.3, 5.0),
                Vec3::new(0.1, -0.05, -1.0).normalize(),
            );
            let (a, b) =
                (s.intersect(&r, 1e-4, f32::INFINITY), s.intersect_brute_force(&r, 1e-4, f32::INFINITY));
            assert_eq!(a.map(|h| (h.shape, h.t)), b.map(|h| (h.shape, h.t)));
        }
    }

    /// A ray `may_meet_specular` turns away never has a mirror or dielectric as its first
    /// hit (the brute-force scan says so), on sample scenes with meshes and analytic
    /// shapes; rays are turned away and let through, so the check is not vacuous. A scene
    /// without specular surfaces turns every ray away; one with an infinite mirror, none.
    #[test]
    fn rays_that_miss_the_specular_box_never_meet_a_specular_surface_first() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(12);
        for name in ["prism", "glass-sphere", "ring", "reflector", "point-glass"] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("samples/scenes/{name}.toml"));
            let scene = Scene::load(&path).unwrap();
            let (lo, hi) = scene.bounds();
            let (mut away, mut through) = (0, 0);
            for _ in 0..20_000 {
                let o = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random());
                let w = Vec3::new(
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                );
                let Some(dir) = w.try_normalize() else { continue };
                let ray = Ray::new(o, dir);
                if scene.may_meet_specular(&ray) {
                    through += 1;
                    continue;
                }
                away += 1;
                if let Some(h) = scene.intersect_brute_force(&ray, 0.0, f32::INFINITY) {
                    assert!(!scene.material(h.shape).is_specular(), "{name}: {ray:?} meets {h:?}");
                }
            }
            assert!(away > 200 && through > 200, "{name}: {away} turned away, {through} let through");
        }
        let plain = parse(BASE).unwrap();
        assert!(!plain.may_meet_specular(&Ray::new(Vec3::new(0.0, 0.0, 2.0), Vec3::NEG_Z)));
        let mirror = parse(&BASE.replace("material = \"floor\"", "material = \"glass\"")).unwrap();
        assert!(mirror.may_meet_specular(&Ray::new(Vec3::new(0.0, 0.0, 2.0), Vec3::Z)));
    }

    /// A ray leaving a random point of a random triangle of `scene` as the tracer starts one:
    /// a ray offset off it, to either side, in a random direction (grazing ones included).
    /// Returns the triangle, the point, the side (± its unit normal) and the ray.
    fn ray_leaving_a_triangle(
        scene: &Scene,
        rng: &mut rand_pcg::Pcg64Mcg,
    ) -> Option<(usize, Vec3, Vec3, Ray)> {
        use rand::RngExt;
        let k = rng.random_range(0..scene.triangles.len());
        let [a, b, c] = scene.triangles[k];
        let (mut u, mut v) = (rng.random::<f32>(), rng.random::<f32>());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let p = a + (b - a) * u + (c - a) * v;
        let n = scene.tri_info[k].normal;
        let side = if rng.random::<bool>() { n } else { -n };
        let w = Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5);
        let tangent = (w - n * w.dot(n)).normalize_or_zero();
        let lift = if rng.random::<bool>() { rng.random::<f32>() } else { rng.random::<f32>() * 1e-3 };
        let dir = (tangent + side * lift).try_normalize()?;
        Some((k, p, side, Ray::new(p + side * scene.ray_offset(), dir)))
    }

    #[test]
    fn rays_leaving_a_convex_mesh_meet_none_of_its_triangles() {
        use rand::SeedableRng;
        let prism =
            Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes/prism.toml")).unwrap();
        let Some((surface, _)) = prism.convex_mesh else { panic!("the prism is convex") };
        // Not convex: an L-shaped extrusion; and a box beside a second mesh.
        let l_shape = format!(
            "{BASE}\n[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\n\
             outline = [[0,0],[2,0],[2,1],[1,1],[1,2],[0,2]]\nz_range = [1, 1.5]\n"
        );
        assert!(parse(&l_shape).unwrap().convex_mesh.is_none());
        let cube =
            "[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[0,0],[1,0],[1,1],[0,1]]\n";
        let one = format!("{BASE}\n{cube}z_range = [1, 1.5]\n");
        assert!(parse(&one).unwrap().convex_mesh.is_some());
        let two = format!("{one}\n{cube}z_range = [2, 2.5]\n");
        assert!(parse(&two).unwrap().convex_mesh.is_none());

        // Rays from random points of the prism's triangles, on either side, in random
        // directions (grazing ones included): whenever the skip applies, the full
        // intersection agrees with the analytic shapes alone and no triangle is met.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut skipped = 0;
        for _ in 0..200_000 {
            let Some((_, p, side, ray)) = ray_leaving_a_triangle(&prism, &mut rng) else { continue };
            if prism.leaves_convex_mesh(surface, p, side, &ray) {
                skipped += 1;
                assert!(bvh::brute_force(&prism.triangles, &ray, 0.0, f32::INFINITY).is_none());
                assert_eq!(
                    prism.intersect(&ray, 0.0, f32::INFINITY),
                    prism.intersect_analytic(&ray, 0.0, f32::INFINITY)
                );
            }
        }
        // About half the rays start outside.
        assert!((80_000..120_000).contains(&skipped), "{skipped}");
    }

    #[test]
    fn a_triangle_met_by_a_ray_leaving_a_mesh_apart_is_the_nearest_hit() {
        use rand::SeedableRng;
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
        let cube = "[[shapes]]\nkind = \"extrusion\"\nmaterial = \"glass\"\noutline = [[0,0],[1,0],[1,1],[0,1]]\n\
                    z_range = [1, 1.5]\n";
        let with = |shape: &str| {
            parse(&format!("{BASE}\n{cube}\n[[shapes]]\nmaterial = \"floor\"\n{shape}\n")).unwrap()
        };
        let mut scenes: Vec<(&str, Scene)> = ["prism", "cognac", "water", "point-glass", "reflector"]
            .into_iter()
            .map(|name| (name, Scene::load(&dir.join(format!("{name}.toml"))).unwrap()))
            .collect();
        // A sphere half inside the cube: not apart.
        scenes.push(("cube and sphere", with("kind = \"sphere\"\ncenter = [0.5, 0.5, 1.5]\nradius = 0.3")));
        // The triangles themselves, as the brute force tests them: the prism's and the cube's
        // planes (`hull`, checked against the triangles in its own tests) would give the same
        // hits only to rounding, and this checks which shapes a ray is tested against.
        for (_, scene) in &mut scenes {
            scene.hull = None;
        }
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(13);
        for (name, scene) in &scenes {
            let apart = *name != "cube and sphere";
            assert_eq!(scene.mesh_apart, apart, "{name}");
            // Rays leaving random points of random triangles as the tracer starts them, to
            // either side, in random directions (grazing ones included), checked by brute force.
            let rays = (20_000_000 / scene.triangles.len()).min(20_000);
            let mut first = 0;
            for _ in 0..rays {
                let Some((k, p, side, ray)) = ray_leaving_a_triangle(scene, &mut rng) else { continue };
                let reach = scene.reach_after(scene.tri_info[k].surface, p, side, &ray);
                assert_eq!(reach == Reach::MeshFirst, apart && reach != Reach::Analytic);
                let got = scene.intersect_reach(&ray, reach, 0.0, f32::INFINITY);
                let want = scene.intersect_brute_force(&ray, 0.0, f32::INFINITY);
                assert_eq!(
                    got.map(|h| (h.t, h.normal, h.shape)),
                    want.map(|h| (h.t, h.normal, h.shape)),
                    "{name}"
                );
                first += (reach == Reach::MeshFirst) as usize;
            }
            assert!(!apart || first > rays / 3, "{name}: {first} of {rays}");
        }
        // A sphere inside the mesh's box, or a plane through it, or a floor closer than the
        // pad: not apart. The same floor far enough below: apart.
        assert!(!with("kind = \"sphere\"\ncenter = [0.5, 0.5, 1.2]\nradius = 0.1").mesh_apart);
        assert!(!with("kind = \"plane\"\npoint = [0, 0, 1.4]\nnormal = [1, 1, 1]").mesh_apart);
        let gap =
            |g: f32| format!("kind = \"plane\"\npoint = [0, 0, {}]\nnormal = [0, 0, 1]", 1.0 - g * 5e-5);
        assert_eq!(with(&gap(0.0)).ray_offset(), 5e-5, "extent 2 m");
        assert!(!with(&gap(2.0)).mesh_apart);
        assert!(with(&gap(8.0)).mesh_apart);
    }
}
