//! `render` (an image as a numpy array, and the EXR and PNG `photonkit render` writes) and
//! `compare` (every method against the truth, `photonkit compare`).

use std::path::PathBuf;

use numpy::{PyArray1, PyArrayMethods};
use photonkit::eval::compare::{CompareError, CompareOptions, MethodKind, Target};
use photonkit::eval::report::{self, Run};
use photonkit::eval::truth::{Quality, TruthError};
use photonkit::render::from_map::{CameraChanges, DiagnosticView, Framing, MapRender, render_map};
use photonkit::render::{Diagnostic, Estimator, EyeOptions, Kernel, Mode, Outputs, Specular};
use photonkit::scene::{Camera, Scene, SceneFile, unsupported_warning};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{Failure, Kind};
use crate::map::input;
use crate::stages::{load_scene, notes, refuse_input_as_output, tell_scene};
use crate::{options, run};

/// The scene's own camera.
fn scene_camera(scene: &Scene) -> Option<&Camera> {
    scene.camera()
}

/// "x=VALUE", "y=VALUE" or "z=VALUE", as `render --plane` reads it.
fn plane(s: &str) -> Result<(usize, f32), Failure> {
    let bad = |m: String| Failure::value(format!("invalid value '{s}' for 'plane': {m}"));
    let (axis, value) = s
        .split_once('=')
        .ok_or_else(|| bad(format!("'{s}': write the plane as x=VALUE, y=VALUE or z=VALUE")))?;
    let axis = match axis.trim() {
        "x" | "X" => 0,
        "y" | "Y" => 1,
        "z" | "Z" => 2,
        a => return Err(bad(format!("'{a}': the plane's axis is x, y or z"))),
    };
    match value.trim().parse::<f32>() {
        Ok(v) if v.is_finite() => Ok((axis, v)),
        _ => Err(bad(format!("'{value}': not a number"))),
    }
}

/// Renders a photon map (`photonkit render`): radiance through the scene's camera (or
/// irradiance with `mode="irradiance"`, or on a `plane` without a scene), returned as a
/// float32 array of shape (height, width, 3), top row first, in W/(m²·sr) (W/m² for
/// irradiance) per RGB channel. With `output`, also writes the EXR and its PNG preview as
/// `photonkit render -o` does.
#[pyfunction]
#[pyo3(signature = (map, output=None, *, scene=None, mode=None, estimator="knn", kernel="epanechnikov",
    k=None, max_radius=None, diffusion_k=500, diffusion_q=0.02, diagnostic=None, threshold=0.5,
    dot_radius=None, plane=None, rect=None, plane_tolerance=1e-3, png=None, no_png=false, exposure=0.0,
    fixed_exposure=false, width=None, height=None, spp=4, specular="split", max_depth=16, eye=None,
    look_at=None, up=None, fov=None, ortho=None, seed=0, threads=None, memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    map: &Bound<'py, PyAny>,
    output: Option<&Bound<'py, PyAny>>,
    scene: Option<&Bound<'py, PyAny>>,
    mode: Option<&str>,
    estimator: &str,
    kernel: &str,
    k: Option<usize>,
    max_radius: Option<f32>,
    diffusion_k: usize,
    diffusion_q: f32,
    diagnostic: Option<&str>,
    threshold: f32,
    dot_radius: Option<f32>,
    plane: Option<&str>,
    rect: Option<[f32; 4]>,
    plane_tolerance: f32,
    png: Option<&Bound<'py, PyAny>>,
    no_png: bool,
    exposure: f32,
    fixed_exposure: bool,
    width: Option<u32>,
    height: Option<u32>,
    spp: u32,
    specular: &str,
    max_depth: u32,
    eye: Option<&Bound<'py, PyAny>>,
    look_at: Option<&Bound<'py, PyAny>>,
    up: Option<&Bound<'py, PyAny>>,
    fov: Option<f32>,
    ortho: Option<f32>,
    seed: u64,
    threads: Option<usize>,
    memory: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let memory = memory.map(options::memory).transpose()?;
    if memory.is_some() && (plane.is_some() || diagnostic.is_some()) {
        return Err(Failure::value("memory cannot be given with plane or diagnostic".into()).into());
    }
    let map = input(map)?;
    let map = map.get();
    let output = options::opt_path(output)?;
    let scene_path = options::opt_path(scene)?;
    let png = options::opt_path(png)?;
    if png.is_some() && no_png {
        return Err(Failure::value("png and no_png cannot be given together".into()).into());
    }
    if plane.is_none() && (rect.is_some() || plane_tolerance != 1e-3) {
        return Err(Failure::value("rect and plane_tolerance need plane".into()).into());
    }
    if fov.is_some() && ortho.is_some() {
        return Err(Failure::value("fov and ortho cannot be given together".into()).into());
    }
    if let Some([u0, v0, u1, v1]) = rect
        && !(rect.into_iter().flatten().all(f32::is_finite) && u1 > u0 && v1 > v0)
    {
        return Err(Failure::value(format!(
            "invalid value '{u0},{v0},{u1},{v1}' for 'rect': expected u0,v0,u1,v1 with u0 < u1 and v0 < v1"
        ))
        .into());
    }
    for (option, x) in [
        ("threshold", threshold),
        ("diffusion_q", diffusion_q),
        ("exposure", exposure),
        ("plane_tolerance", plane_tolerance),
    ] {
        options::finite(option, x)?;
    }
    for (option, x) in
        [("max_radius", max_radius), ("dot_radius", dot_radius), ("fov", fov), ("ortho", ortho)]
    {
        if let Some(x) = x {
            options::finite(option, x)?;
        }
    }
    let plane = plane.map(self::plane).transpose()?;
    let mode = mode
        .map(|m| options::choice("mode", m, &["full", "caustic", "direct", "irradiance"]))
        .transpose()?
        .map(|m| match m {
            "full" => Mode::Full,
            "caustic" => Mode::Caustic,
            "direct" => Mode::Direct,
            _ => Mode::Irradiance,
        });
    let kernel = match options::choice("kernel", kernel, &["epanechnikov", "disc", "cone"])? {
        "disc" => Kernel::Disc,
        "cone" => Kernel::Cone,
        _ => Kernel::Epanechnikov,
    };
    let estimator = options::choice("estimator", estimator, &["knn", "diffusion", "variable"])?;
    // A map grown in refinement, with no k asked for: each estimate gathers within the distance
    // of the 15th nearest of its first photons, as `photonkit render` does (docs/progressive.md).
    let grown = k.is_none()
        && max_radius.is_none()
        && estimator == "knn"
        && photonkit::refine::first_photons(&map.view()).is_some();
    let k = k.unwrap_or(15);
    let estimator = match estimator {
        "diffusion" => Estimator::Diffusion { k: diffusion_k, q: diffusion_q },
        "variable" => Estimator::Variable { k, kernel },
        _ if grown => Estimator::LocalRadius { k, scale: 1.0, kernel },
        _ => Estimator::Knn { k, kernel, max_radius },
    };
    let diagnostic = diagnostic
        .map(|d| options::choice("diagnostic", d, &["params", "path-length", "constrained", "splat"]))
        .transpose()?
        .map(|d| DiagnosticView {
            which: match d {
                "params" => Diagnostic::Params,
                "path-length" => Diagnostic::PathLength,
                "constrained" => Diagnostic::Constrained,
                _ => Diagnostic::Splat,
            },
            threshold,
            dot_radius,
        });
    let specular = match options::choice("specular", specular, &["split", "sample"])? {
        "sample" => Specular::Sample,
        _ => Specular::Split,
    };
    let changes = CameraChanges {
        eye: eye.map(|v| options::vec3("eye", v)).transpose()?,
        look_at: look_at.map(|v| options::vec3("look_at", v)).transpose()?,
        up: up.map(|v| options::vec3("up", v)).transpose()?,
        fov_deg: fov,
        ortho_height_m: ortho,
        width,
        height,
    };
    let outputs = output.as_ref().map(|exr| Outputs {
        exr: Some(exr.clone()),
        png: if no_png { None } else { Some(png.clone().unwrap_or_else(|| exr.with_extension("png"))) },
        exposure,
        fixed_exposure,
        codes: diagnostic.is_some(),
    });
    let ((w, h, pixels), told) = run(py, threads, || {
        let view = map.view();
        for p in outputs.iter().flat_map(|o| o.exr.iter().chain(&o.png)) {
            refuse_input_as_output(p)?;
        }
        let mut told = Vec::new();
        let scene = match plane {
            Some(_) => None,
            None => {
                let r = photonkit::scene::for_map(Some(&view), scene_path.as_deref())?;
                told.extend(r.notes.iter().map(|n| match r.recorded {
                    true => n.clone(),
                    false => format!("{n} (pass scene=FILE, or plane= for a scene-less view)"),
                }));
                Some((r.scene, r.name))
            }
        };
        let framing = match (plane, &scene) {
            (Some((axis, offset)), _) => {
                Framing::Plane { axis, offset, tolerance_m: plane_tolerance, rect, width, height }
            }
            (None, Some((scene, name))) => {
                Framing::Scene { scene, camera: changes.camera(scene_camera(scene))?, name: name.clone() }
            }
            (None, None) => unreachable!("a scene is resolved whenever no plane is given"),
        };
        let request = MapRender {
            mode,
            estimator,
            diagnostic,
            spp,
            eye: EyeOptions { specular, max_depth, ..EyeOptions::default() },
            seed,
            keep_samples: outputs.is_some(),
            ..MapRender::new(framing)
        };
        let rendered = match memory {
            Some(budget) => photonkit::render::from_map::render_map_within(&view, &request, budget, &|_| {})?,
            None => render_map(&view, &request, &|_| {})?,
        };
        told.extend(rendered.remarks.iter().cloned());
        let plan = rendered.plan;
        if plan.tiles > 1 || plan.chunks > 1 {
            told.push(format!(
                "the estimate streamed the map in {} tiles, {} pass{}, to stay under memory={}",
                plan.tiles,
                plan.chunks,
                if plan.chunks == 1 { "" } else { "es" },
                memory.unwrap_or(0)
            ));
        }
        if let Some(o) = &outputs {
            photonkit::render::image::write(&rendered.image, o, &rendered.notes)?;
        }
        let image = &rendered.image;
        let pixels: Vec<f32> = image.pixels.iter().flat_map(|p| p.to_array()).collect();
        Ok(((image.width as usize, image.height as usize, pixels), told))
    })?;
    notes(py, &told)?;
    Ok(PyArray1::from_vec(py, pixels).reshape([h, w, 3])?.into_any())
}

/// Runs every method on the same traced photons of a scene, times every stage and measures
/// each image against the truth (`photonkit compare`, one run: loop in Python for a sweep).
/// Writes report.md, report.csv and the images into `out_dir`; returns a dict with `rows`
/// (one dict per method, setting and region, the columns of report.csv), `table` (the
/// report's Table I in Markdown) and `report` (the path of report.md).
#[pyfunction]
#[pyo3(signature = (scene=None, out_dir=None, *, photons=None, seed=1,
    methods=None, k=15, pm_k=None, estimator="knn", kc=CompareOptions::default().kc,
    beta=CompareOptions::default().beta, growths=CompareOptions::default().growths,
    spectral_scale=CompareOptions::default().spectral_scale, k_density=None,
    iterations=CompareOptions::default().iterations, kf=CompareOptions::default().kf,
    spectral_window=CompareOptions::default().spectral_window, iterations_2009=14, diffusion_k=500, diffusion_q=0.02, ppm_passes=None, ppm_photons=None,
    ppm_k=30, spp=16, feature_spp=CompareOptions::default().feature_spp, seeds=4, cells=128, reference_passes=64, fast_truth=false, threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn compare<'py>(
    py: Python<'py>,
    scene: Option<&Bound<'py, PyAny>>,
    out_dir: Option<&Bound<'py, PyAny>>,
    photons: Option<&Bound<'py, PyAny>>,
    seed: u64,
    methods: Option<Vec<String>>,
    k: usize,
    pm_k: Option<Vec<usize>>,
    estimator: &str,
    kc: usize,
    beta: f32,
    growths: u32,
    spectral_scale: f32,
    k_density: Option<usize>,
    iterations: usize,
    kf: usize,
    spectral_window: f32,
    iterations_2009: usize,
    diffusion_k: usize,
    diffusion_q: f32,
    ppm_passes: Option<Vec<u64>>,
    ppm_photons: Option<&Bound<'py, PyAny>>,
    ppm_k: usize,
    spp: u32,
    feature_spp: u32,
    seeds: u32,
    cells: usize,
    reference_passes: u64,
    fast_truth: bool,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene_path = options::opt_path(scene)?;
    let out_dir = options::opt_path(out_dir)?.unwrap_or_else(|| PathBuf::from("photonkit-compare"));
    let defaults = CompareOptions::default();
    let methods = match methods {
        None => defaults.methods.clone(),
        Some(list) => list
            .iter()
            .map(|m| {
                MethodKind::from_slug(m.trim()).ok_or_else(|| {
                    Failure::value(format!(
                        "--methods: unknown method '{m}' (pm, relax2009, diffusion, ours, ppm, ours-progressive)"
                    ))
                })
            })
            .collect::<Result<_, _>>()?,
    };
    let variable_kernel = options::choice("estimator", estimator, &["knn", "variable"])? == "variable";
    let o = CompareOptions {
        photons: photons.map(options::count).transpose()?.unwrap_or(defaults.photons),
        seed,
        k,
        pm_ks: pm_k.unwrap_or(defaults.pm_ks),
        variable_kernel,
        kc,
        beta,
        k_density,
        growths,
        spectral_scale: options::finite("spectral_scale", spectral_scale)?,
        kf,
        spectral_window: options::finite("spectral_window", spectral_window)?,
        iterations,
        iterations_2009,
        diffusion_k,
        diffusion_q,
        ppm_passes: ppm_passes.unwrap_or(defaults.ppm_passes),
        ppm_photons_per_pass: ppm_photons.map(options::count).transpose()?,
        refine_photons_per_pass: None,
        ppm_k,
        // ours-progressive runs at the library's pass counts (1, 4, 16).
        refine_passes: defaults.refine_passes.clone(),
        refine_iterations: defaults.refine_iterations,
        refine_growth: defaults.refine_growth,
        refine_prior: defaults.refine_prior,
        refine_prior_hold: defaults.refine_prior_hold,
        spp,
        feature_spp,
        seeds,
        methods,
    };
    o.check().map_err(Failure::from)?;
    if cells < 4 {
        return Err(Failure::value("--cells needs at least 4".into()).into());
    }
    let (rows, table, told, warning) = run(py, threads, || {
        let SceneFile { scene, name: label, content: text, notes: mut told, unsupported } =
            load_scene(scene_path.as_deref())?;
        let warning = unsupported_warning(&label, &unsupported);
        std::fs::create_dir_all(&out_dir).map_err(|e| Failure {
            kind: Kind::Os(e.kind()),
            message: format!("creating {}: {e}", out_dir.display()),
        })?;
        let quality = if fast_truth { Quality::Test } else { Quality::Report };
        let target = match Target::closed_form(&scene, cells, quality) {
            Ok(t) => t,
            Err(CompareError::Truth(TruthError::Unsupported(why))) => {
                told.push(format!(
                    "no closed-form truth for this scene ({why}): the truth is a progressive reference of \
                     {reference_passes} passes"
                ));
                let Some(cam) = scene_camera(&scene).cloned() else {
                    return Err(Failure::runtime(
                        "the scene has no [camera] to view the reference through".into(),
                    ));
                };
                let h = ((cells as f64) * cam.resolution[1] as f64 / cam.resolution[0] as f64)
                    .round()
                    .max(1.0) as u32;
                let cam = Camera { resolution: [cells as u32, h], ..cam };
                let per_pass = o.ppm_photons_per_pass.unwrap_or(o.photons);
                Target::progressive_reference(
                    &scene,
                    cam,
                    Mode::Caustic,
                    reference_passes,
                    per_pass,
                    o.spp,
                    &|_| {},
                )?
            }
            Err(e) => return Err(e.into()),
        };
        told.push(format!("truth: {}", target.description));
        let rows = photonkit::eval::compare::run(&scene, &label, &text, &target, &o, &out_dir, &|_| {})?;
        let runs = [Run { label: String::new(), rows }];
        let title = format!("photonkit compare: {label}");
        report::write(
            &out_dir,
            &title,
            &target,
            &runs,
            &format!("photonkit.compare({label:?}) from Python"),
            [o.spp, o.feature_spp],
        )?;
        let [run] = runs;
        Ok((report::csv(std::slice::from_ref(&run)), report::table_markdown(&run.rows), told, warning))
    })?;
    tell_scene(py, &told, warning.as_deref())?;
    let result = PyDict::new(py);
    result.set_item("rows", csv_rows(py, &rows)?)?;
    result.set_item("table", table)?;
    result.set_item("report", options::text(&out_dir.join("report.md")))?;
    Ok(result)
}

/// report.csv's lines as dicts: numbers as floats (ints for counts), empty cells as None.
fn csv_rows<'py>(py: Python<'py>, csv: &str) -> PyResult<Bound<'py, PyAny>> {
    let reader = py
        .import("csv")?
        .call_method1("DictReader", (py.import("io")?.call_method1("StringIO", (csv,))?,))?;
    let rows = pyo3::types::PyList::empty(py);
    let text_columns = ["run", "method", "setting", "region"];
    let int_columns = ["emitted", "photons", "radiance_k", "seeds", "cells"];
    for row in reader.try_iter()? {
        let row = row?.cast_into::<PyDict>()?;
        let out = PyDict::new(py);
        for (key, value) in row.iter() {
            let (key, value): (String, String) = (key.extract()?, value.extract()?);
            if text_columns.contains(&key.as_str()) {
                out.set_item(key, value)?;
            } else if value.is_empty() {
                out.set_item(key, py.None())?;
            } else if int_columns.contains(&key.as_str()) {
                out.set_item(key, value.parse::<u64>().map_err(|e| Failure::runtime(e.to_string()))?)?;
            } else {
                out.set_item(key, value.parse::<f64>().map_err(|e| Failure::runtime(e.to_string()))?)?;
            }
        }
        rows.append(out)?;
    }
    Ok(rows.into_any())
}
