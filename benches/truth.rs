//! Ground-truth cost and convergence (issue 7): `floor_truth` at `Quality::Report` on each
//! truth scene's default 256-column grid, its CPU time, and its difference from the same
//! integration with twice the parameter quads per side and twice the wavelengths.
//!
//! `cargo bench --bench truth`. Times are CPU seconds of this process (user + system,
//! /proc/self/stat): the integration is single-threaded, and other jobs sharing the machine
//! inflate wall-clock time but not this.

use std::path::Path;

use photonkit::eval::truth::{FloorTruth, Quality, default_grid, floor_truth_scaled};
use photonkit::scene::Scene;

fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit_once(')').map_or("", |x| x.1).split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn total(e: &[f64; 3]) -> f64 {
    e[0] + e[1] + e[2]
}

fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
    println!(
        "scene | cells | Report CPU s | 2× CPU s | L1 rel. diff | cells > 1 % off (of cells ≥ 1 % of max) | overlap cells"
    );
    for f in ["glass-sphere.toml", "water.toml", "prism.toml", "ring.toml"] {
        let scene = Scene::load(&dir.join(f)).expect("sample scene");
        let grid = default_grid(&scene, 256).expect("a truth scene");
        let t0 = cpu();
        let a: FloorTruth = floor_truth_scaled(&scene, &grid, Quality::Report, 1).expect("truth");
        let t1 = cpu();
        let b = floor_truth_scaled(&scene, &grid, Quality::Report, 2).expect("truth");
        let t2 = cpu();
        let l1: f64 =
            a.irradiance.iter().zip(&b.irradiance).map(|(x, y)| (total(x) - total(y)).abs()).sum::<f64>()
                / b.irradiance.iter().map(total).sum::<f64>();
        let max = b.irradiance.iter().map(total).fold(0.0, f64::max);
        let (mut big, mut off) = (0, 0);
        for (x, y) in a.irradiance.iter().zip(&b.irradiance) {
            if total(y) >= 0.01 * max {
                big += 1;
                if (total(x) / total(y) - 1.0).abs() > 0.01 {
                    off += 1;
                }
            }
        }
        let ov = a.overlap.iter().filter(|&&o| o).count();
        println!(
            "{f} | {}×{} | {:.2} | {:.2} | {l1:.2e} | {off} of {big} | {ov}",
            grid.cells[0],
            grid.cells[1],
            t1 - t0,
            t2 - t1
        );
    }
}
