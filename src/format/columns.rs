//! Element types and the catalogue of columns photonkit knows (format-spec/phm-v1.md §4).

use serde::{Deserialize, Serialize};

/// The element type of a column. Fixed for major version 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DType {
    /// Unsigned 8-bit integer.
    U8,
    /// Unsigned 16-bit integer.
    U16,
    /// Unsigned 32-bit integer.
    U32,
    /// Unsigned 64-bit integer.
    U64,
    /// Signed 8-bit integer.
    I8,
    /// Signed 16-bit integer.
    I16,
    /// Signed 32-bit integer.
    I32,
    /// Signed 64-bit integer.
    I64,
    /// IEEE 754 single precision.
    F32,
    /// IEEE 754 double precision.
    F64,
}

impl DType {
    /// Size of one component in bytes.
    pub fn size(self) -> u64 {
        match self {
            DType::U8 | DType::I8 => 1,
            DType::U16 | DType::I16 => 2,
            DType::U32 | DType::I32 | DType::F32 => 4,
            DType::U64 | DType::I64 | DType::F64 => 8,
        }
    }

    /// Whether this is `f32` or `f64`.
    pub fn is_float(self) -> bool {
        matches!(self, DType::F32 | DType::F64)
    }

    /// The type's name in the metadata (`u8` … `f64`).
    pub fn name(self) -> &'static str {
        match self {
            DType::U8 => "u8",
            DType::U16 => "u16",
            DType::U32 => "u32",
            DType::U64 => "u64",
            DType::I8 => "i8",
            DType::I16 => "i16",
            DType::I32 => "i32",
            DType::I64 => "i64",
            DType::F32 => "f32",
            DType::F64 => "f64",
        }
    }

    /// Reads component `i` of a little-endian byte slice as f64 (for statistics and text dumps).
    pub fn value_f64(self, bytes: &[u8], i: usize) -> f64 {
        let s = self.size() as usize;
        let b = &bytes[i * s..(i + 1) * s];
        match self {
            DType::U8 => b[0] as f64,
            DType::I8 => b[0] as i8 as f64,
            DType::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            DType::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            DType::U32 => u32::from_le_bytes(b.try_into().expect("4")) as f64,
            DType::I32 => i32::from_le_bytes(b.try_into().expect("4")) as f64,
            DType::U64 => u64::from_le_bytes(b.try_into().expect("8")) as f64,
            DType::I64 => i64::from_le_bytes(b.try_into().expect("8")) as f64,
            DType::F32 => f32::from_le_bytes(b.try_into().expect("4")) as f64,
            DType::F64 => f64::from_le_bytes(b.try_into().expect("8")),
        }
    }

    /// Writes component `i` as text that parses back to the same bits.
    pub fn format_value(self, bytes: &[u8], i: usize, out: &mut String) {
        use std::fmt::Write;
        let s = self.size() as usize;
        let b = &bytes[i * s..(i + 1) * s];
        let _ = match self {
            DType::U8 => write!(out, "{}", b[0]),
            DType::I8 => write!(out, "{}", b[0] as i8),
            DType::U16 => write!(out, "{}", u16::from_le_bytes([b[0], b[1]])),
            DType::I16 => write!(out, "{}", i16::from_le_bytes([b[0], b[1]])),
            DType::U32 => write!(out, "{}", u32::from_le_bytes(b.try_into().expect("4"))),
            DType::I32 => write!(out, "{}", i32::from_le_bytes(b.try_into().expect("4"))),
            DType::U64 => write!(out, "{}", u64::from_le_bytes(b.try_into().expect("8"))),
            DType::I64 => write!(out, "{}", i64::from_le_bytes(b.try_into().expect("8"))),
            // Rust's Display for floats prints the shortest text that round-trips.
            DType::F32 => write!(out, "{}", f32::from_le_bytes(b.try_into().expect("4"))),
            DType::F64 => write!(out, "{}", f64::from_le_bytes(b.try_into().expect("8"))),
        };
    }
}

/// A Rust type that is the exact in-memory image of one photon's entry in a column.
pub trait Element: bytemuck::Pod {
    /// The column's element type.
    const DTYPE: DType;
    /// Components per photon (3 for `[f32; 3]`).
    const COMPONENTS: u32;
}

macro_rules! element {
    ($t:ty, $d:expr) => {
        impl Element for $t {
            const DTYPE: DType = $d;
            const COMPONENTS: u32 = 1;
        }
        impl Element for [$t; 2] {
            const DTYPE: DType = $d;
            const COMPONENTS: u32 = 2;
        }
        impl Element for [$t; 3] {
            const DTYPE: DType = $d;
            const COMPONENTS: u32 = 3;
        }
    };
}
element!(u8, DType::U8);
element!(u16, DType::U16);
element!(u32, DType::U32);
element!(u64, DType::U64);
element!(i8, DType::I8);
element!(i16, DType::I16);
element!(i32, DType::I32);
element!(i64, DType::I64);
element!(f32, DType::F32);
element!(f64, DType::F64);

/// Names of the columns defined by PHM 1.0.
pub mod name {
    /// World position of the photon on the diffuse surface, metres. f32×3, required.
    pub const POSITION: &str = "position";
    /// Flux carried by the photon, watts per RGB channel. f32×3, required.
    pub const FLUX: &str = "flux";
    /// Unit surface normal at the photon. f32×3.
    pub const NORMAL: &str = "normal";
    /// Unit direction of travel of the photon when it arrived. f32×3.
    pub const INCIDENT: &str = "incident";
    /// Index into the metadata's emitter list. u16×1.
    pub const EMITTER: &str = "emitter";
    /// Primal trajectory parameters: (u,v) on a collimated emitter or a unit emission direction.
    /// f32×2 or f32×3.
    pub const PARAMS: &str = "params";
    /// Length of the path from the emitter to the photon, metres. f32×1.
    pub const PATH_LENGTH: &str = "path_length";
    /// Number of specular interactions on the path. u8×1.
    pub const BOUNCES: &str = "bounces";
    /// The photon's index in its emitter sequence. u64×1.
    pub const EMISSION_INDEX: &str = "emission_index";
    /// Identifier of the surface the photon lies on. u32×1.
    pub const SURFACE: &str = "surface";
    /// Constraint basis vector u_b (Eq. 7), world space. f32×3.
    pub const BASIS_U: &str = "basis_u";
    /// Constraint basis vector v_b, already scaled by its factor (Eq. 7), world space. f32×3.
    pub const BASIS_V: &str = "basis_v";
    /// Normalised second eigenvalue λ2 of the neighbourhood (Eq. 2–6). f32×1.
    pub const LAMBDA2: &str = "lambda2";
    /// Parameter-space search radius r_param (Eq. 1). f32×1.
    pub const R_PARAM: &str = "r_param";
}

/// A column PHM 1.0 defines: its type, allowed component counts and text names.
pub struct KnownColumn {
    /// The column's name in the metadata.
    pub name: &'static str,
    /// Its element type.
    pub dtype: DType,
    /// The component counts it may have.
    pub components: &'static [u32],
    /// Names of the components in text form (TSV, CSV, PLY), for the first allowed count.
    pub text_names: &'static [&'static str],
}

/// Every column PHM 1.0 defines (format-spec/phm-v1.md §4.1).
pub const KNOWN_COLUMNS: &[KnownColumn] = &[
    KnownColumn { name: name::POSITION, dtype: DType::F32, components: &[3], text_names: &["x", "y", "z"] },
    KnownColumn { name: name::NORMAL, dtype: DType::F32, components: &[3], text_names: &["nx", "ny", "nz"] },
    KnownColumn {
        name: name::FLUX,
        dtype: DType::F32,
        components: &[3],
        text_names: &["flux_r", "flux_g", "flux_b"],
    },
    KnownColumn {
        name: name::INCIDENT,
        dtype: DType::F32,
        components: &[3],
        text_names: &["dx", "dy", "dz"],
    },
    KnownColumn { name: name::EMITTER, dtype: DType::U16, components: &[1], text_names: &["emitter"] },
    KnownColumn {
        name: name::PARAMS,
        dtype: DType::F32,
        components: &[2, 3, 4],
        text_names: &["param_0", "param_1", "param_2", "param_3"],
    },
    KnownColumn {
        name: name::PATH_LENGTH,
        dtype: DType::F32,
        components: &[1],
        text_names: &["path_length"],
    },
    KnownColumn { name: name::BOUNCES, dtype: DType::U8, components: &[1], text_names: &["bounces"] },
    KnownColumn {
        name: name::EMISSION_INDEX,
        dtype: DType::U64,
        components: &[1],
        text_names: &["emission_index"],
    },
    KnownColumn { name: name::SURFACE, dtype: DType::U32, components: &[1], text_names: &["surface"] },
    KnownColumn {
        name: name::BASIS_U,
        dtype: DType::F32,
        components: &[3],
        text_names: &["basis_u_x", "basis_u_y", "basis_u_z"],
    },
    KnownColumn {
        name: name::BASIS_V,
        dtype: DType::F32,
        components: &[3],
        text_names: &["basis_v_x", "basis_v_y", "basis_v_z"],
    },
    KnownColumn { name: name::LAMBDA2, dtype: DType::F32, components: &[1], text_names: &["lambda2"] },
    KnownColumn { name: name::R_PARAM, dtype: DType::F32, components: &[1], text_names: &["r_param"] },
];

/// The catalogue entry of the column named `name`, if PHM defines it.
pub fn known_column(name: &str) -> Option<&'static KnownColumn> {
    KNOWN_COLUMNS.iter().find(|k| k.name == name)
}

/// The text names of a column's components: the catalogue's names for a known column,
/// `name` for an unknown scalar column and `name_0`, `name_1`, … otherwise.
pub fn text_names(column: &str, components: u32) -> Vec<String> {
    if let Some(k) = known_column(column) {
        return k.text_names[..components as usize].iter().map(|s| s.to_string()).collect();
    }
    if components == 1 {
        vec![column.to_string()]
    } else {
        (0..components).map(|i| format!("{column}_{i}")).collect()
    }
}

/// [`text_names`] of a column of a map with these `emitters`: the same, except that the
/// `params` component holding every emitter's wavelength (all of them spectral, with the
/// wavelength last) is named `wavelength` (format-spec/phm-v1.md §7).
pub fn text_names_in(emitters: &[super::Emitter], column: &str, components: u32) -> Vec<String> {
    let mut names = text_names(column, components);
    let with_params: Vec<_> = emitters.iter().filter(|e| e.param_dims > 0).collect();
    let last = components as usize;
    if column == name::PARAMS
        && !with_params.is_empty()
        && with_params.iter().all(|e| e.parameterisation.spectral_component().map(|k| k + 1) == Some(last))
    {
        names[last - 1] = WAVELENGTH_TEXT_NAME.to_string();
    }
    names
}

/// The text name of a wavelength in `params` ([`text_names_in`]).
pub const WAVELENGTH_TEXT_NAME: &str = "wavelength";

/// The type and shape of one column, without its place in a file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColumnSpec {
    /// The column's name.
    pub name: String,
    /// Its element type.
    pub dtype: DType,
    /// Components per photon.
    pub components: u32,
    /// Keys of the column's table entry that this version does not define (a newer minor
    /// version's), carried through unchanged by a stage that passes the column on.
    pub extra: serde_json::Map<String, serde_json::Value>,
}

impl ColumnSpec {
    /// A column of `components` values of `dtype` per photon, with no extra keys.
    pub fn new(name: &str, dtype: DType, components: u32) -> Self {
        ColumnSpec { name: name.to_string(), dtype, components, extra: Default::default() }
    }

    /// The spec of a column whose elements are `T`.
    pub fn of<T: Element>(name: &str) -> Self {
        Self::new(name, T::DTYPE, T::COMPONENTS)
    }

    /// Bytes per photon.
    pub fn stride(&self) -> u64 {
        self.dtype.size() * self.components as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_names_cover_known_and_unknown_columns() {
        assert_eq!(text_names("position", 3), ["x", "y", "z"]);
        assert_eq!(text_names("params", 2), ["param_0", "param_1"]);
        assert_eq!(text_names("weight", 1), ["weight"]);
        assert_eq!(text_names("colour", 2), ["colour_0", "colour_1"]);
    }

    #[test]
    fn every_known_column_has_names_for_its_largest_shape() {
        for k in KNOWN_COLUMNS {
            let max = *k.components.iter().max().unwrap();
            assert_eq!(k.text_names.len(), max as usize, "{}", k.name);
        }
    }

    #[test]
    fn values_read_back_little_endian() {
        let b = (-2.5f32).to_le_bytes();
        assert_eq!(DType::F32.value_f64(&b, 0), -2.5);
        let b = 0xFFFEu16.to_le_bytes();
        assert_eq!(DType::I16.value_f64(&b, 0), -2.0);
        let mut s = String::new();
        DType::F32.format_value(&0.1f32.to_le_bytes(), 0, &mut s);
        assert_eq!(s, "0.1");
    }
}
