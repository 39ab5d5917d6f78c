//! Relaxation (Eq. 8–9) and collapse: photons repel their nearest neighbours until they form
//! a blue-noise set, each moving only within its constraint basis.
//!
//! One iteration is Jacobi style: every photon's force is computed from the same snapshot of
//! positions, then all photons move, then the neighbour index is brought up to date (refitted
//! to the moved photons, rebuilt every [`REBUILD_EVERY`] iterations). Motion lies in the
//! photon's tangent plane, so photons on planar receivers stay on them; flux never changes, so
//! the total flux is preserved exactly.

mod force;
mod iteration;
pub mod part;
mod surface;
#[cfg(test)]
mod tests;
pub mod tiled;

use serde::Serialize;

pub use crate::tiles::ExactSum;
pub use force::{clamp_step, project_on_basis, project_on_tangent, repulsion};
pub use iteration::{
    Constraint, IndexSearch, IterationMeasure, MapWide, MeasureSums, NeighbourSearch, PerPhoton,
    REBUILD_EVERY, Scratch, coefficient_of_variation, diffuse_flux, index_positions, iterate, iterate_in,
    map_spacing,
};
pub use part::{merge_parts, tile_part};
use surface::back_to_surfaces;
pub use surface::return_to_surface;
pub use tiled::{TileRelaxed, relax_tile, relax_tiled};

/// Relaxation parameters; defaults are the paper's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct RelaxParams {
    /// R: number of iterations.
    pub iterations: usize,
    /// Kf: neighbours in the repulsion force.
    pub kf: usize,
    /// ε of Eq. 8, as a fraction of r_K so the force does not depend on the scene's scale.
    pub epsilon: f32,
    /// Largest step, as a fraction of the mean photon spacing r_K·sqrt(π/Kf) around the photon,
    /// so no photon jumps past its neighbours.
    pub step_limit: f32,
    /// The 2009 method's flux diffusion, per iteration: each photon's flux moves this fraction
    /// of the way toward the mean of its Kf neighbours' ([`diffuse_flux`]); 0 (the default)
    /// leaves every photon's flux untouched.
    pub flux_diffusion: f32,
    /// For photons that carry their wavelength (a dispersive scene), outside the parameter-space
    /// phase: a photon's Kf neighbours are those within this many nanometres of its own
    /// wavelength ([`RelaxSpace::WorldSpectral`]), so the photons of each colour spread evenly
    /// among themselves and every kernel holds an even sample of the spectrum (docs/spectral.md);
    /// 0 takes every wavelength (and is what a record written before the window reads as).
    #[serde(default)]
    pub spectral_window: f32,
}

/// The default [`RelaxParams::spectral_window`], nm (docs/spectral.md has the measurements).
pub const DEFAULT_SPECTRAL_WINDOW: f32 = 35.0;

impl Default for RelaxParams {
    fn default() -> Self {
        RelaxParams {
            iterations: 7,
            kf: 16,
            epsilon: 1e-3,
            step_limit: 0.5,
            flux_diffusion: 0.0,
            spectral_window: DEFAULT_SPECTRAL_WINDOW,
        }
    }
}

/// What can stop the relax or collapse stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RelaxError {
    /// Reading the map's columns failed.
    #[error(transparent)]
    Format(#[from] crate::format::FormatError),
    /// The photons can not be indexed.
    #[error(transparent)]
    Spatial(#[from] crate::spatial::SpatialError),
    /// A parameter out of range, or a column relax needs missing or malformed.
    #[error("{file}: {message}")]
    Input {
        /// The map as named to the user.
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A map's photons can not be indexed.
    #[error("{file}: {source}")]
    Photons {
        /// The map as named to the user.
        file: String,
        /// Why, photon indices in the map's order.
        source: crate::spatial::SpatialError,
    },
}

/// The most iterations one `relax` runs. Relaxation settles within tens of iterations (the
/// paper runs 7 + 7), so more than this is a mistyped count: `-R 1000000000` is refused here
/// instead of aborting on its allocation (issue 31, item 4).
pub const MAX_ITERATIONS: usize = 10_000;

impl RelaxParams {
    /// These parameters as a stage record holds them: the spectral window only where it
    /// applied (`space` [`RelaxSpace::WorldSpectral`]), so a map without a wavelength is
    /// recorded, and written, as it was before the window.
    pub fn record(&self, space: RelaxSpace) -> serde_json::Value {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        if space != RelaxSpace::WorldSpectral
            && let Some(o) = v.as_object_mut()
        {
            o.remove("spectral_window");
        }
        v
    }

    /// These parameters with Kf capped at `photons` − 1 (at least 1): a photon has no more
    /// neighbours than that, so the result is the same without buffers sized for the request
    /// (issue 31, item 6).
    pub fn capped(&self, photons: usize) -> RelaxParams {
        RelaxParams { kf: self.kf.min(photons.saturating_sub(1).max(1)), ..*self }
    }
}

/// Which neighbours relaxation uses, from the map's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RelaxSpace {
    /// Before collapse: world-space neighbours within each photon's r_param in parameter
    /// space, exactly as `detect` restricted them.
    WorldParams,
    /// After collapse, or without trajectory parameters: plain world-space neighbours.
    World,
    /// After collapse, for photons that all carry their wavelength: world-space neighbours
    /// within [`RelaxParams::spectral_window`] of the photon's wavelength; a photon that
    /// detection held along an edge or filament (its factor on v_b below
    /// [`crate::detect::HELD_FACTOR`]) keeps the neighbours of every wavelength, which spread it
    /// evenly along its edge (docs/spectral.md).
    WorldSpectral,
}

/// The outcome of relaxing a map: new positions and what each iteration did.
#[derive(Clone)]
pub struct Relaxed {
    /// The relaxed positions, in the map's photon order, metres.
    pub positions: Vec<[f32; 3]>,
    /// Which neighbours were used.
    pub space: RelaxSpace,
    /// False when the map has no constraint basis and photons moved freely in their tangent plane.
    pub constrained: bool,
    /// One per iteration, in order.
    pub measures: Vec<IterationMeasure>,
    /// New surface normals when photons were returned to curved surfaces ([`relax_map_on`]).
    pub normals: Option<Vec<[f32; 3]>>,
    /// Moves refused because the photon's surface was not found near the moved point.
    pub refused_moves: u64,
    /// Diffused flux, when `flux_diffusion` > 0.
    pub flux: Option<Vec<[f32; 3]>>,
}

/// Relaxes every photon of `map` for `p.iterations` iterations (Eq. 8–9), calling
/// `on_iteration` after each. The map's state picks the space ([`RelaxSpace`]); its
/// `basis_u`/`basis_v` columns constrain the motion, or, without them, its `normal` column
/// keeps photons in their tangent plane.
pub fn relax_map(
    map: &crate::format::MapView,
    p: &RelaxParams,
    on_iteration: impl FnMut(&IterationMeasure),
) -> Result<Relaxed, RelaxError> {
    relax_map_on(map, p, None, on_iteration)
}

/// [`relax_map`], and with a scene, photons that moved are returned to their surface (the
/// `surface` column names it) by [`return_to_surface`], and their normals follow: photons on
/// curved receivers stay on them. A move whose surface is not found is refused.
pub fn relax_map_on(
    map: &crate::format::MapView,
    p: &RelaxParams,
    scene: Option<&crate::scene::Scene>,
    mut on_iteration: impl FnMut(&IterationMeasure),
) -> Result<Relaxed, RelaxError> {
    use crate::spatial::order::{locality_order, unpermuted};
    let setup = Setup::of(map, p, scene.is_some())?;
    // Photons are worked on in spatial order (see [`crate::spatial::order`]): every column
    // the iterations read is relabelled here, and what they change is put back at the end.
    let order = locality_order(map.positions());
    let mut columns = Columns::of(map, &order, &setup)?;
    let wide = MapWide { labels: None, spacing: setup.spacing, coincident: setup.coincident };
    let run = run(map, &mut columns, &setup, scene, &wide, &order, |_, m, _| {
        on_iteration(m);
        true
    })?;
    Ok(Relaxed {
        positions: unpermuted(&columns.unscaled_positions(&setup), &order),
        space: setup.space,
        constrained: columns.constrained(),
        measures: run.measures,
        normals: columns.normals.map(|n| unpermuted(&n, &order)),
        refused_moves: run.refused.iter().map(|&k| k as u64).sum(),
        flux: columns.flux.map(|f| unpermuted(&f, &order)),
    })
}

/// What a relax run takes from the whole map before it starts: the parameters checked and
/// capped, the space, and the map-wide quantities every tile must share (docs/tiles.md).
#[derive(Clone, Debug)]
pub(crate) struct Setup {
    /// The parameters, Kf capped at the map's photons.
    pub p: RelaxParams,
    pub space: RelaxSpace,
    /// The power of two the positions are worked on scaled by ([`working_scale`]).
    pub scale: f32,
    /// The map's mean spacing in working units ([`iteration::map_spacing`]).
    pub spacing: f32,
    /// Whether all the map's photons sit on one point.
    pub coincident: bool,
}

impl Setup {
    pub fn of(map: &crate::format::MapView, p: &RelaxParams, with_scene: bool) -> Result<Setup, RelaxError> {
        use crate::format::{State, name};
        let input = |message: String| RelaxError::Input { file: map.file_name().to_string(), message };
        if p.kf == 0 {
            return Err(input("Kf must be at least 1".into()));
        }
        if !(p.spectral_window.is_finite() && p.spectral_window >= 0.0) {
            return Err(input(format!(
                "the spectral window must be a finite number of nanometres, at least 0 (got {})",
                p.spectral_window
            )));
        }
        if p.iterations > MAX_ITERATIONS {
            return Err(input(format!(
                "{} iterations requested; at most {MAX_ITERATIONS} are allowed (relaxation settles within tens)",
                p.iterations
            )));
        }
        let space = match (map.info().state, map.spec(name::R_PARAM), map.spec(name::PARAMS)) {
            (State::Detected, Some(_), Some(_)) => RelaxSpace::WorldParams,
            (_, _, Some(_))
                if p.spectral_window > 0.0
                    && !map.info().emitters.is_empty()
                    && map.info().emitters.iter().all(|e| e.is_spectral()) =>
            {
                RelaxSpace::WorldSpectral
            }
            _ => RelaxSpace::World,
        };
        let positions = map.positions();
        // Coordinates far from 1 (near 1e30, or 1e-30) overflow or underflow squared distances in
        // f32; without a scene to return to, the photons are worked on scaled by a power of two
        // (exact) and scaled back at the end (issue 31, item 7).
        let scale = if with_scene { 1.0 } else { working_scale(positions) };
        let spacing = if scale == 1.0 {
            iteration::map_spacing(positions)
        } else {
            let scaled: Vec<[f32; 3]> = positions.iter().map(|x| x.map(|v| v * scale)).collect();
            iteration::map_spacing(&scaled)
        };
        let coincident = positions.iter().all(|x| *x == positions[0]);
        Ok(Setup { p: p.capped(map.len()), space, scale, spacing, coincident })
    }
}

/// The columns relaxation reads and changes, for some photons of a map (all of them, or a
/// tile's working set) in the whole map's working order; positions scaled to working units.
pub(crate) struct Columns {
    pub positions: Vec<[f32; 3]>,
    basis_u: Option<Vec<[f32; 3]>>,
    basis_v: Option<Vec<[f32; 3]>>,
    normal: Option<Vec<[f32; 3]>>,
    r_param: Option<Vec<f32>>,
    /// Parameters (wavelength components scaled as detect measured them) and their stride.
    params: Option<(Vec<f32>, usize)>,
    dims: Vec<u32>,
    emitters: Option<Vec<u16>>,
    surfaces: Option<Vec<u32>>,
    /// New normals, when photons are returned to their surfaces.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Diffused flux, when `flux_diffusion` > 0.
    pub flux: Option<Vec<[f32; 3]>>,
}

impl Columns {
    /// The columns of photons `work` (file indices) of `map`.
    pub fn of(map: &crate::format::MapView, work: &[u32], setup: &Setup) -> Result<Columns, RelaxError> {
        Self::of_gathered(map, &mut Gathered::of(work), setup, false)
    }

    /// The columns of `map` of the photons `gathered` holds, whose file order, and possibly
    /// positions, are known ([`Gathered`]; its positions are taken, not copied). `search_only`:
    /// only those [`first_spacings`] reads (positions, and what restricts the search), not the
    /// constraint's.
    pub(crate) fn of_gathered(
        map: &crate::format::MapView,
        gathered: &mut Gathered,
        setup: &Setup,
        search_only: bool,
    ) -> Result<Columns, RelaxError> {
        use crate::format::name;
        use crate::spatial::ParamColumn;
        use crate::spatial::order::permuted;
        let input = |message: String| RelaxError::Input { file: map.file_name().to_string(), message };
        let meta = map.info();
        let pages = map.pages();
        // A tile's photons lie all over the file: each column is copied in file order, in blocks
        // whose pages are released as read ([`crate::format::Pages::gather_rows`]), and put in
        // `work`'s order in memory.
        let known = gathered.positions.take();
        let (work, rows, within) = (&gathered.photons[..], &gathered.rows[..], &gathered.within[..]);
        fn copy<T: bytemuck::Pod + Default + Send + Sync>(
            pages: &crate::format::Pages,
            v: &[T],
            stride: usize,
            rows: &[u32],
            within: &[u32],
        ) -> Vec<T> {
            permuted(&pages.gather_rows(v, stride, rows), within, stride)
        }
        let sorted = |column: Option<&[[f32; 3]]>| column.map(|c| copy(&pages, c, 1, rows, within));
        // A search reads the basis only where it marks the photons held in the spectral window.
        let wanted = |column: &str| {
            !search_only || column == name::BASIS_V && setup.space == RelaxSpace::WorldSpectral
        };
        let column = |name: &str| -> Result<Option<Vec<[f32; 3]>>, RelaxError> {
            Ok(if wanted(name) { sorted(map.column::<[f32; 3]>(name)?) } else { None })
        };
        let basis_u = column(name::BASIS_U)?;
        let basis_v = column(name::BASIS_V)?;
        let normal = column(name::NORMAL)?;
        if !(search_only || normal.is_some() || basis_u.is_some() && basis_v.is_some()) {
            return Err(input(
                "relax needs a constraint basis (run `photonkit detect`) or a 'normal' column to keep \
                 photons on their surfaces"
                    .into(),
            ));
        }
        // r_param restricts only the parameter-space phase.
        let r_param = match setup.space {
            RelaxSpace::WorldParams => {
                map.column::<f32>(name::R_PARAM)?.map(|r| copy(&pages, r, 1, rows, within))
            }
            RelaxSpace::World | RelaxSpace::WorldSpectral => None,
        };
        let params = match map.spec(name::PARAMS) {
            Some(c) => {
                let values =
                    bytemuck::try_cast_slice::<u8, f32>(map.column_bytes(name::PARAMS).unwrap_or(&[]))
                        .map_err(|e| input(format!("params column: {e}")))?;
                let stride = c.components as usize;
                if values.len() != stride * map.len() {
                    return Err(input(format!(
                        "params column holds {} values, expected {}",
                        values.len(),
                        stride * map.len()
                    )));
                }
                Some((copy(&pages, values, stride, rows, within), stride))
            }
            None => None,
        };
        let dims: Vec<u32> = meta.emitters.iter().map(|e| e.param_dims).collect();
        let emitters = map.column::<u16>(name::EMITTER)?.map(|e| copy(&pages, e, 1, rows, within));
        // A wavelength component enters distances with the scale detect gave it (the one its
        // r_param was measured in; docs/spectral.md).
        let (params, r_param, dims) = match (params, meta.param_scales()) {
            // After collapse, the wavelength alone, in units of the spectral window, so that the
            // window is a parameter-space radius of 1; a held photon's radius is unbounded.
            (Some((values, stride)), _) if setup.space == RelaxSpace::WorldSpectral => {
                let at: Vec<Option<usize>> =
                    meta.emitters.iter().map(|e| e.parameterisation.spectral_component()).collect();
                let w = setup.p.spectral_window;
                let lambda = values
                    .chunks_exact(stride)
                    .enumerate()
                    .map(|(i, q)| {
                        let e = emitters.as_ref().map_or(0, |e| e[i] as usize);
                        match at.get(e) {
                            Some(Some(k)) if *k < stride => Ok(q[*k] / w),
                            _ => Err(input(format!("photon {}: emitter {e} has no wavelength", work[i]))),
                        }
                    })
                    .collect::<Result<Vec<f32>, _>>()?;
                let held = |i: usize| {
                    basis_v
                        .as_ref()
                        .is_some_and(|v| glam::Vec3::from(v[i]).length() < crate::detect::HELD_FACTOR)
                };
                let radius = (0..work.len()).map(|i| if held(i) { f32::INFINITY } else { 1.0 }).collect();
                (Some((lambda, 1)), Some(radius), vec![1])
            }
            (Some((values, stride)), Some(factors)) => {
                let column = ParamColumn { values: &values, stride, dims: &dims };
                (Some((column.scaled(emitters.as_deref(), &factors), stride)), r_param, dims)
            }
            (p, _) => (p, r_param, dims),
        };
        let mut positions = match known {
            Some(at) => at,
            None => copy(&pages, map.positions(), 1, rows, within),
        };
        if setup.scale != 1.0 {
            positions.iter_mut().flatten().for_each(|x| *x *= setup.scale);
        }
        let surfaces = if search_only {
            None
        } else {
            map.column::<u32>(name::SURFACE)?.map(|s| copy(&pages, s, 1, rows, within))
        };
        let flux =
            (!search_only && setup.p.flux_diffusion > 0.0).then(|| copy(&pages, map.flux(), 1, rows, within));
        Ok(Columns {
            positions,
            basis_u,
            basis_v,
            normal,
            r_param,
            params,
            dims,
            emitters,
            surfaces,
            normals: None,
            flux,
        })
    }

    /// Whether motion is constrained by a basis (else by the tangent plane).
    pub fn constrained(&self) -> bool {
        self.basis_u.is_some() && self.basis_v.is_some()
    }

    /// The positions in metres.
    pub fn unscaled_positions(&self, setup: &Setup) -> Vec<[f32; 3]> {
        let mut x = self.positions.clone();
        if setup.scale != 1.0 {
            x.iter_mut().flatten().for_each(|v| *v /= setup.scale);
        }
        x
    }
}

/// What [`run`] reports besides the moved columns.
pub(crate) struct Run {
    pub measures: Vec<IterationMeasure>,
    /// Each photon's refused moves (empty without a scene).
    pub refused: Vec<u32>,
}

/// Algorithm 1's relax stage over `columns`: the iterations, each followed by
/// `after(scratch, measure, positions the iteration started from)`, which stops the run by
/// returning false. `order` turns a working label back into a file index for errors.
pub(crate) fn run(
    map: &crate::format::MapView,
    columns: &mut Columns,
    setup: &Setup,
    scene: Option<&crate::scene::Scene>,
    wide: &MapWide,
    order: &[u32],
    mut after: impl FnMut(&Scratch, &IterationMeasure, &[[f32; 3]]) -> bool,
) -> Result<Run, RelaxError> {
    use crate::spatial::SpatialIndex;
    let p = &setup.p;
    let space = setup.space;
    let Columns {
        positions,
        basis_u,
        basis_v,
        normal,
        r_param,
        params,
        dims,
        emitters,
        surfaces,
        normals,
        flux,
    } = columns;
    let constraint = match (basis_u.as_deref(), basis_v.as_deref(), normal.as_deref()) {
        (Some(u), Some(v), _) => Constraint::Basis { u, v },
        (_, _, Some(normal)) => Constraint::Tangent { normal },
        _ => unreachable!("checked by Columns::of"),
    };
    if let (Some(_), Some(_), Some(n)) = (scene, surfaces.as_ref(), normal.as_ref()) {
        *normals = Some(n.clone());
    }
    let params = params.as_ref().map(|(v, s)| (v.as_slice(), *s));
    let (r_param, emitters, surfaces) = (r_param.as_deref(), emitters.as_deref(), surfaces.as_deref());
    let mut next = positions.clone();
    let mut refused = vec![0u32; if scene.is_some() && surfaces.is_some() { positions.len() } else { 0 }];
    let mut scratch = Scratch::default();
    let mut measures = Vec::with_capacity(p.iterations);
    let mut index: Option<SpatialIndex> = None;
    let (sp, split_scale) = search_space(space, positions, r_param, p.kf);
    for it in 0..p.iterations {
        let points = search_points(space, positions, params, dims, emitters);
        let separated = measures.last().is_some_and(|m: &IterationMeasure| m.separated > 0);
        index_positions(&mut index, &points, sp, split_scale, it, separated).map_err(|e| {
            RelaxError::Photons { file: map.file_name().to_string(), source: e.in_file_order(order) }
        })?;
        let search = IndexSearch {
            index: index.as_ref().expect("built above"),
            points: &points,
            radius: if space == RelaxSpace::World { None } else { r_param },
        };
        // The index borrows `positions`; `iterate` moves a copy, then the two swap.
        next.copy_from_slice(positions);
        let m = iterate_in(&mut next, &search, constraint, p, it, &mut scratch, wide);
        if let Some(f) = flux.as_mut() {
            diffuse_flux(f, &search, p.kf, p.flux_diffusion);
        }
        if let (Some(scene), Some(surf), Some(ns)) = (scene, surfaces, normals.as_mut()) {
            back_to_surfaces(scene, surf, positions, &mut next, ns, &mut refused);
        }
        std::mem::swap(positions, &mut next);
        let scale = setup.scale as f64;
        let m = IterationMeasure {
            mean_displacement: m.mean_displacement / scale,
            max_displacement: m.max_displacement / scale,
            ..m
        };
        measures.push(m);
        // `next` now holds the positions the iteration started from.
        if !after(&scratch, &m, &next) {
            break;
        }
    }
    Ok(Run { measures, refused })
}

/// The photons as relaxation's searches in `space` see them: their positions, and where the
/// search is restricted (the parameter ball before the collapse, the spectral window after it)
/// their parameters; parameters compare within an emitter, wavelengths across emitters.
fn search_points<'a>(
    space: RelaxSpace,
    positions: &'a [[f32; 3]],
    params: Option<(&'a [f32], usize)>,
    dims: &'a [u32],
    emitters: Option<&'a [u16]>,
) -> crate::spatial::PointSet<'a> {
    use crate::spatial::ParamColumn;
    crate::spatial::PointSet {
        positions,
        params: match space {
            RelaxSpace::WorldParams | RelaxSpace::WorldSpectral => {
                params.map(|(values, stride)| ParamColumn { values, stride, dims })
            }
            RelaxSpace::World => None,
        },
        emitters: if space == RelaxSpace::WorldParams { emitters } else { None },
    }
}

/// The index's space for relaxation in `space`, and its split scale: a parameter ball (r_param,
/// or the spectral window's radius 1) is often far wider, in its units, than the world
/// neighbourhood it restricts, so the trees split as if it were not (a speed setting only).
fn search_space(
    space: RelaxSpace,
    positions: &[[f32; 3]],
    r_param: Option<&[f32]>,
    kf: usize,
) -> (crate::spatial::Space, Option<f32>) {
    use crate::spatial::Space;
    match space {
        RelaxSpace::World => (Space::World, None),
        RelaxSpace::WorldParams | RelaxSpace::WorldSpectral => {
            (Space::WorldParams, r_param.and_then(|r| crate::spatial::ball_split_scale(positions, r, kf)))
        }
    }
}

/// What the first iteration of [`run`] sets of each photon of `columns` (in their order),
/// without computing any step: its first spacing, r_K·sqrt(π/Kf) from its Kf nearest in the
/// iteration's space (Eq. 8's step limit; ∞ when they all sit on it), and how far its search
/// read (r_K; ∞ when it found fewer than Kf). The one search a photon makes is for its Kf + 1
/// nearest counting itself, which sits at distance 0, so r_K is the farthest found.
pub(crate) fn first_spacings(
    map: &crate::format::MapView,
    columns: &Columns,
    setup: &Setup,
    order: &[u32],
) -> Result<(Vec<f32>, Vec<f32>), RelaxError> {
    use crate::spatial::Neighbours;
    use rayon::prelude::*;
    let (p, space) = (&setup.p, setup.space);
    let positions = &columns.positions;
    let r_param = columns.r_param.as_deref();
    let params = columns.params.as_ref().map(|(v, s)| (v.as_slice(), *s));
    let points = search_points(space, positions, params, &columns.dims, columns.emitters.as_deref());
    let (sp, split_scale) = search_space(space, positions, r_param, p.kf);
    let mut index = None;
    index_positions(&mut index, &points, sp, split_scale, 0, false).map_err(|e| RelaxError::Photons {
        file: map.file_name().to_string(),
        source: e.in_file_order(order),
    })?;
    let index = index.expect("built above");
    let n = positions.len();
    let k = p.capped(n).kf;
    let radius = if space == RelaxSpace::World { None } else { r_param };
    // In the index's order, as the iterations search.
    let slots = index.order();
    let found: Vec<Vec<(f32, f32)>> = slots
        .par_chunks(iteration::CHUNK)
        .map(|chunk| {
            let mut found = Neighbours::farthest_only(k + 1);
            chunk
                .iter()
                .map(|&i| {
                    let i = i as usize;
                    index.knn(&points.query(i, radius.map(|r| r[i])), k + 1, &mut found);
                    let kept = found.len().saturating_sub(1);
                    let r_k = if kept == 0 { 0.0 } else { found.max_dist2().unwrap_or(0.0).sqrt() };
                    let spacing = r_k * (std::f32::consts::PI / kept.max(1) as f32).sqrt();
                    let first = if spacing > 0.0 { spacing } else { f32::INFINITY };
                    (first, if kept < p.kf { f32::INFINITY } else { r_k })
                })
                .collect()
        })
        .collect();
    let (mut first, mut read) = (vec![0f32; n], vec![0f32; n]);
    for (&i, (f, r)) in slots.iter().zip(found.into_iter().flatten()) {
        (first[i as usize], read[i as usize]) = (f, r);
    }
    Ok((first, read))
}

/// `work`'s photons (file indices, distinct) in file order, and where each of `work` is among
/// them: `work[k] == rows[within[k]]`.
/// Photons a relaxation works on, in the order it works on them, with their file order (a
/// copy of their columns reads the map in file order), and their positions when the one who
/// chose them has read them already.
pub(crate) struct Gathered {
    /// The photons (indices in the map), in working order.
    pub photons: Vec<u32>,
    /// The same photons in file order (ascending).
    pub rows: Vec<u32>,
    /// Per photon in working order, its place in `rows`.
    pub within: Vec<u32>,
    /// Their positions in working order (metres), if read.
    pub positions: Option<Vec<[f32; 3]>>,
}

impl Gathered {
    /// `work` (indices in the map, in working order), its file order found by a sort.
    pub fn of(work: &[u32]) -> Gathered {
        let (rows, within) = file_order(work);
        Gathered { photons: work.to_vec(), rows, within, positions: None }
    }
}

fn file_order(work: &[u32]) -> (Vec<u32>, Vec<u32>) {
    use rayon::prelude::*;
    let mut by_index: Vec<(u32, u32)> = work.iter().enumerate().map(|(k, &i)| (i, k as u32)).collect();
    by_index.par_sort_unstable();
    let mut within = vec![0u32; work.len()];
    for (q, &(_, k)) in by_index.iter().enumerate() {
        within[k as usize] = q as u32;
    }
    (by_index.into_iter().map(|(i, _)| i).collect(), within)
}

/// The power of two relax scales `positions` by so that their largest coordinate lies within
/// 2^±40 of 1, where squared distances between them neither overflow nor underflow in f32
/// (1 when it already does, or when every coordinate is 0 or non-finite).
fn working_scale(positions: &[[f32; 3]]) -> f32 {
    let far = positions.iter().flatten().filter(|x| x.is_finite()).fold(0f32, |m, x| m.max(x.abs()));
    if far == 0.0 || (2f32.powi(-40)..=2f32.powi(40)).contains(&far) {
        return 1.0;
    }
    2f32.powi(-(far.log2().floor() as i32).clamp(-126, 126))
}

/// The most per-iteration measures a relax record keeps (about 200 bytes each).
pub const MAX_ITERATION_RECORDS: usize = 1000;

/// `map` with its positions replaced by `relaxed` (and its normals and flux, where relaxation
/// changed them), every other column carried through (borrowed), and a stage record holding
/// the parameters and the per-iteration measures. The relaxed vectors move into the table
/// (a relaxed map is not held twice while it is written).
pub fn relaxed_map<'a>(
    map: &crate::format::MapView<'a>,
    relaxed: Relaxed,
    p: &RelaxParams,
    seconds: f64,
) -> Result<crate::format::PhotonTable<'a>, RelaxError> {
    use crate::format::{PhotonTable, StageRecord, name};
    let mut info = map.info().clone();
    let mut rec = StageRecord::now("relax", p.record(relaxed.space));
    // At most MAX_ITERATION_RECORDS per-iteration measures (every k-th and the last), so a
    // long run's history stays far below the metadata limit.
    let every = relaxed.measures.len().div_ceil(MAX_ITERATION_RECORDS).max(1);
    let kept: Vec<_> = relaxed
        .measures
        .iter()
        .enumerate()
        .filter(|(i, _)| i % every == 0 || i + 1 == relaxed.measures.len())
        .map(|(_, m)| m)
        .collect();
    rec.report = serde_json::json!({
        "space": relaxed.space,
        "constrained": relaxed.constrained,
        "seconds": crate::format::meta::reported_seconds(seconds),
        "iterations_recorded_every": every,
        "iterations": kept,
    });
    info.history.push(rec);
    let mut table = PhotonTable::carrying(map, info);
    table.set_vec(name::POSITION, relaxed.positions)?;
    if let Some(n) = relaxed.normals
        && map.spec(name::NORMAL).is_some()
    {
        table.set_vec(name::NORMAL, n)?;
    }
    if let Some(f) = relaxed.flux {
        table.set_vec(name::FLUX, f)?;
    }
    Ok(table)
}

/// Collapse: drops the parameter dimensions from the neighbour search by moving the map to the
/// `collapsed` state. Every column stays (the parameters remain for diagnostics).
pub fn collapse<'a>(map: &crate::format::MapView<'a>) -> Result<crate::format::PhotonTable<'a>, RelaxError> {
    use crate::format::{PhotonTable, StageRecord, State};
    let from = map.info().state;
    if from != State::Detected {
        return Err(RelaxError::Input {
            file: map.file_name().to_string(),
            message: format!(
                "collapse applies to a detected map (state 'detected'); this one is '{}'",
                from.name()
            ),
        });
    }
    let mut info = map.info().clone();
    info.state = State::Collapsed;
    info.history.push(StageRecord::now("collapse", serde_json::json!({ "from_state": from.name() })));
    Ok(PhotonTable::carrying(map, info))
}
