//! Exact cell averages of a piecewise-linear forward map: the emitter's parameter square is cut
//! into triangles, each triangle's corners are carried to the floor by the optics, and the
//! triangle's flux is spread uniformly over its image triangle and shared among the grid cells
//! by exact polygon clipping. Where the map is affine (flat facets, a prism) this is exact;
//! elsewhere the error is that of linear interpolation, O(h²) in the parameter spacing h.
//!
//! Triangles whose corners take different optical paths (another facet sequence, or a corner
//! that misses) are subdivided, as are triangles stretched over many cells; at the depth limit
//! the flux goes to the cell of the triangle's centroid image (the midpoint rule).

use std::collections::BTreeSet;

use super::FloorGrid;

/// Where one ray of the beam lands on the floor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Landing {
    /// Floor point (x, y), metres.
    pub xy: [f64; 2],
    /// Fraction of the emitted flux arriving, per RGB channel (colour share, Fresnel
    /// transmittances, reflectances, wavelength weight).
    pub weight: [f64; 3],
    /// The optical path taken (the sequence of faces or sides met), for telling sheets apart.
    pub class: u64,
    /// Specular bounces before the floor (the tracer's BOUNCES).
    pub bounces: u8,
}

/// Image triangles covering more cells than this are subdivided (while depth remains).
const REFINE_CELLS: f64 = 64.0;

/// Flux per cell, split by the orientation of the map (sign of det X′).
pub(crate) struct Accumulator<'g> {
    pub grid: &'g FloorGrid,
    /// W per RGB channel per cell, row-major.
    pub flux: Vec<[f64; 3]>,
    /// Flux (sum over channels) per cell from orientation-preserving and -reversing pieces.
    pub by_sign: Vec<[f64; 2]>,
    /// Flux that landed anywhere on the floor (on or off the grid), W summed over channels.
    pub landed: f64,
    pub bounces: BTreeSet<u8>,
    /// Parameter triangles splatted and midpoint deposits made.
    pub triangles: u64,
    pub points: u64,
    cell: [f64; 2],
}

impl<'g> Accumulator<'g> {
    pub fn new(grid: &'g FloorGrid) -> Self {
        let n = grid.cells[0] * grid.cells[1];
        Accumulator {
            grid,
            flux: vec![[0.0; 3]; n],
            by_sign: vec![[0.0; 2]; n],
            landed: 0.0,
            bounces: BTreeSet::new(),
            triangles: 0,
            points: 0,
            cell: grid.cell_size(),
        }
    }

    /// Splats the map over the parameter square [0, 1]², cut into `n[0] × n[1]` quads of two
    /// triangles, with `power` watts per unit parameter area and up to `depth` subdivisions.
    pub fn splat(
        &mut self,
        n: [usize; 2],
        depth: u32,
        power: f64,
        map: &dyn Fn(f64, f64) -> Option<Landing>,
    ) {
        let [nu, nv] = n;
        let at = |i: usize, j: usize| [i as f64 / nu as f64, j as f64 / nv as f64];
        let row = |j: usize| (0..=nu).map(|i| map(at(i, j)[0], at(i, j)[1])).collect::<Vec<_>>();
        let mut lo = row(0);
        for j in 0..nv {
            let hi = row(j + 1);
            for i in 0..nu {
                let (q00, q10, q01, q11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
                self.triangle(map, [q00, q10, q11], [lo[i], lo[i + 1], hi[i + 1]], depth, power);
                self.triangle(map, [q00, q11, q01], [lo[i], hi[i + 1], hi[i]], depth, power);
            }
            lo = hi;
        }
    }

    fn triangle(
        &mut self,
        map: &dyn Fn(f64, f64) -> Option<Landing>,
        q: [[f64; 2]; 3],
        l: [Option<Landing>; 3],
        depth: u32,
        power: f64,
    ) {
        let param_area = 0.5 * cross(sub(q[1], q[0]), sub(q[2], q[0]));
        let same = match l {
            [Some(a), Some(b), Some(c)] => {
                (a.class == b.class && b.class == c.class && a.bounces == b.bounces && b.bounces == c.bounces)
                    .then_some([a, b, c])
            }
            _ => None,
        };
        if let Some(ls) = same {
            let p = ls.map(|x| x.xy);
            let (w, h) = self.extent_cells(&p);
            if depth == 0 || (w * h <= REFINE_CELLS && self.nearly_linear(map, q, &p)) {
                let mut f = [0.0; 3];
                for x in &ls {
                    for (fc, wc) in f.iter_mut().zip(x.weight) {
                        *fc += wc / 3.0;
                    }
                }
                let f = f.map(|x| x * power * param_area.abs());
                let image = 0.5 * cross(sub(p[1], p[0]), sub(p[2], p[0]));
                let sign = usize::from(image * param_area < 0.0);
                self.bounces.insert(ls[0].bounces);
                self.triangles += 1;
                self.deposit_triangle(p, f, sign);
                return;
            }
        } else if l.iter().all(Option::is_none) && depth == 0 {
            return;
        }
        if depth == 0 {
            let c = [(q[0][0] + q[1][0] + q[2][0]) / 3.0, (q[0][1] + q[1][1] + q[2][1]) / 3.0];
            if let Some(x) = map(c[0], c[1]) {
                let f = x.weight.map(|w| w * power * param_area.abs());
                self.bounces.insert(x.bounces);
                self.points += 1;
                self.deposit_point(x.xy, f, None);
            }
            return;
        }
        let mid = |a: [f64; 2], b: [f64; 2]| [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
        let (m01, m12, m20) = (mid(q[0], q[1]), mid(q[1], q[2]), mid(q[2], q[0]));
        let (l01, l12, l20) = (map(m01[0], m01[1]), map(m12[0], m12[1]), map(m20[0], m20[1]));
        self.triangle(map, [q[0], m01, m20], [l[0], l01, l20], depth - 1, power);
        self.triangle(map, [m01, q[1], m12], [l01, l[1], l12], depth - 1, power);
        self.triangle(map, [m20, m12, q[2]], [l20, l12, l[2]], depth - 1, power);
        self.triangle(map, [m01, m12, m20], [l01, l12, l20], depth - 1, power);
    }

    /// Whether the map carries the parameter triangle's centroid within a hundredth of a cell of
    /// its image triangle's centroid (else the linear interpolation is refined). Triangles
    /// inside one cell need no check: the cell gets their flux either way.
    fn nearly_linear(
        &self,
        map: &dyn Fn(f64, f64) -> Option<Landing>,
        q: [[f64; 2]; 3],
        p: &[[f64; 2]; 3],
    ) -> bool {
        let (w, h) = self.extent_cells(p);
        if w < 0.5 && h < 0.5 {
            return true;
        }
        let c = [(q[0][0] + q[1][0] + q[2][0]) / 3.0, (q[0][1] + q[1][1] + q[2][1]) / 3.0];
        let Some(x) = map(c[0], c[1]) else { return false };
        let lin = [(p[0][0] + p[1][0] + p[2][0]) / 3.0, (p[0][1] + p[1][1] + p[2][1]) / 3.0];
        ((x.xy[0] - lin[0]) / self.cell[0]).abs() < 0.01 && ((x.xy[1] - lin[1]) / self.cell[1]).abs() < 0.01
    }

    /// Width and height of a triangle's bounding box in cells.
    fn extent_cells(&self, p: &[[f64; 2]; 3]) -> (f64, f64) {
        let (x0, x1, y0, y1) = bbox(p);
        ((x1 - x0) / self.cell[0], (y1 - y0) / self.cell[1])
    }

    fn cell_of(&self, xy: [f64; 2]) -> Option<usize> {
        let g = self.grid;
        let c = ((xy[0] - g.min[0]) / self.cell[0]).floor();
        let r = ((g.max[1] - xy[1]) / self.cell[1]).floor();
        (c >= 0.0 && r >= 0.0 && (c as usize) < g.cells[0] && (r as usize) < g.cells[1])
            .then(|| r as usize * g.cells[0] + c as usize)
    }

    fn add(&mut self, k: usize, f: [f64; 3], share: f64, sign: Option<usize>) {
        for (fc, x) in self.flux[k].iter_mut().zip(f) {
            *fc += x * share;
        }
        if let Some(s) = sign {
            self.by_sign[k][s] += (f[0] + f[1] + f[2]) * share;
        }
    }

    fn deposit_point(&mut self, xy: [f64; 2], f: [f64; 3], sign: Option<usize>) {
        self.landed += f[0] + f[1] + f[2];
        if let Some(k) = self.cell_of(xy) {
            self.add(k, f, 1.0, sign);
        }
    }

    /// Spreads flux `f` uniformly over the triangle `p` and adds each cell's share, the area
    /// of the triangle clipped to the cell over the triangle's area.
    fn deposit_triangle(&mut self, p: [[f64; 2]; 3], f: [f64; 3], sign: usize) {
        let area = 0.5 * cross(sub(p[1], p[0]), sub(p[2], p[0])).abs();
        let cell_area = self.cell[0] * self.cell[1];
        let centroid = [(p[0][0] + p[1][0] + p[2][0]) / 3.0, (p[0][1] + p[1][1] + p[2][1]) / 3.0];
        if area <= 1e-12 * cell_area {
            self.deposit_point(centroid, f, Some(sign));
            return;
        }
        self.landed += f[0] + f[1] + f[2];
        let g = *self.grid;
        let (x0, x1, y0, y1) = bbox(&p);
        let c0 = ((x0 - g.min[0]) / self.cell[0]).floor().max(0.0);
        let c1 = ((x1 - g.min[0]) / self.cell[0]).floor().min(g.cells[0] as f64 - 1.0);
        let r0 = ((g.max[1] - y1) / self.cell[1]).floor().max(0.0);
        let r1 = ((g.max[1] - y0) / self.cell[1]).floor().min(g.cells[1] as f64 - 1.0);
        if c0 > c1 || r0 > r1 {
            return;
        }
        let (c0, c1, r0, r1) = (c0 as usize, c1 as usize, r0 as usize, r1 as usize);
        if c0 == c1 && r0 == r1 && self.cell_of([x0, y0]).is_some() && self.cell_of([x1, y1]).is_some() {
            self.add(r0 * g.cells[0] + c0, f, 1.0, Some(sign));
            return;
        }
        let mut poly = Vec::with_capacity(8);
        let mut tmp = Vec::with_capacity(8);
        for r in r0..=r1 {
            let ytop = g.max[1] - r as f64 * self.cell[1];
            let ybot = ytop - self.cell[1];
            for c in c0..=c1 {
                let xl = g.min[0] + c as f64 * self.cell[0];
                let xr = xl + self.cell[0];
                poly.clear();
                poly.extend_from_slice(&p);
                clip(&mut poly, &mut tmp, |q| q[0] - xl);
                clip(&mut poly, &mut tmp, |q| xr - q[0]);
                clip(&mut poly, &mut tmp, |q| q[1] - ybot);
                clip(&mut poly, &mut tmp, |q| ytop - q[1]);
                let a = polygon_area(&poly);
                if a > 0.0 {
                    self.add(r * g.cells[0] + c, f, a / area, Some(sign));
                }
            }
        }
    }
}

/// Sutherland–Hodgman: keeps the part of `poly` where `inside(q) ≥ 0` (a half-plane).
fn clip(poly: &mut Vec<[f64; 2]>, tmp: &mut Vec<[f64; 2]>, inside: impl Fn([f64; 2]) -> f64) {
    tmp.clear();
    let n = poly.len();
    for k in 0..n {
        let (a, b) = (poly[k], poly[(k + 1) % n]);
        let (da, db) = (inside(a), inside(b));
        if da >= 0.0 {
            tmp.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            let t = da / (da - db);
            tmp.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
        }
    }
    std::mem::swap(poly, tmp);
}

/// Unsigned area of a simple polygon (shoelace).
fn polygon_area(p: &[[f64; 2]]) -> f64 {
    if p.len() < 3 {
        return 0.0;
    }
    let mut s = 0.0;
    for k in 0..p.len() {
        let (a, b) = (p[k], p[(k + 1) % p.len()]);
        s += a[0] * b[1] - a[1] * b[0];
    }
    0.5 * s.abs()
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

fn bbox(p: &[[f64; 2]; 3]) -> (f64, f64, f64, f64) {
    let xs = p.map(|q| q[0]);
    let ys = p.map(|q| q[1]);
    let min = |v: [f64; 3]| v[0].min(v[1]).min(v[2]);
    let max = |v: [f64; 3]| v[0].max(v[1]).max(v[2]);
    (min(xs), max(xs), min(ys), max(ys))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> FloorGrid {
        FloorGrid { min: [-1.0, -1.0], max: [1.0, 1.0], cells: [8, 8], z: 0.0 }
    }

    #[test]
    fn clipping_shares_a_triangle_by_area() {
        // The right triangle (−1,−1), (1,−1), (1,1) covers half the grid: the cells below the
        // diagonal get all of a cell's worth, those on it half, those above none.
        let g = grid();
        let mut acc = Accumulator::new(&g);
        acc.deposit_triangle([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0]], [2.0, 0.0, 0.0], 0);
        let per_cell = 2.0 / 32.0;
        for r in 0..8 {
            for c in 0..8 {
                let want = match (7 - r).cmp(&c) {
                    std::cmp::Ordering::Less => per_cell,
                    std::cmp::Ordering::Equal => per_cell / 2.0,
                    std::cmp::Ordering::Greater => 0.0,
                };
                let got = acc.flux[r * 8 + c][0];
                assert!((got - want).abs() < 1e-12, "cell ({c}, row {r}): {got} vs {want}");
            }
        }
        assert!((acc.flux.iter().map(|f| f[0]).sum::<f64>() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn an_affine_map_gives_its_exact_image_density() {
        // (u, v) ↦ (0.3 + 0.5u − 0.2v, −0.4 + 0.6v): a parallelogram of area 0.3 receiving 1 W,
        // uniform 1/0.3 W/m²; cells wholly inside must hold exactly cell area × that.
        let g = FloorGrid { min: [0.0, -0.5], max: [1.0, 0.5], cells: [40, 40], z: 0.0 };
        let mut acc = Accumulator::new(&g);
        let map = |u: f64, v: f64| {
            Some(Landing {
                xy: [0.3 + 0.5 * u - 0.2 * v, -0.4 + 0.6 * v],
                weight: [1.0, 0.0, 0.0],
                class: 0,
                bounces: 1,
            })
        };
        acc.splat([3, 5], 4, 1.0, &map);
        let cell = 0.025 * 0.025;
        let total: f64 = acc.flux.iter().map(|f| f[0]).sum();
        assert!((total - 1.0).abs() < 1e-12, "{total}");
        // Cell (col 20, row 20): x ∈ [0.5, 0.525], y ∈ [−0.025, 0]: inside the parallelogram.
        assert!((acc.flux[20 * 40 + 20][0] - cell / 0.3).abs() < 1e-12);
        assert_eq!(acc.by_sign.iter().map(|s| s[1]).sum::<f64>(), 0.0);
    }
}
