//! Progressive refinement of a relaxed photon map (issue 24; after Spencer & Jones,
//! "Progressive Photon Relaxation", ACM TOG 32(1), 2013, whose abstract states the idea:
//! successive passes of fresh photons estimate the flux local to each *primal* photon, and a
//! relaxation step works toward a constant per-photon flux). docs/progressive.md says what is
//! adopted from it and what differs.
//!
//! Each pass:
//! 1. traces M fresh photons, continuing the emission sequence where the map's trace (or the
//!    last pass) stopped ([`crate::trace::trace_range`]);
//! 2. gives every fresh photon's flux to the primal photon nearest to it (on its side of the
//!    surface): each primal photon accumulates the flux that fell in its Voronoi cell, and
//!    the mean over passes, τ_i / P_i, converges to the cell's exact flux;
//! 3. moves the primal photons toward a constant per-photon flux: the repulsion of Eq. 8 takes
//!    the pairwise rest length s_ij = (s_i + s_j)/2 with s_i = r_i·sqrt(φ̄/φ_i) (r_i the
//!    distance to the Kf-th neighbour, φ_i the cell flux), so photons whose cells hold more
//!    than the mean flux draw their neighbours in; the step is projected onto the constraint
//!    basis (Eq. 9) so edges stay sharp, and a photon that moves keeps only the share of its
//!    statistics its cell keeps;
//! 4. sets every primal photon's flux to its cell's estimate, scaled so the map's total flux
//!    per channel is the total it had (energy is conserved exactly).

mod grow;
mod pass;
#[cfg(test)]
mod tests;

use std::cell::OnceCell;

use serde::{Deserialize, Serialize};

pub use grow::{Cells, GrownRows, HierarchyColumns, Moments, Promoted, target_count};
pub use pass::{PassMeasure, Primal, Statistics, gather, gather_cells, relax_toward_flux, set_flux};

use crate::format::{Element, FormatError, MapView, PhotonTable, StageRecord, name};
use crate::scene::Scene;
use crate::spatial::BoxTree;
use crate::trace::{self, StorePolicy, TraceError, TraceOptions};

/// Settings of a refinement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefineParams {
    /// Passes in all (a resumed run goes on up to this count).
    pub passes: u64,
    /// Photons emitted per pass; `None`: as many as the map's trace emitted.
    pub photons_per_pass: Option<u64>,
    /// Relaxation iterations toward constant flux after each pass; 0 (the default): the
    /// photons stay put and only their flux is refined, which measured better on the truth
    /// scenes (docs/progressive.md).
    pub iterations: usize,
    /// Kf: neighbours of the repulsion (Eq. 8).
    pub kf: usize,
    /// Largest step, as a fraction of the local photon spacing.
    pub step_limit: f32,
    /// γ: the primal photons grow to N₀·p^γ after p passes by splitting the brightest cells
    /// (docs/progressive.md, "Growth"); 0 keeps the map's photons.
    #[serde(default)]
    pub growth: f32,
    /// Passes' worth of weight the map's own photon fluxes carry as each cell's first
    /// estimate (docs/progressive.md, "The prior"): a photon's cell flux is
    /// (w·φ_i + τ_i)/(w + P_i). 0: the passes' photons alone.
    #[serde(default)]
    pub prior_passes: f32,
    /// The exponent a of a held photon's prior: photon i's weight is w / f_i^a, f_i its freedom
    /// across its constraint (|v_b|, floored at 10⁻³), so photons that detection held at folds
    /// keep the relaxed map's flux; w for those on their parameter domain's border
    /// ([`border_scores`]; docs/progressive.md, "The prior"). 0: every photon's is w.
    #[serde(default)]
    pub prior_hold: f32,
}

/// The default exponent of a held photon's prior weight ([`RefineParams::prior_hold`]): 0,
/// every photon's prior the same, since the kernel narrows fast at held photons
/// ([`FEATURE_NARROWING`]) and the cells' converged flux is then the better estimate at folds
/// and edges; a caustic net the relaxation drew well (the water's) keeps more of it with 1/2
/// or 1 (docs/progressive.md, "The prior").
pub const PRIOR_HOLD: f32 = 0.0;

/// The default weight of the map's own fluxes, in passes (docs/progressive.md, "The prior").
pub const PRIOR_PASSES: f32 = 4.0;

impl Default for RefineParams {
    fn default() -> Self {
        RefineParams {
            passes: 8,
            photons_per_pass: None,
            iterations: 0,
            kf: 16,
            step_limit: 0.25,
            growth: 1.0 / 3.0,
            prior_passes: PRIOR_PASSES,
            prior_hold: PRIOR_HOLD,
        }
    }
}

/// What can stop a refinement.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RefineError {
    /// Reading the map or writing a pass's table failed.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// Tracing a pass's fresh photons failed.
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// The map's columns are not as detection reads them (its parameters, for
    /// [`border_scores`]).
    #[error(transparent)]
    Detect(#[from] crate::detect::DetectError),
    /// The map cannot be refined (no trace record, a column missing or of the wrong shape).
    #[error("{file}: {message}")]
    Input {
        /// The map's file name.
        file: String,
        /// What is wrong with it.
        message: String,
    },
    /// Parameters out of range (no neighbour, a negative step limit, no photon per pass).
    #[error("{0}")]
    Invalid(String),
}

/// Column names of the progressive statistics a refined map carries (so a run resumes;
/// format-spec/phm-v1.md §4.2).
pub mod column {
    /// Accumulated flux τ_i of the photon's cell, watts per RGB channel, summed over passes. f32×3.
    pub const TAU: &str = "refine_tau";
    /// Passes the statistics hold, P_i (fewer than the run's after the photon moved). f32×1.
    pub const PASSES: &str = "refine_passes";
    /// With growth: the photon whose cell this one split, u32::MAX for the map's own photons
    /// (the roots); an added photon's `refine_tau` is what its region gathered since the
    /// split. u32.
    pub const SPLIT_OF: &str = "refine_split_of";
    /// With growth: a root's site (its position before any split), or an added photon's
    /// region's site, metres. f32×3.
    pub const SITE: &str = "refine_site";
    /// With growth: for an added photon, the site of the split photon's region made with it.
    /// f32×3.
    pub const SITE_KEPT: &str = "refine_site_kept";
    /// With growth: for an added photon, what the split photon's region made with it gathered
    /// since, W per channel. f32×3.
    pub const TAU_KEPT: &str = "refine_tau_kept";
    /// With growth: the flux-weighted moments of what each photon's cell gathered since it
    /// was made (weight, first moment, second moments, count; [`super::Moments`]). f32×11.
    pub const MOMENTS: &str = "refine_moments";
}

/// The record a refinement adds to the map's history (one per run; a resumed run adds one).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefineRecord {
    /// The parameters of this run.
    pub params: RefineParams,
    /// Photons emitted per pass (the resolved `photons_per_pass`).
    pub photons_per_pass: u64,
    /// Passes done in all after this run.
    pub passes_done: u64,
    /// The next emission number a pass would trace.
    pub next_emission: u64,
    /// Fresh photons stored over all passes.
    pub fresh_stored: u64,
    /// The map's total flux before the first pass, W per channel: every pass keeps it.
    pub total_flux: [f64; 3],
    /// Per pass of this run: its measures.
    pub measures: Vec<PassMeasure>,
    /// Primal photons before the first pass, N₀ of the growth rule (0 in a record written
    /// before growth: the map's count).
    #[serde(default)]
    pub primal_start: u64,
}

impl RefineRecord {
    /// The last refine record of a map's history.
    pub fn of(map: &MapView) -> Option<RefineRecord> {
        let rec = map.info().history.iter().rev().find(|r| r.stage == "refine")?;
        serde_json::from_value(rec.report.clone()).ok()
    }
}

/// Where a run starts: the primal photons, their statistics, and the emission counter.
struct Start {
    primal: Primal,
    stats: Statistics,
    cells: Cells,
    passes_done: u64,
    next_emission: u64,
    fresh_stored: u64,
    total: [f64; 3],
    primal_start: usize,
}

/// Each photon's prior weight in passes (docs/progressive.md, "The prior"): `w` for a free
/// photon, w / max(f, 10⁻³)^(`hold`·(1 − b)) for one whose freedom across its constraint is
/// f = |v_b| (Eq. 7's factor: 1 free, 0 held on its line; `basis_v` from detect) and whose
/// parameter neighbourhood lies on the border of its emitter's lit domain to the degree b
/// ([`border_weight`] of [`border_scores`]; 0 without `border`). A photon held at a fold keeps
/// the relaxed map's flux, which there measured better than its cell's (the cell straddles
/// the fold's peak); one held at an edge where the light stops (the emitter's border, the
/// spectrum's end, a shadow) weighs w like a free one: there its cell's flux measured better.
fn prior_weights(
    n: usize,
    w: f32,
    hold: f32,
    basis_v: Option<&[[f32; 3]]>,
    border: Option<&[f32]>,
) -> Vec<f32> {
    match basis_v {
        Some(v) if hold > 0.0 => v
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let f = glam::Vec3::from(*v).length();
                let b = border.map_or(0.0, |s| border_weight(s[i]));
                w / f.clamp(1e-3, 1.0).powf(hold * (1.0 - b))
            })
            .collect(),
        _ => vec![w; n],
    }
}

/// Neighbours in a photon's [`border_scores`] (itself not counted).
pub const BORDER_NEIGHBOURS: usize = 32;

/// The border scores at which [`border_weight`] starts and reaches 1: inside the domain the
/// score of 32 neighbours is about 0.11 (the mean of 32 offsets spread over a disc), on a
/// straight border 4/(3π) ≈ 0.42 (a half disc's centroid); measured on the closed-form scenes
/// (docs/progressive.md, "The prior").
pub const BORDER_SCORES: [f32; 2] = [0.12, 0.22];

/// How much a photon with this [`border_scores`] score is on its domain's border: 0 below
/// [`BORDER_SCORES`]\[0\], 1 above \[1\], linear between.
pub fn border_weight(score: f32) -> f32 {
    let [lo, hi] = BORDER_SCORES;
    ((score - lo) / (hi - lo)).clamp(0.0, 1.0)
}

/// Per photon of `map`, how one-sided its neighbourhood in parameter space is:
/// |mean_j (p_j − p_i)| / r over its [`BORDER_NEIGHBOURS`] nearest photons j of the same
/// emitter, r the distance to the farthest of them, in the parameter space detection searched
/// (a wavelength scaled as detect recorded it). About 0.11 where photons surround p_i, 0.42
/// where they lie on one side only: where the light stops in parameter space (an emitter's
/// border, the spectrum's end, a shadow; a fold, where two sheets of the same parameters meet,
/// is surrounded). `None` for a map without parameters.
pub fn border_scores(map: &MapView) -> Result<Option<Vec<f32>>, RefineError> {
    use crate::spatial::{Neighbours, ParamColumn, PointSet, Space, SpatialIndex};
    use rayon::prelude::*;
    let columns = crate::detect::map_input(map)?;
    let Some(params) = columns.params else { return Ok(None) };
    // The parameter space detection searched: each emitter's dimensions, a wavelength scaled
    // as detect recorded it.
    let dims: Vec<u32> = map.info().emitters.iter().map(|e| e.param_dims).collect();
    let scaled =
        map.info().param_scales().map(|f| ParamColumn { dims: &dims, ..params }.scaled(columns.emitters, &f));
    let points = PointSet {
        positions: columns.positions,
        params: Some(ParamColumn {
            values: scaled.as_deref().unwrap_or(params.values),
            dims: &dims,
            ..params
        }),
        emitters: columns.emitters,
    };
    let index = SpatialIndex::build(&points, Space::Params).map_err(crate::detect::DetectError::from)?;
    let k = BORDER_NEIGHBOURS + 1;
    // Queried in the index's order, whose neighbouring queries share their tree nodes.
    let order = index.order();
    let mut found = vec![0f32; order.len()];
    found.par_chunks_mut(1024).zip(order.par_chunks(1024)).for_each(|(out, ids)| {
        let mut nb = Neighbours::with_capacity(k).without_coords();
        for (score, &i) in out.iter_mut().zip(ids) {
            let i = i as usize;
            let own = points.params_of(i);
            if own.is_empty() {
                continue;
            }
            index.knn(&points.query(i, None), k, &mut nb);
            let (mut sum, mut far2, mut m) = ([0f64; crate::spatial::MAX_PARAM_DIMS], 0f32, 0usize);
            for n in nb.as_slice().iter().filter(|n| n.index as usize != i) {
                for (s, (q, p)) in sum.iter_mut().zip(points.params_of(n.index as usize).iter().zip(own)) {
                    *s += (q - p) as f64;
                }
                far2 = far2.max(n.dist2);
                m += 1;
            }
            if m > 0 && far2 > 0.0 {
                let offset = sum.iter().map(|s| (s / m as f64).powi(2)).sum::<f64>().sqrt();
                *score = (offset / (far2 as f64).sqrt()) as f32;
            }
        }
    });
    let mut scores = vec![0f32; points.len()];
    for (&i, &s) in order.iter().zip(&found) {
        scores[i as usize] = s;
    }
    Ok(Some(scores))
}

fn start(map: &MapView, per_pass: u64, prior_passes: f32, prior_hold: f32) -> Result<Start, RefineError> {
    let file = map.file_name();
    let input = |message: String| RefineError::Input { file: file.to_string(), message };
    let primal = Primal::from_map(map)?;
    if primal.len() < 2 {
        return Err(input("refinement needs at least two primal photons".into()));
    }
    if let Some(rec) = RefineRecord::of(map) {
        if rec.photons_per_pass != per_pass {
            return Err(input(format!(
                "refined before with other settings ({} photons per pass): resume with those",
                rec.photons_per_pass
            )));
        }
        let stats = Statistics::from_map(map)?
            .ok_or_else(|| input("has a refine record but not its statistics columns".into()))?;
        let cells = match hierarchy_columns(map, &stats)? {
            Some(c) => Cells::rebuild(rec.primal_start as usize, &c)
                .ok_or_else(|| input("its refine_* columns do not describe a hierarchy of cells".into()))?,
            None => Cells::new(&primal.positions),
        };
        return Ok(Start {
            cells,
            stats,
            passes_done: rec.passes_done,
            next_emission: rec.next_emission,
            fresh_stored: rec.fresh_stored,
            total: rec.total_flux,
            primal_start: if rec.primal_start > 0 { rec.primal_start as usize } else { primal.len() },
            primal,
        });
    }
    let trace = map
        .info()
        .trace_record()
        .ok_or_else(|| input("names no trace: refinement continues the trace's emission sequence".into()))?;
    let next_emission = trace.report.emission_range.map_or(trace.report.emitted, |r| r[1]);
    let freedom = map.column::<[f32; 3]>(name::BASIS_V)?;
    let border = match (freedom, prior_hold > 0.0) {
        (Some(_), true) => border_scores(map)?,
        _ => None,
    };
    let weights = prior_weights(primal.len(), prior_passes, prior_hold, freedom, border.as_deref());
    let stats = Statistics::start_weighted(&primal.flux, &weights);
    let total = primal.total_flux();
    Ok(Start {
        primal_start: primal.len(),
        cells: Cells::new(&primal.positions),
        primal,
        stats,
        passes_done: 0,
        next_emission,
        fresh_stored: 0,
        total,
    })
}

/// Refines `map` (its primal photons, with their constraint bases where it has them) in
/// passes of fresh photons traced from `scene`, up to `p.passes` passes in all. After each
/// pass `after_pass` sees its measures and, built only if asked for ([`PassDone::table`]), the
/// refined map (to write it, so an interrupted run resumes from the last pass written); it
/// returns `false` to stop. With `bounces`, only the fresh photons of these specular bounce
/// counts are gathered (as the map's were chosen: [`crate::trace::Traced::retain_bounces`]).
pub fn refine<'a>(
    map: &MapView<'a>,
    scene: &Scene,
    p: &RefineParams,
    bounces: Option<&[u8]>,
    after_pass: &mut dyn FnMut(&PassDone<'_, 'a>) -> Result<bool, RefineError>,
) -> Result<PhotonTable<'a>, RefineError> {
    if p.kf == 0 {
        return Err(RefineError::Invalid("the repulsion needs at least one neighbour".into()));
    }
    if !(p.step_limit >= 0.0 && p.step_limit.is_finite()) {
        return Err(RefineError::Invalid("the step limit must be a non-negative number".into()));
    }
    let trace = map.info().trace_record();
    let per_pass = match p.photons_per_pass {
        Some(0) => return Err(RefineError::Invalid("a pass needs at least one photon".into())),
        Some(n) => n,
        None => trace.as_ref().map(|t| t.report.emitted).filter(|&n| n > 0).ok_or_else(|| {
            RefineError::Invalid("the map names no emitted count: give the photons per pass".into())
        })?,
    };
    if p.growth > 0.0 && p.iterations > 0 {
        return Err(RefineError::Invalid(
            "growth splits the photons' cells where they stand: it does not combine with relaxation iterations".into(),
        ));
    }
    if !(p.prior_hold >= 0.0 && p.prior_hold.is_finite()) {
        return Err(RefineError::Invalid(
            "the held photons' prior exponent must be a non-negative number".into(),
        ));
    }
    if !(p.growth >= 0.0 && p.growth <= 1.0) {
        return Err(RefineError::Invalid("the growth exponent γ must lie in [0, 1]".into()));
    }
    let Start {
        mut primal,
        mut stats,
        mut cells,
        mut passes_done,
        mut next_emission,
        mut fresh_stored,
        total,
        primal_start,
    } = start(map, per_pass, p.prior_passes, p.prior_hold)?;
    let topts = TraceOptions {
        seed: trace.as_ref().map_or(1, |t| t.parameters.seed),
        store: match trace.as_ref().map(|t| t.parameters.store.as_str()) {
            Some("direct") => StorePolicy::Direct,
            _ => StorePolicy::Caustic,
        },
        max_bounces: trace.as_ref().map_or(64, |t| t.parameters.max_bounces),
        ..TraceOptions::default()
    };
    let mut measures = Vec::new();
    let counters = |passes_done, next_emission, fresh_stored| Counters {
        per_pass,
        passes_done,
        next_emission,
        fresh_stored,
        total,
        primal_start,
    };
    // The index of the root photons (the map's own): rebuilt only when relaxation moves them.
    let mut tree = BoxTree::build(&cells.root_sites());
    let mut grown = GrownRows::default();
    let mut table = None;
    while passes_done < p.passes {
        let t = std::time::Instant::now();
        let range = next_emission
            ..next_emission.checked_add(per_pass).ok_or_else(|| {
                RefineError::Invalid("the emission numbers overflow: too many passes".into())
            })?;
        let mut traced = trace::trace_range(scene, &topts, range.clone(), &|_, _| {})?;
        if let Some(keep) = bounces {
            traced.retain_bounces(keep)?;
        }
        let fresh = traced.photons()?;
        next_emission = range.end;
        fresh_stored += fresh.len() as u64;
        let (gathered, root) = gather_cells(&mut stats, &primal, &tree, &fresh);
        cells.descend(&fresh, &root);
        passes_done += 1;
        let mut estimate = cells.leaf_flux(&stats);
        let target = target_count(primal_start, passes_done, p.growth);
        if target > primal.len() {
            let add = target - primal.len();
            let promoted = cells.split_brightest(&mut primal, &estimate, add);
            stats.tau.resize(primal.len(), [0.0; 3]);
            stats.passes.resize(primal.len(), 0.0);
            grown.push(map, &promoted);
            grow::halve_split_cells(&mut estimate, &promoted);
        }
        let mut moved = 0.0;
        for _ in 0..p.iterations {
            moved += relax_toward_flux(&mut primal, &mut stats, p);
        }
        if p.iterations > 0 {
            tree = BoxTree::build(&primal.positions);
            estimate = cells.leaf_flux(&stats);
        }
        let spread = set_flux(&mut primal, &estimate, total);
        let m = PassMeasure {
            pass: passes_done,
            fresh_stored: fresh.len() as u64,
            gathered_per_photon: gathered,
            mean_step: moved / p.iterations.max(1) as f64,
            flux_cv: spread,
            seconds: crate::format::meta::reported_seconds(t.elapsed().as_secs_f64()).as_f64(),
        };
        measures.push(m);
        let state = State { primal: &primal, stats: &stats, cells: &cells, grown: &grown };
        let c = counters(passes_done, next_emission, fresh_stored);
        let build = || make_table(map, state, p, c, &measures);
        let done = PassDone { measure: &m, table: OnceCell::new(), build: &build };
        let go_on = after_pass(&done)?;
        table = done.table.into_inner();
        if !go_on {
            break;
        }
    }
    // The last pass's map unless `after_pass` built it; with no pass to run (the map already
    // holds `p.passes`), the map as it is, with this run's record.
    match table {
        Some(t) => Ok(t),
        None => {
            let state = State { primal: &primal, stats: &stats, cells: &cells, grown: &grown };
            make_table(map, state, p, counters(passes_done, next_emission, fresh_stored), &measures)
        }
    }
}

/// A finished pass as `after_pass` sees it: its measures and, built when first asked for, the
/// refined map.
pub struct PassDone<'s, 'a> {
    /// What the pass measured.
    pub measure: &'s PassMeasure,
    table: OnceCell<PhotonTable<'a>>,
    build: &'s dyn Fn() -> Result<PhotonTable<'a>, RefineError>,
}

impl<'a> PassDone<'_, 'a> {
    /// The map after this pass (built on the first call: a copy of every column).
    pub fn table(&self) -> Result<&PhotonTable<'a>, RefineError> {
        if let Some(t) = self.table.get() {
            return Ok(t);
        }
        let t = (self.build)()?;
        Ok(self.table.get_or_init(|| t))
    }
}

/// A run's counters, for its record.
#[derive(Clone, Copy)]
struct Counters {
    per_pass: u64,
    passes_done: u64,
    next_emission: u64,
    fresh_stored: u64,
    total: [f64; 3],
    primal_start: usize,
}

/// What a pass leaves: the primal photons, their statistics and cells, and the rows growth added.
#[derive(Clone, Copy)]
struct State<'s> {
    primal: &'s Primal,
    stats: &'s Statistics,
    cells: &'s Cells,
    grown: &'s GrownRows,
}

/// `map` with the primal photons' positions, flux and statistics replaced (and the rows growth
/// added), and this run's refine record last in its history.
fn make_table<'a>(
    map: &MapView<'a>,
    State { primal, stats, cells, grown }: State,
    p: &RefineParams,
    c: Counters,
    measures: &[PassMeasure],
) -> Result<PhotonTable<'a>, RefineError> {
    let mut info = map.info().clone();
    let record = RefineRecord {
        params: *p,
        photons_per_pass: c.per_pass,
        passes_done: c.passes_done,
        next_emission: c.next_emission,
        fresh_stored: c.fresh_stored,
        total_flux: c.total,
        measures: measures.to_vec(),
        primal_start: c.primal_start as u64,
    };
    let mut rec = StageRecord::now("refine", serde_json::to_value(p).unwrap_or_default());
    rec.report = serde_json::to_value(&record).unwrap_or_default();
    info.history.push(rec);
    let mut table = if grown.len == 0 {
        PhotonTable::carrying(map, info)
    } else {
        PhotonTable::carrying_appended(map, info, grown.len, &grown.bytes)?
    };
    table.set(name::POSITION, &primal.positions)?;
    table.set(name::FLUX, &primal.flux)?;
    if p.growth > 0.0 || cells.roots() < primal.len() {
        let c = cells.columns(stats);
        table.set(column::TAU, &c.tau)?;
        table.set(column::SPLIT_OF, &c.split_of)?;
        table.set(column::SITE, &c.site)?;
        table.set(column::SITE_KEPT, &c.site_kept)?;
        table.set(column::TAU_KEPT, &c.tau_kept)?;
        table.set_flat::<f32>(column::MOMENTS, 11, bytemuck::cast_slice(&c.moments))?;
    } else {
        table.set(column::TAU, &stats.tau)?;
    }
    table.set(column::PASSES, &stats.passes)?;
    Ok(table)
}

/// The first N₀ photons of a map that growth took from N₀ to N photons: the map's photons before
/// it grew, each where refinement left it (a photon whose cell split stands at one half's
/// site). `render` gathers each estimate within the distance of the K-th nearest of these
/// ([`crate::render::Estimator::LocalRadius`]), so the kernel keeps, wherever the map grew, about
/// the area it had before refinement, and the finer cells in it carry the flux more exactly
/// (docs/progressive.md, "Rendering a grown map"). `None` for any other map.
pub fn first_photons<'a>(map: &MapView<'a>) -> Option<&'a [[f32; 3]]> {
    match RefineRecord::of(map) {
        Some(rec) if rec.primal_start > 0 && map.len() as u64 > rec.primal_start => {
            Some(&map.positions()[..rec.primal_start as usize])
        }
        _ => None,
    }
}

/// How fast a grown map's kernel narrows at features ([`radius_factors`]): the radius after P
/// passes is P^(−FEATURE_NARROWING·n(f)/2), n(f) = (1 − f) + max(0, 1 − f/[`HELD_FREEDOM`]) of a
/// photon's freedom f across its constraint (Eq. 7's |v_b|). A free photon (f = 1) keeps its
/// area; one held half-way (f = 1/2) narrows its area as P^(−1/6); one held on its line (f = 0)
/// as P^(−2/3), twice progressive photon mapping's R² ∝ P^(α−1) with α = 2/3
/// (docs/progressive.md, "A faster narrowing where detection held the photon").
pub const FEATURE_NARROWING: f32 = 1.0 / 3.0;

/// The freedom below which a photon counts as held on its line and its kernel narrows faster
/// ([`FEATURE_NARROWING`]): above it detection's freedom is as often noise as a feature (the
/// glass sphere's caustic has no line, and its photons' median freedom is 0.92, a tenth below
/// 0.74), and narrowing there trades blur for noise.
pub const HELD_FREEDOM: f32 = 0.5;

/// The factor on a grown map's kernel radius at each of its first photons
/// ([`first_photons`]; docs/progressive.md, "Rendering a grown map"): [`radius_factor`] of the
/// passes done and the photon's freedom f = |v_b| across its constraint (Eq. 7; 1 without a
/// `basis_v` column). At a feature the kernel's blur is the error that remains once the cells'
/// flux has converged, so there it narrows; in smooth light a narrower kernel would only add
/// noise. Empty for a map that did not grow.
pub fn radius_factors(map: &MapView) -> Vec<f32> {
    let (Some(sites), Some(rec)) = (first_photons(map), RefineRecord::of(map)) else {
        return Vec::new();
    };
    let freedom = map.column::<[f32; 3]>(name::BASIS_V).ok().flatten();
    (0..sites.len())
        .map(|i| radius_factor(rec.passes_done, freedom.map_or(1.0, |v| glam::Vec3::from(v[i]).length())))
        .collect()
}

/// [`radius_factors`]' factor P^(−[`FEATURE_NARROWING`]·n(f)/2) after P = `passes` at a photon
/// of freedom `f` (clamped to [0, 1]), n(f) = (1 − f) + max(0, 1 − f/[`HELD_FREEDOM`]).
fn radius_factor(passes: u64, f: f32) -> f32 {
    let f = f.clamp(0.0, 1.0);
    let n = (1.0 - f) + (1.0 - f / HELD_FREEDOM).max(0.0);
    (passes.max(1) as f32).powf(-FEATURE_NARROWING * n / 2.0)
}

/// The hierarchy's columns of a map refined with growth, if it has them (roots' τ from `stats`).
fn hierarchy_columns(map: &MapView, stats: &Statistics) -> Result<Option<HierarchyColumns>, RefineError> {
    let Some(split_of) = map.column::<u32>(column::SPLIT_OF)? else {
        return Ok(None);
    };
    let missing = |c: &str| RefineError::Input {
        file: map.file_name().to_string(),
        message: format!("has {} but not {c}", column::SPLIT_OF),
    };
    let three = |c: &'static str| -> Result<Vec<[f32; 3]>, RefineError> {
        Ok(map.column::<[f32; 3]>(c)?.ok_or_else(|| missing(c))?.to_vec())
    };
    let moments = match (map.spec(column::MOMENTS), map.column_bytes(column::MOMENTS)) {
        (Some(spec), Some(bytes)) if spec.dtype == f32::DTYPE && spec.components == 11 => {
            bytemuck::pod_collect_to_vec::<u8, Moments>(bytes)
        }
        (Some(_), _) => {
            return Err(RefineError::Input {
                file: map.file_name().to_string(),
                message: format!("column {} must be f32×11", column::MOMENTS),
            });
        }
        _ => return Err(missing(column::MOMENTS)),
    };
    Ok(Some(HierarchyColumns {
        split_of: split_of.to_vec(),
        site: three(column::SITE)?,
        site_kept: three(column::SITE_KEPT)?,
        tau: stats.tau.clone(),
        tau_kept: three(column::TAU_KEPT)?,
        moments,
    }))
}
