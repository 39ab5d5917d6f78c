//! Field names → columns, shared by PLY and CSV: the text names of format-spec/phm-v1.md §7
//! (and display colours, and runs `c_0 … c_{n-1}`) turned into PHM columns ([`layout`]), and
//! the columns filled photon by photon with every value checked against its column's type
//! ([`Columns`]).

use crate::format::columns::{KNOWN_COLUMNS, KnownColumn, WAVELENGTH_TEXT_NAME};
use std::collections::HashMap;

use crate::format::{ColumnSpec, DType, name};

use super::{At, ImportError, Result};

/// Where one named field of the source goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Slot {
    pub col: usize,
    pub comp: usize,
    /// Multiplier applied to the value (8-bit colours read as flux: 1/255).
    pub scale: Option<f64>,
}

/// The columns a list of field names makes, and where each field goes (`None`: ignored).
#[derive(Clone, Debug)]
pub(crate) struct Layout {
    pub specs: Vec<ColumnSpec>,
    pub slots: Vec<Option<Slot>>,
    /// Whether a `wavelength` field became the last component of `params` (a spectral
    /// parameterisation; docs/spectral.md).
    pub spectral: bool,
}

/// What the layout needs to know of one source field.
pub(crate) struct Field<'a> {
    pub name: &'a str,
    /// The field's own element type where the source declares one (PLY); `None` for text.
    pub dtype: Option<DType>,
    /// Largest integer value of the field's type (for colours: 255 for uchar).
    pub colour_max: Option<f64>,
    pub at: At,
}

const COLOUR_NAMES: [&str; 3] = ["red", "green", "blue"];

fn known_field(name: &str) -> Option<(&'static KnownColumn, usize)> {
    KNOWN_COLUMNS.iter().find_map(|k| k.text_names.iter().position(|t| *t == name).map(|i| (k, i)))
}

/// The name a field is read under: a known name (format-spec/phm-v1.md §7, or a display
/// colour) in any case and with CloudCompare's `scalar_` prefix becomes that name; any other
/// name is kept as written.
pub(crate) fn canonical_name(name: &str) -> String {
    let lower = name.to_ascii_lowercase();
    let base = lower.strip_prefix("scalar_").unwrap_or(&lower);
    if known_field(base).is_some() || COLOUR_NAMES.contains(&base) {
        base.to_string()
    } else {
        name.to_string()
    }
}

/// Maps field names to columns: §4.1's text names to their columns, `red green blue` to flux
/// when there is no `flux_*`, runs `c_0 … c_{n-1}` of other names to one column `c` with n
/// components, and every other name to a column of its own.
pub(crate) fn layout(
    file: &str,
    fields: &[Field],
    flux_from_colour: bool,
    extra_dtype: &dyn Fn(usize) -> DType,
) -> Result<Layout> {
    let bad = |at: At, message: String| ImportError::Malformed { file: file.to_string(), at, message };
    let mut seen = HashMap::new();
    for f in fields {
        if f.name.is_empty() || f.name.len() > 256 {
            return Err(bad(f.at, format!("field name '{}' must be 1 to 256 bytes long", f.name)));
        }
        if seen.insert(f.name, f.at).is_some() {
            return Err(bad(f.at, format!("field '{}' is named twice", f.name)));
        }
    }
    let has_flux = fields.iter().any(|f| f.name.starts_with("flux_") && known_field(f.name).is_some());
    let colours_as_flux = !has_flux && COLOUR_NAMES.iter().all(|c| seen.contains_key(c));
    if colours_as_flux && !flux_from_colour {
        return Err(ImportError::Invalid {
            file: file.to_string(),
            message: "no flux_r flux_g flux_b fields, only red green blue: those are display colours, not \
                      watts (a viewer may have renamed flux_* on saving). Rename the flux fields, or pass \
                      --flux-from-colour to take the colours as flux in W"
                .into(),
        });
    }

    let mut specs: Vec<ColumnSpec> = Vec::new();
    let mut slots: Vec<Option<Slot>> = vec![None; fields.len()];
    let col_of = |specs: &mut Vec<ColumnSpec>, spec: ColumnSpec| -> usize {
        match specs.iter().position(|s| s.name == spec.name) {
            Some(i) => i,
            None => {
                specs.push(spec);
                specs.len() - 1
            }
        }
    };

    // A wavelength beside (u, v) or a direction is their last trajectory parameter.
    let spectral = seen.contains_key(WAVELENGTH_TEXT_NAME) && seen.contains_key("param_0");
    let base_params = if seen.contains_key("param_2") { 3 } else { 2 };
    // Known columns first, in the order of their first field.
    for (i, f) in fields.iter().enumerate() {
        let (known, comp, scale) = if let Some((k, comp)) = known_field(f.name) {
            (k, comp, None)
        } else if spectral && f.name == WAVELENGTH_TEXT_NAME {
            let k = KNOWN_COLUMNS.iter().find(|k| k.name == name::PARAMS).expect("params is known");
            (k, base_params, None)
        } else if let Some(c) = COLOUR_NAMES.iter().position(|c| *c == f.name) {
            if !colours_as_flux {
                continue; // display colours beside flux (as `export` writes them): not data
            }
            let k = KNOWN_COLUMNS.iter().find(|k| k.name == name::FLUX).expect("flux is known");
            (k, c, f.colour_max.map(|m| 1.0 / m))
        } else {
            continue;
        };
        if let Some(d) = f.dtype
            && !fits(d, known.dtype)
        {
            return Err(bad(
                f.at,
                format!(
                    "field '{}' is {} but column '{}' holds {} values",
                    f.name,
                    d.name(),
                    known.name,
                    known.dtype.name()
                ),
            ));
        }
        let comps = if known.name == name::PARAMS {
            if seen.contains_key("param_3") { 4 } else { base_params as u32 + u32::from(spectral) }
        } else {
            known.components[0]
        };
        let col = col_of(&mut specs, ColumnSpec::new(known.name, known.dtype, comps));
        slots[i] = Some(Slot { col, comp, scale });
    }
    check_complete(file, fields, &specs, &slots, &seen, colours_as_flux, spectral)?;
    extra_columns(file, fields, extra_dtype, &mut specs, &mut slots)?;
    Ok(Layout { specs, slots, spectral })
}

/// Refuses a layout that lacks a component of a known column it makes (`z` beside `x y`), or
/// lacks `position` or `flux` altogether.
fn check_complete(
    file: &str,
    fields: &[Field],
    specs: &[ColumnSpec],
    slots: &[Option<Slot>],
    seen: &HashMap<&str, At>,
    colours_as_flux: bool,
    spectral: bool,
) -> Result<()> {
    let bad = |at: At, message: String| ImportError::Malformed { file: file.to_string(), at, message };
    for (ci, s) in specs.iter().enumerate() {
        let names: Vec<&str> = if s.name == name::FLUX && colours_as_flux {
            COLOUR_NAMES.to_vec()
        } else {
            let k = crate::format::columns::known_column(&s.name).expect("known");
            if s.name == name::PARAMS && spectral {
                [&k.text_names[..s.components as usize - 1], &[WAVELENGTH_TEXT_NAME]].concat()
            } else {
                k.text_names[..s.components as usize].to_vec()
            }
        };
        let missing: Vec<&str> = names.iter().copied().filter(|n| !seen.contains_key(n)).collect();
        if !missing.is_empty() {
            let first =
                slots.iter().position(|t| t.is_some_and(|t| t.col == ci)).expect("a field made the column");
            return Err(bad(
                fields[first].at,
                format!(
                    "field '{}' makes column '{}', which needs the fields {}; missing: {}",
                    fields[first].name,
                    s.name,
                    names.join(" "),
                    missing.join(" ")
                ),
            ));
        }
    }
    for required in [name::POSITION, name::FLUX] {
        if !specs.iter().any(|s| s.name == required) {
            let what =
                if required == name::POSITION { "x y z" } else { "flux_r flux_g flux_b (or red green blue)" };
            return Err(ImportError::Invalid {
                file: file.to_string(),
                message: format!("no '{required}' column: the fields {what} are required"),
            });
        }
    }
    Ok(())
}

/// Other fields become extra columns, kept; `c_0 … c_{n-1}` (n ≥ 2, same type) is one column.
fn extra_columns(
    file: &str,
    fields: &[Field],
    extra_dtype: &dyn Fn(usize) -> DType,
    specs: &mut Vec<ColumnSpec>,
    slots: &mut [Option<Slot>],
) -> Result<()> {
    let bad = |at: At, message: String| ImportError::Malformed { file: file.to_string(), at, message };
    // (Names in a set: a table of many thousand columns costs linear time.)
    let mut spec_names: std::collections::HashSet<String> = specs.iter().map(|s| s.name.clone()).collect();
    let mut i = 0;
    while i < fields.len() {
        let f = &fields[i];
        let taken = slots[i].is_some() || known_field(f.name).is_some() || COLOUR_NAMES.contains(&f.name);
        if taken {
            i += 1;
            continue;
        }
        let dtype = f.dtype.unwrap_or_else(|| extra_dtype(i));
        let mut n = 1;
        if let Some(base) = f.name.strip_suffix("_0") {
            while i + n < fields.len()
                && n < 64
                && fields[i + n].name == format!("{base}_{n}")
                && fields[i + n].dtype.unwrap_or_else(|| extra_dtype(i + n)) == dtype
            {
                n += 1;
            }
        }
        let (col_name, n) = match f.name.strip_suffix("_0") {
            Some(base) if n >= 2 && !base.is_empty() => (base.to_string(), n),
            _ => (f.name.to_string(), 1),
        };
        if !spec_names.insert(col_name.clone()) || known_field(&col_name).is_some() {
            return Err(bad(f.at, format!("field '{}' would make a second column '{col_name}'", f.name)));
        }
        specs.push(ColumnSpec::new(&col_name, dtype, n as u32));
        let col = specs.len() - 1;
        for k in 0..n {
            slots[i + k] = Some(Slot { col, comp: k, scale: None });
        }
        i += n;
    }
    Ok(())
}

/// Whether values of type `from` can be stored in a column of type `to` without losing their
/// meaning: anything into floats, integers into integers (each value range-checked), and
/// `double` into 64-bit integers (PLY has no 64-bit integer type; values checked integral).
fn fits(from: DType, to: DType) -> bool {
    match to {
        DType::F32 | DType::F64 => true,
        DType::U64 | DType::I64 => !matches!(from, DType::F32),
        _ => !from.is_float(),
    }
}

/// Photon columns being filled row by row.
pub(crate) struct Columns<'f> {
    file: &'f str,
    pub specs: Vec<ColumnSpec>,
    pub data: Vec<Vec<u8>>,
    rows: usize,
}

impl<'f> Columns<'f> {
    /// `rows_hint` must already be capped by what the input's remaining bytes can hold.
    pub fn new(file: &'f str, specs: Vec<ColumnSpec>, rows_hint: usize) -> Self {
        let data = specs.iter().map(|s| Vec::with_capacity(rows_hint * s.stride() as usize)).collect();
        Columns { file, specs, data, rows: 0 }
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Starts a photon: every component zero until set.
    pub fn begin_row(&mut self) {
        for (s, d) in self.specs.iter().zip(&mut self.data) {
            d.resize(d.len() + s.stride() as usize, 0);
        }
        self.rows += 1;
    }

    fn slot_bytes(&mut self, slot: Slot) -> (DType, &mut [u8]) {
        let s = &self.specs[slot.col];
        let size = s.dtype.size() as usize;
        let at = (self.rows - 1) * s.stride() as usize + slot.comp * size;
        (s.dtype, &mut self.data[slot.col][at..at + size])
    }

    fn err(&self, at: At, field: &str, message: String) -> ImportError {
        ImportError::Malformed {
            file: self.file.to_string(),
            at,
            message: format!("field '{field}': {message}"),
        }
    }

    /// Stores a float value in the current photon.
    pub fn set_f64(&mut self, slot: Slot, v: f64, at: At, field: &str) -> Result<()> {
        let v = slot.scale.map_or(v, |s| v * s);
        let (dtype, b) = self.slot_bytes(slot);
        if !v.is_finite() {
            return Err(self.err(at, field, format!("{v} is not a finite number")));
        }
        match dtype {
            DType::F32 => {
                let x = v as f32;
                if !x.is_finite() {
                    return Err(self.err(at, field, format!("{v} is out of the range of f32")));
                }
                b.copy_from_slice(&x.to_le_bytes());
            }
            DType::F64 => b.copy_from_slice(&v.to_le_bytes()),
            _ => {
                if v.fract() != 0.0 || v.abs() > 9.007_199_254_740_992e15 {
                    return Err(self.err(at, field, format!("{v} is not an integer exactly representable")));
                }
                return self.set_i128(slot, v as i128, at, field);
            }
        }
        Ok(())
    }

    /// Stores an integer value in the current photon, range-checked against the column type.
    pub fn set_i128(&mut self, slot: Slot, v: i128, at: At, field: &str) -> Result<()> {
        if slot.scale.is_some() {
            return self.set_f64(slot, v as f64, at, field);
        }
        let (dtype, b) = self.slot_bytes(slot);
        let ok = match dtype {
            DType::U8 => u8::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::U16 => u16::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::U32 => u32::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::U64 => u64::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::I8 => i8::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::I16 => i16::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::I32 => i32::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::I64 => i64::try_from(v).map(|x| b.copy_from_slice(&x.to_le_bytes())).is_ok(),
            DType::F32 => {
                b.copy_from_slice(&(v as f32).to_le_bytes());
                true
            }
            DType::F64 => {
                b.copy_from_slice(&(v as f64).to_le_bytes());
                true
            }
        };
        if !ok {
            return Err(self.err(at, field, format!("{v} does not fit in {}", dtype.name())));
        }
        Ok(())
    }

    /// Parses text straight into the column's type (so a shortest-form f32 reads back exactly).
    pub fn set_text(&mut self, slot: Slot, text: &str, at: At, field: &str) -> Result<()> {
        let dtype = self.specs[slot.col].dtype;
        if slot.scale.is_none() && dtype == DType::F32 {
            let x: f32 =
                text.parse().map_err(|_| self.err(at, field, format!("'{text}' is not a number")))?;
            if !x.is_finite() {
                return Err(self.err(at, field, format!("'{text}' is not a finite f32")));
            }
            self.slot_bytes(slot).1.copy_from_slice(&x.to_le_bytes());
            return Ok(());
        }
        if slot.scale.is_none() && !dtype.is_float() {
            let v: i128 =
                text.parse().map_err(|_| self.err(at, field, format!("'{text}' is not an integer")))?;
            return self.set_i128(slot, v, at, field);
        }
        let v: f64 = text.parse().map_err(|_| self.err(at, field, format!("'{text}' is not a number")))?;
        self.set_f64(slot, v, at, field)
    }

    pub fn into_columns(self) -> Vec<(ColumnSpec, Vec<u8>)> {
        self.specs.into_iter().zip(self.data).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fields<'a>(names: &[&'a str]) -> Vec<Field<'a>> {
        names
            .iter()
            .enumerate()
            .map(|(i, n)| Field { name: n, dtype: None, colour_max: None, at: At::Line(i as u64) })
            .collect()
    }

    #[test]
    fn names_map_to_columns_and_extras_group() {
        let f =
            fields(&["x", "y", "z", "flux_r", "flux_g", "flux_b", "w_0", "w_1", "q", "red", "green", "blue"]);
        let l = layout("t", &f, true, &|_| DType::F32).unwrap();
        let names: Vec<_> = l.specs.iter().map(|s| (s.name.as_str(), s.components)).collect();
        assert_eq!(names, [("position", 3), ("flux", 3), ("w", 2), ("q", 1)]);
        assert!(l.slots[9].is_none(), "display colours beside flux are dropped");
    }

    #[test]
    fn colours_become_flux_and_missing_components_are_named() {
        let f = fields(&["x", "y", "z", "red", "green", "blue"]);
        let l = layout("t", &f, true, &|_| DType::F32).unwrap();
        assert_eq!(l.specs[1].name, "flux");
        let e = layout("t", &f, false, &|_| DType::F32).unwrap_err().to_string();
        assert!(e.contains("--flux-from-colour"), "colours are flux only when asked: {e}");
        let f = fields(&["x", "y", "flux_r", "flux_g", "flux_b"]);
        let e = layout("t", &f, true, &|_| DType::F32).unwrap_err().to_string();
        assert!(e.contains("missing: z"), "{e}");
    }

    #[test]
    fn integer_columns_refuse_out_of_range_and_fractions() {
        let specs = vec![ColumnSpec::new("bounces", DType::U8, 1)];
        let mut c = Columns::new("t", specs, 0);
        c.begin_row();
        let s = Slot { col: 0, comp: 0, scale: None };
        assert!(c.set_i128(s, 300, At::Line(2), "bounces").unwrap_err().to_string().contains("line 2"));
        assert!(c.set_text(s, "1.5", At::Line(2), "bounces").is_err());
        c.set_text(s, "7", At::Line(2), "bounces").unwrap();
        assert_eq!(c.data[0], [7]);
    }
}
