//! The reference renderer: progressive photon mapping, memoryless variant (Knaus & Zwicker
//! 2011).
//!
//! Pass i (i = 1, 2, …) traces a fresh caustic photon map (the tracer with seed `seed + i − 1`,
//! so every pass has its own rotation of the Halton sequence), renders an image with one
//! global gather radius r_i (every photon within r_i counts, [`Estimator::Radius`]), and the
//! image is the mean of the pass images. The radius shrinks as
//!
//! ```text
//!     r²_{i+1} = r²_i · (i + α) / (i + 1),     α = 2/3
//! ```
//!
//! so r²_i ∝ i^(α−1): bias and variance both vanish, and the error of the mean falls as
//! n^(−α/2) = n^(−1/3) with n passes for independent random photons (faster with the
//! low-discrepancy photons the tracer emits). The running mean and a small state record
//! (pass count, next radius, settings) are all a run needs to be resumed.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::render::image::{self, Notes};
use crate::render::{
    Estimator, Image, Kernel, Mode, Outputs, PhotonData, PhotonLookup, RenderError, RenderOptions, Renderer,
    View,
};
use crate::scene::{Camera, Scene};
use crate::spatial::{Neighbours, PointSet, Query, Space, SpatialIndex};
use crate::trace::{self, Budget, StorePolicy, TraceError, TraceOptions};

/// Everything that can go wrong in a reference run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// A pass could not be rendered, or the image written.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// A pass could not be traced.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// Settings out of range, or a first pass too sparse to choose r₁.
    #[error("{0}")]
    Invalid(String),
    /// The saved run to resume is missing, unreadable or saved with other settings.
    #[error("{file}: {message}")]
    Saved {
        /// The saved run's EXR.
        file: String,
        /// What is wrong with it.
        message: String,
    },
}

/// The paper's and Knaus & Zwicker's α.
pub const ALPHA: f64 = 2.0 / 3.0;

/// Settings of a progressive run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceOptions {
    /// Photons emitted per pass.
    pub photons_per_pass: u64,
    /// α of the radius schedule, in (0, 1) (the module docs).
    pub alpha: f64,
    /// r₁ in metres; `None` chooses it from the first pass's photons ([`initial_radius`]).
    pub initial_radius: Option<f32>,
    /// The tracer's base seed (pass i uses seed + i − 1).
    pub seed: u64,
    /// Specular bounces after which the tracer drops a photon ([`TraceOptions::max_bounces`]).
    pub max_bounces: u32,
    /// With `Some(k)`, the radius varies over the image with the photon density: at a point
    /// x, pass i gathers within r_i(x) = r_k(x) · r_i / r₁, r_k(x) the distance from x to the
    /// k-th nearest photon of the first pass ([`Estimator::LocalRadius`]; Hachisuka & Jensen
    /// advise k in the tens), so sparse regions are not left empty by a radius chosen where
    /// the photons crowd. `None`: one radius for the whole image.
    #[serde(default)]
    pub local_k: Option<usize>,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        ReferenceOptions {
            photons_per_pass: 1_000_000,
            alpha: ALPHA,
            initial_radius: None,
            seed: 1,
            max_bounces: 64,
            local_k: None,
        }
    }
}

/// Where a progressive run is: saved beside its image so it can be resumed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceState {
    /// Passes averaged into the image so far.
    pub passes: u64,
    /// r₁, metres (0 until the first pass has chosen it).
    pub initial_radius: f32,
    /// r² of the next pass, m².
    pub next_radius2: f64,
    /// The run's settings.
    pub options: ReferenceOptions,
    /// Free-form description of the image settings (scene, camera, size, mode) that a resumed
    /// run must match.
    pub settings: serde_json::Value,
}

impl ReferenceState {
    /// A run that has made no pass yet (r₁ is chosen by the first pass unless the options
    /// give it).
    pub fn start(options: ReferenceOptions, settings: serde_json::Value) -> ReferenceState {
        ReferenceState { passes: 0, initial_radius: 0.0, next_radius2: 0.0, options, settings }
    }
}

/// r² of pass `i` (1-based) from r₁²: r²_{i+1} = r²_i · (i + α)/(i + 1).
pub fn radius2(r1_2: f64, alpha: f64, i: u64) -> f64 {
    let mut r2 = r1_2;
    for j in 1..i {
        r2 *= (j as f64 + alpha) / (j as f64 + 1.0);
    }
    r2
}

/// The default r₁: the median over (up to 1000 evenly chosen) photons of the distance to their
/// 15th nearest neighbour: a k-NN estimate's radius at K = 15 where the photons are.
pub fn initial_radius(positions: &[[f32; 3]]) -> Option<f32> {
    if positions.len() < 16 {
        return None;
    }
    let index = SpatialIndex::build(&PointSet::world(positions), Space::World).ok()?;
    let step = (positions.len() / 1000).max(1);
    let mut out = Neighbours::default();
    let mut r: Vec<f32> = (0..positions.len())
        .step_by(step)
        .filter_map(|i| {
            let q = Query {
                position: positions[i],
                params: &[],
                radius: None,
                emitter: 0,
                exclude: Some(i as u32),
            };
            index.knn(&q, 15, &mut out);
            out.last().map(|n| n.dist2.sqrt())
        })
        .filter(|&d| d > 0.0)
        .collect();
    if r.is_empty() {
        return None;
    }
    let mid = r.len() / 2;
    Some(*r.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The EXR header attribute holding a progressive run's state (JSON).
pub const STATE_NOTE: &str = "photonkit:reference_state";

/// The settings a resumed run must share with the saved one: the scene file's CRC-32, the
/// camera, image size, samples, mode, kernel, eye-path options and seed.
pub fn settings(
    scene_content: &[u8],
    camera: &Camera,
    render: &RenderOptions,
    kernel: Kernel,
) -> serde_json::Value {
    serde_json::json!({
        "scene_crc32": crate::scene::scene_crc32(scene_content),
        "camera": format!("{:?}", camera),
        "width": render.width, "height": render.height, "spp": render.spp,
        "mode": render.mode.name(), "kernel": kernel.name(), "specular": format!("{:?}", render.eye.specular),
        "max_depth": render.eye.max_depth, "seed": render.seed,
    })
}

/// A run's image on disk: the running mean in an EXR whose header holds the run's state
/// ([`STATE_NOTE`]), so `--resume` continues it.
#[derive(Clone, Debug)]
pub struct SavedRun {
    /// The EXR (and the PNG preview, if any).
    pub outputs: Outputs,
    /// The render mode, for the header's units.
    pub mode: Mode,
    /// The gather kernel, for the header's description.
    pub kernel: Kernel,
    /// The scene's name for the header.
    pub scene_name: String,
}

/// Where [`SavedRun::resume`] leaves a run.
#[derive(Debug)]
pub enum Resumed {
    /// The saved image and state, to run on from.
    Continue(Image, ReferenceState),
    /// The saved run already holds this many passes (at least the number asked for).
    Done(u64),
}

impl SavedRun {
    fn exr(&self) -> Result<&Path, ReferenceError> {
        self.outputs
            .exr
            .as_deref()
            .ok_or_else(|| ReferenceError::Invalid("a saved run needs an EXR path".into()))
    }

    /// Reads the saved run for `until` passes in all, refusing one saved with other
    /// `settings` ([`settings`]) or other pass `options` (the initial radius may differ: the
    /// saved run's first pass chose it).
    pub fn resume(
        &self,
        settings: &serde_json::Value,
        options: &ReferenceOptions,
        until: u64,
    ) -> Result<Resumed, ReferenceError> {
        let path = self.exr()?;
        let saved = |message: String| ReferenceError::Saved { file: path.display().to_string(), message };
        let (image, notes) =
            image::read_exr(path).map_err(|e| saved(format!("reading the saved run: {e}")))?;
        let state = notes
            .iter()
            .find(|(k, _)| k == STATE_NOTE)
            .ok_or_else(|| saved("not saved by `photonkit reference` (no run state)".into()))?;
        let state: ReferenceState =
            serde_json::from_str(&state.1).map_err(|e| saved(format!("unreadable run state: {e}")))?;
        if state.settings != *settings {
            return Err(saved(format!(
                "saved with other settings ({}); resume with the same scene, camera, size, mode and kernel",
                state.settings
            )));
        }
        let same = ReferenceOptions { initial_radius: state.options.initial_radius, ..options.clone() };
        if state.options != same {
            return Err(saved(format!("saved with other pass options ({:?})", state.options)));
        }
        if state.passes >= until {
            return Ok(Resumed::Done(state.passes));
        }
        Ok(Resumed::Continue(image, state))
    }

    /// Writes the running mean with the run's state in its header.
    pub fn save(&self, state: &ReferenceState, image: &Image) -> Result<(), ReferenceError> {
        let json = serde_json::to_string(state).expect("the state serialises");
        let notes: Notes = vec![
            ("photonkit:units".to_string(), self.mode.unit().to_string()),
            ("photonkit:mode".to_string(), self.mode.name().to_string()),
            (
                "photonkit:estimator".to_string(),
                format!("progressive photon mapping, {} kernel, {} passes", self.kernel.name(), state.passes),
            ),
            ("photonkit:scene".to_string(), self.scene_name.clone()),
            (STATE_NOTE.to_string(), json),
        ];
        Ok(image::write(image, &self.outputs, &notes)?)
    }
}

/// A progressive photon mapping run over one scene and camera.
pub struct Progressive<'a> {
    /// The scene traced and seen.
    pub scene: &'a Scene,
    /// The camera (its resolution is replaced by the options').
    pub camera: Camera,
    /// Image options; the estimator's kernel is used with each pass's radius, `seed` is
    /// advanced per pass so the sub-pixel jitter differs.
    pub render: RenderOptions,
    /// The gather kernel of every pass.
    pub kernel: Kernel,
    /// Keep only the photons with these specular bounce counts (`None`: every caustic
    /// photon), as [`crate::trace::Traced::retain_bounces`].
    pub bounces: Option<&'a [u8]>,
}

impl Progressive<'_> {
    /// Runs passes until `state.passes` reaches `until`, averaging into `image` (which holds
    /// the mean of the passes so far). `after_pass(state, image)` is called after each pass
    /// (to save, report progress, or stop early by returning `Ok(false)`).
    pub fn run(
        &self,
        image: &mut Image,
        state: &mut ReferenceState,
        until: u64,
        after_pass: &mut dyn FnMut(&ReferenceState, &Image) -> Result<bool, ReferenceError>,
    ) -> Result<(), ReferenceError> {
        let o = &state.options.clone();
        if o.photons_per_pass == 0 {
            return Err(ReferenceError::Invalid("a pass needs at least one photon".into()));
        }
        if !(o.alpha > 0.0 && o.alpha < 1.0) {
            return Err(ReferenceError::Invalid(format!("α = {}: must lie in (0, 1)", o.alpha)));
        }
        if (image.width, image.height) != (self.render.width, self.render.height) {
            return Err(ReferenceError::Invalid(format!(
                "the running image is {}×{}, the options say {}×{}",
                image.width, image.height, self.render.width, self.render.height
            )));
        }
        let pass_photons = |i: u64| -> Result<_, ReferenceError> {
            let topts = TraceOptions {
                seed: o.seed.wrapping_add(i - 1),
                budget: Budget::Emitted(o.photons_per_pass),
                store: StorePolicy::Caustic,
                shard: None,
                max_bounces: o.max_bounces,
                spool: None,
            };
            let mut traced = trace::trace(self.scene, &topts, &|_, _| {})?;
            if let Some(keep) = self.bounces {
                traced.retain_bounces(keep)?;
            }
            Ok(traced.photons()?)
        };
        // The local radius's map: the first pass's photons (traced again on a resumed run).
        let mut radius_map: Option<crate::spatial::BoxTree> = match o.local_k {
            Some(_) if state.passes > 0 => Some(crate::spatial::BoxTree::build(&pass_photons(1)?.position)),
            _ => None,
        };
        while state.passes < until {
            let i = state.passes + 1;
            let photons = pass_photons(i)?;
            if o.local_k.is_some() && radius_map.is_none() {
                radius_map = Some(crate::spatial::BoxTree::build(&photons.position));
            }
            if state.initial_radius <= 0.0 {
                let r1 = match o.initial_radius {
                    Some(r) => r,
                    None => initial_radius(&photons.position).ok_or_else(|| {
                        ReferenceError::Invalid(
                            "the first pass stored too few photons to choose a radius: give one (--radius) or more \
                             photons per pass"
                                .into(),
                        )
                    })?,
                };
                state.initial_radius = r1;
                state.next_radius2 = (r1 as f64) * (r1 as f64);
            }
            let r = state.next_radius2.sqrt() as f32;
            let data = PhotonData {
                positions: &photons.position,
                flux: &photons.flux,
                normals: Some(&photons.normal),
            };
            let (lookup, estimator) = match (o.local_k, &radius_map) {
                (Some(k), Some(map)) => (
                    PhotonLookup::with_radius_map("<pass>", data, map)?,
                    Estimator::LocalRadius { k, scale: r / state.initial_radius, kernel: self.kernel },
                ),
                _ => (
                    PhotonLookup::for_radius("<pass>", data, r)?,
                    Estimator::Radius { radius: r, kernel: self.kernel },
                ),
            };
            let opts = RenderOptions {
                estimator,
                seed: self.render.seed.wrapping_add((i - 1).wrapping_mul(0x9E37_79B9)),
                // A pass is summed into the reference, not shown.
                keep_samples: false,
                ..self.render.clone()
            };
            let renderer = Renderer {
                view: View::Scene { scene: self.scene, camera: self.camera.clone() },
                photons: Some(&lookup),
                diagnostic: None,
                opts,
            };
            let (pass, _) = renderer.render(&|_| {})?;
            // Mean of i passes: m_i = m_{i−1} + (x_i − m_{i−1}) / i.
            let w = 1.0 / i as f32;
            for (m, x) in image.pixels.iter_mut().zip(&pass.pixels) {
                *m += (*x - *m) * w;
            }
            state.passes = i;
            state.next_radius2 *= (i as f64 + o.alpha) / (i as f64 + 1.0);
            if !after_pass(state, image)? {
                break;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use glam::Vec3;

    use super::*;
    use crate::render::{EyeOptions, Mode};
    use crate::scene::Projection;

    #[test]
    fn radius_sequence_follows_the_recurrence() {
        let r2 = radius2(1.0, ALPHA, 3);
        assert!((r2 - (1.0 + ALPHA) / 2.0 * (2.0 + ALPHA) / 3.0).abs() < 1e-12);
        // Asymptotically r²_i ∝ i^(α − 1): the ratio over a factor 10 in i is 10^(α − 1).
        let ratio = radius2(1.0, ALPHA, 100_000) / radius2(1.0, ALPHA, 10_000);
        assert!((ratio / 10f64.powf(ALPHA - 1.0) - 1.0).abs() < 1e-3, "{ratio}");
    }

    /// The trace module's test scene: a 1 m × 1 m collimated beam of 6 W straight down
    /// through an ideal glass slab onto the floor. Every photon crosses the slab unbent, so
    /// the floor's irradiance under the beam is uniform: 6 W / 1 m² / 3 = 2 W/m² per channel.
    fn slab_scene() -> Scene {
        Scene::parse(&crate::trace::tests::slab(true, 1.5), "slab.toml", Path::new(".")).unwrap()
    }

    #[test]
    fn reference_converges_on_uniform_irradiance() {
        // Irradiance over the central 0.6 m × 0.6 m (10 × 10 pixels, one sample each) seen
        // from above; the RMS relative error against 2 W/m² after n passes of N = 1000
        // photons (density ρ = 1000 /m², spacing ≈ 0.032 m).
        //
        // Closed form for independent random photons: one pass's Epanechnikov estimate has
        // relative variance ∫w² dA / ρ = 4/(3π ρ r²), and the mean of n passes has
        // RMS error sqrt(Σ_i 4/(3π ρ r_i²)) / n, which falls as n^(−α/2) = n^(−1/3). The
        // tracer's photons are a rotated Halton set per pass, which beats random photons while
        // the radius spans several photon spacings (there the error falls more slowly, towards
        // the random-photon curve from below); with r₁ at half the spacing, as here, each pass
        // is about as noisy as random photons and the closed form applies.
        let scene = slab_scene();
        let camera = Camera::look_at(
            Projection::Orthographic { height_m: 0.6 },
            Vec3::new(0.0, 0.0, 3.0),
            Vec3::ZERO,
            Vec3::Y,
            [10, 10],
        )
        .unwrap();
        let render = RenderOptions {
            width: 10,
            height: 10,
            spp: 1,
            mode: Mode::Irradiance,
            estimator: Estimator::DEFAULT,
            eye: EyeOptions::default(),
            seed: 0,
            keep_samples: false,
            supersample: None,
        };
        let p = Progressive { scene: &scene, camera, render, kernel: Kernel::Epanechnikov, bounces: None };
        let r1 = 0.015f64;
        let rho = 1000.0;
        let options = ReferenceOptions {
            photons_per_pass: 1000,
            initial_radius: Some(r1 as f32),
            ..ReferenceOptions::default()
        };
        let mut state = ReferenceState::start(options, serde_json::Value::Null);
        let mut image = Image::new(10, 10);
        let mut measured = Vec::new();
        let checkpoints = [4u64, 16, 64, 256];
        p.run(&mut image, &mut state, 256, &mut |s, img| {
            if checkpoints.contains(&s.passes) {
                let e2: f64 = img.pixels.iter().map(|v| (v.x as f64 / 2.0 - 1.0).powi(2)).sum::<f64>()
                    / img.pixels.len() as f64;
                measured.push(e2.sqrt());
            }
            Ok(true)
        })
        .unwrap();
        assert_eq!(state.passes, 256);
        assert!((state.next_radius2 / radius2(r1 * r1, ALPHA, 257) - 1.0).abs() < 1e-6);
        let predicted: Vec<f64> = checkpoints
            .iter()
            .map(|&n| {
                let var: f64 = (1..=n)
                    .map(|i| 4.0 / (3.0 * std::f64::consts::PI * rho * radius2(r1 * r1, ALPHA, i)))
                    .sum();
                var.sqrt() / n as f64
            })
            .collect();
        // The error falls at every checkpoint; each is the closed form's within the noise of an
        // RMS over 100 correlated pixels (and a little below it: Halton photons); the slope over
        // the factor 64 in passes is −1/3 within ±0.08.
        for w in measured.windows(2) {
            assert!(w[1] < w[0], "{measured:?}");
        }
        for (m, p) in measured.iter().zip(&predicted) {
            assert!(m / p > 0.6 && m / p < 1.25, "measured {measured:?}, closed form {predicted:?}");
        }
        let slope = (measured[3] / measured[0]).ln() / 64f64.ln();
        assert!((slope + 1.0 / 3.0).abs() < 0.08, "measured {measured:?}: slope {slope}");
    }
}
