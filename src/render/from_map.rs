//! Rendering a photon map: all of `photonkit render` as one library call.
//!
//! [`render_map`] takes a [`MapView`] (a memory-mapped file or an in-memory table), a
//! [`MapRender`] request (a scene with its camera, or a scene-less plane; the estimator; an
//! optional diagnostic colouring) and returns the image with the EXR header notes that say
//! what it holds. Writing the image is the caller's choice ([`super::image::write`]).

use glam::Vec3;

use super::{
    Diagnostic, Diagnostics, Estimator, EyeOptions, Image, Mode, PhotonData, PhotonLookup, PlaneView,
    RenderError, RenderOptions, RenderStats, Renderer, View, image::Notes,
};
use crate::format::{MapView, name};
use crate::scene::{Camera, Projection, Scene};

/// Changes to a scene's camera; every field left `None` keeps the scene's.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraChanges {
    /// The eye's position, metres.
    pub eye: Option<Vec3>,
    /// The point looked at, metres.
    pub look_at: Option<Vec3>,
    /// Roughly up in the image (default: the scene camera's, else +z).
    pub up: Option<Vec3>,
    /// A pinhole camera with this vertical field of view, degrees.
    pub fov_deg: Option<f32>,
    /// An orthographic camera showing this height, metres.
    pub ortho_height_m: Option<f32>,
    /// Image width in pixels; alone, the height follows the camera's aspect.
    pub width: Option<u32>,
    /// Image height in pixels; alone, the width follows the camera's aspect.
    pub height: Option<u32>,
}

impl CameraChanges {
    /// The camera `base` (a scene's, if it has one) with these changes; a scene without a
    /// camera needs at least the eye and the look-at point (40° pinhole, 600×600 by default).
    pub fn camera(&self, base: Option<&Camera>) -> Result<Camera, RenderError> {
        let invalid = |m: String| RenderError::Invalid(m);
        let eye = self.eye.or(base.map(|c| c.eye));
        let look = self.look_at.or(base.map(|c| c.eye + c.forward));
        let up = self.up.or(base.map(|c| c.up)).unwrap_or(Vec3::Z);
        let projection = match (self.fov_deg, self.ortho_height_m, base) {
            (Some(f), _, _) if f > 0.0 && f < 180.0 => Projection::Pinhole { fov_y_rad: f.to_radians() },
            (Some(f), _, _) => {
                return Err(invalid(format!("--fov {f}: needs a field of view between 0 and 180 degrees")));
            }
            (_, Some(h), _) if h > 0.0 && h.is_finite() => Projection::Orthographic { height_m: h },
            (_, Some(h), _) => {
                return Err(invalid(format!("--ortho {h}: needs a positive height in metres")));
            }
            (None, None, Some(c)) => c.projection,
            (None, None, None) => Projection::Pinhole { fov_y_rad: 40f32.to_radians() },
        };
        let (Some(eye), Some(look)) = (eye, look) else {
            return Err(invalid(
                "the scene has no [camera]: give --eye and --look-at (and --fov or --ortho)".into(),
            ));
        };
        let res = base.map_or([600, 600], |c| c.resolution);
        let aspect =
            |n: u32, num: u32, den: u32| ((n as f64 * num as f64 / den as f64).round() as u32).max(1);
        let (w, h) = match (self.width, self.height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, aspect(w, res[1], res[0])),
            (None, Some(h)) => (aspect(h, res[0], res[1]), h),
            (None, None) => (res[0], res[1]),
        };
        Camera::look_at(projection, eye, look, up, [w, h]).ok_or_else(|| {
            invalid("the camera's eye and look-at coincide, or the view is parallel to up".into())
        })
    }
}

/// What the image looks at.
#[derive(Clone, Debug)]
pub enum Framing<'s> {
    /// A scene through a camera (whose resolution is the image's); `name` goes to the header.
    Scene {
        /// The scene.
        scene: &'s Scene,
        /// The camera.
        camera: Camera,
        /// The scene's name for the header.
        name: String,
    },
    /// No scene: the photons within `tolerance_m` of the plane `axis` = `offset` (axis 0, 1, 2
    /// for x, y, z), seen orthographically from its positive side; irradiance only.
    Plane {
        /// The plane's normal axis: 0, 1, 2 for x, y, z.
        axis: usize,
        /// The plane's coordinate on `axis`, metres.
        offset: f32,
        /// How far from the plane a photon may lie and count, metres.
        tolerance_m: f32,
        /// [u0, v0, u1, v1] in the plane's other two coordinates (default: the photons' frame).
        rect: Option<[f32; 4]>,
        /// Image width in pixels; alone, the height follows the rectangle's aspect; with
        /// neither, the longer side is 600.
        width: Option<u32>,
        /// Image height in pixels (as `width`).
        height: Option<u32>,
    },
}

/// A diagnostic view: photons as dots coloured by a property, instead of radiance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiagnosticView {
    /// The property that colours the photons.
    pub which: Diagnostic,
    /// Constraint factor |basis_v| below which [`Diagnostic::Constrained`] paints a photon red.
    pub threshold: f32,
    /// Dot radius, metres (default: 0.4 × the local photon spacing, bounded).
    pub dot_radius: Option<f32>,
}

/// Everything [`render_map`] needs besides the map.
#[derive(Clone, Debug)]
pub struct MapRender<'s> {
    /// What the image looks at.
    pub framing: Framing<'s>,
    /// What to render; `None`: full radiance, or irradiance for a plane.
    pub mode: Option<Mode>,
    /// How irradiance is estimated from the photons.
    pub estimator: Estimator,
    /// Photons as coloured dots instead of radiance.
    pub diagnostic: Option<DiagnosticView>,
    /// Samples per pixel (the paper: 4).
    pub spp: u32,
    /// How eye paths continue through specular surfaces.
    pub eye: EyeOptions,
    /// Seeds the sub-pixel jitter and sampled Fresnel choices.
    pub seed: u64,
    /// Keep every sample for a tone-mapped preview ([`RenderOptions::keep_samples`]).
    pub keep_samples: bool,
}

impl<'s> MapRender<'s> {
    /// The paper's setting on `framing`: full radiance (irradiance for a plane), K = 15
    /// Epanechnikov, 4 samples per pixel, samples kept for the preview.
    pub fn new(framing: Framing<'s>) -> Self {
        let o = RenderOptions::default();
        MapRender {
            framing,
            mode: None,
            estimator: o.estimator,
            diagnostic: None,
            spp: o.spp,
            eye: o.eye,
            seed: o.seed,
            keep_samples: true,
        }
    }
}

/// Progress of [`render_map`]: the number of tiles once known, then tiles as they finish.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Rendering begins.
    Start {
        /// Tiles in the image ([`super::TILE`] pixels square).
        tiles: u64,
    },
    /// This many more tiles are done.
    Tiles(u64),
    /// The estimate streaming the map tile by tile ([`render_map_within`]).
    Estimate(super::tiled::Progress),
}

/// What [`render_map`] made.
#[derive(Debug)]
pub struct Rendered {
    /// The image, linear.
    pub image: Image,
    /// Samples traced and lookups made.
    pub stats: RenderStats,
    /// The EXR header's notes: units, mode, estimator, photon map, scene, samples per pixel.
    pub notes: Notes,
    /// The options the image was rendered with (the mode as finally chosen).
    pub options: RenderOptions,
    /// The estimator's description, or the diagnostic's.
    pub description: String,
    /// Photons the estimate used (for a plane: those near it).
    pub photons: usize,
    /// Things the caller may tell the user (e.g. direct light not added twice).
    pub remarks: Vec<String>,
    /// The spatial tiles the map's photons streamed through memory in, and the passes over
    /// them (one tile, one pass: held whole; [`render_map_within`]).
    pub plan: super::tiled::Plan,
}

/// Renders `map` as `request` asks (the whole of `photonkit render`).
///
/// A map traced with direct photons stored is rendered in caustic mode when full radiance is
/// asked for (direct light would count twice), with a remark saying so.
pub fn render_map(
    map: &MapView,
    request: &MapRender,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<Rendered, RenderError> {
    let file = map.file_name();
    let plane = match request.framing {
        Framing::Plane { axis, offset, tolerance_m, .. } => Some((axis, offset, tolerance_m)),
        Framing::Scene { .. } => None,
    };
    let (mode, remarks) = settle_mode(map, request)?;
    let diagnostic = request
        .diagnostic
        .map(|d| Diagnostics::from_map(map, d.which, d.threshold, d.dot_radius))
        .transpose()?;

    // Photon columns: the plane view keeps the photons near its plane (and ignores normals).
    let (positions, flux) = (map.positions(), map.flux());
    let near_plane: Option<Vec<u32>> = plane.map(|(axis, offset, tolerance)| {
        (0..positions.len() as u32)
            .filter(|&i| (positions[i as usize][axis] - offset).abs() <= tolerance)
            .collect()
    });
    // (positions, flux) of the photons near the plane.
    type Columns = (Vec<[f32; 3]>, Vec<[f32; 3]>);
    let kept: Option<Columns> = near_plane.as_ref().map(|keep| {
        (
            keep.iter().map(|&i| positions[i as usize]).collect(),
            keep.iter().map(|&i| flux[i as usize]).collect(),
        )
    });
    let data = match &kept {
        Some((p, f)) => PhotonData { positions: p, flux: f, normals: None },
        None => PhotonData { positions, flux, normals: map.column::<[f32; 3]>(name::NORMAL)? },
    };
    if let (Some((p, _)), Some((_, _, tolerance))) = (&kept, plane)
        && p.is_empty()
    {
        return Err(RenderError::Invalid(format!(
            "{file}: no photon lies within {tolerance} m of the plane"
        )));
    }
    let mut photons = PhotonLookup::new(file, data)?.prepared_for(&request.estimator);
    if let Estimator::LocalRadius { .. } = request.estimator {
        // A grown map's estimate takes its radius from the photons before it grew.
        let sites = crate::refine::first_photons(map).ok_or_else(|| {
            RenderError::Invalid(format!(
                "{file}: the local-radius estimate needs a map grown by `photonkit refine --growth`"
            ))
        })?;
        photons = photons.with_own_radius_map(sites, &crate::refine::radius_factors(map));
    }
    let diagnostic = match (diagnostic, &near_plane) {
        (Some(d), Some(keep)) => {
            Some(Diagnostics { colours: keep.iter().map(|&i| d.colours[i as usize]).collect(), ..d })
        }
        (d, _) => d,
    }
    .map(|d| d.bounded(&photons));

    let (view, opts, scene_name) = match &request.framing {
        Framing::Plane { axis, offset, rect, width, height, .. } => {
            let points = &kept.as_ref().expect("a plane keeps its photons").0;
            let rect = rect.unwrap_or_else(|| PlaneView::frame(*axis, points));
            let (w, h) = PlaneView::image_size(rect, *width, *height, 600);
            let name = format!(
                "plane {}={offset} [{}, {}] × [{}, {}]",
                ["x", "y", "z"][*axis],
                rect[0],
                rect[2],
                rect[1],
                rect[3]
            );
            (View::Plane(PlaneView::axis_aligned(*axis, *offset, rect)), options(request, mode, (w, h)), name)
        }
        Framing::Scene { scene, camera, name } => {
            let [w, h] = camera.resolution;
            (View::Scene { scene, camera: camera.clone() }, options(request, mode, (w, h)), name.clone())
        }
    };
    let renderer = Renderer { view, photons: Some(&photons), diagnostic: diagnostic.as_ref(), opts };
    progress(Progress::Start { tiles: renderer.tiles() });
    let (image, stats) = renderer.render(&|n| progress(Progress::Tiles(n)))?;
    let o = renderer.opts;
    let (notes, description) = header_notes(&o, request, file, scene_name);
    let plan = super::tiled::Plan { tiles: 1, chunks: 1 };
    Ok(Rendered { image, stats, notes, options: o, description, photons: photons.len(), remarks, plan })
}

/// [`render_map`] with the peak memory kept under `budget` bytes: when the map's photons and
/// their index would not fit beside the render's lookups, the k-NN estimate streams them
/// through memory one spatial tile at a time ([`super::tiled`]), and the image is the one
/// [`render_map`] makes, byte for byte. Takes the k-NN estimate through a scene's camera;
/// other estimators, diagnostic views and `--plane` views hold the whole map.
pub fn render_map_within(
    map: &MapView,
    request: &MapRender,
    budget: u64,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<Rendered, RenderError> {
    let file = map.file_name();
    let Streamable { renderer, knn, remarks, scene: name } = streamable(map, request)?;
    let k = knn.k;
    let photons = map.len();
    let baseline = super::tiled::Demand::baseline_now();
    let image_bytes = image_bytes(&renderer.opts);
    let demand = super::tiled::Demand { photons, lookups: 0, k, image_bytes, baseline };
    if super::tiled::whole_fits(&demand, budget) {
        return render_map(map, request, progress);
    }
    // Where the estimate is looked up: the eye paths alone, no photons.
    let lookups = renderer.lookups(&|_| {})?;
    let count: usize = lookups.iter().map(Vec::len).sum();
    let demand = super::tiled::Demand { lookups: count, ..demand };
    let plan =
        super::tiled::plan(&demand, budget).map_err(|needed| RenderError::Budget { budget, needed })?;
    let grid = crate::tiles::TileSpec { index: 0, count: plan.tiles }.grid();
    let tiling = crate::tiles::Tiling::new_releasing(map.positions(), grid, map.pages());
    let streamed = super::tiled::StreamedMap::new(map, file, tiling)?;
    let caustic = streamed.estimate(&lookups, knn, plan.chunks, &|p| progress(Progress::Estimate(p)))?;
    drop((lookups, streamed));
    progress(Progress::Start { tiles: renderer.tiles() });
    let (image, stats) = renderer.render_given(&caustic, &|t| progress(Progress::Tiles(t)))?;
    let o = renderer.opts;
    let (notes, description) = header_notes(&o, request, file, name);
    Ok(Rendered { image, stats, notes, options: o, description, photons, remarks, plan })
}

/// A render whose estimates can be made apart from it: its renderer (no photons), the k-NN
/// estimate's settings, the remarks for the user and the scene's name.
struct Streamable<'s> {
    renderer: Renderer<'s>,
    knn: super::tiled::Knn,
    remarks: Vec<String>,
    scene: String,
}

/// `request` on `map` as a render whose estimates are made apart from it (under `--memory`, or
/// by tile jobs): the k-NN estimate through a scene's camera, radiance, not a diagnostic view.
fn streamable<'s>(map: &MapView, request: &'s MapRender) -> Result<Streamable<'s>, RenderError> {
    let (mode, remarks) = settle_mode(map, request)?;
    let Framing::Scene { scene, camera, name } = &request.framing else {
        return Err(RenderError::Invalid(
            "--memory and --tile render through a scene's camera, not a --plane view".into(),
        ));
    };
    let Estimator::Knn { k, kernel, max_radius } = request.estimator else {
        return Err(RenderError::Invalid(format!(
            "--memory and --tile render the k-NN estimate (the default), not {}",
            request.estimator.describe()
        )));
    };
    if request.diagnostic.is_some() {
        return Err(RenderError::Invalid(
            "--memory and --tile render radiance, not a diagnostic view".into(),
        ));
    }
    let opts = options(request, mode, (camera.resolution[0], camera.resolution[1]));
    let renderer = Renderer {
        view: View::Scene { scene, camera: camera.clone() },
        photons: None,
        diagnostic: None,
        opts,
    };
    let knn = super::tiled::Knn { k, kernel, max_radius };
    Ok(Streamable { renderer, knn, remarks, scene: name.clone() })
}

/// The image of `o` with the samples it keeps for the preview (twice while tiles are
/// assembled), bytes.
fn image_bytes(o: &RenderOptions) -> u64 {
    let pixels = o.width as u64 * o.height as u64;
    pixels * (12 + 1) + if o.keep_samples { pixels * o.spp as u64 * 24 } else { 0 }
}

/// A render tile part's column of each row's lookup (u32): its place among the image's
/// lookups in the order the render meets them.
pub const PART_LOOKUP: &str = "render_lookup";
/// A render tile part's column of each row's squared distance from its lookup (f32).
pub const PART_DIST2: &str = "render_dist2";

/// CRC-32 of the lookups' points and normals: which render a part's rows belong to.
fn lookups_crc(lookups: &[super::Lookup]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    for l in lookups {
        h.update(bytemuck::cast_slice(&[l.point.to_array(), l.normal.to_array()]));
    }
    h.finalize()
}

/// The estimate's settings as a part's record holds them.
fn knn_record(knn: &super::tiled::Knn) -> serde_json::Value {
    serde_json::json!({ "k": knn.k, "kernel": knn.kernel.name(), "max_radius": knn.max_radius })
}

/// Tile `tile` of `map`'s share of the render `request` asks, as a job of its own
/// (`photonkit render MAP --tile i/n -o PART`): a PHM map of, for each of the image's
/// lookups, the tile's photons among its K nearest within a bound on the map's K-th (position,
/// flux, normal, `photon_index`, [`PART_LOOKUP`], [`PART_DIST2`]), whose last record names
/// the tile, the map and the lookups. [`render_from_parts`] makes the image from every tile's.
pub fn render_tile_part(
    map: &MapView,
    request: &MapRender,
    tile: crate::tiles::TileSpec,
) -> Result<crate::format::PhotonTable<'static>, RenderError> {
    use crate::format::{ColumnSpec, PhotonTable, StageRecord};
    let start = std::time::Instant::now();
    let Streamable { renderer, knn, .. } = streamable(map, request)?;
    let lookups: Vec<super::Lookup> = renderer.lookups(&|_| {})?.concat();
    let tiling = crate::tiles::Tiling::new(map.positions(), tile.grid());
    map.release_pages();
    let streamed = super::tiled::StreamedMap::new(map, map.file_name(), tiling)?;
    let c = streamed.candidates(&lookups, knn, tile.index)?;
    drop(streamed);
    let mut info = map.info().clone();
    let mut rec = StageRecord::now("render", knn_record(&knn));
    rec.report = crate::tiles::part_report(
        map,
        tile,
        c.photon.len(),
        start.elapsed().as_secs_f64(),
        serde_json::json!({ "lookups": lookups.len(), "lookups_crc32": lookups_crc(&lookups) }),
    );
    info.history.push(rec);
    let gather = |column: &[[f32; 3]]| -> Vec<[f32; 3]> {
        let v = c.photon.iter().map(|&i| column[i as usize]).collect();
        map.release_pages();
        v
    };
    let (positions, flux) = (gather(map.positions()), gather(map.flux()));
    let normals = map.column::<[f32; 3]>(name::NORMAL)?.map(gather);
    let index: Vec<u64> = c.photon.iter().map(|&i| i as u64).collect();
    let mut columns: Vec<(ColumnSpec, &[u8])> = vec![
        (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&positions)),
        (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&flux)),
    ];
    if let Some(n) = &normals {
        columns.push((ColumnSpec::of::<[f32; 3]>(name::NORMAL), bytemuck::cast_slice(n)));
    }
    columns.extend([
        (ColumnSpec::of::<u64>(crate::detect::PHOTON_INDEX), bytemuck::cast_slice(&index)),
        (ColumnSpec::of::<u32>(PART_LOOKUP), bytemuck::cast_slice(&c.lookup)),
        (ColumnSpec::of::<f32>(PART_DIST2), bytemuck::cast_slice(&c.dist2)),
    ]);
    let table = PhotonTable::from_columns(map.file_name(), info, &columns)?.into_owned();
    Ok(table)
}

/// The image `request` asks of `map`, its estimates made from the tile parts of every tile
/// (in any order) that `render MAP --tile i/n` wrote with the same options: the image
/// [`render_map`] makes, byte for byte. An error names the part at fault: one cut from
/// another map, made for other lookups or another estimate, a tile given twice or missing.
pub fn render_from_parts(
    map: &MapView,
    request: &MapRender,
    parts: &[MapView],
) -> Result<Rendered, RenderError> {
    let file = map.file_name();
    let Streamable { renderer, knn, remarks, scene } = streamable(map, request)?;
    let lookups = renderer.lookups(&|_| {})?;
    let flat: Vec<super::Lookup> = lookups.iter().flatten().copied().collect();
    let crc = lookups_crc(&flat) as u64;
    let bad = |part: &MapView, m: String| RenderError::Invalid(format!("{}: {m}", part.file_name()));
    let Some(first) = parts.first() else { return Err(RenderError::Invalid("no tile parts given".into())) };
    let count = crate::tiles::part_record(map, first, "render", "photonkit render")
        .map_err(|m| bad(first, m))?
        .tile
        .count;
    let mut seen = vec![false; count];
    let mut rows = Vec::new();
    for part in parts {
        let r =
            crate::tiles::part_record(map, part, "render", "photonkit render").map_err(|m| bad(part, m))?;
        if r.tile.count != count {
            return Err(bad(
                part,
                format!("a part of {} tiles, where the first is of {count}", r.tile.count),
            ));
        }
        if std::mem::replace(&mut seen[r.tile.index], true) {
            return Err(bad(part, format!("tile {} is given twice", r.tile)));
        }
        let num = |key: &str| r.report.get(key).and_then(serde_json::Value::as_u64);
        if num("lookups") != Some(flat.len() as u64)
            || num("lookups_crc32") != Some(crc)
            || *r.parameters != knn_record(&knn)
        {
            return Err(bad(
                part,
                "made with other render options (its lookups or its estimate differ from this render's)"
                    .into(),
            ));
        }
        let missing = |name: &str| bad(part, format!("no {name} column"));
        let lookup = part.column::<u32>(PART_LOOKUP)?.ok_or_else(|| missing(PART_LOOKUP))?;
        let photon = part
            .column::<u64>(crate::detect::PHOTON_INDEX)?
            .ok_or_else(|| missing(crate::detect::PHOTON_INDEX))?;
        let dist2 = part.column::<f32>(PART_DIST2)?.ok_or_else(|| missing(PART_DIST2))?;
        let (flux, normals) = (part.flux(), part.column::<[f32; 3]>(name::NORMAL)?);
        for (j, ((&l, &p), &d)) in lookup.iter().zip(photon).zip(dist2).enumerate() {
            if l as usize >= flat.len() || p >= map.len() as u64 {
                return Err(bad(part, format!("row {j} names a lookup or photon that does not exist")));
            }
            rows.push(super::tiled::CandidateRow {
                lookup: l,
                photon: p as u32,
                dist2: d,
                flux: flux[j],
                normal: normals.map(|n| n[j]),
            });
        }
    }
    if let Some(missing) = seen.iter().position(|s| !s) {
        return Err(RenderError::Invalid(format!("the part of tile {missing}/{count} is missing")));
    }
    let estimated = super::tiled::estimate_from_candidates(&flat, rows, knn);
    let caustic = super::tiled::per_image_tile(&estimated, &lookups);
    let (image, stats) = renderer.render_given(&caustic, &|_| {})?;
    let o = renderer.opts;
    let (notes, description) = header_notes(&o, request, file, scene);
    let plan = super::tiled::Plan { tiles: count, chunks: 1 };
    Ok(Rendered { image, stats, notes, options: o, description, photons: map.len(), remarks, plan })
}

/// The mode `request` renders `map` in, and what to tell the user about it; checks what can
/// be checked before any work.
fn settle_mode(map: &MapView, request: &MapRender) -> Result<(Mode, Vec<String>), RenderError> {
    let plane = matches!(request.framing, Framing::Plane { .. });
    let mut mode = request.mode.unwrap_or(if plane { Mode::Irradiance } else { Mode::Full });
    if plane && mode != Mode::Irradiance {
        return Err(RenderError::Invalid(
            "--plane shows irradiance only (no scene, no materials): leave out --mode or use irradiance"
                .into(),
        ));
    }
    check_estimator(&request.estimator, request.diagnostic.as_ref())?;
    if map.is_empty() {
        return Err(RenderError::EmptyMap { file: map.file_name().to_string() });
    }
    let mut remarks = Vec::new();
    let traced_direct = map.info().trace_record().is_some_and(|t| t.parameters.store == "direct");
    if traced_direct && mode == Mode::Full {
        remarks.push("the map stores direct photons too, so direct light is not added again".to_string());
        mode = Mode::Caustic;
    }
    Ok((mode, remarks))
}

/// The options of `request` in `mode` for an image of `width` × `height`.
fn options(request: &MapRender, mode: Mode, (width, height): (u32, u32)) -> RenderOptions {
    RenderOptions {
        width,
        height,
        spp: request.spp,
        mode,
        estimator: request.estimator,
        eye: request.eye,
        seed: request.seed,
        keep_samples: request.keep_samples,
        supersample: None,
    }
}

/// The EXR header's notes of an image rendered with `o`.
fn header_notes(o: &RenderOptions, request: &MapRender, file: &str, scene: String) -> (Notes, String) {
    let description = match request.diagnostic {
        Some(d) => format!("diagnostic {}", d.which.name()),
        None => o.estimator.describe(),
    };
    let unit = if request.diagnostic.is_some() { "none (false colour)" } else { o.mode.unit() };
    let notes = vec![
        ("photonkit:units".to_string(), unit.to_string()),
        ("photonkit:mode".to_string(), o.mode.name().to_string()),
        ("photonkit:estimator".to_string(), description.clone()),
        ("photonkit:photon_map".to_string(), file.to_string()),
        ("photonkit:scene".to_string(), scene),
        ("photonkit:samples_per_pixel".to_string(), o.spp.to_string()),
    ];
    (notes, description)
}

/// The estimator's and the diagnostic's settings, checked before any work.
fn check_estimator(estimator: &Estimator, diagnostic: Option<&DiagnosticView>) -> Result<(), RenderError> {
    let positive = |x: f32| x > 0.0 && x.is_finite();
    let (k, q, max_radius) = match *estimator {
        Estimator::Knn { k, max_radius, .. } => (k, None, max_radius),
        Estimator::Variable { k, .. } => (k, None, None),
        Estimator::Diffusion { k, q } => (k, Some(q), None),
        _ => (estimator.k(), None, None),
    };
    if k == 0 {
        return Err(RenderError::Invalid("-k and --diffusion-k need at least 1 neighbour".into()));
    }
    if q.is_some_and(|q| !positive(q))
        || max_radius.is_some_and(|r| !positive(r))
        || diagnostic.and_then(|d| d.dot_radius).is_some_and(|r| !positive(r))
    {
        return Err(RenderError::Invalid(
            "--diffusion-q, --max-radius and --dot-radius must be positive".into(),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::PhotonTable;
    use crate::synthetic::uniform_square;

    fn plane(offset: f32) -> Framing<'static> {
        Framing::Plane {
            axis: 2,
            offset,
            tolerance_m: 1e-3,
            rect: Some([0.1, 0.1, 0.9, 0.9]),
            width: Some(32),
            height: None,
        }
    }

    #[test]
    fn a_plane_view_of_uniform_photons_shows_their_irradiance() {
        // 1 W spread uniformly over the unit square: E = 1/3 W/m² per channel.
        let m = uniform_square(20_000, 3, 1.0);
        let info = m.info("test", 3, "2026-01-01T00:00:00Z");
        let table = PhotonTable::from_columns("square", info, &m.columns()).unwrap();
        let ticks = std::sync::atomic::AtomicU64::new(0);
        let total = std::sync::atomic::AtomicU64::new(0);
        let progress = |p: Progress| match p {
            Progress::Start { tiles } => total.store(tiles, std::sync::atomic::Ordering::Relaxed),
            Progress::Tiles(n) => _ = ticks.fetch_add(n, std::sync::atomic::Ordering::Relaxed),
            Progress::Estimate(_) => {}
        };
        let r = render_map(&table.view(), &MapRender::new(plane(0.0)), &progress).unwrap();
        assert_eq!((r.image.width, r.image.height), (32, 32), "the square rectangle keeps its aspect");
        assert_eq!(r.options.mode, Mode::Irradiance);
        assert_eq!(r.photons, 20_000);
        assert_eq!(ticks.into_inner(), total.into_inner());
        let mean = r.image.mean();
        for c in mean.to_array() {
            assert!((c / (1.0 / 3.0) - 1.0).abs() < 0.03, "mean irradiance {mean} W/m², expected 1/3");
        }
        let unit = r.notes.iter().find(|(k, _)| k == "photonkit:units").unwrap();
        assert!(unit.1.starts_with("W/m^2"), "{unit:?}");
    }

    #[test]
    fn bad_requests_are_refused_before_any_work() {
        let m = uniform_square(100, 3, 1.0);
        let info = m.info("test", 3, "2026-01-01T00:00:00Z");
        let table = PhotonTable::from_columns("square", info, &m.columns()).unwrap();
        let none = |_: Progress| {};
        let err = |req: &MapRender| render_map(&table.view(), req, &none).unwrap_err().to_string();
        let full = MapRender { mode: Some(Mode::Full), ..MapRender::new(plane(0.0)) };
        assert!(err(&full).contains("irradiance only"), "{}", err(&full));
        let far = MapRender::new(plane(5.0));
        assert!(err(&far).contains("no photon lies within"), "{}", err(&far));
        let k0 = MapRender {
            estimator: Estimator::Knn { k: 0, kernel: super::super::Kernel::Epanechnikov, max_radius: None },
            ..MapRender::new(plane(0.0))
        };
        assert!(err(&k0).contains("at least 1 neighbour"), "{}", err(&k0));
        let empty = uniform_square(0, 3, 1.0);
        let info = empty.info("test", 3, "2026-01-01T00:00:00Z");
        let table = PhotonTable::from_columns("empty", info, &empty.columns()).unwrap();
        let e = render_map(&table.view(), &MapRender::new(plane(0.0)), &none).unwrap_err();
        assert!(matches!(e, RenderError::EmptyMap { .. }), "{e}");
    }

    #[test]
    fn camera_changes_keep_the_aspect_and_need_a_view() {
        let base = Camera::look_at(
            Projection::Pinhole { fov_y_rad: 0.5 },
            Vec3::new(0.0, -3.0, 1.0),
            Vec3::ZERO,
            Vec3::Z,
            [800, 400],
        )
        .unwrap();
        let c = CameraChanges { width: Some(300), ..Default::default() }.camera(Some(&base)).unwrap();
        assert_eq!(c.resolution, [300, 150]);
        assert_eq!(c.eye, base.eye);
        assert!(c.forward.abs_diff_eq(base.forward, 1e-6));
        let c =
            CameraChanges { ortho_height_m: Some(2.0), ..Default::default() }.camera(Some(&base)).unwrap();
        assert_eq!(c.projection, Projection::Orthographic { height_m: 2.0 });
        let e = CameraChanges::default().camera(None).unwrap_err().to_string();
        assert!(e.contains("no [camera]"), "{e}");
        let e = CameraChanges { fov_deg: Some(180.0), ..Default::default() }.camera(Some(&base)).unwrap_err();
        assert!(e.to_string().contains("between 0 and 180"), "{e}");
    }
}
