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

mod chunks;
mod merge;
mod output;
mod store;
#[cfg(test)]
pub(crate) mod tests;
mod walk;

use std::ops::Range;

use glam::Vec3;

use crate::format::FormatError;
pub use crate::sampling::halton;
use crate::scene::{Dielectric, Material, Scene};
use halton::Halton;
pub use merge::merge;
pub use output::{Traced, map_info, record_scene_location, source_date};
use store::{ChunkStore, Layout};
pub use store::{DEFAULT_SPOOL_MEMORY, Spool};

/// Emission numbers per unit of parallel work.
pub const CHUNK: u64 = 4096;

/// Everything that can go wrong while tracing or merging.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TraceError {
    /// Reading a shard or writing the map failed.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// A shard index not below the shard count.
    #[error("shard {index}/{count}: needs 0 ≤ i < n")]
    BadShard {
        /// The shard asked for.
        index: u64,
        /// The number of shards.
        count: u64,
    },
    /// A storage budget with a shard: a shard's range of emission numbers is fixed in advance.
    #[error("--stored cannot be combined with --shard: a shard traces a fixed range of emission numbers")]
    StoredWithShard,
    /// A storage budget that stored nothing in the first 50 million emissions.
    #[error(
        "no photon was stored after {emitted} emitted: does light reach a diffuse surface by way of \
         a mirror or dielectric? (--store direct stores direct hits too)"
    )]
    NothingStored {
        /// Photons emitted before giving up.
        emitted: u64,
    },
    /// Shards that do not make one run.
    #[error("{file}: cannot merge: {message}")]
    Merge {
        /// The shard as named to the user.
        file: String,
        /// How it differs from the others.
        message: String,
    },
    /// The stored photons would not fit in memory.
    #[error(
        "{what} would need about {need_gb:.1} GB for the stored photons, more than the {avail_gb:.1} GB of memory \
         available: trace fewer photons, lower `trace --memory`, or split the run with --shard i/n and join the shards with `photonkit merge`"
    )]
    OutOfMemory {
        /// The run, as the message names it.
        what: String,
        /// Memory needed, GB.
        need_gb: f64,
        /// Memory available, GB.
        avail_gb: f64,
    },
    /// The spooled photons and the output would not fit on disk.
    #[error(
        "{what} would need about {need_gb:.1} GB of disk for the stored photons (spooled, then the output), \
         more than the {avail_gb:.1} GB free in {dir}: trace fewer photons, write to a larger disk, or split the \
         run with --shard i/n and join the shards with `photonkit merge`"
    )]
    OutOfDisk {
        /// The run, as the message names it.
        what: String,
        /// Disk needed, GB.
        need_gb: f64,
        /// Disk free, GB.
        avail_gb: f64,
        /// The folder the spool is in.
        dir: String,
    },
    /// Writing or reading the spool failed.
    #[error("spooling stored photons in {dir}: {source}")]
    Spool {
        /// The folder the spool is in.
        dir: String,
        /// What the system said.
        source: std::io::Error,
    },
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
    /// Which slice, from 0.
    pub index: u64,
    /// How many slices.
    pub count: u64,
}

impl Shard {
    /// The emission numbers of this shard out of `total`.
    pub fn range(&self, total: u64) -> Range<u64> {
        let at = |k: u64| (total as u128 * k as u128 / self.count as u128) as u64;
        at(self.index)..at(self.index + 1)
    }
}

/// How a trace runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TraceOptions {
    /// The seed of the emission sequence's rotation and of the per-photon random streams
    /// ([`crate::sampling`]).
    pub seed: u64,
    /// What to trace until.
    pub budget: Budget,
    /// Which photons are stored.
    pub store: StorePolicy,
    /// The slice of the emission numbers to trace; `None`: all of them.
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
    /// Where each photon landed, metres.
    pub position: Vec<[f32; 3]>,
    /// The unit geometric normal there (on the side the photon arrived from).
    pub normal: Vec<[f32; 3]>,
    /// RGB flux.
    pub flux: Vec<[f32; 3]>,
    /// Unit direction of travel when it arrived.
    pub incident: Vec<[f32; 3]>,
    /// Index of its emitter in the scene.
    pub emitter: Vec<u16>,
    /// `param_dims` values per photon.
    pub params: Vec<f32>,
    /// Length of the path from the emitter, metres.
    pub path_length: Vec<f32>,
    /// Specular interactions on the path.
    pub bounces: Vec<u8>,
    /// The photon's number in the emission sequence.
    pub emission_index: Vec<u64>,
    /// The scene surface it lies on ([`Scene::surfaces`]).
    pub surface: Vec<u32>,
}

impl Photons {
    /// Number of photons.
    pub fn len(&self) -> usize {
        self.position.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }
}

/// One stored photon, as [`Scratch::push`](chunks::Scratch::push) takes it.
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

/// Traces the emission numbers `range` of `scene` (the budget and shard of `opts` are not
/// used), every photon's flux the scene's power over the range's length: a pass of a
/// progressive method that continues the emission sequence where an earlier run stopped, so
/// its photons are new and the run stays deterministic.
pub fn trace_range(
    scene: &Scene,
    opts: &TraceOptions,
    range: Range<u64>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Traced, TraceError> {
    let tracer = Tracer::new(scene, opts);
    let layout = Layout { dims: tracer.dims, emitter_column: tracer.emitter_column };
    let mut store = ChunkStore::new(layout, opts.spool.clone(), None);
    let bounce_limited = tracer.run(range.clone(), &mut store, progress)?;
    Ok(Traced {
        stored: store.count(),
        store,
        param_dims: scene.param_dims(),
        emitter_column: tracer.emitter_column,
        emitted: range.end - range.start,
        range,
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
        let power: f64 = scene.emitters().iter().map(|e| e.power_w).sum();
        let mut acc = 0.0;
        let mut cdf: Vec<f32> = scene
            .emitters()
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
            colour: scene.emitters().iter().map(|e| e.colour / e.colour.element_sum()).collect(),
        };
        Tracer {
            scene,
            opts,
            table,
            halton: Halton::new(opts.seed),
            dims: scene.param_dims() as usize,
            wavelength_slot: scene
                .emitters()
                .iter()
                .map(|e| scene.is_spectral().then(|| e.param_dims(false) as usize))
                .collect(),
            emitter_column: scene.emitters().len() > 1,
            cull: scene
                .emitters()
                .iter()
                .map(|e| opts.store != StorePolicy::Direct && cull_worth_it(scene, e))
                .collect(),
            avx: crate::scene::bvh::avx_available(),
            power_w: power,
            dispersive: {
                let mut d = scene.materials().iter().filter_map(|m| match m {
                    Material::Dielectric(d) if d.dispersion.is_some() => Some(d),
                    _ => None,
                });
                d.next().filter(|_| d.next().is_none())
            },
        }
    }
}
