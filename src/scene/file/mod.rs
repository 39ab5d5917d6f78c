//! The scene file: TOML read with serde into `Raw*` structs that mirror the file (every value
//! with its byte span), then checked and turned into a [`Scene`]. Every error names the line
//! and the field. docs/scene.md is the reference for users.
//!
//! Emitters and shapes are read one function per kind ([`emitters`], [`shapes`]), each
//! refusing the keys that do not apply to its kind.

mod emitters;
pub(super) use emitters::MAX_POWER_W;
mod shapes;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use glam::Vec3;
use serde::Deserialize;
use toml::Spanned;

use super::camera::{Camera, Projection};
use super::material::{Dielectric, Dispersion, Material};
use super::{Background, Scene, SceneDescription, SceneError, Surface};
use emitters::emitter;
use shapes::shape;

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
    #[serde(default)]
    zenith: Option<Sp<[f32; 3]>>,
    #[serde(default)]
    horizon: Option<Sp<[f32; 3]>>,
    #[serde(default)]
    ground: Option<Sp<[f32; 3]>>,
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

    let mut surfaces = Vec::new();
    for (i, s) in raw.shapes.iter().enumerate() {
        let (name, material, geometry) = shape(&cx, i, s, &material_index, dir)?;
        surfaces.push(Surface { name, material, geometry });
    }
    if surfaces.is_empty() {
        return Err(cx.err(0..0, "shapes", "the scene has no shape: add a [[shapes]] table"));
    }
    let desc = SceneDescription {
        name: raw.name.clone(),
        camera,
        background,
        materials,
        material_names,
        emitters,
        emitter_names,
        surfaces,
    };
    Ok(if scale == 1.0 { desc } else { desc.scaled(scale) }.build())
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
    let rgb = |c: &Sp<[f32; 3]>, key: &str| {
        let v = *c.get_ref();
        match v.iter().all(|x| x.is_finite() && *x >= 0.0) {
            true => Ok(Vec3::from_array(v) * strength),
            false => Err(cx.err(c.span(), key, "needs three finite values ≥ 0")),
        }
    };
    let sky = [&r.zenith, &r.horizon, &r.ground];
    if sky.iter().any(|k| k.is_some()) {
        if r.colour.is_some() || r.image.is_some() || r.rotate_deg.is_some() {
            return Err(cx.err(
                span,
                "background",
                "a sky (zenith, horizon, ground) takes no colour, image or rotate_deg",
            ));
        }
        let (Some(zenith), Some(horizon)) = (&r.zenith, &r.horizon) else {
            return Err(cx.err(span, "background", "a sky needs both zenith and horizon"));
        };
        let (zenith, horizon) = (rgb(zenith, "background.zenith")?, rgb(horizon, "background.horizon")?);
        let ground = match &r.ground {
            Some(g) => rgb(g, "background.ground")?,
            None => horizon,
        };
        return Ok(Background::Sky { zenith, horizon, ground });
    }
    match (&r.colour, &r.image) {
        (Some(c), None) => {
            if r.rotate_deg.is_some() {
                return Err(cx.err(span, "background.rotate_deg", "applies to an image only"));
            }
            Ok(Background::Uniform(rgb(c, "background.colour")?))
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
        _ => Err(cx.err(
            span,
            "background",
            "give one of colour = [r, g, b], image = \"file.exr\", or a sky (zenith = [r, g, b], horizon = [r, g, b])",
        )),
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
