//! Chunked parallel emission: consecutive emission numbers traced a chunk at a time on rayon's
//! pool, each worker writing its photons into a reused [`Scratch`], the chunks handed to the
//! store in emission order, batch by batch.

use std::ops::Range;

use rayon::prelude::*;

use super::store::{Chunk, ChunkStore};
use super::{CHUNK, Landing, TraceError, Tracer};

/// Chunks traced in parallel between two hand-overs to the store and checks of the room
/// left (1 M emission numbers: the photons in flight take tens of MB).
const BATCH_CHUNKS: u64 = 256;

const CHUNK_LEN: usize = CHUNK as usize;

/// A worker's chunk under construction, reused chunk after chunk: columns with room for a
/// photon per emission number of a chunk, written in place under one count (no length and
/// capacity per column to check and update, no copy call for the parameters).
pub(super) struct Scratch {
    pub(super) first: u64,
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
    pub(super) fn new(dims: usize) -> Scratch {
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
    pub(super) fn push(&mut self, p: Landing) {
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
    pub(super) fn to_chunk(&self, emitter_column: bool) -> Chunk {
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
pub(super) fn copy<T: Copy>(v: &[T]) -> Vec<T> {
    let mut out = Vec::with_capacity(v.len());
    prefault(out.as_mut_ptr() as *mut u8, std::mem::size_of_val(v));
    out.extend_from_slice(v);
    out
}

/// Asks the kernel to map the pages spanning `len` bytes from `p` writable now
/// (`MADV_POPULATE_WRITE`, Linux 5.14): contents unchanged, pages already mapped untouched.
/// On older kernels and other systems the pages fault in on first write as usual.
pub(super) fn prefault(p: *mut u8, len: usize) {
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

impl Tracer<'_> {
    /// Traces `range` in chunks on rayon's pool into `store`, in emission order; returns the
    /// number of photons dropped at the bounce limit (in the chunks the store took).
    ///
    /// Chunks are traced in batches of [`BATCH_CHUNKS`] (nothing is sized by the whole range),
    /// tracing stops once the store is full, and the run stops with an error as soon as the
    /// photons it will store, extrapolated from those stored so far, are known not to fit
    /// ([`ChunkStore::check_room`]), not when memory or disk runs out.
    pub(super) fn run(
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
    pub(super) fn chunk(&self, range: Range<u64>, out: &mut Scratch) -> u64 {
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
}
