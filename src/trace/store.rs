//! Where the tracer keeps its stored photons until they are written.
//!
//! Chunks stay in memory up to a limit. Past it, with a [`Spool`], they are appended column by
//! column to unnamed temporary files in the spool's directory (the output's, so the photons go
//! to the disk the user chose) and read back once, in order, when the map is written: memory
//! stays bounded whatever the photon count, and the written map is the same byte for byte.
//! The files have no name, so the system removes them however the process ends (SIGKILL
//! included). Requests that cannot fit are refused early: in memory against what the system
//! has available, spooled against the free space of the spool's file system.

use std::fs::File;
use std::io::Write;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::{CHUNK, Photons, TraceError};
use crate::format::{ColumnSpec, DType, name};

/// Where stored photons go once those held in memory take more than `memory` bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Spool {
    /// Directory of the unnamed temporary files (normally the output's).
    pub dir: PathBuf,
    /// Bytes of stored photons held in memory before they are spooled.
    pub memory: u64,
}

/// The default [`Spool::memory`]: 256 MiB, about four million photons.
pub const DEFAULT_SPOOL_MEMORY: u64 = 256 << 20;

/// Photons read back from the spool at a time.
const BLOCK: u64 = 1 << 16;

/// One chunk's stored photons as the tracer keeps them until they are written: the columns of
/// [`Photons`], but each emission number as its offset from the chunk's first (a chunk spans
/// [`CHUNK`] ≤ 2¹⁶ numbers) and no emitter column when the scene has one emitter: 67 bytes
/// per prism photon instead of 75, fewer fresh pages to fill.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Chunk {
    /// Emission number the offsets count from.
    pub first: u64,
    pub position: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
    pub flux: Vec<[f32; 3]>,
    pub incident: Vec<[f32; 3]>,
    /// Empty when the map has no emitter column.
    pub emitter: Vec<u16>,
    pub params: Vec<f32>,
    pub path_length: Vec<f32>,
    pub bounces: Vec<u8>,
    pub emission_offset: Vec<u16>,
    pub surface: Vec<u32>,
}

const _: () = assert!(CHUNK <= 1 << 16, "emission offsets within a chunk are 16-bit");

impl Chunk {
    pub fn len(&self) -> usize {
        self.position.len()
    }

    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }

    /// Emission number of photon `i`.
    pub fn emission_index(&self, i: usize) -> u64 {
        self.first + self.emission_offset[i] as u64
    }

    pub fn truncate(&mut self, n: usize, dims: usize) {
        self.position.truncate(n);
        self.normal.truncate(n);
        self.flux.truncate(n);
        self.incident.truncate(n);
        self.emitter.truncate(n);
        self.params.truncate(n * dims);
        self.path_length.truncate(n);
        self.bounces.truncate(n);
        self.emission_offset.truncate(n);
        self.surface.truncate(n);
    }

    /// Keeps the photons whose `keep` is true.
    pub fn retain(&mut self, keep: &[bool], dims: usize) {
        fn filter<T: Copy>(v: &mut Vec<T>, keep: &[bool], per: usize) {
            let mut i = 0;
            v.retain(|_| {
                let k = keep[i / per];
                i += 1;
                k
            });
        }
        filter(&mut self.position, keep, 1);
        filter(&mut self.normal, keep, 1);
        filter(&mut self.flux, keep, 1);
        filter(&mut self.incident, keep, 1);
        filter(&mut self.emitter, keep, 1);
        if dims > 0 {
            filter(&mut self.params, keep, dims);
        }
        filter(&mut self.path_length, keep, 1);
        filter(&mut self.bounces, keep, 1);
        filter(&mut self.emission_offset, keep, 1);
        filter(&mut self.surface, keep, 1);
    }
}

/// Which columns a traced map has.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    /// Trajectory parameters per photon.
    pub dims: usize,
    /// Whether photons keep their emitter's number (the scene has several emitters).
    pub emitter_column: bool,
}

impl Layout {
    /// The columns written, in order (the spool keeps the same, flux relative).
    pub fn column_specs(&self) -> Vec<ColumnSpec> {
        let mut c = vec![
            ColumnSpec::of::<[f32; 3]>(name::POSITION),
            ColumnSpec::of::<[f32; 3]>(name::NORMAL),
            ColumnSpec::of::<[f32; 3]>(name::FLUX),
            ColumnSpec::of::<[f32; 3]>(name::INCIDENT),
        ];
        if self.emitter_column {
            c.push(ColumnSpec::of::<u16>(name::EMITTER));
        }
        if self.dims > 0 {
            c.push(ColumnSpec::new(name::PARAMS, DType::F32, self.dims as u32));
        }
        c.push(ColumnSpec::of::<f32>(name::PATH_LENGTH));
        c.push(ColumnSpec::of::<u8>(name::BOUNCES));
        c.push(ColumnSpec::of::<u64>(name::EMISSION_INDEX));
        c.push(ColumnSpec::of::<u32>(name::SURFACE));
        c
    }

    /// Bytes one stored photon takes in memory (its columns in a [`Chunk`]).
    pub fn memory_bytes(&self) -> u64 {
        // position, normal, flux, incident (4 × 12), path length and surface (2 × 4), bounces,
        // emission offset (2), emitter (2), and the trajectory parameters.
        (48 + 8 + 1 + 2 + 2 + 4 * self.dims) as u64
    }

    /// Bytes one photon takes in the file (and in the spool).
    pub fn file_bytes(&self) -> u64 {
        self.column_specs().iter().map(ColumnSpec::stride).sum()
    }

    /// Chunk `c`'s columns as the file holds them, given its flux and absolute emission
    /// numbers (which the caller computes).
    fn columns<'a>(&self, c: &'a Chunk, flux: &'a [[f32; 3]], emission_index: &'a [u64]) -> Vec<&'a [u8]> {
        let mut cols: Vec<&[u8]> = vec![
            bytemuck::cast_slice(&c.position),
            bytemuck::cast_slice(&c.normal),
            bytemuck::cast_slice(flux),
            bytemuck::cast_slice(&c.incident),
        ];
        if self.emitter_column {
            cols.push(bytemuck::cast_slice(&c.emitter));
        }
        if self.dims > 0 {
            cols.push(bytemuck::cast_slice(&c.params));
        }
        cols.push(bytemuck::cast_slice(&c.path_length));
        cols.push(bytemuck::cast_slice(&c.bounces));
        cols.push(bytemuck::cast_slice(emission_index));
        cols.push(bytemuck::cast_slice(&c.surface));
        cols
    }
}

/// Photons moved out of memory: one unnamed file per column of [`Layout::column_specs`],
/// flux relative, emission numbers absolute.
#[derive(Debug)]
struct Spooled {
    files: Vec<File>,
    count: u64,
}

/// The stored photons of a run, in emission order: the first `spooled.count` in the spool,
/// the rest in memory.
#[derive(Debug)]
pub(super) struct ChunkStore {
    layout: Layout,
    chunks: Vec<Chunk>,
    /// Bytes of `chunks`.
    held: u64,
    spool: Option<Spool>,
    spooled: Option<Spooled>,
    /// At most this many photons are kept ([`super::Budget::Stored`]); later ones are dropped.
    limit: Option<u64>,
    count: u64,
    /// Emission number of the last photon kept.
    last_index: Option<u64>,
    /// Memory the photons may take (80 % of what the system has available), if known.
    memory_avail: Option<u64>,
    /// Free space in the spool's directory, if spooling and known.
    disk_avail: Option<u64>,
}

impl ChunkStore {
    pub fn new(layout: Layout, spool: Option<Spool>, limit: Option<u64>) -> Self {
        let disk_avail = spool.as_ref().and_then(|s| disk_budget(&s.dir));
        ChunkStore {
            layout,
            chunks: Vec::new(),
            held: 0,
            spool,
            spooled: None,
            limit,
            count: 0,
            last_index: None,
            memory_avail: memory_budget(),
            disk_avail,
        }
    }

    /// Photons kept so far.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Photons in the spool.
    #[cfg(test)]
    pub fn spooled_count(&self) -> u64 {
        self.spooled.as_ref().map_or(0, |s| s.count)
    }

    /// Whether the limit is reached: later chunks would be dropped.
    pub fn is_full(&self) -> bool {
        self.limit.is_some_and(|l| self.count >= l)
    }

    /// Emission number of the last photon kept.
    pub fn last_index(&self) -> Option<u64> {
        self.last_index
    }

    /// Keeps chunk `c` (the next in emission order), cut at the limit; spools everything held
    /// in memory once it passes the spool's limit.
    pub fn push(&mut self, mut c: Chunk) -> Result<(), TraceError> {
        if let Some(l) = self.limit {
            let room = l.saturating_sub(self.count);
            if (c.len() as u64) > room {
                c.truncate(room as usize, self.layout.dims);
            }
        }
        if c.is_empty() {
            return Ok(());
        }
        self.last_index = Some(c.emission_index(c.len() - 1));
        self.count += c.len() as u64;
        self.held += c.len() as u64 * self.layout.memory_bytes();
        self.chunks.push(c);
        if self.spool.as_ref().is_some_and(|s| self.held > s.memory) {
            self.spool_held()?;
        }
        Ok(())
    }

    /// Refuses a run whose photons, `projected` in all, would not fit: those held in memory
    /// (all of them without a spool) in the memory available, and with a spool, the spooled
    /// photons and the output beside them on its disk.
    pub fn check_room(&self, projected: u64, what: impl Fn() -> String) -> Result<(), TraceError> {
        let projected = self.limit.map_or(projected, |l| projected.min(l));
        let bytes = self.layout.memory_bytes();
        let held = self.spool.as_ref().map_or(projected, |s| projected.min(s.memory / bytes));
        let need = held as f64 * bytes as f64;
        if let Some(avail) = self.memory_avail
            && need > avail as f64
        {
            return Err(TraceError::OutOfMemory {
                what: what(),
                need_gb: need / 1e9,
                avail_gb: avail as f64 / 1e9,
            });
        }
        if let (Some(s), Some(avail)) = (&self.spool, self.disk_avail) {
            let need = (projected as f64 + (projected - held) as f64) * self.layout.file_bytes() as f64;
            if need > avail as f64 {
                return Err(TraceError::OutOfDisk {
                    what: what(),
                    need_gb: need / 1e9,
                    avail_gb: avail as f64 / 1e9,
                    dir: s.dir.display().to_string(),
                });
            }
        }
        Ok(())
    }

    fn spool_error(&self, source: std::io::Error) -> TraceError {
        let dir = self.spool.as_ref().map_or_else(String::new, |s| s.dir.display().to_string());
        TraceError::Spool { dir, source }
    }

    /// One unnamed file per column in the spool's directory.
    fn new_spool_files(&self) -> Result<Vec<File>, TraceError> {
        let dir = self.spool.as_ref().map(|s| s.dir.clone()).unwrap_or_default();
        (0..self.layout.column_specs().len())
            .map(|_| tempfile::tempfile_in(&dir))
            .collect::<Result<_, _>>()
            .map_err(|e| self.spool_error(e))
    }

    /// Moves every chunk held in memory to the end of the spool.
    fn spool_held(&mut self) -> Result<(), TraceError> {
        if self.spooled.is_none() {
            self.spooled = Some(Spooled { files: self.new_spool_files()?, count: 0 });
        }
        let mut index = Vec::new();
        for c in std::mem::take(&mut self.chunks) {
            index.clear();
            index.extend((0..c.len()).map(|i| c.emission_index(i)));
            let cols = self.layout.columns(&c, &c.flux, &index);
            let spooled = self.spooled.as_mut().expect("opened above");
            for (mut f, b) in spooled.files.iter().zip(cols) {
                if let Err(e) = f.write_all(b) {
                    return Err(self.spool_error(e));
                }
            }
            spooled.count += c.len() as u64;
        }
        self.held = 0;
        Ok(())
    }

    /// Calls `f` with the photons' columns as the file holds them (flux multiplied by
    /// `flux_scale`), a block at a time, in emission order.
    pub fn for_each_block(
        &self,
        flux_scale: f64,
        mut f: impl FnMut(&[&[u8]]) -> Result<(), TraceError>,
    ) -> Result<(), TraceError> {
        self.for_each_spooled_block(flux_scale, &mut f)?;
        let (mut flux, mut index) = (Vec::new(), Vec::new());
        for c in &self.chunks {
            flux.clear();
            flux.extend(c.flux.iter().map(|v| scaled(*v, flux_scale)));
            index.clear();
            index.extend((0..c.len()).map(|i| c.emission_index(i)));
            f(&self.layout.columns(c, &flux, &index))?;
        }
        Ok(())
    }

    /// [`Self::for_each_block`] over the spooled photons only.
    fn for_each_spooled_block(
        &self,
        flux_scale: f64,
        mut f: impl FnMut(&[&[u8]]) -> Result<(), TraceError>,
    ) -> Result<(), TraceError> {
        let Some(s) = &self.spooled else { return Ok(()) };
        let specs = self.layout.column_specs();
        let flux_at = specs.iter().position(|c| c.name == name::FLUX).expect("a flux column");
        let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); specs.len()];
        let mut flux: Vec<[f32; 3]> = Vec::new();
        let mut at = 0;
        while at < s.count {
            let n = BLOCK.min(s.count - at);
            for ((file, buf), spec) in s.files.iter().zip(&mut bufs).zip(&specs) {
                buf.resize((n * spec.stride()) as usize, 0);
                file.read_exact_at(buf, at * spec.stride()).map_err(|e| self.spool_error(e))?;
            }
            flux.clear();
            flux.extend(
                bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(&bufs[flux_at])
                    .into_iter()
                    .map(|v| scaled(v, flux_scale)),
            );
            let mut cols: Vec<&[u8]> = bufs.iter().map(Vec::as_slice).collect();
            cols[flux_at] = bytemuck::cast_slice(&flux);
            f(&cols)?;
            at += n;
        }
        Ok(())
    }

    /// All photons as columns, flux multiplied by `flux_scale`.
    pub fn photons(&self, flux_scale: f64) -> Result<Photons, TraceError> {
        let mut all = Photons::default();
        let emitter_column = self.layout.emitter_column;
        let dims = self.layout.dims;
        self.for_each_block(flux_scale, |cols| {
            let mut cols = cols.iter();
            let mut next = || *cols.next().expect("a column per spec");
            all.position.extend(bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(next()));
            all.normal.extend(bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(next()));
            all.flux.extend(bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(next()));
            all.incident.extend(bytemuck::pod_collect_to_vec::<u8, [f32; 3]>(next()));
            let n = all.position.len();
            if emitter_column {
                all.emitter.extend(bytemuck::pod_collect_to_vec::<u8, u16>(next()));
            } else {
                all.emitter.resize(n, 0);
            }
            if dims > 0 {
                all.params.extend(bytemuck::pod_collect_to_vec::<u8, f32>(next()));
            }
            all.path_length.extend(bytemuck::pod_collect_to_vec::<u8, f32>(next()));
            all.bounces.extend_from_slice(next());
            all.emission_index.extend(bytemuck::pod_collect_to_vec::<u8, u64>(next()));
            all.surface.extend(bytemuck::pod_collect_to_vec::<u8, u32>(next()));
            Ok(())
        })?;
        Ok(all)
    }

    /// Keeps only the photons for which `keep(bounces)` holds, spooled ones included.
    pub fn retain(&mut self, keep: impl Fn(u8) -> bool) -> Result<(), TraceError> {
        let dims = self.layout.dims;
        for c in &mut self.chunks {
            let mask: Vec<bool> = c.bounces.iter().map(|&b| keep(b)).collect();
            c.retain(&mask, dims);
        }
        self.chunks.retain(|c| !c.is_empty());
        if self.spooled.is_some() {
            // Read the spool back a block at a time (flux still relative: scale 1) and write
            // what is kept to a fresh one, a column's kept bytes at a time.
            let specs = self.layout.column_specs();
            let bounces_at = specs.iter().position(|s| s.name == name::BOUNCES).expect("a bounces column");
            let files = self.new_spool_files()?;
            let (mut count, mut kept) = (0, Vec::new());
            self.for_each_spooled_block(1.0, |cols| {
                let mask: Vec<bool> = cols[bounces_at].iter().map(|&b| keep(b)).collect();
                for ((mut file, col), spec) in files.iter().zip(cols).zip(&specs) {
                    kept.clear();
                    let photons = col.chunks_exact(spec.stride() as usize).zip(&mask);
                    kept.extend(photons.filter(|(_, k)| **k).flat_map(|(p, _)| p));
                    file.write_all(&kept).map_err(|e| self.spool_error(e))?;
                }
                count += mask.iter().filter(|&&k| k).count() as u64;
                Ok(())
            })?;
            self.spooled = Some(Spooled { files, count });
        }
        self.count = self.spooled.as_ref().map_or(0, |s| s.count)
            + self.chunks.iter().map(|c| c.len() as u64).sum::<u64>();
        self.held = self.chunks.iter().map(|c| c.len() as u64).sum::<u64>() * self.layout.memory_bytes();
        Ok(())
    }
}

/// A relative flux multiplied by `scale` (watts per emitted photon), rounded to f32.
fn scaled(v: [f32; 3], scale: f64) -> [f32; 3] {
    v.map(|x| (x as f64 * scale) as f32)
}

/// Memory the stored photons may take: 80 % of what the system reports available
/// (`MemAvailable` in /proc/meminfo), or unbounded where that is unknown.
fn memory_budget() -> Option<u64> {
    // A hidden override for tests of the refusal.
    if let Some(b) = std::env::var("PHOTONKIT_TEST_MEMORY_BUDGET").ok().and_then(|b| b.parse().ok()) {
        return Some(b);
    }
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kib: u64 =
        text.lines().find(|l| l.starts_with("MemAvailable:"))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024 / 10 * 8)
}

/// Free space for an unprivileged user in the file system of `dir`, or unknown.
fn disk_budget(dir: &Path) -> Option<u64> {
    // A hidden override for tests of the refusal.
    if let Some(b) = std::env::var("PHOTONKIT_TEST_DISK_BUDGET").ok().and_then(|b| b.parse().ok()) {
        return Some(b);
    }
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain data, for which all zeroes is a valid value.
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `path` is NUL-terminated and `s` is a statvfs the call fills.
    if unsafe { libc::statvfs(path.as_ptr(), &mut s) } != 0 {
        return None;
    }
    Some((s.f_bavail as u64).saturating_mul(s.f_frsize as u64))
}
