//! One seed of [`super::run`]: the shared trace, then each method's photon map, image and
//! measures, one function per method.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{CompareError, CompareOptions, MethodKind, Progress, Row, StageTimes, Target, pixels};
use crate::detect::{DetectParams, Method};
use crate::eval::metrics::{self, Errors};
use crate::eval::reference::{Progressive, ReferenceOptions, ReferenceState};
use crate::format::{Output, PhotonMap, PhotonTable};
use crate::pipeline::{self, PipelineError, PipelineParams, Stage, StageDone};
use crate::refine::RefineParams;
use crate::relax::RelaxParams;
use crate::render::{
    Estimator, EyeOptions, Image, Kernel, PhotonData, PhotonLookup, RenderOptions, Renderer, View,
};
use crate::scene::Scene;
use crate::trace::{self, Budget, TraceOptions};

/// Samples a progressive photon mapping pass takes in each core and edge pixel, at most
/// (docs/truth.md, "Sampling").
const PPM_FEATURE_SPP: u32 = 256;

/// Samples the diffusion estimate's image takes in each core and edge pixel, at most: each of
/// its lookups searches 500 neighbours (about 90 µs), so 4096 in the ring's 2283 feature
/// pixels are 9.4 M lookups (minutes on 2 cores, the water's three times as many), and at
/// 1024 the ring's core and edges are within 6 % and 2 % of 4096 (docs/truth.md, "Sampling").
const DIFFUSION_FEATURE_SPP: u32 = 1024;

/// [`super::run`] for one seed: the rows of every requested method, in the paper's column order.
pub(super) fn run_seed(
    scene: &Scene,
    scene_label: &str,
    scene_content: &[u8],
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
    let mut s = Seed { scene, target, o, work_dir, log, trace_secs: 0.0 };
    // Trace once for every map-based method.
    if o.methods.iter().any(|&m| m != MethodKind::Progressive) {
        s.trace_secs = s.trace_shared(scene_label, scene_content)?;
    }
    let wants = |m: MethodKind| o.methods.contains(&m);
    let mut rows = Vec::new();
    if wants(MethodKind::StandardPm) {
        s.standard_pm(&mut rows)?;
    }
    if wants(MethodKind::DiffusionPm) {
        s.diffusion_pm(&mut rows)?;
    }
    if wants(MethodKind::Relaxation2009) {
        s.relaxation_2009(&mut rows)?;
    }
    // This method's relaxed map, made once for ours and ours-progressive (which refines it).
    let mut ours = None;
    if wants(MethodKind::Ours) {
        ours = Some(s.ours(&mut rows)?);
    }
    if wants(MethodKind::OursProgressive) && !o.refine_passes.is_empty() {
        s.ours_progressive(ours.take(), &mut rows)?;
    }
    if wants(MethodKind::Progressive) && !o.ppm_passes.is_empty() {
        s.progressive(&mut rows)?;
    }
    // The paper's column order.
    rows.sort_by_key(|r| MethodKind::ALL.iter().position(|&m| m == r.method));
    Ok(rows)
}

/// A relaxed map with the seconds its detect and relax stages took and the detection used.
type Relaxed = (PhotonMap, f64, f64, Method);

/// What every method of one seed shares.
struct Seed<'a> {
    scene: &'a Scene,
    target: &'a Target,
    /// The options, with this seed's `seed`.
    o: &'a CompareOptions,
    work_dir: &'a Path,
    log: &'a dyn Fn(Progress),
    /// Seconds spent tracing the shared map (0 when only progressive photon mapping runs).
    trace_secs: f64,
}

impl Seed<'_> {
    fn file(&self, name: &str) -> PathBuf {
        self.work_dir.join(name)
    }

    /// The target's measures of `img`.
    fn measure(&self, img: &Image) -> Errors {
        let t = self.target;
        metrics::measure(&pixels(img), &t.truth, t.width(), t.height(), &t.edges, t.overlap.as_deref())
    }

    /// Traces the shared map into `traced.phm` (only the bounce counts the truth accounts
    /// for kept); returns the seconds spent tracing.
    fn trace_shared(&self, scene_label: &str, scene_content: &[u8]) -> Result<f64, CompareError> {
        let o = self.o;
        let topts =
            TraceOptions { seed: o.seed, budget: Budget::Emitted(o.photons), ..TraceOptions::default() };
        (self.log)(Progress::Started("trace"));
        let t = Instant::now();
        let mut traced = trace::trace(self.scene, &topts, &|_, _| {})?;
        if let Some(keep) = &self.target.bounces {
            traced.retain_bounces(keep)?;
        }
        let trace_secs = t.elapsed().as_secs_f64();
        if traced.stored == 0 {
            return Err(CompareError::Invalid(format!(
                "no photon of the kind the truth accounts for was stored from {} emitted",
                o.photons
            )));
        }
        let info = trace::map_info(self.scene, &topts, &traced, scene_label, scene_content);
        traced.write(Output::Path(self.file("traced.phm")), info)?;
        (self.log)(Progress::Finished(&format!(
            "trace: {:.2} s, {} photons stored",
            trace_secs, traced.stored
        )));
        Ok(trace_secs)
    }

    /// The image of `map` in the target's view with `estimator`, and the seconds a render at
    /// `spp` samples in every pixel takes, building the lookup included: the method's cost.
    /// Where the target supersamples its core and edge pixels, the image is a second, untimed
    /// render with them: the pixel averages the error is measured on are the measurement's
    /// cost, not the method's (docs/truth.md, "Sampling").
    fn render(&self, map: &PhotonMap, estimator: Estimator) -> Result<(Image, f64), CompareError> {
        let t = Instant::now();
        let normals = map.column::<[f32; 3]>(crate::format::name::NORMAL)?;
        let data = PhotonData { positions: map.positions(), flux: map.flux(), normals };
        let mut lookup = PhotonLookup::new(map.file_name(), data)?.prepared_for(&estimator);
        if let Estimator::LocalRadius { .. } = estimator {
            // A grown map: the radius comes from its photons before it grew.
            let view = map.view();
            let sites = crate::refine::first_photons(&view).unwrap_or(map.positions());
            lookup = lookup.with_own_radius_map(sites, &crate::refine::radius_factors(&view));
        }
        let mut renderer = Renderer {
            view: View::Scene { scene: self.scene, camera: self.target.camera.clone() },
            photons: Some(&lookup),
            diagnostic: None,
            opts: RenderOptions {
                width: self.target.width() as u32,
                height: self.target.height() as u32,
                spp: self.o.spp,
                mode: self.target.mode,
                estimator,
                eye: EyeOptions::default(),
                seed: 0,
                keep_samples: false,
                supersample: None,
            },
        };
        let (img, _) = renderer.render(&|_| {})?;
        let secs = t.elapsed().as_secs_f64();
        let feature_spp = match estimator {
            Estimator::Diffusion { .. } => self.o.feature_spp.min(DIFFUSION_FEATURE_SPP),
            _ => self.o.feature_spp,
        };
        let Some(supersample) = self.target.supersample(self.o.spp, feature_spp) else {
            return Ok((img, secs));
        };
        renderer.opts.supersample = Some(supersample);
        let (img, _) = renderer.render(&|_| {})?;
        Ok((img, secs))
    }

    /// The fixed-K estimate: the paper's k-NN, or the variable kernel when chosen.
    fn fixed_k(&self, k: usize) -> Estimator {
        match self.o.variable_kernel {
            false => Estimator::Knn { k, kernel: Kernel::Epanechnikov, max_radius: None },
            true => Estimator::Variable { k, kernel: Kernel::Epanechnikov },
        }
    }

    /// How a setting names its estimate's K (and the variable kernel, when chosen).
    fn k_label(&self, k: usize) -> String {
        match self.o.variable_kernel {
            false => format!("K = {k}"),
            true => format!("K = {k}, variable kernel"),
        }
    }

    /// Algorithm 1 on the traced map ([`pipeline::run`]), each stage's map written as
    /// `{prefix}-{stage}.phm`; the relaxed map and the detect and relax seconds (the collapse
    /// counted with relaxation).
    fn relax_photons(
        &self,
        prefix: &str,
        method: Option<Method>,
        iterations: [usize; 2],
    ) -> Result<(PhotonMap, f64, f64, Method), CompareError> {
        let o = self.o;
        let traced = PhotonMap::open_path(&self.file("traced.phm"))?;
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
            // The 2009 relaxation relaxes every wavelength together, as it was published.
            relax: RelaxParams {
                kf: o.kf,
                spectral_window: if method == Some(Method::Gradient) { 0.0 } else { o.spectral_window },
                ..RelaxParams::default()
            },
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
            table.write(Output::Path(self.file(&format!("{prefix}-{stage}.phm"))))?;
            match done.stage {
                Stage::Detect => detect_secs = done.seconds,
                Stage::Collapse => relax_secs += done.seconds + t.elapsed().as_secs_f64(),
                _ => relax_secs += done.seconds,
            }
            Ok(())
        };
        let done = pipeline::run(&traced.view(), Some(self.scene), &params, &mut on_stage, &|_| {})?;
        let map = PhotonMap::open_path(&self.file(&format!("{prefix}-relaxed.phm")))?;
        Ok((map, detect_secs, relax_secs, done.method))
    }

    /// The row of a map-based method: its image measured, and a line to the log.
    fn row(
        &self,
        method: MethodKind,
        setting: String,
        map: &PhotonMap,
        radiance_k: usize,
        times: StageTimes,
        image: Image,
    ) -> Row {
        let errors = self.measure(&image);
        (self.log)(Progress::Finished(&format!(
            "{}: {:.2} s, NRMSE {:.4}, SSIM {:.4}",
            method.label(),
            times.total,
            errors.nrmse,
            errors.ssim
        )));
        Row {
            method,
            setting,
            emitted: self.o.photons,
            photons: map.len() as u64,
            radiance_k,
            passes: None,
            times,
            errors,
            seeds: 1,
            regions: Vec::new(),
            image,
        }
    }

    /// Standard photon mapping on the traced map, a row per K of `pm_ks`.
    fn standard_pm(&self, rows: &mut Vec<Row>) -> Result<(), CompareError> {
        (self.log)(Progress::Started(MethodKind::StandardPm.label()));
        let map = PhotonMap::open_path(&self.file("traced.phm"))?;
        for &k in &self.o.pm_ks {
            let (img, secs) = self.render(&map, self.fixed_k(k))?;
            let times = StageTimes::of(self.trace_secs, None, None, secs);
            rows.push(self.row(MethodKind::StandardPm, self.k_label(k), &map, k, times, img));
        }
        Ok(())
    }

    /// Diffusion-based photon mapping on the traced map.
    fn diffusion_pm(&self, rows: &mut Vec<Row>) -> Result<(), CompareError> {
        let o = self.o;
        (self.log)(Progress::Started(MethodKind::DiffusionPm.label()));
        let map = PhotonMap::open_path(&self.file("traced.phm"))?;
        let (img, secs) = self.render(&map, Estimator::Diffusion { k: o.diffusion_k, q: o.diffusion_q })?;
        let times = StageTimes::of(self.trace_secs, None, None, secs);
        let setting = format!("{} neighbours, q = {}", o.diffusion_k, o.diffusion_q);
        rows.push(self.row(MethodKind::DiffusionPm, setting, &map, o.diffusion_k, times, img));
        Ok(())
    }

    /// The 2009 relaxation: gradient constraints, world-space iterations only.
    fn relaxation_2009(&self, rows: &mut Vec<Row>) -> Result<(), CompareError> {
        let o = self.o;
        (self.log)(Progress::Started(MethodKind::Relaxation2009.label()));
        let (map, det, rel, _) =
            self.relax_photons("relax2009", Some(Method::Gradient), [0, o.iterations_2009])?;
        let (img, secs) = self.render(&map, self.fixed_k(o.k))?;
        let times = StageTimes::of(self.trace_secs, Some(det), Some(rel), secs);
        let setting = format!("gradient, {} world iterations, {}", o.iterations_2009, self.k_label(o.k));
        rows.push(self.row(MethodKind::Relaxation2009, setting, &map, o.k, times, img));
        Ok(())
    }

    /// This method: detection (chosen by the map), relax, collapse, relax. Returns the relaxed
    /// map for [`Seed::ours_progressive`].
    fn ours(&self, rows: &mut Vec<Row>) -> Result<Relaxed, CompareError> {
        let o = self.o;
        (self.log)(Progress::Started(MethodKind::Ours.label()));
        let (map, det, rel, method) = self.relax_photons("ours", None, [o.iterations, o.iterations])?;
        let (img, secs) = self.render(&map, self.fixed_k(o.k))?;
        let times = StageTimes::of(self.trace_secs, Some(det), Some(rel), secs);
        let setting = format!(
            "{}, {} + {} iterations, {}",
            method.name(),
            o.iterations,
            o.iterations,
            self.k_label(o.k)
        );
        rows.push(self.row(MethodKind::Ours, setting, &map, o.k, times, img));
        Ok((map, det, rel, method))
    }

    /// This method's relaxed map (`made` by [`Seed::ours`], else made here) refined
    /// progressively ([`crate::refine`]) with `photons` per pass, a row at each pass count of
    /// `refine_passes` (the clock stopped while a snapshot is written).
    fn ours_progressive(&self, made: Option<Relaxed>, rows: &mut Vec<Row>) -> Result<(), CompareError> {
        let o = self.o;
        (self.log)(Progress::Started(MethodKind::OursProgressive.label()));
        let (map, det, rel, method) = match made {
            Some(made) => made,
            None => self.relax_photons("ours", None, [o.iterations, o.iterations])?,
        };
        let mut passes = o.refine_passes.clone();
        passes.sort_unstable();
        passes.dedup();
        let p = RefineParams {
            passes: *passes.last().expect("not empty"),
            photons_per_pass: Some(o.refine_photons_per_pass.unwrap_or(o.photons)),
            iterations: o.refine_iterations,
            growth: o.refine_growth,
            prior_passes: o.refine_prior,
            prior_hold: o.refine_prior_hold,
            kf: o.kf,
            ..RefineParams::default()
        };
        let start = Instant::now();
        let (mut paused, mut snapshots) = (0.0, Vec::new());
        crate::refine::refine(&map.view(), self.scene, &p, self.target.bounces.as_deref(), &mut |done| {
            let m = done.measure;
            if passes.contains(&m.pass) {
                let t = Instant::now();
                done.table()?.write(Output::Path(self.file(&format!("refined-{}.phm", m.pass))))?;
                snapshots.push((m.pass, start.elapsed().as_secs_f64() - paused));
                paused += t.elapsed().as_secs_f64();
            }
            Ok(true)
        })?;
        for (n, secs) in snapshots {
            let refined = PhotonMap::open_path(&self.file(&format!("refined-{n}.phm")))?;
            let k = o.k;
            // A grown map keeps its kernel's first area wherever it grew (docs/progressive.md).
            let grown = !o.variable_kernel && crate::refine::first_photons(&refined.view()).is_some();
            let estimator = match grown {
                true => Estimator::LocalRadius { k, scale: 1.0, kernel: Kernel::Epanechnikov },
                false => self.fixed_k(k),
            };
            let (img, render_secs) = self.render(&refined, estimator)?;
            let times = StageTimes::of(self.trace_secs, Some(det), Some(rel + secs), render_secs);
            let setting = format!(
                "{}, then {n} passes of {} ({} iterations each, growth γ = {:.3}, prior of {} passes{}), {}",
                method.name(),
                o.refine_photons_per_pass.unwrap_or(o.photons),
                o.refine_iterations,
                o.refine_growth,
                o.refine_prior,
                if o.refine_prior_hold > 0.0 {
                    format!(" / f^{} off the domain border", o.refine_prior_hold)
                } else {
                    String::new()
                },
                match grown {
                    true => format!("within the {k}th nearest photon's distance before growth"),
                    false => self.k_label(k),
                }
            );
            let row = self.row(MethodKind::OursProgressive, setting, &refined, k, times, img);
            rows.push(Row { passes: Some(n), ..row });
        }
        Ok(())
    }

    /// Progressive photon mapping with its own photons, one run measured at each pass count
    /// of `ppm_passes` (the clock stopped while a snapshot is taken).
    fn progressive(&self, rows: &mut Vec<Row>) -> Result<(), CompareError> {
        let (o, target) = (self.o, self.target);
        let (w, h) = (target.width(), target.height());
        (self.log)(Progress::Started(MethodKind::Progressive.label()));
        let per_pass = o.ppm_photons_per_pass.unwrap_or(o.photons);
        let mut passes = o.ppm_passes.clone();
        passes.sort_unstable();
        passes.dedup();
        let last = *passes.last().expect("not empty");
        let p = Progressive {
            scene: self.scene,
            camera: target.camera.clone(),
            render: RenderOptions {
                width: w as u32,
                height: h as u32,
                spp: o.spp,
                mode: target.mode,
                // Each pass jitters its samples afresh, so the passes average the sampling of
                // the feature pixels themselves: 256 a pass (after 16 passes as many as a
                // single render's 4096) is the method's own cost, charged to it.
                supersample: target.supersample(o.spp, o.feature_spp.min(PPM_FEATURE_SPP)),
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
            let errors = self.measure(&img);
            (self.log)(Progress::Finished(&format!(
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
                passes: Some(n),
                times: StageTimes { total: secs, ..Default::default() },
                errors,
                seeds: 1,
                regions: Vec::new(),
                image: img,
            });
        }
        Ok(())
    }
}
