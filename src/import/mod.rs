//! Photons from other tracers: PLY point clouds, CSV/TSV tables and Radiance photon maps.
//!
//! Every importer ends in the same place: photon columns in memory ([`Imported`]) with the
//! names and types of format-spec/phm-v1.md §4.1, plus the emitters they belong to, written
//! as one PHM file by [`Imported::write`]. Text and PLY sources name their fields with the
//! text names of §7 (`x y z`, `flux_r flux_g flux_b`, …; the whole mapping is in
//! format-spec/import.md); `layout.rs` turns a list of field names into columns, so PLY and CSV
//! share one mapping.
//!
//! Input is distrusted: a count read from a file never sizes an allocation before the bytes
//! that back it have been seen to exist, and every error names the file and the line or byte
//! offset where it was found.

pub mod csv;
mod layout;
pub mod ply;
pub mod radiance;

pub(crate) use layout::{Columns, Field, Layout, canonical_name, layout};

use std::fmt;
use std::path::Path;

use serde_json::{Value, json};

use crate::format::{
    ColumnSpec, Emitter, EmitterKind, FormatError, MapInfo, Output, Parameterisation, StageRecord, State,
    name, write_map,
};

/// Where in an input file something was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum At {
    /// 1-based line of a text file or text header.
    Line(u64),
    /// 0-based byte offset from the start of the file.
    Byte(u64),
}

impl fmt::Display for At {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            At::Line(l) => write!(f, "line {l}"),
            At::Byte(b) => write!(f, "byte {b}"),
        }
    }
}

/// Everything that can be wrong with a file to import.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// Reading the input failed.
    #[error("{file}: {source}")]
    Io {
        /// The input as named to the user.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// Bad bytes or text at a known place.
    #[error("{file}: {at}: {message}")]
    Malformed {
        /// The input as named to the user.
        file: String,
        /// The line or byte offset.
        at: At,
        /// What is wrong there.
        message: String,
    },
    /// Well-formed input that does not make a photon map (no positions, inconsistent options).
    #[error("{file}: {message}")]
    Invalid {
        /// The input as named to the user.
        file: String,
        /// What is missing or inconsistent.
        message: String,
    },
    /// A variant of a format this importer knows of but does not read.
    #[error("{file}: {variant} is not supported: {message}")]
    Unsupported {
        /// The input as named to the user.
        file: String,
        /// The variant found (a Radiance version, record size or map kind).
        variant: String,
        /// What this importer reads instead.
        message: String,
    },
    /// Neither the first bytes nor the extension say which format the input is.
    #[error(
        "{file}: format not recognised (expected a PLY file starting with 'ply', a Radiance photon map \
         starting with '#?RADIANCE', or a .csv/.tsv/.txt table); name it with --from"
    )]
    UnknownFormat {
        /// The input as named to the user.
        file: String,
    },
    /// Writing the PHM file failed.
    #[error(transparent)]
    Format(#[from] FormatError),
}

/// A result whose error is an [`ImportError`].
pub type Result<T, E = ImportError> = std::result::Result<T, E>;

/// The formats `photonkit import` reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SourceFormat {
    /// PLY point cloud, ASCII or binary (format-spec/import.md).
    Ply,
    /// Comma- or tab-separated text with a header row (the delimiter is taken from the header).
    Csv,
    /// A Radiance photon map written by `mkpmap` (format 3.1).
    Radiance,
}

impl SourceFormat {
    /// The format's name in messages and stage records (`ply`, `csv`, `radiance`).
    pub fn name(self) -> &'static str {
        match self {
            SourceFormat::Ply => "ply",
            SourceFormat::Csv => "csv",
            SourceFormat::Radiance => "radiance",
        }
    }

    /// Recognises a file by its first bytes, then by its extension.
    pub fn detect(path: &Path, head: &[u8]) -> Option<Self> {
        if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
            return Some(SourceFormat::Ply);
        }
        if head.starts_with(b"#?RADIANCE") {
            return Some(SourceFormat::Radiance);
        }
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "csv" | "tsv" | "txt" => Some(SourceFormat::Csv),
            "ply" => Some(SourceFormat::Ply),
            "pm" | "pmap" => Some(SourceFormat::Radiance),
            _ => None,
        }
    }
}

/// Choices the user makes about an import.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// The source format; detected from the file when `None`.
    pub format: Option<SourceFormat>,
    /// How to read the `param_*` fields of a PLY or CSV file; when `None`, two parameters are
    /// `rect_uv` and three are `direction`.
    pub parameterisation: Option<Parameterisation>,
    /// Radiance: keep only photons whose caustic flag is set (last segment specular).
    pub caustic_only: bool,
    /// PLY/CSV without `flux_*` fields: take `red green blue` as the flux, W (without this,
    /// such a file is refused: colours are display values, not watts).
    pub flux_from_colour: bool,
}

/// Photons read from another format, held as PHM columns in memory.
#[derive(Clone, Debug)]
pub struct Imported {
    /// The format the photons were read from.
    pub format: SourceFormat,
    /// Columns in the order they will be written; `position` and `flux` always present.
    pub columns: Vec<(ColumnSpec, Vec<u8>)>,
    /// One `external` emitter per value of the `emitter` column (one when there is none).
    pub emitters: Vec<Emitter>,
    /// What the importer learnt about the source (stored in the stage record's `report`).
    pub report: Value,
}

impl Imported {
    /// Number of photons.
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, |(s, b)| b.len() / s.stride().max(1) as usize)
    }

    /// Whether no photon was imported.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The bytes of the column named `column`, if there is one.
    pub fn column(&self, column: &str) -> Option<&[u8]> {
        self.columns.iter().find(|(s, _)| s.name == column).map(|(_, b)| b.as_slice())
    }

    /// Writes the photons as a PHM file (state `traced`) with one `import` stage record.
    pub fn write(self, target: Output, parameters: Value) -> Result<()> {
        let mut info = MapInfo::new(self.emitters, State::Traced);
        let mut record = StageRecord::now("import", parameters);
        record.report = self.report;
        info.history.push(record);
        let cols: Vec<(ColumnSpec, &[u8])> =
            self.columns.iter().map(|(s, b)| (s.clone(), b.as_slice())).collect();
        write_map(target, info, &cols)?;
        Ok(())
    }
}

/// Reads `path` in the format given or detected.
pub fn import(path: &Path, options: &Options) -> Result<Imported> {
    let stdin = path == Path::new("-");
    let file = if stdin { "<stdin>".to_string() } else { path.display().to_string() };
    let io = |source| ImportError::Io { file: file.clone(), source };
    let bytes = if stdin {
        read_bounded(&file, path, options.format, std::io::stdin().lock())?
    } else {
        crate::format::guard::register_input(path);
        read_bounded(&file, path, options.format, std::fs::File::open(path).map_err(io)?)?
    };
    let format = match options.format {
        Some(f) => f,
        None => SourceFormat::detect(path, &bytes)
            .ok_or_else(|| ImportError::UnknownFormat { file: file.clone() })?,
    };
    if options.caustic_only && format != SourceFormat::Radiance {
        return Err(ImportError::Invalid {
            file,
            message: format!("--caustic-only applies to Radiance photon maps, not to {}", format.name()),
        });
    }
    match format {
        SourceFormat::Ply => ply::read(&file, &bytes, options),
        SourceFormat::Csv => csv::read(&file, &bytes, options),
        SourceFormat::Radiance => radiance::read(path, &bytes, options),
    }
}

/// Makes imported columns satisfy format-spec/phm-v1.md §5, or refuses them: a negative or
/// non-finite flux is refused (with its photon); `normal` and `incident` vectors of non-unit
/// length are normalised (MeshLab writes unnormalised normals), zero or non-finite ones refused;
/// sparse emitter ids (`emitter = 65535` on one photon) are renumbered 0, 1, … in order.
/// Returns notes of what was changed.
fn sanitise(file: &str, columns: &mut [(ColumnSpec, Vec<u8>)]) -> Result<Vec<String>> {
    let invalid = |message: String| ImportError::Invalid { file: file.to_string(), message };
    let mut notes = Vec::new();
    // Columns are little-endian bytes of no particular alignment: read and write by value.
    let f32s = |b: &[u8]| -> Vec<f32> {
        b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
    };
    for (spec, bytes) in columns.iter_mut() {
        if spec.name == name::FLUX {
            let flux = f32s(bytes);
            if let Some(k) = flux.iter().position(|&c| !(c >= 0.0 && c.is_finite())) {
                let i = k / 3;
                return Err(invalid(format!(
                    "photon {i} has flux {:?} W: flux must be finite and non-negative",
                    &flux[3 * i..3 * i + 3]
                )));
            }
        } else if (spec.name == name::NORMAL || spec.name == name::INCIDENT) && spec.components == 3 {
            let mut v = f32s(bytes);
            let mut fixed = 0usize;
            for (i, x) in v.chunks_exact_mut(3).enumerate() {
                let len = x.iter().map(|c| (*c as f64) * (*c as f64)).sum::<f64>().sqrt();
                if !(len > 0.0 && len.is_finite()) {
                    return Err(invalid(format!(
                        "photon {i} has a '{}' vector {x:?} of no direction: it must be a unit vector",
                        spec.name
                    )));
                }
                if (len - 1.0).abs() > crate::format::UNIT_TOLERANCE as f64 {
                    x.iter_mut().for_each(|c| *c = (*c as f64 / len) as f32);
                    fixed += 1;
                }
            }
            if fixed > 0 {
                *bytes = v.iter().flat_map(|c| c.to_le_bytes()).collect();
                notes.push(format!("{fixed} '{}' vectors of non-unit length normalised", spec.name));
            }
        } else if spec.name == name::EMITTER {
            let ids: Vec<u16> = bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
            let mut distinct = ids.clone();
            distinct.sort_unstable();
            distinct.dedup();
            if distinct.last().is_some_and(|&m| m as usize + 1 != distinct.len()) {
                let map: std::collections::HashMap<u16, u16> =
                    distinct.iter().enumerate().map(|(k, &id)| (id, k as u16)).collect();
                *bytes = ids.iter().flat_map(|id| map[id].to_le_bytes()).collect();
                let shown: Vec<String> = distinct.iter().take(8).map(u16::to_string).collect();
                notes.push(format!(
                    "emitter ids {}{} renumbered 0 to {}",
                    shown.join(", "),
                    if distinct.len() > 8 { ", …" } else { "" },
                    distinct.len() - 1
                ));
            }
        }
    }
    Ok(notes)
}

/// Longest text a header (PLY, Radiance) or a CSV line may be: anything longer is not a photon
/// file, and is refused before it is read whole (`/dev/zero`, a 200 MB comment line).
pub const MAX_TEXT_LINE: usize = 1 << 20;

/// Reads a whole input, refusing early what cannot be a photon file of its format: a PLY or
/// Radiance header that does not end within [`MAX_TEXT_LINE`] bytes, a CSV line longer than that.
fn read_bounded(
    file: &str,
    path: &Path,
    format: Option<SourceFormat>,
    mut r: impl std::io::Read,
) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let mut chunk = vec![0u8; 1 << 16];
    // The format as far as it can be told (from the option, the first bytes, the extension).
    let mut known: Option<SourceFormat> = format;
    let mut header_done = false;
    let mut line_start = 0usize;
    let refuse = |message: String| ImportError::Invalid { file: file.to_string(), message };
    loop {
        let n = match r.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(source) => return Err(ImportError::Io { file: file.to_string(), source }),
        };
        let from = bytes.len();
        bytes.extend_from_slice(&chunk[..n]);
        if known.is_none() && bytes.len() >= 16 {
            // Told from the first bytes or the extension: if not now, never.
            known = Some(
                SourceFormat::detect(path, &bytes)
                    .ok_or(ImportError::UnknownFormat { file: file.to_string() })?,
            );
        }
        match known {
            Some(SourceFormat::Ply | SourceFormat::Radiance) if !header_done => {
                let end: &[u8] = if known == Some(SourceFormat::Ply) { b"end_header" } else { b"\n\n" };
                let look = from.saturating_sub(end.len());
                if bytes[look..].windows(end.len()).any(|w| w == end) {
                    header_done = true;
                } else if bytes.len() > MAX_TEXT_LINE {
                    let what = if known == Some(SourceFormat::Ply) { "'end_header'" } else { "a blank line" };
                    return Err(refuse(format!(
                        "no {what} ending the header in the first {} MiB: not a {} file",
                        MAX_TEXT_LINE >> 20,
                        known.map_or("", |k| k.name())
                    )));
                }
            }
            Some(SourceFormat::Csv) => {
                for (i, &b) in bytes[from..].iter().enumerate() {
                    if b == b'\n' {
                        line_start = from + i + 1;
                    }
                }
                if bytes.len() - line_start > MAX_TEXT_LINE {
                    let line = bytes[..line_start].iter().filter(|&&b| b == b'\n').count() + 1;
                    return Err(refuse(format!(
                        "line {line} is longer than {} MiB: not a photon table",
                        MAX_TEXT_LINE >> 20
                    )));
                }
            }
            _ => {}
        }
    }
    Ok(bytes)
}

/// Gives imported photons their emitters: one `external` emitter per value of the `emitter`
/// column (one in all when there is none).
///
/// Each emitter's parameterisation is `param_override` when given, else the first, in the order
/// `direction` (only with three `param_*` fields), `rect_uv`, that every one of its photons
/// satisfies by the invariants of format-spec/phm-v1.md §5: so a map with a `rect_uv` and a
/// `direction` emitter, exported and imported again, keeps both. Photons whose parameters fit
/// no parameterisation (or not the one asked for) are refused: the map written would fail
/// `inspect --check`.
pub(crate) fn with_emitters(
    file: &str,
    format: SourceFormat,
    columns: Vec<(ColumnSpec, Vec<u8>)>,
    param_override: Option<Parameterisation>,
    spectral: bool,
    report: Value,
) -> Result<Imported> {
    let invalid = |message: String| ImportError::Invalid { file: file.to_string(), message };
    let mut columns = columns;
    let mut report = report;
    let notes = sanitise(file, &mut columns)?;
    if !notes.is_empty() {
        for n in &notes {
            eprintln!("photonkit import: {file}: {n}");
        }
        if let Some(r) = report.as_object_mut() {
            r.insert("sanitised".into(), notes.into());
        }
    }
    let params: Option<(usize, Vec<f32>)> =
        columns.iter().find(|(s, _)| s.name == name::PARAMS).map(|(s, b)| {
            let v = b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            (s.components as usize, v)
        });
    let dims = params.as_ref().map_or(0, |p| p.0);
    if let Some(p) = param_override {
        let needed = p.dims().ok_or_else(|| invalid("unknown parameterisation".into()))? as usize;
        let padded =
            matches!(p, Parameterisation::RectUv | Parameterisation::RectUvSpectral) && dims == needed + 1;
        if needed != dims && !padded {
            return Err(invalid(format!(
                "parameterisation '{}' needs {needed} trajectory parameters (param_0 …) but the file has {dims}",
                p.name()
            )));
        }
    }
    let ids: Option<Vec<u16>> = columns
        .iter()
        .find(|(s, _)| s.name == name::EMITTER)
        .map(|(_, b)| b.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect());
    let count = ids.as_ref().map_or(1, |v| v.iter().copied().max().map_or(1, |m| m as usize + 1));
    let emitter_of = |i: usize| ids.as_ref().map_or(0, |v| v[i] as usize);
    let flux = &columns.iter().find(|(s, _)| s.name == name::FLUX).expect("layout requires flux").1;
    let mut sums = vec![[0.0f64; 3]; count];
    for (i, f) in flux.chunks_exact(12).enumerate() {
        let sum = &mut sums[emitter_of(i)];
        for (k, c) in f.chunks_exact(4).enumerate() {
            sum[k] += f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64;
        }
    }

    // Candidates per emitter, struck off by the first photon that breaks them.
    let candidates: Vec<Parameterisation> = match (param_override, dims) {
        (Some(p), _) => vec![p],
        (None, 0) => vec![Parameterisation::None],
        (None, 2) => vec![Parameterisation::RectUv],
        // A `wavelength` field after (u, v) or a direction.
        (None, 3) if spectral => vec![Parameterisation::RectUvSpectral],
        (None, 4) if spectral => vec![Parameterisation::DirectionSpectral],
        (None, 3) => vec![Parameterisation::Direction, Parameterisation::RectUv],
        // param_0 … param_3: a spectral map of collimated and point emitters (export names
        // the wavelength `wavelength` only where it is every emitter's last parameter).
        (None, _) => vec![Parameterisation::DirectionSpectral, Parameterisation::RectUvSpectral],
    };
    let mut open: Vec<Vec<Parameterisation>> = vec![candidates.clone(); count];
    if let Some((d, v)) = &params {
        for (i, q) in v.chunks_exact(*d).enumerate() {
            let e = emitter_of(i);
            open[e].retain(|p| p.admits(q));
            if open[e].is_empty() {
                let names: Vec<&str> = candidates.iter().map(|p| p.name()).collect();
                let hint = if param_override.is_some() {
                    "the parameterisation given does not fit"
                } else {
                    "give --parameterisation, or rename the param_* fields to keep them as extra columns"
                };
                return Err(invalid(format!(
                    "photon {i} (emitter {e}) has trajectory parameters {q:?} that fit no parameterisation of {} \
                     (format-spec/phm-v1.md §5: rect_uv in [0, 1]², direction of unit length); {hint}",
                    names.join(" or ")
                )));
            }
        }
    }
    let emitters: Vec<Emitter> =
        sums.iter().enumerate().map(|(id, s)| external_emitter(id as u32, open[id][0], *s)).collect();
    // Three fields but only `rect_uv` emitters: the column holds (u, v, 0) and must have the
    // largest param_dims (2) components (§4.1), so the zeros go.
    if dims == 3
        && emitters.iter().all(|e| e.param_dims < 3)
        && let Some((s, b)) = columns.iter_mut().find(|(s, _)| s.name == name::PARAMS)
    {
        s.components = 2;
        *b = b.chunks_exact(12).flat_map(|q| q[..8].iter().copied()).collect();
    }
    Ok(Imported { format, columns, emitters, report })
}

/// An emitter known only by its photons: power is the flux that reached the map (a lower
/// bound on what was emitted), colour that flux's relative RGB.
pub(crate) fn external_emitter(id: u32, p: Parameterisation, flux_w: [f64; 3]) -> Emitter {
    let max = flux_w.iter().copied().fold(0.0f64, f64::max);
    let colour = if max > 0.0 { flux_w.map(|c| (c / max) as f32) } else { [1.0; 3] };
    Emitter {
        id,
        kind: EmitterKind::External,
        parameterisation: p,
        param_dims: p.dims().unwrap_or(0),
        power_w: flux_w.iter().sum(),
        colour,
        param_measure: None,
        geometry: Value::Null,
        dimensions: if p.spectral_component().is_some() { p.dimensions() } else { Vec::new() },
        extra: Default::default(),
    }
}

/// The parameters recorded for an import stage.
pub fn stage_parameters(path: &Path, format: SourceFormat, options: &Options) -> Value {
    json!({
        "from": path.display().to_string(),
        "format": format.name(),
        "parameterisation": options.parameterisation.map(|p| serde_json::to_value(p).unwrap_or(Value::Null)),
        "caustic_only": options.caustic_only,
    })
}
