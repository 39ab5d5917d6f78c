//! The photon-map stages: trace, detect, relax, collapse, and detect → relax → collapse →
//! relax in one call. Each takes the command line's options as keyword arguments (the same
//! names in snake_case, the same defaults), runs with the interpreter released, and returns
//! the new map: in memory, or written to `output` (as the command line writes it, byte for
//! byte) and opened from there.

use std::path::{Path, PathBuf};

use photonkit::detect::{DetectParams, Method, NoiseModel};
use photonkit::format::{self, ColumnSpec, MapView, Output, PhotonTable, guard, name};
use photonkit::pipeline::{PipelineError, PipelineParams, Stage, StageDone};
use photonkit::relax::RelaxParams;
use photonkit::scene::{Scene, SceneFile, unsupported_warning};
use photonkit::trace::{Budget, Shard, Spool, StorePolicy, TraceOptions};
use pyo3::prelude::*;

use crate::errors::{Failure, Kind};
use crate::map::{PhotonMap, Source, input, write_view};
use crate::{options, run};

/// Tells the user what the command line prints as a note: the logger `photonkit`, level INFO.
pub fn notes(py: Python<'_>, notes: &[String]) -> PyResult<()> {
    if notes.is_empty() {
        return Ok(());
    }
    let logger = py.import("logging")?.call_method1("getLogger", ("photonkit",))?;
    for n in notes {
        logger.call_method1("info", (n,))?;
    }
    Ok(())
}

/// What the command line prints as a warning: a Python `UserWarning`.
fn warn(py: Python<'_>, message: &str) -> PyResult<()> {
    py.import("warnings")?
        .call_method1("warn", (message, py.get_type::<pyo3::exceptions::PyUserWarning>(), 2))?;
    Ok(())
}

/// Refuses, before any work, an output that is one of the inputs open in this process.
pub fn refuse_input_as_output(output: &Path) -> Result<(), Failure> {
    Ok(guard::check_output(output)?)
}

/// A stage's map: written to `output` and opened from there, or kept in memory.
fn finish(table: PhotonTable, output: Option<PathBuf>, context: &str) -> Result<Source, Failure> {
    match output {
        Some(p) => write_view(&table, p, Some(context)),
        None => Ok(Source::Memory(Box::new(table.into_owned()))),
    }
}

/// Tells the user what the command line tells about a scene: its notes to the `photonkit`
/// logger, what it holds and the tracer does not honour as one `UserWarning`.
pub fn tell_scene(py: Python<'_>, told: &[String], warning: Option<&str>) -> PyResult<()> {
    notes(py, told)?;
    if let Some(w) = warning {
        warn(py, w)?;
    }
    Ok(())
}

/// The scene file at `path` (TOML or glTF, its `name` as records give it), or the embedded
/// default, as `photonkit trace` loads it.
pub fn load_scene(path: Option<&Path>) -> Result<SceneFile, Failure> {
    Ok(match path {
        Some(p) => SceneFile { name: options::text(p), ..SceneFile::read(p)? },
        None => SceneFile::default_scene(),
    })
}

fn shard(value: &Bound<'_, PyAny>) -> PyResult<Shard> {
    let (index, count): (u64, u64) = match value.extract::<String>() {
        Ok(s) => {
            let bad = || Failure::value(format!("'{s}': write the shard as i/n, e.g. 0/4"));
            let (i, n) = s.split_once('/').ok_or_else(bad)?;
            match (i.trim().parse(), n.trim().parse()) {
                (Ok(i), Ok(n)) => (i, n),
                _ => return Err(Failure::value(format!("'{s}': needs whole numbers with 0 ≤ i < n")).into()),
            }
        }
        Err(_) => value.extract()?,
    };
    if index >= count {
        return Err(Failure::value(format!("'{index}/{count}': needs whole numbers with 0 ≤ i < n")).into());
    }
    Ok(Shard { index, count })
}

/// Traces photons from a scene file (the embedded default scene without one) and stores the
/// caustic ones with their trajectory parameters (`photonkit trace`).
#[pyfunction]
#[pyo3(signature = (scene=None, output=None, *, photons=None, stored=None, seed=1, shard=None,
    store="caustic", threads=None, max_bounces=64, memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn trace(
    py: Python<'_>,
    scene: Option<&Bound<'_, PyAny>>,
    output: Option<&Bound<'_, PyAny>>,
    photons: Option<&Bound<'_, PyAny>>,
    stored: Option<&Bound<'_, PyAny>>,
    seed: u64,
    shard: Option<&Bound<'_, PyAny>>,
    store: &str,
    threads: Option<usize>,
    max_bounces: u32,
    memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<PhotonMap> {
    let scene_path = options::opt_path(scene)?;
    let output = options::opt_path(output)?;
    let photons = photons.map(options::count).transpose()?;
    let stored = stored.map(options::count).transpose()?;
    let shard = shard.map(self::shard).transpose()?;
    let memory = memory.map(options::memory).transpose()?.unwrap_or(photonkit::trace::DEFAULT_SPOOL_MEMORY);
    if photons.is_some() && stored.is_some() {
        return Err(Failure::value("photons and stored cannot be given together".into()).into());
    }
    if stored.is_some() && shard.is_some() {
        return Err(Failure::value("stored and shard cannot be given together".into()).into());
    }
    let store = match options::choice("store", store, &["caustic", "direct"])? {
        "direct" => StorePolicy::Direct,
        _ => StorePolicy::Caustic,
    };
    let (source, nothing_stored, told, warning) = run(py, threads, || {
        let SceneFile { scene, name: label, content: text, notes: told, unsupported } =
            load_scene(scene_path.as_deref())?;
        let warning = unsupported_warning(&label, &unsupported);
        if let Some(p) = &output {
            refuse_input_as_output(p)?;
        }
        let budget = match (photons, stored) {
            (_, Some(0)) | (Some(0), _) => {
                return Err(Failure::value("--photons and --stored need at least 1".into()));
            }
            (_, Some(n)) => Budget::Stored(n),
            (Some(n), None) => Budget::Emitted(n),
            (None, None) => Budget::Emitted(1_000_000),
        };
        let opts = TraceOptions {
            seed,
            budget,
            store,
            shard,
            max_bounces,
            // Written to a file, photons beyond `memory` wait on the output's disk; kept in
            // memory, they are all held there anyway.
            spool: output.as_ref().map(|p| Spool { dir: format::folder_of(p).to_path_buf(), memory }),
        };
        let traced = photonkit::trace::trace(&scene, &opts, &|_, _| {})?;
        let nothing = traced.stored == 0 && shard.is_none();
        let mut info = photonkit::trace::map_info(&scene, &opts, &traced, &label, &text);
        let source = match output {
            Some(p) => {
                if let Some(scene_file) = &scene_path {
                    photonkit::trace::record_scene_location(&mut info, scene_file, &p);
                }
                traced.write(Output::Path(p.clone()), info)?;
                Source::File(Box::new(format::PhotonMap::open_path(&p)?))
            }
            None => Source::Memory(Box::new(traced_table(&traced, info)?)),
        };
        Ok((source, nothing, told, warning))
    })?;
    tell_scene(py, &told, warning.as_deref())?;
    if nothing_stored {
        warn(py, "no photon was stored (does light reach a diffuse surface through a mirror or glass?)")?;
    }
    Ok(PhotonMap { source })
}

/// The traced photons as an in-memory map with the columns, in the order, a file gets.
fn traced_table(
    traced: &photonkit::trace::Traced,
    info: format::MapInfo,
) -> Result<PhotonTable<'static>, Failure> {
    let p = traced.photons()?;
    let bytes = |spec: &ColumnSpec| -> &[u8] {
        match spec.name.as_str() {
            name::POSITION => bytemuck::cast_slice(&p.position),
            name::NORMAL => bytemuck::cast_slice(&p.normal),
            name::FLUX => bytemuck::cast_slice(&p.flux),
            name::INCIDENT => bytemuck::cast_slice(&p.incident),
            name::EMITTER => bytemuck::cast_slice(&p.emitter),
            name::PARAMS => bytemuck::cast_slice(&p.params),
            name::PATH_LENGTH => bytemuck::cast_slice(&p.path_length),
            name::BOUNCES => bytemuck::cast_slice(&p.bounces),
            name::EMISSION_INDEX => bytemuck::cast_slice(&p.emission_index),
            name::SURFACE => bytemuck::cast_slice(&p.surface),
            _ => &[],
        }
    };
    let columns: Vec<(ColumnSpec, &[u8])> = traced
        .column_specs()
        .into_iter()
        .map(|s| {
            let b = bytes(&s);
            (s, b)
        })
        .collect();
    Ok(PhotonTable::from_columns("<trace>", info, &columns)?.into_owned())
}

/// The detection settings shared by `detect` and `pipeline`, checked as the command line's.
#[allow(clippy::too_many_arguments)]
fn detect_params(
    method: Option<&str>,
    kc: usize,
    beta: f32,
    growths: u32,
    spectral_scale: f32,
    k_density: Option<usize>,
    gain: f32,
    mu_sigma: &str,
) -> Result<(Option<Method>, DetectParams), Failure> {
    let method = method
        .map(|m| options::choice("method", m, &["param-pca", "world-pca", "gradient", "none"]))
        .transpose()?
        .map(|m| match m {
            "param-pca" => Method::ParamPca,
            "world-pca" => Method::WorldPca,
            "gradient" => Method::Gradient,
            _ => Method::None,
        });
    let noise = match options::choice("mu_sigma", mu_sigma, &["simulated", "paper"])? {
        "paper" => NoiseModel::Paper,
        _ => NoiseModel::Simulated,
    };
    let p = DetectParams {
        kc,
        beta: options::finite("beta", beta)?,
        growths,
        spectral_scale: options::finite("spectral_scale", spectral_scale)?,
        k_density,
        gain: options::finite("gain", gain)?,
        noise,
        ..DetectParams::default()
    };
    Ok((method, p))
}

/// Feature detection (Eq. 1–7): a constraint basis per photon for `relax` (`photonkit detect`).
#[pyfunction]
#[pyo3(signature = (map, output=None, *, method=None, kc=DetectParams::default().kc,
    beta=DetectParams::default().beta, growths=DetectParams::default().growths,
    spectral_scale=DetectParams::default().spectral_scale, k_density=None, gain=photonkit::detect::DEFAULT_GAIN,
    mu_sigma="simulated", memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn detect(
    py: Python<'_>,
    map: &Bound<'_, PyAny>,
    output: Option<&Bound<'_, PyAny>>,
    method: Option<&str>,
    kc: usize,
    beta: f32,
    growths: u32,
    spectral_scale: f32,
    k_density: Option<usize>,
    gain: f32,
    mu_sigma: &str,
    memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<PhotonMap> {
    let (requested, p) = detect_params(method, kc, beta, growths, spectral_scale, k_density, gain, mu_sigma)?;
    let memory = memory.map(options::memory).transpose()?;
    let map = input(map)?;
    let map = map.get();
    let output = options::opt_path(output)?;
    let (source, told) = run(py, None, || {
        let view = map.view();
        if let Some(p) = &output {
            refuse_input_as_output(p)?;
        }
        let mut told = Vec::new();
        let (method, note) = photonkit::detect::choose_method(&view, requested)?;
        told.extend(note);
        let p = DetectParams { method, ..p };
        let capped = p.capped(view.len());
        if capped.kc < p.kc {
            told.push(format!(
                "--kc {} exceeds the map's {} photons: using Kc = {}",
                p.kc,
                view.len(),
                capped.kc
            ));
        }
        let t = std::time::Instant::now();
        let tiling = match memory {
            Some(budget) => photonkit::tiles::tiling_for_budget(
                view.positions(),
                budget,
                &photonkit::detect::memory(&view),
            )?,
            None => None,
        };
        let d = match &tiling {
            Some(tiling) => {
                told.push(format!(
                    "detecting in {} tiles to stay under memory={}",
                    tiling.len(),
                    memory.unwrap_or(0)
                ));
                let radius = photonkit::detect::Radius::for_budget(
                    view.len(),
                    memory.unwrap_or(0),
                    0,
                    &photonkit::detect::memory(&view),
                );
                photonkit::detect::detect_map_tiled(
                    &view,
                    &capped,
                    tiling,
                    radius,
                    &|_| {},
                    &mut |_, _, _| {},
                )?
            }
            None => photonkit::detect::detect_map(&view, &capped, &|_| {})?,
        };
        let table = photonkit::detect::detected_map(&view, d, &capped, t.elapsed().as_secs_f64())?;
        Ok((finish(table, output, "writing the detected map")?, told))
    })?;
    notes(py, &told)?;
    Ok(PhotonMap { source })
}

/// The scene relaxation returns photons to: `given`, or the one the map's trace record names
/// when it is found; none otherwise (photons then move in their tangent planes), as `photonkit
/// relax` finds it.
fn relax_scene(
    view: &MapView,
    given: Option<&Path>,
    told: &mut Vec<String>,
) -> Result<Option<Scene>, Failure> {
    match photonkit::scene::for_map(Some(view), given) {
        Ok(r) if r.recorded => {
            told.extend(r.notes);
            Ok(Some(r.scene))
        }
        Ok(_) => Ok(None),
        Err(e) if given.is_some() => Err(e.into()),
        Err(e) => {
            told.push(format!("{e}; photons move in their tangent planes"));
            Ok(None)
        }
    }
}

/// Relaxation's settings as `photonkit relax` checks them.
fn relax_params(
    iterations: usize,
    kf: usize,
    epsilon: f32,
    step_limit: f32,
    flux_diffusion: f32,
    spectral_window: f32,
) -> Result<RelaxParams, Failure> {
    let p = RelaxParams { iterations, kf, epsilon, step_limit, flux_diffusion, spectral_window };
    let ok = p.epsilon.is_finite()
        && p.epsilon >= 0.0
        && p.step_limit.is_finite()
        && p.step_limit > 0.0
        && (0.0..=1.0).contains(&p.flux_diffusion);
    // A spectral window out of range is refused by the stage itself, as on the command line.
    if !ok {
        return Err(Failure::value(
            "--epsilon must be ≥ 0, --step-limit > 0 and --flux-diffusion in [0, 1]".into(),
        ));
    }
    Ok(p)
}

/// Relaxation (Eq. 8–9): photons pushed apart toward blue noise, along their constraint basis
/// (`photonkit relax`).
#[pyfunction]
#[pyo3(signature = (map, output=None, *, iterations=RelaxParams::default().iterations,
    kf=RelaxParams::default().kf, epsilon=RelaxParams::default().epsilon,
    step_limit=RelaxParams::default().step_limit, scene=None,
    flux_diffusion=RelaxParams::default().flux_diffusion,
    spectral_window=RelaxParams::default().spectral_window, memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn relax(
    py: Python<'_>,
    map: &Bound<'_, PyAny>,
    output: Option<&Bound<'_, PyAny>>,
    iterations: usize,
    kf: usize,
    epsilon: f32,
    step_limit: f32,
    scene: Option<&Bound<'_, PyAny>>,
    flux_diffusion: f32,
    spectral_window: f32,
    memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<PhotonMap> {
    let p = relax_params(iterations, kf, epsilon, step_limit, flux_diffusion, spectral_window)?;
    let memory = memory.map(options::memory).transpose()?;
    let map = input(map)?;
    let map = map.get();
    let output = options::opt_path(output)?;
    let scene = options::opt_path(scene)?;
    let (source, told) = run(py, None, || {
        let view = map.view();
        if let Some(p) = &output {
            refuse_input_as_output(p)?;
        }
        let mut told = Vec::new();
        let capped = p.capped(view.len());
        if capped.kf < p.kf {
            told.push(format!(
                "--kf {} exceeds the {} other photons in the map: using Kf = {}",
                p.kf, capped.kf, capped.kf
            ));
        }
        let t = std::time::Instant::now();
        let scene = relax_scene(&view, scene.as_deref(), &mut told)?;
        let model = photonkit::relax::tiled::memory(scene.is_some());
        let tiling = match memory {
            Some(budget) => photonkit::tiles::tiling_for_budget(view.positions(), budget, &model)?,
            None => None,
        };
        let relaxed = match &tiling {
            Some(tiling) => {
                told.push(format!(
                    "relaxing in {} tiles to stay under memory={}",
                    tiling.len(),
                    memory.unwrap_or(0)
                ));
                photonkit::relax::relax_tiled(&view, &capped, scene.as_ref(), tiling, |_, _, _| {})?
            }
            None => photonkit::relax::relax_map_on(&view, &capped, scene.as_ref(), |_| {})?,
        };
        if relaxed.refused_moves > 0 {
            told.push(format!(
                "{} moves were refused because the photon's surface was not found where it moved",
                relaxed.refused_moves
            ));
        }
        if !relaxed.constrained {
            told.push(format!(
                "{} has no constraint basis (run `photonkit detect` first): relaxed unconstrained",
                view.file_name()
            ));
        }
        let table = photonkit::relax::relaxed_map(&view, relaxed, &capped, t.elapsed().as_secs_f64())?;
        Ok((finish(table, output, "writing the relaxed map")?, told))
    })?;
    notes(py, &told)?;
    Ok(PhotonMap { source })
}

/// Collapse: drops the parameter dimensions from the neighbour search (Algorithm 1); the next
/// `relax` works in world space (`photonkit collapse`).
#[pyfunction]
#[pyo3(signature = (map, output=None))]
pub fn collapse(
    py: Python<'_>,
    map: &Bound<'_, PyAny>,
    output: Option<&Bound<'_, PyAny>>,
) -> PyResult<PhotonMap> {
    let map = input(map)?;
    let map = map.get();
    let output = options::opt_path(output)?;
    let source = run(py, None, || {
        let view = map.view();
        if let Some(p) = &output {
            refuse_input_as_output(p)?;
        }
        let table = photonkit::relax::collapse(&view)?;
        match output {
            Some(p) => write_view(&table, p, None),
            None => Ok(Source::Memory(Box::new(table.into_owned()))),
        }
    })?;
    Ok(PhotonMap { source })
}

/// Algorithm 1 after the trace, in memory: detect → relax (parameter space) → collapse →
/// relax (world space), with `photonkit pipeline`'s settings. With `out_dir`, each stage's map
/// is written there under the names `pipeline` gives it (detected.phm, relaxed-params.phm,
/// collapsed.phm, relaxed.phm).
#[pyfunction]
#[pyo3(signature = (map, out_dir=None, *, scene=None, method=None, kc=DetectParams::default().kc,
    beta=DetectParams::default().beta, growths=DetectParams::default().growths,
    spectral_scale=DetectParams::default().spectral_scale, k_density=None,
    iterations=RelaxParams::default().iterations, kf=RelaxParams::default().kf,
    spectral_window=RelaxParams::default().spectral_window))]
#[allow(clippy::too_many_arguments)]
pub fn pipeline(
    py: Python<'_>,
    map: &Bound<'_, PyAny>,
    out_dir: Option<&Bound<'_, PyAny>>,
    scene: Option<&Bound<'_, PyAny>>,
    method: Option<&str>,
    kc: usize,
    beta: f32,
    growths: u32,
    spectral_scale: f32,
    k_density: Option<usize>,
    iterations: usize,
    kf: usize,
    spectral_window: f32,
) -> PyResult<PhotonMap> {
    let (requested, dp) = detect_params(
        method,
        kc,
        beta,
        growths,
        spectral_scale,
        k_density,
        photonkit::detect::DEFAULT_GAIN,
        "simulated",
    )?;
    let d = RelaxParams::default();
    let rp = relax_params(iterations, kf, d.epsilon, d.step_limit, d.flux_diffusion, spectral_window)?;
    let map = input(map)?;
    let map = map.get();
    let out_dir = options::opt_path(out_dir)?;
    let scene = options::opt_path(scene)?;
    let (source, told) = run(py, None, || {
        let view = map.view();
        let mut told = Vec::new();
        if let Some(dir) = &out_dir {
            std::fs::create_dir_all(dir).map_err(|e| Failure {
                kind: Kind::Os(e.kind()),
                message: format!("creating {}: {e}", dir.display()),
            })?;
        }
        let scene = relax_scene(&view, scene.as_deref(), &mut told)?;
        let params =
            PipelineParams { detect: dp, method: requested, relax: rp, iterations: [iterations, iterations] };
        let mut last = None;
        let mut on_stage = |done: &StageDone, table: &PhotonTable| -> Result<(), PipelineError> {
            let Some(dir) = &out_dir else { return Ok(()) };
            let file = dir.join(match done.stage {
                Stage::Detect => "detected.phm",
                Stage::RelaxParams => "relaxed-params.phm",
                Stage::Collapse => "collapsed.phm",
                Stage::RelaxWorld => "relaxed.phm",
            });
            table.write(Output::Path(file.clone()))?;
            last = Some(file);
            Ok(())
        };
        let stage_notes = std::cell::RefCell::new(Vec::new());
        let progress = |p: photonkit::pipeline::Progress| {
            if let photonkit::pipeline::Progress::Note(n) = p {
                stage_notes.borrow_mut().push(n.to_string());
            }
        };
        let outcome = photonkit::pipeline::run(&view, scene.as_ref(), &params, &mut on_stage, &progress)?;
        told.extend(stage_notes.into_inner());
        let source = match last {
            Some(file) => Source::File(Box::new(format::PhotonMap::open_path(&file)?)),
            None => Source::Memory(Box::new(outcome.map)),
        };
        Ok((source, told))
    })?;
    notes(py, &told)?;
    Ok(PhotonMap { source })
}
