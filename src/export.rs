//! Photons out to point-cloud viewers (MeshLab, CloudCompare, ParaView): PLY and CSV.
//!
//! Both forms name every column with the text names of format-spec/phm-v1.md §7 (mapping in
//! format-spec/import.md), in file order, so `photonkit import` reads them back to the same
//! f32 bits. The PLY file is binary
//! little-endian with one `vertex` per photon: flux stays as float `flux_r flux_g flux_b`
//! (watts) and 8-bit `red green blue` are added for display; normals are `nx ny nz`, which
//! the viewers shade with. PLY has no 64-bit integers: u64/i64 columns are written as
//! `double`, exact up to 2⁵³ (larger values are refused rather than rounded).

use std::io::Write;
use std::path::Path;

use crate::format::columns::text_names_in;
use crate::format::{DType, Output, PhotonMap};

/// Everything that can go wrong writing an export.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportError {
    /// Writing the output failed.
    #[error("{file}: {source}")]
    Io {
        /// The output as named to the user.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// A value the format can not hold so that `import` reads it back the same.
    #[error("{file}: column '{column}', photon {photon}: {message}")]
    Value {
        /// The map or output as named to the user.
        file: String,
        /// The column holding the value.
        column: String,
        /// The photon's index (0-based).
        photon: usize,
        /// Why the value can not be written.
        message: String,
    },
    /// A column whose name can not be a field name of the format.
    #[error("{file}: column '{column}' can not be named in {format}: {message}")]
    Name {
        /// The output as named to the user.
        file: String,
        /// The column's name.
        column: String,
        /// `PLY` or `CSV`.
        format: &'static str,
        /// Why the name does not fit.
        message: String,
    },
}

/// A result whose error is an [`ExportError`].
pub type Result<T, E = ExportError> = std::result::Result<T, E>;

/// The formats `photonkit export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// Binary little-endian PLY, one `vertex` per photon.
    Ply,
    /// Comma-separated text with a header row.
    Csv,
}

impl ExportFormat {
    /// The file name extension (`ply`, `csv`).
    pub fn extension(self) -> &'static str {
        match self {
            ExportFormat::Ply => "ply",
            ExportFormat::Csv => "csv",
        }
    }
}

/// Writes `map` to `target` through a temporary file beside it, renamed into place only when
/// complete (standard output is written directly).
pub fn export(map: &PhotonMap, to: ExportFormat, target: &Output) -> Result<()> {
    match target {
        Output::Stdout => {
            let file = "<stdout>";
            let mut out = std::io::BufWriter::new(std::io::stdout().lock());
            write(map, to, &mut out, file)?;
            out.flush().map_err(|source| ExportError::Io { file: file.into(), source })
        }
        Output::Path(p) => {
            let file = p.display().to_string();
            let io = |source| ExportError::Io { file: file.clone(), source };
            let tmp = crate::format::temp_beside(p, ".export-").map_err(io)?;
            let mut out = std::io::BufWriter::new(tmp);
            write(map, to, &mut out, &file)?;
            let tmp = out.into_inner().map_err(|e| io(e.into_error()))?;
            crate::format::persist(tmp, p).map_err(io)?;
            Ok(())
        }
    }
}

/// Writes the export to any stream; `file` names it in errors.
pub fn write(map: &PhotonMap, to: ExportFormat, out: &mut dyn Write, file: &str) -> Result<()> {
    // A value `import` refuses is refused here too, before anything is written.
    for (spec, bytes) in map.columns() {
        let width = match spec.dtype {
            DType::F32 => 4,
            DType::F64 => 8,
            _ => continue,
        };
        let finite = |c: &[u8]| match width {
            4 => f32::from_le_bytes(c.try_into().unwrap()).is_finite(),
            _ => f64::from_le_bytes(c.try_into().unwrap()).is_finite(),
        };
        if let Some(k) = bytes.chunks_exact(width).position(|c| !finite(c)) {
            return Err(ExportError::Value {
                file: map.file_name().to_string(),
                column: spec.name.clone(),
                photon: k / spec.components.max(1) as usize,
                message: "not a finite number (`import` would refuse the file)".into(),
            });
        }
    }
    match to {
        ExportFormat::Ply => write_ply(map, out, file),
        ExportFormat::Csv => write_csv(map, out, file),
    }
}

fn ply_type(d: DType) -> &'static str {
    match d {
        DType::U8 => "uchar",
        DType::I8 => "char",
        DType::U16 => "ushort",
        DType::I16 => "short",
        DType::U32 => "uint",
        DType::I32 => "int",
        DType::F32 => "float",
        DType::F64 | DType::U64 | DType::I64 => "double",
    }
}

/// Largest integer a double holds exactly.
const MAX_EXACT: u64 = 1 << 53;

/// 8-bit display colour of each photon: flux over the map's largest channel, gamma 1/2.2 so
/// dim caustic photons stay visible.
fn display_colours(flux: &[[f32; 3]]) -> impl Fn(usize) -> [u8; 3] + '_ {
    let max = flux.iter().flatten().copied().filter(|x| x.is_finite()).fold(0.0f32, f32::max);
    move |i| {
        flux[i].map(|c| {
            if max > 0.0 && c > 0.0 { ((c / max).min(1.0).powf(1.0 / 2.2) * 255.0).round() as u8 } else { 0 }
        })
    }
}

/// Refuses column names the output can not carry so that `import` reads them back: PLY
/// property names are single words and `red green blue` are the display colours; CSV fields
/// are unquoted and trimmed on import.
fn check_names(map: &PhotonMap, to: ExportFormat, file: &str) -> Result<()> {
    let (format, bad_char): (&str, fn(char) -> bool) = match to {
        ExportFormat::Ply => ("PLY", |c| c.is_whitespace() || c.is_control()),
        ExportFormat::Csv => ("CSV", |c| c == ',' || c == '"' || c.is_whitespace() || c.is_control()),
    };
    for c in &map.meta().columns {
        let message = if c.name.chars().any(bad_char) {
            "it holds white space, a control character or a delimiter"
        } else if to == ExportFormat::Ply && ["red", "green", "blue"].contains(&c.name.as_str()) {
            "the export adds red green blue display colours under that name"
        } else {
            continue;
        };
        return Err(ExportError::Name {
            file: file.into(),
            column: c.name.clone(),
            format,
            message: message.into(),
        });
    }
    Ok(())
}

/// A 64-bit integer as a PLY `double`, when the double holds it exactly.
fn as_double(dtype: DType, a: [u8; 8]) -> Option<f64> {
    if dtype == DType::U64 {
        let v = u64::from_le_bytes(a);
        (v <= MAX_EXACT).then_some(v as f64)
    } else {
        let v = i64::from_le_bytes(a);
        (v.unsigned_abs() <= MAX_EXACT).then_some(v as f64)
    }
}

fn write_ply(map: &PhotonMap, out: &mut dyn Write, file: &str) -> Result<()> {
    check_names(map, ExportFormat::Ply, file)?;
    // Checked before the first byte goes out, so standard output gets all or nothing.
    for (s, b) in map.columns().iter().filter(|(s, _)| matches!(s.dtype, DType::U64 | DType::I64)) {
        if let Some(at) =
            b.chunks_exact(8).position(|c| as_double(s.dtype, c.try_into().expect("8")).is_none())
        {
            return Err(ExportError::Value {
                file: file.into(),
                column: s.name.clone(),
                photon: at / s.components as usize,
                message: "the value exceeds 2^53 and PLY's double can not hold it exactly".into(),
            });
        }
    }
    let io = |source| ExportError::Io { file: file.into(), source };
    let cols = map.columns();
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    header.push_str(
        "comment photonkit export (format-spec/import.md): flux_* in watts, red green blue for display\n",
    );
    header.push_str(&format!("element vertex {}\n", map.len()));
    for (s, _) in &cols {
        for t in text_names_in(&map.meta().emitters, &s.name, s.components) {
            header.push_str(&format!("property {} {t}\n", ply_type(s.dtype)));
        }
    }
    header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n");
    out.write_all(header.as_bytes()).map_err(io)?;
    let colour = display_colours(map.flux());
    let mut rec = Vec::new();
    for i in 0..map.len() {
        rec.clear();
        for (s, b) in &cols {
            let stride = s.stride() as usize;
            let bytes = &b[i * stride..(i + 1) * stride];
            match s.dtype {
                DType::U64 | DType::I64 => {
                    for c in bytes.chunks_exact(8) {
                        let a: [u8; 8] = c.try_into().expect("8 bytes");
                        rec.extend_from_slice(&as_double(s.dtype, a).unwrap_or(f64::NAN).to_le_bytes());
                    }
                }
                _ => rec.extend_from_slice(bytes),
            }
        }
        rec.extend_from_slice(&colour(i));
        out.write_all(&rec).map_err(io)?;
    }
    Ok(())
}

fn write_csv(map: &PhotonMap, out: &mut dyn Write, file: &str) -> Result<()> {
    check_names(map, ExportFormat::Csv, file)?;
    let io = |source| ExportError::Io { file: file.into(), source };
    let cols = map.columns();
    let header: Vec<String> =
        cols.iter().flat_map(|(s, _)| text_names_in(&map.meta().emitters, &s.name, s.components)).collect();
    writeln!(out, "{}", header.join(",")).map_err(io)?;
    let mut line = String::new();
    for i in 0..map.len() {
        line.clear();
        for (s, b) in &cols {
            for k in 0..s.components as usize {
                if !line.is_empty() {
                    line.push(',');
                }
                s.dtype.format_value(b, i * s.components as usize + k, &mut line);
            }
        }
        line.push('\n');
        out.write_all(line.as_bytes()).map_err(io)?;
    }
    Ok(())
}

/// The default output path: the input's with the format's extension.
pub fn default_output(input: &str, to: ExportFormat) -> Output {
    if input == "-" {
        return Output::Stdout;
    }
    Output::Path(Path::new(input).with_extension(to.extension()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_colours_scale_by_the_brightest_channel() {
        let flux = [[1.0, 0.5, 0.0], [0.25, 0.0, 0.0]];
        let c = display_colours(&flux);
        assert_eq!(c(0)[0], 255);
        assert_eq!(c(0)[2], 0);
        assert!(c(1)[0] > 64, "gamma lifts dim photons");
    }
}
