//! What a comparison measures against: the [`Target`] view with its truth (closed-form floor
//! irradiance, or a long progressive run), and the top-down camera whose pixels are the
//! truth's floor cells.

use glam::Vec3;

use super::CompareError;
use crate::eval::metrics::{self, Region};
use crate::eval::reference::{Progressive, ReferenceOptions, ReferenceState};
use crate::eval::truth::{self, FloorGrid, Quality};
use crate::render::{Image, Kernel, Mode, RenderOptions, Supersample};
use crate::scene::{Camera, Projection, Scene};

/// What the images are measured against: a view, a mode and the truth's image in that view.
#[derive(Clone, Debug)]
pub struct Target {
    /// The view: its resolution is the images'.
    pub camera: Camera,
    /// What the images hold (irradiance for the closed-form floor truths).
    pub mode: Mode,
    /// The truth, row-major, `camera.resolution` pixels.
    pub truth: Vec<[f64; 3]>,
    /// The band around the truth's caustic edges ([`metrics::edge_band`]).
    pub edges: Vec<bool>,
    /// The region class of every pixel ([`metrics::regions`]).
    pub regions: Vec<Region>,
    /// Where filaments overlap, if the truth knows.
    pub overlap: Option<Vec<bool>>,
    /// Keep only photons with these bounce counts (the path families the truth accounts for).
    pub bounces: Option<Vec<u8>>,
    /// What the truth is, for the report.
    pub description: String,
    /// The floor grid whose cells are the pixels (closed-form truths).
    pub grid: Option<FloorGrid>,
}

/// Width of the edge band on each side of an edge, pixels.
pub const EDGE_BAND: usize = 2;

/// The orthographic top-down camera whose pixels are the cells of `grid`.
pub fn floor_camera(grid: &FloorGrid) -> Result<Camera, CompareError> {
    let (w, h) = (grid.max[0] - grid.min[0], grid.max[1] - grid.min[1]);
    let centre = Vec3::new(
        (0.5 * (grid.min[0] + grid.max[0])) as f32,
        (0.5 * (grid.min[1] + grid.max[1])) as f32,
        grid.z as f32,
    );
    let cells = [grid.cells[0] as u32, grid.cells[1] as u32];
    let square = (w / cells[0] as f64) / (h / cells[1] as f64);
    if !(w > 0.0 && h > 0.0 && (square - 1.0).abs() < 1e-3) {
        return Err(CompareError::Invalid(format!(
            "the floor grid {w} × {h} m in {} × {} cells does not have square cells",
            cells[0], cells[1]
        )));
    }
    let eye = centre + Vec3::Z * (10.0 * w.max(h)) as f32;
    Camera::look_at(Projection::Orthographic { height_m: h as f32 }, eye, centre, Vec3::Y, cells)
        .ok_or_else(|| CompareError::Invalid("degenerate floor camera".into()))
}

impl Target {
    /// The closed-form floor irradiance of a scene [`truth::floor_truth`] knows, on its default
    /// grid of `cells` columns.
    pub fn closed_form(scene: &Scene, cells: usize, quality: Quality) -> Result<Target, CompareError> {
        let grid = truth::default_grid(scene, cells)?;
        let t = truth::floor_truth(scene, &grid, quality)?;
        let camera = floor_camera(&t.grid)?;
        let (w, h) = (t.grid.cells[0], t.grid.cells[1]);
        let edges = metrics::edge_band(&t.irradiance, w, h, EDGE_BAND);
        Ok(Target {
            camera,
            mode: Mode::Irradiance,
            regions: metrics::regions(&t.irradiance, w, h, &edges),
            edges,
            overlap: Some(t.overlap),
            bounces: Some(t.bounces),
            description: format!("closed-form floor irradiance: {}", t.method),
            truth: t.irradiance,
            grid: Some(t.grid),
        })
    }

    /// A long progressive photon mapping run in `camera`'s view with `mode`, as the truth of a
    /// scene without a closed form: `passes` passes of `photons_per_pass`, seeds far from the
    /// compared runs'.
    pub fn progressive_reference(
        scene: &Scene,
        camera: Camera,
        mode: Mode,
        passes: u64,
        photons_per_pass: u64,
        spp: u32,
        progress: &dyn Fn(u64),
    ) -> Result<Target, CompareError> {
        let [w, h] = camera.resolution;
        let render =
            RenderOptions { width: w, height: h, spp, mode, seed: 0x5EED, ..RenderOptions::default() };
        let p = Progressive {
            scene,
            camera: camera.clone(),
            render,
            kernel: Kernel::Epanechnikov,
            bounces: None,
        };
        let options =
            ReferenceOptions { photons_per_pass, seed: 1_000_000_007, ..ReferenceOptions::default() };
        let mut state = ReferenceState::start(options, serde_json::Value::Null);
        let mut image = Image::new(w, h);
        p.run(&mut image, &mut state, passes, &mut |s, _| {
            progress(s.passes);
            Ok(true)
        })?;
        let truth = pixels(&image);
        let edges = metrics::edge_band(&truth, w as usize, h as usize, EDGE_BAND);
        Ok(Target {
            camera,
            mode,
            regions: metrics::regions(&truth, w as usize, h as usize, &edges),
            truth,
            edges,
            overlap: None,
            bounces: None,
            description: format!(
                "progressive photon mapping reference: {passes} passes of {photons_per_pass} photons"
            ),
            grid: None,
        })
    }

    /// Image width, pixels.
    pub fn width(&self) -> usize {
        self.camera.resolution[0] as usize
    }

    /// Image height, pixels.
    pub fn height(&self) -> usize {
        self.camera.resolution[1] as usize
    }

    /// The sampling plan of images measured against this truth: its core and edge pixels take
    /// `feature_spp` samples (when that is more than the image's own).
    pub fn supersample(&self, spp: u32, feature_spp: u32) -> Option<Supersample> {
        (feature_spp > spp).then(|| Supersample {
            spp: feature_spp,
            pixels: self.regions.iter().map(|r| matches!(r, Region::Core | Region::Edge)).collect(),
        })
    }
}

/// An image's pixels as f64 RGB.
pub fn pixels(img: &Image) -> Vec<[f64; 3]> {
    img.pixels.iter().map(|p| p.as_dvec3().to_array()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_floor_camera_looks_at_each_cells_centre_from_above() {
        let grid = FloorGrid { min: [-1.0, 0.5], max: [1.0, 1.5], cells: [40, 20], z: 0.25 };
        let cam = floor_camera(&grid).unwrap();
        for (col, row) in [(0usize, 0usize), (39, 0), (0, 19), (17, 11)] {
            let ray = cam.ray(col as f32 + 0.5, row as f32 + 0.5);
            assert!((ray.dir - Vec3::NEG_Z).length() < 1e-6);
            let t = (grid.z as f32 - ray.origin.z) / ray.dir.z;
            let hit = ray.origin + ray.dir * t;
            // Column 0 is the smallest x, row 0 the largest y; cells 0.05 m square.
            let want = (-1.0 + 0.05 * (col as f32 + 0.5), 1.5 - 0.05 * (row as f32 + 0.5));
            assert!((hit.x - want.0).abs() < 1e-5 && (hit.y - want.1).abs() < 1e-5, "{col},{row}: {hit}");
        }
        let bad = FloorGrid { cells: [40, 40], ..grid };
        assert!(floor_camera(&bad).is_err(), "cells must be square");
    }
}
