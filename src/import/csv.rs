//! CSV and TSV tables with a header row of format-spec/phm-v1.md §7 names → photon columns.
//!
//! The delimiter is a tab when the header row holds one (the TSV `inspect --dump` writes),
//! a comma otherwise. Values are parsed straight into their column's type, so the shortest
//! decimal text `inspect --dump` and `export --to csv` write reads back to the same bits.
//! Fields are plain: no quoting (photon tables hold numbers only).

use super::{At, Columns, Field, ImportError, Options, Result, SourceFormat, layout, with_emitters};
use crate::format::DType;

/// Reads a delimited table as photons.
pub fn read(file: &str, bytes: &[u8], options: &Options) -> Result<super::Imported> {
    let text = std::str::from_utf8(bytes).map_err(|e| ImportError::Malformed {
        file: file.into(),
        at: At::Byte(e.valid_up_to() as u64),
        message: "a CSV/TSV file must be UTF-8 text".into(),
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines =
        text.lines().enumerate().map(|(i, l)| (i as u64 + 1, l)).filter(|(_, l)| !l.trim().is_empty());
    let (header_line, header) = lines.next().ok_or_else(|| ImportError::Invalid {
        file: file.into(),
        message: "the file is empty: no header row".into(),
    })?;
    let delim = if header.contains('\t') { '\t' } else { ',' };
    let unquote = |s: &str| {
        let s = s.trim();
        s.strip_prefix('"').and_then(|s| s.strip_suffix('"')).unwrap_or(s).to_string()
    };
    let names: Vec<String> = header.split(delim).map(unquote).collect();
    if names.iter().any(|n| n.parse::<f64>().is_ok()) {
        return Err(ImportError::Malformed {
            file: file.into(),
            at: At::Line(header_line),
            message: "the first row must name the columns (x, y, z, flux_r, …), not hold numbers".into(),
        });
    }
    let rows: Vec<(u64, &str)> = lines.collect();
    let fields: Vec<Field> = names
        .iter()
        .map(|n| Field { name: n, dtype: None, colour_max: None, at: At::Line(header_line) })
        .collect();
    let lay = layout(file, &fields, &|i| {
        infer(rows.iter().map(|(_, l)| l.split(delim).nth(i).unwrap_or("").trim()))
    })?;
    let mut cols = Columns::new(file, lay.specs, rows.len());
    for &(ln, line) in &rows {
        cols.begin_row();
        let mut n = 0;
        for (i, value) in line.split(delim).enumerate() {
            n = i + 1;
            let Some(Some(slot)) = lay.slots.get(i) else { continue };
            cols.set_text(*slot, value.trim(), At::Line(ln), &names[i])?;
        }
        if n != names.len() {
            return Err(ImportError::Malformed {
                file: file.into(),
                at: At::Line(ln),
                message: format!("expected {} values (one per header name), found {n}", names.len()),
            });
        }
    }
    let report = serde_json::json!({
        "delimiter": if delim == '\t' { "tab" } else { "comma" },
        "photons": cols.rows(),
        "fields": names,
    });
    with_emitters(file, SourceFormat::Csv, cols.into_columns(), options.parameterisation, report)
}

/// The type of a column this importer does not know, from its text: integers as i64, floats
/// as f32 when every value is written as the shortest text of an f32 (as photonkit writes
/// f32 columns, so they come back as f32), f64 otherwise.
fn infer<'a>(values: impl Iterator<Item = &'a str> + Clone) -> DType {
    if values.clone().all(|v| v.parse::<i64>().is_ok()) {
        return DType::I64;
    }
    let shortest_f32 = |v: &str| v.parse::<f32>().is_ok_and(|x| x.to_string() == v);
    if values.clone().all(shortest_f32) { DType::F32 } else { DType::F64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tsv_and_csv_read_alike() {
        let tsv = "x\ty\tz\tflux_r\tflux_g\tflux_b\tbounces\n0.1\t0.2\t0\t1\t2\t3\t2\n";
        let csv = tsv.replace('\t', ",");
        for t in [tsv.to_string(), csv] {
            let m = read("t", t.as_bytes(), &Options::default()).unwrap();
            let pos: &[f32] = bytemuck::cast_slice(m.column("position").unwrap());
            assert_eq!(pos, [0.1, 0.2, 0.0]);
            assert_eq!(m.column("bounces").unwrap(), [2]);
        }
    }

    #[test]
    fn extra_columns_get_types_from_their_text() {
        assert_eq!(infer(["1", "-2"].into_iter()), DType::I64);
        assert_eq!(infer(["0.1", "2"].into_iter()), DType::F32);
        assert_eq!(infer(["0.1000000000000000055511151231257827"].into_iter()), DType::F64);
    }

    #[test]
    fn bad_rows_name_their_line() {
        let t = "x,y,z,flux_r,flux_g,flux_b\n1,2,3,1,1,1\n\n1,2,nan,1,1,1\n";
        let e = read("t.csv", t.as_bytes(), &Options::default()).unwrap_err().to_string();
        assert!(e.contains("t.csv: line 4") && e.contains("'z'"), "{e}");
        let t = "x,y,z,flux_r,flux_g,flux_b\n1,2,3,1,1\n";
        let e = read("t.csv", t.as_bytes(), &Options::default()).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("found 5"), "{e}");
    }
}
