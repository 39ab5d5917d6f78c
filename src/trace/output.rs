//! What a run leaves: the stored photons ([`Traced`]), written to a PHM file with the
//! metadata of the trace stage.

use std::ops::Range;

use serde_json::json;

use super::store::{ChunkStore, Layout};
use super::{Budget, Photons, StorePolicy, TraceError, TraceOptions};
use crate::format::{
    ColumnSpec, MapInfo, Output, PhotonWriter, State, TraceParameters, TraceRecord, TraceReport,
};
use crate::scene::{Scene, scene_crc32};

/// The outcome of a run: the stored photons (in emission order) and counts.
#[derive(Debug)]
pub struct Traced {
    pub(super) store: ChunkStore,
    /// Number of trajectory parameters per photon.
    pub param_dims: u32,
    /// Whether the map gets an `emitter` column (the scene has several emitters).
    pub emitter_column: bool,
    /// Emission numbers traced by this run (a shard's slice, or 0..emitted).
    pub range: Range<u64>,
    /// Photons emitted by the whole run (all shards): the divisor of the flux.
    pub emitted: u64,
    /// Photons stored by this run.
    pub stored: u64,
    /// Photons dropped at the bounce limit.
    pub bounce_limited: u64,
    /// Scene power in watts, the numerator of the flux.
    pub(super) power_w: f64,
}

impl Traced {
    /// Stored photons with their final flux in watts (read back from the spool if the run
    /// had one and used it).
    pub fn photons(&self) -> Result<Photons, TraceError> {
        self.store.photons(self.flux_scale())
    }

    /// Keeps only the photons whose specular bounce count is in `keep` (each photon's flux is
    /// unchanged, so the kept photons estimate the irradiance of those paths alone): how the
    /// comparison matches a ground truth that accounts for some path families only.
    pub fn retain_bounces(&mut self, keep: &[u8]) -> Result<(), TraceError> {
        self.store.retain(|b| keep.contains(&b))?;
        self.stored = self.store.count();
        Ok(())
    }

    fn flux_scale(&self) -> f64 {
        self.power_w / self.emitted.max(1) as f64
    }

    fn layout(&self) -> Layout {
        Layout { dims: self.param_dims as usize, emitter_column: self.emitter_column }
    }

    /// The columns written, in order.
    pub fn column_specs(&self) -> Vec<ColumnSpec> {
        self.layout().column_specs()
    }

    /// Streams the photons into a PHM file, a block at a time.
    pub fn write(&self, target: Output, info: MapInfo) -> Result<(), TraceError> {
        let mut w = PhotonWriter::create(target, info, &self.column_specs(), self.stored)?;
        self.store.for_each_block(self.flux_scale(), |cols| Ok(w.push(cols)?))?;
        Ok(w.finish()?)
    }
}

/// The metadata of a traced map: the scene's emitters and the `trace` stage record.
/// `scene_label` names the scene file; `scene_content` (a TOML file's text, a glTF file's
/// bytes and its buffers': [`crate::scene::SceneFile::content`]) is hashed ([`scene_crc32`]) so
/// shards of different scenes are not merged.
pub fn map_info(
    scene: &Scene,
    opts: &TraceOptions,
    traced: &Traced,
    scene_label: &str,
    scene_content: &[u8],
) -> MapInfo {
    let mut info = MapInfo::new(scene.emitter_records(), State::Traced);
    let (photons, stored) = match opts.budget {
        Budget::Emitted(n) => (Some(n), None),
        Budget::Stored(n) => (None, Some(n)),
    };
    let parameters = TraceParameters {
        scene: scene_label.to_string(),
        scene_crc32: scene_crc32(scene_content),
        seed: opts.seed,
        store: match opts.store {
            StorePolicy::Caustic => "caustic",
            StorePolicy::Direct => "direct",
        }
        .to_string(),
        max_bounces: opts.max_bounces,
        photons,
        stored,
        shard: opts.shard.map(|s| format!("{}/{}", s.index, s.count)),
        ..TraceParameters::default()
    };
    let report = TraceReport {
        emitted: traced.emitted,
        stored: traced.stored,
        bounce_limited: traced.bounce_limited,
        emission_range: opts.shard.map(|_| [traced.range.start, traced.range.end]),
        ..TraceReport::default()
    };
    let mut rec = TraceRecord { parameters, report }.to_stage_record();
    if let Some(t) = source_date() {
        rec.time = t;
    }
    info.history.push(rec);
    info
}

/// Records in `info`'s trace record where the scene file lies relative to the map's folder
/// (`report.scene_from_map`), so later stages find the scene from any working directory while
/// the file's bytes do not depend on where the run was started. Nothing when either path
/// cannot be resolved.
pub fn record_scene_location(info: &mut MapInfo, scene: &std::path::Path, map: &std::path::Path) {
    let map_dir = crate::format::folder_of(map);
    let (Ok(scene), Ok(dir)) = (scene.canonicalize(), map_dir.canonicalize()) else { return };
    let Some(rel) = pathdiff::diff_paths(&scene, &dir) else { return };
    if let Some(rec) = info.history.iter_mut().rev().find(|r| r.stage == "trace")
        && let Some(report) = rec.report.as_object_mut()
    {
        report.insert("scene_from_map".into(), json!(rel.to_string_lossy()));
    }
}

/// The time from `SOURCE_DATE_EPOCH`, if set ([`crate::format::meta::source_date`]).
pub fn source_date() -> Option<String> {
    crate::format::meta::source_date()
}
