//! `KHR_lights_punctual` lights as emitters: point → point, spot → spot, directional →
//! collimated, their photometric intensities turned into watts at [`LUMENS_PER_WATT`].

use std::f64::consts::PI;

use glam::{Mat4, Vec3};

use super::Cx;
use crate::scene::SceneError;
use crate::scene::emitter::{Emitter, EmitterShape};

/// Luminous efficacy used to turn lumens into watts: 683 lm/W, that of monochromatic light at
/// 555 nm, the same for every light kind and colour (docs/scene.md, "glTF scenes"). Blender's
/// glTF exporter uses the same constant, so its lights' watts come back.
pub const LUMENS_PER_WATT: f64 = 683.0;

/// The key of a directional light's beam size, `[w, h]` metres, in the light's or its node's
/// `extras`.
pub const BEAM_SIZE_KEY: &str = "photonkit_beam_size";

/// A light of the file placed by its node's world matrix.
pub(super) struct Placed<'a> {
    pub light: gltf::khr_lights_punctual::Light<'a>,
    pub node: gltf::Node<'a>,
    pub world: Mat4,
}

/// The emitter of `p`, or `None` (with a line in `unsupported`) for a light that sends
/// nothing. `specular_box` is the box around every mirror and dielectric vertex and `scene_box`
/// around every vertex: a directional light without a beam size covers the first from
/// upstream of the second, and `notes` says so.
pub(super) fn emitter(
    cx: &Cx,
    p: &Placed,
    specular_box: Option<(Vec3, Vec3)>,
    scene_box: Option<(Vec3, Vec3)>,
    unsupported: &mut Vec<String>,
    notes: &mut Vec<String>,
) -> Result<Option<Emitter>, SceneError> {
    use gltf::khr_lights_punctual::Kind;
    let what = super::label("lights", p.light.index(), p.light.name());
    let intensity = p.light.intensity();
    let colour = Vec3::from_array(p.light.color());
    if !(intensity.is_finite() && intensity >= 0.0 && colour.is_finite()) || colour.min_element() < 0.0 {
        return Err(cx.err(&what, "intensity and color must be finite and ≥ 0"));
    }
    if intensity == 0.0 || colour.max_element() == 0.0 {
        unsupported.push(format!("{what}: sends no light (intensity or colour zero): left out"));
        return Ok(None);
    }
    if p.light.range().is_some() {
        unsupported.push(format!("{what}: range (a rendering cut-off; light reaches every distance here)"));
    }
    let position = p.world.transform_point3(Vec3::ZERO);
    let axis = p.world.transform_vector3(Vec3::NEG_Z).try_normalize();
    let node = super::label("nodes", p.node.index(), p.node.name());
    let axis = || axis.ok_or_else(|| cx.err(&node, format!("its transform collapses {what}'s direction")));
    let (shape, lumens) = match p.light.kind() {
        Kind::Point => (EmitterShape::Point { position }, intensity as f64 * 4.0 * PI),
        Kind::Spot { outer_cone_angle, .. } => {
            if !(outer_cone_angle > 0.0 && outer_cone_angle <= std::f32::consts::FRAC_PI_2) {
                return Err(cx.err(&what, format!("outerConeAngle {outer_cone_angle} must lie in (0, π/2]")));
            }
            notes.push(format!(
                "{what}: a spot emits cosine-weighted within its outer cone ({:.1}°), not glTF's flat cone with a soft edge",
                outer_cone_angle.to_degrees()
            ));
            let lumens = spot_lumens(intensity, outer_cone_angle);
            (EmitterShape::Spot { position, axis: axis()?, half_angle_rad: outer_cone_angle }, lumens)
        }
        Kind::Directional => {
            let d = axis()?;
            let side = p.world.transform_vector3(Vec3::X);
            let eu = (side - d * d.dot(side)).try_normalize().unwrap_or_else(|| d.any_orthonormal_vector());
            let ev = eu.cross(d);
            let (origin, edge_u, edge_v, how) = match beam_size(cx, &what, p)? {
                Some([w, h]) => {
                    let (eu, ev) = (eu * w, ev * h);
                    (
                        position - 0.5 * eu - 0.5 * ev,
                        eu,
                        ev,
                        format!("{w} × {h} m from extras.{BEAM_SIZE_KEY}"),
                    )
                }
                None => {
                    let (Some(spec), Some(all)) = (specular_box, scene_box) else {
                        return Err(cx.err(
                            &what,
                            format!("a directional light needs extras.{BEAM_SIZE_KEY} = [w, h] (metres) when the scene has no mirror or glass to aim it at"),
                        ));
                    };
                    let (o, u, v) = footprint(d, eu, ev, spec, all);
                    let how = format!(
                        "{:.3} × {:.3} m, the bounding box of the mirrors and glass (no extras.{BEAM_SIZE_KEY})",
                        u.length(),
                        v.length()
                    );
                    (o, u, v, how)
                }
            };
            notes.push(format!("{what}: directional light's beam {how}"));
            let area = edge_u.cross(edge_v).length() as f64;
            if !(area > 0.0 && area.is_finite()) {
                return Err(cx.err(&what, "the directional light's beam has no area"));
            }
            (EmitterShape::Collimated { origin, edge_u, edge_v, direction: d }, intensity as f64 * area)
        }
    };
    let power_w = lumens / LUMENS_PER_WATT;
    let max = crate::scene::file::MAX_POWER_W;
    if !(power_w > 0.0 && power_w <= max) {
        return Err(cx.err(&what, format!("{power_w:e} W is beyond the {max:e} W photon flux can hold")));
    }
    Ok(Some(Emitter { kind: shape, power_w, colour }))
}

/// The luminous flux of a spot of `intensity` candela with a flat cone of half angle
/// `outer` (rad): I · 2π(1 − cos outer), the soft edge counted as inside.
pub fn spot_lumens(intensity: f32, outer: f32) -> f64 {
    intensity as f64 * 2.0 * PI * (1.0 - (outer as f64).cos())
}

/// `extras.photonkit_beam_size` of the light, else of its node: two positive lengths.
fn beam_size(cx: &Cx, what: &str, p: &Placed) -> Result<Option<[f32; 2]>, SceneError> {
    for extras in [p.light.extras(), p.node.extras()] {
        let Some(raw) = extras else { continue };
        let v: serde_json::Value =
            serde_json::from_str(raw.get()).map_err(|e| cx.err(what, format!("extras: {e}")))?;
        let Some(size) = v.get(BEAM_SIZE_KEY) else { continue };
        let wh: Option<Vec<f32>> =
            size.as_array().map(|a| a.iter().filter_map(|x| x.as_f64()).map(|x| x as f32).collect());
        return match wh.as_deref() {
            Some(&[w, h]) if w > 0.0 && h > 0.0 && w.is_finite() && h.is_finite() => Ok(Some([w, h])),
            _ => Err(
                cx.err(what, format!("extras.{BEAM_SIZE_KEY} needs [w, h], two positive lengths in metres"))
            ),
        };
    }
    Ok(None)
}

/// A beam along `d` covering box `spec` across it (in the frame eu, ev), starting upstream of
/// every point of box `all`: (origin, edge_u, edge_v).
fn footprint(d: Vec3, eu: Vec3, ev: Vec3, spec: (Vec3, Vec3), all: (Vec3, Vec3)) -> (Vec3, Vec3, Vec3) {
    let corners = |(lo, hi): (Vec3, Vec3)| {
        (0..8).map(move |i| Vec3::new([lo.x, hi.x][i & 1], [lo.y, hi.y][(i >> 1) & 1], [lo.z, hi.z][i >> 2]))
    };
    let range = |b, a: Vec3| {
        corners(b)
            .map(|c| c.dot(a))
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), x| (l.min(x), h.max(x)))
    };
    let (u0, u1) = range(spec, eu);
    let (v0, v1) = range(spec, ev);
    let (d0, d1) = range(all, d);
    let start = d0 - 0.01 * (d1 - d0).max(u1 - u0).max(v1 - v0);
    (eu * u0 + ev * v0 + d * start, eu * (u1 - u0), ev * (v1 - v0))
}
