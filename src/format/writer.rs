//! Writing a PHM file: photons stream into a temporary file beside the target, the header
//! is patched in at the end, and the file is renamed into place only when complete.

use std::collections::HashSet;
use std::io::{Seek, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::columns::{known_column, name};
use super::meta::{BoundingBox, ColumnEntry, MapInfo, Metadata};
use super::preamble::{MAX_METADATA_LEN, PREAMBLE_LEN, Preamble, VERSION_MAJOR, VERSION_MINOR, align_up};
use super::reader::{validate, validate_emitters};
use super::{ColumnSpec, FormatError, Result};

/// Where a stage writes its photon map.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Output {
    /// A file, replaced atomically once every photon is written.
    Path(PathBuf),
    /// Standard output (`-` on the command line), copied there once the file is complete.
    Stdout,
}

impl Output {
    /// `-` means standard output; anything else is a path.
    pub fn parse(s: &str) -> Self {
        if s == "-" { Output::Stdout } else { Output::Path(PathBuf::from(s)) }
    }

    fn display(&self) -> String {
        match self {
            Output::Path(p) => p.display().to_string(),
            Output::Stdout => "<stdout>".into(),
        }
    }
}

/// Bytes buffered per column before a positioned write.
const COLUMN_BUFFER: usize = 1 << 20;

struct ColumnSink {
    entry: ColumnEntry,
    stride: usize,
    hasher: crc32fast::Hasher,
    flushed: u64,
    buf: Vec<u8>,
}

/// Streams photons, chunk by chunk, into a PHM file whose photon count is known up front.
pub struct PhotonWriter {
    target: Output,
    tmp: tempfile::NamedTempFile,
    info: MapInfo,
    sinks: Vec<ColumnSink>,
    count: u64,
    pushed: u64,
    metadata_len: u64,
    file_len: u64,
    bbox: Option<BoundingBox>,
}

/// Refuses a layout the reader would refuse: a column given twice, unnamed or without
/// components, a known column (format-spec/phm-v1.md §4.1) of the wrong type or width, a
/// missing `position` or `flux`, or emitters not numbered 0, 1, … with finite power and colour.
fn check_layout(tname: &str, info: &MapInfo, specs: &[ColumnSpec]) -> Result<()> {
    let bad = |message: String| FormatError::Invalid { file: tname.to_string(), message };
    let mut seen = HashSet::new();
    for s in specs {
        if !seen.insert(s.name.as_str()) {
            return Err(bad(format!("column '{}' given twice", s.name)));
        }
        if s.components == 0 || s.name.is_empty() {
            return Err(bad(format!("column '{}' needs a name and at least one component", s.name)));
        }
        if let Some(k) = known_column(&s.name)
            && (k.dtype != s.dtype || !k.components.contains(&s.components))
        {
            return Err(bad(format!("column '{}' must be {}×{:?}", s.name, k.dtype.name(), k.components)));
        }
    }
    for required in [name::POSITION, name::FLUX] {
        if !seen.contains(required) {
            return Err(bad(format!("the required column '{required}' is missing")));
        }
    }
    for (i, e) in info.emitters.iter().enumerate() {
        if e.id as usize != i || !e.power_w.is_finite() || e.colour.iter().any(|c| !c.is_finite()) {
            return Err(bad(format!("emitter {i} needs id {i} and finite power and colour")));
        }
    }
    Ok(())
}

impl PhotonWriter {
    /// Lays out a file of `count` photons with the given columns (position and flux required).
    pub fn create(target: Output, info: MapInfo, specs: &[ColumnSpec], count: u64) -> Result<Self> {
        let tname = target.display();
        let bad = |message: String| FormatError::Invalid { file: tname.clone(), message };
        check_layout(&tname, &info, specs)?;

        // The metadata is written last but sits first, so reserve room for its longest form:
        // the same JSON with the widest possible checksums, offsets and box, plus slack.
        let wide = BoundingBox { min: [-1.2345678e-38; 3], max: [-1.2345678e-38; 3] };
        let mut entries: Vec<ColumnEntry> = specs
            .iter()
            .map(|s| ColumnEntry {
                name: s.name.clone(),
                dtype: s.dtype,
                components: s.components,
                offset: u64::MAX,
                length: u64::MAX,
                crc32: u32::MAX,
                extra: s.extra.clone(),
            })
            .collect();
        let widest = metadata(&info, count, entries.clone(), Some(wide));
        // Refuse up front what the reader would refuse (emitters against the column table),
        // before any photon is streamed.
        validate_emitters(&tname, &widest)?;
        let json_len = serde_json::to_vec_pretty(&widest).map_err(|e| bad(e.to_string()))?.len() as u64;
        let data_start = align_up(PREAMBLE_LEN as u64 + json_len + 64);
        // Never write a file the reader refuses: its metadata limit applies here too.
        if data_start - PREAMBLE_LEN as u64 > MAX_METADATA_LEN {
            return Err(FormatError::MetadataTooLarge {
                file: tname.clone(),
                len: data_start - PREAMBLE_LEN as u64,
                limit: MAX_METADATA_LEN,
            });
        }
        let mut at = data_start;
        for (e, s) in entries.iter_mut().zip(specs) {
            e.offset = at;
            e.length = count.checked_mul(s.stride()).ok_or_else(|| bad("photon count overflows".into()))?;
            at = align_up(at + e.length);
        }

        let tmp = match &target {
            Output::Path(p) => temp_beside(p, ".phm-"),
            Output::Stdout => new_file_builder("photonkit-", ".phm").tempfile().inspect(|t| {
                super::guard::register_temp(t.path());
            }),
        }
        .map_err(|source| FormatError::Io { file: tname.clone(), source })?;
        // Sizing the file up front makes every padding byte zero without writing it.
        tmp.as_file().set_len(at).map_err(|source| FormatError::Io { file: tname.clone(), source })?;

        let sinks = entries
            .into_iter()
            .zip(specs)
            .map(|(entry, s)| ColumnSink {
                entry,
                stride: s.stride() as usize,
                hasher: crc32fast::Hasher::new(),
                flushed: 0,
                buf: Vec::new(),
            })
            .collect();
        Ok(PhotonWriter {
            target,
            tmp,
            info,
            sinks,
            count,
            pushed: 0,
            metadata_len: data_start - PREAMBLE_LEN as u64,
            file_len: at,
            bbox: None,
        })
    }

    fn io(&self, source: std::io::Error) -> FormatError {
        FormatError::Io { file: self.target.display(), source }
    }

    /// Appends photons: one byte slice per column, in the order given to [`create`](Self::create),
    /// each holding the same number of photons. Non-finite positions or flux are refused.
    pub fn push(&mut self, chunk: &[&[u8]]) -> Result<()> {
        let file = self.target.display();
        if chunk.len() != self.sinks.len() {
            return Err(FormatError::Invalid {
                file,
                message: format!("{} columns pushed, {} declared", chunk.len(), self.sinks.len()),
            });
        }
        let n = chunk[0].len() / self.sinks[0].stride;
        for (s, b) in self.sinks.iter().zip(chunk) {
            if b.len() != n * s.stride {
                return Err(FormatError::Column {
                    file,
                    column: s.entry.name.clone(),
                    message: format!(
                        "chunk holds {} bytes, expected {} for {n} photons",
                        b.len(),
                        n * s.stride
                    ),
                });
            }
        }
        if self.pushed + n as u64 > self.count {
            return Err(FormatError::Invalid {
                file,
                message: format!("more photons pushed than the {} declared", self.count),
            });
        }
        for (s, b) in self.sinks.iter().zip(chunk) {
            if s.entry.name == name::POSITION || s.entry.name == name::FLUX {
                // Chunks from callers need not be aligned, so decode instead of casting.
                let v = b
                    .chunks_exact(12)
                    .map(|p| [0, 4, 8].map(|o| f32::from_le_bytes(p[o..o + 4].try_into().expect("4 bytes"))));
                if let Some(i) = v.clone().position(|p| p.iter().any(|x| !x.is_finite())) {
                    return Err(FormatError::NonFinite {
                        file,
                        column: s.entry.name.clone(),
                        index: self.pushed + i as u64,
                    });
                }
                if s.entry.name == name::POSITION {
                    for p in v {
                        let b = self.bbox.get_or_insert(BoundingBox { min: p, max: p });
                        b.min = std::array::from_fn(|k| b.min[k].min(p[k]));
                        b.max = std::array::from_fn(|k| b.max[k].max(p[k]));
                    }
                }
            }
        }
        for (i, &b) in chunk.iter().enumerate() {
            self.sinks[i].hasher.update(b);
            if self.sinks[i].buf.len() + b.len() > COLUMN_BUFFER {
                self.flush_column(i)?;
            }
            if b.len() >= COLUMN_BUFFER {
                let s = &mut self.sinks[i];
                let at = s.entry.offset + s.flushed;
                s.flushed += b.len() as u64;
                self.tmp.as_file().write_all_at(b, at).map_err(|e| self.io(e))?;
            } else {
                self.sinks[i].buf.extend_from_slice(b);
            }
        }
        self.pushed += n as u64;
        Ok(())
    }

    fn flush_column(&mut self, i: usize) -> Result<()> {
        let s = &mut self.sinks[i];
        let at = s.entry.offset + s.flushed;
        s.flushed += s.buf.len() as u64;
        let buf = std::mem::take(&mut s.buf);
        self.tmp.as_file().write_all_at(&buf, at).map_err(|e| self.io(e))?;
        self.sinks[i].buf = buf;
        self.sinks[i].buf.clear();
        Ok(())
    }

    /// Writes the header and moves the file into place (or copies it to standard output).
    pub fn finish(mut self) -> Result<()> {
        if self.pushed != self.count {
            return Err(FormatError::Invalid {
                file: self.target.display(),
                message: format!("{} photons pushed, {} declared", self.pushed, self.count),
            });
        }
        for i in 0..self.sinks.len() {
            self.flush_column(i)?;
        }
        let entries = self
            .sinks
            .iter()
            .map(|s| ColumnEntry { crc32: s.hasher.clone().finalize(), ..s.entry.clone() })
            .collect();
        let meta = metadata(&self.info, self.count, entries, self.bbox);
        let mut region = serde_json::to_vec_pretty(&meta)
            .map_err(|e| FormatError::Invalid { file: self.target.display(), message: e.to_string() })?;
        assert!(region.len() < self.metadata_len as usize, "metadata outgrew its reservation");
        region.resize(self.metadata_len as usize - 1, b' ');
        region.push(b'\n');
        let pre = Preamble {
            version_major: VERSION_MAJOR,
            version_minor: meta.minor_version().min(VERSION_MINOR),
            metadata_crc32: crc32fast::hash(&region),
            metadata_len: self.metadata_len,
            file_len: self.file_len,
        };
        // Never write a file our own reader refuses (the temporary file goes with `self`).
        validate(&self.target.display(), &pre, &meta)?;
        let f = self.tmp.as_file();
        f.write_all_at(&pre.to_bytes(), 0).map_err(|e| self.io(e))?;
        f.write_all_at(&region, PREAMBLE_LEN as u64).map_err(|e| self.io(e))?;
        match &self.target {
            Output::Path(p) => {
                persist(self.tmp, p)
                    .map_err(|source| FormatError::Io { file: p.display().to_string(), source })?;
            }
            Output::Stdout => {
                let mut f = self.tmp.reopen().map_err(|e| self.io(e))?;
                f.rewind().map_err(|e| self.io(e))?;
                let mut out = std::io::stdout().lock();
                std::io::copy(&mut f, &mut out).map_err(|e| self.io(e))?;
                out.flush().map_err(|e| self.io(e))?;
            }
        }
        Ok(())
    }
}

fn metadata(info: &MapInfo, count: u64, columns: Vec<ColumnEntry>, bbox: Option<BoundingBox>) -> Metadata {
    Metadata {
        photon_count: count,
        columns,
        emitters: info.emitters.clone(),
        units: info.units.clone(),
        bounding_box: if count == 0 { None } else { bbox },
        state: info.state,
        history: info.history.clone(),
        extra: info.extra.clone(),
    }
}

/// Photons per chunk when a whole in-memory map is written.
const CHUNK: usize = 1 << 16;

/// A builder for files a command creates: mode 0666 before the umask, as for any file a
/// command creates (tempfile's default is 0600).
fn new_file_builder<'a>(prefix: &'a str, suffix: &'a str) -> tempfile::Builder<'a, 'a> {
    let mut builder = tempfile::Builder::new();
    builder.prefix(prefix).suffix(suffix);
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    builder
}

/// The folder holding the file `path` names: its parent, or `.` for a bare file name.
pub fn folder_of(path: &Path) -> &Path {
    path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// A temporary file beside `path` (same directory, so the final rename stays on one disk),
/// named `<prefix>….tmp`: every output of every stage is written there and renamed into place
/// only when complete, so a failed run never leaves a damaged file.
///
/// Refuses a `path` that is one of the command's inputs ([`super::guard::check_output`]), and
/// registers the temporary file so an interrupt removes it.
pub fn temp_beside(path: &Path, prefix: &str) -> std::io::Result<tempfile::NamedTempFile> {
    super::guard::check_output(path)?;
    let tmp = new_file_builder(prefix, ".tmp").tempfile_in(folder_of(path))?;
    super::guard::register_temp(tmp.path());
    Ok(tmp)
}

/// Renames a finished temporary file from [`temp_beside`] into place, checking once more that
/// the target is not one of the command's inputs.
pub fn persist(tmp: tempfile::NamedTempFile, path: &Path) -> std::io::Result<()> {
    super::guard::check_output(path)?;
    super::guard::test_pause("BEFORE_RENAME");
    let temp_path = tmp.path().to_path_buf();
    tmp.persist(path).map_err(|e| e.error)?;
    super::guard::forget_temp(&temp_path);
    Ok(())
}

/// Writes whole columns held in memory (or mapped from an input file) as one PHM file.
pub fn write_map(target: Output, info: MapInfo, columns: &[(ColumnSpec, &[u8])]) -> Result<()> {
    write_map_releasing(target, info, columns, Default::default())
}

/// [`write_map`], releasing `pages` (of the input file some columns are borrowed
/// from) as they are written, so writing a map never makes its whole input resident.
pub(super) fn write_map_releasing(
    target: Output,
    info: MapInfo,
    columns: &[(ColumnSpec, &[u8])],
    pages: super::Pages<'_>,
) -> Result<()> {
    let file = target.display();
    let first = columns
        .first()
        .ok_or_else(|| FormatError::Invalid { file: file.clone(), message: "no columns".into() })?;
    let count = first.1.len() as u64 / first.0.stride().max(1);
    for (s, b) in columns {
        if b.len() as u64 != count * s.stride() {
            return Err(FormatError::Column {
                file,
                column: s.name.clone(),
                message: format!(
                    "holds {} bytes, expected {} for {count} photons",
                    b.len(),
                    count * s.stride()
                ),
            });
        }
    }
    let specs: Vec<ColumnSpec> = columns.iter().map(|(s, _)| s.clone()).collect();
    let mut w = PhotonWriter::create(target, info, &specs, count)?;
    let mut start = 0usize;
    while (start as u64) < count {
        let end = (start + CHUNK).min(count as usize);
        let chunk: Vec<&[u8]> =
            columns.iter().map(|(s, b)| &b[start * s.stride() as usize..end * s.stride() as usize]).collect();
        w.push(&chunk)?;
        for c in &chunk {
            pages.release_range(c);
        }
        start = end;
    }
    w.finish()
}
