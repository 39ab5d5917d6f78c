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
pub use reader::{Pages, PhotonMap};
pub use records::{TraceParameters, TraceRecord, TraceReport};
pub use table::{MapView, PhotonTable};
pub use writer::{Output, PhotonWriter, folder_of, persist, temp_beside, write_map};

#[cfg(target_endian = "big")]
compile_error!("photonkit views PHM columns in place and needs a little-endian machine");

/// Everything that can be wrong with a PHM file or with a request to write one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    /// Reading or writing the file failed.
    #[error("{file}: {source}")]
    Io {
        /// The file as named to the user.
        file: String,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file does not start with the PHM magic number (format-spec/phm-v1.md §2).
    #[error("{file}: not a PHM photon map (the first 8 bytes are not the PHM magic number)")]
    BadMagic {
        /// The file as named to the user.
        file: String,
    },
    /// The file ends before a part it declares.
    #[error("{file}: truncated: {what} needs {needed} bytes but the file has {actual}")]
    Truncated {
        /// The file as named to the user.
        file: String,
        /// The part that does not fit (the preamble, the metadata, a column).
        what: &'static str,
        /// Bytes the part needs the file to have.
        needed: u64,
        /// Bytes the file has.
        actual: u64,
    },
    /// A major version this build does not read.
    #[error(
        "{file}: PHM version {major}.{minor} is not supported: this photonkit reads major version 1 \
         (a newer major version changes the layout; upgrade photonkit)"
    )]
    UnsupportedVersion {
        /// The file as named to the user.
        file: String,
        /// The preamble's major version.
        major: u16,
        /// The preamble's minor version.
        minor: u16,
    },
    /// The metadata is longer than [`MAX_METADATA_LEN`](preamble::MAX_METADATA_LEN).
    #[error("{file}: metadata length {len} bytes exceeds the limit of {limit} bytes")]
    MetadataTooLarge {
        /// The file as named to the user.
        file: String,
        /// The metadata's length, bytes.
        len: u64,
        /// The limit, bytes.
        limit: u64,
    },
    /// The preamble's CRC-32 over the metadata does not match it.
    #[error("{file}: metadata checksum mismatch (bytes 32..{end}): the header is corrupt")]
    MetadataChecksum {
        /// The file as named to the user.
        file: String,
        /// Byte offset just past the metadata.
        end: u64,
    },
    /// The metadata is not JSON of the expected shape.
    #[error("{file}: metadata (byte {offset}): {message}")]
    MetadataJson {
        /// The file as named to the user.
        file: String,
        /// Byte offset in the file where the JSON parser stopped.
        offset: u64,
        /// What the parser said.
        message: String,
    },
    /// Metadata that parses but breaks a rule of the spec (or a request to write such a file).
    #[error("{file}: invalid metadata: {message}")]
    Invalid {
        /// The file as named to the user.
        file: String,
        /// Which rule, and how.
        message: String,
    },
    /// A column whose entry or data breaks a rule of the spec.
    #[error("{file}: column '{column}': {message}")]
    Column {
        /// The file as named to the user.
        file: String,
        /// The column's name.
        column: String,
        /// Which rule, and how.
        message: String,
    },
    /// A column's data does not match its stored CRC-32.
    #[error("{file}: column '{column}' fails its checksum (stored {stored:08x}, computed {computed:08x})")]
    Checksum {
        /// The file as named to the user.
        file: String,
        /// The column's name.
        column: String,
        /// The CRC-32 in the column table.
        stored: u32,
        /// The CRC-32 of the bytes read.
        computed: u32,
    },
    /// A NaN or infinity where the spec requires finite values (§5).
    #[error("{file}: photon {index} has a non-finite value in column '{column}'")]
    NonFinite {
        /// The file as named to the user.
        file: String,
        /// The column's name.
        column: String,
        /// The photon's index (0-based).
        index: u64,
    },
}

/// A result whose error is a [`FormatError`].
pub type Result<T, E = FormatError> = std::result::Result<T, E>;
