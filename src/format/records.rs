//! The stage records of a map's history, typed: what each stage writes into its
//! [`StageRecord`]'s `parameters` and `report`, and how a later stage reads them back.
//!
//! A record's JSON objects are written with sorted keys, so a typed record serialises to the
//! same bytes as the one built key by key; keys a newer version adds are kept in `extra`.

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::meta::{MapInfo, StageRecord};

/// `parameters` of the `trace` record: what was traced, and how (a key an older file lacks
/// reads as its default).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TraceParameters {
    /// The scene as the user named it (a path, or the embedded default's name).
    pub scene: String,
    /// CRC-32 of the scene file's text, 8 hex digits ([`crate::scene::scene_crc32`]).
    pub scene_crc32: String,
    /// The seed of the emission sequence's rotation and of the per-photon random streams
    /// ([`crate::sampling`]).
    pub seed: u64,
    /// Which photons were stored: "caustic" (L S+ D) or "direct".
    pub store: String,
    /// Specular interactions after which a photon is dropped.
    pub max_bounces: u32,
    /// Photons emitted (a fixed emission budget).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub photons: Option<u64>,
    /// Photons to store (a storage budget).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stored: Option<u64>,
    /// "i/n" for shard i of n.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<String>,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl TraceParameters {
    /// The shard (index, count) this trace was, if it was one and the field is well formed.
    pub fn shard(&self) -> Option<Result<(u64, u64), String>> {
        let s = self.shard.as_deref()?;
        Some(
            s.split_once('/')
                .and_then(|(i, n)| Some((i.parse::<u64>().ok()?, n.parse::<u64>().ok()?)))
                .filter(|(i, n)| i < n)
                .ok_or_else(|| format!("bad shard parameter \"{s}\"")),
        )
    }
}

/// `report` of the `trace` record: what the trace did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TraceReport {
    /// Photons emitted (by the whole run, every shard).
    pub emitted: u64,
    /// Photons stored in the map.
    pub stored: u64,
    /// Photons dropped at the bounce limit.
    pub bounce_limited: u64,
    /// The emission numbers a shard traced, [start, end).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub emission_range: Option<[u64; 2]>,
    /// Where the scene file lies relative to the map's folder, when it was known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene_from_map: Option<String>,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A map's `trace` record, typed.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceRecord {
    /// What was traced, and how.
    pub parameters: TraceParameters,
    /// What the trace did.
    pub report: TraceReport,
}

impl TraceRecord {
    /// The record as a history entry (stamped now: [`StageRecord::now`]).
    pub fn to_stage_record(&self) -> StageRecord {
        let mut rec = StageRecord::now("trace", to_value(&self.parameters));
        rec.report = to_value(&self.report);
        rec
    }

    /// The typed form of a `trace` history entry; `None` for another stage's or a record
    /// this version cannot read.
    pub fn of(rec: &StageRecord) -> Option<TraceRecord> {
        if rec.stage != "trace" {
            return None;
        }
        Some(TraceRecord {
            parameters: serde_json::from_value(rec.parameters.clone()).ok()?,
            report: serde_json::from_value(rec.report.clone()).ok()?,
        })
    }
}

fn to_value(v: &impl Serialize) -> Value {
    serde_json::to_value(v).expect("a record serialises")
}

impl MapInfo {
    /// The last `trace` record of the history (a map made by `trace`, or by stages after it).
    pub fn trace_record(&self) -> Option<TraceRecord> {
        self.history.iter().rev().find(|r| r.stage == "trace").and_then(TraceRecord::of)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A typed trace record writes the JSON the key-by-key one did (same keys and values,
    /// sorted), reads back equal, and keeps keys it does not know.
    #[test]
    fn a_trace_record_round_trips_and_keeps_unknown_keys() {
        let text = r#"{"max_bounces":16,"photons":1000,"scene":"s.toml","scene_crc32":"0badf00d",
                       "seed":3,"shard":"1/4","store":"caustic","future":[1,2]}"#;
        let value: Value = serde_json::from_str(text).unwrap();
        let p: TraceParameters = serde_json::from_value(value.clone()).unwrap();
        assert_eq!(p.shard(), Some(Ok((1, 4))));
        assert_eq!(p.extra["future"], serde_json::json!([1, 2]));
        assert_eq!(serde_json::to_string(&to_value(&p)).unwrap(), serde_json::to_string(&value).unwrap());
        let bad = TraceParameters { shard: Some("4/4".into()), ..p };
        assert_eq!(bad.shard(), Some(Err("bad shard parameter \"4/4\"".into())));
        let report = TraceReport { emitted: 10, stored: 4, ..TraceReport::default() };
        assert_eq!(to_value(&report), serde_json::json!({ "emitted": 10, "stored": 4, "bounce_limited": 0 }));
        let rec = TraceRecord { parameters: bad, report }.to_stage_record();
        assert_eq!(TraceRecord::of(&rec).unwrap().report.stored, 4);
    }
}
