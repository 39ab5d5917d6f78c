//! glTF materials as the tracer's: transmissive → dielectric, polished metal → mirror,
//! everything else → diffuse with its base colour (docs/scene.md, "glTF scenes").

use glam::Vec3;

use super::Cx;
use crate::scene::SceneError;
use crate::scene::material::{Dielectric, Dispersion, Material};

/// The roughness up to which a metal (metallic 1) is a mirror and a transmissive material is
/// smooth glass; rougher ones are read with a warning (docs/scene.md).
pub const SMOOTH_ROUGHNESS: f32 = 0.05;

/// The material of glTF material `m`; what it cannot honour is added to `unsupported`.
pub(super) fn material(
    cx: &Cx,
    m: &gltf::Material,
    unsupported: &mut Vec<String>,
) -> Result<Material, SceneError> {
    let what = super::label("materials", m.index().unwrap_or(0), m.name());
    let pbr = m.pbr_metallic_roughness();
    let base = Vec3::from_slice(&pbr.base_color_factor()[..3]);
    let (metallic, roughness) = (pbr.metallic_factor(), pbr.roughness_factor());
    if !(base.is_finite() && metallic.is_finite() && roughness.is_finite()) {
        return Err(cx.err(&what, "baseColorFactor, metallicFactor and roughnessFactor must be finite"));
    }
    let mut skip = |s: &str| unsupported.push(format!("{what}: {s}"));
    let textures = [
        ("baseColorTexture", pbr.base_color_texture().is_some()),
        ("metallicRoughnessTexture", pbr.metallic_roughness_texture().is_some()),
        ("normalTexture", m.normal_texture().is_some()),
        ("occlusionTexture", m.occlusion_texture().is_some()),
        ("emissiveTexture", m.emissive_texture().is_some()),
        ("transmissionTexture", m.transmission().is_some_and(|t| t.transmission_texture().is_some())),
        ("thicknessTexture", m.volume().is_some_and(|v| v.thickness_texture().is_some())),
    ];
    for (t, _) in textures.iter().filter(|(_, there)| *there) {
        skip(&format!("{t} (textures are not read: the factors are used)"));
    }
    if m.emissive_factor().iter().any(|&e| e > 0.0) {
        skip("emissiveFactor (emissive meshes are not lights: add a KHR_lights_punctual light)");
    }
    if m.alpha_mode() != gltf::material::AlphaMode::Opaque {
        skip(&format!("alphaMode {:?} (every surface is opaque)", m.alpha_mode()));
    }
    for k in m.extensions().into_iter().flat_map(|e| e.keys()) {
        if k != "KHR_materials_dispersion" {
            skip(&format!("{k} (an extension that is not read)"));
        }
    }
    if let Some(t) = m.transmission().filter(|t| t.transmission_factor() > 0.0) {
        if t.transmission_factor() < 1.0 {
            skip(&format!(
                "transmissionFactor {} (traced as 1: every photon that is not reflected refracts)",
                t.transmission_factor()
            ));
        }
        if roughness > SMOOTH_ROUGHNESS {
            skip(&format!("rough transmission (roughness {roughness}): traced as smooth glass"));
        }
        return dielectric(cx, &what, m).map(Material::Dielectric);
    }
    let albedo = base.clamp(Vec3::ZERO, Vec3::ONE);
    if metallic >= 1.0 {
        if roughness <= SMOOTH_ROUGHNESS {
            return Ok(Material::Mirror { reflectance: albedo });
        }
        skip(&format!("rough metal (roughness {roughness}): diffuse with its base colour"));
    }
    Ok(Material::Diffuse { albedo })
}

/// A transmissive material: `KHR_materials_ior` (1.5 by default), `KHR_materials_volume`'s
/// attenuation as a tint, `KHR_materials_dispersion` as a Cauchy law.
fn dielectric(cx: &Cx, what: &str, m: &gltf::Material) -> Result<Dielectric, SceneError> {
    let ior = m.ior().unwrap_or(1.5);
    if !(ior.is_finite() && ior >= 1.0) {
        return Err(cx.err(what, format!("KHR_materials_ior: ior {ior} must be at least 1")));
    }
    let tint = m.volume().map_or(Ok(Vec3::ONE), |v| {
        volume_tint(v.attenuation_color(), v.attenuation_distance(), v.thickness_factor()).ok_or_else(|| {
            cx.err(
                what,
                "KHR_materials_volume: needs a colour in [0, 1], a positive distance and a thickness ≥ 0",
            )
        })
    })?;
    let dispersion = match m.extension_value("KHR_materials_dispersion") {
        None => None,
        Some(v) => {
            let d = v.get("dispersion").map_or(Some(0.0), |x| x.as_f64());
            match d {
                Some(d) if d.is_finite() && d >= 0.0 => cauchy_of(ior as f64, d),
                _ => return Err(cx.err(what, "KHR_materials_dispersion: dispersion must be a number ≥ 0")),
            }
        }
    };
    Ok(Dielectric { ior, dispersion, ideal: false, tint })
}

/// `KHR_materials_volume` as a tint per refraction: light through `thickness` of the
/// material keeps `colour^(thickness / distance)`, and a photon refracts twice on such a
/// crossing, so each refraction keeps the square root of that. `None` for values out of range.
pub fn volume_tint(colour: [f32; 3], distance: f32, thickness: f32) -> Option<Vec3> {
    let ok = colour.iter().all(|c| (0.0..=1.0).contains(c))
        && distance > 0.0
        && thickness >= 0.0
        && thickness.is_finite();
    if !ok {
        return None;
    }
    if thickness == 0.0 || distance.is_infinite() {
        return Some(Vec3::ONE);
    }
    let e = thickness as f64 / (2.0 * distance as f64);
    Some(Vec3::from_array(colour.map(|c| (c as f64).powf(e) as f32)))
}

/// `KHR_materials_dispersion`'s law as a Cauchy law: its n(λ) = n_d + (n_d − 1)/V ·
/// (523655 nm²/λ² − 1.5168) with Abbe number V = 20/dispersion is A + B/λ² with λ in µm.
/// `None` for dispersion 0 (none).
pub fn cauchy_of(ior: f64, dispersion: f64) -> Option<Dispersion> {
    (dispersion > 0.0).then(|| {
        let k = (ior - 1.0) * dispersion / 20.0;
        Dispersion::Cauchy { a: ior - k * 1.5168, b: k * 0.523655, c: 0.0 }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volume_attenuation_is_shared_by_the_two_refractions_of_a_crossing() {
        let t = volume_tint([0.25, 1.0, 0.5], 2.0, 4.0).unwrap();
        // Over 4 m at 0.25 per 2 m: 0.0625 kept; per refraction its square root.
        assert!((t - Vec3::new(0.25, 1.0, 0.5)).abs().max_element() < 1e-6, "{t}");
        assert_eq!(volume_tint([0.5; 3], f32::INFINITY, 1.0), Some(Vec3::ONE));
        assert_eq!(volume_tint([0.5; 3], 1.0, 0.0), Some(Vec3::ONE));
        assert_eq!(volume_tint([1.5, 0.5, 0.5], 1.0, 1.0), None);
    }

    #[test]
    fn the_dispersion_law_keeps_n_d_and_the_abbe_number() {
        // BK7: n_d 1.5168, V 64.17 (dispersion 20/V).
        let Some(d) = cauchy_of(1.5168, 20.0 / 64.17) else { panic!() };
        let n = |nm: f32| d.ior(nm) as f64;
        assert!((n(587.6) - 1.5168).abs() < 2e-4, "{}", n(587.6));
        let v = (n(587.6) - 1.0) / (n(486.1) - n(656.3));
        assert!((v - 64.17).abs() < 0.5, "{v}");
        assert!(cauchy_of(1.5, 0.0).is_none());
    }
}
