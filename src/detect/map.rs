//! Detection over a photon map: the columns it reads, the method it runs, the wavelength's
//! scale, and the map it writes back.

use super::{
    DetectError, DetectInput, DetectParams, Detection, Method, TileDetection, check_params, detect,
    detect_tile,
};
use crate::format::{MapView, PhotonTable, StageRecord, State, name};
use crate::spatial::ParamColumn;
use crate::tiles::Tiling;

/// The method to run on `map`: `requested` if given (an error if it is `param-pca` and the map
/// has no trajectory parameters), else `param-pca`, or `world-pca` with a note to show the
/// user when the map has no trajectory parameters.
pub fn choose_method(
    map: &MapView,
    requested: Option<Method>,
) -> Result<(Method, Option<String>), DetectError> {
    let has = map_input(map)?.has_params();
    match requested {
        Some(Method::ParamPca) if !has => Err(DetectError::NoParameters { file: map.file_name().into() }),
        Some(m) => Ok((m, None)),
        None if has => Ok((Method::ParamPca, None)),
        None => Ok((
            Method::WorldPca,
            Some(format!(
                "{} has no trajectory parameters: detecting with world-pca (world-space neighbours only)",
                map.file_name()
            )),
        )),
    }
}

/// The columns of `map` that detection reads, validated.
pub fn map_input<'a>(map: &MapView<'a>) -> Result<DetectInput<'a>, DetectError> {
    let file = map.file_name();
    let meta = map.info();
    let input = |message: String| DetectError::Input { file: file.to_string(), message };
    let emitters = map.column::<u16>(name::EMITTER)?;
    if let Some(e) = emitters
        && let Some(i) = e.iter().position(|&e| e as usize >= meta.emitters.len().max(1))
    {
        return Err(input(format!(
            "photon {i} has emitter {} but the map lists {} emitters",
            e[i],
            meta.emitters.len()
        )));
    }
    let params = match map.spec(name::PARAMS) {
        None => None,
        Some(c) if c.dtype != crate::format::DType::F32 => {
            return Err(input(format!("the params column is {}, expected f32", c.dtype.name())));
        }
        Some(c) => {
            let bytes = map.column_bytes(name::PARAMS).unwrap_or(&[]);
            let values: &[f32] =
                bytemuck::try_cast_slice(bytes).map_err(|e| input(format!("params column: {e}")))?;
            Some((values, c.components as usize))
        }
    };
    Ok(DetectInput {
        positions: map.positions(),
        normals: map.column::<[f32; 3]>(name::NORMAL)?,
        flux: Some(map.flux()),
        params: params.map(|(values, stride)| ParamColumn { values, stride, dims: &[] }),
        emitters,
        pages: map.pages(),
    })
}

/// [`detect`] over a map (the file's emitter list gives each emitter's parameter dimensions).
pub fn detect_map(
    map: &MapView,
    p: &DetectParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Detection, DetectError> {
    check_params(p)?;
    let prepared = PreparedInput::new(map, p)?;
    let mut d = detect(&prepared.input(), p, progress).map_err(|e| in_map(map, e))?;
    d.spectral_scales = prepared.scales;
    Ok(d)
}

/// [`detect_tile`] over a map: tile `tile` of `tiling` (made over the map's positions), with
/// the parameters as [`detect_map`] reads them; exactly [`detect_map`]'s results for the
/// tile's photons (docs/tiles.md).
pub fn detect_map_tile(
    map: &MapView,
    p: &DetectParams,
    tiling: &Tiling,
    tile: usize,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<TileDetection, DetectError> {
    check_params(p)?;
    let prepared = PreparedInput::new(map, p)?;
    detect_tile(&prepared.input(), p, tiling, tile, progress).map_err(|e| in_map(map, e))
}

/// [`detect_map`] tile by tile in this process (the tiles of `tiling`), holding one tile's
/// working set at a time besides the map's results: bit for bit [`detect_map`]'s detection
/// (docs/tiles.md), with Eq. 1's radius found as `radius` says. `on_tile(tile, tiles, result)`
/// is called after each tile.
pub fn detect_map_tiled(
    map: &MapView,
    p: &DetectParams,
    tiling: &Tiling,
    radius: super::Radius,
    progress: &(dyn Fn(u64) + Sync),
    on_tile: &mut dyn FnMut(usize, usize, &TileDetection),
) -> Result<Detection, DetectError> {
    check_params(p)?;
    let prepared = PreparedInput::new(map, p)?;
    let mut d = super::tiled_with(&prepared.input(), p, tiling, radius, progress, on_tile)
        .map_err(|e| in_map(map, e))?;
    d.spectral_scales = prepared.scales;
    Ok(d)
}

/// What detecting `map` keeps in memory, for a budget (`tiled::memory`).
pub fn memory(map: &MapView) -> crate::tiles::MemoryModel {
    let spectral = map.info().emitters.iter().any(|e| e.is_spectral());
    super::tiled::memory(spectral.then(|| map.spec(name::PARAMS).map_or(0, |c| c.components as usize)))
}

/// An error of [`detect`] named after `map`.
fn in_map(map: &MapView, e: DetectError) -> DetectError {
    match e {
        DetectError::NoParameters { .. } => DetectError::NoParameters { file: map.file_name().into() },
        DetectError::Spatial(source) => DetectError::Photons { file: map.file_name().into(), source },
        e => e,
    }
}

/// A map's columns as detection reads them: each emitter's parameter dimensions from the
/// file's emitter list, and the wavelength component scaled where the map has one
/// (docs/spectral.md; the scaled copy is owned here).
pub struct PreparedInput<'a> {
    base: DetectInput<'a>,
    dims: Vec<u32>,
    scaled: Option<Vec<f32>>,
    /// Per emitter, the scale given to its wavelength ([`spectral_scales`]); empty when the
    /// parameters are used as given.
    pub scales: Vec<Option<f32>>,
}

impl<'a> PreparedInput<'a> {
    /// The columns of `map` for a detection with `p`.
    pub fn new(map: &MapView<'a>, p: &DetectParams) -> Result<Self, DetectError> {
        let emitters = &map.info().emitters;
        let dims: Vec<u32> = emitters.iter().map(|e| e.param_dims).collect();
        let base = map_input(map)?;
        let mut scales = Vec::new();
        let scaled = match base.params {
            Some(c) if p.method == Method::ParamPca && emitters.iter().any(|e| e.is_spectral()) => {
                let c = ParamColumn { dims: &dims, ..c };
                scales = spectral_scales(emitters, c, base.emitters, p.spectral_scale);
                // The factors relax will read back from the records write_detected makes.
                let factors: Vec<Vec<f32>> = emitters
                    .iter()
                    .zip(&scales)
                    .map(|(e, s)| {
                        s.map_or_else(|| e.param_scales(), |s| e.with_spectral_scale(s as f64).param_scales())
                    })
                    .collect();
                Some(c.scaled(base.emitters, &factors))
            }
            _ => None,
        };
        Ok(PreparedInput { base, dims, scaled, scales })
    }

    /// The input to [`detect`] or [`detect_tile`].
    pub fn input(&self) -> DetectInput<'_> {
        let mut input = self.base;
        input.params = input.params.map(|c| ParamColumn {
            dims: &self.dims,
            values: self.scaled.as_deref().unwrap_or(c.values),
            ..c
        });
        input
    }
}

/// The emitters of `info` with the wavelength scales `scales` recorded.
pub(super) fn with_spectral_scales(info: &mut crate::format::MapInfo, scales: &[Option<f32>]) {
    for (e, s) in info.emitters.iter_mut().zip(scales) {
        if let Some(s) = s {
            *e = e.with_spectral_scale(*s as f64);
        }
    }
}

/// Per emitter, the scale of its wavelength component in parameter-space distances (`None`
/// for an emitter without one): S·ℓ/(λmax − λmin), where ℓ is the root-mean-square distance
/// of the emitter's photons' other parameters from their mean and [λmin, λmax] the
/// dimension's range. The visible range then spans S times the spread of the parameters
/// that say where a photon left, whatever their units (a rectangle's (u, v), or directions in
/// a narrow spot's cone) (docs/spectral.md).
pub fn spectral_scales(
    emitters: &[crate::format::Emitter],
    params: ParamColumn,
    photon_emitters: Option<&[u16]>,
    s: f32,
) -> Vec<Option<f32>> {
    let n = params.values.len() / params.stride.max(1);
    emitters
        .iter()
        .enumerate()
        .map(|(e, em)| {
            let k = em.parameterisation.spectral_component()?;
            let [lo, hi] = em.dimensions().get(k).and_then(|d| d.range).unwrap_or_else(|| {
                let (lo, hi) = crate::format::meta::WAVELENGTH_RANGE_NM;
                [lo as f64, hi as f64]
            });
            let mine = |i: &usize| photon_emitters.map_or(e == 0, |pe| pe[*i] as usize == e);
            let rows = || (0..n).filter(mine).map(|i| &params.values[i * params.stride..][..k]);
            let count = rows().count().max(1) as f64;
            let mut mean = vec![0.0f64; k];
            for q in rows() {
                mean.iter_mut().zip(q).for_each(|(m, &x)| *m += x as f64);
            }
            mean.iter_mut().for_each(|m| *m /= count);
            let var: f64 = rows()
                .map(|q| q.iter().zip(&mean).map(|(&x, m)| (x as f64 - m).powi(2)).sum::<f64>())
                .sum::<f64>()
                / count;
            let spread = if var > 0.0 { var.sqrt() } else { 1.0 };
            let width = if hi > lo { hi - lo } else { 1.0 };
            Some((s as f64 * spread / width) as f32)
        })
        .collect()
}

/// `map` with the constraint columns of `d` (replacing any from an earlier run), every other
/// column carried through unchanged (borrowed), state `detected`, and a stage record.
pub fn detected_map<'a>(
    map: &MapView<'a>,
    d: Detection,
    p: &DetectParams,
    seconds: f64,
) -> Result<PhotonTable<'a>, DetectError> {
    let parameters = record_parameters(p, &d.spectral_scales);
    detected_map_with(map, d, parameters, seconds)
}

/// The parameters a detect record holds: `p`, and the spectral scale S when some emitter's
/// wavelength was scaled (`scales`, [`Detection::spectral_scales`]).
pub fn record_parameters(p: &DetectParams, scales: &[Option<f32>]) -> serde_json::Value {
    let mut parameters = serde_json::to_value(p).unwrap_or_default();
    if scales.iter().any(Option::is_some) {
        parameters["spectral_scale"] = serde_json::json!(p.spectral_scale);
    }
    parameters
}

/// [`detected_map`] with the record's parameters given as they are recorded
/// ([`record_parameters`]): how `photonkit merge` writes a map detected tile by tile.
pub fn detected_map_with<'a>(
    map: &MapView<'a>,
    d: Detection,
    parameters: serde_json::Value,
    seconds: f64,
) -> Result<PhotonTable<'a>, DetectError> {
    let mut info = map.info().clone();
    info.state = State::Detected;
    with_spectral_scales(&mut info, &d.spectral_scales);
    let mut rec = StageRecord::now("detect", parameters);
    let s = &d.summary;
    rec.report = serde_json::json!({
        "seconds": crate::format::meta::reported_seconds(seconds),
        "photons": s.photons,
        "constrained_fraction": s.constrained_fraction(),
        "mean_factor": s.mean_factor,
        "measured": s.measured,
        "too_few_neighbours": s.too_few,
        "coincident": s.coincident,
        "parameter_space": d.r_param.is_some(),
    });
    info.history.push(rec);
    let mut table = PhotonTable::carrying(map, info);
    for column in [name::BASIS_U, name::BASIS_V, name::LAMBDA2, name::R_PARAM] {
        table.remove(column);
    }
    // The columns move into the table: a map's results are not held twice while it is written.
    table.set_vec(name::BASIS_U, d.basis_u)?;
    table.set_vec(name::BASIS_V, d.basis_v)?;
    table.set_vec(name::LAMBDA2, d.lambda2)?;
    if let Some(r) = d.r_param {
        table.set_vec(name::R_PARAM, r)?;
    }
    Ok(table)
}
