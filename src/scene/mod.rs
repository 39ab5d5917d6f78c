//! Scenes: the camera, emitters, shapes and materials the tracer shoots photons through.
//!
//! A scene is read from a TOML file (`docs/scene.md`; units are metres and watts) by
//! [`Scene::load`] or [`Scene::parse`], or from a glTF 2.0 file ([`gltf`]); [`SceneFile::read`]
//! reads either and says what the user should be told. Shapes are numbered in file order: that number is the
//! `surface` id stored with each photon. Analytic shapes are intersected directly; every
//! triangle of every mesh goes into one [bounding volume hierarchy](bvh).

pub use crate::accel::bvh;
pub mod camera;
pub mod describe;
pub mod emitter;
mod file;
pub mod gltf;
use crate::accel::hull;
#[cfg(test)]
mod hull_tests;
mod intersect;
pub mod material;
pub mod mesh;
mod resolve;
pub mod shape;
mod source;

use std::path::Path;

use glam::Vec3;

pub use camera::{Camera, Projection};
pub use describe::describe;
pub use emitter::{Emitter, EmitterShape};
pub use intersect::Reach;
pub use material::{Dielectric, Dispersion, Material};
pub use mesh::{Mesh, Transform};
pub use resolve::{ResolvedScene, for_map, scene_crc32};
pub use shape::{Hit, Ray, Shape};
pub use source::{SceneFile, unsupported_warning};

/// The scene `photonkit trace` uses when given none: a glass sphere above a floor under a
/// vertical collimated beam (`samples/scenes/glass-sphere.toml`).
pub const DEFAULT_SCENE: &str = include_str!("../../samples/scenes/glass-sphere.toml");
/// The name the default scene goes by in messages and stage records.
pub const DEFAULT_SCENE_NAME: &str = "<default scene: glass-sphere.toml>";

/// The ray offset as a fraction of the scene's extent ([`Scene::ray_offset`]).
pub const RAY_OFFSET_REL: f32 = 2.5e-5;
/// The ray offset of a scene with no extent (a single point), metres.
const RAY_OFFSET_FALLBACK_M: f32 = 1e-4;

/// Everything that can be wrong with a scene file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    /// Reading the scene file failed.
    #[error("{file}: {source}")]
    Io {
        /// The scene file as named to the user.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// A syntax, type or value error at a place in the file (line and column 1-based).
    #[error("{file}:{line}:{column}: {field}: {message}")]
    Invalid {
        /// The scene file as named to the user.
        file: String,
        /// The line, 1-based.
        line: usize,
        /// The column, 1-based.
        column: usize,
        /// The key's path (`shapes[1].radius`).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// A glTF file that is malformed, refers to what is not there, or asks for more than is
    /// read: `element` names the part (`accessors[3]`, `nodes[2] 'lamp'`, `buffers[0]`).
    #[error("{file}: {element}: {message}")]
    Gltf {
        /// The glTF file as named to the user.
        file: String,
        /// The element of the file at fault.
        element: String,
        /// What is wrong with it.
        message: String,
    },
    /// The scene file a map's trace record names is not where the record says.
    #[error("{map}: traced from the scene '{scene}', which is not found here: pass --scene FILE")]
    NotFound {
        /// The map as named to the user.
        map: String,
        /// The scene file as the record names it.
        scene: String,
    },
}

/// The geometry of one surface, in world space.
#[derive(Clone, Debug, PartialEq)]
pub enum SurfaceGeometry {
    /// A shape intersected in closed form.
    Analytic(Shape),
    /// A triangle mesh, its triangles in the scene's BVH.
    Mesh(Mesh),
}

/// One shape of the scene: its name, material and geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    /// The name in messages (the scene file's `name`, or one made from its kind and number).
    pub name: String,
    /// Index into [`SceneDescription::materials`].
    pub material: u32,
    /// Its shape, world space.
    pub geometry: SurfaceGeometry,
}

/// What a scene is made of, as a scene file or code describes it: every field can be edited.
/// [`SceneDescription::build`] turns it into a [`Scene`], whose acceleration structures (the
/// BVH, the convex hull, the boxes that let rays skip shapes) are built from it once; a
/// `Scene` cannot be edited, so they never go stale.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneDescription {
    /// The scene file's `name`, if it gives one.
    pub name: Option<String>,
    /// The view `photonkit render` uses when given no other.
    pub camera: Option<Camera>,
    /// What eye rays that leave the scene see (docs/scene.md, `[background]`); `None`: black.
    /// It is seen, not a light: it sends no photons and lights no surface.
    pub background: Option<Background>,
    /// The materials, indexed by [`Surface::material`].
    pub materials: Vec<Material>,
    /// The materials' names, one per material.
    pub material_names: Vec<String>,
    /// The emitters; a photon's `emitter` column indexes this list.
    pub emitters: Vec<Emitter>,
    /// The emitters' names, one per emitter.
    pub emitter_names: Vec<String>,
    /// The shapes; a photon's `surface` column indexes this list.
    pub surfaces: Vec<Surface>,
}

impl SceneDescription {
    /// The scene ready to trace: every mesh triangle in the BVH, the ray offset, and the
    /// shortcuts of [`Scene::reach_after`] and [`Scene::may_meet_specular`] worked out. Panics
    /// if a surface names a material that does not exist, or a name list's length differs
    /// from its list's.
    pub fn build(self) -> Scene {
        assert_eq!(self.materials.len(), self.material_names.len(), "one name per material");
        assert_eq!(self.emitters.len(), self.emitter_names.len(), "one name per emitter");
        for surf in &self.surfaces {
            assert!(
                (surf.material as usize) < self.materials.len(),
                "surface '{}' has no material",
                surf.name
            );
        }
        Scene::from_description(self)
    }

    /// The description with every length multiplied by `f` (finite, > 0) about the origin:
    /// shapes, meshes, emitter positions and sizes, the camera's eye and orthographic height.
    /// Powers stay in watts, so irradiance on the scaled scene is 1/f² times the original's.
    pub fn scaled(&self, f: f32) -> SceneDescription {
        assert!(f > 0.0 && f.is_finite(), "scale factor {f}: must be finite and positive");
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
        // The same power over areas f² as large: every radiance, the background's too, is
        // divided by f², so the scaled scene looks the same up to exposure.
        let k = 1.0 / (f * f);
        let background = self.background.as_ref().map(|b| match b {
            Background::Uniform(c) => Background::Uniform(*c * k),
            Background::Sky { zenith, horizon, ground } => {
                Background::Sky { zenith: *zenith * k, horizon: *horizon * k, ground: *ground * k }
            }
            Background::Image { path, strength, rotate_deg } => {
                Background::Image { path: path.clone(), strength: strength * k, rotate_deg: *rotate_deg }
            }
        });
        SceneDescription {
            name: self.name.clone(),
            camera: self.camera.as_ref().map(|c| c.scaled(f)),
            background,
            materials: self.materials.clone(),
            material_names: self.material_names.clone(),
            emitters: self.emitters.iter().map(|e| e.scaled(f)).collect(),
            emitter_names: self.emitter_names.clone(),
            surfaces,
        }
    }
}

/// A scene ready to trace: its [description](SceneDescription) and the acceleration
/// structures built from it. Read-only; to change a scene, edit a copy of its
/// [`Scene::description`] and [build](SceneDescription::build) it again.
#[derive(Clone, Debug)]
pub struct Scene {
    desc: SceneDescription,
    /// Each analytic surface and its id.
    analytic: Vec<(Shape, u32)>,
    /// Every mesh triangle of every surface, in surface order.
    triangles: Vec<[Vec3; 3]>,
    tri_info: Vec<TriInfo>,
    bvh: bvh::Bvh,
    /// See [`Scene::ray_offset`].
    ray_offset: f32,
    /// When every triangle belongs to one surface and that mesh is convex: the surface and
    /// the centroid of its vertices (see [`Scene::leaves_convex_mesh`]).
    convex_mesh: Option<(u32, Vec3)>,
    /// The convex mesh as the half-spaces of its faces, when it is closed and flat-shaded:
    /// rays are tested against its planes instead of its triangles ([`Scene::intersect`]).
    hull: Option<hull::Hull>,
    /// The box around every mirror and dielectric surface, padded by the ray offset; `None`
    /// when one is unbounded (see [`Scene::may_meet_specular`]).
    specular_box: Option<(Vec3, Vec3)>,
    /// Whether no analytic shape comes near the box around the triangles (see
    /// [`Scene::reach_after`]).
    mesh_apart: bool,
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

/// The background of a scene: seen by eye rays that escape, directly or through glass and
/// mirrors (docs/scene.md). Radiance in W/(m²·sr) per channel.
#[derive(Clone, Debug, PartialEq)]
pub enum Background {
    /// The same radiance in every direction.
    Uniform(Vec3),
    /// A sky: above the horizon `horizon` blended into `zenith` with the sine of the
    /// elevation, L = horizon + (zenith − horizon)·d_z for d_z ≥ 0; below it `ground`.
    Sky {
        /// Radiance straight up, W/(m²·sr) per channel.
        zenith: Vec3,
        /// Radiance along the horizon.
        horizon: Vec3,
        /// Radiance of every direction below the horizon.
        ground: Vec3,
    },
    /// An equirectangular image (linear RGB OpenEXR), loaded by the renderer: the image's
    /// top row looks up (+z), its horizontal centre along +x turned by `rotate_deg` about z
    /// (anticlockwise seen from above), each pixel times `strength`.
    Image {
        /// The OpenEXR file, resolved against the scene file's folder.
        path: std::path::PathBuf,
        /// The factor every pixel is multiplied by.
        strength: f32,
        /// The turn about z, degrees, anticlockwise seen from above.
        rotate_deg: f32,
    },
}

impl Scene {
    /// Builds the acceleration structures for `desc` (checked by [`SceneDescription::build`]).
    fn from_description(desc: SceneDescription) -> Scene {
        let mut s = Scene {
            desc,
            analytic: Vec::new(),
            triangles: Vec::new(),
            tri_info: Vec::new(),
            bvh: bvh::Bvh::default(),
            ray_offset: RAY_OFFSET_FALLBACK_M,
            convex_mesh: None,
            hull: None,
            specular_box: None,
            mesh_apart: false,
        };
        for id in 0..s.desc.surfaces.len() {
            s.add_surface(id as u32);
        }
        s.bvh = bvh::Bvh::build(&s.triangles);
        s.ray_offset = s.compute_ray_offset();
        s.convex_mesh = s.find_convex_mesh();
        s.hull = s.find_hull();
        s.specular_box = s.find_specular_box();
        s.mesh_apart = s.find_mesh_apart();
        s
    }

    /// A scene built in code: named materials, emitters (named `emitter0`, `emitter1`, …) and
    /// surfaces (whose `material` indexes `materials`). Panics if a surface names a material
    /// that does not exist.
    pub fn new(materials: Vec<(String, Material)>, emitters: Vec<Emitter>, surfaces: Vec<Surface>) -> Scene {
        let (material_names, materials) = materials.into_iter().unzip();
        SceneDescription {
            emitter_names: (0..emitters.len()).map(|i| format!("emitter{i}")).collect(),
            emitters,
            materials,
            material_names,
            surfaces,
            ..SceneDescription::default()
        }
        .build()
    }

    /// Reads a scene file, TOML or glTF by its extension; relative paths inside it (OBJ files,
    /// glTF buffers) are resolved beside it. [`SceneFile::read`] does the same and also returns
    /// what the file holds that the tracer does not honour.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        SceneFile::read(path).map(|f| f.scene)
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

    /// What the scene was built from.
    pub fn description(&self) -> &SceneDescription {
        &self.desc
    }

    /// The scene file's `name`, if it gives one.
    pub fn name(&self) -> Option<&str> {
        self.desc.name.as_deref()
    }

    /// The view `photonkit render` uses when given no other.
    pub fn camera(&self) -> Option<&Camera> {
        self.desc.camera.as_ref()
    }

    /// What eye rays that leave the scene see; `None`: black ([`SceneDescription::background`]).
    pub fn background(&self) -> Option<&Background> {
        self.desc.background.as_ref()
    }

    /// The materials, indexed by [`Surface::material`].
    pub fn materials(&self) -> &[Material] {
        &self.desc.materials
    }

    /// The materials' names, one per material.
    pub fn material_names(&self) -> &[String] {
        &self.desc.material_names
    }

    /// The emitters; a photon's `emitter` column indexes this list.
    pub fn emitters(&self) -> &[Emitter] {
        &self.desc.emitters
    }

    /// The emitters' names, one per emitter.
    pub fn emitter_names(&self) -> &[String] {
        &self.desc.emitter_names
    }

    /// The shapes; a photon's `surface` column (and [`Hit::shape`]) indexes this list.
    pub fn surfaces(&self) -> &[Surface] {
        &self.desc.surfaces
    }

    /// Adds surface `id`'s shape, or its triangles, to the lists the ray queries read.
    fn add_surface(&mut self, id: u32) {
        match &self.desc.surfaces[id as usize].geometry {
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
    }

    /// The scene with every length multiplied by `f` (finite, > 0) about the origin
    /// ([`SceneDescription::scaled`]).
    pub fn scaled(&self, f: f32) -> Scene {
        self.desc.scaled(f).build()
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
        self.desc.emitters.iter().flat_map(|e| e.extent_points()).for_each(&mut add);
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
        &self.desc.materials[self.desc.surfaces[surface as usize].material as usize]
    }

    /// Whether any material disperses light (photons then take a wavelength).
    pub fn has_dispersion(&self) -> bool {
        self.desc.materials.iter().any(|m| matches!(m, Material::Dielectric(d) if d.dispersion.is_some()))
    }

    /// Largest number of trajectory parameters of any emitter (the `params` column's width).
    pub fn param_dims(&self) -> u32 {
        let spectral = self.is_spectral();
        self.desc.emitters.iter().map(|e| e.param_dims(spectral)).max().unwrap_or(0)
    }

    /// Whether photons carry their wavelength as a trajectory parameter: when some material
    /// disperses light (docs/spectral.md). Every emitter then has the spectral dimension.
    pub fn is_spectral(&self) -> bool {
        self.has_dispersion()
    }

    /// The PHM metadata records of the emitters.
    pub fn emitter_records(&self) -> Vec<crate::format::Emitter> {
        let spectral = self.is_spectral();
        self.desc.emitters.iter().enumerate().map(|(i, e)| e.record(i as u32, spectral)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn parse(src: &str) -> Result<Scene, SceneError> {
        Scene::parse(src, "test.toml", Path::new("."))
    }

    pub(super) const BASE: &str = r#"
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
        assert!(!s.emitters().is_empty() && !s.surfaces().is_empty());
        assert!(s.camera().is_some());
    }

    /// A scene changes only by building an edited copy of its description, so its rays meet
    /// what the description holds: a sphere added to the copy is met, and the original still
    /// misses it. Scaling the description scales the scene.
    #[test]
    fn an_edited_description_builds_a_new_scene() {
        let s = parse(BASE).unwrap();
        let mut d = s.description().clone();
        let glass = d.material_names.iter().position(|n| n == "glass").unwrap() as u32;
        let sphere = Shape::Sphere { center: Vec3::new(0.0, 0.0, 1.0), radius: 0.5 };
        d.surfaces.push(Surface {
            name: "ball".into(),
            material: glass,
            geometry: SurfaceGeometry::Analytic(sphere),
        });
        let edited = d.build();
        let down = Ray::new(Vec3::new(0.0, 0.0, 3.0), Vec3::NEG_Z);
        assert_eq!(edited.intersect(&down, 0.0, f32::INFINITY).map(|h| (h.shape, h.t)), Some((1, 1.5)));
        assert_eq!(s.intersect(&down, 0.0, f32::INFINITY).map(|h| (h.shape, h.t)), Some((0, 3.0)));
        assert_eq!(edited.description().scaled(2.0).build().description(), edited.scaled(2.0).description());
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
}
