//! The reference every index query must equal: a scan over all photons.

use super::{Neighbour, PointSet, Query, Space};

/// Squared distance summed in axis order, exactly as the kd-tree computes it.
fn dist2(a: &[f32], b: &[f32]) -> f32 {
    let mut s = 0.0f32;
    for (x, y) in a.iter().zip(b) {
        let d = x - y;
        s += d * d;
    }
    s
}

/// The `k` nearest candidates of `q` in `space` by a full scan, sorted by (distance²,
/// index): the definition [`super::SpatialIndex::knn`] implements. O(n) per query; for
/// tests and checks.
pub fn brute_force_knn(points: &PointSet, space: Space, q: &Query, k: usize) -> Vec<Neighbour> {
    if matches!(q.radius, Some(r) if r.is_nan() || r < 0.0) {
        return Vec::new();
    }
    let r2 = q.radius.map(|r| r * r);
    let mut v: Vec<Neighbour> = (0..points.len())
        .filter(|&i| Some(i as u32) != q.exclude)
        .filter(|&i| space == Space::World || points.emitter(i) == q.emitter)
        .filter_map(|i| {
            let p = points.params_of(i);
            let d = match space {
                Space::World => dist2(&points.positions[i], &q.position),
                Space::WorldParams => {
                    if let Some(r2) = r2
                        && !p.is_empty()
                        && dist2(p, &q.params[..p.len()]) > r2
                    {
                        return None;
                    }
                    dist2(&points.positions[i], &q.position)
                }
                Space::Params => {
                    if p.is_empty() {
                        return None;
                    }
                    dist2(p, &q.params[..p.len()])
                }
            };
            Some(Neighbour { dist2: d, index: i as u32 })
        })
        .collect();
    v.sort_unstable_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
    v.truncate(k);
    v
}
