//! Growth of the primal set: cells split where the flux is, so the photon count grows where
//! the light is (docs/progressive.md, "Growth").
//!
//! A map of N fixed photons rendered with a K-photon kernel has two errors that passes cannot
//! remove: the kernel's blur and the noise of summing K whole cells over a disc that cuts
//! cells at its rim. Progressive photon mapping shrinks its radius as R² ∝ p^(α−1) (α = 2/3);
//! the map's photon count grows instead, toward N₀·p^γ (γ = 1 − α = 1/3 by default), by
//! splitting the cells whose flux estimate is largest (which works toward the constant
//! per-photon flux the 2013 paper relaxes toward). A cell that has gathered at least
//! `SPLIT_AFTER` fresh photons is cut through the flux-weighted centroid of what it gathered,
//! across its principal axis; its photon moves to one half's site and a new photon takes the
//! other's. The cells form a hierarchy (the map's photons' cells are the roots) and every
//! fresh photon descends it, so children partition their parent exactly and a child's flux is
//! its parent's times its share of what the two gathered since the split: no guess about the
//! split survives the passes after it. Rendered within the distance of the K-th nearest of the
//! map's photons before it grew ([`super::first_photons`]), the kernel keeps its first area
//! and the cells in it, more and smaller, carry the flux more finely.

use glam::Vec3;
use rayon::prelude::*;

use super::pass::{Primal, Statistics};
use crate::format::MapView;
use crate::scene::material::luminance;
use crate::trace::Photons;

/// The primal photons' target count after `pass` passes: N₀·pass^γ, never fewer than N₀.
pub fn target_count(start: usize, pass: u64, growth: f32) -> usize {
    if growth <= 0.0 || pass == 0 {
        return start;
    }
    let n = start as f64 * (pass as f64).powf(growth as f64);
    (n.round() as usize).max(start)
}

/// A photon the growth added: a copy of the photon whose cell it split.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Promoted {
    /// The primal photon (its index in the grown set) whose cell it split.
    pub owner: u32,
}

/// A cell of the hierarchy: the region of the surface it covers accumulates the flux of the
/// fresh photons that fell in it since it was made.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Region {
    /// Flux gathered since the region was made, W per channel (roots: in [`Statistics`]).
    tau: [f32; 3],
    /// The point a split compares distances to.
    site: [f32; 3],
    /// The photon whose cell it is, or was before the split.
    photon: u32,
    /// The two regions it was split into: its photon's and the new photon's.
    children: Option<[u32; 2]>,
}

/// Flux-weighted moments of the fresh photons a leaf gathered since it was made, about its
/// site: weight (luminance), first moment (3), second moments (xx, xy, xz, yy, yz, zz), and
/// the count.
pub type Moments = [f32; 11];

/// The primal photons' cells as a hierarchy: the map's photons' cells are the roots (their
/// statistics are [`Statistics`], over every pass); splitting a photon's cell makes two
/// children, each gathering from then on. Every fresh photon descends from its nearest root to
/// the nearer child site at each split, so the children partition their parent exactly and a
/// child's flux is its parent's times the share the children gathered since the split
/// (docs/progressive.md, "Growth").
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cells {
    roots: usize,
    regions: Vec<Region>,
    /// Per photon, its cell (a leaf region).
    leaf: Vec<u32>,
    /// Per photon, the moments of its leaf.
    moments: Vec<Moments>,
    /// Per promoted photon (index − roots), the two regions its split made.
    made: Vec<[u32; 2]>,
}

/// The hierarchy as a refined map's columns (format-spec/phm-v1.md §4.2), one element per
/// photon; the photons after the roots were added in order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HierarchyColumns {
    /// `refine_split_of`: the photon whose cell it split; u32::MAX for a root.
    pub split_of: Vec<u32>,
    /// `refine_site`: a root's site; an added photon's region's site.
    pub site: Vec<[f32; 3]>,
    /// `refine_site_kept`: for an added photon, the site of the split photon's region made
    /// with it (zero for a root).
    pub site_kept: Vec<[f32; 3]>,
    /// `refine_tau`: a root's τ over every pass; an added photon's region's τ since the split.
    pub tau: Vec<[f32; 3]>,
    /// `refine_tau_kept`: τ of the split photon's region made with it, since the split.
    pub tau_kept: Vec<[f32; 3]>,
    /// `refine_moments`: each photon's leaf moments ([`Moments`]).
    pub moments: Vec<Moments>,
}

/// Passes' worth of prior weight on an even split, while a split's children have gathered
/// little (the share (τ_c + ½·w·F) / (τ_c + τ_s + w·F), F the parent's flux per pass).
const SHARE_PRIOR: f32 = 1.0;

/// Fresh photons a cell must have gathered since it was made before it is split.
const SPLIT_AFTER: f32 = 8.0;

impl Cells {
    /// The cells of the photons at `sites` (the roots), none split.
    pub fn new(sites: &[[f32; 3]]) -> Cells {
        Cells {
            roots: sites.len(),
            regions: sites
                .iter()
                .enumerate()
                .map(|(i, &site)| Region { tau: [0.0; 3], site, photon: i as u32, children: None })
                .collect(),
            leaf: (0..sites.len() as u32).collect(),
            moments: vec![[0.0; 11]; sites.len()],
            made: Vec::new(),
        }
    }

    /// The map's photons that are roots (the rest were promoted, in order).
    pub fn roots(&self) -> usize {
        self.roots
    }

    /// The roots' sites (the map's photons' positions before any split).
    pub fn root_sites(&self) -> Vec<[f32; 3]> {
        self.regions[..self.roots].iter().map(|r| r.site).collect()
    }

    /// Each fresh photon's leaf region, walked down from its root (`root[j]`, from
    /// [`super::gather_cells`] over the roots' sites), the walks in parallel.
    fn leaves(&self, fresh: &Photons, root: &[Option<u32>]) -> Vec<Option<u32>> {
        let regions = &self.regions;
        root.par_iter()
            .enumerate()
            .map(|(j, r)| {
                let mut r = (*r)? as usize;
                let x = Vec3::from(fresh.position[j]);
                let d = |site: [f32; 3]| x.distance_squared(site.into());
                while let Some([a, b]) = regions[r].children {
                    let (sa, sb) = (regions[a as usize].site, regions[b as usize].site);
                    r = if d(sb) < d(sa) { b } else { a } as usize;
                }
                Some(r as u32)
            })
            .collect()
    }

    /// The photon whose cell each fresh photon falls in (`root` as for [`Self::descend`]).
    pub fn owners(&self, fresh: &Photons, root: &[Option<u32>]) -> Vec<Option<u32>> {
        self.leaves(fresh, root).iter().map(|l| l.map(|l| self.regions[l as usize].photon)).collect()
    }

    /// Sends each fresh photon from its root (`root[j]`, from [`super::gather_cells`] over the
    /// roots' sites) down to its leaf, adding its flux to every split region on the way and
    /// to its leaf's moments.
    pub fn descend(&mut self, fresh: &Photons, root: &[Option<u32>]) {
        let leaf = self.leaves(fresh, root);
        // What each leaf received, summed up the hierarchy: a region's children come after it,
        // so in reverse order every region's subtree is summed before its parent reads it.
        let mut deposit = vec![[0.0f64; 3]; self.regions.len()];
        for (j, l) in leaf.iter().enumerate() {
            let Some(l) = *l else { continue };
            for (d, f) in deposit[l as usize].iter_mut().zip(fresh.flux[j]) {
                *d += f as f64;
            }
            let region = self.regions[l as usize];
            let w = luminance(Vec3::from(fresh.flux[j]));
            let v = Vec3::from(fresh.position[j]) - Vec3::from(region.site);
            let add = [
                w,
                w * v.x,
                w * v.y,
                w * v.z,
                w * v.x * v.x,
                w * v.x * v.y,
                w * v.x * v.z,
                w * v.y * v.y,
                w * v.y * v.z,
                w * v.z * v.z,
                1.0,
            ];
            for (m, a) in self.moments[region.photon as usize].iter_mut().zip(add) {
                *m += a;
            }
        }
        for r in (self.roots..self.regions.len()).rev() {
            if let Some([a, b]) = self.regions[r].children {
                let (da, db) = (deposit[a as usize], deposit[b as usize]);
                for c in 0..3 {
                    deposit[r][c] += da[c] + db[c];
                }
            }
            for (t, d) in self.regions[r].tau.iter_mut().zip(deposit[r]) {
                *t = (*t as f64 + d) as f32;
            }
        }
    }

    /// Each photon's cell flux per pass, W per channel: a root's τ/P, a child's its parent's
    /// times its share of what the two children gathered since the split.
    pub fn leaf_flux(&self, stats: &Statistics) -> Vec<Vec3> {
        let mut f = vec![Vec3::ZERO; self.regions.len()];
        for (i, fi) in f.iter_mut().enumerate().take(self.roots) {
            *fi = stats.cell_flux(i);
        }
        for r in 0..self.regions.len() {
            if let Some([a, b]) = self.regions[r].children {
                let (ta, tb) =
                    (Vec3::from(self.regions[a as usize].tau), Vec3::from(self.regions[b as usize].tau));
                let prior = f[r] * SHARE_PRIOR;
                let whole = ta + tb + prior;
                let share = |t: Vec3| {
                    Vec3::from_array(std::array::from_fn(|c| {
                        if whole[c] > 0.0 { (t[c] + 0.5 * prior[c]) / whole[c] } else { 0.5 }
                    }))
                };
                f[a as usize] = f[r] * share(ta);
                f[b as usize] = f[r] * share(tb);
            }
        }
        self.leaf.iter().map(|&l| f[l as usize]).collect()
    }

    /// Splits up to `add` cells: the brightest (`flux`, by luminance, ties by index) among those
    /// that have gathered at least `SPLIT_AFTER` fresh photons since they were made. A cell is
    /// cut through the flux-weighted centroid of what it gathered, across its principal axis:
    /// the two children's sites lie at c ± 0.8·σ₁·e₁ (σ₁² the largest eigenvalue of the
    /// gathered flux's covariance, e₁ its axis; the halves of a uniform segment have their
    /// centroids at ±0.87·σ₁), so the halves hold about equal flux and the even-split prior is
    /// close to the truth. The split photon moves to the first site and a new photon, a copy of
    /// it, takes the second. Returns the new photons, in the order they were appended.
    pub fn split_brightest(&mut self, primal: &mut Primal, flux: &[Vec3], add: usize) -> Vec<Promoted> {
        let n = primal.len();
        let mut cells: Vec<(f32, usize)> = (0..n)
            .filter(|&i| self.moments[i][10] >= SPLIT_AFTER && self.moments[i][0] > 0.0)
            .map(|i| (luminance(flux[i]), i))
            .collect();
        let add = add.min(cells.len());
        if add == 0 {
            return Vec::new();
        }
        let by_flux = |a: &(f32, usize), b: &(f32, usize)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        cells.select_nth_unstable_by(add - 1, by_flux);
        cells.truncate(add);
        cells.sort_unstable_by(by_flux);
        let mut promoted = Vec::with_capacity(add);
        for &(_, i) in &cells {
            let Some((a, b)) = self.cut(i) else { continue };
            let new = primal.len() as u32;
            primal.positions[i] = a;
            primal.positions.push(b);
            primal.flux.push(primal.flux[i]);
            if let Some(normals) = &mut primal.normals {
                normals.push(normals[i]);
            }
            if let Some((u, v)) = &mut primal.basis {
                u.push(u[i]);
                v.push(v[i]);
            }
            self.split_leaf(i as u32, new, a, b);
            promoted.push(Promoted { owner: i as u32 });
        }
        promoted
    }

    /// The two sites photon i's cell is cut at, from its leaf's moments; `None` when what it
    /// gathered has no extent.
    fn cut(&self, i: usize) -> Option<([f32; 3], [f32; 3])> {
        let m = &self.moments[i];
        let w = m[0] as f64;
        let mean = nalgebra::Vector3::new(m[1] as f64, m[2] as f64, m[3] as f64) / w;
        let s = |k: usize| m[k] as f64 / w;
        let cov = nalgebra::Matrix3::new(s(4), s(5), s(6), s(5), s(7), s(8), s(6), s(8), s(9))
            - mean * mean.transpose();
        let eig = nalgebra::SymmetricEigen::new(cov);
        let (k, &l1) = eig.eigenvalues.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
        if !(l1 > 0.0 && l1.is_finite()) {
            return None;
        }
        let e1 = eig.eigenvectors.column(k) * (0.8 * l1.sqrt());
        let site = nalgebra::Vector3::from(self.regions[self.leaf[i] as usize].site).cast::<f64>();
        let c = site + mean;
        let p = |v: nalgebra::Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        Some((p(c - e1), p(c + e1)))
    }

    /// The columns a refined map keeps the hierarchy in, with the roots' statistics.
    pub fn columns(&self, stats: &Statistics) -> HierarchyColumns {
        let n = self.leaf.len();
        let mut c = HierarchyColumns {
            split_of: vec![u32::MAX; n],
            site: vec![[0.0; 3]; n],
            site_kept: vec![[0.0; 3]; n],
            tau: vec![[0.0; 3]; n],
            tau_kept: vec![[0.0; 3]; n],
            moments: self.moments.clone(),
        };
        for i in 0..self.roots {
            c.site[i] = self.regions[i].site;
            c.tau[i] = stats.tau[i];
        }
        for (k, &[c_s, c_j]) in self.made.iter().enumerate() {
            let (kept, own) = (self.regions[c_s as usize], self.regions[c_j as usize]);
            let j = self.roots + k;
            c.split_of[j] = kept.photon;
            c.site[j] = own.site;
            c.site_kept[j] = kept.site;
            c.tau[j] = own.tau;
            c.tau_kept[j] = kept.tau;
        }
        c
    }

    /// Rebuilds the hierarchy of `roots` root photons from a refined map's columns (the
    /// photons after the roots were added in order, each splitting an earlier one's cell).
    /// `None` when the columns do not describe one.
    pub fn rebuild(roots: usize, c: &HierarchyColumns) -> Option<Cells> {
        let n = c.split_of.len();
        let same = [c.site.len(), c.site_kept.len(), c.tau.len(), c.tau_kept.len(), c.moments.len()];
        if roots > n || same.iter().any(|&l| l != n) || c.split_of[..roots].iter().any(|&s| s != u32::MAX) {
            return None;
        }
        let mut cells = Cells::new(&c.site[..roots]);
        for j in roots..n {
            let s = c.split_of[j];
            if s as usize >= j {
                return None;
            }
            cells.split_leaf(s, j as u32, c.site_kept[j], c.site[j]);
            let [c_s, c_j] = cells.made[j - roots];
            cells.regions[c_s as usize].tau = c.tau_kept[j];
            cells.regions[c_j as usize].tau = c.tau[j];
        }
        cells.moments.clone_from(&c.moments);
        Some(cells)
    }

    fn split_leaf(&mut self, s: u32, j: u32, a: [f32; 3], b: [f32; 3]) {
        let parent = self.leaf[s as usize];
        let c_s = self.regions.len() as u32;
        self.regions.push(Region { tau: [0.0; 3], site: a, photon: s, children: None });
        self.regions.push(Region { tau: [0.0; 3], site: b, photon: j, children: None });
        self.regions[parent as usize].children = Some([c_s, c_s + 1]);
        self.leaf[s as usize] = c_s;
        self.leaf.push(c_s + 1);
        self.moments[s as usize] = [0.0; 11];
        self.moments.push([0.0; 11]);
        self.made.push([c_s, c_s + 1]);
    }
}

/// The cell flux estimates after [`Cells::split_brightest`] made `promoted`, from those
/// before it: a cell just split has gathered nothing since, so its two halves share its flux
/// evenly. The same as [`Cells::leaf_flux`] after the split (tested), without a pass over
/// every region.
pub fn halve_split_cells(estimate: &mut Vec<Vec3>, promoted: &[Promoted]) {
    for p in promoted {
        let half = estimate[p.owner as usize] * 0.5;
        estimate[p.owner as usize] = half;
        estimate.push(half);
    }
}

/// The rows the grown photons add to every column of `map`, in the map's column order: a copy
/// of the split photon's row (its trajectory, its constraint basis, λ2 and parameter radius:
/// those of the neighbourhood it was born in). Position and flux are set from the primal set.
#[derive(Clone, Debug, Default)]
pub struct GrownRows {
    /// Photons added.
    pub len: usize,
    /// Per column of the map, the added rows' bytes.
    pub bytes: Vec<Vec<u8>>,
}

impl GrownRows {
    /// Appends the rows of `promoted`.
    pub fn push(&mut self, map: &MapView, promoted: &[Promoted]) {
        let columns = map.columns();
        self.bytes.resize(columns.len(), Vec::new());
        for p in promoted {
            for (c, (spec, bytes)) in columns.iter().enumerate() {
                let stride = spec.stride() as usize;
                let o = p.owner as usize;
                let row = if o < map.len() {
                    bytes[o * stride..(o + 1) * stride].to_vec()
                } else {
                    let k = o - map.len();
                    self.bytes[c][k * stride..(k + 1) * stride].to_vec()
                };
                self.bytes[c].extend_from_slice(&row);
            }
            self.len += 1;
        }
    }
}
