//! Rendering: radiance estimation from a photon map, to OpenEXR and PNG.
//!
//! **Units.** Photon flux is in watts per RGB channel. The irradiance estimate
//! E(x) = Σ_p Φ_p w(d_p) is in W/m² per channel ([`estimate`]); the radiance of a Lambertian
//! surface of albedo ρ is L = (ρ/π)·E in W/(m²·sr) per channel (method.md:
//! L = Σ f_r Φ_p w(d_p), f_r = ρ/π). An image in `full`, `caustic` or `direct` mode holds
//! that radiance as seen by the camera; in `irradiance` mode it holds E on the receiver (no
//! albedo, no 1/π), so a pixel of an orthographic top-down view is the mean irradiance over
//! its floor cell.

pub mod diagnostics;
pub mod environment;
pub mod estimate;
pub mod from_map;
pub mod image;
pub mod shade;
pub mod tiled;
pub mod tone;

use std::f32::consts::FRAC_1_PI;

use glam::Vec3;
use rayon::prelude::*;

pub use diagnostics::{Diagnostic, Diagnostics};
pub use estimate::{Estimator, Kernel, PhotonData, PhotonLookup, Scratch};
pub use image::{Image, Outputs};
pub use shade::{DiffuseHit, EyeOptions, Lights, Specular};

use crate::format::FormatError;
use crate::sampling::halton::PhotonRng;
use crate::scene::{Camera, Scene, SceneError};

/// Everything that can go wrong while rendering.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// Reading the photon map's columns failed.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The scene could not be used.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The map (or the part of it a view keeps) holds no photon.
    #[error("{file}: the photon map holds no photons: nothing to render")]
    EmptyMap {
        /// The map as named to the user.
        file: String,
    },
    /// A photon's position, flux or normal is infinite or NaN.
    #[error("{file}: photon {index} has a non-finite {column}")]
    NonFinite {
        /// The map as named to the user.
        file: String,
        /// `position`, `flux` or `normal`.
        column: String,
        /// The photon's index in the map.
        index: u64,
    },
    /// A memory budget too small for the render ([`from_map::render_map_within`]).
    #[error("a memory budget of {budget} bytes is too small: this render needs at least {needed}")]
    Budget {
        /// The budget, bytes.
        budget: u64,
        /// The least it needs, bytes.
        needed: u64,
    },
    /// An image file could not be encoded or decoded (EXR, PNG).
    #[error("{file}: {message}")]
    Image {
        /// The image file.
        file: String,
        /// The encoder's or decoder's message.
        message: String,
    },
    /// Creating, writing or renaming an image file failed.
    #[error("{file}: {source}")]
    Io {
        /// The image file.
        file: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A request out of range (image size, samples, estimator, mode without a photon map).
    #[error("{0}")]
    Invalid(String),
}

/// What the image shows at each diffuse hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Caustic radiance from the photon map plus direct light from the emitters, W/(m²·sr).
    Full,
    /// Caustic radiance from the photon map only, W/(m²·sr).
    Caustic,
    /// Direct light only (no photon map needed), W/(m²·sr).
    Direct,
    /// The photon map's irradiance on the receiver, W/m² (no albedo, no 1/π); eye rays pass
    /// straight through specular surfaces, so a top-down view maps pixels to floor cells.
    Irradiance,
}

impl Mode {
    /// The mode's name on the command line and in image headers.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Full => "full",
            Mode::Caustic => "caustic",
            Mode::Direct => "direct",
            Mode::Irradiance => "irradiance",
        }
    }

    /// The unit of a pixel value.
    pub fn unit(self) -> &'static str {
        match self {
            Mode::Irradiance => "W/m^2 per RGB channel (irradiance on the receiver)",
            _ => "W/(m^2 sr) per RGB channel (radiance towards the camera)",
        }
    }

    fn needs_photons(self) -> bool {
        self != Mode::Direct
    }
}

/// Image size, sampling and shading choices.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Samples per pixel, stratified (a jittered grid when a perfect square).
    pub spp: u32,
    /// What each pixel shows.
    pub mode: Mode,
    /// How irradiance is estimated from the photons at a diffuse hit.
    pub estimator: Estimator,
    /// How eye paths continue through specular surfaces.
    pub eye: EyeOptions,
    /// Seeds the sub-pixel jitter and sampled Fresnel choices.
    pub seed: u64,
    /// Keep every sample in the image ([`Image::samples`], up to [`KEPT_SAMPLES_MAX`]) so its
    /// preview tone-maps each before averaging: for images written for people, not for
    /// measurements or the passes of a reference.
    pub keep_samples: bool,
    /// Pixels that take more samples than `spp` (for measurements: where the irradiance
    /// varies within a pixel, docs/truth.md); `None`: every pixel takes `spp`.
    pub supersample: Option<Supersample>,
}

/// Some pixels of an image sampled more densely than the rest: a pixel whose flag is set
/// takes `spp` samples, on a jittered grid when a square, and the others the image's own.
#[derive(Clone, Debug, PartialEq)]
pub struct Supersample {
    /// Samples per flagged pixel.
    pub spp: u32,
    /// One flag per pixel, row-major.
    pub pixels: std::sync::Arc<[bool]>,
}

impl Default for RenderOptions {
    /// The paper's setting: 600×600, 4 samples per pixel, K = 15 Epanechnikov, full radiance.
    fn default() -> Self {
        RenderOptions {
            width: 600,
            height: 600,
            spp: 4,
            mode: Mode::Full,
            estimator: Estimator::DEFAULT,
            eye: EyeOptions::default(),
            seed: 0,
            keep_samples: false,
            supersample: None,
        }
    }
}

/// An orthographic view of a rectangle of a plane: pixel (x, y) (from the top-left corner)
/// looks at `origin + (x/width)·right + (y/height)·down`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneView {
    /// The point seen at the image's top-left corner, metres.
    pub origin: Vec3,
    /// The image's width as a vector in the plane, metres.
    pub right: Vec3,
    /// The image's height as a vector in the plane, pointing down the image, metres.
    pub down: Vec3,
    /// Unit normal of the plane (the side irradiance is measured on).
    pub normal: Vec3,
}

impl PlaneView {
    /// The rectangle [u0, u1] × [v0, v1] of the plane `axis` = `offset` (axis 0, 1, 2 for x, y,
    /// z), seen from the positive side: image right is the next axis (y after x, z after y,
    /// x after z), image up the one after.
    pub fn axis_aligned(axis: usize, offset: f32, [u0, v0, u1, v1]: [f32; 4]) -> PlaneView {
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        let mut origin = Vec3::ZERO;
        origin[axis] = offset;
        origin[a] = u0;
        origin[b] = v1;
        let (mut right, mut down, mut normal) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
        right[a] = u1 - u0;
        down[b] = -(v1 - v0);
        normal[axis] = 1.0;
        PlaneView { origin, right, down, normal }
    }

    /// The rectangle [u0, v0, u1, v1] of the plane `axis` = const that frames `points` (the
    /// photons on it), padded by a thousandth of their span (of their distance from the
    /// origin when they all coincide): no absolute length, so tiny and huge scenes frame alike.
    pub fn frame(axis: usize, points: &[[f32; 3]]) -> [f32; 4] {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let lo = points.iter().fold([f32::INFINITY; 2], |m, q| [m[0].min(q[u]), m[1].min(q[v])]);
        let hi = points.iter().fold([f32::NEG_INFINITY; 2], |m, q| [m[0].max(q[u]), m[1].max(q[v])]);
        let span = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let far = lo.iter().chain(&hi).fold(0f32, |m, x| m.max(x.abs()));
        let pad = 1e-3 * if span > 0.0 { span } else { far.max(f32::MIN_POSITIVE.sqrt()) };
        [lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad]
    }

    /// Image size for the rectangle `rect` with the pixels square: the width or height given
    /// (the other follows the aspect), both, or neither (the longer side `longest` pixels).
    pub fn image_size(rect: [f32; 4], width: Option<u32>, height: Option<u32>, longest: u32) -> (u32, u32) {
        let aspect = (rect[3] - rect[1]) / (rect[2] - rect[0]);
        let times = |n: u32| ((n as f32 * aspect).round() as u32).max(1);
        let over = |n: u32| ((n as f32 / aspect).round() as u32).max(1);
        match (width, height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, times(w)),
            (None, Some(h)) => (over(h), h),
            (None, None) if aspect <= 1.0 => (longest, times(longest)),
            (None, None) => (over(longest), longest),
        }
    }
}

/// What the camera looks at.
#[derive(Clone, Debug)]
pub enum View<'a> {
    /// A scene through a camera (its resolution is replaced by the options').
    Scene {
        /// The scene.
        scene: &'a Scene,
        /// The camera.
        camera: Camera,
    },
    /// A rectangle of a plane, orthographically, without a scene: irradiance only.
    Plane(PlaneView),
}

/// Counts of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Eye samples traced.
    pub samples: u64,
    /// Photon-map lookups (density estimates) made.
    pub lookups: u64,
}

/// Most samples a render keeps for the preview ([`Image::samples`]): 2²³, about 100 MB.
pub const KEPT_SAMPLES_MAX: u64 = 1 << 23;

/// Pixels per side of a unit of parallel work.
pub const TILE: u32 = 16;

/// The most samples a pixel may take.
pub const MAX_SPP: u32 = 4096;

/// A view, its photons and the options: everything an image is made from.
pub struct Renderer<'a> {
    /// What the camera looks at.
    pub view: View<'a>,
    /// The photons to estimate from; `None` for [`Mode::Direct`] only.
    pub photons: Option<&'a PhotonLookup<'a>>,
    /// Colour photons for a diagnostic view instead of estimating radiance.
    pub diagnostic: Option<&'a Diagnostics>,
    /// Image size, sampling and shading.
    pub opts: RenderOptions,
}

impl Renderer<'_> {
    /// Number of tiles (the units `render` reports progress in).
    pub fn tiles(&self) -> u64 {
        (self.opts.width.div_ceil(TILE) as u64) * (self.opts.height.div_ceil(TILE) as u64)
    }

    /// Renders the image, tile by tile in parallel; `progress(1)` after each tile.
    pub fn render(&self, progress: &(dyn Fn(u64) + Sync)) -> Result<(Image, RenderStats), RenderError> {
        let (image, stats, _) = self.run(Caustic::Estimated, progress)?;
        Ok((image, stats))
    }

    /// The diffuse hits where the caustic irradiance is looked up, per image tile (row-major
    /// tiles of [`TILE`] pixels), each tile's in the order the render meets them: the first
    /// half of a render whose estimates are made elsewhere ([`Self::render_given`]; a map
    /// estimated tile by tile, `render::tiled`). Needs no photons; empty in direct mode.
    pub fn lookups(&self, progress: &(dyn Fn(u64) + Sync)) -> Result<Vec<Vec<Lookup>>, RenderError> {
        Ok(self.run(Caustic::Recorded, progress)?.2)
    }

    /// The image with the caustic irradiance at each diffuse hit given: `caustic[t][j]` at
    /// the j-th hit of image tile t, in the order of [`Self::lookups`]. The same image, byte
    /// for byte, as [`Self::render`] with photons whose estimates at those hits are these.
    pub fn render_given(
        &self,
        caustic: &[Vec<Vec3>],
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<(Image, RenderStats), RenderError> {
        if caustic.len() as u64 != self.tiles() {
            return Err(RenderError::Invalid(format!(
                "caustic irradiance for {} image tiles, the image has {}",
                caustic.len(),
                self.tiles()
            )));
        }
        let (image, stats, _) = self.run(Caustic::Given(caustic), progress)?;
        Ok((image, stats))
    }

    fn run(
        &self,
        caustic: Caustic,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<(Image, RenderStats, Vec<Vec<Lookup>>), RenderError> {
        let o = &self.opts;
        let pixels = o.width as u64 * o.height as u64;
        if o.width == 0
            || o.height == 0
            || o.width > image::MAX_SIDE
            || o.height > image::MAX_SIDE
            || pixels > image::MAX_PIXELS
        {
            return Err(RenderError::Invalid(format!(
                "image size {}×{}: each side must be 1 to {} pixels, and the image at most {} pixels",
                o.width,
                o.height,
                image::MAX_SIDE,
                image::MAX_PIXELS
            )));
        }
        if o.spp == 0 || o.spp > MAX_SPP {
            return Err(RenderError::Invalid(format!(
                "--spp {}: needs 1 to {MAX_SPP} samples per pixel",
                o.spp
            )));
        }
        if let Some(ss) = &o.supersample {
            if ss.spp == 0 || ss.spp > MAX_SPP {
                return Err(RenderError::Invalid(format!(
                    "{} samples in supersampled pixels: needs 1 to {MAX_SPP}",
                    ss.spp
                )));
            }
            if ss.pixels.len() as u64 != pixels {
                return Err(RenderError::Invalid(format!(
                    "{} supersampling flags for an image of {pixels} pixels",
                    ss.pixels.len()
                )));
            }
        }
        if o.estimator.k() == 0 {
            return Err(RenderError::Invalid("the estimator needs at least one neighbour (k ≥ 1)".into()));
        }
        let needs_photons = self.diagnostic.is_some() || o.mode.needs_photons();
        if !matches!(caustic, Caustic::Estimated) && self.diagnostic.is_some() {
            return Err(RenderError::Invalid("a diagnostic view looks its photons up as it goes".into()));
        }
        if needs_photons && self.photons.is_none() && matches!(caustic, Caustic::Estimated) {
            return Err(RenderError::Invalid(format!("mode {} needs a photon map", o.mode.name())));
        }
        if let Some(p) = self.photons
            && matches!(caustic, Caustic::Estimated)
            && needs_photons
            && self.diagnostic.is_none()
            && !p.serves(&o.estimator)
        {
            return Err(RenderError::Invalid("the photon lookup was not built for this estimator".into()));
        }
        if matches!(self.view, View::Plane(_)) && self.diagnostic.is_none() && o.mode != Mode::Irradiance {
            return Err(RenderError::Invalid(
                "a plane view without a scene shows irradiance only (--mode irradiance)".into(),
            ));
        }
        let lights = match &self.view {
            View::Scene { scene, .. } if matches!(o.mode, Mode::Full | Mode::Direct) => {
                Some(Lights::new(scene))
            }
            _ => None,
        };
        let camera = match &self.view {
            View::Scene { camera, .. } => Some(Camera { resolution: [o.width, o.height], ..camera.clone() }),
            View::Plane(_) => None,
        };
        // The background is part of what is seen (full and direct light), not of a measurement.
        let background = match &self.view {
            View::Scene { scene, .. }
                if matches!(o.mode, Mode::Full | Mode::Direct) && self.diagnostic.is_none() =>
            {
                scene.background().map(environment::Environment::load).transpose()?
            }
            _ => None,
        };
        let seen = Seen { camera: camera.as_ref(), lights: lights.as_ref(), background: background.as_ref() };
        let tiles_x = o.width.div_ceil(TILE);
        // Every sample kept for the preview's anti-aliasing after tone mapping (Image::samples),
        // up to a bound on memory.
        let keep = o.keep_samples
            && !matches!(caustic, Caustic::Recorded)
            && o.supersample.is_none()
            && self.diagnostic.is_none()
            && o.spp > 1
            && pixels * o.spp as u64 <= KEPT_SAMPLES_MAX;
        let results: Vec<TileResult> = (0..self.tiles())
            .into_par_iter()
            .map_init(TileScratch::default, |s, t| {
                let (tx, ty) = ((t % tiles_x as u64) as u32, (t / tiles_x as u64) as u32);
                let given = match caustic {
                    Caustic::Given(all) => Some(&all[t as usize][..]),
                    _ => None,
                };
                let r = self.tile(tx * TILE, ty * TILE, &seen, keep, (caustic, given), s);
                progress(1);
                r
            })
            .collect();
        let mut img = Image::new(o.width, o.height);
        // With a background, the exposure meters the pixels that see a surface.
        let mut metered = background.is_some().then(|| vec![false; img.pixels.len()]);
        let spp = o.spp as usize;
        let mut samples = keep.then(|| vec![Vec3::ZERO; img.pixels.len() * spp]);
        let mut stats = RenderStats::default();
        let mut lookups = Vec::new();
        for (t, TileResult { pixels, surface, each, stats: st, recorded, given }) in
            results.into_iter().enumerate()
        {
            if matches!(caustic, Caustic::Recorded) {
                lookups.push(recorded);
                continue;
            }
            if let Caustic::Given(all) = caustic
                && all[t].len() != given
            {
                return Err(RenderError::Invalid(format!(
                    "image tile {t}: {} caustic values given for {given} lookups",
                    all[t].len()
                )));
            }
            let (x0, y0) = ((t as u32 % tiles_x) * TILE, (t as u32 / tiles_x) * TILE);
            let w = TILE.min(o.width - x0);
            for (k, (p, seen)) in pixels.into_iter().zip(surface).enumerate() {
                let (x, y) = (x0 + k as u32 % w, y0 + k as u32 / w);
                let at = (y * o.width + x) as usize;
                img.pixels[at] = p;
                if let Some(m) = metered.as_mut() {
                    m[at] = seen;
                }
                if let Some(all) = samples.as_mut() {
                    all[at * spp..(at + 1) * spp].copy_from_slice(&each[k * spp..(k + 1) * spp]);
                }
            }
            stats.samples += st.samples;
            stats.lookups += st.lookups;
        }
        img.metered = metered;
        img.samples = samples.map(|s| (o.spp, s));
        Ok((img, stats, lookups))
    }

    fn tile(
        &self,
        x0: u32,
        y0: u32,
        seen: &Seen,
        keep: bool,
        (caustic, given): (Caustic, Option<&[Vec3]>),
        s: &mut TileScratch,
    ) -> TileResult {
        let o = &self.opts;
        let mut source = match (caustic, given) {
            (Caustic::Recorded, _) => Source::Recorded(Vec::new()),
            (Caustic::Given(_), Some(values)) => Source::Given(values, 0),
            _ => Source::Estimated,
        };
        let (w, h) = (TILE.min(o.width - x0), TILE.min(o.height - y0));
        let mut out = Vec::with_capacity((w * h) as usize);
        // Per pixel: whether some sample's eye path reached a surface.
        let mut surface = Vec::with_capacity((w * h) as usize);
        // Every sample, pixel by pixel, when kept.
        let mut each = Vec::with_capacity(if keep { (w * h * o.spp) as usize } else { 0 });
        let mut stats = RenderStats::default();
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                let at = y as usize * o.width as usize + x as usize;
                let spp = match &o.supersample {
                    Some(ss) if ss.pixels[at] => ss.spp,
                    _ => o.spp,
                };
                let grid = (spp as f64).sqrt() as u32;
                let stratified = grid * grid == spp;
                let mut rng = PhotonRng::new(o.seed, at as u64);
                let (jx, jy) = (rng.next_f32(), rng.next_f32());
                let mut sum = Vec3::ZERO;
                let mut hit = false;
                for k in 0..spp {
                    // A jittered grid, or the R2 sequence (Roberts) shifted by the pixel's offset.
                    let (dx, dy) = if stratified {
                        (
                            ((k % grid) as f32 + rng.next_f32()) / grid as f32,
                            ((k / grid) as f32 + rng.next_f32()) / grid as f32,
                        )
                    } else {
                        ((jx + 0.754_877_7 * k as f32).fract(), (jy + 0.569_840_3 * k as f32).fract())
                    };
                    let v = self.sample(
                        x as f32 + dx,
                        y as f32 + dy,
                        (seen, &mut source),
                        &mut rng,
                        s,
                        &mut stats,
                    );
                    sum += v;
                    if keep {
                        each.push(v);
                    }
                    hit |= !s.hits.is_empty();
                }
                surface.push(hit);
                stats.samples += spp as u64;
                out.push(sum / spp as f32);
            }
        }
        let (recorded, given) = match source {
            Source::Recorded(r) => (r, 0),
            Source::Given(_, used) => (Vec::new(), used),
            Source::Estimated => (Vec::new(), 0),
        };
        TileResult { pixels: out, surface, each, stats, recorded, given }
    }

    /// The value of one image-plane sample at (px, py) pixels.
    fn sample(
        &self,
        px: f32,
        py: f32,
        (seen, source): (&Seen, &mut Source),
        rng: &mut PhotonRng,
        s: &mut TileScratch,
        stats: &mut RenderStats,
    ) -> Vec3 {
        let o = &self.opts;
        s.hits.clear();
        let mut escaped = Vec3::ZERO;
        let scene = match (&self.view, seen.camera) {
            (View::Plane(p), _) => {
                let at = p.origin + p.right * (px / o.width as f32) + p.down * (py / o.height as f32);
                s.hits.push(DiffuseHit {
                    point: at,
                    normal: p.normal,
                    albedo: Vec3::ONE,
                    weight: Vec3::ONE,
                    dir: -p.normal,
                });
                None
            }
            (View::Scene { scene, .. }, Some(cam)) => {
                let eye =
                    EyeOptions { see_through: o.eye.see_through || o.mode == Mode::Irradiance, ..o.eye };
                escaped = shade::eye_path(scene, cam.ray(px, py), &eye, seen.background, rng, &mut s.hits);
                Some(*scene)
            }
            (View::Scene { .. }, None) => unreachable!("a scene view has a camera"),
        };
        if let Some(d) = self.diagnostic {
            let photons = self.photons.expect("checked in render");
            let Some(hit) =
                s.hits.iter().max_by(|a, b| a.weight.max_element().total_cmp(&b.weight.max_element()))
            else {
                return Vec3::ZERO;
            };
            stats.lookups += 1;
            return d.colour(photons, hit.point, &mut s.estimate);
        }
        let mut value = escaped;
        for hit in &s.hits {
            let caustic = match (o.mode, &mut *source, self.photons) {
                (Mode::Direct, ..) | (_, Source::Estimated, None) => Vec3::ZERO,
                (_, Source::Estimated, Some(p)) => {
                    stats.lookups += 1;
                    p.irradiance(&o.estimator, hit.point, hit.normal, &mut s.estimate)
                }
                (_, Source::Recorded(r), _) => {
                    // Only where the estimate is looked up matters: the value is not kept.
                    r.push(Lookup { point: hit.point, normal: hit.normal });
                    continue;
                }
                (_, Source::Given(values, next), _) => {
                    stats.lookups += 1;
                    let e = values.get(*next).copied().unwrap_or(Vec3::ZERO);
                    *next += 1;
                    e
                }
            };
            let direct = match (seen.lights, scene) {
                (Some(l), Some(sc)) => l.irradiance(sc, hit.point, hit.normal),
                _ => Vec3::ZERO,
            };
            value += hit.weight
                * match o.mode {
                    Mode::Irradiance => caustic,
                    // L = (ρ/π)·E: the Lambertian BRDF times the irradiance.
                    _ => hit.albedo * FRAC_1_PI * (caustic + direct),
                };
        }
        value
    }
}

/// One tile's pixels (row by row), whether each saw a surface, its samples when kept, counts,
/// and the hits it looked the caustic up at (when recorded).
struct TileResult {
    pixels: Vec<Vec3>,
    surface: Vec<bool>,
    each: Vec<Vec3>,
    stats: RenderStats,
    recorded: Vec<Lookup>,
    /// How many given values it used.
    given: usize,
}

/// A diffuse hit where a render looks the caustic irradiance up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lookup {
    /// The hit point, metres.
    pub point: Vec3,
    /// The surface's unit normal on the eye's side.
    pub normal: Vec3,
}

/// Where a render takes the caustic irradiance at its diffuse hits from.
#[derive(Clone, Copy)]
enum Caustic<'c> {
    /// Estimated from the renderer's photons as each hit is met.
    Estimated,
    /// Not estimated: the hits are recorded ([`Renderer::lookups`]).
    Recorded,
    /// Given per image tile, in the order the hits are met ([`Renderer::render_given`]).
    Given(&'c [Vec<Vec3>]),
}

/// One image tile's [`Caustic`]: the hits recorded so far, or the given values and the next.
enum Source<'g> {
    Estimated,
    Recorded(Vec<Lookup>),
    Given(&'g [Vec3], usize),
}

/// What a sample looks through and at: the camera, the emitters' direct light and the
/// background, each where the view and mode have one.
struct Seen<'a> {
    camera: Option<&'a Camera>,
    lights: Option<&'a Lights>,
    background: Option<&'a environment::Environment>,
}

#[derive(Default)]
struct TileScratch {
    hits: Vec<DiffuseHit>,
    estimate: Scratch,
}

#[cfg(test)]
mod tests;
