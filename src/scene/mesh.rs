//! Triangle meshes: loaded from OBJ files or built procedurally for the sample scenes
//! (surface of revolution, height field, extruded polygon, faceted paraboloid).
//!
//! Meshes wind their triangles counter-clockwise seen from outside, so the geometric normal
//! (b − a) × (c − a) points out of a closed solid (into the air, for a dielectric).

use glam::{Mat3, Vec2, Vec3};

/// A triangle mesh with optional per-vertex shading normals.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions, metres.
    pub positions: Vec<Vec3>,
    /// One unit normal per position, for smooth shading; `None` for flat facets.
    pub normals: Option<Vec<Vec3>>,
    /// Vertex indices of each triangle, counter-clockwise seen from outside.
    pub indices: Vec<[u32; 3]>,
}

/// An affine placement: scale, then rotate about x, y, z (in that order), then translate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Scale, then rotation.
    pub linear: Mat3,
    /// Translation, metres.
    pub translate: Vec3,
}

impl Default for Transform {
    fn default() -> Self {
        Transform { linear: Mat3::IDENTITY, translate: Vec3::ZERO }
    }
}

impl Transform {
    /// Scales by `scale`, rotates by `rotate_deg` about x, then y, then z (degrees), then translates.
    pub fn new(scale: Vec3, rotate_deg: Vec3, translate: Vec3) -> Self {
        let r = Mat3::from_rotation_z(rotate_deg.z.to_radians())
            * Mat3::from_rotation_y(rotate_deg.y.to_radians())
            * Mat3::from_rotation_x(rotate_deg.x.to_radians());
        Transform { linear: r * Mat3::from_diagonal(scale), translate }
    }

    /// Where the point `p` goes.
    pub fn point(&self, p: Vec3) -> Vec3 {
        self.linear * p + self.translate
    }

    /// Where the vector `v` goes (no translation).
    pub fn vector(&self, v: Vec3) -> Vec3 {
        self.linear * v
    }

    /// A unit normal carried by the inverse transpose, flipped if the transform mirrors.
    pub fn normal(&self, n: Vec3) -> Vec3 {
        (self.linear.inverse().transpose() * n).normalize()
    }

    /// The factor lengths are multiplied by, if the transform scales uniformly.
    pub fn uniform_scale(&self) -> Option<f32> {
        let c = [self.linear.x_axis.length(), self.linear.y_axis.length(), self.linear.z_axis.length()];
        let tol = 1e-5 * c[0].max(1e-30);
        ((c[0] - c[1]).abs() <= tol && (c[0] - c[2]).abs() <= tol).then_some(c[0])
    }
}

impl Mesh {
    /// The mesh moved by `t`; a mirroring transform reverses the winding to keep normals outward.
    pub fn transformed(mut self, t: &Transform) -> Mesh {
        for p in &mut self.positions {
            *p = t.point(*p);
        }
        if let Some(ns) = &mut self.normals {
            for n in ns.iter_mut() {
                *n = t.normal(*n);
            }
        }
        if t.linear.determinant() < 0.0 {
            for tri in &mut self.indices {
                tri.swap(1, 2);
            }
        }
        self
    }

    /// The vertices of triangle `i`.
    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        self.indices[i].map(|k| self.positions[k as usize])
    }

    /// The mesh without its triangles of zero area (the poles of a surface of revolution, for
    /// instance).
    pub(crate) fn without_degenerate(mut self) -> Mesh {
        let pos = &self.positions;
        self.indices.retain(|t| {
            let [a, b, c] = t.map(|k| pos[k as usize]);
            (b - a).cross(c - a).length_squared() > 0.0
        });
        self
    }
}

/// Surface of revolution about the z axis of a profile of (r, z) points, `segments` around.
/// Walk the profile with the solid on the left (the outside of a glass bottom to rim, then
/// the inside rim to bottom): the outward normal is on the right. `crease_deg`: profile
/// corners sharper than this keep separate normals; others are smoothed.
pub fn revolution(profile: &[Vec2], segments: u32, crease_deg: f32) -> Mesh {
    let segments = segments.max(3);
    let np = profile.len();
    // Outward normal of each profile segment in the (r, z) plane: (dz, −dr).
    let seg_n: Vec<Vec2> =
        profile.windows(2).map(|w| Vec2::new(w[1].y - w[0].y, w[0].x - w[1].x).normalize_or_zero()).collect();
    let cos_crease = crease_deg.to_radians().cos();
    let mut mesh = Mesh::default();
    let mut normals = Vec::new();
    let ring = |mesh: &mut Mesh, normals: &mut Vec<Vec3>, p: Vec2, n: Vec2| -> u32 {
        let start = mesh.positions.len() as u32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let (sin, cos) = phi.sin_cos();
            mesh.positions.push(Vec3::new(p.x * cos, p.x * sin, p.y));
            normals.push(Vec3::new(n.x * cos, n.x * sin, n.y).normalize_or_zero());
        }
        start
    };
    for (k, w) in profile.windows(2).enumerate() {
        let own = seg_n[k];
        let end_normal = |j: Option<usize>| match j.and_then(|j| seg_n.get(j)) {
            Some(&o) if o.dot(own) >= cos_crease => (o + own).normalize_or(own),
            _ => own,
        };
        let n0 = end_normal(k.checked_sub(1));
        let n1 = end_normal(Some(k + 1).filter(|&j| j < np - 1));
        let a = ring(&mut mesh, &mut normals, w[0], n0);
        let b = ring(&mut mesh, &mut normals, w[1], n1);
        for s in 0..segments {
            let s1 = (s + 1) % segments;
            mesh.indices.push([a + s, a + s1, b + s1]);
            mesh.indices.push([a + s, b + s1, b + s]);
        }
    }
    mesh.normals = Some(normals);
    mesh.without_degenerate()
}

/// A height field over [−sx/2, sx/2] × [−sy/2, sy/2] with `nx × ny` cells, heights z = h(x, y)
/// and shading normals from the gradient; the outward normal points up (+z).
pub fn height_field(size: Vec2, cells: [u32; 2], h: impl Fn(f32, f32) -> (f32, Vec2)) -> Mesh {
    let [nx, ny] = cells.map(|c| c.max(1));
    let mut mesh = Mesh::default();
    let mut normals = Vec::new();
    for j in 0..=ny {
        for i in 0..=nx {
            let x = size.x * (i as f32 / nx as f32 - 0.5);
            let y = size.y * (j as f32 / ny as f32 - 0.5);
            let (z, grad) = h(x, y);
            mesh.positions.push(Vec3::new(x, y, z));
            normals.push(Vec3::new(-grad.x, -grad.y, 1.0).normalize());
        }
    }
    let at = |i: u32, j: u32| j * (nx + 1) + i;
    for j in 0..ny {
        for i in 0..nx {
            mesh.indices.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            mesh.indices.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    mesh.normals = Some(normals);
    mesh
}

/// A closed prism: the simple polygon `outline` (x, y) extruded along z from `z0` to `z1`,
/// flat faces. The outline may wind either way.
pub fn extrusion(outline: &[Vec2], z0: f32, z1: f32) -> Option<Mesh> {
    let mut pts = outline.to_vec();
    let area2: f32 = pts.iter().zip(pts.iter().cycle().skip(1)).map(|(a, b)| a.perp_dot(*b)).sum();
    if area2 == 0.0 || pts.len() < 3 {
        return None;
    }
    if area2 < 0.0 {
        pts.reverse();
    }
    let (z0, z1) = if z0 <= z1 { (z0, z1) } else { (z1, z0) };
    let n = pts.len() as u32;
    let mut mesh = Mesh::default();
    mesh.positions.extend(pts.iter().map(|p| p.extend(z0)));
    mesh.positions.extend(pts.iter().map(|p| p.extend(z1)));
    for i in 0..n {
        let j = (i + 1) % n;
        mesh.indices.push([i, j, n + j]);
        mesh.indices.push([i, n + j, n + i]);
    }
    for [a, b, c] in ear_clip(&pts)? {
        mesh.indices.push([n + a, n + b, n + c]); // top, counter-clockwise seen from +z
        mesh.indices.push([a, c, b]); // bottom, reversed
    }
    Some(mesh)
}

/// Triangulates a counter-clockwise simple polygon by ear clipping.
fn ear_clip(pts: &[Vec2]) -> Option<Vec<[u32; 3]>> {
    let mut idx: Vec<u32> = (0..pts.len() as u32).collect();
    let mut out = Vec::new();
    let p = |i: u32| pts[i as usize];
    while idx.len() > 3 {
        let m = idx.len();
        let ear = (0..m).find(|&k| {
            let (a, b, c) = (idx[(k + m - 1) % m], idx[k], idx[(k + 1) % m]);
            if (p(b) - p(a)).perp_dot(p(c) - p(b)) <= 0.0 {
                return false; // reflex or straight corner
            }
            idx.iter().all(|&q| {
                if q == a || q == b || q == c {
                    return true;
                }
                let x = p(q);
                let s1 = (p(b) - p(a)).perp_dot(x - p(a));
                let s2 = (p(c) - p(b)).perp_dot(x - p(b));
                let s3 = (p(a) - p(c)).perp_dot(x - p(c));
                !(s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0)
            })
        })?;
        out.push([idx[(ear + m - 1) % m], idx[ear], idx[(ear + 1) % m]]);
        idx.remove(ear);
    }
    out.push([idx[0], idx[1], idx[2]]);
    Some(out)
}

/// A faceted paraboloid z = r²/(4f) from radius `r_min` to `r_max`, opening towards +z with
/// its focus at (0, 0, f): `rings × segments` flat facets, vertices on the exact surface.
pub fn paraboloid(focal: f32, r_min: f32, r_max: f32, rings: u32, segments: u32) -> Mesh {
    let rings = rings.max(1);
    let profile: Vec<Vec2> = (0..=rings)
        .map(|k| {
            let r = r_min + (r_max - r_min) * k as f32 / rings as f32;
            Vec2::new(r, r * r / (4.0 * focal))
        })
        .collect();
    // Walking outwards the solid-left rule puts the normal below: flip to face the focus.
    let mut m = revolution(&profile, segments, 0.0);
    m.normals = None;
    for t in &mut m.indices {
        t.swap(1, 2);
    }
    m
}

/// Largest vertex coordinate accepted from an OBJ file, in the file's units.
pub const MAX_OBJ_COORDINATE: f32 = 1e30;

/// What tobj lets through and a scene cannot use, refused by line: a vertex coordinate that
/// is not a finite number of at most [`MAX_OBJ_COORDINATE`] in size, a face of fewer than three
/// vertices.
fn check_obj_text(bytes: &[u8]) -> Result<(), String> {
    let text = String::from_utf8_lossy(bytes);
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                for w in words.take(3) {
                    match w.parse::<f32>() {
                        Ok(x) if x.is_finite() && x.abs() <= MAX_OBJ_COORDINATE => {}
                        _ => {
                            return Err(format!(
                                "line {}: vertex coordinate '{w}' is not a finite number of at most {MAX_OBJ_COORDINATE:e}",
                                i + 1
                            ));
                        }
                    }
                }
            }
            Some("f") if words.count() < 3 => {
                return Err(format!("line {}: a face needs at least three vertices", i + 1));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Loads every object of an OBJ file as one mesh (triangulated), with its normals if it has
/// them for every vertex.
pub fn load_obj(path: &std::path::Path) -> Result<Mesh, String> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    crate::format::guard::register_input(path);
    check_obj_text(&std::fs::read(path).map_err(|e| e.to_string())?)?;
    let (models, _materials) = tobj::load_obj(path, &opts).map_err(|e| e.to_string())?;
    let mut mesh = Mesh { normals: Some(Vec::new()), ..Default::default() };
    for m in &models {
        let m = &m.mesh;
        let base = mesh.positions.len() as u32;
        let nv = m.positions.len() / 3;
        mesh.positions.extend(m.positions.chunks_exact(3).map(|c| Vec3::new(c[0], c[1], c[2])));
        match (&mut mesh.normals, m.normals.len() == m.positions.len()) {
            (Some(ns), true) => {
                ns.extend(m.normals.chunks_exact(3).map(|c| Vec3::new(c[0], c[1], c[2]).normalize_or_zero()))
            }
            _ => mesh.normals = None,
        }
        for t in m.indices.chunks_exact(3) {
            if t.iter().any(|&k| k as usize >= nv) {
                return Err(format!("a face refers to vertex {} of {nv}", t.iter().max().unwrap_or(&0)));
            }
            mesh.indices.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    if mesh.indices.is_empty() {
        return Err("no faces".into());
    }
    if mesh.normals.as_ref().is_some_and(|ns| ns.contains(&Vec3::ZERO)) {
        mesh.normals = None;
    }
    Ok(mesh.without_degenerate())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed volume by the divergence theorem: positive when every normal points outward.
    fn volume(m: &Mesh) -> f32 {
        (0..m.indices.len())
            .map(|i| {
                let [a, b, c] = m.triangle(i);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn closed_revolution_encloses_the_closed_form_volume_with_outward_normals() {
        // A cylinder of radius 1, height 2, closed at both ends: volume 2π.
        let profile = [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 2.0), Vec2::new(0.0, 2.0)];
        let m = revolution(&profile, 256, 30.0);
        let v = volume(&m);
        let polygon = 0.5 * 256.0 * (std::f32::consts::TAU / 256.0).sin() * 2.0;
        assert!((v - polygon).abs() < 1e-3, "{v} vs {polygon}");
        // Side normals are radial, cap normals axial (the corners are creased, not smoothed).
        let ns = m.normals.as_ref().unwrap();
        for (p, n) in m.positions.iter().zip(ns) {
            assert!((n.length() - 1.0).abs() < 1e-5);
            if p.z > 0.0 && p.z < 2.0 {
                assert!((n.z).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn extruded_triangle_has_closed_form_volume_either_winding() {
        let tri = [Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0), Vec2::new(0.0, 1.0)];
        let m = extrusion(&tri, 0.0, 3.0).unwrap();
        assert!((volume(&m) - 3.0).abs() < 1e-5);
        let rev: Vec<Vec2> = tri.iter().rev().copied().collect();
        assert!((volume(&extrusion(&rev, 3.0, 0.0).unwrap()) - 3.0).abs() < 1e-5);
        // A concave L-shaped outline: area 3, volume 3.
        let l = [
            Vec2::new(0.0, 0.0),
            Vec2::new(2.0, 0.0),
            Vec2::new(2.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 2.0),
            Vec2::new(0.0, 2.0),
        ];
        assert!((volume(&extrusion(&l, 0.0, 1.0).unwrap()) - 3.0).abs() < 1e-5);
        assert!(extrusion(&[Vec2::ZERO, Vec2::X, Vec2::X * 2.0], 0.0, 1.0).is_none());
    }

    #[test]
    fn paraboloid_vertices_lie_on_the_surface_and_face_the_focus() {
        let m = paraboloid(0.25, 0.0, 0.5, 8, 32);
        for p in &m.positions {
            let r2 = p.x * p.x + p.y * p.y;
            assert!((p.z - r2 / 1.0).abs() < 1e-5);
        }
        let focus = Vec3::new(0.0, 0.0, 0.25);
        for i in 0..m.indices.len() {
            let [a, b, c] = m.triangle(i);
            assert!((b - a).cross(c - a).dot(focus - a) > 0.0);
        }
    }

    #[test]
    fn height_field_normals_follow_the_gradient() {
        let m = height_field(Vec2::new(2.0, 2.0), [4, 4], |x, _| (0.5 * x, Vec2::new(0.5, 0.0)));
        let n = m.normals.as_ref().unwrap()[0];
        assert!((n - Vec3::new(-0.5, 0.0, 1.0).normalize()).length() < 1e-6);
        for i in 0..m.indices.len() {
            let [a, b, c] = m.triangle(i);
            assert!((b - a).cross(c - a).z > 0.0);
        }
        assert_eq!(m.indices.len(), 32);
    }

    #[test]
    fn transforms_scale_rotate_translate_and_keep_mirrored_meshes_outward() {
        let t = Transform::new(Vec3::splat(2.0), Vec3::new(0.0, 0.0, 90.0), Vec3::new(1.0, 0.0, 0.0));
        assert!((t.point(Vec3::X) - Vec3::new(1.0, 2.0, 0.0)).length() < 1e-6);
        assert_eq!(t.uniform_scale().map(|s| (s * 1e5).round()), Some(2e5));
        let tri = [Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)];
        let m = extrusion(&tri, 0.0, 1.0).unwrap();
        let mirror = Transform::new(Vec3::new(-1.0, 1.0, 1.0), Vec3::ZERO, Vec3::ZERO);
        assert_eq!(mirror.uniform_scale(), Some(1.0));
        assert!(Transform::new(Vec3::new(1.0, 2.0, 1.0), Vec3::ZERO, Vec3::ZERO).uniform_scale().is_none());
        assert!((volume(&m.transformed(&mirror)) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn obj_files_load_triangulated() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("quad.obj");
        std::fs::write(&p, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        let m = load_obj(&p).unwrap();
        assert_eq!(m.indices.len(), 2);
        assert!(m.normals.is_none());
        std::fs::write(&p, "v 0 0 0\n").unwrap();
        assert!(load_obj(&p).is_err());
    }
}
