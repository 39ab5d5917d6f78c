//! Move bounds: the most a photon moves in one iteration of the whole map's relaxation, found
//! tile by tile (docs/tiles.md).

use crate::relax::{Columns, RelaxError};
use crate::tiles::TilePhotons;

use super::{MAX_ROUNDS, TiledRun, places_of};

/// How far a photon may move (working units): `first` in the first iteration, `later` in each
/// one after it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Moves {
    pub(super) first: f64,
    pub(super) later: f64,
}

impl Moves {
    /// The farthest from where it started that the photon may be after `t` iterations.
    pub(crate) fn after(&self, t: usize) -> f64 {
        match t {
            0 => 0.0,
            1 => self.first,
            _ => self.first + (t - 1) as f64 * self.later,
        }
    }
}

/// A step of length `s` (working units) as far as it moves the photon: widened for the
/// rounding of the move, and with a scene, for the return to the surface (as [`bound`]).
pub(super) fn widen(s: f64, scene: bool, slack: f64) -> f64 {
    let returned = 1.0 + crate::relax::surface::RETURN_REACH as f64;
    (if scene { returned * s } else { s }) * (1.0 + 1e-4) + slack
}

/// The most a photon whose first spacing is `first` (working units; ∞ while it has none) moves
/// in one iteration: `step_limit`·first (Eq. 8's clamp, [`crate::relax::Scratch`]), widened for the
/// rounding of the move, and with a scene, the return to the surface (which searches
/// [`crate::relax::surface::RETURN_REACH`] steps along the normal, plus 10⁻⁵ of the coordinates:
/// [`crate::relax::return_to_surface`]).
pub(super) fn bound(step_limit: f32, first: f32, scene: bool, slack: f64) -> f64 {
    let s = step_limit as f64 * first as f64;
    if !s.is_finite() {
        return f64::INFINITY;
    }
    widen(s, scene, slack)
}

/// Per cell of `tile`, the most any of its photons moves in one iteration, from every photon's
/// move bound (by index in the map).
pub(super) fn most_moved(tile: &TilePhotons, moves: &[f32]) -> Vec<f64> {
    tile.cells
        .iter()
        .map(|c| tile.of_cell(c).iter().fold(0f64, |m, &i| m.max(moves[i as usize] as f64)))
        .collect()
}

/// Per photon of the map (by index in the map): the most it moves in one iteration of the whole map's
/// relaxation, in working units: `step_limit` times its first spacing (Eq. 8's clamp), which
/// the first iteration sets from its Kf nearest (parameter-restricted before collapse) and
/// which caps every later step ([`crate::relax::Scratch`]); ∞ for a photon whose Kf nearest all sit
/// on it (a crowd: its first spacing is found later). Widened by the rounding of a coordinate
/// (and the return to a surface) as [`bound`] says; the rounding slack is returned too.
///
/// Computed tile by tile, never holding the whole map: a photon's first spacing is found among
/// the photons of its tile's halo box, a subset of the map, so its Kf-th nearest there is at
/// least as far as in the whole map and the spacing found bounds the true one from above
/// (docs/tiles.md). A photon that finds fewer than Kf in the box is searched again with the
/// halo doubled.
pub(crate) fn move_bounds(shared: &TiledRun) -> Result<(Vec<f32>, f64), RelaxError> {
    let (map, setup, scene, tiling) = (shared.map, &shared.setup, shared.scene, shared.tiling);
    let pos = map.positions();
    let n = pos.len();
    let on_surface = scene.is_some();
    // A position is rounded to half an ulp of its largest coordinate per axis on each move;
    // 10⁻⁵ of the coordinates for the surface's search margin.
    let far = pos.iter().flatten().fold(0f32, |m, v| m.max((v * setup.scale).abs())) as f64;
    let slack = far * (4.0 * f32::EPSILON as f64 + if on_surface { 1e-5 } else { 0.0 });
    if setup.coincident {
        // Nothing moves.
        return Ok((vec![0.0; n], slack));
    }
    // NaN: not yet bounded.
    let mut bounds = vec![f32::NAN; n];
    let extent = tiling.axes.iter().map(|&a| tiling.hi[a] as f64 - tiling.lo[a] as f64).fold(0.0, f64::max);
    let h0 = 4.0 * extent * (setup.p.kf as f64 / (std::f64::consts::PI * n.max(1) as f64)).sqrt();
    for c in 0..tiling.len() {
        let interior = shared.by_tile[c].ascending();
        let mut left = interior.len();
        let mut h = h0;
        let mut round = 0;
        while left > 0 {
            round += 1;
            let halo = tiling.halo_box(c, if round >= MAX_ROUNDS { f64::INFINITY } else { h });
            let whole = halo.is_whole();
            let (mut work, _) = shared.members_gathered(&halo);
            let members = work.photons.clone();
            let columns = Columns::of_gathered(map, &mut work, setup, true)?;
            // The first spacing does not depend on the return to the surface, which runs after
            // the step (its widening is in `bound`).
            let (first, read) = crate::relax::first_spacings(map, &columns, setup, &members)?;
            // Each interior photon's bound found this round (NaN: none), written to the map's
            // bounds in file order.
            let mut found = vec![f32::NAN; interior.len()];
            for (k, q) in places_of(&work, &interior).into_iter().enumerate() {
                if let Some(q) = q
                    && (read[k].is_finite() || whole)
                {
                    found[q] = rounded_up(bound(setup.p.step_limit, first[k], on_surface, slack));
                }
            }
            for (&i, f) in interior.iter().zip(found) {
                let b = &mut bounds[i as usize];
                if b.is_nan() && !f.is_nan() {
                    *b = f;
                    left -= 1;
                }
            }
            map.release_pages();
            if whole {
                // Photons no box holds (non-finite positions) have no bound.
                break;
            }
            h *= 2.0;
        }
    }
    for b in &mut bounds {
        if b.is_nan() {
            *b = f32::INFINITY;
        }
    }
    Ok((bounds, slack))
}

/// `x` as an f32 no smaller than it (a bound stays a bound).
fn rounded_up(x: f64) -> f32 {
    let v = x as f32;
    if (v as f64) < x { v.next_up() } else { v }
}
