//! Relax tile parts as files: what `photonkit relax MAP --tile i/n -o PART` writes, and how
//! `photonkit merge --map MAP PART…` puts them back into the map `photonkit relax MAP` writes
//! (docs/tiles.md).
//!
//! A part is a PHM map of the tile's interior photons: every column of the map for them, the
//! relaxed positions (and normals), [`PHOTON_INDEX`], and per photon one value per iteration
//! of [`NN`], [`RATIO`] and [`STEP`], from which the merge computes the whole map's
//! per-iteration report. Its last history record is a `relax` record with the whole run's
//! parameters and a report naming the tile, the tile count, and the source map's photon count
//! and position checksum.

use serde_json::{Value, json};

use super::{
    IterationMeasure, MeasureSums, RelaxError, RelaxParams, RelaxSpace, Relaxed, Setup, TileRelaxed,
    relaxed_map,
};
use crate::format::{ColumnSpec, DType, MapView, PhotonTable, StageRecord, name};
use crate::tiles::{PartRecord, TileSpec, part_columns, part_record, part_report};

pub use crate::detect::PHOTON_INDEX;
/// A part's column of each photon's nearest-neighbour distance per iteration (f32 × R,
/// working units).
pub const NN: &str = "relax_nn";
/// A part's column of each photon's nearest over Kf-th neighbour distance per iteration (f32 ×
/// R, NaN where r_K = 0).
pub const RATIO: &str = "relax_nn_ratio";
/// A part's column of each photon's step length per iteration (f32 × R, working units).
pub const STEP: &str = "relax_step";

/// The part file of tile `tile` of `map`, relaxed as `t` with parameters `p` in `seconds`.
pub fn tile_part(
    map: &MapView,
    t: &TileRelaxed,
    p: &RelaxParams,
    tile: TileSpec,
    seconds: f64,
) -> Result<PhotonTable<'static>, RelaxError> {
    let setup = Setup::of(map, p, false)?;
    let (space, constrained) = super::tiled::space_of(map, &setup);
    let mut info = map.info().clone();
    let mut rec = StageRecord::now("relax", setup.p.record(space));
    rec.report = part_report(
        map,
        tile,
        t.indices.len(),
        seconds,
        json!({
            "space": space,
            "constrained": constrained,
            "working_scale": t.scale,
            "iterations": t.iterations,
            "refused_moves": t.refused_moves,
            "returned_to_surfaces": t.normals.is_some(),
            "rounds": t.rounds,
            "working_set": t.working_set,
            "per_round": t.per_round,
        }),
    );
    info.history.push(rec);
    let mut columns = part_columns(map, &t.indices, &[PHOTON_INDEX, NN, RATIO, STEP]);
    if t.iterations > 0 {
        for (column, values) in [(NN, &t.nn), (RATIO, &t.ratio), (STEP, &t.step)] {
            columns.push((
                ColumnSpec::new(column, DType::F32, t.iterations as u32),
                bytemuck::cast_slice(&t.in_interior_order(values)).to_vec(),
            ));
        }
    }
    let borrowed: Vec<(ColumnSpec, &[u8])> = columns.iter().map(|(s, b)| (s.clone(), &b[..])).collect();
    let mut table = PhotonTable::from_columns(map.file_name(), info, &borrowed)?.into_owned();
    table.set(name::POSITION, &t.positions)?;
    if let Some(n) = &t.normals
        && map.spec(name::NORMAL).is_some()
    {
        table.set(name::NORMAL, n)?;
    }
    table.set(PHOTON_INDEX, &t.indices.iter().map(|&i| i as u64).collect::<Vec<_>>())?;
    Ok(table.into_owned())
}

fn part_info<'p>(map: &MapView, part: &MapView<'p>) -> Result<PartRecord<'p>, RelaxError> {
    part_record(map, part, "relax", "photonkit relax")
        .map_err(|message| RelaxError::Input { file: part.file_name().to_string(), message })
}

/// Whether `part`'s last record is a relax tile part's (for `merge --map` to choose).
pub fn is_relax_part(part: &MapView) -> bool {
    part.info().history.last().is_some_and(|r| r.stage == "relax" && r.report.get("tile").is_some())
}

/// `map` relaxed, from the parts of every one of its tiles (in any order): the map
/// `photonkit relax MAP` writes, byte for byte when both runs set `SOURCE_DATE_EPOCH`. An
/// error names the part at fault: one cut from another map, run with other parameters or
/// another tile count, a tile given twice or missing, a photon in two parts or in none.
// Long because it checks the parts and rebuilds the whole map's report in one pass.
pub fn merge_parts<'a>(
    map: &MapView<'a>,
    parts: &[MapView],
) -> Result<(PhotonTable<'a>, Relaxed), RelaxError> {
    let bad = |file: &str, message: String| RelaxError::Input { file: file.to_string(), message };
    let Some(first) = parts.first() else { return Err(bad(map.file_name(), "no tile parts given".into())) };
    let infos = parts.iter().map(|p| part_info(map, p)).collect::<Result<Vec<_>, _>>()?;
    let (count, parameters) = (infos[0].tile.count, infos[0].parameters);
    let same = |a: &Value, b: &Value, key: &str| a.get(key) == b.get(key);
    let mut seen = vec![None; count];
    for (part, info) in parts.iter().zip(&infos) {
        if info.tile.count != count
            || info.parameters != parameters
            || ["space", "constrained", "working_scale", "iterations"]
                .iter()
                .any(|k| !same(info.report, infos[0].report, k))
        {
            return Err(bad(
                part.file_name(),
                format!("run with other parameters or tile count than {}", first.file_name()),
            ));
        }
        if let Some(other) = seen[info.tile.index].replace(part.file_name()) {
            return Err(bad(part.file_name(), format!("tile {} is also in {other}", info.tile)));
        }
    }
    if let Some(missing) = seen.iter().position(Option::is_none) {
        return Err(bad(map.file_name(), format!("tile {missing}/{count} is missing")));
    }
    let p: RelaxParams = serde_json::from_value(parameters.clone())
        .map_err(|e| bad(first.file_name(), format!("its relax parameters: {e}")))?;
    let report = infos[0].report;
    let space: RelaxSpace = serde_json::from_value(report.get("space").cloned().unwrap_or(Value::Null))
        .map_err(|e| bad(first.file_name(), format!("its space: {e}")))?;
    let constrained = report.get("constrained").and_then(Value::as_bool).unwrap_or(false);
    let scale = report.get("working_scale").and_then(Value::as_f64).unwrap_or(1.0);
    let r = p.iterations;
    let n = map.len();
    let mut positions = vec![[0f32; 3]; n];
    let mut normals: Option<Vec<[f32; 3]>> = None;
    // The per-iteration sums, in any order ([`MeasureSums`]).
    let mut sums = vec![MeasureSums::default(); r];
    let mut seen = vec![false; n];
    let mut refused_moves = 0u64;
    for (part, info) in parts.iter().zip(&infos) {
        let need = |c: &str| bad(part.file_name(), format!("a relax tile part needs a {c} column"));
        let indices = part.column::<u64>(PHOTON_INDEX)?.ok_or_else(|| need(PHOTON_INDEX))?;
        let series = |c: &str| -> Result<&[f32], RelaxError> {
            if r == 0 {
                return Ok(&[]);
            }
            let v = part.column_bytes(c).ok_or_else(|| need(c))?;
            let v: &[f32] =
                bytemuck::try_cast_slice(v).map_err(|e| bad(part.file_name(), format!("{c}: {e}")))?;
            if v.len() != indices.len() * r {
                return Err(bad(
                    part.file_name(),
                    format!("{c} holds {} values, expected {}", v.len(), indices.len() * r),
                ));
            }
            Ok(v)
        };
        let (pn, pr, ps) = (series(NN)?, series(RATIO)?, series(STEP)?);
        let px = part.positions();
        let returned = info.report.get("returned_to_surfaces").and_then(Value::as_bool).unwrap_or(false);
        let pnormal = if returned { part.column::<[f32; 3]>(name::NORMAL)? } else { None };
        refused_moves += info.report.get("refused_moves").and_then(Value::as_u64).unwrap_or(0);
        for (k, &i) in indices.iter().enumerate() {
            let i = usize::try_from(i)
                .ok()
                .filter(|&i| i < n)
                .ok_or_else(|| bad(part.file_name(), format!("photon {i} is not in a map of {n}")))?;
            if std::mem::replace(&mut seen[i], true) {
                return Err(bad(part.file_name(), format!("photon {i} is in two tiles")));
            }
            positions[i] = px[k];
            if let Some(ns) = pnormal {
                normals.get_or_insert_with(|| {
                    map.column::<[f32; 3]>(name::NORMAL)
                        .ok()
                        .flatten()
                        .map_or_else(|| vec![[0.0; 3]; n], <[_]>::to_vec)
                })[i] = ns[k];
            }
        }
        MeasureSums::add_series(&mut sums, pn, pr, ps);
    }
    if let Some(i) = seen.iter().position(|s| !s) {
        return Err(bad(map.file_name(), format!("photon {i} is in no tile")));
    }
    let measures = sums
        .iter()
        .enumerate()
        .map(|(t, sum)| {
            let m = sum.measure(t);
            IterationMeasure {
                mean_displacement: m.mean_displacement / scale,
                max_displacement: m.max_displacement / scale,
                ..m
            }
        })
        .collect();
    let relaxed = Relaxed { positions, space, constrained, measures, normals, refused_moves, flux: None };
    let seconds = infos.iter().map(|i| i.seconds).sum();
    Ok((relaxed_map(map, relaxed.clone(), &p, seconds)?, relaxed))
}
