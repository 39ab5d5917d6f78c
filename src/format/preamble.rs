//! The fixed 32-byte little-endian preamble that opens every PHM file (format-spec/phm-v1.md §2).

/// `\x89PHM\r\n\x1a\n`: the high byte catches 7-bit transfers, the CR LF / LF pair catches
/// newline translation, and 0x1A stops `type` on DOS — the PNG trick.
pub const MAGIC: [u8; 8] = *b"\x89PHM\r\n\x1a\n";
/// Length of the preamble in bytes; the metadata starts right after it.
pub const PREAMBLE_LEN: usize = 32;
/// The major version this build reads and writes.
pub const VERSION_MAJOR: u16 = 1;
/// The newest minor version this build writes. A file is written with the lowest minor
/// version that describes it ([`super::meta::Metadata::minor_version`]): 1.0 unless it uses
/// what 1.1 added (a spectral parameter dimension).
pub const VERSION_MINOR: u16 = 1;
/// Upper bound on the metadata length a reader accepts (16 MiB), so a corrupt length can not
/// make us allocate or parse gigabytes.
pub const MAX_METADATA_LEN: u64 = 16 << 20;
/// Every column starts at a multiple of this many bytes.
pub const COLUMN_ALIGN: u64 = 64;

/// The preamble as it lies on disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Preamble {
    /// Major version: files of another major version are refused.
    pub version_major: u16,
    /// Minor version: additions a reader of an older minor version may ignore.
    pub version_minor: u16,
    /// CRC-32 (zlib's polynomial) of the metadata region.
    pub metadata_crc32: u32,
    /// Length in bytes of the metadata region: the JSON text plus its whitespace padding.
    pub metadata_len: u64,
    /// Length of the whole file in bytes.
    pub file_len: u64,
}

impl Preamble {
    /// The 32 bytes as written to the file.
    pub fn to_bytes(self) -> [u8; PREAMBLE_LEN] {
        let mut b = [0u8; PREAMBLE_LEN];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..10].copy_from_slice(&self.version_major.to_le_bytes());
        b[10..12].copy_from_slice(&self.version_minor.to_le_bytes());
        b[12..16].copy_from_slice(&self.metadata_crc32.to_le_bytes());
        b[16..24].copy_from_slice(&self.metadata_len.to_le_bytes());
        b[24..32].copy_from_slice(&self.file_len.to_le_bytes());
        b
    }

    /// Decodes the preamble without judging it; `None` when the magic number is wrong.
    pub fn from_bytes(b: &[u8; PREAMBLE_LEN]) -> Option<Self> {
        if b[0..8] != MAGIC {
            return None;
        }
        let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]);
        let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"));
        Some(Preamble {
            version_major: u16_at(8),
            version_minor: u16_at(10),
            metadata_crc32: u32_at(12),
            metadata_len: u64_at(16),
            file_len: u64_at(24),
        })
    }
}

/// Rounds `x` up to the next multiple of [`COLUMN_ALIGN`].
pub fn align_up(x: u64) -> u64 {
    x.div_ceil(COLUMN_ALIGN) * COLUMN_ALIGN
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn preamble_round_trips_and_is_little_endian() {
        let p = Preamble {
            version_major: 1,
            version_minor: 7,
            metadata_crc32: 0xDEADBEEF,
            metadata_len: 0x0102,
            file_len: 0x0A0B0C,
        };
        let b = p.to_bytes();
        assert_eq!(&b[0..8], b"\x89PHM\r\n\x1a\n");
        assert_eq!(&b[8..12], &[1, 0, 7, 0]);
        assert_eq!(&b[12..16], &[0xEF, 0xBE, 0xAD, 0xDE]);
        assert_eq!(&b[16..18], &[0x02, 0x01]);
        assert_eq!(Preamble::from_bytes(&b), Some(p));
        let mut bad = b;
        bad[1] = b'X';
        assert_eq!(Preamble::from_bytes(&bad), None);
    }

    #[test]
    fn align_up_rounds_to_64() {
        assert_eq!(align_up(0), 0);
        assert_eq!(align_up(1), 64);
        assert_eq!(align_up(64), 64);
        assert_eq!(align_up(65), 128);
    }
}
