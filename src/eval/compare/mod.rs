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

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;

use super::metrics::{self, Errors, Region, RegionErrors};
use super::truth::{self, FloorGrid, Quality};
use crate::detect::{DetectParams, Method};
use crate::eval::reference::{Progressive, ReferenceOptions, ReferenceState};
use crate::format::{Output, PhotonMap, PhotonTable};
use crate::pipeline::{self, PipelineError, PipelineParams, Stage, StageDone};
use crate::relax::RelaxParams;
use crate::render::{
    Estimator, EyeOptions, Image, Kernel, Mode, PhotonData, PhotonLookup, RenderOptions, Renderer, View,
};
use crate::scene::{Camera, Projection, Scene};
use crate::trace::{self, Budget, TraceOptions};

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
}

impl MethodKind {
    /// Every method, in the order of the paper's Table I.
    pub const ALL: [MethodKind; 5] = [
        MethodKind::StandardPm,
        MethodKind::Relaxation2009,
        MethodKind::DiffusionPm,
        MethodKind::Ours,
        MethodKind::Progressive,
    ];

    /// The column name of the paper's Table I.
    pub fn label(self) -> &'static str {
        match self {
            MethodKind::StandardPm => "Standard PM",
            MethodKind::Relaxation2009 => "Photon Relax.",
            MethodKind::DiffusionPm => "Diff-Based PM",
            MethodKind::Ours => "Our method",
            MethodKind::Progressive => "Progressive PM",
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
    /// ([`Estimator::Variable`]: each photon's radius its own K-NN distance) instead of the
    /// paper's k-NN estimate.
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
    /// Photons per progressive pass (default: `photons`).
    pub ppm_photons_per_pass: Option<u64>,
    /// k of progressive photon mapping's initial radius at each point: the distance to the
    /// k-th nearest photon of its first pass (Hachisuka & Jensen: k in the tens); 0 for one
    /// radius over the image (the median 15-NN distance of the first pass's photons, which
    /// leaves sparse regions empty for many passes).
    pub ppm_k: usize,
    /// Samples per pixel of every image: a jittered grid when a square, so that each pixel
    /// is the estimate averaged over its cell, as the truth is.
    pub spp: u32,
    /// Independent runs of every method (seeds `seed`, `seed + 1`, …), for the bias and
    /// variance of each ([`metrics::region_errors`]); times and errors are their means.
    pub seeds: u32,
    /// The methods run.
    pub methods: Vec<MethodKind>,
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
            iterations: r.iterations,
            iterations_2009: 2 * r.iterations,
            diffusion_k: 500,
            diffusion_q: 0.02,
            ppm_passes: vec![1, 4, 16],
            ppm_photons_per_pass: None,
            ppm_k: 30,
            spp: 16,
            seeds: 4,
            methods: MethodKind::ALL.to_vec(),
        }
    }
}

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
}

/// An image's pixels as f64 RGB.
pub fn pixels(img: &Image) -> Vec<[f64; 3]> {
    img.pixels.iter().map(|p| p.as_dvec3().to_array()).collect()
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
    scene_text: &str,
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
        let these = run_seed(scene, scene_label, scene_text, target, &os, work_dir, log)?;
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

/// [`run`] for one seed.
fn run_seed(
    scene: &Scene,
    scene_label: &str,
    scene_text: &str,
    target: &Target,
    o: &CompareOptions,
    work_dir: &Path,
    log: &dyn Fn(Progress),
) -> Result<Vec<Row>, CompareError> {
    if o.photons == 0 {
        return Err(CompareError::Invalid("the comparison needs at least one photon".into()));
    }
    std::fs::create_dir_all(work_dir)
        .map_err(|e| CompareError::Io { path: work_dir.display().to_string(), source: e })?;
    let file = |name: &str| -> PathBuf { work_dir.join(name) };
    let mut rows = Vec::new();
    let wants = |m: MethodKind| o.methods.contains(&m);
    let (w, h) = (target.width(), target.height());
    let measure = |img: &Image| {
        metrics::measure(&pixels(img), &target.truth, w, h, &target.edges, target.overlap.as_deref())
    };

    // Trace once for every map-based method.
    let map_based = o.methods.iter().any(|&m| m != MethodKind::Progressive);
    let mut trace_secs = 0.0;
    if map_based {
        let topts =
            TraceOptions { seed: o.seed, budget: Budget::Emitted(o.photons), ..TraceOptions::default() };
        log(Progress::Started("trace"));
        let t = Instant::now();
        let mut traced = trace::trace(scene, &topts, &|_, _| {})?;
        if let Some(keep) = &target.bounces {
            traced.retain_bounces(keep)?;
        }
        trace_secs = t.elapsed().as_secs_f64();
        if traced.stored == 0 {
            return Err(CompareError::Invalid(format!(
                "no photon of the kind the truth accounts for was stored from {} emitted",
                o.photons
            )));
        }
        let info = trace::map_info(scene, &topts, &traced, scene_label, scene_text);
        traced.write(Output::Path(file("traced.phm")), info)?;
        log(Progress::Finished(&format!("trace: {:.2} s, {} photons stored", trace_secs, traced.stored)));
    }

    let render = |map: &PhotonMap, estimator: Estimator| -> Result<(Image, f64), CompareError> {
        let t = Instant::now();
        let normals = map.column::<[f32; 3]>(crate::format::name::NORMAL)?;
        let data = PhotonData { positions: map.positions(), flux: map.flux(), normals };
        let lookup = PhotonLookup::new(map.file_name(), data)?.prepared_for(&estimator);
        let renderer = Renderer {
            view: View::Scene { scene, camera: target.camera.clone() },
            photons: Some(&lookup),
            diagnostic: None,
            opts: RenderOptions {
                width: w as u32,
                height: h as u32,
                spp: o.spp,
                mode: target.mode,
                estimator,
                eye: EyeOptions::default(),
                seed: 0,
                keep_samples: false,
            },
        };
        let (img, _) = renderer.render(&|_| {})?;
        Ok((img, t.elapsed().as_secs_f64()))
    };
    let fixed_k = |k: usize| match o.variable_kernel {
        false => Estimator::Knn { k, kernel: Kernel::Epanechnikov, max_radius: None },
        true => Estimator::Variable { k, kernel: Kernel::Epanechnikov },
    };
    let knn = fixed_k(o.k);
    // How a setting names its estimate's K (and the variable kernel, when chosen).
    let k_label = |k: usize| match o.variable_kernel {
        false => format!("K = {k}"),
        true => format!("K = {k}, variable kernel"),
    };

    // Algorithm 1 on the traced map ([`pipeline::run`]), each stage's map written as
    // `{prefix}-{stage}.phm`; the relaxed map and the detect and relax seconds (the collapse
    // counted with relaxation).
    let relax_photons = |prefix: &str, method: Option<Method>, iterations: [usize; 2]| {
        let traced = PhotonMap::open_path(&file("traced.phm"))?;
        let params = PipelineParams {
            detect: DetectParams {
                kc: o.kc,
                beta: o.beta,
                k_density: o.k_density,
                growths: o.growths,
                spectral_scale: o.spectral_scale,
                ..DetectParams::default()
            },
            method,
            relax: RelaxParams { kf: o.kf, ..RelaxParams::default() },
            iterations,
        };
        let (mut detect_secs, mut relax_secs) = (0.0, 0.0);
        let mut on_stage = |done: &StageDone, table: &PhotonTable| -> Result<(), PipelineError> {
            let stage = match done.stage {
                Stage::Detect => "detected",
                Stage::RelaxParams => "relaxed-params",
                Stage::Collapse => "collapsed",
                Stage::RelaxWorld => "relaxed",
            };
            let t = Instant::now();
            table.write(Output::Path(file(&format!("{prefix}-{stage}.phm"))))?;
            match done.stage {
                Stage::Detect => detect_secs = done.seconds,
                Stage::Collapse => relax_secs += done.seconds + t.elapsed().as_secs_f64(),
                _ => relax_secs += done.seconds,
            }
            Ok(())
        };
        let done = pipeline::run(&traced.view(), Some(scene), &params, &mut on_stage, &|_| {})?;
        let map = PhotonMap::open_path(&file(&format!("{prefix}-relaxed.phm")))?;
        Ok::<_, CompareError>((map, detect_secs, relax_secs, done.method))
    };

    let mut push = |method: MethodKind,
                    setting: String,
                    map: &PhotonMap,
                    radiance_k,
                    times: StageTimes,
                    image: Image| {
        let errors = measure(&image);
        log(Progress::Finished(&format!(
            "{}: {:.2} s, NRMSE {:.4}, SSIM {:.4}",
            method.label(),
            times.total,
            errors.nrmse,
            errors.ssim
        )));
        rows.push(Row {
            method,
            setting,
            emitted: o.photons,
            photons: map.len() as u64,
            radiance_k,
            times,
            errors,
            seeds: 1,
            regions: Vec::new(),
            image,
        });
    };

    if wants(MethodKind::StandardPm) {
        log(Progress::Started(MethodKind::StandardPm.label()));
        let map = PhotonMap::open_path(&file("traced.phm"))?;
        for &k in &o.pm_ks {
            let (img, secs) = render(&map, fixed_k(k))?;
            let times = StageTimes::of(trace_secs, None, None, secs);
            push(MethodKind::StandardPm, k_label(k), &map, k, times, img);
        }
    }
    if wants(MethodKind::DiffusionPm) {
        log(Progress::Started(MethodKind::DiffusionPm.label()));
        let map = PhotonMap::open_path(&file("traced.phm"))?;
        let (img, secs) = render(&map, Estimator::Diffusion { k: o.diffusion_k, q: o.diffusion_q })?;
        let times = StageTimes::of(trace_secs, None, None, secs);
        push(
            MethodKind::DiffusionPm,
            format!("{} neighbours, q = {}", o.diffusion_k, o.diffusion_q),
            &map,
            o.diffusion_k,
            times,
            img,
        );
    }
    if wants(MethodKind::Relaxation2009) {
        log(Progress::Started(MethodKind::Relaxation2009.label()));
        let (map, det, rel, _) = relax_photons("relax2009", Some(Method::Gradient), [0, o.iterations_2009])?;
        let (img, secs) = render(&map, knn)?;
        let times = StageTimes::of(trace_secs, Some(det), Some(rel), secs);
        push(
            MethodKind::Relaxation2009,
            format!("gradient, {} world iterations, {}", o.iterations_2009, k_label(o.k)),
            &map,
            o.k,
            times,
            img,
        );
    }
    if wants(MethodKind::Ours) {
        log(Progress::Started(MethodKind::Ours.label()));
        let (map, det, rel, method) = relax_photons("ours", None, [o.iterations, o.iterations])?;
        let (img, secs) = render(&map, knn)?;
        let times = StageTimes::of(trace_secs, Some(det), Some(rel), secs);
        push(
            MethodKind::Ours,
            format!("{}, {} + {} iterations, {}", method.name(), o.iterations, o.iterations, k_label(o.k)),
            &map,
            o.k,
            times,
            img,
        );
    }
    if wants(MethodKind::Progressive) && !o.ppm_passes.is_empty() {
        log(Progress::Started(MethodKind::Progressive.label()));
        let per_pass = o.ppm_photons_per_pass.unwrap_or(o.photons);
        let mut passes = o.ppm_passes.clone();
        passes.sort_unstable();
        passes.dedup();
        let last = *passes.last().expect("not empty");
        let p = Progressive {
            scene,
            camera: target.camera.clone(),
            render: RenderOptions {
                width: w as u32,
                height: h as u32,
                spp: o.spp,
                mode: target.mode,
                ..RenderOptions::default()
            },
            kernel: Kernel::Epanechnikov,
            bounces: target.bounces.as_deref(),
        };
        let options = ReferenceOptions {
            photons_per_pass: per_pass,
            seed: o.seed,
            local_k: (o.ppm_k > 0).then_some(o.ppm_k),
            ..ReferenceOptions::default()
        };
        let mut state = ReferenceState::start(options, serde_json::Value::Null);
        let mut image = Image::new(w as u32, h as u32);
        let start = Instant::now();
        let mut snapshots = Vec::new();
        // The clock stops while a snapshot is measured.
        let mut paused = 0.0;
        p.run(&mut image, &mut state, last, &mut |s, img| {
            if passes.contains(&s.passes) {
                let t = Instant::now();
                snapshots.push((s.passes, start.elapsed().as_secs_f64() - paused, img.clone()));
                paused += t.elapsed().as_secs_f64();
            }
            Ok(true)
        })?;
        for (n, secs, img) in snapshots {
            let errors = measure(&img);
            log(Progress::Finished(&format!(
                "{} ({n} passes): {:.2} s, NRMSE {:.4}, SSIM {:.4}",
                MethodKind::Progressive.label(),
                secs,
                errors.nrmse,
                errors.ssim
            )));
            rows.push(Row {
                method: MethodKind::Progressive,
                setting: if o.ppm_k > 0 {
                    format!("{n} passes of {per_pass}, r₁ = {}-NN distance, α = 2/3", o.ppm_k)
                } else {
                    format!("{n} passes of {per_pass}, one r₁, α = 2/3")
                },
                emitted: n * per_pass,
                photons: 0,
                radiance_k: 0,
                times: StageTimes { total: secs, ..Default::default() },
                errors,
                seeds: 1,
                regions: Vec::new(),
                image: img,
            });
        }
    }
    // The paper's column order.
    rows.sort_by_key(|r| MethodKind::ALL.iter().position(|&m| m == r.method));
    Ok(rows)
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

    #[test]
    fn method_slugs_round_trip() {
        for m in MethodKind::ALL {
            assert_eq!(MethodKind::from_slug(m.slug()), Some(m));
        }
        assert_eq!(MethodKind::from_slug("nope"), None);
    }
}
