//! Tile parts as files: what `photonkit detect MAP --tile i/n -o PART` writes, and how
//! `photonkit merge --map MAP PART…` puts them back into the map `photonkit detect MAP` writes
//! (docs/tiles.md).
//!
//! A part is a PHM map of the tile's interior photons: every column of the map for them, the
//! detection columns, and [`PHOTON_INDEX`], [`FACTOR`] and [`OUTCOME`]. Its
//! last history record is a `detect` record with the whole run's parameters and a report
//! naming the tile, the tile count, and the source map's photon count and position checksum.

use serde_json::{Value, json};

use super::map::with_spectral_scales;
use super::{
    DetectError, DetectParams, Outcome, TileDetection, assemble, detected_map_with, record_parameters,
};
use crate::format::{MapView, PhotonTable, StageRecord, State, name};
use crate::tiles::{TileSpec, part_columns, part_record, part_report};

/// A part's column of each photon's index in the source map (u64).
pub const PHOTON_INDEX: &str = "photon_index";
/// A part's column of each photon's Eq. 7 factor (f32), for the whole map's report.
pub const FACTOR: &str = "detect_factor";
/// A part's column of each photon's [`Outcome::code`] (u8), for the whole map's report.
pub const OUTCOME: &str = "detect_outcome";

/// The part file of tile `tile` of `map`, detected as `t` with parameters `p` (the wavelength
/// scales `scales` as [`super::PreparedInput::scales`] found them) in `seconds`.
pub fn tile_part(
    map: &MapView,
    t: &TileDetection,
    p: &DetectParams,
    scales: &[Option<f32>],
    tile: TileSpec,
    seconds: f64,
) -> Result<PhotonTable<'static>, DetectError> {
    let mut info = map.info().clone();
    info.state = State::Detected;
    with_spectral_scales(&mut info, scales);
    let mut rec = StageRecord::now("detect", record_parameters(p, scales));
    rec.report = part_report(
        map,
        tile,
        t.indices.len(),
        seconds,
        json!({
            "spectral_scales": scales,
            "rounds": t.rounds,
            "param_rounds": t.param_rounds,
            "working_set": t.working_set,
            "per_round": t.per_round,
        }),
    );
    info.history.push(rec);
    // Every column of the map for the tile's photons (a part is the tile's map), then the
    // detection's, replacing any from an earlier run.
    let detection =
        [name::BASIS_U, name::BASIS_V, name::LAMBDA2, name::R_PARAM, PHOTON_INDEX, FACTOR, OUTCOME];
    let columns = part_columns(map, &t.indices, &detection);
    let borrowed: Vec<(crate::format::ColumnSpec, &[u8])> =
        columns.iter().map(|(s, b)| (s.clone(), &b[..])).collect();
    let mut table = PhotonTable::from_columns(map.file_name(), info, &borrowed)?.into_owned();
    table.set(name::BASIS_U, &t.basis_u)?;
    table.set(name::BASIS_V, &t.basis_v)?;
    table.set(name::LAMBDA2, &t.lambda2)?;
    if let Some(r) = &t.r_param {
        table.set(name::R_PARAM, r)?;
    }
    table.set(PHOTON_INDEX, &t.indices.iter().map(|&i| i as u64).collect::<Vec<_>>())?;
    table.set(FACTOR, &t.factor)?;
    table.set(OUTCOME, &t.outcome.iter().map(|o| o.code()).collect::<Vec<_>>())?;
    Ok(table.into_owned())
}

/// What a part says about itself.
struct PartInfo<'p> {
    tile: TileSpec,
    parameters: &'p Value,
    scales: Vec<Option<f32>>,
    seconds: f64,
}

fn part_info<'p>(map: &MapView, part: &MapView<'p>) -> Result<PartInfo<'p>, DetectError> {
    let bad = |message: String| DetectError::Input { file: part.file_name().to_string(), message };
    let rec = part_record(map, part, "detect", "photonkit detect").map_err(bad)?;
    let scales = serde_json::from_value(rec.report.get("spectral_scales").cloned().unwrap_or(json!([])))
        .map_err(|e| bad(format!("its spectral_scales: {e}")))?;
    Ok(PartInfo { tile: rec.tile, parameters: rec.parameters, scales, seconds: rec.seconds })
}

/// A part's photons as a [`TileDetection`].
fn part_detection(part: &MapView) -> Result<TileDetection, DetectError> {
    let bad = |message: String| DetectError::Input { file: part.file_name().to_string(), message };
    let need = |c: &str| bad(format!("a tile part needs a {c} column"));
    let indices = part.column::<u64>(PHOTON_INDEX)?.ok_or_else(|| need(PHOTON_INDEX))?;
    let indices = indices
        .iter()
        .map(|&i| u32::try_from(i).map_err(|_| bad(format!("photon index {i} is out of range"))))
        .collect::<Result<Vec<u32>, _>>()?;
    let outcome = part.column::<u8>(OUTCOME)?.ok_or_else(|| need(OUTCOME))?;
    let outcome = outcome
        .iter()
        .map(|&c| Outcome::from_code(c).ok_or_else(|| bad(format!("outcome code {c} is not one"))))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(TileDetection {
        indices,
        basis_u: part.column::<[f32; 3]>(name::BASIS_U)?.ok_or_else(|| need(name::BASIS_U))?.to_vec(),
        basis_v: part.column::<[f32; 3]>(name::BASIS_V)?.ok_or_else(|| need(name::BASIS_V))?.to_vec(),
        lambda2: part.column::<f32>(name::LAMBDA2)?.ok_or_else(|| need(name::LAMBDA2))?.to_vec(),
        r_param: part.column::<f32>(name::R_PARAM)?.map(<[f32]>::to_vec),
        factor: part.column::<f32>(FACTOR)?.ok_or_else(|| need(FACTOR))?.to_vec(),
        outcome,
        ..Default::default()
    })
}

/// `map` detected, from the parts of every one of its tiles (in any order): the map
/// `photonkit detect MAP` writes, byte for byte when both runs set `SOURCE_DATE_EPOCH`. An
/// error names the part at fault: one cut from another map, run with other parameters or
/// another tile count, a tile given twice or missing.
pub fn merge_parts<'a>(
    map: &MapView<'a>,
    parts: &[MapView],
) -> Result<(PhotonTable<'a>, super::Summary), DetectError> {
    let bad = |file: &str, message: String| DetectError::Input { file: file.to_string(), message };
    let Some(first) = parts.first() else { return Err(bad(map.file_name(), "no tile parts given".into())) };
    let infos = parts.iter().map(|p| part_info(map, p)).collect::<Result<Vec<_>, _>>()?;
    let (count, parameters, scales) = (infos[0].tile.count, infos[0].parameters, &infos[0].scales);
    let mut seen = vec![None; count];
    for (part, info) in parts.iter().zip(&infos) {
        if info.tile.count != count || info.parameters != parameters || &info.scales != scales {
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
    let detections = parts.iter().map(part_detection).collect::<Result<Vec<_>, _>>()?;
    let mut d = assemble(map.len(), &detections).map_err(|e| bad(map.file_name(), e.to_string()))?;
    d.spectral_scales = scales.clone();
    let seconds = infos.iter().map(|i| i.seconds).sum();
    let summary = d.summary.clone();
    Ok((detected_map_with(map, d, parameters.clone(), seconds)?, summary))
}
