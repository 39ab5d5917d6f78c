//! The `[[shapes]]` tables: the checks every shape gets (name, material, transform), then
//! one function per kind.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use glam::{Vec2, Vec3};

use super::{Ctx, RawShape, Scale, Sp, finite, only, positive, req, unit, vec3};
use crate::scene::mesh::{self, Mesh, Transform};
use crate::scene::shape::Shape;
use crate::scene::{SceneError, SurfaceGeometry};

pub(super) fn shape(
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
