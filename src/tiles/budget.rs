//! How many tiles keep a stage under a memory budget: each stage's measured model of what it
//! holds per photon, and the process's resident set.

use super::{TileSpec, Tiling};

/// What a stage keeps in memory, for choosing how many tiles keep it under a budget
/// ([`tiles_for_budget`]): bytes per photon of the whole map (its order, bounds and results),
/// and bytes per photon of a tile's working set (its columns, index and scratch), measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemoryModel {
    /// Bytes per photon of the map, whatever the tiling.
    pub per_photon: f64,
    /// Bytes per photon a tile works on (its interior and halo).
    pub per_working_photon: f64,
    /// A tile's working set over its interior photons (halo and later rounds).
    pub halo_growth: f64,
}

/// The fewest photons a tile chosen for a memory budget holds: below it, the halos would hold
/// most of the work.
pub const MIN_TILE_PHOTONS: usize = 1000;

/// The fewest tiles of 1, 2, 4, 6, 9, 12, 16, 20, 25, … (grids k × k and (k + 1) × k, so tiles
/// stay about square) that keep a stage of memory model `m` under `budget` bytes on a map of
/// `n` photons, or the bytes the map alone needs when no tiling can (the per-photon part
/// exceeds the budget, or a tile would have to hold fewer than [`MIN_TILE_PHOTONS`]).
pub fn tiles_for_budget(n: usize, budget: u64, m: &MemoryModel) -> Result<usize, u64> {
    let fixed = m.per_photon * n as f64;
    let left = budget as f64 - fixed;
    let too_small = (fixed + MIN_TILE_PHOTONS as f64 * m.halo_growth * m.per_working_photon).ceil() as u64;
    if left <= 0.0 {
        return Err(too_small);
    }
    let per_tile = m.per_working_photon * m.halo_growth * n as f64;
    let needed = if n == 0 { 1.0 } else { (per_tile / left).ceil().max(1.0) };
    let mut count = 1usize;
    let mut k = 1usize;
    while (count as f64) < needed {
        // 1, 2, 4, 6, 9, 12, …: k × k then (k + 1) × k.
        count = if count == k * k {
            (k + 1) * k
        } else {
            k += 1;
            k * k
        };
    }
    if count > 1 && n / count < MIN_TILE_PHOTONS {
        return Err(too_small);
    }
    Ok(count)
}

/// A memory budget no tiling meets: the least it takes, bytes (what the map needs per photon,
/// one tile of [`MIN_TILE_PHOTONS`], and what the process held already).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error(
    "a budget of {budget} bytes is too small: {photons} photons need at least {need} bytes, {held} of them held by the process already"
)]
pub struct BudgetTooSmall {
    /// The budget asked for.
    pub budget: u64,
    /// The map's photons.
    pub photons: usize,
    /// The least budget that would do.
    pub need: u64,
    /// What the process held before the stage (the program, the scene, the map's header).
    pub held: u64,
}

/// The tiling that keeps a stage of memory model `model` under `budget` bytes on the photons
/// at `positions`, leaving room for what the process holds already ([`resident_bytes`]):
/// `None` when the whole map fits ([`tiles_for_budget`] chooses the count, [`Tiling::new`]
/// the cuts).
pub fn tiling_for_budget(
    positions: &[[f32; 3]],
    budget: u64,
    model: &MemoryModel,
) -> Result<Option<Tiling>, BudgetTooSmall> {
    tiling_beside(positions, budget, resident_bytes().unwrap_or(0), model)
}

/// [`tiling_for_budget`] with the process holding `held` bytes already (read by the caller
/// before anything else of the stage).
pub fn tiling_beside(
    positions: &[[f32; 3]],
    budget: u64,
    held: u64,
    model: &MemoryModel,
) -> Result<Option<Tiling>, BudgetTooSmall> {
    let tiles = tiles_for_budget(positions.len(), budget.saturating_sub(held), model)
        .map_err(|need| BudgetTooSmall { budget, photons: positions.len(), need: need + held, held })?;
    Ok((tiles > 1).then(|| Tiling::new(positions, TileSpec { index: 0, count: tiles }.grid())))
}

/// The process's resident set now, bytes (Linux: `VmRSS` of /proc/self/status; `None`
/// elsewhere): what a stage holds before its own work (the program, the scene, the map's
/// header), which a memory budget must leave room for besides the stage's model.
pub fn resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.trim_start_matches("VmRSS:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kb * 1024)
}
