//! Joining the shards of one trace into the file a single run writes.
//!
//! Shard i of n holds the photons of its slice of emission numbers, with flux already divided
//! by the whole run's emitted count; so the merged map is the shards' columns one after the
//! other in shard order, under the `trace` record the single run would have written (the shard
//! parameter dropped, counts summed, the latest shard's time).

use super::TraceError;
use crate::format::{ColumnSpec, Output, PhotonMap, PhotonWriter, StageRecord, TraceRecord, TraceReport};

/// Photons per pushed chunk.
const CHUNK: usize = 1 << 16;

struct ShardInfo<'a> {
    map: &'a PhotonMap,
    index: u64,
    count: u64,
    record: &'a StageRecord,
    /// The shard's trace record, typed, its `shard` parameter taken out (what every shard of
    /// one trace shares).
    trace: TraceRecord,
}

fn fail(map: &PhotonMap, message: impl Into<String>) -> TraceError {
    TraceError::Merge { file: map.file_name().to_string(), message: message.into() }
}

fn shard_info(map: &PhotonMap) -> Result<ShardInfo<'_>, TraceError> {
    let record = match map.meta().history.as_slice() {
        [r] if r.stage == "trace" => r,
        _ => {
            return Err(fail(
                map,
                "not a shard written by `photonkit trace --shard` (its history is not one trace record)",
            ));
        }
    };
    let mut trace = TraceRecord::of(record).ok_or_else(|| fail(map, "its trace record can not be read"))?;
    let (index, count) = trace
        .parameters
        .shard()
        .ok_or_else(|| fail(map, "its trace record has no shard parameter"))?
        .map_err(|e| fail(map, e))?;
    trace.parameters.shard = None;
    Ok(ShardInfo { map, index, count, record, trace })
}

fn specs(map: &PhotonMap) -> Vec<ColumnSpec> {
    map.meta().columns.iter().map(|c| ColumnSpec::new(&c.name, c.dtype, c.components)).collect()
}

/// Merges every shard of one trace (in any order) into `target`; returns the photon count.
pub fn merge(inputs: &[PhotonMap], target: Output) -> Result<u64, TraceError> {
    let mut shards = inputs.iter().map(shard_info).collect::<Result<Vec<_>, _>>()?;
    if shards.is_empty() {
        return Err(TraceError::Merge { file: "-".into(), message: "no shards given".into() });
    }
    shards.sort_by_key(|s| s.index);
    let first = &shards[0];
    let (n, params, version) = (first.count, &first.trace.parameters, first.record.version.clone());
    let (emitters, units, cols) = (&first.map.meta().emitters, &first.map.meta().units, specs(first.map));
    for s in &shards {
        if s.count != n {
            return Err(fail(s.map, format!("shard of {} but shard 0 is a shard of {n}", s.count)));
        }
        if s.trace.parameters != *params || s.record.version != version {
            return Err(fail(s.map, "traced with other parameters, scene or photonkit version than shard 0"));
        }
        if &s.map.meta().emitters != emitters || &s.map.meta().units != units || specs(s.map) != cols {
            return Err(fail(s.map, "its emitters, units or columns differ from shard 0's"));
        }
    }
    for (k, s) in shards.iter().enumerate() {
        if s.index != k as u64 {
            let what = if s.index < k as u64 { "given twice" } else { "missing" };
            let (shard, file) = if s.index < k as u64 { (s.index, s.map) } else { (k as u64, s.map) };
            return Err(fail(file, format!("shard {shard}/{n} is {what}")));
        }
    }
    if shards.len() as u64 != n {
        return Err(TraceError::Merge {
            file: shards[shards.len() - 1].map.file_name().to_string(),
            message: format!("shard {}/{n} is missing", shards.len()),
        });
    }

    let total: u64 = shards.iter().map(|s| s.map.len() as u64).sum();
    let report = TraceReport {
        emitted: first.trace.report.emitted,
        stored: total,
        bounce_limited: shards.iter().map(|s| s.trace.report.bounce_limited).sum(),
        ..TraceReport::default()
    };
    let mut record = first.record.clone();
    record.parameters = serde_json::to_value(params).expect("a record serialises");
    record.time = shards.iter().map(|s| s.record.time.clone()).max().unwrap_or_default();
    record.report = serde_json::to_value(&report).expect("a record serialises");
    let mut info = first.map.meta().info();
    info.history = vec![record];
    // The scene's place relative to the merged map, from shard 0's (as a single run records it).
    if let (Some(rel), Output::Path(out)) = (&first.trace.report.scene_from_map, &target) {
        let dir = crate::format::folder_of(std::path::Path::new(first.map.file_name()));
        super::record_scene_location(&mut info, &dir.join(rel), out);
    }

    let mut w = PhotonWriter::create(target, info, &cols, total)?;
    for s in &shards {
        let columns = s.map.columns();
        let len = s.map.len();
        let mut start = 0;
        while start < len {
            let end = (start + CHUNK).min(len);
            let chunk: Vec<&[u8]> = columns
                .iter()
                .map(|(spec, b)| &b[start * spec.stride() as usize..end * spec.stride() as usize])
                .collect();
            w.push(&chunk)?;
            start = end;
        }
    }
    w.finish()?;
    Ok(total)
}
