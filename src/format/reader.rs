//! Opening and validating a PHM file; nothing is exposed before every check has passed.

use std::collections::HashSet;
use std::io::Read;
use std::path::Path;

use super::columns::{Element, known_column, name};
use super::meta::Metadata;
use super::preamble::{MAGIC, MAX_METADATA_LEN, PREAMBLE_LEN, Preamble, VERSION_MAJOR};
use super::{ColumnSpec, FormatError, Result};

/// Deepest nesting of arrays and objects the metadata may have (serde_json's recursion limit).
pub const MAX_JSON_DEPTH: usize = 128;

/// Largest component count accepted for any column.
const MAX_COMPONENTS: u32 = 64;

enum Storage {
    Mapped(memmap2::Mmap),
    /// Bytes held in memory (standard input, tests), in u64 words so every column is aligned.
    Owned {
        words: Vec<u64>,
        len: usize,
    },
}

/// A validated, read-only photon map: the view every stage reads photons through.
pub struct PhotonMap {
    file: String,
    storage: Storage,
    preamble: Preamble,
    meta: Metadata,
    /// The part of `meta` a stage carries into its output ([`Metadata::info`]).
    info: super::MapInfo,
    /// Keeps the file registered as an input while mapped ([`super::guard`]).
    hold: Option<super::guard::InputHold>,
}

impl std::fmt::Debug for PhotonMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PhotonMap").field("file", &self.file).field("photons", &self.len()).finish()
    }
}

impl PhotonMap {
    /// Opens `path`, or standard input when `path` is `-`, and verifies every column's CRC-32:
    /// a stage never turns a corrupt input into a new file with fresh checksums.
    pub fn open(path: &str) -> Result<Self> {
        let map = Self::open_unverified(path)?;
        map.verify_checksums()?;
        Ok(map)
    }

    /// [`Self::open`] without the column checksums (the header is still checked): for
    /// `inspect`, which reports a checksum failure among its other findings.
    pub fn open_unverified(path: &str) -> Result<Self> {
        if path == "-" {
            return Self::read_from("<stdin>", std::io::stdin().lock());
        }
        Self::map_path(Path::new(path))
    }

    /// Memory-maps a file, validates it and verifies its column checksums.
    pub fn open_path(path: &Path) -> Result<Self> {
        let map = Self::map_path(path)?;
        map.verify_checksums()?;
        Ok(map)
    }

    /// Memory-maps a file and validates its header and column table.
    fn map_path(path: &Path) -> Result<Self> {
        let file = path.display().to_string();
        let io = |source| FormatError::Io { file: file.clone(), source };
        let f = std::fs::File::open(path).map_err(io)?;
        if f.metadata().map_err(io)?.len() == 0 {
            return Err(FormatError::Truncated { file, what: "preamble", needed: 32, actual: 0 });
        }
        // SAFETY: the map is read-only; a file truncated by another process while mapped raises
        // SIGBUS on access, which `guard` reports by name (the process then exits).
        let map = unsafe { memmap2::Mmap::map(&f) }.map_err(io)?;
        let hold = super::guard::hold_mapped_input(path);
        super::guard::test_pause("AFTER_MAP");
        let mut map = Self::from_storage(file, Storage::Mapped(map))?;
        map.hold = hold;
        Ok(map)
    }

    /// Reads a whole file from a stream (standard input) into memory and validates it.
    pub fn read_from(file: &str, mut r: impl Read) -> Result<Self> {
        let mut bytes = Vec::new();
        r.read_to_end(&mut bytes).map_err(|source| FormatError::Io { file: file.to_string(), source })?;
        Self::from_bytes(file, &bytes)
    }

    /// Validates a copy of `bytes`; `file` names it in error messages.
    pub fn from_bytes(file: &str, bytes: &[u8]) -> Result<Self> {
        let mut words = vec![0u64; bytes.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Self::from_storage(file.to_string(), Storage::Owned { words, len: bytes.len() })
    }

    fn from_storage(file: String, storage: Storage) -> Result<Self> {
        let bytes: &[u8] = match &storage {
            Storage::Mapped(m) => m,
            Storage::Owned { words, len } => &bytemuck::cast_slice(words)[..*len],
        };
        let (preamble, meta) = parse(&file, bytes)?;
        let info = meta.info();
        Ok(PhotonMap { file, storage, preamble, meta, info, hold: None })
    }

    /// The whole file.
    pub fn bytes(&self) -> &[u8] {
        match &self.storage {
            Storage::Mapped(m) => m,
            Storage::Owned { words, len } => &bytemuck::cast_slice(words)[..*len],
        }
    }

    /// The name used in messages: the path, or `<stdin>`.
    pub fn file_name(&self) -> &str {
        &self.file
    }

    /// (major, minor) version of the file as written.
    pub fn version(&self) -> (u16, u16) {
        (self.preamble.version_major, self.preamble.version_minor)
    }

    /// The metadata as read and validated.
    pub fn meta(&self) -> &Metadata {
        &self.meta
    }

    /// The header a stage carries into its output (emitters, units, state, history).
    pub fn info(&self) -> &super::MapInfo {
        &self.info
    }

    /// Number of photons.
    pub fn len(&self) -> usize {
        self.meta.photon_count as usize
    }

    /// Whether the map has no photons.
    pub fn is_empty(&self) -> bool {
        self.meta.photon_count == 0
    }

    /// The raw little-endian bytes of a column, if the file has it.
    pub fn column_bytes(&self, column: &str) -> Option<&[u8]> {
        let c = self.meta.column(column)?;
        Some(&self.bytes()[c.offset as usize..(c.offset + c.length) as usize])
    }

    /// Every column's spec and bytes, in file order: what a stage passes on unchanged.
    pub fn columns(&self) -> Vec<(ColumnSpec, &[u8])> {
        self.meta
            .columns
            .iter()
            .map(|c| {
                let spec =
                    ColumnSpec { extra: c.extra.clone(), ..ColumnSpec::new(&c.name, c.dtype, c.components) };
                (spec, self.column_bytes(&c.name).expect("listed column"))
            })
            .collect()
    }

    /// A typed, zero-copy view of a column; `Ok(None)` if absent, an error if its type differs.
    pub fn column<T: Element>(&self, column: &str) -> Result<Option<&[T]>> {
        let Some(c) = self.meta.column(column) else { return Ok(None) };
        if c.dtype != T::DTYPE || c.components != T::COMPONENTS {
            return Err(FormatError::Column {
                file: self.file.clone(),
                column: column.to_string(),
                message: format!(
                    "is {}×{}, expected {}×{}",
                    c.dtype.name(),
                    c.components,
                    T::DTYPE.name(),
                    T::COMPONENTS
                ),
            });
        }
        let bytes = self.column_bytes(column).expect("listed column");
        bytemuck::try_cast_slice(bytes).map(Some).map_err(|e| FormatError::Column {
            file: self.file.clone(),
            column: column.to_string(),
            message: format!("can not be viewed in place: {e}"),
        })
    }

    /// Photon positions (validated present and f32×3 when the map was opened).
    pub fn positions(&self) -> &[[f32; 3]] {
        self.column(name::POSITION).ok().flatten().expect("validated on open")
    }

    /// Photon flux in watts per RGB channel (validated present and f32×3 on open).
    pub fn flux(&self) -> &[[f32; 3]] {
        self.column(name::FLUX).ok().flatten().expect("validated on open")
    }

    /// Recomputes every column's CRC-32 and compares it with the column table.
    pub fn verify_checksums(&self) -> Result<()> {
        for c in &self.meta.columns {
            // In pieces, each released once hashed: a file larger than the memory is verified
            // without ever being resident as a whole.
            let mut crc = crc32fast::Hasher::new();
            for piece in self.column_bytes(&c.name).expect("listed column").chunks(RELEASE_EVERY) {
                crc.update(piece);
                self.pages().release_range(piece);
            }
            let computed = crc.finalize();
            if computed != c.crc32 {
                return Err(FormatError::Checksum {
                    file: self.file.clone(),
                    column: c.name.clone(),
                    stored: c.crc32,
                    computed,
                });
            }
        }
        Ok(())
    }

    /// Drops the file's pages from this process's resident set (a memory-mapped map; nothing
    /// for one held in memory). Nothing is lost: a page read again is mapped again from the
    /// file (the page cache, usually). Stages that bound their memory call it between tiles,
    /// so the pages one tile read do not count against the next (docs/tiles.md).
    pub fn release_pages(&self) {
        self.pages().release();
    }

    /// The file's pages, to release later ([`Self::release_pages`]).
    pub fn pages(&self) -> Pages<'_> {
        match &self.storage {
            Storage::Mapped(m) => Pages(Some(m)),
            Storage::Owned { .. } => Pages(None),
        }
    }
}

/// The pages of a memory-mapped map ([`PhotonMap::pages`], [`super::MapView::pages`]), for a
/// stage that reads its columns through plain slices to release once it has copied what it
/// needs (none for a map held in memory).
#[derive(Clone, Copy, Debug, Default)]
pub struct Pages<'a>(Option<&'a memmap2::Mmap>);

impl Pages<'_> {
    /// Drops every page of the file from this process's resident set
    /// ([`PhotonMap::release_pages`]).
    pub fn release(&self) {
        #[cfg(unix)]
        if let Some(m) = self.0 {
            // SAFETY: the mapping is read-only and shared (memmap2's `Mmap::map`): dropping its
            // pages changes no byte a borrow can see, as a page read again is the file's page.
            // Failure only leaves the pages resident.
            let _ = unsafe { m.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
    }

    /// `v`, once the pages are released ([`Self::release`]): for a copy just made from the
    /// file, as a tile copies its photons' rows, which are scattered over every page of a
    /// column, so that one column's pages at a time stay resident.
    pub fn released<T>(&self, v: T) -> T {
        self.release();
        v
    }

    /// Drops the pages of `bytes`, a part of the file, as [`Self::release`] does for all of it
    /// (nothing when `bytes` is not in the file).
    pub fn release_range(&self, bytes: &[u8]) {
        self.release_around(bytes, 0);
    }

    /// [`Self::release_range`] of `bytes` grown by `margin` bytes on each side (within the file).
    fn release_around(&self, bytes: &[u8], margin: usize) {
        #[cfg(unix)]
        if let Some(m) = self.0 {
            let start = bytes.as_ptr() as usize;
            let Some(offset) = start.checked_sub(m.as_ptr() as usize) else { return };
            if offset + bytes.len() > m.len() {
                return;
            }
            let from = offset.saturating_sub(margin);
            let to = (offset + bytes.len()).saturating_add(margin).min(m.len());
            // SAFETY: as in `release`.
            let _ = unsafe { m.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, from, to - from) };
        }
        #[cfg(not(unix))]
        let _ = (bytes, margin);
    }
}

impl Pages<'_> {
    /// `column[i]` for each of `indices` (ascending), copied in blocks whose span of the file
    /// is released once copied: a gather from all over a large file keeps at most a few
    /// blocks' pages resident, where copying first and releasing after would hold every page
    /// it touched (for a scattered tile, nearly all of the column).
    pub fn gather<T: bytemuck::Pod + Default + Send + Sync>(&self, column: &[T], indices: &[u32]) -> Vec<T> {
        self.gather_rows(column, 1, indices)
    }

    /// [`Self::gather`] of rows of `stride` elements: `column[i·stride..(i + 1)·stride]` for
    /// each of `indices` (ascending), one after another.
    pub fn gather_rows<T: bytemuck::Pod + Default + Send + Sync>(
        &self,
        column: &[T],
        stride: usize,
        indices: &[u32],
    ) -> Vec<T> {
        use rayon::prelude::*;
        let stride = stride.max(1);
        let mut out = vec![T::default(); indices.len() * stride];
        out.par_chunks_mut(GATHER_BLOCK * stride).zip(indices.par_chunks(GATHER_BLOCK)).for_each(
            |(out, ix)| {
                if stride == 1 {
                    // One element a row: a plain copy (a slice copy of one element calls memmove).
                    for (o, &i) in out.iter_mut().zip(ix) {
                        *o = column[i as usize];
                    }
                } else {
                    for (o, &i) in out.chunks_exact_mut(stride).zip(ix) {
                        o.copy_from_slice(&column[i as usize * stride..][..stride]);
                    }
                }
                if let (Some(&a), Some(&b)) = (ix.first(), ix.last())
                    && a <= b
                {
                    // A page fault maps its neighbours too (the kernel's fault-around, 64 KiB), so
                    // a block's faults map pages of the blocks beside it: release them with it.
                    let span = &column[a as usize * stride..(b as usize + 1) * stride];
                    self.release_around(bytemuck::cast_slice(span), FAULT_AROUND);
                }
            },
        );
        out
    }
}

/// Bytes around a gathered block's span released with it: the kernel's fault-around maps up
/// to 64 KiB about a faulting page, and read-ahead more (measured: with the span alone, half of
/// a column gathered in four stayed resident at 10⁸ photons).
const FAULT_AROUND: usize = 1 << 20;

/// Indices a [`Pages::gather`] block copies before it releases their span (at most this many
/// pages resident per block and column).
const GATHER_BLOCK: usize = 4096;

/// How many bytes of a mapped file a long scan reads before it releases them.
const RELEASE_EVERY: usize = 64 << 20;

/// Checks the preamble, the metadata and the column table against the bytes present.
fn parse(file: &str, bytes: &[u8]) -> Result<(Preamble, Metadata)> {
    let file_s = || file.to_string();
    let actual = bytes.len() as u64;
    let Some(head) = bytes.first_chunk::<PREAMBLE_LEN>() else {
        let n = bytes.len().min(MAGIC.len());
        if bytes[..n] != MAGIC[..n] {
            return Err(FormatError::BadMagic { file: file_s() });
        }
        return Err(FormatError::Truncated { file: file_s(), what: "preamble", needed: 32, actual });
    };
    let pre = Preamble::from_bytes(head).ok_or_else(|| FormatError::BadMagic { file: file_s() })?;
    if pre.version_major != VERSION_MAJOR {
        return Err(FormatError::UnsupportedVersion {
            file: file_s(),
            major: pre.version_major,
            minor: pre.version_minor,
        });
    }
    if pre.metadata_len > MAX_METADATA_LEN {
        return Err(FormatError::MetadataTooLarge {
            file: file_s(),
            len: pre.metadata_len,
            limit: MAX_METADATA_LEN,
        });
    }
    if actual < pre.file_len {
        return Err(FormatError::Truncated {
            file: file_s(),
            what: "the file",
            needed: pre.file_len,
            actual,
        });
    }
    if actual > pre.file_len {
        return Err(invalid(
            file,
            format!(
                "the file has {actual} bytes but its preamble says {}: trailing data or a corrupt length",
                pre.file_len
            ),
        ));
    }
    let meta_end = PREAMBLE_LEN as u64 + pre.metadata_len;
    if meta_end > actual {
        return Err(FormatError::Truncated {
            file: file_s(),
            what: "the metadata",
            needed: meta_end,
            actual,
        });
    }
    let region = &bytes[PREAMBLE_LEN..meta_end as usize];
    if crc32fast::hash(region) != pre.metadata_crc32 {
        return Err(FormatError::MetadataChecksum { file: file_s(), end: meta_end });
    }
    let text = std::str::from_utf8(region).map_err(|e| FormatError::MetadataJson {
        file: file_s(),
        offset: PREAMBLE_LEN as u64 + e.valid_up_to() as u64,
        message: "not UTF-8".into(),
    })?;
    // Deserialised through serde_path_to_error, so a wrong type names its field
    // (`emitters[0].power_w`); serde_json's nesting limit (128 levels) is the spec's (§3).
    let mut de = serde_json::Deserializer::from_str(text);
    let meta: Metadata = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| (e.path().to_string(), e.into_inner()))
        .and_then(|m| de.end().map(|()| m).map_err(|e| (String::new(), e)))
        .map_err(|(path, e)| {
            // serde_json reports line and column; turn them into a byte offset in the file.
            let line_start: usize =
                text.split_inclusive('\n').take(e.line().saturating_sub(1)).map(str::len).sum();
            let mut message = match e.classify() {
                serde_json::error::Category::Data => format!("invalid: {e}"),
                _ => format!("not valid JSON: {e}"),
            };
            if message.contains("recursion limit") {
                message = format!("nested deeper than {MAX_JSON_DEPTH} levels (format-spec/phm-v1.md §3)");
            } else if path != "." && !path.is_empty() {
                message = format!("field '{path}': {message}");
            }
            FormatError::MetadataJson {
                file: file_s(),
                offset: (PREAMBLE_LEN + line_start + e.column().saturating_sub(1)) as u64,
                message,
            }
        })?;
    validate(file, &pre, &meta)?;
    Ok((pre, meta))
}

fn invalid(file: &str, message: String) -> FormatError {
    FormatError::Invalid { file: file.to_string(), message }
}

fn column_err(file: &str, column: &str, message: String) -> FormatError {
    FormatError::Column { file: file.to_string(), column: column.to_string(), message }
}

/// The rules of format-spec/phm-v1.md §3–4 that do not need to read photon data (the writer
/// applies them too, so it never writes a file this reader refuses).
pub(super) fn validate(file: &str, pre: &Preamble, meta: &Metadata) -> Result<()> {
    let count = meta.photon_count;
    let data_start = PREAMBLE_LEN as u64 + pre.metadata_len;
    let mut names = HashSet::new();
    let mut spans = Vec::with_capacity(meta.columns.len());
    for c in &meta.columns {
        let n = c.name.as_str();
        if n.is_empty() || n.len() > 256 {
            return Err(invalid(file, format!("a column name is empty or longer than 256 bytes: {n:?}")));
        }
        if !names.insert(n) {
            return Err(column_err(file, n, "appears twice in the column table".into()));
        }
        if c.components == 0 || c.components > MAX_COMPONENTS {
            return Err(column_err(
                file,
                n,
                format!("has {} components (1..={MAX_COMPONENTS} allowed)", c.components),
            ));
        }
        if let Some(k) = known_column(n)
            && (k.dtype != c.dtype || !k.components.contains(&c.components))
        {
            return Err(column_err(
                file,
                n,
                format!(
                    "is {}×{} but PHM 1 defines it as {}×{:?}",
                    c.dtype.name(),
                    c.components,
                    k.dtype.name(),
                    k.components
                ),
            ));
        }
        let expected = count
            .checked_mul(c.dtype.size() * c.components as u64)
            .ok_or_else(|| column_err(file, n, format!("photon_count {count} overflows its length")))?;
        if c.length != expected {
            return Err(column_err(
                file,
                n,
                format!(
                    "length is {} bytes but {count} photons × {}×{} need {expected}",
                    c.length,
                    c.dtype.name(),
                    c.components
                ),
            ));
        }
        if c.offset % 64 != 0 {
            return Err(column_err(file, n, format!("offset {} is not a multiple of 64", c.offset)));
        }
        let end = c.offset.checked_add(c.length).filter(|&e| e <= pre.file_len).ok_or_else(|| {
            column_err(
                file,
                n,
                format!("bytes {}..+{} lie outside the {}-byte file", c.offset, c.length, pre.file_len),
            )
        })?;
        if c.offset < data_start {
            return Err(column_err(
                file,
                n,
                format!("offset {} overlaps the header (which ends at {data_start})", c.offset),
            ));
        }
        spans.push((c.offset, end, n));
    }
    spans.sort();
    for w in spans.windows(2) {
        if w[1].0 < w[0].1 {
            return Err(invalid(file, format!("columns '{}' and '{}' overlap", w[0].2, w[1].2)));
        }
    }
    for required in [name::POSITION, name::FLUX] {
        if meta.column(required).is_none() {
            return Err(invalid(file, format!("the required column '{required}' is missing")));
        }
    }
    validate_emitters(file, meta)?;
    match (&meta.bounding_box, count) {
        (None, 0) => {}
        (Some(b), n) if n > 0 => {
            let ok = (0..3).all(|k| b.min[k].is_finite() && b.max[k].is_finite() && b.min[k] <= b.max[k]);
            if !ok {
                return Err(invalid(file, format!("bounding_box {b} is not a finite box with min ≤ max")));
            }
        }
        (Some(_), _) => return Err(invalid(file, "bounding_box must be null for an empty map".into())),
        (None, _) => return Err(invalid(file, "bounding_box is missing for a non-empty map".into())),
    }
    Ok(())
}

pub(super) fn validate_emitters(file: &str, meta: &Metadata) -> Result<()> {
    if meta.emitters.len() > u16::MAX as usize + 1 {
        return Err(invalid(file, format!("{} emitters; at most 65536 are allowed", meta.emitters.len())));
    }
    for (i, e) in meta.emitters.iter().enumerate() {
        if e.id as usize != i {
            return Err(invalid(
                file,
                format!("emitter at index {i} has id {}; ids must equal their index", e.id),
            ));
        }
        if let Some(d) = e.parameterisation.dims()
            && d != e.param_dims
        {
            return Err(invalid(
                file,
                format!(
                    "emitter {i}: parameterisation {:?} has {d} dimensions, not param_dims = {}",
                    e.parameterisation, e.param_dims
                ),
            ));
        }
        if !(e.power_w.is_finite() && e.power_w >= 0.0) || e.colour.iter().any(|c| !c.is_finite()) {
            return Err(invalid(file, format!("emitter {i}: power_w and colour must be finite, power ≥ 0")));
        }
        if e.param_measure.is_some_and(|m| !(m.is_finite() && m > 0.0)) {
            return Err(invalid(file, format!("emitter {i}: param_measure must be finite and positive")));
        }
        if !e.dimensions.is_empty() && e.dimensions.len() != e.param_dims as usize {
            return Err(invalid(
                file,
                format!(
                    "emitter {i}: {} dimensions described, not param_dims = {}",
                    e.dimensions.len(),
                    e.param_dims
                ),
            ));
        }
        for d in &e.dimensions {
            if d.scale.is_some_and(|s| !(s.is_finite() && s > 0.0))
                || d.range.is_some_and(|[lo, hi]| !(lo.is_finite() && hi.is_finite() && lo <= hi))
            {
                return Err(invalid(
                    file,
                    format!(
                        "emitter {i}: dimension '{}' needs a finite positive scale and a finite range lo ≤ hi",
                        d.name
                    ),
                ));
            }
        }
    }
    if meta.emitters.len() > 1 && meta.column(name::EMITTER).is_none() {
        return Err(invalid(
            file,
            "several emitters but no 'emitter' column to tell their photons apart".into(),
        ));
    }
    if let Some(p) = meta.column(name::PARAMS) {
        let dims = meta.emitters.iter().map(|e| e.param_dims).max().unwrap_or(0);
        if dims != p.components {
            return Err(column_err(
                file,
                name::PARAMS,
                format!(
                    "has {} components but the emitters need {dims} (the largest param_dims)",
                    p.components
                ),
            ));
        }
    }
    Ok(())
}
