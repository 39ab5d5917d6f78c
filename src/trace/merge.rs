//! Joining the shards of one trace into the file a single run writes.
//!
//! Shard i of n holds the photons of its slice of emission numbers, with flux already divided
//! by the whole run's emitted count; so the merged map is the shards' columns one after the
//! other in shard order, under the `trace` record the single run would have written (the shard
//! parameter dropped, counts summed, the latest shard's time).

use serde_json::{Value, json};

use super::TraceError;
use crate::format::{ColumnSpec, Output, PhotonMap, PhotonWriter, StageRecord};

/// Photons per pushed chunk.
const CHUNK: usize = 1 << 16;

struct ShardInfo<'a> {
    map: &'a PhotonMap,
    index: u64,
    count: u64,
    record: &'a StageRecord,
    params: Value,
}

fn fail(map: &PhotonMap, message: impl Into<String>) -> TraceError {
    TraceError::Merge { file: map.file_name().to_string(), message: message.into() }
}

fn shard_info(map: &PhotonMap) -> Result<ShardInfo<'_>, TraceError> {
    let h = &map.meta().history;
    let record = match h.as_slice() {
        [r] if r.stage == "trace" => r,
        _ => {
            return Err(fail(
                map,
                "not a shard written by `photonkit trace --shard` (its history is not one trace record)",
            ));
        }
    };
    let mut params = record.parameters.clone();
    let shard = params
        .as_object_mut()
        .and_then(|o| o.remove("shard"))
        .and_then(|s| s.as_str().map(str::to_string))
        .ok_or_else(|| fail(map, "its trace record has no shard parameter"))?;
    let (i, n) = shard
        .split_once('/')
        .and_then(|(i, n)| Some((i.parse::<u64>().ok()?, n.parse::<u64>().ok()?)))
        .filter(|(i, n)| i < n)
        .ok_or_else(|| fail(map, format!("bad shard parameter \"{shard}\"")))?;
    Ok(ShardInfo { map, index: i, count: n, record, params })
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
    let (n, params, version) = (first.count, first.params.clone(), first.record.version.clone());
    let (emitters, units, cols) = (&first.map.meta().emitters, &first.map.meta().units, specs(first.map));
    for s in &shards {
        if s.count != n {
            return Err(fail(s.map, format!("shard of {} but shard 0 is a shard of {n}", s.count)));
        }
        if s.params != params || s.record.version != version {
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

    let sum = |key: &str| -> u64 { shards.iter().map(|s| s.record.report[key].as_u64().unwrap_or(0)).sum() };
    let emitted = first.record.report["emitted"].as_u64().unwrap_or(0);
    let total: u64 = shards.iter().map(|s| s.map.len() as u64).sum();
    let mut record = first.record.clone();
    record.parameters = params;
    record.time = shards.iter().map(|s| s.record.time.clone()).max().unwrap_or_default();
    record.report = json!({ "emitted": emitted, "stored": total, "bounce_limited": sum("bounce_limited") });
    let mut info = first.map.meta().info();
    info.history = vec![record];
    // The scene's place relative to the merged map, from shard 0's (as a single run records it).
    if let (Some(rel), Output::Path(out)) =
        (first.record.report.get("scene_from_map").and_then(|v| v.as_str()), &target)
    {
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
