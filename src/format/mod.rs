//! The PHM photon-map file, version 1: the one place every stage reads and writes photons.
//!
//! A PHM file is a 32-byte little-endian [preamble], a JSON [metadata](meta) object, and
//! the photon data as columns (structure of arrays), each aligned to 64 bytes so a
//! memory-mapped file is viewed as typed slices with no copy. `format-spec/phm-v1.md` is the
//! byte-for-byte specification; this module implements it:
//!
//! - [`PhotonMap`] opens and validates a file (or standard input) and hands out column views;
//! - [`MapView`] is the view every stage reads (a [`PhotonMap`]'s or a [`PhotonTable`]'s), and
//!   [`PhotonTable`] the in-memory map every stage returns;
//! - [`PhotonWriter`] streams photons into a temporary file beside the target and renames it
//!   into place when, and only when, everything was written.

pub mod columns;
pub mod guard;
pub mod meta;
pub mod preamble;
mod reader;
pub mod records;
mod table;
mod writer;

pub use columns::{ColumnSpec, DType, Element, name};
pub use meta::{
    BoundingBox, ColumnEntry, DimensionKind, Emitter, EmitterKind, MapInfo, Metadata, ParamDimension,
    Parameterisation, StageRecord, State, UNIT_TOLERANCE, Units,
};
pub use reader::PhotonMap;
pub use records::{TraceParameters, TraceRecord, TraceReport};
pub use table::{MapView, PhotonTable};
pub use writer::{Output, PhotonWriter, folder_of, persist, temp_beside, write_map};

#[cfg(target_endian = "big")]
compile_error!("photonkit views PHM columns in place and needs a little-endian machine");

/// Everything that can be wrong with a PHM file or with a request to write one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    #[error("{file}: {source}")]
    Io { file: String, source: std::io::Error },
    #[error("{file}: not a PHM photon map (the first 8 bytes are not the PHM magic number)")]
    BadMagic { file: String },
    #[error("{file}: truncated: {what} needs {needed} bytes but the file has {actual}")]
    Truncated { file: String, what: &'static str, needed: u64, actual: u64 },
    #[error(
        "{file}: PHM version {major}.{minor} is not supported: this photonkit reads major version 1 \
         (a newer major version changes the layout; upgrade photonkit)"
    )]
    UnsupportedVersion { file: String, major: u16, minor: u16 },
    #[error("{file}: metadata length {len} bytes exceeds the limit of {limit} bytes")]
    MetadataTooLarge { file: String, len: u64, limit: u64 },
    #[error("{file}: metadata checksum mismatch (bytes 32..{end}): the header is corrupt")]
    MetadataChecksum { file: String, end: u64 },
    #[error("{file}: metadata (byte {offset}): {message}")]
    MetadataJson { file: String, offset: u64, message: String },
    #[error("{file}: invalid metadata: {message}")]
    Invalid { file: String, message: String },
    #[error("{file}: column '{column}': {message}")]
    Column { file: String, column: String, message: String },
    #[error("{file}: column '{column}' fails its checksum (stored {stored:08x}, computed {computed:08x})")]
    Checksum { file: String, column: String, stored: u32, computed: u32 },
    #[error("{file}: photon {index} has a non-finite value in column '{column}'")]
    NonFinite { file: String, column: String, index: u64 },
}

pub type Result<T, E = FormatError> = std::result::Result<T, E>;
