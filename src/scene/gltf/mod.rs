//! glTF 2.0 scenes (`.gltf` with its buffers, or `.glb`): the default scene's node hierarchy
//! with its transforms, triangle meshes (smooth where they carry normals, flat where not),
//! the first camera, `KHR_lights_punctual` lights and the materials the tracer knows, turned
//! into the same [`SceneDescription`] the TOML reader makes. docs/scene.md ("glTF scenes")
//! is the reference for users.
//!
//! The document is parsed and validated by the `gltf` crate; buffers and accessors are read
//! here, every offset, stride and count checked against the bytes that are there
//! (the `buffers` module). What the file holds and the tracer cannot honour (textures, animation,
//! emissive meshes, extensions not read, …) is listed in [`GltfScene::unsupported`], never
//! dropped silently.

mod buffers;
mod lights;
mod materials;

use std::path::Path;

use glam::{Mat3, Mat4, Quat, Vec3};

use super::camera::{Camera, Projection};
use super::material::Material;
use super::mesh::{Mesh, Transform};
use super::{SceneDescription, SceneError, Surface, SurfaceGeometry};
pub use buffers::{MAX_ACCESSOR_COUNT, MAX_BUFFER_BYTES};
pub use lights::{BEAM_SIZE_KEY, LUMENS_PER_WATT, spot_lumens};
pub use materials::{SMOOTH_ROUGHNESS, cauchy_of, volume_tint};

/// The largest glTF or GLB file read, bytes.
pub const MAX_FILE_BYTES: u64 = 1 << 31;
/// The most triangles a glTF scene may hold, over every instance of every mesh.
pub const MAX_TRIANGLES: usize = 1 << 25;

/// The extensions this reader understands; a file that requires another is refused, and one
/// that uses another has it listed as unsupported.
pub const EXTENSIONS_READ: [&str; 5] = [
    "KHR_lights_punctual",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_volume",
    "KHR_materials_dispersion",
];

/// A glTF file read: the scene, and what the user should be told about how it was read.
#[derive(Clone, Debug)]
pub struct GltfScene {
    /// The scene as the tracer sees it.
    pub description: SceneDescription,
    /// How things were read that the file leaves open (a directional light's beam, a spot's
    /// profile).
    pub notes: Vec<String>,
    /// Everything in the file that is not honoured, one line each, naming its element.
    pub unsupported: Vec<String>,
    /// The bytes of every external buffer file read, in order (recorded in the CRC that tells
    /// later stages whether the scene changed).
    pub buffer_files: Vec<Vec<u8>>,
}

/// Whether `path` names a glTF file (`.gltf` or `.glb`, any case).
pub fn is_gltf_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// Where errors point: the file as named to the user.
pub(super) struct Cx<'a> {
    file: &'a str,
}

impl Cx<'_> {
    fn err(&self, element: &str, message: impl Into<String>) -> SceneError {
        SceneError::Gltf {
            file: self.file.to_string(),
            element: element.to_string(),
            message: message.into(),
        }
    }
}

/// `kind[i]`, with the name if it has one: `materials[2] 'glass'`.
fn label(kind: &str, i: usize, name: Option<&str>) -> String {
    match name {
        Some(n) => format!("{kind}[{i}] '{n}'"),
        None => format!("{kind}[{i}]"),
    }
}

/// Refuses a mesh primitive whose POSITION names an accessor that does not exist, before the
/// `gltf` crate's validation, which reads that accessor unchecked (gltf-json 1.4.1,
/// `primitive_validate_hook`: an index out of bounds panics there; found by fuzzing).
fn check_position_accessors(cx: &Cx, json: &gltf::json::Root) -> Result<(), SceneError> {
    use gltf::json::validation::Checked;
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = primitive.attributes.get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if let Some(a) = position.filter(|a| a.value() >= json.accessors.len()) {
                return Err(cx.err(
                    &format!("meshes[{m}].primitives[{p}].attributes.POSITION"),
                    format!("accessor {} does not exist ({} accessors)", a.value(), json.accessors.len()),
                ));
            }
        }
    }
    Ok(())
}

/// Reads a glTF or GLB file's bytes; `file` names it in errors, `dir` resolves buffer files.
pub fn parse(bytes: &[u8], file: &str, dir: &Path) -> Result<GltfScene, SceneError> {
    let cx = Cx { file };
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(cx.err("file", format!("{} bytes is over the {MAX_FILE_BYTES} read", bytes.len())));
    }
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| cx.err("document", e.to_string()))?;
    let json = document.into_json();
    check_position_accessors(&cx, &json)?;
    let doc = gltf::Document::from_json(json).map_err(|e| cx.err("document", e.to_string()))?;
    let mut unsupported = Vec::new();
    let mut notes = Vec::new();
    for e in doc.extensions_required() {
        if !EXTENSIONS_READ.contains(&e) {
            return Err(cx.err("extensionsRequired", format!("{e} is required and not read here")));
        }
    }
    for e in doc.extensions_used().filter(|e| !EXTENSIONS_READ.contains(e)) {
        unsupported.push(format!("extension {e}"));
    }
    for (what, n) in [
        ("animations", doc.animations().len()),
        ("skins", doc.skins().len()),
        ("textures", doc.textures().len()),
    ] {
        if n > 0 {
            unsupported.push(format!("{n} {what} (the scene is read static and untextured)"));
        }
    }
    let mut buffer_files = Vec::new();
    let buffers = buffers::load(&cx, &doc, blob, dir, &mut buffer_files)?;

    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| cx.err("scenes", "the file has no scene"))?;
    if doc.scenes().len() > 1 {
        unsupported.push(format!(
            "{} scenes besides scenes[{}], the one read",
            doc.scenes().len() - 1,
            scene.index()
        ));
    }
    let placed = walk(&cx, &doc, &scene)?;

    let mut materials = Vec::new();
    let mut material_names = Vec::new();
    for m in doc.materials() {
        materials.push(materials::material(&cx, &m, &mut unsupported)?);
        material_names
            .push(m.name().map_or_else(|| format!("material{}", m.index().unwrap_or(0)), str::to_string));
    }
    let mut default_material = None;

    let mut surfaces = Vec::new();
    let mut triangles = 0usize;
    for (node, world) in placed.iter().filter(|(n, _)| n.mesh().is_some()) {
        let Some(mesh) = node.mesh() else { continue };
        let nwhat = label("nodes", node.index(), node.name());
        if node.skin().is_some() {
            unsupported.push(format!("{nwhat}: skin (the mesh is read in its bind pose)"));
        }
        let t = transform(&cx, &nwhat, world)?;
        let prims = mesh.primitives().len();
        for prim in mesh.primitives() {
            let pwhat =
                format!("{}.primitives[{}]", label("meshes", mesh.index(), mesh.name()), prim.index());
            let Some(m) = primitive(&cx, &pwhat, &prim, &buffers, &mut unsupported)? else { continue };
            triangles += m.indices.len();
            if triangles > MAX_TRIANGLES {
                return Err(cx.err(&pwhat, format!("the scene holds over {MAX_TRIANGLES} triangles")));
            }
            let material = match prim.material().index() {
                Some(i) => i as u32,
                None => *default_material.get_or_insert_with(|| {
                    materials.push(Material::Diffuse { albedo: Vec3::ONE });
                    material_names.push("default".to_string());
                    materials.len() as u32 - 1
                }),
            };
            let base =
                node.name().or(mesh.name()).map_or_else(|| format!("node{}", node.index()), str::to_string);
            let name = if prims > 1 { format!("{base}/{}", prim.index()) } else { base };
            surfaces.push(Surface { name, material, geometry: SurfaceGeometry::Mesh(m.transformed(&t)) });
        }
    }
    if surfaces.is_empty() {
        return Err(cx.err("meshes", "the scene has no triangle mesh"));
    }

    let boxes = |specular_only: bool| {
        let pts = surfaces
            .iter()
            .filter(|s| !specular_only || materials[s.material as usize].is_specular())
            .flat_map(|s| match &s.geometry {
                // The vertices of its triangles (an accessor may hold others' too).
                SurfaceGeometry::Mesh(m) => (0..m.indices.len()).flat_map(|i| m.triangle(i)).collect(),
                SurfaceGeometry::Analytic(_) => Vec::new(),
            });
        pts.fold(None, |b: Option<(Vec3, Vec3)>, p| Some(b.map_or((p, p), |(lo, hi)| (lo.min(p), hi.max(p)))))
    };
    let (specular_box, scene_box) = (boxes(true), boxes(false));
    let mut emitters = Vec::new();
    let mut emitter_names = Vec::new();
    let mut camera = None;
    for (node, world) in &placed {
        if let Some(light) = node.light() {
            let p = lights::Placed { light, node: node.clone(), world: *world };
            if let Some(e) = lights::emitter(&cx, &p, specular_box, scene_box, &mut unsupported, &mut notes)?
            {
                let name = p
                    .light
                    .name()
                    .or(node.name())
                    .map_or_else(|| format!("light{}", p.light.index()), str::to_string);
                emitters.push(e);
                emitter_names.push(name);
            }
        }
        if let Some(c) = node.camera() {
            let cwhat = label("cameras", c.index(), c.name());
            if camera.is_some() {
                unsupported.push(format!("{cwhat}: a camera besides the first (the scene's view)"));
            } else {
                camera = Some(read_camera(&cx, &cwhat, &c, world)?);
            }
        }
    }
    if emitters.is_empty() {
        return Err(cx.err("lights", "the scene has no light: add a KHR_lights_punctual light to a node"));
    }
    if emitters.len() > u16::MAX as usize + 1 {
        return Err(cx.err("lights", "more than 65536 lights"));
    }
    let description = SceneDescription {
        name: scene.name().map(str::to_string),
        camera,
        background: None,
        materials,
        material_names,
        emitters,
        emitter_names,
        surfaces,
    };
    Ok(GltfScene { description, notes, unsupported, buffer_files })
}

/// Every node of `scene` with its world matrix, depth first in file order. A node met twice
/// (a cycle, or a child shared by two parents) is refused: glTF's nodes form trees.
fn walk<'a>(
    cx: &Cx,
    doc: &'a gltf::Document,
    scene: &gltf::Scene<'a>,
) -> Result<Vec<(gltf::Node<'a>, Mat4)>, SceneError> {
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    stack.reverse();
    while let Some((node, parent)) = stack.pop() {
        let what = label("nodes", node.index(), node.name());
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(cx.err(
                &what,
                "is reached twice: the node graph has a cycle or a shared child (glTF nodes form trees)",
            ));
        }
        let world = parent * local(cx, &what, &node)?;
        if !world.is_finite() {
            return Err(cx.err(&what, "its world transform is not finite"));
        }
        stack.extend(node.children().collect::<Vec<_>>().into_iter().rev().map(|c| (c, world)));
        out.push((node, world));
    }
    Ok(out)
}

/// A node's own transform: its matrix, or its translation, rotation (a quaternion, normalised
/// here) and scale.
fn local(cx: &Cx, what: &str, node: &gltf::Node) -> Result<Mat4, SceneError> {
    match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => Ok(Mat4::from_cols_array_2d(&matrix)),
        gltf::scene::Transform::Decomposed { translation, rotation, scale } => {
            let q = glam::Vec4::from_array(rotation)
                .try_normalize()
                .map(Quat::from_vec4)
                .ok_or_else(|| cx.err(what, "rotation must be a non-zero finite quaternion"))?;
            Ok(Mat4::from_scale_rotation_translation(Vec3::from(scale), q, Vec3::from(translation)))
        }
    }
}

/// A node's world matrix as the mesh [`Transform`] (its upper 3 × 3 and its translation).
fn transform(cx: &Cx, what: &str, world: &Mat4) -> Result<Transform, SceneError> {
    let linear = Mat3::from_mat4(*world);
    let det = linear.determinant();
    if !(det.is_finite() && det != 0.0) {
        return Err(cx.err(what, "its world transform is singular (a zero scale)"));
    }
    Ok(Transform { linear, translate: world.w_axis.truncate() })
}

/// The triangle mesh of a primitive (in its node's space), or `None` (listed as unsupported)
/// for a primitive that is not of triangles or has no triangle of non-zero area.
fn primitive(
    cx: &Cx,
    what: &str,
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    unsupported: &mut Vec<String>,
) -> Result<Option<Mesh>, SceneError> {
    if prim.mode() != gltf::mesh::Mode::Triangles {
        unsupported.push(format!("{what}: mode {:?} (only TRIANGLES are read): left out", prim.mode()));
        return Ok(None);
    }
    if prim.morph_targets().len() > 0 {
        unsupported.push(format!("{what}: morph targets (the base shape is read)"));
    }
    for (sem, _) in prim.attributes() {
        if matches!(sem, gltf::Semantic::Colors(_)) {
            unsupported.push(format!("{what}: vertex colours {sem:?}"));
        }
    }
    let pos =
        prim.get(&gltf::Semantic::Positions).ok_or_else(|| cx.err(what, "has no POSITION attribute"))?;
    let positions = buffers::vec3s(cx, &pos, buffers)?;
    let normals = match prim.get(&gltf::Semantic::Normals) {
        Some(n) => {
            let ns = buffers::vec3s(cx, &n, buffers)?;
            if ns.len() != positions.len() {
                return Err(cx.err(what, format!("{} normals for {} positions", ns.len(), positions.len())));
            }
            let ns: Vec<Vec3> = ns.iter().map(|n| n.normalize_or_zero()).collect();
            if ns.contains(&Vec3::ZERO) {
                unsupported.push(format!("{what}: a zero normal (the primitive is shaded flat)"));
                None
            } else {
                Some(ns)
            }
        }
        None => None,
    };
    let flat: Vec<u32> = match prim.indices() {
        Some(acc) => buffers::indices(cx, &acc, buffers)?,
        None => (0..positions.len() as u32).collect(),
    };
    if !flat.len().is_multiple_of(3) {
        return Err(cx.err(what, format!("{} indices is not a whole number of triangles", flat.len())));
    }
    if let Some(&bad) = flat.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(cx.err(what, format!("index {bad} is past its {} vertices", positions.len())));
    }
    let indices = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    let m = Mesh { positions, normals, indices }.without_degenerate();
    if m.indices.is_empty() {
        unsupported.push(format!("{what}: no triangle of non-zero area: left out"));
        return Ok(None);
    }
    Ok(Some(m))
}

/// The scene camera from a glTF camera at `world`: it looks along its node's −z with +y up.
/// The image is 600 pixels high, as wide as the aspect ratio says (square without one).
fn read_camera(cx: &Cx, what: &str, c: &gltf::Camera, world: &Mat4) -> Result<Camera, SceneError> {
    let (projection, aspect) = match c.projection() {
        gltf::camera::Projection::Perspective(p) => {
            if !(p.yfov() > 0.0 && p.yfov() < std::f32::consts::PI) {
                return Err(cx.err(what, format!("yfov {} must lie in (0, π)", p.yfov())));
            }
            (Projection::Pinhole { fov_y_rad: p.yfov() }, p.aspect_ratio().unwrap_or(1.0))
        }
        gltf::camera::Projection::Orthographic(o) => {
            if !(o.ymag() > 0.0 && o.xmag() > 0.0 && o.ymag().is_finite() && o.xmag().is_finite()) {
                return Err(cx.err(what, "xmag and ymag must be positive"));
            }
            (Projection::Orthographic { height_m: 2.0 * o.ymag() }, o.xmag() / o.ymag())
        }
    };
    if !(aspect > 0.0 && aspect.is_finite()) {
        return Err(cx.err(what, format!("aspect ratio {aspect} must be positive")));
    }
    let width = (600.0 * aspect).round().clamp(1.0, 65536.0) as u32;
    let eye = world.transform_point3(Vec3::ZERO);
    let forward = world.transform_vector3(Vec3::NEG_Z);
    let up = world.transform_vector3(Vec3::Y);
    Camera::look_at(projection, eye, eye + forward, up, [width, 600])
        .ok_or_else(|| cx.err(what, "its node's transform collapses the view direction or up"))
}
