//! CSV and TSV tables with a header row of format-spec/phm-v1.md §7 names → photon columns.
//!
//! The dialects other tools write are read as format-spec/import.md §3 lists: a header row
//! that may sit in a comment (`# x,y,z` from `numpy.savetxt`, `//X,Y,Z` from CloudCompare),
//! comment lines (`#`) before or among the rows, names in any case and with CloudCompare's
//! `scalar_` prefix, an unnamed first column (a pandas index, ignored), a trailing delimiter,
//! quoted fields, and `,`, `;` or tab as the delimiter. The records are split by the `csv`
//! crate; values are parsed straight into their column's type, so the shortest decimal text
//! `inspect --dump` and `export --to csv` write reads back to the same bits.

use super::{
    At, Columns, Field, ImportError, Options, Result, SourceFormat, canonical_name, layout, with_emitters,
};
use crate::format::DType;

/// The delimiter of a header row: a tab if it holds one, else `;` if it holds one and no
/// comma, else a comma.
fn delimiter(header: &str) -> u8 {
    if header.contains('\t') {
        b'\t'
    } else if header.contains(';') && !header.contains(',') {
        b';'
    } else {
        b','
    }
}

/// The fields of one row of text, split as the `csv` crate splits (quotes honoured).
fn split_header(line: &str, delim: u8) -> Vec<String> {
    let mut r = csv::ReaderBuilder::new()
        .has_headers(false)
        .delimiter(delim)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(line.as_bytes());
    r.records()
        .next()
        .and_then(|r| r.ok())
        .map(|r| r.iter().map(str::to_string).collect())
        .unwrap_or_default()
}

/// Whether a list of names is a header (it names x, y and z, in any case).
fn names_xyz(names: &[String]) -> bool {
    ["x", "y", "z"].iter().all(|c| names.iter().any(|n| n.eq_ignore_ascii_case(c)))
}

/// Reads a delimited table as photons.
pub fn read(file: &str, bytes: &[u8], options: &Options) -> Result<super::Imported> {
    let text = std::str::from_utf8(bytes).map_err(|e| ImportError::Malformed {
        file: file.into(),
        at: At::Byte(e.valid_up_to() as u64),
        message: "a CSV/TSV file must be UTF-8 text".into(),
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let malformed = |line: u64, message: String| ImportError::Malformed {
        file: file.into(),
        at: At::Line(line),
        message,
    };

    let (offset, header, comments) = find_header(text);
    let (header_line, header) = header.ok_or_else(|| ImportError::Invalid {
        file: file.into(),
        message: "the file is empty: no header row".into(),
    })?;
    let delim = delimiter(&header);
    let mut names: Vec<String> = split_header(&header, delim);
    if names.iter().any(|n| n.parse::<f64>().is_ok()) {
        return Err(malformed(
            header_line,
            "the first row must name the columns (x, y, z, flux_r, …), not hold numbers".into(),
        ));
    }
    let mut notes: Vec<String> = Vec::new();
    if comments > 0 {
        notes.push(format!("{comments} comment line(s) before the header skipped"));
    }
    // A trailing delimiter makes an unnamed last field; an unnamed first field is an index.
    let trailing = names.len() > 1 && names.last().is_some_and(|n| n.is_empty());
    if trailing {
        names.pop();
    }
    let index = names.len() > 1 && (names[0].is_empty() || names[0] == "Unnamed: 0");
    if index {
        notes.push(format!("the unnamed first column '{}' (an index) is ignored", names[0]));
    }
    let first = usize::from(index);
    let canonical: Vec<String> = names[first..].iter().map(|n| canonical_name(n)).collect();
    for (n, c) in names[first..].iter().zip(&canonical) {
        if n != c {
            notes.push(format!("field '{n}' read as '{c}'"));
        }
    }

    let rows = records(file, &text.as_bytes()[offset..], header_line, delim, names.len(), trailing)?;

    let fields: Vec<Field> = canonical
        .iter()
        .map(|n| Field { name: n, dtype: None, colour_max: None, at: At::Line(header_line) })
        .collect();
    let lay = layout(file, &fields, options.flux_from_colour, &|i| {
        infer(rows.iter().map(|(_, r)| r.get(i + first).unwrap_or("")))
    })?;
    let lay_spectral = lay.spectral;
    let mut cols = Columns::new(file, lay.specs, rows.len());
    for (ln, record) in &rows {
        cols.begin_row();
        for (i, slot) in lay.slots.iter().enumerate() {
            if let Some(slot) = slot {
                cols.set_text(*slot, &record[i + first], At::Line(*ln), &canonical[i])?;
            }
        }
    }
    let report = serde_json::json!({
        "delimiter": match delim { b'\t' => "tab", b';' => "semicolon", _ => "comma" },
        "photons": cols.rows(),
        "fields": names,
        "notes": notes,
    });
    for n in &notes {
        eprintln!("photonkit import: {file}: {n}");
    }
    let spectral = lay_spectral;
    with_emitters(file, SourceFormat::Csv, cols.into_columns(), options.parameterisation, spectral, report)
}

/// The header: the first line that is not blank and not a comment, or a comment line that
/// names x, y and z (a header written behind `#` or `//`). Returns the byte offset just past
/// it, its 1-based line and text (`None`: no header), and how many comment lines came before.
fn find_header(text: &str) -> (usize, Option<(u64, String)>, usize) {
    let mut offset = 0usize;
    let mut header: Option<(u64, String)> = None;
    let mut comments = 0usize;
    for (i, line) in text.split_inclusive('\n').enumerate() {
        offset += line.len();
        let l = line.trim();
        if l.is_empty() {
            continue;
        }
        let commented = l.strip_prefix("//").or_else(|| l.strip_prefix('#'));
        match commented {
            Some(rest) if !names_xyz(&split_header(rest, delimiter(rest))) => comments += 1,
            Some(rest) => {
                header = Some((i as u64 + 1, rest.trim().to_string()));
                break;
            }
            None => {
                header = Some((i as u64 + 1, l.to_string()));
                break;
            }
        }
    }
    (offset, header, comments)
}

/// The rows after the header (`data`, whose first line is file line `header_line + 1`), split
/// by the csv crate: one record per line, `#` lines and blank lines skipped, each with its
/// 1-based file line. A row of other than `expected` values is refused, except for the empty
/// last value a `trailing` delimiter leaves.
fn records(
    file: &str,
    data: &[u8],
    header_line: u64,
    delim: u8,
    expected: usize,
    trailing: bool,
) -> Result<Vec<(u64, csv::StringRecord)>> {
    let malformed = |line: u64, message: String| ImportError::Malformed {
        file: file.into(),
        at: At::Line(line),
        message,
    };
    // 1-based file line of a byte offset into the rows (from the offsets of the line ends).
    let line_ends: Vec<usize> =
        data.iter().enumerate().filter(|(_, b)| **b == b'\n').map(|(i, _)| i).collect();
    // (A record's position may be that of the blank lines before it: skip them.)
    let line_at = |byte: u64| {
        let mut b = byte as usize;
        while b < data.len() && matches!(data[b], b'\n' | b'\r') {
            b += 1;
        }
        header_line + 1 + line_ends.partition_point(|&e| e < b) as u64
    };
    // The rows, split by the csv crate: one record per line, `#` lines skipped.
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .delimiter(delim)
        .flexible(true)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(data);
    let mut rows: Vec<(u64, csv::StringRecord)> = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map_or(header_line, |p| line_at(p.byte()));
            malformed(line, format!("unreadable row: {e}"))
        })?;
        let line = record.position().map_or(header_line, |p| line_at(p.byte()));
        if record.len() == 1 && record[0].is_empty() {
            continue; // a blank line
        }
        let n = if trailing && record.len() == expected + 1 && record[expected].is_empty() {
            expected
        } else {
            record.len()
        };
        if n != expected {
            return Err(malformed(
                line,
                format!("expected {expected} values (one per header name), found {n}"),
            ));
        }
        rows.push((line, record));
    }
    Ok(rows)
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

    /// One photon at (1, 2, 3) with flux (4, 5, 6) W, read from `text`.
    fn reads_one_photon(text: &str) {
        let m =
            read("t.csv", text.as_bytes(), &Options::default()).unwrap_or_else(|e| panic!("{text:?}: {e}"));
        let pos: &[f32] = bytemuck::cast_slice(m.column("position").unwrap());
        let flux: &[f32] = bytemuck::cast_slice(m.column("flux").unwrap());
        assert_eq!((pos, flux), (&[1.0, 2.0, 3.0][..], &[4.0, 5.0, 6.0][..]), "{text:?}");
    }

    #[test]
    fn the_dialects_other_tools_write_are_read() {
        // numpy.savetxt(..., header="x,y,z,flux_r,flux_g,flux_b", delimiter=",")
        reads_one_photon("# x,y,z,flux_r,flux_g,flux_b\n1,2,3,4,5,6\n");
        // a comment line first, and comments among the rows
        reads_one_photon("# written by my tracer\nx,y,z,flux_r,flux_g,flux_b\n# first photon\n1,2,3,4,5,6\n");
        // upper-case names
        reads_one_photon("X,Y,Z,FLUX_R,Flux_G,flux_b\n1,2,3,4,5,6\n");
        // CloudCompare: `//` header, scalar_ prefixes
        reads_one_photon("//X,Y,Z,scalar_flux_r,scalar_flux_g,scalar_flux_b\n1,2,3,4,5,6\n");
        // pandas to_csv with its index column
        reads_one_photon(",x,y,z,flux_r,flux_g,flux_b\n0,1,2,3,4,5,6\n");
        reads_one_photon("Unnamed: 0,x,y,z,flux_r,flux_g,flux_b\n0,1,2,3,4,5,6\n");
        // a trailing delimiter on every line
        reads_one_photon("x,y,z,flux_r,flux_g,flux_b,\n1,2,3,4,5,6,\n");
        // quoted names and values
        reads_one_photon("\"x\",\"y\",\"z\",\"flux_r\",\"flux_g\",\"flux_b\"\n\"1\",\"2\",\"3\",4,5,6\n");
        // semicolons (European spreadsheets) and tabs
        reads_one_photon("x;y;z;flux_r;flux_g;flux_b\n1;2;3;4;5;6\n");
        reads_one_photon("x\ty\tz\tflux_r\tflux_g\tflux_b\n1\t2\t3\t4\t5\t6\n");
        // Windows line ends
        reads_one_photon("x,y,z,flux_r,flux_g,flux_b\r\n1,2,3,4,5,6\r\n");
    }

    #[test]
    fn many_columns_cost_linear_time() {
        // 20 000 extra columns: quadratic handling took seconds at 16 000.
        let n = 20_000;
        let mut text = String::from("x,y,z,flux_r,flux_g,flux_b");
        for i in 0..n {
            text.push_str(&format!(",c{i}x"));
        }
        text.push_str("\n1,2,3,4,5,6");
        for _ in 0..n {
            text.push_str(",1");
        }
        text.push('\n');
        let start = std::time::Instant::now();
        let m = read("t.csv", text.as_bytes(), &Options::default()).unwrap();
        assert_eq!(m.columns.len(), 2 + n);
        // Generous even for a debug build on a loaded machine; quadratic took minutes here.
        assert!(start.elapsed().as_secs_f64() < 20.0, "{:?}", start.elapsed());
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
