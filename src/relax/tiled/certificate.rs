//! The certificate of a tile's steps: the photons whose positions may differ from the whole
//! map's, and how deep a photon lies in the halo box (docs/tiles.md).

use crate::spatial::BoxTree;
use crate::tiles::HaloBox;

use super::bounds::Moves;

/// Photons whose position at an iteration may differ from the whole map's: where each started
/// (working units) and the most it moves per iteration, grouped by that bound (powers of two)
/// so a query visits, per group, only those that could have come within its reach.
pub(super) struct Uncertain {
    groups: Vec<Group>,
}

struct Group {
    tree: BoxTree,
    start: Vec<[f32; 3]>,
    moves: Vec<Moves>,
    most: Moves,
    /// Per iteration t, the deepest into the halo box any of the group may be.
    front: Vec<f64>,
}

impl Uncertain {
    /// The photons (start, moves), with `depth` their depth in the halo box, for iterations
    /// up to `iterations`.
    pub(super) fn of(
        photons: impl Iterator<Item = ([f32; 3], Moves)>,
        depth: impl Fn([f32; 3]) -> f64,
        iterations: usize,
    ) -> Uncertain {
        type Members = (Vec<[f32; 3]>, Vec<Moves>, Vec<f64>);
        let mut by_bound: std::collections::BTreeMap<i32, Members> = Default::default();
        for (x, m) in photons {
            let d = depth(x);
            let b = m.first.max(m.later);
            let key = if b.is_finite() && b > 0.0 {
                b.log2().floor() as i32
            } else if b > 0.0 {
                i32::MAX
            } else {
                i32::MIN
            };
            let g = by_bound
                .entry(key)
                .or_insert_with(|| (Vec::new(), Vec::new(), vec![f64::NEG_INFINITY; iterations + 1]));
            g.0.push(x);
            g.1.push(m);
            for (t, f) in g.2.iter_mut().enumerate() {
                *f = f.max(d + m.after(t));
            }
        }
        let groups = by_bound
            .into_values()
            .map(|(start, moves, front)| Group {
                front,
                tree: BoxTree::build(&start),
                most: moves.iter().fold(Moves { first: 0.0, later: 0.0 }, |a, m| Moves {
                    first: a.first.max(m.first),
                    later: a.later.max(m.later),
                }),
                start,
                moves,
            })
            .collect();
        Uncertain { groups }
    }

    /// Whether none of these photons can be within `read` of `x` after `t` iterations: each
    /// lies farther from `x` than `read` plus the most it moves in `t` iterations.
    /// `depth` is x's depth in the halo box: when `read` stays inside the part of the box none
    /// of a group can have reached, that group needs no search.
    pub(super) fn clear_of(&self, x: [f32; 3], depth: f64, read: f64, t: usize) -> bool {
        self.groups.iter().all(|g| {
            if read < depth - g.front[t] {
                return true;
            }
            let reach = read + g.most.after(t);
            if !reach.is_finite() {
                return false;
            }
            let r2 = (reach * (1.0 + 1e-5)).powi(2) as f32 * (1.0 + 1e-5);
            !g.tree.any_within(x, r2, &mut |j, _| {
                let a = g.start[j as usize];
                let d2: f64 = (0..3).map(|c| (x[c] as f64 - a[c] as f64).powi(2)).sum();
                d2.sqrt() <= read + g.moves[j as usize].after(t)
            })
        })
    }
}

/// The depth of `x` (working units, positions scaled by `scale`) in `halo` (metres): its
/// distance to the outside, negative outside, +∞ in a whole box.
pub(crate) fn depth_in(halo: &HaloBox, x: [f32; 3], scale: f64) -> f64 {
    (0..2)
        .map(|k| {
            let v = x[halo.axes[k]] as f64;
            (v - halo.lo[k] * scale).min(halo.hi[k] * scale - v)
        })
        .fold(f64::INFINITY, f64::min)
}
