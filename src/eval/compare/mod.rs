//! `photonkit compare`: every method on the same traced photons, each stage timed, each image
//! measured against the truth.
//!
//! The methods (the columns of the paper's Table I): standard photon mapping (K = 15), the
//! 2009 photon relaxation (gradient constraint, 14 world-space iterations), diffusion-based
//! photon mapping (500 neighbours, q = 0.02), this method (parameter-space PCA, 7 iterations in
//! the high-dimensional space, collapse, 7 in world space), and progressive photon mapping at
//! several pass counts. All but progressive photon mapping share one traced photon map; a
//! progressive pass traces its own photons (as the method does), as many per pass as the
//! shared map emitted unless told otherwise.
//!
//! The images are compared on a [`Target`]: a view, a render mode and the truth's image in
//! it — the closed-form floor irradiance of [`crate::eval::truth`] through an orthographic
//! top-down camera, or a long progressive run where there is no closed form.

use std::path::Path;

use super::metrics::{self, Errors, RegionErrors};
use super::truth;
use crate::detect::DetectParams;
use crate::refine::RefineParams;
use crate::relax::RelaxParams;
use crate::render::Image;
use crate::scene::Scene;

mod methods;
mod target;

pub use target::{EDGE_BAND, Target, floor_camera, pixels};

/// Everything that can go wrong in a comparison.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CompareError {
    /// A photon map could not be written or read back.
    #[error(transparent)]
    Format(#[from] crate::format::FormatError),
    /// Tracing the shared map failed.
    #[error(transparent)]
    Trace(#[from] crate::trace::TraceError),
    /// Feature detection failed.
    #[error(transparent)]
    Detect(#[from] crate::detect::DetectError),
    /// Relaxation failed.
    #[error(transparent)]
    Relax(#[from] crate::relax::RelaxError),
    /// A relaxed method's pipeline failed.
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    /// Rendering an image failed.
    #[error(transparent)]
    Render(#[from] crate::render::RenderError),
    /// Progressive photon mapping (a method or the reference truth) failed.
    #[error(transparent)]
    Reference(#[from] crate::eval::reference::ReferenceError),
    /// Progressive refinement of this method's map failed.
    #[error(transparent)]
    Refine(#[from] crate::refine::RefineError),
    /// The closed-form truth could not be computed.
    #[error(transparent)]
    Truth(#[from] truth::TruthError),
    /// Creating the work directory (or a report file) failed.
    #[error("{path}: {source}")]
    Io {
        /// The directory or file.
        path: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// Settings out of range (no seed, no photon, a grid without square cells).
    #[error("{0}")]
    Invalid(String),
}

/// The methods compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MethodKind {
    /// Standard photon mapping: the K nearest photons, Epanechnikov kernel.
    StandardPm,
    /// Photon relaxation (Spencer & Jones 2009): gradient constraint, world-space iterations.
    Relaxation2009,
    /// Diffusion-based photon mapping (Schjøth et al. 2008).
    DiffusionPm,
    /// This method: parameter-space PCA, relax, collapse, relax.
    Ours,
    /// Progressive photon mapping (memoryless, Knaus & Zwicker 2011).
    Progressive,
    /// This method's relaxed map refined progressively ([`crate::refine`], issue 24).
    OursProgressive,
}

impl MethodKind {
    /// Every method, in the order of the paper's Table I (then the refined map).
    pub const ALL: [MethodKind; 6] = [
        MethodKind::StandardPm,
        MethodKind::Relaxation2009,
        MethodKind::DiffusionPm,
        MethodKind::Ours,
        MethodKind::Progressive,
        MethodKind::OursProgressive,
    ];

    /// The column name of the paper's Table I.
    pub fn label(self) -> &'static str {
        match self {
            MethodKind::StandardPm => "Standard PM",
            MethodKind::Relaxation2009 => "Photon Relax.",
            MethodKind::DiffusionPm => "Diff-Based PM",
            MethodKind::Ours => "Our method",
            MethodKind::Progressive => "Progressive PM",
            MethodKind::OursProgressive => "Ours, refined",
        }
    }

    /// A short name for files and the command line.
    pub fn slug(self) -> &'static str {
        match self {
            MethodKind::StandardPm => "pm",
            MethodKind::Relaxation2009 => "relax2009",
            MethodKind::DiffusionPm => "diffusion",
            MethodKind::Ours => "ours",
            MethodKind::Progressive => "ppm",
            MethodKind::OursProgressive => "ours-progressive",
        }
    }

    /// The method named `s` by [`Self::slug`].
    pub fn from_slug(s: &str) -> Option<MethodKind> {
        MethodKind::ALL.into_iter().find(|m| m.slug() == s)
    }
}

/// The settings of one comparison run (the paper's defaults).
#[derive(Clone, Debug, PartialEq)]
pub struct CompareOptions {
    /// Photons emitted for the shared map.
    pub photons: u64,
    /// The first run's seed (run i, from 0, uses `seed + i`).
    pub seed: u64,
    /// K of the radiance estimate (2009 relaxation, ours).
    pub k: usize,
    /// The K values standard photon mapping runs at, each a row (the baseline at its best,
    /// not only at the relaxed maps' K: more neighbours trade its noise for blur).
    pub pm_ks: Vec<usize>,
    /// Whether the fixed-K estimates (standard PM, the relaxed maps) use the variable kernel
    /// ([`crate::render::Estimator::Variable`]: each photon's radius its own K-NN distance)
    /// instead of the paper's k-NN estimate.
    pub variable_kernel: bool,
    /// Kc of feature detection: neighbours in the PCA.
    pub kc: usize,
    /// β of Eq. 1: the parameter-space radius ([`DetectParams::beta`]).
    pub beta: f32,
    /// k of the parameter-space density ρ (Eq. 1); `None` means Kc.
    pub k_density: Option<usize>,
    /// Doublings of a binding parameter ball ([`DetectParams::growths`]).
    pub growths: u32,
    /// The wavelength's scale in parameter space ([`DetectParams::spectral_scale`]).
    pub spectral_scale: f32,
    /// Kf of the repulsion force.
    pub kf: usize,
    /// The wavelength window of our method's relaxation after the collapse
    /// ([`RelaxParams::spectral_window`]).
    pub spectral_window: f32,
    /// R: iterations before the collapse and again after it (this method).
    pub iterations: usize,
    /// World-space iterations of the 2009 relaxation.
    pub iterations_2009: usize,
    /// Neighbours of diffusion-based photon mapping.
    pub diffusion_k: usize,
    /// The control q of diffusion-based photon mapping's diffusivity.
    pub diffusion_q: f32,
    /// Progressive photon mapping: the pass counts at which its image is measured.
    pub ppm_passes: Vec<u64>,
    /// Pass counts at which this method's map refined progressively is measured (photons per
    /// pass: `photons`).
    pub refine_passes: Vec<u64>,
    /// Relaxation iterations toward constant flux per refinement pass.
    pub refine_iterations: usize,
    /// γ of the refinement's growth (0: the map's photons stay).
    pub refine_growth: f32,
    /// Passes' worth of weight of the relaxed map's own fluxes in the refinement.
    pub refine_prior: f32,
    /// The exponent of a held photon's prior weight in the refinement
    /// ([`RefineParams::prior_hold`]).
    pub refine_prior_hold: f32,
    /// Photons per progressive pass (default: `photons`).
    pub ppm_photons_per_pass: Option<u64>,
    /// Photons emitted per refinement pass (default: `photons`).
    pub refine_photons_per_pass: Option<u64>,
    /// k of progressive photon mapping's initial radius at each point: the distance to the
    /// k-th nearest photon of its first pass (Hachisuka & Jensen: k in the tens); 0 for one
    /// radius over the image (the median 15-NN distance of the first pass's photons, which
    /// leaves sparse regions empty for many passes).
    pub ppm_k: usize,
    /// Samples per pixel of every image: a jittered grid when a square, so that each pixel
    /// is the estimate averaged over its cell, as the truth is.
    pub spp: u32,
    /// Samples per pixel in the truth's core and edge pixels (docs/truth.md, "Sampling"):
    /// where the irradiance varies within a pixel, `spp` point samples of a narrow kernel's
    /// estimate miss the pixel's average by more than the methods differ. Not timed (a
    /// method's time counts a render at `spp`); progressive photon mapping takes at most 256
    /// a pass, diffusion-based PM at most 1024. At most `spp`: every pixel takes `spp`.
    pub feature_spp: u32,
    /// Independent runs of every method (seeds `seed`, `seed + 1`, …), for the bias and
    /// variance of each ([`metrics::region_errors`]); times and errors are their means.
    pub seeds: u32,
    /// The methods run.
    pub methods: Vec<MethodKind>,
}

impl CompareOptions {
    /// Refuses settings out of range, before anything is traced (the messages name the
    /// command line's options).
    pub fn check(&self) -> Result<(), CompareError> {
        let bad = |m: &str| Err(CompareError::Invalid(m.into()));
        if self.pm_ks.is_empty() || self.pm_ks.contains(&0) {
            return bad("--pm-k needs one or more K values of at least 1");
        }
        if self.k == 0
            || self.kc < 3
            || self.kf == 0
            || self.diffusion_k == 0
            || self.spp == 0
            || self.seeds == 0
        {
            return bad("-k, --kf, --diffusion-k, --spp and --seeds need at least 1, --kc at least 3");
        }
        if !(self.spectral_window.is_finite() && self.spectral_window >= 0.0) {
            return bad("--spectral-window takes a finite number of nanometres, at least 0");
        }
        if self.k_density.is_some_and(|k| k < 2) {
            return bad("--k-density needs at least 2");
        }
        let most = crate::render::MAX_SPP;
        if self.spp > most || self.feature_spp > most {
            return bad(&format!("--spp and --feature-spp take at most {most} samples per pixel"));
        }
        let positive = |x: f32| x > 0.0 && x.is_finite();
        if !(positive(self.beta) && positive(self.diffusion_q)) {
            return bad("--beta and --diffusion-q must be positive");
        }
        Ok(())
    }
}

impl Default for CompareOptions {
    fn default() -> Self {
        let (d, r) = (DetectParams::default(), RelaxParams::default());
        CompareOptions {
            photons: 1_000_000,
            seed: 1,
            k: 15,
            pm_ks: vec![15, 50, 200],
            variable_kernel: false,
            kc: d.kc,
            beta: d.beta,
            k_density: d.k_density,
            growths: d.growths,
            spectral_scale: d.spectral_scale,
            kf: r.kf,
            spectral_window: r.spectral_window,
            iterations: r.iterations,
            iterations_2009: 2 * r.iterations,
            diffusion_k: 500,
            diffusion_q: 0.02,
            ppm_passes: vec![1, 4, 16],
            refine_passes: vec![1, 4, 16],
            refine_iterations: RefineParams::default().iterations,
            refine_growth: RefineParams::default().growth,
            refine_prior: RefineParams::default().prior_passes,
            refine_prior_hold: RefineParams::default().prior_hold,
            ppm_photons_per_pass: None,
            refine_photons_per_pass: None,
            ppm_k: 30,
            spp: 16,
            feature_spp: 4096,
            seeds: 4,
            // Every method but the refined map, which is asked for by name (it adds passes).
            methods: MethodKind::ALL.into_iter().filter(|&m| m != MethodKind::OursProgressive).collect(),
        }
    }
}

/// Seconds spent in each stage of one method (`None`: the method has no such stage).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Tracing the shared map.
    pub trace: Option<f64>,
    /// Feature detection.
    pub detect: Option<f64>,
    /// Relaxation, including the collapse.
    pub relax: Option<f64>,
    /// Rendering the image.
    pub render: Option<f64>,
    /// The method's whole time: its stages' sum, or the progressive run's clock.
    pub total: f64,
}

impl StageTimes {
    /// The times of a method's stages, the total their sum.
    fn of(trace: f64, detect: Option<f64>, relax: Option<f64>, render: f64) -> StageTimes {
        let total = trace + detect.unwrap_or(0.0) + relax.unwrap_or(0.0) + render;
        StageTimes { trace: Some(trace), detect, relax, render: Some(render), total }
    }
}

/// One method's result.
#[derive(Clone, Debug)]
pub struct Row {
    /// The method.
    pub method: MethodKind,
    /// The method's settings in a few words (K, iterations, passes).
    pub setting: String,
    /// Photons emitted (all passes for progressive).
    pub emitted: u64,
    /// Photons in the map the estimate used (0 for progressive), mean over the seeds.
    pub photons: u64,
    /// K of the radiance estimate (0 for the progressive radius estimate).
    pub radiance_k: usize,
    /// Passes of a progressive method (progressive photon mapping, the refined map); `None`
    /// for the others.
    pub passes: Option<u64>,
    /// Mean times over the seeds.
    pub times: StageTimes,
    /// The whole-image measures, mean over the seeds.
    pub errors: Errors,
    /// Seeds run.
    pub seeds: u32,
    /// The measures over the seeds for the whole image and each region class
    /// ([`metrics::region_errors`]; empty until every seed has run).
    pub regions: Vec<RegionErrors>,
    /// The image of the first seed, in the target's view.
    pub image: Image,
}

/// What a comparison reports while it runs.
#[derive(Clone, Copy, Debug)]
pub enum Progress<'a> {
    /// A stage or method has begun (e.g. "trace", "Our method").
    Started(&'a str),
    /// A one-line result of a finished stage or method.
    Finished(&'a str),
}

/// Runs every requested method `o.seeds` times (seeds `o.seed`, `o.seed + 1`, …) and
/// measures each against `target`: one row per method and setting, with mean times and
/// errors and the bias and variance over the seeds per region class. Intermediate photon
/// maps go to `work_dir` (the last seed's stay); `log` hears each stage begin and end.
pub fn run(
    scene: &Scene,
    scene_label: &str,
    scene_content: &[u8],
    target: &Target,
    o: &CompareOptions,
    work_dir: &Path,
    log: &dyn Fn(Progress),
) -> Result<Vec<Row>, CompareError> {
    if o.seeds == 0 {
        return Err(CompareError::Invalid("the comparison needs at least one seed".into()));
    }
    let mut rows: Vec<Row> = Vec::new();
    let mut images: Vec<Vec<Vec<[f64; 3]>>> = Vec::new();
    for s in 0..o.seeds {
        if o.seeds > 1 {
            log(Progress::Finished(&format!("seed {} ({} of {})", o.seed + s as u64, s + 1, o.seeds)));
        }
        let os = CompareOptions { seed: o.seed + s as u64, ..o.clone() };
        let these = methods::run_seed(scene, scene_label, scene_content, target, &os, work_dir, log)?;
        if s == 0 {
            images = these.iter().map(|r| vec![pixels(&r.image)]).collect();
            rows = these;
            continue;
        }
        if these.len() != rows.len() {
            return Err(CompareError::Invalid("a seed ran another set of methods".into()));
        }
        for ((row, r), im) in rows.iter_mut().zip(these).zip(images.iter_mut()) {
            im.push(pixels(&r.image));
            row.add(&r);
        }
    }
    for (row, im) in rows.iter_mut().zip(&images) {
        row.mean_over(o.seeds);
        row.regions = metrics::region_errors(im, &target.truth, &target.regions);
    }
    Ok(rows)
}

impl Row {
    /// Adds another seed's times, errors and photon counts (see [`Self::mean_over`]).
    fn add(&mut self, r: &Row) {
        let sum = |a: &mut Option<f64>, b: Option<f64>| *a = a.zip(b).map(|(x, y)| x + y);
        sum(&mut self.times.trace, r.times.trace);
        sum(&mut self.times.detect, r.times.detect);
        sum(&mut self.times.relax, r.times.relax);
        sum(&mut self.times.render, r.times.render);
        self.times.total += r.times.total;
        let (e, f) = (&mut self.errors, &r.errors);
        e.rmse += f.rmse;
        e.nrmse += f.nrmse;
        e.rel_mse += f.rel_mse;
        e.ssim += f.ssim;
        e.edge_nrmse += f.edge_nrmse;
        e.overlap_nrmse += f.overlap_nrmse;
        self.photons += r.photons;
        self.seeds += 1;
    }

    /// Divides the sums of [`Self::add`] by the `seeds` added.
    fn mean_over(&mut self, seeds: u32) {
        let n = seeds as f64;
        let t = &mut self.times;
        for x in [&mut t.trace, &mut t.detect, &mut t.relax, &mut t.render] {
            *x = x.map(|v| v / n);
        }
        t.total /= n;
        let e = &mut self.errors;
        for x in
            [&mut e.rmse, &mut e.nrmse, &mut e.rel_mse, &mut e.ssim, &mut e.edge_nrmse, &mut e.overlap_nrmse]
        {
            *x /= n;
        }
        self.photons = (self.photons as f64 / n).round() as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_slugs_round_trip() {
        for m in MethodKind::ALL {
            assert_eq!(MethodKind::from_slug(m.slug()), Some(m));
        }
        assert_eq!(MethodKind::from_slug("nope"), None);
    }
}
