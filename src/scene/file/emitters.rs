//! The `[[emitters]]` tables: the checks every emitter gets (power, colour), then one
//! function per kind.

use std::ops::Range;

use glam::Vec3;

use super::{Ctx, RawEmitter, Sp, finite, only, positive, req, unit, vec3};
use crate::scene::SceneError;
use crate::scene::emitter::{Emitter, EmitterShape};

/// The largest emitter power accepted, W (photon flux is f32; a photon's share stays finite).
pub const MAX_POWER_W: f64 = 1e30;

pub(super) fn emitter(cx: &Ctx, i: usize, e: &Sp<RawEmitter>) -> Result<Emitter, SceneError> {
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
