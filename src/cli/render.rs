//! `photonkit render` and `photonkit reference`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use glam::Vec3;
use indicatif::HumanBytes;
use indicatif::{ProgressBar, ProgressStyle};
use photonkit::format::{MapView, PhotonMap};
use photonkit::render::from_map::{
    CameraChanges, DiagnosticView, Framing, MapRender, Progress, render_from_parts, render_map,
    render_map_within, render_tile_part,
};
use photonkit::render::tiled::Progress as EstimateProgress;
use photonkit::render::{
    self, Diagnostic, Estimator, EyeOptions, Kernel, Mode, Outputs, RenderOptions, Specular,
};
use photonkit::scene::{Camera, Scene};

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
    /// Scene file (TOML or glTF 2.0) for geometry, materials, lights and camera.
    #[arg(long, value_name = "FILE")]
    pub(super) scene: Option<PathBuf>,
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
    /// Default 15; for a map that `refine --growth` grew, 15 × its photons over the map's
    /// before refinement, so each kernel spans the area it did (docs/progressive.md, "Growth").
    #[arg(short)]
    k: Option<usize>,
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
    /// Keep the peak memory under SIZE (512M, 8G, 2GiB): when the map's photons and their
    /// index would not fit beside the image's lookups, the k-NN estimate streams the map through
    /// memory one spatial tile at a time; the image is the same, byte for byte (docs/tiles.md).
    /// Needs the k-NN estimate and the scene's camera (no --plane, no --diagnostic).
    #[arg(long, value_name = "SIZE", value_parser = super::parse_memory, conflicts_with_all = ["plane", "diagnostic"])]
    memory: Option<u64>,
    /// Estimate only map tile i of n (the tiles `detect --tile` cuts) and write a tile part to
    /// -o (a PHM file): for every lookup of the image, the tile's photons that may be among
    /// its K nearest. `render MAP --parts PART… -o IMAGE` with the same options makes the image
    /// from every tile's part, the same byte for byte (docs/tiles.md), so tiles can run on
    /// other machines.
    #[arg(long, value_name = "i/n", value_parser = parse_tile, conflicts_with_all = ["memory", "plane", "diagnostic", "parts"])]
    tile: Option<photonkit::tiles::TileSpec>,
    /// Make the image from the tile parts `render MAP --tile i/n` wrote (every tile, any
    /// order), with the options they were made with.
    #[arg(long, value_name = "PART", num_args = 1.., conflicts_with_all = ["memory", "plane", "diagnostic"])]
    parts: Vec<String>,
}

fn parse_tile(s: &str) -> Result<photonkit::tiles::TileSpec, String> {
    s.parse().map_err(|e: photonkit::tiles::TileError| e.to_string())
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

    /// The camera changes the command line asks for.
    fn camera_changes(&self) -> CameraChanges {
        CameraChanges {
            eye: self.eye,
            look_at: self.look_at,
            up: self.up,
            fov_deg: self.fov,
            ortho_height_m: self.ortho,
            width: self.width,
            height: self.height,
        }
    }

    /// The scene's camera with the command line's changes; its resolution is the image's.
    fn camera(&self, scene: &Scene) -> anyhow::Result<Camera> {
        Ok(self.camera_changes().camera(scene.camera())?)
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
            supersample: None,
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
pub(super) fn load_scene(map: Option<&PhotonMap>, arg: Option<&Path>) -> anyhow::Result<(Scene, String)> {
    let view = map.map(PhotonMap::view);
    let r = photonkit::scene::for_map(view.as_ref(), arg)?;
    if let Some(w) = photonkit::scene::unsupported_warning(&r.name, &r.unsupported) {
        eprintln!("photonkit: warning: {w}");
    }
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
    let scene = match a.plane {
        Some(_) => None,
        None => Some(load_scene(Some(&map), a.scene.as_deref())?),
    };
    render_view(&a, &map.view(), scene.as_ref().map(|(s, name)| (s, name.as_str())))?;
    Ok(ExitCode::SUCCESS)
}

/// K of the k-NN estimate when `-k` is not given (the paper's).
const DEFAULT_K: usize = 15;

/// Renders `map` as the arguments ask, through `scene` (its name for the header) unless they
/// ask for a plane, and writes the EXR and its preview.
pub(super) fn render_view(a: &Args, map: &MapView, scene: Option<(&Scene, &str)>) -> anyhow::Result<()> {
    for p in [Some(a.output.clone()), a.common.outputs(&a.output).png].into_iter().flatten() {
        super::refuse_input_as_output(&p.to_string_lossy())?;
        let same = |other: &str| std::fs::canonicalize(other).ok() == std::fs::canonicalize(&p).ok();
        if p.exists() && a.parts.iter().any(|part| same(part)) {
            bail!("-o {}: that is one of the --parts being read", p.display());
        }
    }
    let kernel = match a.kernel {
        KernelArg::Epanechnikov => Kernel::Epanechnikov,
        KernelArg::Disc => Kernel::Disc,
        KernelArg::Cone => Kernel::Cone,
    };
    let k = a.k.unwrap_or(DEFAULT_K);
    // A map grown in refinement: each estimate gathers within the distance of the K-th nearest
    // of its photons before it grew (docs/progressive.md).
    let grown = a.k.is_none()
        && a.max_radius.is_none()
        && matches!(a.estimator, EstimatorArg::Knn)
        && photonkit::refine::first_photons(map).is_some();
    if grown {
        super::note!(
            "photonkit render: the map grew in refinement: each estimate gathers within the distance of the {k}th nearest of its photons before it grew, narrowed where detection held them (-k sets a plain k-NN estimate)"
        );
    }
    let estimator = match a.estimator {
        EstimatorArg::Knn if grown => Estimator::LocalRadius { k, scale: 1.0, kernel },
        EstimatorArg::Knn => Estimator::Knn { k, kernel, max_radius: a.max_radius },
        EstimatorArg::Diffusion => Estimator::Diffusion { k: a.diffusion_k, q: a.diffusion_q },
        EstimatorArg::Variable => Estimator::Variable { k, kernel },
    };
    let framing = match (a.plane, scene) {
        (Some((axis, offset)), _) => Framing::Plane {
            axis,
            offset,
            tolerance_m: a.plane_tolerance,
            rect: a.rect,
            width: a.common.width,
            height: a.common.height,
        },
        (None, Some((scene, name))) => {
            Framing::Scene { scene, camera: a.common.camera(scene)?, name: name.to_string() }
        }
        (None, None) => bail!("no scene to render through (give --scene, or --plane for a scene-less view)"),
    };
    let request = MapRender {
        mode: a.mode.map(|m| match m {
            ModeArg::Full => Mode::Full,
            ModeArg::Caustic => Mode::Caustic,
            ModeArg::Direct => Mode::Direct,
            ModeArg::Irradiance => Mode::Irradiance,
        }),
        estimator,
        diagnostic: a.diagnostic.map(|d| DiagnosticView {
            which: match d {
                DiagnosticArg::Params => Diagnostic::Params,
                DiagnosticArg::PathLength => Diagnostic::PathLength,
                DiagnosticArg::Constrained => Diagnostic::Constrained,
                DiagnosticArg::Splat => Diagnostic::Splat,
            },
            threshold: a.threshold,
            dot_radius: a.dot_radius,
        }),
        spp: a.common.spp,
        eye: a.common.eye_options(),
        seed: a.common.seed,
        ..MapRender::new(framing)
    };
    let bar = progress_bar(0, "render");
    let progress = |p: Progress| match p {
        Progress::Start { tiles } => {
            bar.set_message("render");
            bar.set_position(0);
            bar.set_length(tiles)
        }
        Progress::Tiles(n) => bar.inc(n),
        Progress::Estimate(EstimateProgress::Start(steps)) => {
            bar.set_message("estimate, map tiles");
            bar.set_length(steps)
        }
        Progress::Estimate(EstimateProgress::Step) => bar.inc(1),
    };
    let t = Instant::now();
    if let Some(tile) = a.tile {
        let output = a.output.to_string_lossy().to_string();
        let t = Instant::now();
        let part = render_tile_part(map, &request, tile)?;
        part.write(photonkit::format::Output::parse(&output)).context("writing the tile part")?;
        super::note!(
            "photonkit render: tile {tile}: {} candidate photons for the image's lookups in {:.2} s",
            part.len(),
            t.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    let parts = a.parts.iter().map(|p| PhotonMap::open(p)).collect::<Result<Vec<_>, _>>()?;
    let part_views: Vec<MapView> = parts.iter().map(PhotonMap::view).collect();
    let run = || match a.memory {
        _ if !part_views.is_empty() => render_from_parts(map, &request, &part_views),
        Some(budget) => render_map_within(map, &request, budget, &progress),
        None => render_map(map, &request, &progress),
    };
    let result = match a.common.pool()? {
        Some(pool) => pool.install(run),
        None => run(),
    };
    bar.finish_and_clear();
    let rendered = match result {
        Err(render::RenderError::Budget { budget, needed }) => bail!(
            "--memory {}: this render needs at least {} (the map's photons in tiles of at least {} \
             photons, and the image's lookups in runs of at least {})",
            HumanBytes(budget),
            HumanBytes(needed),
            photonkit::tiles::MIN_TILE_PHOTONS,
            photonkit::render::tiled::MIN_CHUNK_LOOKUPS
        ),
        r => r?,
    };
    let plan = rendered.plan;
    if plan.tiles > 1 || plan.chunks > 1 {
        super::note!(
            "photonkit render: the estimate streamed the map in {} tiles, {} pass{}, to stay under --memory {}",
            plan.tiles,
            plan.chunks,
            if plan.chunks == 1 { "" } else { "es" },
            HumanBytes(a.memory.unwrap_or(0))
        );
    }
    let secs = t.elapsed().as_secs_f64();
    for remark in &rendered.remarks {
        super::note!("photonkit render: note: {remark}");
    }
    let outputs = Outputs { codes: a.diagnostic.is_some(), ..a.common.outputs(&a.output) };
    render::image::write(&rendered.image, &outputs, &rendered.notes)?;
    let (o, stats) = (&rendered.options, rendered.stats);
    super::note!(
        "photonkit render: {}×{} × {} spp, {} ({}), {} photons: {:.2} s ({:.3} µs/sample, {} lookups)",
        o.width,
        o.height,
        o.spp,
        o.mode.name(),
        rendered.description,
        rendered.photons,
        secs,
        secs * 1e6 / stats.samples.max(1) as f64,
        stats.lookups
    );
    Ok(())
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
    /// Scene file, TOML or glTF 2.0 (.gltf, .glb); without it, the embedded default scene.
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

pub fn reference(a: ReferenceArgs) -> anyhow::Result<ExitCode> {
    use photonkit::eval::reference::{
        self, Progressive, ReferenceOptions, ReferenceState, Resumed, SavedRun,
    };

    let (scene, scene_name, text) = super::trace::load_scene(a.scene.as_deref())?;
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
    let settings = reference::settings(&text, &camera, &render, kernel);
    let saved = SavedRun { outputs: a.common.outputs(&a.output), mode, kernel, scene_name };
    let (mut image, mut state) = if a.resume {
        match saved.resume(&settings, &options, a.passes)? {
            Resumed::Continue(image, state) => (image, state),
            Resumed::Done(passes) => {
                super::note!("photonkit reference: {} already holds {passes} passes", a.output.display());
                return Ok(ExitCode::SUCCESS);
            }
        }
    } else {
        (render::Image::new(render.width, render.height), ReferenceState::start(options, settings))
    };
    let first = state.passes;
    let progressive = Progressive { scene: &scene, camera, render, kernel, bounces: None };
    let bar = progress_bar(a.passes - first, "reference");
    let t = Instant::now();
    let mut last_save = Instant::now();
    let mut after = |s: &ReferenceState, img: &render::Image| {
        bar.inc(1);
        if s.passes == a.passes || last_save.elapsed().as_secs_f64() >= a.save_every {
            saved.save(s, img)?;
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
    let shrink = reference::radius2(1.0, state.options.alpha, state.passes).sqrt();
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
