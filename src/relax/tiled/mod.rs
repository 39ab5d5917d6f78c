//! Relaxation tile by tile, exact against the whole map (docs/tiles.md).
//!
//! A tile's interior photons are relaxed with the photons within a halo around the tile, and
//! every step of every photon is certified: a photon's position after iteration t is the whole
//! map's if its position at t was, and if every photon its step read (its Kf nearest) lies
//! closer than anything whose position at t may differ from the whole map's. What may differ
//! (photons outside the halo box, and photons of the box not certified) is bounded per photon:
//! it lies within its step at iteration 0 plus t − 1 times its later step bound (a fraction of
//! its first spacing, [`super::Scratch`]) of where it started. The test is spatial, photon by
//! photon (`Uncertain`), so a sparse photon that moves far holds back only the photons it
//! could reach. Interior photons not certified through every iteration are relaxed again with
//! the halo doubled, until the halo holds the whole map.

use std::cmp::Ordering;

use rayon::prelude::*;

use super::{Columns, MapWide, RelaxError, RelaxParams, RelaxSpace, Setup, run};
use crate::format::MapView;
use crate::spatial::BoxTree;
use crate::spatial::order::locality_order;
use crate::tiles::{HaloBox, TileCell, TilePhotons, Tiling};

mod bounds;
mod certificate;
mod series;

use bounds::{Moves, bound, most_moved, move_bounds, widen};
use certificate::Uncertain;
pub(crate) use certificate::depth_in;
use series::Series;

/// The relaxation of one tile's interior photons, in file order, with what the whole map's
/// per-iteration report needs of each ([`super::merge_parts`] puts tiles together).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TileRelaxed {
    /// The interior photons' indices in the map, ascending.
    pub indices: Vec<u32>,
    /// Their relaxed positions, metres.
    pub positions: Vec<[f32; 3]>,
    /// Their normals, when photons were returned to their surfaces.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Iterations run (R): the three per-photon series below hold R values per photon.
    pub iterations: usize,
    /// Per interior photon, the row of its series in [`Self::nn`], [`Self::ratio`] and
    /// [`Self::step`] (rows are in the order the tile's run wrote them;
    /// [`Self::in_interior_order`] puts them in the photons' order).
    pub rows: Vec<u32>,
    /// Per photon and iteration (photon-major, in rows of R): the nearest-neighbour distance,
    /// in working units ([`Self::scale`]).
    pub nn: Vec<f32>,
    /// Per photon and iteration: that distance over r_K (NaN where r_K = 0).
    pub ratio: Vec<f32>,
    /// Per photon and iteration: the step length, in working units.
    pub step: Vec<f32>,
    /// The power of two the whole map's positions were worked on scaled by.
    pub scale: f32,
    /// Moves refused because the photon's surface was not found (the tile's photons).
    pub refused_moves: u64,
    /// Rounds (1: the first halo certified every photon).
    pub rounds: u32,
    /// The most photons one round worked on (interior and halo).
    pub working_set: usize,
    /// Per round: interior photons still to certify, and the working set.
    pub per_round: Vec<[usize; 2]>,
}

impl TileRelaxed {
    /// One of the per-photon series ([`Self::nn`], [`Self::ratio`], [`Self::step`]) with its
    /// rows in the interior photons' order.
    pub fn in_interior_order(&self, series: &[f32]) -> Vec<f32> {
        let r = self.iterations;
        let mut ordered = vec![0.0; series.len()];
        ordered
            .par_chunks_mut(r.max(1))
            .zip(&self.rows)
            .for_each(|(to, &j)| to.copy_from_slice(&series[j as usize * r..][..r]));
        ordered
    }
}

/// The most iterations a tiled run takes: a part stores one value per photon and iteration in
/// a column, and a column holds at most 64 components.
pub const MAX_TILE_ITERATIONS: usize = 64;

/// Rounds after which the halo is the whole map (a guard: doubling reaches it long before).
const MAX_ROUNDS: u32 = 48;

/// How [`relax_tile_with`] sizes and checks its halos (for tests: the defaults are the only
/// exact choice of `certify`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Options {
    /// The first halo's width in units of 2·(R + 1) mean neighbour spacings. The default 1.5
    /// was measured on the water, whose photons return to its floor (a move bounded by 1.25
    /// steps, [`super::surface::RETURN_REACH`]): one round for every tile tried of 12 at 10⁶
    /// and of 20 at 10⁷, with working sets 1.3–2.0 and 1.16–1.29 times the tile (2.5 took
    /// 1.6–2.8 and 1.28–1.54); 1.2 and 1.0 left 0.03–0.5 % of a tile at 10⁷ to a second round.
    pub halo_scale: f64,
    /// Whether steps are certified; without, the first halo's results are kept.
    pub certify: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options { halo_scale: 1.5, certify: true }
    }
}

/// Relaxation of tile `tile` of `tiling` of `map` with parameters `p` (and `scene`, as
/// [`super::relax_map_on`]): each interior photon ends bit for bit where the whole map's
/// relaxation puts it (docs/tiles.md). Flux diffusion, which rescales the whole map's flux, is
/// refused.
pub fn relax_tile(
    map: &MapView,
    p: &RelaxParams,
    scene: Option<&crate::scene::Scene>,
    tiling: &Tiling,
    tile: usize,
) -> Result<TileRelaxed, RelaxError> {
    relax_tile_with(map, p, scene, tiling, tile, Options::default())
}

/// [`relax_tile`] with [`Options`].
pub(crate) fn relax_tile_with(
    map: &MapView,
    p: &RelaxParams,
    scene: Option<&crate::scene::Scene>,
    tiling: &Tiling,
    tile: usize,
    opts: Options,
) -> Result<TileRelaxed, RelaxError> {
    if tile >= tiling.len() {
        return Err(RelaxError::Input {
            file: map.file_name().to_string(),
            message: format!("tile {tile} of a tiling of {}", tiling.len()),
        });
    }
    TiledRun::new(map, p, scene, tiling, Some(tile))?.tile(tile, opts)
}

/// What relaxation keeps in memory ([`crate::tiles::tiles_for_budget`]), measured with
/// `/usr/bin/time` and the process's resident set between tiles on the water scene's maps
/// (BENCHMARKS.md, "Tiles and the memory budget"): the whole map's labels, move bounds, tile
/// cells and relaxed positions per photon (measured when the working order was kept too, 4
/// bytes more), and per photon a tile works on its columns,
/// index and iteration scratch. With a scene (`on_surfaces`), the relaxed normals too: 56 bytes
/// per photon (54 measured at 10⁷ photons, 42 at 10⁸; a tile's copies read the map in blocks
/// released as read, so no whole column stays resident); without one, 48.
pub fn memory(on_surfaces: bool) -> crate::tiles::MemoryModel {
    crate::tiles::MemoryModel {
        per_photon: if on_surfaces { 56.0 } else { 48.0 },
        per_working_photon: 360.0,
        halo_growth: 1.4,
    }
}

/// Relaxes every photon of `map` tile by tile in this process (the tiles of `tiling`), holding
/// one tile's working set at a time besides the whole map's per-photon bookkeeping (its labels,
/// move bounds and the relaxed positions): the result is [`super::relax_map_on`]'s bit for bit
/// (docs/tiles.md). `on_tile(tile, tiles, result)` is called after each tile.
pub fn relax_tiled(
    map: &MapView,
    p: &RelaxParams,
    scene: Option<&crate::scene::Scene>,
    tiling: &Tiling,
    mut on_tile: impl FnMut(usize, usize, &TileRelaxed),
) -> Result<super::Relaxed, RelaxError> {
    use crate::format::name;
    let shared = TiledRun::new(map, p, scene, tiling, None)?;
    let (space, constrained) = space_of(map, &shared.setup);
    let r = shared.setup.p.iterations;
    let scale = shared.setup.scale as f64;
    // The copies' pages in the map are released as soon as they are read: resident, they would
    // count twice against the memory budget.
    let mut positions = map.positions().to_vec();
    map.release_pages();
    let mut normals: Option<Vec<[f32; 3]>> = None;
    let mut sums = vec![super::MeasureSums::default(); r];
    let mut refused_moves = 0;
    for t in 0..tiling.len() {
        let part = shared.tile(t, Options::default())?;
        if let Some(ns) = &part.normals {
            let all = match &mut normals {
                Some(all) => all,
                None => {
                    let copied = match map.column::<[f32; 3]>(name::NORMAL)? {
                        Some(c) => c.to_vec(),
                        None => vec![[0.0; 3]; map.len()],
                    };
                    map.release_pages();
                    normals.insert(copied)
                }
            };
            for (&i, &n) in part.indices.iter().zip(ns) {
                all[i as usize] = n;
            }
        }
        for (k, &i) in part.indices.iter().enumerate() {
            positions[i as usize] = part.positions[k];
        }
        super::MeasureSums::add_series(&mut sums, &part.nn, &part.ratio, &part.step);
        refused_moves += part.refused_moves;
        on_tile(t, tiling.len(), &part);
    }
    let measures = sums
        .iter()
        .enumerate()
        .map(|(t, sum)| {
            let m = sum.measure(t);
            super::IterationMeasure {
                mean_displacement: m.mean_displacement / scale,
                max_displacement: m.max_displacement / scale,
                ..m
            }
        })
        .collect();
    Ok(super::Relaxed { positions, space, constrained, measures, normals, refused_moves, flux: None })
}

/// What the tiles of one map's tiled relaxation share, computed once from the whole map
/// without holding it (its working order, where each tile's photons are, each photon's move
/// bound): one tile job computes it for its tile, a run of every tile in one process
/// ([`relax_tiled`]) once for all.
pub struct TiledRun<'r, 'm> {
    map: &'r MapView<'m>,
    setup: Setup,
    scene: Option<&'r crate::scene::Scene>,
    tiling: &'r Tiling,
    /// Per photon, its label: its rank in the whole map's working order.
    label: Vec<u32>,
    /// Per tile, its photons in the cells of a grid over them.
    by_tile: Vec<TilePhotons>,
    /// Per tile and cell, the most any of the cell's photons moves in one iteration (working
    /// units), from their move bounds.
    most: Vec<Vec<f64>>,
    /// Per photon (by index in the map), the most it moves in one iteration ([`move_bounds`]),
    /// working units.
    moves: Vec<f32>,
    slack: f64,
}

impl<'r, 'm> TiledRun<'r, 'm> {
    /// The shared part of relaxing `map` in the tiles of `tiling` (`only`: when just that tile
    /// will be relaxed, the checks of an empty tile are all that is done for it).
    pub fn new(
        map: &'r MapView<'m>,
        p: &RelaxParams,
        scene: Option<&'r crate::scene::Scene>,
        tiling: &'r Tiling,
        only: Option<usize>,
    ) -> Result<Self, RelaxError> {
        let input = |message: String| RelaxError::Input { file: map.file_name().to_string(), message };
        let setup = Setup::of(map, p, scene.is_some())?;
        if setup.p.flux_diffusion > 0.0 {
            return Err(input(
                "flux diffusion rescales the whole map's flux: it can not run tile by tile".into(),
            ));
        }
        if setup.p.iterations > MAX_TILE_ITERATIONS {
            return Err(input(format!("a tiled relax runs at most {MAX_TILE_ITERATIONS} iterations")));
        }
        let pos = map.positions();
        let n = pos.len();
        let order = locality_order(pos);
        let mut label = vec![0u32; n];
        for (l, &i) in order.iter().enumerate() {
            label[i as usize] = l as u32;
        }
        drop(order);
        let by_tile = tiling.tile_photons(pos);
        map.release_pages();
        let mut run = TiledRun {
            map,
            setup,
            scene,
            tiling,
            label,
            by_tile,
            most: Vec::new(),
            moves: Vec::new(),
            slack: 0.0,
        };
        let wanted = only.map_or(n, |t| run.by_tile.get(t).map_or(0, |c| c.photons.len()));
        if wanted == 0 {
            // Checked as the whole map is, so a tile fails where the whole map fails.
            Columns::of(map, &[], &run.setup)?;
        } else if run.setup.p.iterations > 0 {
            let (moves, slack) = move_bounds(&run)?;
            run.most = run.by_tile.par_iter().map(|t| most_moved(t, &moves)).collect();
            (run.moves, run.slack) = (moves, slack);
        }
        Ok(run)
    }

    /// The file indices of the photons in `halo`, in label order.
    #[cfg(test)]
    pub(crate) fn members(&self, halo: &HaloBox) -> Vec<u32> {
        self.members_gathered(halo).0.photons
    }

    /// The photons in `halo` in label order, with their file order and positions as read to
    /// find them, and their labels.
    pub(crate) fn members_gathered(&self, halo: &HaloBox) -> (super::Gathered, Vec<u32>) {
        let (near, at) = self.gathered_cells(|c, _| c.meets(halo));
        // The photons in the box, by place in file order.
        let inside: Vec<u32> =
            (0..near.len() as u32).into_par_iter().filter(|&q| halo.contains(at[q as usize])).collect();
        // (label, place in file order), sorted by label.
        let mut by_label: Vec<(u32, u32)> =
            inside.par_iter().map(|&q| (self.label[near[q as usize] as usize], q)).collect();
        by_label.par_sort_unstable();
        let labels = by_label.par_iter().map(|&(l, _)| l).collect();
        let photons = by_label.par_iter().map(|&(_, q)| near[q as usize]).collect();
        let positions = Some(by_label.par_iter().map(|&(_, q)| at[q as usize]).collect());
        // Places in `near` become places among the photons in the box.
        let mut place = vec![0u32; near.len()];
        for (r, &q) in inside.iter().enumerate() {
            place[q as usize] = r as u32;
        }
        let within = by_label.par_iter().map(|&(_, q)| place[q as usize]).collect();
        let rows = inside.par_iter().map(|&q| near[q as usize]).collect();
        (super::Gathered { photons, rows, within, positions }, labels)
    }

    /// The photons of the cells `keep` keeps ([`Self::cells_where`]) with their positions, in
    /// file order ([`crate::tiles::gather_cells`]).
    fn near_cells(&self, keep: impl Fn(&TileCell, f64) -> bool) -> Vec<(u32, [f32; 3])> {
        let (near, at) = self.gathered_cells(keep);
        near.into_iter().zip(at).collect()
    }

    /// [`Self::near_cells`] as two columns: the photons, and their positions.
    fn gathered_cells(&self, keep: impl Fn(&TileCell, f64) -> bool) -> (Vec<u32>, Vec<[f32; 3]>) {
        crate::tiles::gather_cells(self.map.pages(), self.map.positions(), self.cells_where(keep).into_iter())
    }

    /// The photons of every cell, of every tile, that `keep` keeps.
    /// (`keep` sees a cell and the most any of its photons moves in one iteration, 0 before
    /// the move bounds are known.)
    fn cells_where(&self, keep: impl Fn(&TileCell, f64) -> bool) -> Vec<&[u32]> {
        let keep = &keep;
        self.by_tile
            .iter()
            .enumerate()
            .flat_map(|(t, photons)| {
                let most = self.most.get(t);
                photons
                    .cells
                    .iter()
                    .enumerate()
                    .filter(move |&(c, cell)| keep(cell, most.map_or(0.0, |m| m[c])))
                    .map(|(_, cell)| photons.of_cell(cell))
            })
            .collect()
    }

    /// The photons outside `halo` that could come within `reach` (working units) of it in `r`
    /// iterations, with where they start (working units) and their move bounds.
    pub(crate) fn outside(&self, halo: &HaloBox, r: usize, reach: f64) -> Vec<([f32; 3], Moves)> {
        let scale = self.setup.scale as f64;
        // A cell whose nearest photon lies farther outside the box (working units) than the most
        // any of its photons moves in the run plus the reach holds none that can come within it.
        let near = |c: &TileCell, most: f64| {
            let gap =
                (0..2).map(|k| (halo.lo[k] - c.hi[k]).max(c.lo[k] - halo.hi[k]).max(0.0)).fold(0.0, f64::max)
                    * scale;
            gap < r as f64 * most + reach
        };
        self.near_cells(near)
            .into_par_iter()
            .filter_map(|(i, x)| {
                if halo.contains(x) {
                    return None;
                }
                let (x, m) = (scaled(x, self.setup.scale), self.moves_of(i));
                (-depth_in(halo, x, scale) < m.after(r) + reach).then_some((x, m))
            })
            .collect()
    }

    /// Per photon (by index in the map), the most it moves in one iteration (working units).
    #[cfg(test)]
    pub(crate) fn moves(&self) -> &[f32] {
        &self.moves
    }

    /// How far photon `i` of the map may move.
    fn moves_of(&self, i: u32) -> Moves {
        let b = self.moves[i as usize] as f64;
        Moves { first: b, later: b }
    }

    /// Tile `tile` relaxed ([`relax_tile`]).
    // Long because it is one loop of rounds whose certificate reads every quantity set up before.
    pub(crate) fn tile(&self, tile: usize, opts: Options) -> Result<TileRelaxed, RelaxError> {
        let (map, setup, scene, tiling) = (self.map, &self.setup, self.scene, self.tiling);
        let (slack, label) = (self.slack, &self.label);
        let iterations = setup.p.iterations;
        let pos = map.positions();
        let n = pos.len();
        let interior = self.by_tile[tile].ascending();
        let mut out = TileRelaxed { iterations, scale: setup.scale, ..Default::default() };
        if interior.is_empty() {
            return Ok(out);
        }
        if iterations == 0 {
            out.positions = interior.iter().map(|&i| pos[i as usize]).collect();
            out.indices = interior;
            return Ok(out);
        }
        let scale = setup.scale as f64;
        let extent =
            tiling.axes.iter().map(|&a| tiling.hi[a] as f64 - tiling.lo[a] as f64).fold(0.0, f64::max);
        let mut h = opts.halo_scale
            * 2.0
            * (iterations as f64 + 1.0)
            * extent
            * (setup.p.kf as f64 / (std::f64::consts::PI * n as f64)).sqrt();
        let r = iterations;
        out.rows = (0..interior.len() as u32).collect();
        out.nn = vec![0.0; interior.len() * r];
        out.ratio = vec![f32::NAN; interior.len() * r];
        out.step = vec![0.0; interior.len() * r];
        out.positions = vec![[0.0; 3]; interior.len()];
        let mut normals = vec![[0.0f32; 3]; interior.len()];
        let mut with_normals = false;
        let mut pending: Vec<bool> = vec![true; interior.len()];
        let mut left = interior.len();
        while left > 0 {
            out.rounds += 1;
            let left_before = left;
            let halo = tiling.halo_box(tile, if out.rounds >= MAX_ROUNDS { f64::INFINITY } else { h });
            let whole = halo.is_whole() || !opts.certify;
            // Depth of a position (working units) in the halo box: its distance inside it, negative
            // outside (a photon moving by s changes it by at most s).
            let depth = |x: [f32; 3]| depth_in(&halo, x, scale);
            let (mut work, mut labels) = self.members_gathered(&halo);
            let mut members = work.photons.clone();
            // After the first round only a few photons are pending, along the tile's sides:
            // the round works on the box's photons within the halo's width of one of them, and
            // the box's other photons are uncertain like those outside it (docs/tiles.md).
            let mut left_out: Vec<([f32; 3], Moves)> = Vec::new();
            if out.rounds > 1 && !whole {
                let near: Vec<[f32; 3]> = interior
                    .iter()
                    .zip(&pending)
                    .filter(|(_, p)| **p)
                    .map(|(&i, _)| pos[i as usize])
                    .collect();
                let tree = BoxTree::build(&near);
                let r2 = (h * h) as f32;
                let keep: Vec<bool> = members
                    .par_iter()
                    .map_init(
                        || crate::spatial::Neighbours::with_capacity(1),
                        |found, &i| {
                            tree.knn(pos[i as usize], 1, r2, found);
                            !found.is_empty()
                        },
                    )
                    .collect();
                // A photon left out farther than twice the halo's width plus its own reach from
                // every pending photon is farther than the halo's width (the most a member may
                // read) plus its reach from every member: it can not matter.
                left_out = members
                    .par_iter()
                    .zip(&keep)
                    .filter(|(_, k)| !**k)
                    .map_init(
                        || crate::spatial::Neighbours::with_capacity(1),
                        |found, (&i, _)| {
                            let m = self.moves_of(i);
                            let far = 2.0 * h + m.after(r) / scale;
                            tree.knn(pos[i as usize], 1, (far * far * (1.0 + 1e-4)) as f32, found);
                            (!found.is_empty()).then(|| (scaled(pos[i as usize], setup.scale), m))
                        },
                    )
                    .flatten()
                    .collect();
                members = members.iter().zip(&keep).filter(|(_, k)| **k).map(|(&i, _)| i).collect();
                work = super::Gathered::of(&members);
                labels = members.iter().map(|&i| label[i as usize]).collect();
                // The members' positions were read across the file.
                map.release_pages();
            }
            out.working_set = out.working_set.max(members.len());
            out.per_round.push([left, members.len()]);
            // The photons outside the box that may come within reach of a member: any other lies
            // farther from the box than the most it moves in the whole run plus the halo's width,
            // which bounds the reach a member may be certified with.
            let reach_cap = h * scale;
            let mut outside = if whole { Vec::new() } else { self.outside(&halo, r, reach_cap) };
            outside.append(&mut left_out);
            let outside = Uncertain::of(outside.into_iter(), depth, r);
            let slot: Vec<Option<usize>> =
                places_of(&work, &interior).into_iter().map(|q| q.filter(|&q| pending[q])).collect();
            // The pending interior photons among the members, in member order: (member, place in
            // the interior). Their per-iteration series are written row by row in this order,
            // reading the members' values in order, and put in interior order once the round
            // ends (`Series`).
            let rows: Vec<(u32, u32)> =
                slot.iter().enumerate().filter_map(|(k, q)| q.map(|q| (k as u32, q as u32))).collect();
            let mut series = Series::for_round(&mut out, rows.len(), interior.len());
            let mut columns = Columns::of_gathered(map, &mut work, setup, false)?;
            // Its file order is not needed while the round runs.
            drop(work);
            let start: Vec<[f32; 3]> = columns.positions.clone();
            let mut member_moves: Vec<Moves> = members.iter().map(|&i| self.moves_of(i)).collect();
            let mut certified = vec![true; members.len()];
            let wide =
                MapWide { labels: Some(&labels), spacing: setup.spacing, coincident: setup.coincident };
            let mut t = 0usize;
            let result = run(map, &mut columns, setup, scene, &wide, &members, |scratch, _, before| {
                let per = scratch.per_photon();
                // The tile's own photons move as far as the tile's run moves them too (an
                // uncertified photon's tile position may differ from the whole map's).
                if t == 0 {
                    for (m, &s) in member_moves.iter_mut().zip(&per.step) {
                        m.first = m.first.max(widen(s as f64, scene.is_some(), slack));
                    }
                } else if t == 1 {
                    for (m, &s) in member_moves.iter_mut().zip(scratch.first_spacing()) {
                        m.later = m.later.max(bound(setup.p.step_limit, s, scene.is_some(), slack));
                    }
                }
                if !whole {
                    // Where the members whose position may differ from the whole map's started.
                    let per_read = &per.read;
                    // An uncertain member that can not come within the read of any member
                    // still certified is left out.
                    let lowest = (0..members.len())
                        .into_par_iter()
                        .filter(|&k| certified[k])
                        .map(|k| depth(before[k]) - per_read[k] as f64 * (1.0 + 1e-5))
                        .reduce(|| f64::INFINITY, f64::min);
                    let unsure = Uncertain::of(
                        certified
                            .iter()
                            .zip(&start)
                            .zip(&member_moves)
                            .filter(|((c, x), m)| {
                                !**c && (depth(**x) + m.after(t)).partial_cmp(&lowest) != Some(Ordering::Less)
                            })
                            .map(|((_, &x), &m)| (x, m)),
                        depth,
                        r,
                    );
                    let keep: Vec<bool> = (0..members.len())
                        .into_par_iter()
                        .map(|k| {
                            let read = per_read[k] as f64 * (1.0 + 1e-5);
                            let at = depth(before[k]);
                            certified[k]
                                && read.is_finite()
                                && read <= reach_cap
                                && at >= 0.0
                                && outside.clear_of(before[k], at, read, t)
                                && unsure.clear_of(before[k], at, read, t)
                        })
                        .collect();
                    certified = keep;
                }
                series.record(&rows, t, per);
                t += 1;
                // Nothing more to learn once no pending interior photon is certified.
                slot.iter().zip(&certified).any(|(s, &c)| s.is_some() && c)
            })?;
            let ran_all = t == r;
            let moved = columns.unscaled_positions(setup);
            with_normals = columns.normals.is_some();
            for k in 0..members.len() {
                if let Some(q) = slot[k]
                    && certified[k]
                    && ran_all
                {
                    out.positions[q] = moved[k];
                    // The whole map's refused moves of this photon, as its run is the whole map's.
                    out.refused_moves += result.refused.get(k).copied().unwrap_or(0) as u64;
                    if let Some(ns) = &columns.normals {
                        normals[q] = ns[k];
                    }
                    pending[q] = false;
                    left -= 1;
                }
            }
            drop(columns);
            series.place(&mut out, &rows, |k| certified[k as usize] && ran_all);
            // A halo that certified nothing is held back by photons whose bounds reach the whole
            // tile (a sparse surround, docs/tiles.md): doubling it again would not help.
            h = if left == left_before { f64::INFINITY } else { 2.0 * h };
            // The map's pages this round read are read again only as the next round needs them.
            map.release_pages();
        }
        out.normals = with_normals.then_some(normals);
        out.indices = interior;
        Ok(out)
    }
}

/// Where each of `photons` (indices in the map) is in `sorted` (ascending indices), if there.
#[cfg(test)]
fn places_in(photons: &[u32], sorted: &[u32]) -> Vec<Option<usize>> {
    places_of(&super::Gathered::of(photons), sorted)
}

/// Where each photon of `work` (in its working order) is in `sorted` (ascending indices), if
/// there: one merge of the photons in file order, where a search per photon would read
/// `sorted` at random.
fn places_of(work: &super::Gathered, sorted: &[u32]) -> Vec<Option<usize>> {
    let mut at_row = Vec::with_capacity(work.rows.len());
    let mut q = 0;
    for &i in &work.rows {
        while q < sorted.len() && sorted[q] < i {
            q += 1;
        }
        at_row.push((sorted.get(q) == Some(&i)).then_some(q));
    }
    work.within.iter().map(|&r| at_row[r as usize]).collect()
}

/// `x` scaled by `s` (the working units).
fn scaled(x: [f32; 3], s: f32) -> [f32; 3] {
    if s == 1.0 { x } else { x.map(|v| v * s) }
}

/// The relax record's space and constraint for `map` (also for a tile with no photons).
pub(crate) fn space_of(map: &MapView, setup: &Setup) -> (RelaxSpace, bool) {
    use crate::format::name;
    (setup.space, map.spec(name::BASIS_U).is_some() && map.spec(name::BASIS_V).is_some())
}

#[cfg(test)]
mod tests {
    #[test]
    fn places_are_where_a_search_finds_them() {
        let sorted: Vec<u32> = (0..500).map(|k| 3 * k + (k % 2)).collect();
        let photons: Vec<u32> = (0..1600).rev().step_by(7).chain([0, 1, 1499, 1500, 1501]).collect();
        let places = super::places_in(&photons, &sorted);
        for (k, &i) in photons.iter().enumerate() {
            assert_eq!(places[k], sorted.binary_search(&i).ok(), "photon {i}");
        }
        assert!(places.iter().filter(|q| q.is_some()).count() > 50);
        assert!(super::places_in(&photons, &[]).iter().all(Option::is_none));
    }
}
