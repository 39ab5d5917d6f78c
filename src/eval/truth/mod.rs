//! Ground truth without a photon map: floor irradiance computed from the optics alone, for
//! scenes simple enough to integrate (issue 7). Every function here is independent of the
//! tracer: its own f64 geometry, Snell's law and the Fresnel equations; from the scene it reads
//! only parameters (shapes, materials, the emitter) and the tracer's colour definition (the
//! wavelength → RGB weights and the uniform wavelength distribution).
//!
//! [`floor_truth`] gives cell-averaged irradiance on a [`FloorGrid`]: flux landing in each cell
//! divided by its area. The beam's parameter square is cut into triangles whose corners are
//! carried through the optics (E(X) = Σ E0·T/|det X′| over the pre-images of X, integrated
//! exactly over each cell for the piecewise-linear map; `splat`). `docs/truth.md` describes
//! each scene's truth and its accuracy.

mod optics;
mod sphere;
mod splat;

pub use sphere::{SphereCaustic, fresnel_reflectance};

use crate::scene::Scene;
use crate::scene::material::WAVELENGTH_RANGE_NM;
use optics::{Optic, Setup};
use splat::Accumulator;

/// A rectangle of the floor plane z = `z`, cut into `cells[0]` columns (x, increasing) and
/// `cells[1]` rows; row 0 is the largest y (the top row of an orthographic top-down image
/// with up = +y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloorGrid {
    /// The smallest (x, y), metres.
    pub min: [f64; 2],
    /// The largest (x, y), metres.
    pub max: [f64; 2],
    /// Columns and rows.
    pub cells: [usize; 2],
    /// The floor's height, metres.
    pub z: f64,
}

impl FloorGrid {
    /// Width and height of one cell, metres.
    pub fn cell_size(&self) -> [f64; 2] {
        [
            (self.max[0] - self.min[0]) / self.cells[0] as f64,
            (self.max[1] - self.min[1]) / self.cells[1] as f64,
        ]
    }

    /// Area of one cell, m².
    pub fn cell_area(&self) -> f64 {
        let [w, h] = self.cell_size();
        w * h
    }

    /// The cell (column, row) holding floor point (x, y), if on the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let [w, h] = self.cell_size();
        let c = ((x - self.min[0]) / w).floor();
        let r = ((self.max[1] - y) / h).floor();
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.cells[0] && (r as usize) < self.cells[1])
            .then_some((c as usize, r as usize))
    }

    /// Centre of cell (column, row).
    pub fn centre(&self, col: usize, row: usize) -> [f64; 2] {
        let [w, h] = self.cell_size();
        [self.min[0] + (col as f64 + 0.5) * w, self.max[1] - (row as f64 + 0.5) * h]
    }

    fn check(&self) -> Result<(), TruthError> {
        let ok = self.cells[0] > 0
            && self.cells[1] > 0
            && self.cells[0].checked_mul(self.cells[1]).is_some_and(|n| n <= 1 << 26)
            && self.min.iter().chain(&self.max).chain([&self.z]).all(|v| v.is_finite())
            && self.max[0] > self.min[0]
            && self.max[1] > self.min[1];
        if ok { Ok(()) } else { Err(TruthError::BadGrid(format!("{self:?}"))) }
    }
}

/// Cell-averaged caustic irradiance on a floor grid, W/m² per RGB channel, row-major
/// (index = `row * cells[0] + column`).
#[derive(Clone, Debug)]
pub struct FloorTruth {
    /// The cells.
    pub grid: FloorGrid,
    /// Irradiance per cell, W/m² per RGB channel, row-major.
    pub irradiance: Vec<[f64; 3]>,
    /// Which stored photons this truth accounts for, by their BOUNCES value (specular bounces
    /// before the floor), e.g. `[2]` for the sphere's once-in-once-out light. The comparison keeps
    /// only these photons before running any method.
    pub bounces: Vec<u8>,
    /// Per cell: true where light arrives from two or more separate pre-image sheets (folded
    /// or crossing filaments overlap), each bringing at least 10 % of the cell's flux.
    pub overlap: Vec<bool>,
    /// A short human description of what was integrated and how (quadrature, sample counts).
    pub method: String,
}

/// How hard to integrate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// Fast, for unit tests (< 1 s in the dev profile).
    Test,
    /// Converged for a 256² grid; seconds in release.
    Report,
}

/// Why there is no truth.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TruthError {
    /// A scene whose caustic has no closed-form optics here (why in the message).
    #[error("no ground truth for this scene: {0}")]
    Unsupported(String),
    /// A grid with no cells, too many, or a non-finite or empty extent.
    #[error("unusable floor grid {0}: needs positive extents, 1 to 2^26 cells and finite values")]
    BadGrid(String),
    /// A grid that is not in the scene's floor plane.
    #[error("the grid lies at z = {grid}, the scene's floor at z = {floor}")]
    WrongPlane {
        /// The grid's z, metres.
        grid: f64,
        /// The floor's z, metres.
        floor: f64,
    },
}

/// Integration effort: parameter quads per side, subdivision depth, wavelengths.
struct Effort {
    n: usize,
    depth: u32,
    wavelengths: usize,
}

fn effort(setup: &Setup, q: Quality) -> Effort {
    match (&setup.optic, q) {
        // The prism's map is affine per wavelength: few triangles, many wavelengths.
        (Optic::Facets { .. }, Quality::Test) => Effort { n: 4, depth: 6, wavelengths: 48 },
        (Optic::Facets { .. }, Quality::Report) => Effort { n: 4, depth: 6, wavelengths: 400 },
        (_, Quality::Test) => Effort { n: 128, depth: 4, wavelengths: 16 },
        (_, Quality::Report) => Effort { n: 512, depth: 4, wavelengths: 200 },
    }
}

/// The wavelengths (nm) of the quadrature and their weights: the midpoint rule over the
/// tracer's uniform distribution on [`WAVELENGTH_RANGE_NM`]; one unweighted pass without
/// dispersion.
fn wavelengths(setup: &Setup, n: usize) -> Vec<(Option<f64>, f64)> {
    if !setup.dispersive() {
        return vec![(None, 1.0)];
    }
    let (lo, hi) = (WAVELENGTH_RANGE_NM.0 as f64, WAVELENGTH_RANGE_NM.1 as f64);
    (0..n).map(|k| (Some(lo + (hi - lo) * (k as f64 + 0.5) / n as f64), 1.0 / n as f64)).collect()
}

/// The sample scenes with a known truth, recognised from the scene's contents (not its name):
/// a dielectric sphere above a floor under a collimated beam; a dielectric height field (the
/// tracer's triangulated one, with its interpolated normals) under a collimated beam; a
/// flat-faceted dielectric solid of at most 64 triangles (the prism) under a collimated beam; a
/// mirror cylinder on the floor under a collimated beam. There must be exactly one collimated
/// emitter, one diffuse horizontal floor and one specular object.
/// `Err(TruthError::Unsupported(why))` for anything else.
pub fn floor_truth(scene: &Scene, grid: &FloorGrid, quality: Quality) -> Result<FloorTruth, TruthError> {
    floor_truth_scaled(scene, grid, quality, 1)
}

/// [`floor_truth`] with `scale` times the quality's parameter quads per side and wavelengths
/// (for convergence checks: `benches/truth.rs`).
#[doc(hidden)]
pub fn floor_truth_scaled(
    scene: &Scene,
    grid: &FloorGrid,
    quality: Quality,
    scale: usize,
) -> Result<FloorTruth, TruthError> {
    grid.check()?;
    let setup = Setup::from_scene(scene)?;
    if (setup.floor.z - grid.z).abs() > 1e-6 * (1.0 + grid.z.abs()) {
        return Err(TruthError::WrongPlane { grid: grid.z, floor: setup.floor.z });
    }
    let mut e = effort(&setup, quality);
    e.n *= scale.max(1);
    e.wavelengths *= scale.max(1);
    let mut acc = Accumulator::new(grid);
    let lambdas = wavelengths(&setup, e.wavelengths);
    for &(l, w) in &lambdas {
        acc.splat([e.n, e.n], e.depth, setup.beam.power_w * w, &|u, v| setup.land(u, v, l));
    }
    let area = grid.cell_area();
    let irradiance = acc.flux.iter().map(|f| f.map(|x| x / area)).collect();
    let overlap = acc
        .by_sign
        .iter()
        .map(|&[a, b]| {
            let t = a + b;
            t > 0.0 && a >= 0.1 * t && b >= 0.1 * t
        })
        .collect();
    let method = format!(
        "{}: the beam's parameter square in {n}×{n} quads of two triangles, carried through the \
         optics in f64 (refraction only, expected Fresnel transmittance; or mirror reflections) \
         and splatted onto the cells by exact polygon clipping of each image triangle \
         (piecewise-linear map), subdivided up to {d} times where the path changes or an image \
         spans over 64 cells: {t} triangles, {p} midpoint deposits{w}",
        setup.kind(),
        n = e.n,
        d = e.depth,
        t = acc.triangles,
        p = acc.points,
        w = if lambdas.len() > 1 {
            format!(
                "; {} wavelengths (midpoint rule, uniform on 380–720 nm, RGB weights as the tracer)",
                lambdas.len()
            )
        } else {
            String::new()
        }
    );
    Ok(FloorTruth { grid: *grid, irradiance, bounces: acc.bounces.into_iter().collect(), overlap, method })
}

/// A default floor grid for the scene: the rectangle that holds the caustic (the flux-weighted
/// 0.2 % to 99.8 % range of landing x and y, padded by 5 % and kept on the floor), cut into
/// `cells_x` columns of square cells.
pub fn default_grid(scene: &Scene, cells_x: usize) -> Result<FloorGrid, TruthError> {
    let setup = Setup::from_scene(scene)?;
    if cells_x == 0 {
        return Err(TruthError::BadGrid("no columns".into()));
    }
    let n = 160;
    let mut pts: Vec<([f64; 2], f64)> = Vec::new();
    for (l, w) in wavelengths(&setup, 9) {
        for j in 0..n {
            for i in 0..n {
                let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                if let Some(x) = setup.land(u, v, l) {
                    pts.push((x.xy, w * x.weight.iter().sum::<f64>()));
                }
            }
        }
    }
    if pts.is_empty() {
        return Err(TruthError::Unsupported("no light reaches the floor by a specular path".into()));
    }
    let range = |axis: usize| {
        let mut v: Vec<(f64, f64)> = pts.iter().map(|(p, w)| (p[axis], *w)).collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = v.iter().map(|x| x.1).sum();
        let (mut acc, mut lo, mut hi) = (0.0, v[0].0, v[v.len() - 1].0);
        let mut lo_set = false;
        for &(x, w) in &v {
            acc += w;
            if !lo_set && acc >= 0.002 * total {
                lo = x;
                lo_set = true;
            }
            if acc >= 0.998 * total {
                hi = x;
                break;
            }
        }
        let pad = 0.05 * (hi - lo).max(1e-3);
        (lo - pad, hi + pad)
    };
    let (mut x0, mut x1) = range(0);
    let (mut y0, mut y1) = range(1);
    if let Some([fx0, fy0, fx1, fy1]) = setup.floor.bounds() {
        (x0, x1, y0, y1) = (x0.max(fx0), x1.min(fx1), y0.max(fy0), y1.min(fy1));
    }
    let cell = (x1 - x0) / cells_x as f64;
    let rows = ((y1 - y0) / cell).ceil().max(1.0) as usize;
    let mid = 0.5 * (y0 + y1);
    let half = 0.5 * rows as f64 * cell;
    Ok(FloorGrid { min: [x0, mid - half], max: [x1, mid + half], cells: [cells_x, rows], z: setup.floor.z })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;
    use std::path::Path;

    fn sample(name: &str) -> Scene {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes").join(name);
        Scene::load(&p).unwrap()
    }

    fn parse(src: &str) -> Scene {
        Scene::parse(src, "test.toml", Path::new(".")).unwrap()
    }

    fn sum(e: &[f64; 3]) -> f64 {
        e[0] + e[1] + e[2]
    }

    #[test]
    fn cosine_and_angle_forms_of_fresnel_agree() {
        for k in 1..89 {
            let ti = (k as f64).to_radians();
            let tt = (ti.sin() / 1.33).asin();
            assert!((optics::fresnel(ti.cos(), 1.0 / 1.33) - fresnel_reflectance(ti, tt)).abs() < 1e-12);
            // Leaving the glass below the critical angle: the same pair of angles, reversed.
            assert!((optics::fresnel(tt.cos(), 1.33) - fresnel_reflectance(tt, ti)).abs() < 1e-12);
        }
    }

    /// Flat water (no waves): every ray refracts at normal incidence, so the floor under the
    /// beam is lit uniformly with E0·(1 − ((n − 1)/(n + 1))²), a third per channel.
    #[test]
    fn flat_water_gives_the_uniform_transmitted_beam() {
        let scene = parse(
            r#"
[materials.floor]
kind = "diffuse"
[materials.water]
kind = "dielectric"
ior = 1.33
[[emitters]]
kind = "collimated"
center = [0.0, 0.0, 1.0]
size = [1.0, 1.0]
direction = [0.0, 0.0, -1.0]
power_w = 10.0
[[shapes]]
kind = "rectangle"
origin = [-1.0, -1.0, 0.0]
edge_u = [2.0, 0.0, 0.0]
edge_v = [0.0, 2.0, 0.0]
material = "floor"
[[shapes]]
kind = "height_field"
size = [1.2, 1.2]
cells = [12, 12]
height = 0.3
material = "water"
"#,
        );
        let grid = FloorGrid { min: [-0.6, -0.6], max: [0.6, 0.6], cells: [24, 24], z: 0.0 };
        let t = floor_truth(&scene, &grid, Quality::Test).unwrap();
        let want = 10.0 * (1.0 - (0.33f64 / 2.33).powi(2)) / 3.0;
        for r in 0..24 {
            for c in 0..24 {
                let e = t.irradiance[r * 24 + c];
                // The beam covers [−0.5, 0.5]²: cells 2..22 in each direction.
                let inside = (2..22).contains(&r) && (2..22).contains(&c);
                for ch in e {
                    let w = if inside { want } else { 0.0 };
                    assert!((ch - w).abs() < 1e-6 * want, "cell ({c}, {r}): {ch} vs {w}");
                }
            }
        }
        assert_eq!(t.bounces, vec![1]);
        assert!(!t.overlap.contains(&true));
    }

    /// The 2-D truth of the default scene against the 1-D radial quadrature: every cell's
    /// average of the radial irradiance (sampled 20 × 20 per cell from 0.5 mm annuli) away from
    /// the central spike, and the total flux on the floor against the radial integral with
    /// the exact share of each landing circle that lies on the 4 m × 4 m floor.
    #[test]
    fn sphere_grid_agrees_with_the_radial_quadrature_and_conserves_flux() {
        let scene = sample("glass-sphere.toml");
        let s =
            SphereCaustic { radius: 0.5, centre_height: 0.8, ior: 1.5, beam_irradiance: 10.0, fresnel: true };
        let grid = FloorGrid { min: [-0.4, -0.4], max: [0.4, 0.4], cells: [32, 32], z: 0.0 };
        let t = floor_truth(&scene, &grid, Quality::Test).unwrap();
        assert_eq!(t.bounces, vec![2]);
        let edges: Vec<f64> = (0..=1200).map(|i| i as f64 * 0.0005).collect();
        let radial = s.radial(&edges, 400_000);
        let (mut checked, mut worst) = (0, 0.0f64);
        for r in 0..32 {
            for c in 0..32 {
                let [x, y] = grid.centre(c, r);
                if x.hypot(y) < 0.1 || x.hypot(y) > 0.35 {
                    continue;
                }
                let mut e = 0.0;
                for k in 0..400 {
                    let px = x + ((k % 20) as f64 + 0.5) / 20.0 * 0.025 - 0.0125;
                    let py = y + ((k / 20) as f64 + 0.5) / 20.0 * 0.025 - 0.0125;
                    e += radial[(px.hypot(py) / 0.0005) as usize] / 400.0;
                }
                let rel = sum(&t.irradiance[r * 32 + c]) / e - 1.0;
                worst = worst.max(rel.abs());
                checked += 1;
            }
        }
        println!("{checked} cells, worst {worst}");
        assert!(checked > 200 && worst < 0.02, "{checked} cells, worst relative difference {worst}");

        let floor = FloorGrid { min: [-2.0, -2.0], max: [2.0, 2.0], cells: [64, 64], z: 0.0 };
        let t = floor_truth(&scene, &floor, Quality::Test).unwrap();
        let total: f64 = t.irradiance.iter().map(sum).sum::<f64>() * floor.cell_area();
        // Share of the circle of radius ρ inside the square |x|, |y| ≤ 2.
        let on_floor = |rho: f64| match rho {
            r if r <= 2.0 => 1.0,
            r if r < 2.0 * 2f64.sqrt() => 1.0 - 4.0 / PI * (2.0 / r).acos(),
            _ => 0.0,
        };
        let n = 400_000;
        let db = 0.5 / n as f64;
        let want: f64 = (0..n)
            .filter_map(|k| {
                let b = (k as f64 + 0.5) * db;
                s.landing(b).map(|(rho, tr)| 10.0 * tr * 2.0 * PI * b * db * on_floor(rho.abs()))
            })
            .sum();
        assert!((total / want - 1.0).abs() < 2e-3, "{total} W on the floor, radial quadrature {want} W");
    }

    /// The prism with a fixed index 1.7 (no dispersion): every ray turns by the same angles,
    /// so the band on the floor is one rectangle of constant irradiance. Its edges and level
    /// follow from Snell's law in angle form applied by hand to the beam's two edge rays
    /// (directions as angles in the x–z plane from +x).
    #[test]
    fn prism_band_edges_follow_snells_law_by_hand() {
        let src =
            std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes/prism.toml"))
                .unwrap();
        let start = src.find("sellmeier").unwrap();
        let end = start + src[start..].find('\n').unwrap();
        let scene = parse(&src.replace(&src[start..end], "ior = 1.7"));
        let n = 1.7f64;
        let d = [0.837f64, 0.547];
        let alpha = d[1].atan2(d[0]);
        // The faces' normals from the outline (its apex 0.8598 makes the faces 59.9998°, not
        // 60°: the difference moves the band by 0.2 mm).
        let in_left = 0.2598f64.atan2(0.15) - PI / 2.0; // inward normal of the left face, ≈ −30°
        let out_right = 0.2598f64.atan2(-0.15) - PI / 2.0; // outward normal of the right face, ≈ 30°
        let ti1 = alpha - in_left;
        let tt1 = (ti1.sin() / n).asin();
        let beta = in_left + tt1;
        let ti2 = beta - out_right;
        let tt2 = (n * ti2.sin()).asin();
        let gamma = out_right + tt2;
        assert!(gamma < 0.0, "the ray leaves downward");
        let trans = (1.0 - fresnel_reflectance(ti1, tt1)) * (1.0 - fresnel_reflectance(ti2, tt2));
        // Where the line p + s·(cos a, sin a) meets the segment a0–a1.
        let meet = |p: [f64; 2], a: f64, a0: [f64; 2], a1: [f64; 2]| {
            let (dx, dz) = (a.cos(), a.sin());
            let (ex, ez) = (a1[0] - a0[0], a1[1] - a0[1]);
            let den = dx * ez - dz * ex;
            let s = ((a0[0] - p[0]) * ez - (a0[1] - p[1]) * ex) / den;
            let u = ((a0[0] - p[0]) * dz - (a0[1] - p[1]) * dx) / den;
            assert!((0.0..=1.0).contains(&u), "misses the face");
            [p[0] + s * dx, p[1] + s * dz]
        };
        let (left, right) = (([-0.15, 0.6], [0.0, 0.8598]), ([0.15, 0.6], [0.0, 0.8598]));
        let norm = d[0].hypot(d[1]);
        // Across the beam (side +1 is up-left); the beam spans ±0.06 m about its centre, but
        // its upper part passes above the apex: only s ≤ s_apex meets the left face.
        let across = [-d[1] / norm, d[0] / norm];
        let centre = [-0.546, 0.456];
        let apex = [0.0, 0.8598];
        let s_apex = (apex[0] - centre[0]) * across[0] + (apex[1] - centre[1]) * across[1];
        assert!(s_apex > -0.06 && s_apex < 0.06);
        let floor_x = |r: [f64; 2]| r[0] - r[1] / gamma.tan();
        let lower = [centre[0] - 0.06 * across[0], centre[1] - 0.06 * across[1]];
        let q = meet(lower, alpha, left.0, left.1);
        let a = floor_x(meet(q, beta, right.0, right.1));
        let b = floor_x(apex); // the ray through the apex enters and leaves there
        let (x0, x1) = (a.min(b), a.max(b));
        let power = 10.0 * (s_apex + 0.06) / 0.12;
        let want = power * trans / ((x1 - x0) * 0.4) / 3.0;
        let cells = 200;
        let grid = FloorGrid { min: [x0 - 0.05, -0.3], max: [x1 + 0.05, 0.3], cells: [cells, 12], z: 0.0 };
        let t = floor_truth(&scene, &grid, Quality::Test).unwrap();
        assert_eq!(t.bounces, vec![2]);
        let w = grid.cell_size()[0];
        for r in 0..12 {
            // Rows of 5 cm: the beam's y ∈ [−0.2, 0.2] covers rows 2..10 exactly.
            let lit_row = (2..10).contains(&r);
            for c in 0..cells {
                let xl = grid.min[0] + c as f64 * w;
                let cover = ((x1.min(xl + w) - x0.max(xl)) / w).clamp(0.0, 1.0);
                let expect = if lit_row { want * cover } else { 0.0 };
                let got = t.irradiance[r * cells + c];
                // The apex edge is resolved by subdivision (rays above it miss): its cell to a
                // tenth of a cell; the other edge to a micrometre (the scene's f32 vertices);
                // everywhere else to rounding.
                let tol = if (xl - x1).abs() < 2.0 * w {
                    0.1
                } else if (xl - x0).abs() < 2.0 * w {
                    2e-3
                } else {
                    1e-6
                };
                for ch in got {
                    assert!((ch - expect).abs() < tol * want, "cell ({c}, {r}): {ch} vs {expect}");
                }
            }
        }
    }

    /// The ring: for parallel light in the plane of a circular mirror of radius R the caustic
    /// is a nephroid with its cusp R/2 from the centre. At 30° elevation a wall reflection keeps
    /// the vertical component, so each reflected ray's horizontal projection is the 2-D one:
    /// rays of one horizontal offset fill a vertical plane, and neighbouring planes meet on the
    /// vertical line over the 2-D caustic; the floor caustic is the nephroid itself, cusp at
    /// (−R/2, 0) (light from +x). It is reached: the paraxial ray crosses the focal line at
    /// floor level after meeting the far wall (R/2)·tan 30° = 0.289 m high, below the 0.5 m rim.
    /// Checked on the forward map: the floor landings of once-reflected rays of one small
    /// offset y = ε lie on a line that crosses the axis at −R/2 + O(ε²).
    #[test]
    fn ring_caustic_has_its_cusp_half_a_radius_from_the_centre() {
        let scene = sample("ring.toml");
        let setup = optics::Setup::from_scene(&scene).unwrap();
        // The beam's u runs along +y over 2.4 m; v up its face.
        for eps in [1e-3, -2e-3] {
            let u = 0.5 + eps / 2.4;
            let hits: Vec<[f64; 2]> = (0..100)
                .filter_map(|k| setup.land(u, k as f64 / 100.0, None))
                .filter(|l| l.bounces == 1 && l.xy[0] < 0.0)
                .map(|l| l.xy)
                .collect();
            assert!(hits.len() > 10, "{} once-reflected rays", hits.len());
            let (p, q) = (hits[0], hits[hits.len() - 1]);
            let x_axis = p[0] - p[1] * (q[0] - p[0]) / (q[1] - p[1]);
            assert!((x_axis + 0.5).abs() < 1e-5, "ε = {eps}: crosses the axis at {x_axis}");
            // One vertical plane: every landing on that line.
            for h in &hits {
                let off = (h[0] - p[0]) * (q[1] - p[1]) - (h[1] - p[1]) * (q[0] - p[0]);
                assert!(off.abs() < 1e-12, "{h:?}");
            }
        }
        let grid = FloorGrid { min: [-0.95, -0.0125], max: [-0.05, 0.0125], cells: [72, 1], z: 0.0 };
        let t = floor_truth(&scene, &grid, Quality::Test).unwrap();
        // Between the cusp and the wall two sheets of once-reflected light overlap (the fold's
        // two sides); between the centre and the cusp there is one.
        let at = |x: f64| grid.cell_of(x, 0.0).unwrap().0;
        assert!(t.overlap[at(-0.75)], "{:?}", t.overlap);
        assert!(!t.overlap[at(-0.3)]);
        assert_eq!(t.bounces.first(), Some(&1));
    }
}
