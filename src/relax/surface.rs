//! Photons moved in their tangent plane are returned to their curved surface, or their move
//! is refused.

use glam::Vec3;
use rayon::prelude::*;

/// Returns every moved photon of `moved` to its surface, or back to `before` when its surface
/// is not found; updates `normals`, and counts each photon's refused moves in `refused`.
pub(super) fn back_to_surfaces(
    scene: &crate::scene::Scene,
    surfaces: &[u32],
    before: &[[f32; 3]],
    moved: &mut [[f32; 3]],
    normals: &mut [[f32; 3]],
    refused: &mut [u32],
) {
    moved.par_iter_mut().zip(normals.par_iter_mut()).zip(refused.par_iter_mut()).enumerate().for_each(
        |(i, ((x, n), refused))| {
            let (old, new) = (Vec3::from(before[i]), Vec3::from(*x));
            let step = old.distance(new);
            if step == 0.0 {
                return;
            }
            match return_to_surface(scene, surfaces[i], new, Vec3::from(*n), step) {
                Some((at, normal)) => {
                    *x = at.into();
                    *n = normal.into();
                }
                None => {
                    *x = before[i];
                    *refused += 1;
                }
            }
        },
    );
}

/// How far along its normal a moved photon's surface is searched, in steps: a tangent step of
/// length s leaves a surface of radius R by s²/2R, a quarter of the step where s = R/2. A
/// surface farther than that from the step is curved on the scale of the photon's spacing, and
/// the move is refused. It also bounds how far one iteration moves a photon, (1 + this)·step,
/// which sizes the halo of a tile (docs/tiles.md).
pub const RETURN_REACH: f32 = 0.25;

/// The point of surface `surface` nearest along the normal to a photon moved by `step` in its
/// tangent plane, and the surface's normal there (oriented like `normal`): the photon's
/// surface is searched along ±normal within `RETURN_REACH`·step plus a rounding margin.
/// `None` if another surface or none lies there, or if `step` is not positive.
pub fn return_to_surface(
    scene: &crate::scene::Scene,
    surface: u32,
    moved: Vec3,
    normal: Vec3,
    step: f32,
) -> Option<(Vec3, Vec3)> {
    let n = normal.try_normalize()?;
    // The margin covers the rounding of `moved` (relative to its size) and, at the origin, a
    // fraction of the step: no absolute length, so it holds at any scene scale.
    let reach = RETURN_REACH * step + 1e-5 * moved.abs().max_element().max(step);
    for dir in [-n, n] {
        let ray = crate::scene::Ray::new(moved - dir * reach, dir);
        if let Some(hit) = scene.intersect(&ray, 0.0, 2.0 * reach)
            && hit.shape == surface
        {
            let hn = if hit.normal.dot(n) < 0.0 { -hit.normal } else { hit.normal };
            return Some((ray.at(hit.t), hn));
        }
    }
    None
}
