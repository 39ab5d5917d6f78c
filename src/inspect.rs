//! Looking into a photon map: summary statistics, invariant checks, text dumps, subsampling.
//!
//! The JSON form of [`Summary`] is also what `tools/phm.py` prints, so the two readers can be
//! compared field by field (format-spec/phm-v1.md §6).

use rand::SeedableRng;
use rayon::prelude::*;
use serde::Serialize;

use crate::format::{
    BoundingBox, ColumnSpec, DType, Emitter, FormatError, MapInfo, Output, PhotonMap, StageRecord,
    UNIT_TOLERANCE, Units, columns::text_names_in, name, write_map,
};

/// Statistics of one component of one column, over its finite values.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ComponentStats {
    /// Smallest finite value; `None` when there is none.
    pub min: Option<f64>,
    /// Largest finite value; `None` when there is none.
    pub max: Option<f64>,
    /// Mean of the finite values, summed in f64 in file order.
    pub mean: Option<f64>,
    /// Number of NaN values.
    pub nan: u64,
    /// Number of infinite values.
    pub inf: u64,
}

/// One row of the column table, with statistics of its values.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ColumnSummary {
    /// The column's name.
    pub name: String,
    /// Its element type.
    pub dtype: DType,
    /// Components per photon.
    pub components: u32,
    /// Byte offset in the file.
    pub offset: u64,
    /// Length, bytes.
    pub length: u64,
    /// The stored CRC-32.
    pub crc32: u32,
    /// One entry per component.
    pub stats: Vec<ComponentStats>,
}

/// What `photonkit inspect --json` prints.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// The map as named to the user.
    pub file: String,
    /// The file's version, `major.minor`.
    pub version: String,
    /// Number of photons.
    pub photon_count: u64,
    /// The map's state (`traced`, `detected`, `collapsed`).
    pub state: String,
    /// Units of length and flux.
    pub units: Units,
    /// The light sources.
    pub emitters: Vec<Emitter>,
    /// The box around every photon position, metres; `None` for an empty map.
    pub bounding_box: Option<BoundingBox>,
    /// Sum of the flux column per RGB channel, watts (f64, file order).
    pub total_flux_w: [f64; 3],
    /// The column table, in file order, with statistics.
    pub columns: Vec<ColumnSummary>,
    /// The stages that wrote the file, oldest first.
    pub history: Vec<StageRecord>,
}

/// Per-component statistics of a column's raw little-endian bytes.
pub fn column_stats(dtype: DType, components: u32, bytes: &[u8]) -> Vec<ComponentStats> {
    let c = components as usize;
    let n = bytes.len() / (dtype.size() as usize * c);
    (0..c)
        .map(|k| {
            let (mut min, mut max, mut sum, mut finite, mut nan, mut inf) =
                (f64::INFINITY, f64::NEG_INFINITY, 0.0f64, 0u64, 0u64, 0u64);
            for i in 0..n {
                let x = dtype.value_f64(bytes, i * c + k);
                if x.is_nan() {
                    nan += 1;
                } else if x.is_infinite() {
                    inf += 1;
                } else {
                    min = min.min(x);
                    max = max.max(x);
                    sum += x;
                    finite += 1;
                }
            }
            let some = |v: f64| (finite > 0).then_some(v);
            ComponentStats { min: some(min), max: some(max), mean: some(sum / finite as f64), nan, inf }
        })
        .collect()
}

/// Summarises a map: metadata, per-column statistics, total flux.
pub fn summarize(map: &PhotonMap) -> Summary {
    let meta = map.meta();
    let columns: Vec<ColumnSummary> = meta
        .columns
        .par_iter()
        .map(|c| ColumnSummary {
            name: c.name.clone(),
            dtype: c.dtype,
            components: c.components,
            offset: c.offset,
            length: c.length,
            crc32: c.crc32,
            stats: column_stats(c.dtype, c.components, map.column_bytes(&c.name).expect("listed")),
        })
        .collect();
    let mut total = [0.0f64; 3];
    for f in map.flux() {
        for k in 0..3 {
            total[k] += f[k] as f64;
        }
    }
    let (major, minor) = map.version();
    Summary {
        file: map.file_name().to_string(),
        version: format!("{major}.{minor}"),
        photon_count: meta.photon_count,
        state: meta.state.name().to_string(),
        units: meta.units.clone(),
        emitters: meta.emitters.clone(),
        bounding_box: meta.bounding_box,
        total_flux_w: total,
        columns,
        history: meta.history.clone(),
    }
}

/// One broken invariant: which rule, how many photons break it, and the first of them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Violation {
    /// The rule broken (format-spec/phm-v1.md §5), or the checksum error.
    pub rule: String,
    /// Photons that break it (0 for a checksum error).
    pub photons: u64,
    /// The first of them (0-based).
    pub first: Option<u64>,
}

/// Verifies checksums and the data invariants of format-spec/phm-v1.md §5.
pub fn check(map: &PhotonMap) -> Vec<Violation> {
    let mut out = Vec::new();
    if let Err(e) = map.verify_checksums() {
        out.push(Violation { rule: e.to_string(), photons: 0, first: None });
        return out;
    }
    let mut rule = |rule: String, bad: &mut dyn Iterator<Item = bool>| {
        let (mut n, mut first) = (0u64, None);
        for (i, b) in bad.enumerate() {
            if b {
                n += 1;
                first.get_or_insert(i as u64);
            }
        }
        if n > 0 {
            out.push(Violation { rule, photons: n, first });
        }
    };
    let meta = map.meta();
    for c in meta.columns.iter().filter(|c| c.dtype.is_float()) {
        let bytes = map.column_bytes(&c.name).expect("listed");
        let k = c.components as usize;
        let mut it = (0..map.len()).map(|i| (0..k).any(|j| !c.dtype.value_f64(bytes, i * k + j).is_finite()));
        rule(format!("column '{}' holds only finite values", c.name), &mut it);
    }
    let norm = |v: &[f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    for col in [name::NORMAL, name::INCIDENT, name::BASIS_U] {
        if let Ok(Some(v)) = map.column::<[f32; 3]>(col) {
            rule(
                format!("'{col}' vectors have unit length"),
                &mut v.iter().map(|v| (norm(v) - 1.0).abs() > UNIT_TOLERANCE),
            );
        }
    }
    if let Ok(Some(v)) = map.column::<[f32; 3]>(name::BASIS_V) {
        rule(
            "'basis_v' vectors have length ≤ 1".into(),
            &mut v.iter().map(|v| norm(v) > 1.0 + UNIT_TOLERANCE),
        );
    }
    rule("flux is non-negative".into(), &mut map.flux().iter().map(|f| f.iter().any(|&x| x < 0.0)));
    let emitter_of = emitter_ids(map);
    if let Some(ids) = &emitter_of {
        let n = meta.emitters.len();
        rule(format!("'emitter' values index the {n} emitters"), &mut ids.iter().map(|&e| e as usize >= n));
    }
    if let Some(p) = meta.column(name::PARAMS) {
        let dims = p.components as usize;
        let params: &[f32] = bytemuck::cast_slice(map.column_bytes(name::PARAMS).expect("listed"));
        let mut it = params.chunks_exact(dims).enumerate().map(|(i, q)| {
            let e = emitter_of.as_ref().map_or(0, |ids| ids[i] as usize);
            let Some(em) = meta.emitters.get(e) else { return false };
            let ok = match em.parameterisation.dims() {
                Some(_) => em.parameterisation.admits(q),
                None => q[(em.param_dims as usize).min(dims)..].iter().all(|&x| x == 0.0),
            };
            !ok
        });
        rule("trajectory parameters lie in their emitter's range".into(), &mut it);
    }
    if let Some(b) = meta.bounding_box {
        let pos = map.positions();
        let mut lo = pos.first().copied().unwrap_or_default();
        let mut hi = lo;
        for p in pos {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if lo != b.min || hi != b.max {
            out.push(Violation {
                rule: format!(
                    "bounding_box {b} equals the positions' box ({}, {}, {}) .. ({}, {}, {})",
                    lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
                ),
                photons: 0,
                first: None,
            });
        }
    }
    out
}

fn emitter_ids(map: &PhotonMap) -> Option<Vec<u16>> {
    map.column::<u16>(name::EMITTER).ok().flatten().map(<[u16]>::to_vec)
}

/// Writes photons `[0, head)` (all when `None`) as TSV with a header row of text names.
pub fn dump_tsv(map: &PhotonMap, head: Option<usize>, out: &mut dyn std::io::Write) -> std::io::Result<()> {
    let cols = map.columns();
    let header: Vec<String> =
        cols.iter().flat_map(|(s, _)| text_names_in(&map.meta().emitters, &s.name, s.components)).collect();
    writeln!(out, "{}", header.join("\t"))?;
    let n = head.map_or(map.len(), |h| h.min(map.len()));
    let mut line = String::new();
    for i in 0..n {
        line.clear();
        for (ci, (s, b)) in cols.iter().enumerate() {
            for k in 0..s.components as usize {
                if ci + k > 0 {
                    line.push('\t');
                }
                s.dtype.format_value(b, i * s.components as usize + k, &mut line);
            }
        }
        line.push('\n');
        out.write_all(line.as_bytes())?;
    }
    Ok(())
}

/// Writes a uniform random subset of `n` photons (in file order), with flux scaled per channel
/// so the total flux equals the original's.
pub fn sample(map: &PhotonMap, n: usize, seed: u64, target: Output) -> Result<(), FormatError> {
    let total = map.len();
    let n = n.min(total);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let mut keep = rand::seq::index::sample(&mut rng, total, n).into_vec();
    keep.sort_unstable();
    let flux = map.flux();
    let (mut before, mut after) = ([0.0f64; 3], [0.0f64; 3]);
    for f in flux {
        (0..3).for_each(|k| before[k] += f[k] as f64);
    }
    for &i in &keep {
        (0..3).for_each(|k| after[k] += flux[i][k] as f64);
    }
    let scale: [f64; 3] = std::array::from_fn(|k| {
        if after[k] > 0.0 { before[k] / after[k] } else { total as f64 / n.max(1) as f64 }
    });
    let owned: Vec<(ColumnSpec, Vec<u8>)> = map
        .columns()
        .into_iter()
        .map(|(spec, bytes)| {
            let s = spec.stride() as usize;
            let mut v = Vec::with_capacity(n * s);
            for &i in &keep {
                v.extend_from_slice(&bytes[i * s..(i + 1) * s]);
            }
            if spec.name == name::FLUX {
                let f: Vec<f32> = v
                    .chunks_exact(4)
                    .enumerate()
                    .map(|(j, b)| (f32::from_le_bytes(b.try_into().expect("4")) as f64 * scale[j % 3]) as f32)
                    .collect();
                v = bytemuck::cast_slice(&f).to_vec();
            }
            (spec, v)
        })
        .collect();
    let mut info: MapInfo = map.meta().info();
    info.history.push(StageRecord::now(
        "sample",
        serde_json::json!({ "from": map.file_name(), "photons": n, "of": total, "seed": seed }),
    ));
    let cols: Vec<(ColumnSpec, &[u8])> = owned.iter().map(|(s, v)| (s.clone(), v.as_slice())).collect();
    write_map(target, info, &cols)
}
