//! Photon emission and tracing: the first stage of the pipeline.
//!
//! Photon number i leaves an emitter chosen in proportion to power, at the point or in the
//! direction given by the i-th point of a [Halton sequence](halton); its **trajectory
//! parameters** record where it left ((u, v) on a collimated emitter's rectangle, or the unit
//! emission direction of a point or spot light). It is traced through mirrors and dielectrics
//! (Fresnel reflection or refraction chosen stochastically, Russian roulette on losses so the
//! expected flux is unbiased) to the first diffuse surface, where it is stored if it met at
//! least one specular surface on the way (a caustic photon, path L S+ D), or always with
//! [`StorePolicy::Direct`].
//!
//! Work is split into chunks of consecutive emission numbers traced in parallel (rayon); the
//! output depends only on the scene, the seed and the range of emission numbers, never on
//! the thread count. A shard traces one slice of the range; [`merge`] joins shards into the
//! file a single run writes.

pub use crate::sampling::halton;
mod merge;
mod store;

use std::ops::Range;

use glam::Vec3;
use rayon::prelude::*;
use serde_json::json;

use crate::format::{ColumnSpec, FormatError, MapInfo, Output, PhotonWriter, StageRecord, State};
use crate::scene::material::{
    WAVELENGTH_RANGE_NM, fresnel_cosines, reflect, refract_unnormalised, wavelength_rgb_tabulated,
};
use crate::scene::{Dielectric, Material, Ray, Reach, Scene};
use halton::{Halton, PhotonRng};
pub use merge::merge;
use store::{Chunk, ChunkStore, Layout};
pub use store::{DEFAULT_SPOOL_MEMORY, Spool};

/// Emission numbers per unit of parallel work.
pub const CHUNK: u64 = 4096;

/// Chunks traced in parallel between two hand-overs to the store and checks of the room
/// left (1 M emission numbers: the photons in flight take tens of MB).
const BATCH_CHUNKS: u64 = 256;

/// Everything that can go wrong while tracing or merging.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TraceError {
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("shard {index}/{count}: needs 0 ≤ i < n")]
    BadShard { index: u64, count: u64 },
    #[error("--stored cannot be combined with --shard: a shard traces a fixed range of emission numbers")]
    StoredWithShard,
    #[error(
        "no photon was stored after {emitted} emitted: does light reach a diffuse surface by way of \
         a mirror or dielectric? (--store direct stores direct hits too)"
    )]
    NothingStored { emitted: u64 },
    #[error("{file}: cannot merge: {message}")]
    Merge { file: String, message: String },
    #[error(
        "{what} would need about {need_gb:.1} GB for the stored photons, more than the {avail_gb:.1} GB of memory \
         available: trace fewer photons, lower `trace --memory`, or split the run with --shard i/n and join the shards with `photonkit merge`"
    )]
    OutOfMemory { what: String, need_gb: f64, avail_gb: f64 },
    #[error(
        "{what} would need about {need_gb:.1} GB of disk for the stored photons (spooled, then the output), \
         more than the {avail_gb:.1} GB free in {dir}: trace fewer photons, write to a larger disk, or split the \
         run with --shard i/n and join the shards with `photonkit merge`"
    )]
    OutOfDisk { what: String, need_gb: f64, avail_gb: f64, dir: String },
    #[error("spooling stored photons in {dir}: {source}")]
    Spool { dir: String, source: std::io::Error },
}

/// What to trace until.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Budget {
    /// Emit this many photons (emission numbers 0..n).
    Emitted(u64),
    /// Emit until this many photons are stored (the run then counts as having emitted up to
    /// and including the emission number of the last one stored).
    Stored(u64),
}

/// Which photons are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StorePolicy {
    /// Caustic photons only: at least one specular interaction before the diffuse hit.
    Caustic,
    /// Caustic photons and photons that reach a diffuse surface straight from the emitter.
    Direct,
}

/// One slice `index` of `count` equal slices of the emission numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
}

impl Shard {
    /// The emission numbers of this shard out of `total`.
    pub fn range(&self, total: u64) -> Range<u64> {
        let at = |k: u64| (total as u128 * k as u128 / self.count as u128) as u64;
        at(self.index)..at(self.index + 1)
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TraceOptions {
    pub seed: u64,
    pub budget: Budget,
    pub store: StorePolicy,
    pub shard: Option<Shard>,
    /// Specular interactions after which a photon is dropped (counted in the report).
    pub max_bounces: u32,
    /// Where stored photons go when they outgrow memory; `None` keeps them all in memory
    /// (for callers that use them there rather than write them).
    pub spool: Option<Spool>,
}

impl Default for TraceOptions {
    fn default() -> Self {
        TraceOptions {
            seed: 1,
            budget: Budget::Emitted(1_000_000),
            store: StorePolicy::Caustic,
            shard: None,
            max_bounces: 64,
            spool: None,
        }
    }
}

/// Stored photons as columns (structure of arrays). `flux` is relative until the run ends:
/// the share of one photon carrying the scene's whole power.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Photons {
    pub position: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
    pub flux: Vec<[f32; 3]>,
    pub incident: Vec<[f32; 3]>,
    pub emitter: Vec<u16>,
    /// `param_dims` values per photon.
    pub params: Vec<f32>,
    pub path_length: Vec<f32>,
    pub bounces: Vec<u8>,
    pub emission_index: Vec<u64>,
    pub surface: Vec<u32>,
}

impl Photons {
    pub fn len(&self) -> usize {
        self.position.len()
    }

    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }
}

const CHUNK_LEN: usize = CHUNK as usize;

/// One stored photon, as [`Scratch::push`] takes it.
struct Landing {
    position: Vec3,
    normal: Vec3,
    flux: Vec3,
    incident: Vec3,
    emitter: u16,
    /// All four; the first `dims` are kept.
    params: [f32; 4],
    path_length: f32,
    bounces: u8,
    emission_offset: u16,
    surface: u32,
}

/// A worker's chunk under construction, reused chunk after chunk: columns with room for a
/// photon per emission number of a chunk, written in place under one count (no length and
/// capacity per column to check and update, no copy call for the parameters).
struct Scratch {
    first: u64,
    len: usize,
    /// Trajectory parameters per photon (at most 4).
    dims: usize,
    position: Box<[[f32; 3]; CHUNK_LEN]>,
    normal: Box<[[f32; 3]; CHUNK_LEN]>,
    flux: Box<[[f32; 3]; CHUNK_LEN]>,
    incident: Box<[[f32; 3]; CHUNK_LEN]>,
    emitter: Box<[u16; CHUNK_LEN]>,
    /// `dims` values per photon; each photon writes four, the next overwriting the surplus.
    params: Box<[f32; 4 * CHUNK_LEN]>,
    path_length: Box<[f32; CHUNK_LEN]>,
    bounces: Box<[u8; CHUNK_LEN]>,
    emission_offset: Box<[u16; CHUNK_LEN]>,
    surface: Box<[u32; CHUNK_LEN]>,
}

impl Scratch {
    fn new(dims: usize) -> Scratch {
        fn column<T: Copy + Default, const N: usize>() -> Box<[T; N]> {
            vec![T::default(); N].into_boxed_slice().try_into().unwrap_or_else(|_| unreachable!())
        }
        assert!(dims <= 4, "at most four trajectory parameters");
        Scratch {
            first: 0,
            len: 0,
            dims,
            position: column(),
            normal: column(),
            flux: column(),
            incident: column(),
            emitter: column(),
            params: column(),
            path_length: column(),
            bounces: column(),
            emission_offset: column(),
            surface: column(),
        }
    }

    /// Empties it for a chunk starting at emission number `first`.
    fn reset(&mut self, first: u64) {
        self.first = first;
        self.len = 0;
    }

    /// Appends photon `p`. A chunk stores each of its at most [`CHUNK`] emission numbers
    /// at most once, so there is always room.
    #[inline(always)]
    fn push(&mut self, p: Landing) {
        let n = self.len;
        assert!(n < CHUNK_LEN, "a chunk stores at most one photon per emission number");
        self.position[n] = p.position.to_array();
        self.normal[n] = p.normal.to_array();
        self.flux[n] = p.flux.to_array();
        self.incident[n] = p.incident.to_array();
        self.emitter[n] = p.emitter;
        let at = n * self.dims.min(4);
        self.params[at..at + 4].copy_from_slice(&p.params);
        self.path_length[n] = p.path_length;
        self.bounces[n] = p.bounces;
        self.emission_offset[n] = p.emission_offset;
        self.surface[n] = p.surface;
        self.len = n + 1;
    }

    /// A copy of exactly the stored photons (with the emitter column if `emitter_column`):
    /// only the copy lands in fresh memory.
    fn to_chunk(&self, emitter_column: bool) -> Chunk {
        let n = self.len;
        Chunk {
            first: self.first,
            position: copy(&self.position[..n]),
            normal: copy(&self.normal[..n]),
            flux: copy(&self.flux[..n]),
            incident: copy(&self.incident[..n]),
            emitter: if emitter_column { copy(&self.emitter[..n]) } else { Vec::new() },
            params: copy(&self.params[..n * self.dims]),
            path_length: copy(&self.path_length[..n]),
            bounces: copy(&self.bounces[..n]),
            emission_offset: copy(&self.emission_offset[..n]),
            surface: copy(&self.surface[..n]),
        }
    }
}

/// `v` copied into a new vector whose memory is made ready for writing in one call to the
/// kernel first ([`prefault`]) rather than a page fault per fresh page.
fn copy<T: Copy>(v: &[T]) -> Vec<T> {
    let mut out = Vec::with_capacity(v.len());
    prefault(out.as_mut_ptr() as *mut u8, std::mem::size_of_val(v));
    out.extend_from_slice(v);
    out
}

/// Asks the kernel to map the pages spanning `len` bytes from `p` writable now
/// (`MADV_POPULATE_WRITE`, Linux 5.14): contents unchanged, pages already mapped untouched.
/// On older kernels and other systems the pages fault in on first write as usual.
fn prefault(p: *mut u8, len: usize) {
    #[cfg(target_os = "linux")]
    {
        static PAGE: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
        // SAFETY: sysconf only reads a system setting.
        let page = *PAGE.get_or_init(|| match unsafe { libc::sysconf(libc::_SC_PAGESIZE) } {
            n if n > 0 && (n as usize).is_power_of_two() => n as usize,
            _ => 4096,
        });
        if len < page {
            return;
        }
        let start = p as usize & !(page - 1);
        let end = (p as usize + len).div_ceil(page) * page;
        // SAFETY: the range covers memory of this process's heap (the new vector's); the
        // advice only maps its pages, it does not change their contents.
        unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_POPULATE_WRITE) };
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (p, len);
}

/// The outcome of a run: the stored photons (in emission order) and counts.
#[derive(Debug)]
pub struct Traced {
    store: ChunkStore,
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
    power_w: f64,
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

/// The CRC-32 of a scene file's text as the trace record's `scene_crc32` holds it (8 hex
/// digits): how later stages tell whether a scene file is the one the map was traced from.
pub fn scene_crc32(scene_text: &str) -> String {
    format!("{:08x}", crc32fast::hash(scene_text.as_bytes()))
}

/// The metadata of a traced map: the scene's emitters and the `trace` stage record.
/// `scene_label` names the scene file; `scene_text` is hashed ([`scene_crc32`]) so shards of
/// different scenes are not merged.
pub fn map_info(
    scene: &Scene,
    opts: &TraceOptions,
    traced: &Traced,
    scene_label: &str,
    scene_text: &str,
) -> MapInfo {
    let emitters = scene.emitter_records();
    let mut info = MapInfo::new(emitters, State::Traced);
    let mut params = json!({
        "scene": scene_label,
        "scene_crc32": scene_crc32(scene_text),
        "seed": opts.seed,
        "store": match opts.store { StorePolicy::Caustic => "caustic", StorePolicy::Direct => "direct" },
        "max_bounces": opts.max_bounces,
    });
    match opts.budget {
        Budget::Emitted(n) => params["photons"] = json!(n),
        Budget::Stored(n) => params["stored"] = json!(n),
    }
    let mut report = json!({ "emitted": traced.emitted, "stored": traced.stored,
                             "bounce_limited": traced.bounce_limited });
    if let Some(s) = opts.shard {
        params["shard"] = json!(format!("{}/{}", s.index, s.count));
        report["emission_range"] = json!([traced.range.start, traced.range.end]);
    }
    let mut rec = StageRecord::now("trace", params);
    if let Some(t) = source_date() {
        rec.time = t;
    }
    rec.report = report;
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

/// Per-emitter constants of the tracer.
struct EmitterTable {
    /// Cumulative power fractions, the last one 1.
    cdf: Vec<f32>,
    /// Each emitter's RGB share of one photon's flux (sums to 1 over RGB).
    colour: Vec<Vec3>,
}

/// Traces photons of `scene`. `progress(emitted, stored)` is called after each chunk with
/// that chunk's counts.
pub fn trace(
    scene: &Scene,
    opts: &TraceOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Traced, TraceError> {
    if let Some(s) = opts.shard {
        if s.count == 0 || s.index >= s.count {
            return Err(TraceError::BadShard { index: s.index, count: s.count });
        }
        if matches!(opts.budget, Budget::Stored(_)) {
            return Err(TraceError::StoredWithShard);
        }
    }
    let tracer = Tracer::new(scene, opts);
    let layout = Layout { dims: tracer.dims, emitter_column: tracer.emitter_column };
    let limit = match opts.budget {
        Budget::Stored(target) => Some(target),
        Budget::Emitted(_) => None,
    };
    let mut store = ChunkStore::new(layout, opts.spool.clone(), limit);
    let (range, emitted, bounce_limited) = match opts.budget {
        Budget::Emitted(n) => {
            let range = opts.shard.map_or(0..n, |s| s.range(n));
            let limited = tracer.run(range.clone(), &mut store, progress)?;
            (range, n, limited)
        }
        Budget::Stored(target) => {
            store.check_room(target, || format!("storing {target} photons"))?;
            let mut next = 0u64;
            let mut limited = 0;
            // Each round traces a range sized from the storage rate so far; the store keeps
            // exactly `target` photons, and the run emitted up to the last one kept.
            while !store.is_full() {
                let stored = store.count();
                let round = if stored == 0 {
                    if next >= 50_000_000 {
                        return Err(TraceError::NothingStored { emitted: next });
                    }
                    next.clamp(CHUNK * 16, 1 << 24)
                } else {
                    let rate = stored as f64 / next as f64;
                    (((target - stored) as f64 / rate * 1.05) as u64).clamp(CHUNK, 1 << 26)
                };
                let round = round.div_ceil(CHUNK) * CHUNK;
                limited += tracer.run(next..next + round, &mut store, progress)?;
                next += round;
            }
            let emitted = store.last_index().map_or(0, |i| i + 1);
            (0..emitted, emitted, limited)
        }
    };
    Ok(Traced {
        stored: store.count(),
        store,
        param_dims: scene.param_dims(),
        emitter_column: tracer.emitter_column,
        range,
        emitted,
        bounce_limited,
        power_w: tracer.power_w,
    })
}

/// Whether testing an emitter's rays against the box around the specular surfaces saves
/// time: true when at least one in eight of 256 rays spread over its sample square misses
/// the box. A photon whose emission ray misses reaches a diffuse surface (or nothing) first
/// and is never a caustic photon, so the test changes no output; it pays when rays miss, as
/// from a point light above a small glass, and is pure cost in a beam aimed at the glass.
fn cull_worth_it(scene: &Scene, e: &crate::scene::emitter::Emitter) -> bool {
    let misses = (0..16)
        .flat_map(|a| (0..16).map(move |b| ((a as f32 + 0.5) / 16.0, (b as f32 + 0.5) / 16.0)))
        .filter(|&(u, v)| !scene.may_meet_specular(&e.emit(u, v).0))
        .count();
    misses * 8 >= 256
}

struct Tracer<'a> {
    scene: &'a Scene,
    opts: &'a TraceOptions,
    table: EmitterTable,
    halton: Halton,
    dims: usize,
    /// Whether photons keep their emitter's number (the scene has several).
    emitter_column: bool,
    /// Per emitter: whether to test its emission rays against the box around the specular
    /// surfaces ([`Scene::may_meet_specular`]; see [`cull_worth_it`]).
    cull: Vec<bool>,
    /// Whether the processor has AVX: the photon loop then runs compiled for it ([`Tracer::chunk`]).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    avx: bool,
    /// The scene's power in watts (the emitters chosen in proportion to it).
    power_w: f64,
    /// The scene's dispersive dielectric when it has exactly one.
    dispersive: Option<&'a Dielectric>,
    /// Per emitter, the parameter component that holds the photon's wavelength (its spatial
    /// or directional dimensions come first) when the scene is spectral.
    wavelength_slot: Vec<Option<usize>>,
}

impl<'a> Tracer<'a> {
    /// The tracer of `scene` under `opts`: emitters chosen in proportion to power, the Halton
    /// sequence of the seed, and which emitters' rays are culled.
    fn new(scene: &'a Scene, opts: &'a TraceOptions) -> Self {
        let power: f64 = scene.emitters.iter().map(|e| e.power_w).sum();
        let mut acc = 0.0;
        let mut cdf: Vec<f32> = scene
            .emitters
            .iter()
            .map(|e| {
                acc += e.power_w;
                (acc / power) as f32
            })
            .collect();
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        let table = EmitterTable {
            cdf,
            colour: scene.emitters.iter().map(|e| e.colour / e.colour.element_sum()).collect(),
        };
        Tracer {
            scene,
            opts,
            table,
            halton: Halton::new(opts.seed),
            dims: scene.param_dims() as usize,
            wavelength_slot: scene
                .emitters
                .iter()
                .map(|e| scene.is_spectral().then(|| e.param_dims(false) as usize))
                .collect(),
            emitter_column: scene.emitters.len() > 1,
            cull: scene
                .emitters
                .iter()
                .map(|e| opts.store != StorePolicy::Direct && cull_worth_it(scene, e))
                .collect(),
            avx: crate::scene::bvh::avx_available(),
            power_w: power,
            dispersive: {
                let mut d = scene.materials.iter().filter_map(|m| match m {
                    Material::Dielectric(d) if d.dispersion.is_some() => Some(d),
                    _ => None,
                });
                d.next().filter(|_| d.next().is_none())
            },
        }
    }
}

impl Tracer<'_> {
    /// Traces `range` in chunks on rayon's pool into `store`, in emission order; returns the
    /// number of photons dropped at the bounce limit (in the chunks the store took).
    ///
    /// Chunks are traced in batches of [`BATCH_CHUNKS`] (nothing is sized by the whole range),
    /// tracing stops once the store is full, and the run stops with an error as soon as the
    /// photons it will store, extrapolated from those stored so far, are known not to fit
    /// ([`ChunkStore::check_room`]), not when memory or disk runs out.
    fn run(
        &self,
        range: Range<u64>,
        store: &mut ChunkStore,
        progress: &(dyn Fn(u64, u64) + Sync),
    ) -> Result<u64, TraceError> {
        let n_chunks = (range.end - range.start).div_ceil(CHUNK);
        let before = store.count();
        let mut limited = 0u64;
        let mut first = 0u64;
        while first < n_chunks && !store.is_full() {
            let last = (first + BATCH_CHUNKS).min(n_chunks);
            let out: Vec<(Chunk, u64)> = (first..last)
                .into_par_iter()
                .map_init(
                    || Scratch::new(self.dims),
                    |scratch, k| {
                        let a = range.start + k * CHUNK;
                        let b = (a + CHUNK).min(range.end);
                        let limited = self.chunk(a..b, scratch);
                        progress(b - a, scratch.len as u64);
                        (scratch.to_chunk(self.emitter_column), limited)
                    },
                )
                .collect();
            for (c, l) in out {
                if store.is_full() {
                    break;
                }
                limited += l;
                store.push(c)?;
            }
            first = last;
            // The Halton sequence spreads every batch over the whole emitter, so the rate so
            // far predicts the whole range's.
            let done = (range.start + first * CHUNK).min(range.end) - range.start;
            let projected = before as f64
                + (store.count() - before) as f64 * (range.end - range.start) as f64 / done.max(1) as f64;
            store.check_room(projected as u64, || format!("tracing {} photons", range.end - range.start))?;
        }
        Ok(limited)
    }

    /// Traces `range` into `out` (emptied first); returns the number dropped at the bounce limit.
    fn chunk(&self, range: Range<u64>, out: &mut Scratch) -> u64 {
        #[cfg(target_arch = "x86_64")]
        if self.avx {
            // SAFETY: `avx` says the processor has AVX.
            return unsafe { self.chunk_avx(range, out) };
        }
        self.chunk_any(range, out)
    }

    /// [`Self::chunk`] compiled for AVX: the photon loop, the intersections and the BVH's
    /// eight-triangle test (an AVX function, which a loop compiled without AVX can only call,
    /// not inline) become one body. The same operations in the same order (no fused
    /// multiply-add), so the same photons, faster (measured by benches/trace.rs; see
    /// BENCHMARKS.md).
    ///
    /// # Safety
    /// The processor must have AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn chunk_avx(&self, range: Range<u64>, out: &mut Scratch) -> u64 {
        self.chunk_any(range, out)
    }

    #[inline(always)]
    fn chunk_any(&self, range: Range<u64>, out: &mut Scratch) -> u64 {
        out.reset(range.start);
        let mut limited = 0;
        let mut halton = self.halton.run(range.start);
        // Without culling (as in a beam aimed at the glass) the loop has no test at all.
        if self.cull.contains(&true) {
            for i in range {
                limited += self.photon::<true>(i, halton.next_point(), out) as u64;
            }
        } else {
            for i in range {
                limited += self.photon::<false>(i, halton.next_point(), out) as u64;
            }
        }
        limited
    }

    /// Traces photon `index`, appending it to `out` if it is stored. Returns whether it was
    /// dropped at the bounce limit. `point` is the Halton point of `index`. With `CULL`, a
    /// photon of an emitter marked in [`Tracer::cull`] whose emission ray cannot meet a
    /// specular surface stops at once.
    #[inline(always)]
    fn photon<const CULL: bool>(&self, index: u64, point: [f32; 4], out: &mut Scratch) -> bool {
        let scene = self.scene;
        let [u0, u1, u2, u3] = point;
        let e = self.table.cdf.iter().position(|&c| u0 < c).unwrap_or(self.table.cdf.len() - 1);
        let (mut ray, [p0, p1, p2]) = scene.emitters[e].emit(u1, u2);
        let mut params = [p0, p1, p2, 0.0];
        if let Some(slot) = self.wavelength_slot[e] {
            params[slot] = wavelength_nm(u3);
        }
        if CULL && self.cull[e] && !scene.may_meet_specular(&ray) {
            return false; // it can never be a caustic photon
        }
        let mut flux = self.table.colour[e];
        let mut rng = PhotonRng::new(self.opts.seed, index);
        let mut wavelength: Option<f32> = None;
        // The dielectric met last, its index of refraction n at this photon's wavelength and
        // 1/n: a dispersion formula is evaluated once per photon and material, not per
        // interface, and the division off each entry's chain of dependent operations.
        // With one dispersive material in the scene its index is computed here, from the
        // Halton coordinate alone, where it overlaps the first ray's intersection instead of
        // following it (the same value as at the first hit: the same wavelength).
        let mut ior: Option<(&Dielectric, f32, f32)> =
            self.dispersive.map(|di| index_of_refraction(di, Some(wavelength_nm(u3))));
        let mut specular = 0u32;
        let mut path = 0.0f32;
        // Which shapes the ray can meet first (the emission ray: any).
        let mut reach = Reach::All;
        // The analytic surface the ray starts on (exactly, not offset), if any.
        let mut leaving: Option<u32> = None;
        loop {
            let found = match leaving {
                Some(s) => scene.intersect_leaving(&ray, reach, s, f32::INFINITY),
                None => scene.intersect_reach(&ray, reach, 0.0, f32::INFINITY),
            };
            let Some(hit) = found else { return false };
            path += hit.t;
            let p = ray.at(hit.t);
            // A continuing ray starts on an analytic surface exactly (a nearby surface, such
            // as the floor a sphere rests on, is then never skipped), on a mesh a ray offset
            // off it (`side` is the normal on the side it continues to).
            let analytic = scene.is_analytic(hit.shape);
            leaving = analytic.then_some(hit.shape);
            let start = |side: Vec3| if analytic { p } else { p + side * scene.ray_offset() };
            let front = ray.dir.dot(hit.normal) < 0.0;
            // Normals facing the side the photon came from.
            let ng = if front { hit.normal } else { -hit.normal };
            let ns = if front { hit.shading } else { -hit.shading };
            match scene.material(hit.shape) {
                Material::Diffuse { .. } => {
                    if specular > 0 || self.opts.store == StorePolicy::Direct {
                        out.push(Landing {
                            position: p,
                            normal: ng,
                            flux,
                            incident: ray.dir,
                            emitter: e as u16,
                            params,
                            path_length: path,
                            bounces: specular.min(255) as u8,
                            emission_offset: (index - out.first) as u16,
                            surface: hit.shape,
                        });
                    }
                    return false;
                }
                Material::Absorber => return false,
                Material::Mirror { reflectance } => {
                    if !roulette(&mut flux, *reflectance, &mut rng) {
                        return false;
                    }
                    let mut d = reflect(ray.dir, ns);
                    if d.dot(ng) <= 0.0 {
                        d = reflect(ray.dir, ng); // the shading normal would send it into the surface
                    }
                    // Renormalised: rounding would otherwise compound over the bounces.
                    ray = Ray::new(start(ng), d.normalize());
                    reach = scene.reach_after(hit.shape, p, ng, &ray);
                }
                Material::Dielectric(di) => {
                    if di.dispersion.is_some() && wavelength.is_none() {
                        let l = wavelength_nm(u3);
                        flux *= wavelength_rgb_tabulated(l);
                        wavelength = Some(l);
                    }
                    let (n, inv_n) = match ior {
                        Some((d, n, inv_n)) if std::ptr::eq(d, di) => (n, inv_n),
                        _ => {
                            let entry = index_of_refraction(di, wavelength);
                            ior = Some(entry);
                            (entry.1, entry.2)
                        }
                    };
                    let eta = if front { inv_n } else { n };
                    let mut normal = ns;
                    let mut refracted = refract_unnormalised(ray.dir, normal, eta);
                    if refracted.is_some_and(|r| r.dir.dot(ng) >= 0.0) || ray.dir.dot(normal) >= 0.0 {
                        // The shading normal disagrees with the geometry: use the facet's.
                        normal = ng;
                        refracted = refract_unnormalised(ray.dir, normal, eta);
                    }
                    let reflects = match refracted {
                        None => true,
                        Some(_) if di.ideal => false,
                        Some(r) => rng.next_f32() < fresnel_cosines(r.cos_i, r.cos_t, eta),
                    };
                    match refracted {
                        Some(r) if !reflects => {
                            if !roulette(&mut flux, di.tint, &mut rng) {
                                return false;
                            }
                            // Renormalised: rounding compounds over the interfaces otherwise
                            // (|d| off by 3e-3 after 8–10 bounces), and a stored direction
                            // must be unit.
                            ray = Ray::new(start(-ng), r.dir.normalize());
                            reach = scene.reach_after(hit.shape, p, -ng, &ray);
                        }
                        _ => {
                            let mut d = reflect(ray.dir, normal);
                            if d.dot(ng) <= 0.0 {
                                d = reflect(ray.dir, ng);
                            }
                            ray = Ray::new(start(ng), d.normalize());
                            reach = scene.reach_after(hit.shape, p, ng, &ray);
                        }
                    }
                }
            }
            specular += 1;
            if specular > self.opts.max_bounces {
                return true;
            }
        }
    }
}

/// The wavelength, nm, of a photon whose fourth Halton coordinate is `u3`: uniform on
/// [`WAVELENGTH_RANGE_NM`].
#[inline(always)]
fn wavelength_nm(u3: f32) -> f32 {
    let (lo, hi) = WAVELENGTH_RANGE_NM;
    lo + (hi - lo) * u3
}

/// A photon's cached entry for dielectric `di` at its wavelength: the material, n and 1/n.
#[inline(always)]
fn index_of_refraction(di: &Dielectric, wavelength_nm: Option<f32>) -> (&Dielectric, f32, f32) {
    let n = di.ior_at(wavelength_nm);
    (di, n, 1.0 / n)
}

/// Multiplies `flux` by the attenuation `a` and plays Russian roulette with survival
/// probability max(a), dividing the survivors' flux by it: the expected flux stays `flux·a`.
/// Returns whether the photon survives.
fn roulette(flux: &mut Vec3, a: Vec3, rng: &mut PhotonRng) -> bool {
    let p = a.max_element();
    if p >= 1.0 {
        *flux *= a;
        return true;
    }
    if p <= 0.0 || rng.next_f32() >= p {
        return false;
    }
    *flux *= a / p;
    true
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::path::Path;

    fn scene(src: &str) -> Scene {
        Scene::parse(src, "test.toml", Path::new(".")).unwrap()
    }

    fn run(s: &Scene, opts: &TraceOptions) -> Traced {
        trace(s, opts, &|_, _| {}).unwrap()
    }

    /// `opts` with a spool in `dir` that holds `memory` bytes of photons in memory.
    fn spooled(opts: &TraceOptions, dir: &Path, memory: u64) -> TraceOptions {
        TraceOptions { spool: Some(Spool { dir: dir.to_path_buf(), memory }), ..opts.clone() }
    }

    #[test]
    fn retain_bounces_keeps_exactly_the_photons_of_those_paths_with_their_columns() {
        let s = Scene::default_scene();
        let dir = tempfile::tempdir().unwrap();
        let opts = TraceOptions { budget: Budget::Emitted(20_000), ..TraceOptions::default() };
        let all = run(&s, &opts).photons().unwrap();
        // In memory, and spooled but for the last chunks.
        for opts in [opts.clone(), spooled(&opts, dir.path(), 100_000)] {
            let mut kept = run(&s, &opts);
            assert_eq!(kept.store.spooled_count() > 0, opts.spool.is_some());
            kept.retain_bounces(&[2]).unwrap();
            let k = kept.photons().unwrap();
            let want: Vec<usize> = (0..all.len()).filter(|&i| all.bounces[i] == 2).collect();
            assert!(!want.is_empty() && want.len() < all.len(), "the default scene has other paths too");
            assert_eq!(kept.stored as usize, want.len());
            assert_eq!(k.len(), want.len());
            let d = s.param_dims() as usize;
            for (j, &i) in want.iter().enumerate() {
                assert_eq!(k.emission_index[j], all.emission_index[i]);
                assert_eq!(k.position[j], all.position[i]);
                assert_eq!(k.flux[j], all.flux[i], "flux is not renormalised");
                assert_eq!(k.params[j * d..(j + 1) * d], all.params[i * d..(i + 1) * d]);
                assert_eq!(k.surface[j], all.surface[i]);
            }
        }
    }

    /// Photons spooled to disk (every one, or all but the last chunks) come back as a run
    /// holding them in memory has them: the same photons and the same file byte for byte,
    /// for either budget and with several emitters; the spool's files have no name, so the
    /// directory holds only what was written.
    #[test]
    fn spooled_photons_are_the_photons_held_in_memory() {
        let dir = tempfile::tempdir().unwrap();
        // The default scene with a second emitter (a point light above the ball): an
        // emitter column and three trajectory parameters.
        let two = crate::scene::DEFAULT_SCENE.to_string()
            + "[[emitters]]\nkind = \"point\"\nposition = [0.3, 0.0, 1.5]\npower_w = 5.0\n";
        for (scene, budget) in [
            (Scene::default_scene(), Budget::Emitted(100_000)),
            (Scene::default_scene(), Budget::Stored(30_000)),
            (scene(&two), Budget::Emitted(100_000)),
        ] {
            let opts = TraceOptions { budget, ..TraceOptions::default() };
            let held = run(&scene, &opts);
            assert_eq!(held.store.spooled_count(), 0);
            assert_eq!(held.emitter_column, scene.emitters.len() > 1);
            let info = map_info(&scene, &opts, &held, "default", "");
            let want = dir.path().join("held.phm");
            held.write(Output::Path(want.clone()), info.clone()).unwrap();
            for memory in [1, held.stored * 30] {
                let t = run(&scene, &spooled(&opts, dir.path(), memory));
                assert!(t.store.spooled_count() > 0);
                assert_eq!(memory == 1, t.store.spooled_count() == t.stored, "memory {memory}");
                assert_eq!(
                    (t.stored, t.emitted, t.range.clone()),
                    (held.stored, held.emitted, held.range.clone())
                );
                assert_eq!(t.bounce_limited, held.bounce_limited);
                assert_eq!(t.photons().unwrap(), held.photons().unwrap(), "{budget:?}, memory {memory}");
                let got = dir.path().join("spooled.phm");
                t.write(Output::Path(got.clone()), info.clone()).unwrap();
                assert!(
                    std::fs::read(&got).unwrap() == std::fs::read(&want).unwrap(),
                    "{budget:?}, memory {memory}"
                );
                let mut names: Vec<_> =
                    std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
                names.sort();
                assert_eq!(names, ["held.phm", "spooled.phm"]);
            }
        }
    }

    /// A glass slab (0.2 m thick) between a collimated beam and the floor, in a closed world.
    pub(crate) fn slab(ideal: bool, ior: f32) -> String {
        format!(
            r#"
[materials.floor]
kind = "diffuse"
[materials.glass]
kind = "dielectric"
ior = {ior}
ideal = {ideal}
[[emitters]]
kind = "collimated"
center = [0, 0, 2]
size = [1, 1]
direction = [0, 0, -1]
power_w = 6
[[shapes]]
kind = "plane"
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "extrusion"
outline = [[-2, -2], [2, -2], [2, 2], [-2, 2]]
z_range = [0.5, 0.7]
material = "glass"
"#
        )
    }

    /// The photon loop compiled for AVX ([`Tracer::chunk`]) and without ([`Tracer::chunk_any`])
    /// store the same photons, bit for bit, on sample scenes with a small mesh (the prism's
    /// eight triangles: the AVX pair test inlined), a large one (the water, through the
    /// hierarchy) and none. (Without AVX there is nothing to compare.)
    #[test]
    fn the_loop_compiled_for_avx_stores_the_same_photons() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/scenes");
        for name in ["prism", "water", "ring", "point-glass"] {
            let scene = Scene::load(&dir.join(format!("{name}.toml"))).unwrap();
            let opts = TraceOptions::default();
            let mut tracer = Tracer::new(&scene, &opts);
            if !tracer.avx {
                return;
            }
            let (mut with, mut without) = (Scratch::new(tracer.dims), Scratch::new(tracer.dims));
            let range = 3 * CHUNK..4 * CHUNK;
            let limited = tracer.chunk(range.clone(), &mut with);
            tracer.avx = false;
            assert_eq!(tracer.chunk(range, &mut without), limited);
            let (with, without) = (with.to_chunk(true), without.to_chunk(true));
            assert!(with.len() > 100, "{name}: {} stored", with.len());
            assert!(with == without, "{name}: the two loops stored different photons");
        }
    }

    /// Prefaulting maps pages without touching what they hold: a vector's contents, and its
    /// neighbours' on the pages the range is widened to, stay as they were.
    #[test]
    fn prefaulting_leaves_memory_as_it_was() {
        let data: Vec<u64> = (0..10_000u64).map(|i| i.wrapping_mul(0x9E37_79B9_7F4A_7C15)).collect();
        let before = data.clone();
        prefault(data.as_ptr().wrapping_add(100) as *mut u8, 8 * 5_000);
        assert_eq!(data, before);
        let copied = copy(&data);
        assert_eq!(copied, before);
    }

    #[test]
    fn shards_cover_the_range_exactly() {
        let n = 1_000_003;
        let mut next = 0;
        for i in 0..7 {
            let r = Shard { index: i, count: 7 }.range(n);
            assert_eq!(r.start, next);
            next = r.end;
        }
        assert_eq!(next, n);
    }

    #[test]
    fn roulette_is_unbiased() {
        let mut rng = PhotonRng::new(9, 9);
        let a = Vec3::new(0.5, 0.25, 0.1);
        let n = 200_000;
        let mut sum = Vec3::ZERO;
        for _ in 0..n {
            let mut f = Vec3::ONE;
            if roulette(&mut f, a, &mut rng) {
                sum += f;
            }
        }
        let mean = sum / n as f32;
        assert!((mean - a).abs().max_element() < 0.005, "{mean}");
    }

    #[test]
    fn ideal_slab_passes_the_whole_beam_with_uniform_density() {
        let s = scene(&slab(true, 1.5));
        let t = run(&s, &TraceOptions { budget: Budget::Emitted(40_000), ..Default::default() });
        let p = t.photons().unwrap();
        assert_eq!(p.len(), 40_000, "every photon crosses the slab");
        let total: f64 = p.flux.iter().flatten().map(|&f| f as f64).sum();
        assert!((total - 6.0).abs() < 1e-4, "{total}");
        assert!(p.bounces.iter().all(|&b| b == 2));
        // Normal incidence: the beam lands where it started, one photon per cell of a 10×10 grid
        // within 15 % (Halton points are far more even than random ones).
        let mut cells = [0u32; 100];
        for q in &p.position {
            assert!(q[0].abs() <= 0.5 + 1e-4 && q[1].abs() <= 0.5 + 1e-4 && q[2].abs() < 1e-5);
            let (i, j) = (((q[0] + 0.5) * 10.0).min(9.0) as usize, ((q[1] + 0.5) * 10.0).min(9.0) as usize);
            cells[j * 10 + i] += 1;
        }
        assert!(cells.iter().all(|&c| (340..=460).contains(&c)), "{cells:?}");
        // Trajectory parameters are the landing point: (u, v) = (x + ½, y + ½).
        for (q, uv) in p.position.iter().zip(p.params.chunks(2)) {
            assert!((q[0] + 0.5 - uv[0]).abs() < 1e-4 && (q[1] + 0.5 - uv[1]).abs() < 1e-4);
        }
    }

    #[test]
    fn fresnel_slab_transmits_the_two_interface_fraction() {
        // Normal incidence, n = 1.5: each interface reflects R = 0.04. With the multiple
        // reflections inside the slab, the transmitted fraction is (1 − R)/(1 + R).
        let s = scene(&slab(false, 1.5));
        let n = 200_000;
        let t = run(&s, &TraceOptions { budget: Budget::Emitted(n), seed: 5, ..Default::default() });
        let total: f64 = t.photons().unwrap().flux.iter().flatten().map(|&f| f as f64).sum();
        let expected = 6.0 * (1.0 - 0.04) / (1.0 + 0.04);
        // Binomial noise: σ ≈ 6·sqrt(T(1−T)/n) ≈ 0.0036.
        assert!((total - expected).abs() < 0.015, "{total} vs {expected}");
    }

    #[test]
    fn stored_budget_stops_at_the_photon_count() {
        let s = scene(&slab(false, 1.5));
        let t = run(&s, &TraceOptions { budget: Budget::Stored(5000), ..Default::default() });
        let p = t.photons().unwrap();
        assert_eq!(p.len(), 5000);
        assert_eq!(t.emitted, p.emission_index[4999] + 1);
        // The same photons as an emitted budget of that size.
        let u = run(&s, &TraceOptions { budget: Budget::Emitted(t.emitted), ..Default::default() })
            .photons()
            .unwrap();
        assert_eq!(p, u);
    }

    #[test]
    fn direct_photons_are_stored_only_on_request() {
        let src = slab(true, 1.5)
            .replace("[-2, -2], [2, -2], [2, 2], [-2, 2]", "[-2, -2], [0, -2], [0, 2], [-2, 2]");
        let s = scene(&src);
        let c = run(&s, &TraceOptions { budget: Budget::Emitted(10_000), ..Default::default() })
            .photons()
            .unwrap();
        let d = run(
            &s,
            &TraceOptions {
                budget: Budget::Emitted(10_000),
                store: StorePolicy::Direct,
                ..Default::default()
            },
        )
        .photons()
        .unwrap();
        // Half the beam misses the half-slab.
        assert!((c.len() as f64 / 5000.0 - 1.0).abs() < 0.01, "{}", c.len());
        assert_eq!(d.len(), 10_000);
        assert!(d.bounces.iter().filter(|&&b| b == 0).count() == d.len() - c.len());
    }

    #[test]
    fn mirror_losses_are_unbiased_under_russian_roulette() {
        let src = r#"
[materials.floor]
kind = "diffuse"
[materials.metal]
kind = "mirror"
reflectance = [0.9, 0.5, 0.2]
[[emitters]]
kind = "collimated"
center = [0, 0, 1]
size = [1, 1]
direction = [0, 0, 1]
power_w = 3
[[shapes]]
kind = "plane"
point = [0, 0, 0]
normal = [0, 0, 1]
material = "floor"
[[shapes]]
kind = "plane"
point = [0, 0, 2]
normal = [0, 0, -1]
material = "metal"
"#;
        let t = run(&scene(src), &TraceOptions { budget: Budget::Emitted(100_000), ..Default::default() });
        let p = t.photons().unwrap();
        let mut sum = [0.0f64; 3];
        for f in &p.flux {
            for k in 0..3 {
                sum[k] += f[k] as f64;
            }
        }
        // Each channel carries 1 W, times its reflectance.
        for (k, r) in [0.9, 0.5, 0.2].iter().enumerate() {
            assert!((sum[k] - r).abs() < 0.01, "channel {k}: {} vs {r}", sum[k]);
        }
    }

    #[test]
    fn output_is_the_same_on_one_and_two_threads() {
        let s = Scene::default_scene();
        let opts = TraceOptions { budget: Budget::Emitted(30_000), seed: 3, ..Default::default() };
        let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        let a = pool(1).install(|| run(&s, &opts)).photons().unwrap();
        let b = pool(2).install(|| run(&s, &opts)).photons().unwrap();
        assert!(a.len() > 1000);
        assert_eq!(a, b);
        let c = run(&s, &TraceOptions { seed: 4, ..opts }).photons().unwrap();
        assert_ne!(a, c);
    }
}
