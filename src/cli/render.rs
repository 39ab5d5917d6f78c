//! `photonkit render` and `photonkit reference`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::format::{PhotonMap, name};
use photonkit::render::{
    self, Diagnostic, Diagnostics, Estimator, EyeOptions, Kernel, Mode, Outputs, PhotonData, PhotonLookup,
    PlaneView, RenderOptions, Renderer, Specular, View,
};
use photonkit::scene::{Camera, Projection, Scene};

/// Render radiance or irradiance from a photon map to OpenEXR (linear float RGB, ZIP) and an
/// sRGB PNG preview.
///
/// Eye rays from the camera pass through mirrors and glass to the first diffuse surface,
/// where the caustic radiance is estimated from the photon map, L = Σ (ρ/π)·Φ_p·w(d_p), with
/// w the kernel over the K nearest photons (Epanechnikov w(d) = 2/(πr²)·(1 − d²/r²), K = 15,
/// by default), and direct light from the emitters is added with shadow rays.
///
/// Units: photon flux is in watts; pixels hold radiance in W/(m²·sr) per RGB channel, or with
/// --mode irradiance the irradiance on the receiver in W/m² (no albedo, no 1/π; eye rays then
/// pass straight through glass, so an orthographic top-down view maps pixels to floor cells).
/// The EXR header records the unit, mode and estimator.
///
/// The scene is --scene, else the scene file the map was traced from (its history names it),
/// else the embedded default scene. With --plane no scene is used: the photons near an
/// axis-aligned plane are viewed orthographically and the image holds irradiance (for photon
/// maps imported from another tracer).
#[derive(clap::Args)]
#[command(
    after_help = "Units: pixels hold radiance in W/(m²·sr) per RGB channel, or irradiance in W/m² with \
    --mode irradiance or --plane; photon flux is in W. The EXR header says which.\n\n\
    Examples:\n  \
    photonkit render map.phm -o map.exr                     # map.exr and map.png, the scene's camera\n  \
    photonkit render map.phm -o top.exr --mode irradiance --eye 0,0,3 --look-at 0,0,0 --up 0,1,0 --ortho 2\n  \
    photonkit render map.phm -o d.exr --estimator diffusion --diffusion-k 500 --diffusion-q 0.02\n  \
    photonkit render map.phm -o c.exr --diagnostic constrained\n  \
    photonkit render imported.phm --plane z=0 --rect -1,-1,1,1 -o floor.exr"
)]
pub struct Args {
    /// Input photon map (`-` for standard input).
    input: String,
    /// Output OpenEXR image; the PNG preview goes beside it (same name, .png) unless --png.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Scene file (TOML) for geometry, materials, lights and camera.
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    #[command(flatten)]
    common: Common,
    /// What to render (default: full, or irradiance with --plane).
    #[arg(long, value_enum)]
    mode: Option<ModeArg>,
    /// Density estimator: `knn`, the K nearest photons with --kernel (radius the distance from
    /// the point to the K-th, the paper's); `variable`, every photon's --kernel of radius the
    /// distance to its own K-th nearest photon (unbiased on stratified photons, where knn reads
    /// about 1 % low); or `diffusion`, diffusion-based photon mapping (an anisotropic kernel
    /// shaped by the structure tensor of the density estimate).
    #[arg(long, value_enum, default_value_t = EstimatorArg::Knn)]
    estimator: EstimatorArg,
    /// Kernel of the knn and variable estimates.
    #[arg(long, value_enum, default_value_t = KernelArg::Epanechnikov)]
    kernel: KernelArg,
    /// K: photons in each knn estimate (variable: the neighbour that sets each photon's radius).
    #[arg(short, default_value_t = 15)]
    k: usize,
    /// Largest kernel radius of the k-NN estimate, metres (fewer than K photons count then).
    #[arg(value_parser = super::finite_f32, long, value_name = "M")]
    max_radius: Option<f32>,
    /// Neighbours of the diffusion estimator (the paper compares with 500).
    #[arg(long, value_name = "N", default_value_t = 500)]
    diffusion_k: usize,
    /// Anisotropy control q of the diffusion estimator: the diffusivity across a feature is
    /// 1/(1 + (g/q)²), g the relative density gradient; smaller q, sharper and noisier.
    #[arg(value_parser = super::finite_f32, long, value_name = "Q", default_value_t = 0.02)]
    diffusion_q: f32,
    /// Instead of radiance, draw the photons as dots coloured by a property.
    #[arg(long, value_enum)]
    diagnostic: Option<DiagnosticArg>,
    /// Constraint factor |basis_v| below which --diagnostic constrained paints a photon red.
    #[arg(value_parser = super::finite_f32, long, default_value_t = 0.5)]
    threshold: f32,
    /// Dot radius of the diagnostic views, metres (default: 0.4 × the local photon spacing).
    #[arg(value_parser = super::finite_f32, long, value_name = "M")]
    dot_radius: Option<f32>,
    /// Scene-less view: the plane AXIS=VALUE (x=, y= or z=), seen from its positive side.
    #[arg(long, value_name = "AXIS=VALUE", value_parser = parse_plane)]
    plane: Option<(usize, f32)>,
    /// The rectangle of the --plane shown: u0,v0,u1,v1 in the plane's two other coordinates
    /// (y,z for x=; z,x for y=; x,y for z=). Default: the photons' bounding box.
    #[arg(long, value_name = "U0,V0,U1,V1", value_parser = parse_rect, requires = "plane", allow_hyphen_values = true)]
    rect: Option<[f32; 4]>,
    /// Photons farther than this from the --plane are left out, metres.
    #[arg(value_parser = super::finite_f32, long, value_name = "M", default_value_t = 1e-3, requires = "plane")]
    plane_tolerance: f32,
}

/// Options `render` and `reference` share.
#[derive(clap::Args)]
struct Common {
    /// PNG preview path (default: the EXR's name with .png).
    #[arg(long, value_name = "FILE")]
    png: Option<PathBuf>,
    /// Write no PNG preview.
    #[arg(long, conflicts_with = "png")]
    no_png: bool,
    /// Preview exposure in stops, added to the automatic exposure (the lit pixels' log-average
    /// luminance exposed to mid-grey); highlights then roll off along a shoulder that keeps
    /// every pixel's hue. The EXR is linear and never exposed.
    #[arg(value_parser = super::finite_f32, long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f32,
    /// Take --exposure as the whole exposure (pixel values times 2^EXPOSURE), not an offset from
    /// the automatic one: the same for every image, for side-by-side comparisons.
    #[arg(long)]
    fixed_exposure: bool,
    /// Image width in pixels (default: the camera's).
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels (default: the camera's, or the width's share of the aspect).
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel (the paper: 4).
    #[arg(long, default_value_t = 4)]
    spp: u32,
    /// How eye rays meet glass: follow both the reflected and refracted rays weighted by
    /// Fresnel, or sample one.
    #[arg(long, value_enum, default_value_t = SpecularArg::Split)]
    specular: SpecularArg,
    /// Specular bounces after which an eye path is dropped.
    #[arg(long, default_value_t = 16)]
    max_depth: u32,
    /// Camera position (overrides the scene's camera), x,y,z.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    eye: Option<Vec3>,
    /// Point at the image centre, x,y,z.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    look_at: Option<Vec3>,
    /// Roughly up in the image, x,y,z.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    up: Option<Vec3>,
    /// Pinhole camera with this vertical field of view, degrees.
    #[arg(value_parser = super::finite_f32, long, value_name = "DEG", conflicts_with = "ortho")]
    fov: Option<f32>,
    /// Orthographic camera showing this height, metres.
    #[arg(value_parser = super::finite_f32, long, value_name = "M")]
    ortho: Option<f32>,
    /// Seed of the sub-pixel jitter and sampled Fresnel choices.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Number of worker threads (default: all cores, or RAYON_NUM_THREADS).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum ModeArg {
    /// Caustic radiance from the photons plus direct light, W/(m²·sr).
    Full,
    /// Caustic radiance from the photons only, W/(m²·sr).
    Caustic,
    /// Direct light only, W/(m²·sr).
    Direct,
    /// The photons' irradiance on the receiver, W/m².
    Irradiance,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum EstimatorArg {
    Knn,
    Diffusion,
    /// Each photon's kernel radius is the distance to its own K-th nearest photon.
    Variable,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum KernelArg {
    Epanechnikov,
    Disc,
    Cone,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum DiagnosticArg {
    /// Colour by trajectory parameters (Fig. 6e).
    Params,
    /// Colour by path length (Fig. 6f).
    PathLength,
    /// Constrained photons (|basis_v| < --threshold) in red (Fig. 6g).
    Constrained,
    /// Every photon as a white dot.
    Splat,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum SpecularArg {
    Split,
    Sample,
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> =
        s.split(',').map(|x| x.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("'{s}': expected three finite numbers x,y,z")),
    }
}

fn parse_rect(s: &str) -> Result<[f32; 4], String> {
    let v: Vec<f32> =
        s.split(',').map(|x| x.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v[..] {
        [u0, v0, u1, v1] if v.iter().all(|c| c.is_finite()) && u1 > u0 && v1 > v0 => Ok([u0, v0, u1, v1]),
        _ => Err(format!("'{s}': expected u0,v0,u1,v1 with u0 < u1 and v0 < v1")),
    }
}

fn parse_plane(s: &str) -> Result<(usize, f32), String> {
    let (axis, value) =
        s.split_once('=').ok_or_else(|| format!("'{s}': write the plane as x=VALUE, y=VALUE or z=VALUE"))?;
    let axis = match axis.trim() {
        "x" | "X" => 0,
        "y" | "Y" => 1,
        "z" | "Z" => 2,
        a => return Err(format!("'{a}': the plane's axis is x, y or z")),
    };
    match value.trim().parse::<f32>() {
        Ok(v) if v.is_finite() => Ok((axis, v)),
        _ => Err(format!("'{value}': not a number")),
    }
}

impl Common {
    fn outputs(&self, exr: &Path) -> Outputs {
        let png = if self.no_png {
            None
        } else {
            Some(self.png.clone().unwrap_or_else(|| exr.with_extension("png")))
        };
        Outputs {
            exr: Some(exr.to_path_buf()),
            png,
            exposure: self.exposure,
            fixed_exposure: self.fixed_exposure,
            codes: false,
        }
    }

    fn eye_options(&self) -> EyeOptions {
        EyeOptions {
            specular: match self.specular {
                SpecularArg::Split => Specular::Split,
                SpecularArg::Sample => Specular::Sample,
            },
            max_depth: self.max_depth,
            ..EyeOptions::default()
        }
    }

    /// The scene's camera with the command line's changes; its resolution is the image's.
    fn camera(&self, scene: &Scene) -> anyhow::Result<Camera> {
        let base = scene.camera().cloned();
        let eye = self.eye.or(base.as_ref().map(|c| c.eye));
        let look = self.look_at.or(base.as_ref().map(|c| c.eye + c.forward));
        let up = self.up.or(base.as_ref().map(|c| c.up)).unwrap_or(Vec3::Z);
        let projection = match (self.fov, self.ortho, base.as_ref()) {
            (Some(f), _, _) if f > 0.0 && f < 180.0 => Projection::Pinhole { fov_y_rad: f.to_radians() },
            (Some(f), _, _) => bail!("--fov {f}: needs a field of view between 0 and 180 degrees"),
            (_, Some(h), _) if h > 0.0 && h.is_finite() => Projection::Orthographic { height_m: h },
            (_, Some(h), _) => bail!("--ortho {h}: needs a positive height in metres"),
            (None, None, Some(c)) => c.projection,
            (None, None, None) => Projection::Pinhole { fov_y_rad: 40f32.to_radians() },
        };
        let (Some(eye), Some(look)) = (eye, look) else {
            bail!("the scene has no [camera]: give --eye and --look-at (and --fov or --ortho)")
        };
        let res = base.as_ref().map_or([600, 600], |c| c.resolution);
        let (w, h) = match (self.width, self.height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, ((w as f64 * res[1] as f64 / res[0] as f64).round() as u32).max(1)),
            (None, Some(h)) => (((h as f64 * res[0] as f64 / res[1] as f64).round() as u32).max(1), h),
            (None, None) => (res[0], res[1]),
        };
        Camera::look_at(projection, eye, look, up, [w, h])
            .context("the camera's eye and look-at coincide, or the view is parallel to up")
    }

    fn options(&self, camera: &Camera, mode: Mode, estimator: Estimator) -> RenderOptions {
        RenderOptions {
            width: camera.resolution[0],
            height: camera.resolution[1],
            spp: self.spp,
            mode,
            estimator,
            eye: self.eye_options(),
            seed: self.seed,
            keep_samples: true,
        }
    }

    fn pool(&self) -> anyhow::Result<Option<rayon::ThreadPool>> {
        self.threads
            .map(|n| {
                rayon::ThreadPoolBuilder::new().num_threads(n).build().context("starting the worker threads")
            })
            .transpose()
    }
}

/// The scene: `--scene`, else the file the map's trace record names (if it still exists),
/// else the embedded default ([`photonkit::scene::for_map`]). Returns the scene and its name.
fn load_scene(map: Option<&PhotonMap>, arg: Option<&Path>) -> anyhow::Result<(Scene, String)> {
    let view = map.map(PhotonMap::view);
    let r = photonkit::scene::for_map(view.as_ref(), arg)?;
    for note in &r.notes {
        if r.recorded {
            eprintln!("photonkit: note: {note}");
        } else {
            super::note!(
                "photonkit render: note: {note} (pass --scene FILE, or --plane for a scene-less view)"
            );
        }
    }
    Ok((r.scene, r.name))
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let target = super::draw_target();
    ProgressBar::with_draw_target(Some(len), target).with_style(
        ProgressStyle::with_template(&format!("{what} {{bar:30}} {{percent}}% {{elapsed}} (eta {{eta}})"))
            .expect("valid template"),
    )
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let map = PhotonMap::open(&a.input)?;
    let file = map.file_name().to_string();
    for p in [Some(a.output.clone()), a.common.outputs(&a.output).png].into_iter().flatten() {
        super::refuse_input_as_output(&p.to_string_lossy())?;
    }
    let mut mode = match a.mode {
        None if a.plane.is_some() => Mode::Irradiance,
        None | Some(ModeArg::Full) => Mode::Full,
        Some(ModeArg::Caustic) => Mode::Caustic,
        Some(ModeArg::Direct) => Mode::Direct,
        Some(ModeArg::Irradiance) => Mode::Irradiance,
    };
    if a.plane.is_some() && mode != Mode::Irradiance {
        bail!("--plane shows irradiance only (no scene, no materials): leave out --mode or use irradiance");
    }
    let kernel = |k: KernelArg| match k {
        KernelArg::Epanechnikov => Kernel::Epanechnikov,
        KernelArg::Disc => Kernel::Disc,
        KernelArg::Cone => Kernel::Cone,
    };
    let estimator = match a.estimator {
        EstimatorArg::Knn => Estimator::Knn { k: a.k, kernel: kernel(a.kernel), max_radius: a.max_radius },
        EstimatorArg::Diffusion => Estimator::Diffusion { k: a.diffusion_k, q: a.diffusion_q },
        EstimatorArg::Variable => Estimator::Variable { k: a.k, kernel: kernel(a.kernel) },
    };
    if a.k == 0 || a.diffusion_k == 0 {
        bail!("-k and --diffusion-k need at least 1 neighbour");
    }
    let positive = |x: f32| x > 0.0 && x.is_finite();
    if !positive(a.diffusion_q)
        || a.max_radius.is_some_and(|r| !positive(r))
        || a.dot_radius.is_some_and(|r| !positive(r))
    {
        bail!("--diffusion-q, --max-radius and --dot-radius must be positive");
    }
    if map.is_empty() {
        bail!("{file}: the photon map holds no photons: nothing to render");
    }
    let traced_direct = map
        .meta()
        .history
        .iter()
        .rev()
        .find(|r| r.stage == "trace")
        .and_then(|r| r.parameters.get("store"))
        .is_some_and(|s| s == "direct");
    if traced_direct && mode == Mode::Full {
        super::note!(
            "photonkit render: note: the map stores direct photons too, so direct light is not added again"
        );
        mode = Mode::Caustic;
    }
    let diagnostic = a
        .diagnostic
        .map(|d| {
            let which = match d {
                DiagnosticArg::Params => Diagnostic::Params,
                DiagnosticArg::PathLength => Diagnostic::PathLength,
                DiagnosticArg::Constrained => Diagnostic::Constrained,
                DiagnosticArg::Splat => Diagnostic::Splat,
            };
            Diagnostics::from_map(&map, which, a.threshold, a.dot_radius)
        })
        .transpose()?;

    // Photon columns: the plane view keeps the photons near its plane (and ignores normals).
    let normals = map.column::<[f32; 3]>(name::NORMAL)?;
    let (positions, flux) = (map.positions(), map.flux());
    // (positions, flux, index in the map) of the photons kept.
    type Kept = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u32>);
    let near_plane: Option<Kept> = a.plane.map(|(axis, offset)| {
        let keep: Vec<u32> = (0..positions.len() as u32)
            .filter(|&i| (positions[i as usize][axis] - offset).abs() <= a.plane_tolerance)
            .collect();
        (
            keep.iter().map(|&i| positions[i as usize]).collect(),
            keep.iter().map(|&i| flux[i as usize]).collect(),
            keep,
        )
    });
    let data = match &near_plane {
        Some((p, f, _)) => PhotonData { positions: p, flux: f, normals: None },
        None => PhotonData { positions, flux, normals },
    };
    if let Some((p, _, _)) = &near_plane
        && p.is_empty()
    {
        bail!("{file}: no photon lies within {} m of the plane", a.plane_tolerance);
    }
    let photons = PhotonLookup::new(&file, data)?.prepared_for(&estimator);
    let diagnostic = match (diagnostic, &near_plane) {
        (Some(d), Some((_, _, keep))) => {
            Some(Diagnostics { colours: keep.iter().map(|&i| d.colours[i as usize]).collect(), ..d })
        }
        (d, _) => d,
    }
    .map(|d| d.bounded(&photons));

    let scene_store;
    let (view, opts, scene_name) = match a.plane {
        Some((axis, offset)) => {
            let rect =
                a.rect.unwrap_or_else(|| PlaneView::frame(axis, &near_plane.as_ref().expect("plane").0));
            let (w, h) = PlaneView::image_size(rect, a.common.width, a.common.height, 600);
            let opts = RenderOptions {
                width: w,
                height: h,
                spp: a.common.spp,
                mode,
                estimator,
                eye: a.common.eye_options(),
                seed: a.common.seed,
                keep_samples: true,
            };
            let name = format!(
                "plane {}={offset} [{}, {}] × [{}, {}]",
                ["x", "y", "z"][axis],
                rect[0],
                rect[2],
                rect[1],
                rect[3]
            );
            (View::Plane(PlaneView::axis_aligned(axis, offset, rect)), opts, name)
        }
        None => {
            let (scene, scene_name) = load_scene(Some(&map), a.scene.as_deref())?;
            scene_store = scene;
            let camera = a.common.camera(&scene_store)?;
            let opts = a.common.options(&camera, mode, estimator);
            (View::Scene { scene: &scene_store, camera }, opts, scene_name)
        }
    };
    let renderer = Renderer { view, photons: Some(&photons), diagnostic: diagnostic.as_ref(), opts };
    let bar = progress_bar(renderer.tiles(), "render");
    let t = Instant::now();
    let result = match a.common.pool()? {
        Some(pool) => pool.install(|| renderer.render(&|n| bar.inc(n))),
        None => renderer.render(&|n| bar.inc(n)),
    };
    bar.finish_and_clear();
    let (img, stats) = result?;
    let secs = t.elapsed().as_secs_f64();
    let o = &renderer.opts;
    let what = match a.diagnostic {
        Some(_) => format!("diagnostic {}", diagnostic_name(a.diagnostic)),
        None => o.estimator.describe(),
    };
    let notes = vec![
        (
            "photonkit:units".to_string(),
            if a.diagnostic.is_some() { "none (false colour)" } else { o.mode.unit() }.to_string(),
        ),
        ("photonkit:mode".to_string(), o.mode.name().to_string()),
        ("photonkit:estimator".to_string(), what.clone()),
        ("photonkit:photon_map".to_string(), file.clone()),
        ("photonkit:scene".to_string(), scene_name),
        ("photonkit:samples_per_pixel".to_string(), o.spp.to_string()),
    ];
    let outputs = Outputs { codes: a.diagnostic.is_some(), ..a.common.outputs(&a.output) };
    render::image::write(&img, &outputs, &notes)?;
    super::note!(
        "photonkit render: {}×{} × {} spp, {} ({}), {} photons: {:.2} s ({:.3} µs/sample, {} lookups)",
        o.width,
        o.height,
        o.spp,
        o.mode.name(),
        what,
        photons.len(),
        secs,
        secs * 1e6 / stats.samples.max(1) as f64,
        stats.lookups
    );
    Ok(ExitCode::SUCCESS)
}

fn diagnostic_name(d: Option<DiagnosticArg>) -> &'static str {
    match d {
        Some(DiagnosticArg::Params) => "params",
        Some(DiagnosticArg::PathLength) => "path-length",
        Some(DiagnosticArg::Constrained) => "constrained",
        Some(DiagnosticArg::Splat) => "splat",
        None => "none",
    }
}

/// Render a reference image by progressive photon mapping (memoryless variant): no photon
/// map needed.
///
/// Each pass traces a fresh caustic photon map from the scene (seed + pass number), renders it
/// with one global gather radius r_i, and the image is the mean of the passes; the radius
/// shrinks as r²_{i+1} = r²_i·(i + α)/(i + 1), α = 2/3, so the mean converges to the exact
/// caustic (bias and noise both vanish). Direct light is added by ray tracing as in `render`;
/// units are those of `render` (W/(m²·sr), or W/m² with --mode irradiance).
///
/// The running mean is saved to the EXR (with the run's state in its header) every
/// --save-every seconds and at the end; --resume continues a saved run up to --passes.
#[derive(clap::Args)]
#[command(after_help = "Each pass traces a fresh photon map and gathers with one global radius, \
    r²(i+1) = r²(i)·(i + α)/(i + 1); the image is the mean of the passes, saved with the run's state in the EXR \
    header. Units as for render: W/(m²·sr) per RGB channel, or W/m² with --mode irradiance.\n\n\
    Examples:\n  \
    photonkit reference samples/scenes/prism.toml --passes 100 -o ref.exr\n  \
    photonkit reference samples/scenes/prism.toml --passes 400 -o ref.exr --resume   # 300 more")]
pub struct ReferenceArgs {
    /// Scene file (TOML); without it, the embedded default scene.
    scene: Option<PathBuf>,
    /// Output OpenEXR image (the running mean); the PNG preview goes beside it unless --png.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Total number of passes.
    #[arg(long, value_name = "N")]
    passes: u64,
    /// Photons emitted per pass.
    #[arg(long, value_name = "N", default_value_t = 1_000_000)]
    photons_per_pass: u64,
    /// Initial gather radius r₁, metres (default: the median distance from a first-pass photon
    /// to its 15th nearest neighbour).
    #[arg(value_parser = super::finite_f32, long, value_name = "M")]
    radius: Option<f32>,
    /// Let the radius follow the photon density: at each point, r₁ is the distance to the
    /// K-th nearest photon of the first pass (Hachisuka & Jensen advise K in the tens;
    /// `compare` uses 30), so sparse regions are not left dark by one radius chosen where the
    /// photons crowd.
    #[arg(long, value_name = "K", conflicts_with = "radius", value_parser = clap::value_parser!(u64).range(1..=10_000))]
    local_k: Option<u64>,
    /// α of the radius reduction, in (0, 1).
    #[arg(value_parser = super::finite_f64, long, default_value_t = 2.0 / 3.0)]
    alpha: f64,
    /// Kernel of the gather.
    #[arg(long, value_enum, default_value_t = KernelArg::Epanechnikov)]
    kernel: KernelArg,
    /// What to render.
    #[arg(long, value_enum, default_value_t = ModeArg::Full)]
    mode: ModeArg,
    /// Continue the run saved in the output EXR.
    #[arg(long)]
    resume: bool,
    /// Seconds between saves of the running mean.
    #[arg(value_parser = super::finite_f64, long, value_name = "S", default_value_t = 30.0)]
    save_every: f64,
    /// Base seed of the passes' photons.
    #[arg(long, value_name = "N", default_value_t = 1)]
    photon_seed: u64,
    #[command(flatten)]
    common: Common,
}

/// The EXR header attribute holding a progressive run's state (JSON).
const STATE_NOTE: &str = "photonkit:reference_state";

pub fn reference(a: ReferenceArgs) -> anyhow::Result<ExitCode> {
    use photonkit::render::reference::{Progressive, ReferenceOptions, ReferenceState};

    let (scene, scene_name) = load_scene(None, a.scene.as_deref())?;
    let text = match &a.scene {
        Some(p) => {
            photonkit::format::guard::register_input(p);
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?
        }
        None => photonkit::scene::DEFAULT_SCENE.to_string(),
    };
    let camera = a.common.camera(&scene)?;
    let mode = match a.mode {
        ModeArg::Full => Mode::Full,
        ModeArg::Caustic => Mode::Caustic,
        ModeArg::Direct => Mode::Direct,
        ModeArg::Irradiance => Mode::Irradiance,
    };
    let kernel = match a.kernel {
        KernelArg::Epanechnikov => Kernel::Epanechnikov,
        KernelArg::Disc => Kernel::Disc,
        KernelArg::Cone => Kernel::Cone,
    };
    if a.radius.is_some_and(|r| !(r > 0.0 && r.is_finite())) {
        bail!("--radius must be a positive number of metres");
    }
    let render = a.common.options(&camera, mode, Estimator::DEFAULT);
    let options = ReferenceOptions {
        photons_per_pass: a.photons_per_pass,
        alpha: a.alpha,
        initial_radius: a.radius,
        seed: a.photon_seed,
        max_bounces: 64,
        local_k: a.local_k.map(|k| k as usize),
    };
    let settings = serde_json::json!({
        "scene_crc32": photonkit::scene::scene_crc32(&text),
        "camera": format!("{:?}", camera),
        "width": render.width, "height": render.height, "spp": render.spp,
        "mode": mode.name(), "kernel": kernel.name(), "specular": format!("{:?}", render.eye.specular),
        "max_depth": render.eye.max_depth, "seed": render.seed,
    });
    let (mut image, mut state) = if a.resume {
        let (image, notes) = render::image::read_exr(&a.output)
            .with_context(|| format!("--resume: reading the saved run {}", a.output.display()))?;
        let saved = notes.iter().find(|(k, _)| k == STATE_NOTE).with_context(|| {
            format!("{}: not saved by `photonkit reference` (no run state)", a.output.display())
        })?;
        let state: ReferenceState = serde_json::from_str(&saved.1)
            .with_context(|| format!("{}: unreadable run state", a.output.display()))?;
        if state.settings != settings {
            bail!(
                "{}: saved with other settings ({}); resume with the same scene, camera, size, mode and kernel",
                a.output.display(),
                state.settings
            );
        }
        let same = ReferenceOptions { initial_radius: state.options.initial_radius, ..options.clone() };
        if state.options != same {
            bail!("{}: saved with other pass options ({:?})", a.output.display(), state.options);
        }
        if state.passes >= a.passes {
            super::note!("photonkit reference: {} already holds {} passes", a.output.display(), state.passes);
            return Ok(ExitCode::SUCCESS);
        }
        (image, state)
    } else {
        let state = ReferenceState::start(options, settings);
        (render::Image::new(render.width, render.height), state)
    };
    let first = state.passes;
    let progressive = Progressive { scene: &scene, camera, render, kernel, bounces: None };
    let outputs = a.common.outputs(&a.output);
    let save = |state: &ReferenceState, image: &render::Image| -> Result<(), render::RenderError> {
        let json = serde_json::to_string(state).expect("the state serialises");
        let notes = vec![
            ("photonkit:units".to_string(), mode.unit().to_string()),
            ("photonkit:mode".to_string(), mode.name().to_string()),
            (
                "photonkit:estimator".to_string(),
                format!("progressive photon mapping, {} kernel, {} passes", kernel.name(), state.passes),
            ),
            ("photonkit:scene".to_string(), scene_name.clone()),
            (STATE_NOTE.to_string(), json),
        ];
        render::image::write(image, &outputs, &notes)
    };
    let bar = progress_bar(a.passes - first, "reference");
    let t = Instant::now();
    let mut last_save = Instant::now();
    let mut after = |s: &ReferenceState, img: &render::Image| -> Result<bool, render::RenderError> {
        bar.inc(1);
        if s.passes == a.passes || last_save.elapsed().as_secs_f64() >= a.save_every {
            save(s, img)?;
            last_save = Instant::now();
        }
        Ok(true)
    };
    let result = match a.common.pool()? {
        Some(pool) => pool.install(|| progressive.run(&mut image, &mut state, a.passes, &mut after)),
        None => progressive.run(&mut image, &mut state, a.passes, &mut after),
    };
    bar.finish_and_clear();
    result?;
    let secs = t.elapsed().as_secs_f64();
    let shrink = photonkit::render::reference::radius2(1.0, state.options.alpha, state.passes).sqrt();
    let radius = match state.options.local_k {
        Some(k) => format!("radius the {k}-NN distance of the first pass × 1 → × {shrink:.4}"),
        None => {
            format!("radius {:.4} m → {:.4} m", state.initial_radius, state.initial_radius as f64 * shrink)
        }
    };
    super::note!(
        "photonkit reference: passes {}..{} of {} photons in {secs:.2} s ({:.3} s/pass); {radius}",
        first + 1,
        state.passes,
        a.photons_per_pass,
        secs / (state.passes - first).max(1) as f64,
    );
    Ok(ExitCode::SUCCESS)
}
