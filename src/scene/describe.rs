//! What a scene holds, in words: `photonkit trace --dry-run` prints it, so a user can check
//! what was understood of a scene file (TOML or glTF) before tracing it.

use std::fmt::Write;

use glam::Vec3;

use super::emitter::EmitterShape;
use super::material::{Dispersion, Material};
use super::{Background, Projection, Scene, Shape, SurfaceGeometry};

fn v(x: Vec3) -> String {
    format!("({:.4}, {:.4}, {:.4})", x.x, x.y, x.z)
}

/// One material in words: its kind and what it does to light.
pub fn material(m: &Material) -> String {
    match m {
        Material::Diffuse { albedo } => format!("diffuse, albedo {}", v(*albedo)),
        Material::Mirror { reflectance } => format!("mirror, reflectance {}", v(*reflectance)),
        Material::Absorber => "absorber".into(),
        Material::Dielectric(d) => {
            let mut s = format!("dielectric, ior {}", d.ior);
            if d.tint != Vec3::ONE {
                let _ = write!(s, ", tint {} per refraction", v(d.tint));
            }
            match &d.dispersion {
                Some(Dispersion::Cauchy { a, b, c }) => {
                    let _ = write!(s, ", Cauchy dispersion A {a:.6} B {b:.6} µm² C {c:.6} µm⁴");
                }
                Some(Dispersion::Sellmeier { b, c }) => {
                    let _ = write!(s, ", Sellmeier dispersion B {b:?} C {c:?} µm²");
                }
                None => {}
            }
            if d.ideal {
                s.push_str(", ideal (no Fresnel reflection)");
            }
            s
        }
    }
}

/// The scene in words: its objects, materials, emitters (with the number of trajectory
/// parameters each gives its photons), camera and background, one line each.
pub fn describe(scene: &Scene) -> String {
    let mut s = String::new();
    let d = scene.description();
    if let Some(n) = &d.name {
        let _ = writeln!(s, "scene: {n}");
    }
    let _ = writeln!(s, "objects: {} ({} mesh triangles)", d.surfaces.len(), scene.triangle_count());
    for (i, surf) in d.surfaces.iter().enumerate() {
        let geometry = match &surf.geometry {
            SurfaceGeometry::Mesh(m) => format!(
                "mesh of {} triangles, {} vertices, {}",
                m.indices.len(),
                m.positions.len(),
                if m.normals.is_some() { "smooth" } else { "flat" }
            ),
            SurfaceGeometry::Analytic(sh) => match sh {
                Shape::Sphere { center, radius } => format!("sphere at {} radius {radius} m", v(*center)),
                Shape::Plane { point, normal } => {
                    format!("plane through {} normal {}", v(*point), v(*normal))
                }
                Shape::Rectangle { origin, edge_u, edge_v, .. } => {
                    format!("rectangle at {} edges {} {}", v(*origin), v(*edge_u), v(*edge_v))
                }
                Shape::Disc { center, radius, .. } => format!("disc at {} radius {radius} m", v(*center)),
                Shape::Cylinder { base, radius, height, .. } => {
                    format!("cylinder from {} radius {radius} m height {height} m", v(*base))
                }
            },
        };
        let m = &d.material_names[surf.material as usize];
        let _ = writeln!(s, "  [{i}] {}: {geometry}; material {m}", surf.name);
    }
    let _ = writeln!(s, "materials: {}", d.materials.len());
    for (name, m) in d.material_names.iter().zip(&d.materials) {
        let _ = writeln!(s, "  {name}: {}", material(m));
    }
    let spectral = scene.is_spectral();
    let _ = writeln!(
        s,
        "emitters: {} ({} trajectory parameters at most{})",
        d.emitters.len(),
        scene.param_dims(),
        if spectral { ", the wavelength among them: the scene disperses light" } else { "" }
    );
    for (i, (name, e)) in d.emitter_names.iter().zip(&d.emitters).enumerate() {
        let (kind, params) = match e.kind {
            EmitterShape::Collimated { origin, edge_u, edge_v, direction } => (
                format!(
                    "collimated along {} from the {:.4} × {:.4} m rectangle at {} (edges {} {})",
                    v(direction),
                    edge_u.length(),
                    edge_v.length(),
                    v(origin),
                    v(edge_u),
                    v(edge_v)
                ),
                "(u, v) on the rectangle",
            ),
            EmitterShape::Point { position } => {
                (format!("point at {}", v(position)), "the unit emission direction")
            }
            EmitterShape::Spot { position, axis, half_angle_rad } => (
                format!(
                    "spot at {} along {}, half angle {:.2}°",
                    v(position),
                    v(axis),
                    half_angle_rad.to_degrees()
                ),
                "the unit emission direction",
            ),
        };
        let _ = writeln!(
            s,
            "  [{i}] {name}: {kind}; {:.6} W, colour {}; {} parameters: {params}{}",
            e.power_w,
            v(e.colour),
            e.param_dims(spectral),
            if spectral { " and the wavelength" } else { "" }
        );
    }
    match &d.camera {
        Some(c) => {
            let p = match c.projection {
                Projection::Pinhole { fov_y_rad } => {
                    format!("pinhole, vertical field of view {:.2}°", fov_y_rad.to_degrees())
                }
                Projection::Orthographic { height_m } => format!("orthographic, {height_m} m high"),
            };
            let _ = writeln!(
                s,
                "camera: {p}, at {} looking along {} (up {}), {} × {} pixels",
                v(c.eye),
                v(c.forward),
                v(c.up),
                c.resolution[0],
                c.resolution[1]
            );
        }
        None => s.push_str("camera: none (render needs --camera options or --plane)\n"),
    }
    match &d.background {
        Some(Background::Uniform(c)) => {
            let _ = writeln!(s, "background: uniform {} W/(m²·sr)", v(*c));
        }
        Some(Background::Sky { zenith, horizon, ground }) => {
            let _ = writeln!(
                s,
                "background: sky, zenith {}, horizon {}, ground {} W/(m²·sr)",
                v(*zenith),
                v(*horizon),
                v(*ground)
            );
        }
        Some(Background::Image { path, strength, .. }) => {
            let _ = writeln!(s, "background: {} times {strength}", path.display());
        }
        None => s.push_str("background: black\n"),
    }
    s
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_default_scene_is_described_object_by_object() {
        let s = super::describe(&crate::scene::Scene::default_scene());
        assert!(
            s.contains("[1] ball: sphere at (0.0000, 0.0000, 0.8000) radius 0.5 m; material glass"),
            "{s}"
        );
        assert!(s.contains("glass: dielectric, ior 1.5"), "{s}");
        assert!(
            s.contains("[0] sun: collimated") && s.contains("10.000000 W") && s.contains("2 parameters"),
            "{s}"
        );
        assert!(s.contains("camera: pinhole"), "{s}");
    }
}
