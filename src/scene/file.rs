//! The scene file: TOML read with serde into `Raw*` structs that mirror the file (every value
//! with its byte span), then checked and turned into a [`Scene`]. Every error names the line
//! and the field. docs/scene.md is the reference for users.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use glam::{Vec2, Vec3};
use serde::Deserialize;
use toml::Spanned;

use super::camera::{Camera, Projection};
use super::emitter::{Emitter, EmitterShape};
use super::material::{Dielectric, Dispersion, Material};
use super::mesh::{self, Mesh, Transform};
use super::shape::Shape;
use super::{Background, Scene, SceneError, SurfaceGeometry};

type Sp<T> = Spanned<T>;

/// Declares a table of the file: every key optional and spanned, unknown keys refused, and a
/// list of the keys present (to refuse those that do not apply to the table's `kind`).
macro_rules! raw_table {
    ($name:ident { $($field:ident : $ty:ty),* $(,)? }) => {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct $name {
            $( #[serde(default)] $field: Option<Sp<$ty>>, )*
        }
        impl $name {
            fn present(&self) -> Vec<(&'static str, Range<usize>)> {
                let mut v = Vec::new();
                $( if let Some(x) = &self.$field { v.push((stringify!($field), x.span())); } )*
                v
            }
        }
    };
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    #[serde(default)]
    name: Option<String>,
    #[serde(default)]
    scale: Option<Sp<f32>>,
    #[serde(default)]
    camera: Option<Sp<RawCamera>>,
    #[serde(default)]
    background: Option<Sp<RawBackground>>,
    #[serde(default)]
    materials: BTreeMap<String, Sp<RawMaterial>>,
    #[serde(default)]
    emitters: Vec<Sp<RawEmitter>>,
    #[serde(default)]
    shapes: Vec<Sp<RawShape>>,
}

raw_table!(RawCamera {
    projection: String,
    eye: [f32; 3],
    look_at: [f32; 3],
    up: [f32; 3],
    fov_deg: f32,
    height: f32,
    resolution: [u32; 2],
});

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBackground {
    #[serde(default)]
    colour: Option<Sp<[f32; 3]>>,
    #[serde(default)]
    image: Option<Sp<String>>,
    #[serde(default)]
    strength: Option<Sp<f32>>,
    #[serde(default)]
    rotate_deg: Option<Sp<f32>>,
}

raw_table!(RawMaterial {
    kind: String,
    albedo: [f32; 3],
    reflectance: [f32; 3],
    ior: f32,
    ideal: bool,
    tint: [f32; 3],
    cauchy: Vec<f64>,
    sellmeier: RawSellmeier,
});

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSellmeier {
    b: Vec<f64>,
    c: Vec<f64>,
}

raw_table!(RawEmitter {
    kind: String,
    name: String,
    power_w: f64,
    colour: [f32; 3],
    position: [f32; 3],
    direction: [f32; 3],
    half_angle_deg: f32,
    center: [f32; 3],
    size: [f32; 2],
    up: [f32; 3],
    origin: [f32; 3],
    edge_u: [f32; 3],
    edge_v: [f32; 3],
});

raw_table!(RawShape {
    kind: String,
    name: String,
    material: String,
    transform: RawTransform,
    center: [f32; 3],
    radius: f32,
    point: [f32; 3],
    normal: [f32; 3],
    origin: [f32; 3],
    edge_u: [f32; 3],
    edge_v: [f32; 3],
    base: [f32; 3],
    axis: [f32; 3],
    height: f32,
    file: String,
    smooth: bool,
    profile: Vec<[f32; 2]>,
    segments: u32,
    crease_deg: f32,
    size: [f32; 2],
    cells: [u32; 2],
    waves: Vec<RawWave>,
    outline: Vec<[f32; 2]>,
    z_range: [f32; 2],
    focal_length: f32,
    inner_radius: f32,
    rings: u32,
});

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTransform {
    #[serde(default)]
    scale: Option<Scale>,
    #[serde(default)]
    rotate_deg: Option<[f32; 3]>,
    #[serde(default)]
    translate: Option<[f32; 3]>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Scale {
    Uniform(f32),
    Axes([f32; 3]),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWave {
    amplitude: f32,
    wavelength: f32,
    #[serde(default)]
    direction_deg: f32,
    #[serde(default)]
    phase_deg: f32,
}

/// Where errors point: the file's name and text.
struct Ctx<'a> {
    file: &'a str,
    src: &'a str,
}

impl Ctx<'_> {
    fn err(&self, span: Range<usize>, field: impl Into<String>, message: impl Into<String>) -> SceneError {
        let (line, column) = line_column(self.src, span.start);
        SceneError::Invalid {
            file: self.file.to_string(),
            line,
            column,
            field: field.into(),
            message: message.into(),
        }
    }

    /// A TOML syntax or type error: the field is read off the line the error points at.
    fn toml(&self, e: &toml::de::Error) -> SceneError {
        let span = e.span().unwrap_or(0..0);
        let field = field_at(self.src, span.clone()).unwrap_or_else(|| "(syntax)".into());
        self.err(span, field, e.message().to_string())
    }
}

/// Fields that hold a fixed number of numbers, and how many.
const FIXED_ARRAYS: [(&str, usize); 23] = [
    ("eye", 3),
    ("look_at", 3),
    ("up", 3),
    ("albedo", 3),
    ("reflectance", 3),
    ("tint", 3),
    ("colour", 3),
    ("position", 3),
    ("direction", 3),
    ("center", 3),
    ("origin", 3),
    ("edge_u", 3),
    ("edge_v", 3),
    ("point", 3),
    ("normal", 3),
    ("base", 3),
    ("axis", 3),
    ("rotate_deg", 3),
    ("translate", 3),
    ("resolution", 2),
    ("size", 2),
    ("cells", 2),
    ("z_range", 2),
];

/// Refuses an array field with the wrong number of elements (`size = [1, 1, 1]` for a
/// rectangle's two sides), which deserialising into a fixed-size array lets through: named by
/// its path, at the first line where that key has such an array.
fn check_array_lengths(cx: &Ctx) -> Result<(), SceneError> {
    fn walk(v: &toml::Value, path: &str, bad: &mut Option<(String, String, usize, usize)>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                    if let (toml::Value::Array(a), Some((_, n))) =
                        (v, FIXED_ARRAYS.iter().find(|(f, _)| f == k))
                    {
                        if a.len() != *n && bad.is_none() {
                            *bad = Some((p.clone(), k.clone(), *n, a.len()));
                        }
                    } else if let (toml::Value::Array(a), "profile" | "outline") = (v, k.as_str()) {
                        if let Some(i) = a.iter().position(|x| x.as_array().is_some_and(|x| x.len() != 2)) {
                            let len = a[i].as_array().map_or(0, Vec::len);
                            bad.get_or_insert((format!("{p}[{i}]"), k.clone(), 2, len));
                        }
                    } else {
                        walk(v, &p, bad);
                    }
                }
            }
            toml::Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    walk(x, &format!("{path}[{i}]"), bad);
                }
            }
            _ => {}
        }
    }
    let Ok(doc) = cx.src.parse::<toml::Table>() else { return Ok(()) };
    let mut bad = None;
    walk(&toml::Value::Table(doc), "", &mut bad);
    let Some((path, key, want, got)) = bad else { return Ok(()) };
    // The line: the first `key = [` whose array has the wrong length (else the first `key =`).
    let mut at = 0;
    let mut offset = 0;
    for line in cx.src.split_inclusive('\n') {
        let t = line.trim_start();
        if let Some(rest) = t.strip_prefix(key.as_str())
            && let Some(value) = rest.trim_start().strip_prefix('=')
        {
            let len = format!("v = {}", value.trim()).parse::<toml::Table>().ok().and_then(|t| {
                t.get("v")
                    .and_then(|v| v.as_array())
                    .map(|a| if key == "profile" || key == "outline" { usize::MAX } else { a.len() })
            });
            if at == 0 {
                at = offset + (line.len() - t.len());
            }
            if len == Some(got) {
                at = offset + (line.len() - t.len());
                break;
            }
        }
        offset += line.len();
    }
    Err(cx.err(at..at, path, format!("expected {want} numbers, found {got}")))
}

/// 1-based line and column of byte `at`.
fn line_column(src: &str, at: usize) -> (usize, usize) {
    let at = at.min(src.len());
    let before = &src.as_bytes()[..at];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let start = before.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    (line, src.get(start..at).map_or(at - start, |s| s.chars().count()) + 1)
}

/// The key a span belongs to: the key itself, or the nearest `key =` before it on its line,
/// or the `[table]` header it is.
fn field_at(src: &str, span: Range<usize>) -> Option<String> {
    let is_key =
        |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    let at = span.start.min(src.len());
    let line_start = src[..at].rfind('\n').map_or(0, |p| p + 1);
    let line_end = src[at..].find('\n').map_or(src.len(), |p| at + p);
    let text = src.get(span.start..span.end.min(line_end)).unwrap_or("");
    if is_key(text.trim()) && src[span.end.min(line_end)..line_end].trim_start().starts_with('=') {
        return Some(text.trim().to_string());
    }
    let before = &src[line_start..at];
    if let Some(eq) = before.rfind('=') {
        let key = before[..eq].trim_end();
        let k =
            key.rsplit(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '-')).next().unwrap_or("");
        if is_key(k) {
            return Some(k.to_string());
        }
    }
    let line = src[line_start..line_end].trim();
    let header = line.trim_start_matches('[').trim_end_matches(']').trim();
    (line.starts_with('[') && is_key(&header.replace('.', "_"))).then(|| header.to_string())
}

/// Reads a scene from TOML text; `file` names it in errors and `dir` resolves relative paths.
pub(super) fn parse(src: &str, file: &str, dir: &Path) -> Result<Scene, SceneError> {
    let cx = Ctx { file, src };
    // Through serde_path_to_error, so a wrong type names its full field (`shapes[1].radius`).
    let de = toml::Deserializer::parse(src).map_err(|e| cx.toml(&e))?;
    let raw: RawScene = serde_path_to_error::deserialize(de).map_err(|e| {
        // (toml's spans appear in the path as private segments: left out.)
        let path: Vec<String> =
            e.path().to_string().split('.').filter(|s| !s.starts_with("$__")).map(str::to_string).collect();
        let path = path.join(".");
        let err = cx.toml(e.inner());
        match err {
            SceneError::Invalid { file, line, column, message, .. } if path != "." && !path.is_empty() => {
                SceneError::Invalid { file, line, column, field: path, message }
            }
            err => err,
        }
    })?;
    check_array_lengths(&cx)?;

    let scale = match &raw.scale {
        Some(f) if !(*f.get_ref() > 0.0 && f.get_ref().is_finite()) => {
            return Err(cx.err(f.span(), "scale", "must be a finite positive number"));
        }
        Some(f) => *f.get_ref(),
        None => 1.0,
    };
    let camera = raw.camera.as_ref().map(|c| camera(&cx, c)).transpose()?;
    let background = raw.background.as_ref().map(|b| background(&cx, b, dir)).transpose()?;

    let mut material_index = BTreeMap::new();
    let mut materials = Vec::new();
    let mut material_names = Vec::new();
    for (name, m) in &raw.materials {
        material_index.insert(name.clone(), materials.len() as u32);
        materials.push(material(&cx, name, m)?);
        material_names.push(name.clone());
    }

    let mut emitters = Vec::new();
    let mut emitter_names = Vec::new();
    for (i, e) in raw.emitters.iter().enumerate() {
        emitters.push(emitter(&cx, i, e)?);
        emitter_names
            .push(e.get_ref().name.as_ref().map_or_else(|| format!("emitter{i}"), |n| n.get_ref().clone()));
    }
    if emitters.is_empty() {
        return Err(cx.err(0..0, "emitters", "the scene has no emitter: add an [[emitters]] table"));
    }
    if emitters.len() > u16::MAX as usize + 1 {
        return Err(cx.err(raw.emitters[0].span(), "emitters", "more than 65536 emitters"));
    }

    let mut scene = Scene::empty();
    scene.name = raw.name.clone();
    scene.camera = camera;
    scene.background = background;
    scene.materials = materials;
    scene.material_names = material_names;
    scene.emitters = emitters;
    scene.emitter_names = emitter_names;
    for (i, s) in raw.shapes.iter().enumerate() {
        let (name, material, geometry) = shape(&cx, i, s, &material_index, dir)?;
        scene.add_surface(name, material, geometry);
    }
    if scene.surfaces.is_empty() {
        return Err(cx.err(0..0, "shapes", "the scene has no shape: add a [[shapes]] table"));
    }
    scene.finish();
    Ok(if scale == 1.0 { scene } else { scene.scaled(scale) })
}

/// Refuses keys that are not in `allowed` for this `kind`.
fn only(
    cx: &Ctx,
    what: &str,
    kind: &str,
    present: Vec<(&'static str, Range<usize>)>,
    allowed: &[&str],
) -> Result<(), SceneError> {
    for (k, span) in present {
        if !allowed.contains(&k) {
            return Err(cx.err(
                span,
                format!("{what}.{k}"),
                format!("does not apply to kind \"{kind}\" (its keys: {})", allowed.join(", ")),
            ));
        }
    }
    Ok(())
}

fn req<'a, T>(
    cx: &Ctx,
    table: Range<usize>,
    what: &str,
    key: &str,
    v: &'a Option<Sp<T>>,
) -> Result<&'a T, SceneError> {
    v.as_ref().map(|s| s.get_ref()).ok_or_else(|| cx.err(table, format!("{what}.{key}"), "missing"))
}

fn vec3(a: &[f32; 3]) -> Vec3 {
    Vec3::from_array(*a)
}

fn finite(cx: &Ctx, what: &str, key: &str, v: &Option<Sp<[f32; 3]>>) -> Result<Option<Vec3>, SceneError> {
    match v {
        Some(s) if s.get_ref().iter().any(|x| !x.is_finite()) => {
            Err(cx.err(s.span(), format!("{what}.{key}"), "must be finite"))
        }
        Some(s) => Ok(Some(vec3(s.get_ref()))),
        None => Ok(None),
    }
}

fn unit(cx: &Ctx, what: &str, key: &str, v: &Option<Sp<[f32; 3]>>) -> Result<Option<Vec3>, SceneError> {
    match (finite(cx, what, key, v)?, v) {
        (Some(x), Some(s)) => x
            .try_normalize()
            .map(Some)
            .ok_or_else(|| cx.err(s.span(), format!("{what}.{key}"), "must not be zero")),
        _ => Ok(None),
    }
}

fn positive(cx: &Ctx, what: &str, key: &str, v: &Option<Sp<f32>>) -> Result<Option<f32>, SceneError> {
    match v {
        Some(s) if !(s.get_ref().is_finite() && *s.get_ref() > 0.0) => {
            Err(cx.err(s.span(), format!("{what}.{key}"), "must be a positive number"))
        }
        Some(s) => Ok(Some(*s.get_ref())),
        None => Ok(None),
    }
}

/// An RGB fraction in [0, 1] per channel.
fn fraction(cx: &Ctx, what: &str, key: &str, v: &Option<Sp<[f32; 3]>>) -> Result<Option<Vec3>, SceneError> {
    match v {
        Some(s) if s.get_ref().iter().any(|x| !(0.0..=1.0).contains(x)) => {
            Err(cx.err(s.span(), format!("{what}.{key}"), "each channel must lie in [0, 1]"))
        }
        Some(s) => Ok(Some(vec3(s.get_ref()))),
        None => Ok(None),
    }
}

/// `[background]`: a uniform `colour` or an equirectangular `image` (its path relative to the
/// scene file, checked to exist here and read by the renderer), times `strength`.
fn background(cx: &Ctx, b: &Sp<RawBackground>, dir: &Path) -> Result<Background, SceneError> {
    let (span, r) = (b.span(), b.get_ref());
    let strength = match &r.strength {
        Some(s) if !(s.get_ref().is_finite() && *s.get_ref() >= 0.0) => {
            return Err(cx.err(s.span(), "background.strength", "must be finite and ≥ 0"));
        }
        Some(s) => *s.get_ref(),
        None => 1.0,
    };
    match (&r.colour, &r.image) {
        (Some(c), None) => {
            if r.rotate_deg.is_some() {
                return Err(cx.err(span, "background.rotate_deg", "applies to an image only"));
            }
            let c = *c.get_ref();
            if c.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(cx.err(b.span(), "background.colour", "needs three finite values ≥ 0"));
            }
            Ok(Background::Uniform(Vec3::from_array(c) * strength))
        }
        (None, Some(f)) => {
            let path = dir.join(f.get_ref());
            if !path.is_file() {
                return Err(cx.err(
                    f.span(),
                    "background.image",
                    format!("{}: no such file (an equirectangular OpenEXR image)", path.display()),
                ));
            }
            let rotate_deg = r.rotate_deg.as_ref().map_or(0.0, |s| *s.get_ref());
            if !rotate_deg.is_finite() {
                return Err(cx.err(span, "background.rotate_deg", "must be finite"));
            }
            Ok(Background::Image { path, strength, rotate_deg })
        }
        _ => Err(cx.err(span, "background", "give either colour = [r, g, b] or image = \"file.exr\"")),
    }
}

fn camera(cx: &Ctx, c: &Sp<RawCamera>) -> Result<Camera, SceneError> {
    let (span, r) = (c.span(), c.get_ref());
    let kind = req(cx, span.clone(), "camera", "projection", &r.projection)?.as_str();
    let common = ["projection", "eye", "look_at", "up", "resolution"];
    let projection = match kind {
        "pinhole" => {
            only(cx, "camera", kind, r.present(), &[&common[..], &["fov_deg"]].concat())?;
            let fov = positive(cx, "camera", "fov_deg", &r.fov_deg)?.unwrap_or(40.0);
            if fov >= 180.0 {
                return Err(cx.err(
                    r.fov_deg.as_ref().map_or(span, |s| s.span()),
                    "camera.fov_deg",
                    "must be below 180",
                ));
            }
            Projection::Pinhole { fov_y_rad: fov.to_radians() }
        }
        "orthographic" => {
            only(cx, "camera", kind, r.present(), &[&common[..], &["height"]].concat())?;
            let h = positive(cx, "camera", "height", &r.height)?;
            Projection::Orthographic {
                height_m: h.ok_or_else(|| cx.err(span.clone(), "camera.height", "missing"))?,
            }
        }
        _ => {
            let s = r.projection.as_ref().map_or(span, |s| s.span());
            return Err(cx.err(
                s,
                "camera.projection",
                format!("unknown projection \"{kind}\" (pinhole, orthographic)"),
            ));
        }
    };
    let eye = finite(cx, "camera", "eye", &r.eye)?;
    let look = finite(cx, "camera", "look_at", &r.look_at)?;
    let (eye, look) = match (eye, look) {
        (Some(e), Some(l)) => (e, l),
        (None, _) => return Err(cx.err(span, "camera.eye", "missing")),
        (_, None) => return Err(cx.err(span, "camera.look_at", "missing")),
    };
    let up = unit(cx, "camera", "up", &r.up)?.unwrap_or(Vec3::Z);
    let res = r.resolution.as_ref().map_or([600, 600], |s| *s.get_ref());
    if res.contains(&0) || res.iter().any(|&x| x > 1 << 16) {
        let s = r.resolution.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, "camera.resolution", "each side must be 1 to 65536 pixels"));
    }
    Camera::look_at(projection, eye, look, up, res).ok_or_else(|| {
        cx.err(span, "camera.look_at", "eye and look_at coincide, or the view is parallel to up")
    })
}

fn material(cx: &Ctx, name: &str, m: &Sp<RawMaterial>) -> Result<Material, SceneError> {
    let what = format!("materials.{name}");
    let (span, r) = (m.span(), m.get_ref());
    let kind = req(cx, span.clone(), &what, "kind", &r.kind)?.as_str();
    Ok(match kind {
        "diffuse" => {
            only(cx, &what, kind, r.present(), &["kind", "albedo"])?;
            Material::Diffuse {
                albedo: fraction(cx, &what, "albedo", &r.albedo)?.unwrap_or(Vec3::splat(0.8)),
            }
        }
        "mirror" => {
            only(cx, &what, kind, r.present(), &["kind", "reflectance"])?;
            Material::Mirror {
                reflectance: fraction(cx, &what, "reflectance", &r.reflectance)?.unwrap_or(Vec3::ONE),
            }
        }
        "absorber" => {
            only(cx, &what, kind, r.present(), &["kind"])?;
            Material::Absorber
        }
        "dielectric" => {
            only(cx, &what, kind, r.present(), &["kind", "ior", "ideal", "tint", "cauchy", "sellmeier"])?;
            let dispersion = match (&r.cauchy, &r.sellmeier) {
                (Some(c), None) => {
                    let v = c.get_ref();
                    if !(2..=3).contains(&v.len()) || v.iter().any(|x| !x.is_finite()) || v[0] < 1.0 {
                        return Err(cx.err(
                            c.span(),
                            format!("{what}.cauchy"),
                            "needs [A, B] or [A, B, C] with A ≥ 1 (λ in µm)",
                        ));
                    }
                    Some(Dispersion::Cauchy { a: v[0], b: v[1], c: v.get(2).copied().unwrap_or(0.0) })
                }
                (None, Some(s)) => {
                    let v = s.get_ref();
                    if v.b.is_empty()
                        || v.b.len() != v.c.len()
                        || v.b.iter().chain(&v.c).any(|x| !x.is_finite() || *x < 0.0)
                    {
                        return Err(cx.err(s.span(), format!("{what}.sellmeier"), "needs b and c lists of equal, non-zero length with non-negative entries (c in µm²)"));
                    }
                    Some(Dispersion::Sellmeier { b: v.b.clone(), c: v.c.clone() })
                }
                (Some(_), Some(s)) => {
                    return Err(cx.err(
                        s.span(),
                        format!("{what}.sellmeier"),
                        "give cauchy or sellmeier, not both",
                    ));
                }
                (None, None) => None,
            };
            let ior = match (positive(cx, &what, "ior", &r.ior)?, &dispersion) {
                (Some(n), _) => n,
                // With dispersion, the index reported for the material is the one at 587.6 nm (n_d).
                (None, Some(d)) => d.ior(587.6),
                (None, None) => {
                    return Err(cx.err(span, format!("{what}.ior"), "missing (or give cauchy or sellmeier)"));
                }
            };
            if ior < 1.0 || !ior.is_finite() {
                let s = r.ior.as_ref().map_or(span, |s| s.span());
                return Err(cx.err(s, format!("{what}.ior"), "must be at least 1"));
            }
            Material::Dielectric(Dielectric {
                ior,
                dispersion,
                ideal: r.ideal.as_ref().is_some_and(|b| *b.get_ref()),
                tint: fraction(cx, &what, "tint", &r.tint)?.unwrap_or(Vec3::ONE),
            })
        }
        _ => {
            let s = r.kind.as_ref().map_or(span, |s| s.span());
            return Err(cx.err(
                s,
                format!("{what}.kind"),
                format!("unknown material kind \"{kind}\" (diffuse, mirror, dielectric, absorber)"),
            ));
        }
    })
}

/// The largest emitter power accepted, W (photon flux is f32; a photon's share stays finite).
pub const MAX_POWER_W: f64 = 1e30;

fn emitter(cx: &Ctx, i: usize, e: &Sp<RawEmitter>) -> Result<Emitter, SceneError> {
    let what = format!("emitters[{i}]");
    let (span, r) = (e.span(), e.get_ref());
    let kind = req(cx, span.clone(), &what, "kind", &r.kind)?.as_str();
    let power =
        r.power_w.as_ref().ok_or_else(|| cx.err(span.clone(), format!("{what}.power_w"), "missing"))?;
    if !(power.get_ref().is_finite() && *power.get_ref() > 0.0) {
        return Err(cx.err(power.span(), format!("{what}.power_w"), "must be a positive number of watts"));
    }
    // Photon flux is stored in f32: a power beyond this would overflow it.
    if *power.get_ref() > MAX_POWER_W {
        return Err(cx.err(
            power.span(),
            format!("{what}.power_w"),
            format!("{:e} W is beyond the {MAX_POWER_W:e} W photon flux can hold (f32)", power.get_ref()),
        ));
    }
    let colour = match &r.colour {
        Some(c)
            if c.get_ref().iter().any(|x| !(x.is_finite() && *x >= 0.0))
                || c.get_ref().iter().sum::<f32>() <= 0.0 =>
        {
            return Err(cx.err(
                c.span(),
                format!("{what}.colour"),
                "needs non-negative channels, not all zero",
            ));
        }
        Some(c) => vec3(c.get_ref()),
        None => Vec3::ONE,
    };
    let input = EmitterIn { cx, what: what.clone(), kind, span: span.clone(), r };
    let shape = match kind {
        "point" => point_emitter(&input)?,
        "spot" => spot_emitter(&input)?,
        "collimated" => collimated_emitter(&input)?,
        _ => {
            let s = r.kind.as_ref().map_or(span, |s| s.span());
            return Err(cx.err(
                s,
                format!("{what}.kind"),
                format!("unknown emitter kind \"{kind}\" (collimated, point, spot)"),
            ));
        }
    };
    Ok(Emitter { kind: shape, power_w: *power.get_ref(), colour })
}

/// An emitter's table as its kind reads it: where errors point (`emitters[i]`, the table's
/// span) and its keys.
struct EmitterIn<'a> {
    cx: &'a Ctx<'a>,
    what: String,
    kind: &'a str,
    span: Range<usize>,
    r: &'a RawEmitter,
}

impl EmitterIn<'_> {
    /// Refuses keys other than every emitter's and `extra`.
    fn allow(&self, extra: &[&str]) -> Result<(), SceneError> {
        let common = ["kind", "name", "power_w", "colour"];
        only(self.cx, &self.what, self.kind, self.r.present(), &[&common[..], extra].concat())
    }

    /// The error for a required key that is absent.
    fn missing(&self, key: &str) -> SceneError {
        self.cx.err(self.span.clone(), format!("{}.{key}", self.what), "missing")
    }
}

/// `kind = "point"`: a position.
fn point_emitter(e: &EmitterIn) -> Result<EmitterShape, SceneError> {
    let EmitterIn { cx, what, r, .. } = e;
    e.allow(&["position"])?;
    let p = finite(cx, what, "position", &r.position)?;
    Ok(EmitterShape::Point { position: p.ok_or_else(|| e.missing("position"))? })
}

/// `kind = "spot"`: a position, the cone's axis and its half angle (at most a hemisphere).
fn spot_emitter(e: &EmitterIn) -> Result<EmitterShape, SceneError> {
    let EmitterIn { cx, what, span, r, .. } = e;
    e.allow(&["position", "direction", "half_angle_deg"])?;
    let p = finite(cx, what, "position", &r.position)?;
    let d = unit(cx, what, "direction", &r.direction)?;
    let half = positive(cx, what, "half_angle_deg", &r.half_angle_deg)?.unwrap_or(90.0);
    if half > 90.0 {
        let s = r.half_angle_deg.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, format!("{what}.half_angle_deg"), "must be at most 90 (a hemisphere)"));
    }
    Ok(EmitterShape::Spot {
        position: p.ok_or_else(|| e.missing("position"))?,
        axis: d.ok_or_else(|| e.missing("direction"))?,
        half_angle_rad: half.to_radians(),
    })
}

/// `kind = "collimated"`: a rectangle given by center + size + direction or by origin +
/// edge_u + edge_v, and the beam's direction (by default the rectangle's normal), which must
/// not lie in the rectangle's plane.
fn collimated_emitter(e: &EmitterIn) -> Result<EmitterShape, SceneError> {
    let EmitterIn { cx, what, span, r, .. } = e;
    e.allow(&["direction", "center", "size", "up", "origin", "edge_u", "edge_v"])?;
    let dir = unit(cx, what, "direction", &r.direction)?;
    let (origin, eu, ev) =
        if r.center.is_some() || r.size.is_some() { centred_rectangle(e, dir)? } else { edge_rectangle(e)? };
    let n = eu.cross(ev).try_normalize().ok_or_else(|| {
        cx.err(
            r.edge_v.as_ref().map_or(span.clone(), |s| s.span()),
            format!("{what}.edge_v"),
            "the edges are parallel or zero",
        )
    })?;
    let direction = dir.unwrap_or(n);
    if direction.dot(n).abs() < 1e-3 {
        let s = r.direction.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, format!("{what}.direction"), "lies in the emitter's plane"));
    }
    Ok(EmitterShape::Collimated { origin, edge_u: eu, edge_v: ev, direction })
}

/// A collimated emitter's rectangle from center + size + direction `dir` (and `up`), as
/// (origin, edge_u, edge_v).
fn centred_rectangle(e: &EmitterIn, dir: Option<Vec3>) -> Result<(Vec3, Vec3, Vec3), SceneError> {
    let EmitterIn { cx, what, span, r, .. } = e;
    if let Some((k, s)) = r.present().into_iter().find(|(k, _)| ["origin", "edge_u", "edge_v"].contains(k)) {
        return Err(cx.err(
            s,
            format!("{what}.{k}"),
            "give center + size + direction, or origin + edge_u + edge_v, not both",
        ));
    }
    let c = finite(cx, what, "center", &r.center)?.ok_or_else(|| e.missing("center"))?;
    let size = r.size.as_ref().ok_or_else(|| e.missing("size"))?;
    let [w, h] = *size.get_ref();
    if !(w > 0.0 && h > 0.0 && w.is_finite() && h.is_finite()) {
        return Err(cx.err(size.span(), format!("{what}.size"), "needs two positive lengths in metres"));
    }
    let d = dir.ok_or_else(|| e.missing("direction"))?;
    let up = unit(cx, what, "up", &r.up)?.unwrap_or(if d.z.abs() > 0.9 { Vec3::Y } else { Vec3::Z });
    // edge_v along `up` (projected), edge_u to its right seen along the beam.
    let eu = d.cross(up).try_normalize().ok_or_else(|| {
        cx.err(
            r.up.as_ref().map_or(span.clone(), |s| s.span()),
            format!("{what}.up"),
            "must not be parallel to direction",
        )
    })?;
    let ev = eu.cross(d);
    let (eu, ev) = (eu * w, ev * h);
    Ok((c - 0.5 * eu - 0.5 * ev, eu, ev))
}

/// A collimated emitter's rectangle from origin + edge_u + edge_v, as (origin, edge_u, edge_v).
fn edge_rectangle(e: &EmitterIn) -> Result<(Vec3, Vec3, Vec3), SceneError> {
    let EmitterIn { cx, what, span, r, .. } = e;
    if r.up.is_some() {
        return Err(cx.err(
            r.up.as_ref().map_or(span.clone(), |s| s.span()),
            format!("{what}.up"),
            "applies only with center + size",
        ));
    }
    let o = finite(cx, what, "origin", &r.origin)?;
    let eu = finite(cx, what, "edge_u", &r.edge_u)?;
    let ev = finite(cx, what, "edge_v", &r.edge_v)?;
    match (o, eu, ev) {
        (Some(o), Some(u), Some(v)) => Ok((o, u, v)),
        _ => Err(cx.err(
            span.clone(),
            format!("{what}.center"),
            "a collimated emitter needs center + size + direction, or origin + edge_u + edge_v",
        )),
    }
}

fn shape(
    cx: &Ctx,
    i: usize,
    s: &Sp<RawShape>,
    materials: &BTreeMap<String, u32>,
    dir: &Path,
) -> Result<(String, u32, SurfaceGeometry), SceneError> {
    let what = format!("shapes[{i}]");
    let (span, r) = (s.span(), s.get_ref());
    let kind = req(cx, span.clone(), &what, "kind", &r.kind)?.clone();
    let name = r.name.as_ref().map_or_else(|| format!("{kind}{i}"), |n| n.get_ref().clone());
    let m = r.material.as_ref().ok_or_else(|| cx.err(span.clone(), format!("{what}.material"), "missing"))?;
    let material = *materials.get(m.get_ref()).ok_or_else(|| {
        let known: Vec<&str> = materials.keys().map(|k| k.as_str()).collect();
        cx.err(
            m.span(),
            format!("{what}.material"),
            format!("no material named \"{}\" (defined: {})", m.get_ref(), known.join(", ")),
        )
    })?;
    let t = match &r.transform {
        Some(t) => {
            let raw = t.get_ref();
            let scale = match raw.scale {
                Some(Scale::Uniform(s)) => Vec3::splat(s),
                Some(Scale::Axes(a)) => vec3(&a),
                None => Vec3::ONE,
            };
            let rot = raw.rotate_deg.map_or(Vec3::ZERO, |a| vec3(&a));
            let tr = raw.translate.map_or(Vec3::ZERO, |a| vec3(&a));
            let all = scale.to_array().into_iter().chain(rot.to_array()).chain(tr.to_array());
            if scale.cmpeq(Vec3::ZERO).any() || all.clone().any(|x| !x.is_finite()) {
                return Err(cx.err(
                    t.span(),
                    format!("{what}.transform"),
                    "needs finite values and non-zero scale",
                ));
            }
            Transform::new(scale, rot, tr)
        }
        None => Transform::default(),
    };
    let input = ShapeIn { cx, what: what.clone(), kind: kind.clone(), span: span.clone(), r, t, dir };
    let geometry = match kind.as_str() {
        "sphere" => sphere(&input)?,
        "plane" => plane(&input)?,
        "rectangle" => rectangle(&input)?,
        "disc" => disc(&input)?,
        "cylinder" => cylinder(&input)?,
        "obj" => obj(&input)?,
        "revolution" => revolution(&input)?,
        "height_field" => height_field(&input)?,
        "extrusion" => extrusion(&input)?,
        "paraboloid" => paraboloid(&input)?,
        _ => {
            let s = r.kind.as_ref().map_or(span, |s| s.span());
            return Err(cx.err(
                s,
                format!("{what}.kind"),
                format!(
                    "unknown shape kind \"{kind}\" (sphere, plane, rectangle, disc, cylinder, obj, revolution, \
                     height_field, extrusion, paraboloid)"
                ),
            ));
        }
    };
    Ok((name, material, geometry))
}

/// A shape's table as its kind reads it: where errors point (`shapes[i]`, the table's span),
/// its keys, its transform and the folder of the scene file (which `obj` paths are relative to).
struct ShapeIn<'a> {
    cx: &'a Ctx<'a>,
    what: String,
    kind: String,
    span: Range<usize>,
    r: &'a RawShape,
    t: Transform,
    dir: &'a Path,
}

impl ShapeIn<'_> {
    /// Refuses keys other than every shape's and `extra`.
    fn allow(&self, extra: &[&str]) -> Result<(), SceneError> {
        let common = ["kind", "name", "material", "transform"];
        only(self.cx, &self.what, &self.kind, self.r.present(), &[&common[..], extra].concat())
    }

    /// The error for a required key that is absent.
    fn missing(&self, key: &str) -> SceneError {
        self.cx.err(self.span.clone(), format!("{}.{key}", self.what), "missing")
    }

    /// The transform's scale, which must be uniform for a shape with a radius.
    fn uniform(&self) -> Result<f32, SceneError> {
        self.t.uniform_scale().ok_or_else(|| {
            self.cx.err(
                self.r.transform.as_ref().map_or(self.span.clone(), |s| s.span()),
                format!("{}.transform", self.what),
                format!("a {} needs a uniform scale", self.kind),
            )
        })
    }

    /// A required positive length.
    fn radius(&self, key: &str, v: &Option<Sp<f32>>) -> Result<f32, SceneError> {
        positive(self.cx, &self.what, key, v)?.ok_or_else(|| self.missing(key))
    }

    /// Whether `smooth = false` asks for flat facets.
    fn flat(&self) -> bool {
        self.r.smooth.as_ref().is_some_and(|s| !*s.get_ref())
    }
}

/// `kind = "sphere"`: a center (the origin by default) and a radius.
fn sphere(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, .. } = s;
    s.allow(&["center", "radius"])?;
    let c = finite(cx, what, "center", &r.center)?.unwrap_or(Vec3::ZERO);
    let rad = s.radius("radius", &r.radius)?;
    Ok(SurfaceGeometry::Analytic(Shape::Sphere { center: t.point(c), radius: rad * s.uniform()? }))
}

/// `kind = "plane"`: a point (the origin by default) and a normal.
fn plane(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, .. } = s;
    s.allow(&["point", "normal"])?;
    let p = finite(cx, what, "point", &r.point)?.unwrap_or(Vec3::ZERO);
    let n = unit(cx, what, "normal", &r.normal)?.ok_or_else(|| s.missing("normal"))?;
    Ok(SurfaceGeometry::Analytic(Shape::Plane { point: t.point(p), normal: t.normal(n) }))
}

/// `kind = "rectangle"`: a corner and two edges.
fn rectangle(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, span, r, t, .. } = s;
    s.allow(&["origin", "edge_u", "edge_v"])?;
    let o = finite(cx, what, "origin", &r.origin)?.ok_or_else(|| s.missing("origin"))?;
    let u = finite(cx, what, "edge_u", &r.edge_u)?.ok_or_else(|| s.missing("edge_u"))?;
    let v = finite(cx, what, "edge_v", &r.edge_v)?.ok_or_else(|| s.missing("edge_v"))?;
    let sh = Shape::rectangle(t.point(o), t.vector(u), t.vector(v)).ok_or_else(|| {
        cx.err(
            r.edge_v.as_ref().map_or(span.clone(), |s| s.span()),
            format!("{what}.edge_v"),
            "the edges are parallel or zero",
        )
    })?;
    Ok(SurfaceGeometry::Analytic(sh))
}

/// `kind = "disc"`: a center (the origin by default), a normal (+z by default) and a radius.
fn disc(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, .. } = s;
    s.allow(&["center", "normal", "radius"])?;
    let c = finite(cx, what, "center", &r.center)?.unwrap_or(Vec3::ZERO);
    let n = unit(cx, what, "normal", &r.normal)?.unwrap_or(Vec3::Z);
    let rad = s.radius("radius", &r.radius)?;
    Ok(SurfaceGeometry::Analytic(Shape::Disc {
        center: t.point(c),
        normal: t.normal(n),
        radius: rad * s.uniform()?,
    }))
}

/// `kind = "cylinder"`: the base's center (the origin by default), the axis (+z by default),
/// a radius and a height.
fn cylinder(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, .. } = s;
    s.allow(&["base", "axis", "radius", "height"])?;
    let b = finite(cx, what, "base", &r.base)?.unwrap_or(Vec3::ZERO);
    let a = unit(cx, what, "axis", &r.axis)?.unwrap_or(Vec3::Z);
    let rad = s.radius("radius", &r.radius)?;
    let h = s.radius("height", &r.height)?;
    let k = s.uniform()?;
    let axis = t.vector(a).normalize();
    Ok(SurfaceGeometry::Analytic(Shape::Cylinder { base: t.point(b), axis, radius: rad * k, height: h * k }))
}

/// `kind = "obj"`: a Wavefront OBJ mesh, its path relative to the scene file.
fn obj(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, dir, .. } = s;
    s.allow(&["file", "smooth"])?;
    let f = r.file.as_ref().ok_or_else(|| s.missing("file"))?;
    let path = dir.join(f.get_ref());
    let mut m = mesh::load_obj(&path).map_err(|e| {
        cx.err(f.span(), format!("{what}.file"), format!("cannot load {}: {e}", path.display()))
    })?;
    if s.flat() {
        m.normals = None;
    }
    Ok(mesh_geometry(m, t))
}

/// `kind = "revolution"`: a [r, z] profile swept around the z axis.
fn revolution(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, r, t, .. } = s;
    s.allow(&["profile", "segments", "crease_deg", "smooth"])?;
    let p = r.profile.as_ref().ok_or_else(|| s.missing("profile"))?;
    let pts: Vec<Vec2> = p.get_ref().iter().map(|a| Vec2::from_array(*a)).collect();
    if pts.len() < 2 || pts.iter().any(|q| !q.is_finite() || q.x < 0.0) {
        return Err(cx.err(
            p.span(),
            format!("{what}.profile"),
            "needs at least two [r, z] points with r ≥ 0",
        ));
    }
    let segs = count(cx, what, "segments", &r.segments, 64, 3)?;
    let crease = r.crease_deg.as_ref().map_or(30.0, |c| *c.get_ref());
    let mut m = mesh::revolution(&pts, segs, crease);
    if s.flat() {
        m.normals = None;
    }
    if m.indices.is_empty() {
        return Err(cx.err(p.span(), format!("{what}.profile"), "sweeps no area"));
    }
    Ok(mesh_geometry(m, t))
}

/// `kind = "height_field"`: a grid over a rectangle at a base height plus a sum of waves.
fn height_field(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, span, r, t, .. } = s;
    s.allow(&["size", "cells", "height", "waves", "smooth"])?;
    let size = r.size.as_ref().ok_or_else(|| s.missing("size"))?;
    let sz = Vec2::from_array(*size.get_ref());
    if !(sz.x > 0.0 && sz.y > 0.0 && sz.is_finite()) {
        return Err(cx.err(size.span(), format!("{what}.size"), "needs two positive lengths in metres"));
    }
    let cells = r.cells.as_ref().map_or([64, 64], |c| *c.get_ref());
    if cells.contains(&0) || cells[0] as u64 * cells[1] as u64 > 1 << 24 {
        let s = r.cells.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, format!("{what}.cells"), "needs 1 to 2^24 cells in all"));
    }
    let base = r.height.as_ref().map_or(0.0, |h| *h.get_ref());
    let waves = waves(s)?;
    let mut m = mesh::height_field(sz, cells, |x, y| {
        let p = Vec2::new(x, y);
        waves.iter().fold((base, Vec2::ZERO), |(z, g), &(a, k, ph)| {
            let arg = k.dot(p) + ph;
            (z + a * arg.sin(), g + k * (a * arg.cos()))
        })
    });
    if s.flat() {
        m.normals = None;
    }
    Ok(mesh_geometry(m, t))
}

/// A height field's waves as (amplitude, wave vector, phase in radians).
fn waves(s: &ShapeIn) -> Result<Vec<(f32, Vec2, f32)>, SceneError> {
    let ShapeIn { cx, what, r, .. } = s;
    let Some(w) = &r.waves else { return Ok(Vec::new()) };
    let mut v = Vec::new();
    for wave in w.get_ref() {
        if !(wave.wavelength > 0.0 && wave.amplitude.is_finite() && wave.wavelength.is_finite()) {
            return Err(cx.err(
                w.span(),
                format!("{what}.waves"),
                "each wave needs a finite amplitude and a positive wavelength",
            ));
        }
        let k = std::f32::consts::TAU / wave.wavelength;
        let (s, c) = wave.direction_deg.to_radians().sin_cos();
        v.push((wave.amplitude, Vec2::new(c, s) * k, wave.phase_deg.to_radians()));
    }
    Ok(v)
}

/// `kind = "extrusion"`: a simple polygon in the xy plane extruded between two heights.
fn extrusion(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, span, r, t, .. } = s;
    s.allow(&["outline", "z_range"])?;
    let o = r.outline.as_ref().ok_or_else(|| s.missing("outline"))?;
    let pts: Vec<Vec2> = o.get_ref().iter().map(|a| Vec2::from_array(*a)).collect();
    let z = r.z_range.as_ref().map_or([0.0, 1.0], |z| *z.get_ref());
    if z[0] == z[1] || !z[0].is_finite() || !z[1].is_finite() {
        let s = r.z_range.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, format!("{what}.z_range"), "needs two different finite heights"));
    }
    let m =
        pts.iter().all(|p| p.is_finite()).then(|| mesh::extrusion(&pts, z[0], z[1])).flatten().ok_or_else(
            || {
                cx.err(
                    o.span(),
                    format!("{what}.outline"),
                    "needs a simple polygon of at least 3 [x, y] points with non-zero area",
                )
            },
        )?;
    Ok(mesh_geometry(m, t))
}

/// `kind = "paraboloid"`: a mirror of a focal length, between an inner and an outer radius.
fn paraboloid(s: &ShapeIn) -> Result<SurfaceGeometry, SceneError> {
    let ShapeIn { cx, what, span, r, t, .. } = s;
    s.allow(&["focal_length", "radius", "inner_radius", "rings", "segments"])?;
    let f = s.radius("focal_length", &r.focal_length)?;
    let rmax = s.radius("radius", &r.radius)?;
    let rmin = r.inner_radius.as_ref().map_or(0.0, |x| *x.get_ref());
    if !(0.0..rmax).contains(&rmin) {
        let s = r.inner_radius.as_ref().map_or(span.clone(), |s| s.span());
        return Err(cx.err(s, format!("{what}.inner_radius"), "must lie in [0, radius)"));
    }
    let rings = count(cx, what, "rings", &r.rings, 8, 1)?;
    let segs = count(cx, what, "segments", &r.segments, 32, 3)?;
    Ok(mesh_geometry(mesh::paraboloid(f, rmin, rmax, rings, segs), t))
}

fn count(
    cx: &Ctx,
    what: &str,
    key: &str,
    v: &Option<Sp<u32>>,
    default: u32,
    min: u32,
) -> Result<u32, SceneError> {
    match v {
        Some(s) if !(min..=1 << 16).contains(s.get_ref()) => {
            Err(cx.err(s.span(), format!("{what}.{key}"), format!("must lie in [{min}, 65536]")))
        }
        Some(s) => Ok(*s.get_ref()),
        None => Ok(default),
    }
}

fn mesh_geometry(m: Mesh, t: &Transform) -> SurfaceGeometry {
    SurfaceGeometry::Mesh(m.transformed(t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_and_column_are_one_based() {
        assert_eq!(line_column("ab\ncd\n", 4), (2, 2));
        assert_eq!(line_column("ab", 0), (1, 1));
    }

    #[test]
    fn field_is_found_from_the_line() {
        let src = "[[shapes]]\nradius = \"a\"\ntransform = { scale = -1 }\n";
        assert_eq!(field_at(src, 20..23).as_deref(), Some("radius"));
        assert_eq!(field_at(src, 11..17).as_deref(), Some("radius"));
        let at = src.find("-1").unwrap();
        assert_eq!(field_at(src, at..at + 2).as_deref(), Some("scale"));
        assert_eq!(field_at(src, 0..10).as_deref(), Some("shapes"));
    }
}
