//! Photon maps written by Radiance's `mkpmap` (format "3.1") → photon columns.
//!
//! Facts from Radiance's source as summarised, function by function, in the layout notes that
//! came with the test maps (`src/rt/pmapio.c` savePhotonMap, `src/rt/pmapkdt.c`
//! kdT_SavePhotons, `src/rt/oococt.c` OOC_SaveOctree, `src/common/portio.c` putint/putflt,
//! `src/common/dircode.c` encodedir, `src/common/color.c` setcolr):
//!
//! ```text
//! text header      "#?RADIANCE\n", command line, statistics, FORMAT=Radiance_<Type>_<kdT|OOC>_Photon_Map,
//!                  VERSION=<ver>, then an empty line
//! version string   NUL-terminated: "3.1" + ("k" kd-tree | "o" out-of-core) + ["f" float flux]
//!                  + ["P" primary positions] + ["D" primary directions]
//! numPhotons       8-byte big-endian integer
//! 13 floats        average flux ×3, min/max interleaved ×6, centre of gravity ×3, mean dist² ×1
//! numPrimary       4-byte big-endian unsigned
//! primaries        srcIdx (2, signed) [+ direction code (4)] [+ position (3 floats)]
//! kd-tree photons  pos (3 floats) | normal (3 signed bytes, ×1/127) | flux RGBE (4) or 3 floats (15)
//!                  | primary index (4) | flags (1: bits 0–1 split axis, bit 2 caustic)
//! out-of-core      octree (origin, size, record size, counts, nodes) in the .pm file; photons in
//!                  <map>.leaf as raw little-endian 24-byte records
//! ```
//! A "float" is Radiance's portable 5-byte form: a 4-byte big-endian mantissa m (signed, the
//! fraction m/(2³¹−1) with half a unit added away from zero) and a signed exponent byte.
//!
//! The primaries of the PD variant hold a direction towards the source (its negation is the
//! emission direction, which becomes the trajectory parameters with parameterisation
//! `direction`) and a position that, by a Radiance quirk, is the origin of the *previous*
//! emission; that position is therefore not imported.

use std::path::Path;

use serde_json::json;

use super::{At, ImportError, Imported, Options, Result, SourceFormat, external_emitter};
use crate::format::{ColumnSpec, DType, Parameterisation, name};

/// Longest text header accepted (mkpmap writes a few hundred bytes).
const MAX_HEADER: usize = 1 << 20;

/// What the binary version string says about the build that wrote the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Variant {
    out_of_core: bool,
    float_flux: bool,
    primary_pos: bool,
    primary_dir: bool,
}

impl Variant {
    fn parse(v: &str) -> Option<Self> {
        let rest = v.strip_prefix("3.1")?;
        let (out_of_core, rest) = match rest.as_bytes().first()? {
            b'k' => (false, &rest[1..]),
            b'o' => (true, &rest[1..]),
            _ => return None,
        };
        let (float_flux, rest) = rest.strip_prefix('f').map_or((false, rest), |r| (true, r));
        let (primary_pos, rest) = rest.strip_prefix('P').map_or((false, rest), |r| (true, r));
        let (primary_dir, rest) = rest.strip_prefix('D').map_or((false, rest), |r| (true, r));
        rest.is_empty().then_some(Variant { out_of_core, float_flux, primary_pos, primary_dir })
    }

    /// Bytes per primary ray record.
    fn primary_size(self) -> usize {
        2 + if self.primary_dir { 4 } else { 0 } + if self.primary_pos { 15 } else { 0 }
    }

    /// Bytes per kd-tree photon record in the .pm file: position (3 × 5), normal (3), flux
    /// (RGBE 4, or 3 × 5 with `f`: kdT_SavePhotons writes float flux with putflt), primary (4),
    /// flags (1).
    fn kd_record(self) -> usize {
        if self.float_flux { 38 } else { 27 }
    }

    /// Bytes per photon record in the out-of-core .leaf file.
    fn leaf_record(self) -> usize {
        if self.float_flux { 32 } else { 24 }
    }
}

/// A bounds-checked reader over the portable (big-endian) part of the file.
struct Reader<'a> {
    file: &'a str,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn err(&self, at: usize, message: String) -> ImportError {
        ImportError::Malformed { file: self.file.into(), at: At::Byte(at as u64), message }
    }

    fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(self.err(
                self.pos,
                format!(
                    "truncated: {what} needs {n} bytes but the file ends {} bytes later",
                    self.remaining()
                ),
            ));
        }
        let b = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(b)
    }

    /// `getint`: big-endian, sign-extended from the first byte.
    fn int(&mut self, n: usize, what: &str) -> Result<i64> {
        let b = self.take(n, what)?;
        let first = if b[0] & 0x80 != 0 { -1i64 } else { 0 };
        Ok(b.iter().fold(first, |acc, &x| (acc << 8) | x as i64))
    }

    fn uint32(&mut self, what: &str) -> Result<u32> {
        let b = self.take(4, what)?;
        Ok(u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// `getflt`: the 5-byte portable float.
    fn flt(&mut self, what: &str) -> Result<f64> {
        let b = self.take(5, what)?;
        Ok(decode_flt(b[..5].try_into().expect("5 bytes")))
    }

    fn flt3(&mut self, what: &str) -> Result<[f64; 3]> {
        Ok([self.flt(what)?, self.flt(what)?, self.flt(what)?])
    }
}

/// Radiance's portable float (`getflt`, portio.c): mantissa l/(2³¹−1) with the half-unit
/// rounding term, times 2^exponent; a zero mantissa is 0 whatever the exponent.
pub fn decode_flt(b: [u8; 5]) -> f64 {
    let l = i32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    if l == 0 {
        return 0.0;
    }
    let e = b[4] as i8 as i32;
    let m = (l as f64 + 0.5 - if l < 0 { 1.0 } else { 0.0 }) * (1.0 / 2147483647.0);
    m * f64::from_bits(((e + 1023) as u64) << 52)
}

/// RGBE flux (`colr_color`, color.c): channel = (byte + ½)·2^(E−136), in f32; E = 0 is black.
pub fn decode_rgbe(c: [u8; 4]) -> [f32; 3] {
    if c[3] == 0 {
        return [0.0; 3];
    }
    let f = f64::from_bits(((c[3] as i32 - 136 + 1023) as u64) << 52) as f32;
    [0, 1, 2].map(|k| (c[k] as f32 + 0.5) * f)
}

/// Radiance's 32-bit direction code (`decodedir`, dircode.c): two quantised components and
/// the permutation and signs that place them; code 0 is the zero vector.
pub fn decode_dir(dc: u32) -> [f64; 3] {
    const DCSCALE: f64 = 11584.5;
    const FXNEG: u32 = 1;
    const FYNEG: u32 = 2;
    const FZNEG: u32 = 4;
    const F1X: u32 = 8;
    const F2Z: u32 = 16;
    const ITAB: [[usize; 3]; 4] = [[1, 0, 2], [0, 1, 2], [1, 2, 0], [0, 2, 1]];
    if dc == 0 {
        return [0.0; 3];
    }
    let d1 = ((dc >> 5) & 0x1fff) as f64 / DCSCALE;
    let d2 = ((dc >> 18) & 0x1fff) as f64 / DCSCALE;
    let der = (1.0 - d1 * d1 - d2 * d2).sqrt();
    let ndx = (if dc & F2Z != 0 { 2 } else { 0 }) | (if dc & F1X != 0 { 1 } else { 0 });
    let mut v = [0.0; 3];
    v[ITAB[ndx][0]] = d1;
    v[ITAB[ndx][1]] = d2;
    v[ITAB[ndx][2]] = der;
    for (k, flag) in [FXNEG, FYNEG, FZNEG].into_iter().enumerate() {
        if dc & flag != 0 {
            v[k] = -v[k];
        }
    }
    v
}

/// The text header's lines of interest.
struct TextHeader {
    command: String,
    format: String,
    version: Option<String>,
    end: usize,
}

fn text_header(file: &str, bytes: &[u8]) -> Result<TextHeader> {
    let bad = |line: u64, message: String| ImportError::Malformed {
        file: file.into(),
        at: At::Line(line),
        message,
    };
    let mut pos = 0;
    let mut line = 0u64;
    let (mut command, mut format, mut version) = (String::new(), None, None);
    loop {
        line += 1;
        let Some(len) = bytes[pos..bytes.len().min(MAX_HEADER)].iter().position(|&b| b == b'\n') else {
            return Err(bad(line, "the Radiance header does not end (no empty line)".into()));
        };
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        let text = String::from_utf8_lossy(raw);
        let text = text.trim_end_matches('\r');
        if line == 1 {
            if text != "#?RADIANCE" {
                return Err(bad(1, "not a Radiance file: the first line must be '#?RADIANCE'".into()));
            }
            continue;
        }
        if text.is_empty() {
            break;
        }
        if line == 2 {
            command = text.to_string();
        }
        if let Some(f) = text.strip_prefix("FORMAT=") {
            format = Some((line, f.trim().to_string()));
        } else if let Some(v) = text.strip_prefix("VERSION=") {
            version = Some((line, v.trim().to_string()));
        }
    }
    let (_, format) = format.ok_or_else(|| bad(line, "the Radiance header has no FORMAT= line".into()))?;
    if !(format.starts_with("Radiance_") && format.ends_with("_Photon_Map")) {
        return Err(ImportError::Unsupported {
            file: file.into(),
            variant: format!("Radiance format '{format}'"),
            message: "only photon maps (FORMAT=Radiance_*_Photon_Map) are imported".into(),
        });
    }
    if format.starts_with("Radiance_Volume_") {
        return Err(ImportError::Unsupported {
            file: file.into(),
            variant: format!("Radiance volume photon map ({format})"),
            message: "volume photons lie in participating media, not on surfaces, and their normal \
                      bytes hold the incident direction; photonkit imports surface photon maps"
                .into(),
        });
    }
    Ok(TextHeader { command, format, version: version.map(|v| v.1), end: pos })
}

/// One photon as decoded.
struct Photon {
    pos: [f32; 3],
    normal: [i8; 3],
    flux: [f32; 3],
    primary: u32,
    caustic: bool,
    /// Byte offset of the record's primary index (for error messages).
    at: usize,
}

/// Reads a photon map (and, for the out-of-core variant, its `<map>.leaf` beside it).
pub fn read(path: &Path, bytes: &[u8], options: &Options) -> Result<Imported> {
    let file = path.display().to_string();
    let file = file.as_str();
    if options.parameterisation.is_some() {
        return Err(ImportError::Invalid {
            file: file.into(),
            message: "--parameterisation applies to PLY and CSV; a Radiance map says itself".into(),
        });
    }
    let th = text_header(file, bytes)?;
    let mut r = Reader { file, bytes, pos: th.end };
    let vstart = r.pos;
    let vlen = bytes[vstart..].iter().take(64).position(|&b| b == 0).ok_or_else(|| {
        r.err(vstart, "the binary version string is not NUL-terminated within 64 bytes".into())
    })?;
    let version = String::from_utf8_lossy(r.take(vlen + 1, "version string")?[..vlen].as_ref()).into_owned();
    let variant = Variant::parse(&version).ok_or_else(|| ImportError::Unsupported {
        file: file.into(),
        variant: format!("Radiance photon map version '{version}'"),
        message: "this importer reads format 3.1: 3.1k (kd-tree) and 3.1o (out-of-core), with the \
                  optional suffixes f, P, D"
            .into(),
    })?;
    let storage_ok = if variant.out_of_core {
        th.format.ends_with("_OOC_Photon_Map")
    } else {
        th.format.ends_with("_kdT_Photon_Map")
    };
    if !storage_ok {
        return Err(r.err(vstart, format!("binary version '{version}' contradicts FORMAT={}", th.format)));
    }
    if let Some(v) = &th.version
        && *v != version
    {
        return Err(
            r.err(vstart, format!("binary version '{version}' differs from the header's VERSION={v}"))
        );
    }
    let n_at = r.pos;
    let num_photons = r.int(8, "numPhotons")?;
    let num_photons = usize::try_from(num_photons)
        .map_err(|_| r.err(n_at, format!("numPhotons {num_photons} is negative")))?;
    let avg_flux = r.flt3("average flux")?;
    let mut bounds = [0.0; 6];
    for b in &mut bounds {
        *b = r.flt("bounding box")?;
    }
    let cog = r.flt3("centre of gravity")?;
    let _cog_dist = r.flt("mean squared distance")?;
    let np_at = r.pos;
    let num_primary = r.uint32("numPrimary")? as usize;

    let primaries = read_primaries(&mut r, variant, num_primary, np_at)?;

    let (photons, storage) = if variant.out_of_core {
        (read_ooc(path, &mut r, variant, num_photons)?, "out-of-core octree + .leaf")
    } else {
        (read_kd(&mut r, variant, num_photons)?, "kd-tree")
    };

    let mut imported = photon_columns(&r, &photons, &primaries, variant, options.caustic_only)?;
    let n = imported.len();
    imported.report = json!({
        "radiance_format": th.format,
        "radiance_version": version,
        "mkpmap_command": th.command,
        "storage": storage,
        "photons_in_file": num_photons,
        "photons": n,
        "primary_rays": num_primary,
        "average_flux_w": avg_flux,
        "bounding_box": { "min": [bounds[0], bounds[2], bounds[4]], "max": [bounds[1], bounds[3], bounds[5]] },
        "centre_of_gravity": cog,
        "primary_positions": if variant.primary_pos {
            "not imported: Radiance stores the previous emission's origin there"
        } else {
            "absent"
        },
    });
    Ok(imported)
}

/// The primary rays: each one's source index and, in the D variant, the unit direction
/// towards the source. `np_at` is the byte offset of the `numPrimary` count, for errors.
fn read_primaries(
    r: &mut Reader,
    variant: Variant,
    num_primary: usize,
    np_at: usize,
) -> Result<Vec<(u16, Option<[f32; 3]>)>> {
    let psize = variant.primary_size();
    if num_primary.checked_mul(psize).is_none_or(|b| b > r.remaining()) {
        return Err(r.err(
            np_at,
            format!(
                "numPrimary {num_primary} needs {} bytes of primary rays but only {} remain",
                num_primary as u128 * psize as u128,
                r.remaining()
            ),
        ));
    }
    let mut primaries: Vec<(u16, Option<[f32; 3]>)> = Vec::with_capacity(num_primary);
    for i in 0..num_primary {
        let at = r.pos;
        let src = r.int(2, "primary source index")?;
        let src = u16::try_from(src).map_err(|_| r.err(at, format!("primary {i} has source index {src}")))?;
        let dir = if variant.primary_dir {
            let dc = r.uint32("primary direction")?;
            let d = decode_dir(dc);
            if d.iter().any(|x| !x.is_finite()) || dc == 0 {
                return Err(r.err(at + 2, format!("primary {i} has an invalid direction code {dc:#010x}")));
            }
            Some(d.map(|x| -x as f32))
        } else {
            None
        };
        if variant.primary_pos {
            r.take(15, "primary position")?; // the previous emission's origin: not imported
        }
        primaries.push((src, dir));
    }
    Ok(primaries)
}

/// The photon columns in file order (pmapdump's order), only the caustic photons if
/// `caustic_only`, with one external emitter per primary source index (the report left empty).
fn photon_columns(
    r: &Reader,
    photons: &[Photon],
    primaries: &[(u16, Option<[f32; 3]>)],
    variant: Variant,
    caustic_only: bool,
) -> Result<Imported> {
    let num_primary = primaries.len();
    let keep: Vec<&Photon> = photons.iter().filter(|p| p.caustic || !caustic_only).collect();
    let n = keep.len();
    let mut pos = Vec::with_capacity(n);
    let mut flux = Vec::with_capacity(n);
    let mut normal = Vec::with_capacity(n);
    let mut caustic = Vec::with_capacity(n);
    let mut emitter = Vec::with_capacity(if num_primary > 0 { n } else { 0 });
    let mut params = Vec::with_capacity(if variant.primary_dir && num_primary > 0 { n } else { 0 });
    for p in &keep {
        if p.pos.iter().chain(&p.flux).any(|x| !x.is_finite()) {
            return Err(r.err(p.at, "a photon's position or flux is not finite".into()));
        }
        pos.push(p.pos);
        flux.push(p.flux);
        let nf = p.normal.map(|c| c as f32);
        let len = (nf[0] * nf[0] + nf[1] * nf[1] + nf[2] * nf[2]).sqrt();
        normal.push(if len > 0.0 { nf.map(|c| c / len) } else { nf });
        caustic.push(p.caustic as u8);
        if num_primary > 0 {
            let &(src, dir) = primaries.get(p.primary as usize).ok_or_else(|| {
                r.err(p.at, format!("primary index {} is out of range ({num_primary} primaries)", p.primary))
            })?;
            emitter.push(src);
            if let Some(d) = dir {
                params.push(d);
            }
        }
    }
    let emitters_n = emitter.iter().copied().max().map_or(1, |m| m as usize + 1);
    let parameterisation = if variant.primary_dir && num_primary > 0 {
        Parameterisation::Direction
    } else {
        Parameterisation::None
    };
    let mut sums = vec![[0.0f64; 3]; emitters_n];
    for (i, f) in flux.iter().enumerate() {
        let e = emitter.get(i).copied().unwrap_or(0) as usize;
        (0..3).for_each(|k| sums[e][k] += f[k] as f64);
    }
    let emitters =
        sums.iter().enumerate().map(|(id, s)| external_emitter(id as u32, parameterisation, *s)).collect();

    let mut columns = vec![
        (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&pos).to_vec()),
        (ColumnSpec::of::<[f32; 3]>(name::NORMAL), bytemuck::cast_slice(&normal).to_vec()),
        (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&flux).to_vec()),
    ];
    if emitters_n > 1 {
        columns.push((ColumnSpec::of::<u16>(name::EMITTER), bytemuck::cast_slice(&emitter).to_vec()));
    }
    if parameterisation == Parameterisation::Direction {
        columns.push((ColumnSpec::of::<[f32; 3]>(name::PARAMS), bytemuck::cast_slice(&params).to_vec()));
    }
    columns.push((ColumnSpec::new("caustic", DType::U8, 1), caustic));
    Ok(Imported { format: SourceFormat::Radiance, columns, emitters, report: serde_json::Value::Null })
}

fn read_kd(r: &mut Reader, variant: Variant, n: usize) -> Result<Vec<Photon>> {
    let rec = variant.kd_record();
    let start = r.pos;
    let have = r.remaining();
    if n.checked_mul(rec) != Some(have) {
        let held = have / rec;
        let msg = if n.checked_mul(rec).is_none_or(|b| b > have) {
            format!("the map declares {n} photons of {rec} bytes but the {have} bytes left hold only {held}")
        } else {
            format!("{} bytes follow the {n} photons of {rec} bytes (trailing data)", have - n * rec)
        };
        return Err(r.err(start, msg));
    }
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let p = r.flt3("photon position")?.map(|x| x as f32);
        let nb = r.take(3, "photon normal")?;
        let normal = [nb[0] as i8, nb[1] as i8, nb[2] as i8];
        let flux = if variant.float_flux {
            r.flt3("photon flux")?.map(|x| x as f32)
        } else {
            let c = r.take(4, "photon flux")?;
            decode_rgbe([c[0], c[1], c[2], c[3]])
        };
        let at = r.pos;
        let primary = r.uint32("photon primary index")?;
        let flags = r.take(1, "photon flags")?[0];
        out.push(Photon { pos: p, normal, flux, primary, caustic: flags & 0b100 != 0, at });
    }
    Ok(out)
}

/// The out-of-core map's octree, checked and skipped (the photons are in the `.leaf` file):
/// its origin and size, for the check that every photon lies inside it.
fn read_octree(r: &mut Reader, variant: Variant, n: usize) -> Result<([f64; 3], f64)> {
    let origin = r.flt3("octree origin")?;
    let size = r.flt("octree size")?;
    let rs_at = r.pos;
    let rec_size = r.uint32("record size")? as usize;
    let nd_at = r.pos;
    let num_data = r.uint32("octree photon count")? as usize;
    let num_nodes = r.uint32("octree node count")? as usize;
    if rec_size != variant.leaf_record() {
        return Err(ImportError::Unsupported {
            file: r.file.into(),
            variant: format!("out-of-core photon records of {rec_size} bytes (byte {rs_at})"),
            message: format!(
                "this importer reads the {}-byte records of x86-64 builds",
                variant.leaf_record()
            ),
        });
    }
    if num_data != n {
        return Err(r.err(nd_at, format!("the octree holds {num_data} photons but numPhotons is {n}")));
    }
    // Nodes: 9 bytes (leaf: 0xFF + 8 counts) or 10 (interior: 0x00, child, count, branch).
    if num_nodes.checked_mul(9).is_none_or(|b| b > r.remaining()) {
        return Err(
            r.err(nd_at + 4, format!("{num_nodes} octree nodes can not fit in {} bytes", r.remaining()))
        );
    }
    for i in 0..num_nodes {
        let at = r.pos;
        match r.take(1, "octree node")?[0] {
            0xFF => r.take(8, "octree leaf node")?,
            0x00 => r.take(9, "octree interior node")?,
            b => return Err(r.err(at, format!("octree node {i} has an unknown tag byte {b:#04x}"))),
        };
    }
    if r.remaining() != 0 {
        return Err(r.err(r.pos, format!("{} bytes of trailing data after the octree", r.remaining())));
    }
    Ok((origin, size))
}

/// The photons of an out-of-core map, from the `.leaf` file beside `path`.
fn read_ooc(path: &Path, r: &mut Reader, variant: Variant, n: usize) -> Result<Vec<Photon>> {
    let (origin, size) = read_octree(r, variant, n)?;

    let mut leaf_path = path.as_os_str().to_owned();
    leaf_path.push(".leaf");
    let leaf_path = std::path::PathBuf::from(leaf_path);
    let leaf_name = leaf_path.display().to_string();
    crate::format::guard::register_input(&leaf_path);
    let leaf = std::fs::read(&leaf_path).map_err(|source| ImportError::Io {
        file: format!("{leaf_name} (the photons of the out-of-core map {})", r.file),
        source,
    })?;
    let rec = variant.leaf_record();
    if n.checked_mul(rec) != Some(leaf.len()) {
        return Err(ImportError::Malformed {
            file: leaf_name,
            at: At::Byte(0),
            message: format!(
                "the map declares {n} photons of {rec} bytes ({} bytes) but the leaf file has {} bytes",
                n as u128 * rec as u128,
                leaf.len()
            ),
        });
    }
    // Raw little-endian `struct Photon`: pos f32×3, normal i8×3, flags, flux, primary u32.
    let f32_at = |b: &[u8], o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let slack = 1e-4 * size.abs().max(1e-30);
    let mut out = Vec::with_capacity(n);
    for (i, b) in leaf.chunks_exact(rec).enumerate() {
        let pos = [f32_at(b, 0), f32_at(b, 4), f32_at(b, 8)];
        let normal = [b[12] as i8, b[13] as i8, b[14] as i8];
        let flags = b[15];
        let (flux, p_off) = if variant.float_flux {
            ([f32_at(b, 16), f32_at(b, 20), f32_at(b, 24)], 28)
        } else {
            (decode_rgbe([b[16], b[17], b[18], b[19]]), 20)
        };
        let primary = u32::from_le_bytes([b[p_off], b[p_off + 1], b[p_off + 2], b[p_off + 3]]);
        if pos.iter().chain(&flux).any(|x| !x.is_finite()) {
            return Err(ImportError::Malformed {
                file: leaf_name,
                at: At::Byte((i * rec) as u64),
                message: format!("photon {i} has a non-finite position or flux"),
            });
        }
        // The leaf file is written in the writer's native byte order and struct layout; a
        // photon outside the octree's cube means the machine that wrote it was not this one's
        // kind (little-endian, GCC bit-field order), which would otherwise go unnoticed.
        if (0..3).any(|k| !(origin[k] - slack..=origin[k] + size + slack).contains(&(pos[k] as f64))) {
            return Err(ImportError::Unsupported {
                file: leaf_name,
                variant: format!(
                    "an out-of-core leaf file whose photon {i} (byte {}) lies outside its octree",
                    i * rec
                ),
                message: "the .leaf file is raw native records; this importer reads those of little-endian \
                          x86-64 builds"
                    .into(),
            });
        }
        out.push(Photon { pos, normal, flux, primary, caustic: flags & 1 != 0, at: i * rec });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn portable_float_matches_the_documented_example() {
        assert_eq!(decode_flt([0x80, 0x18, 0x9b, 0x01, 0x02]), -3.996996403670402);
        assert_eq!(decode_flt([0, 0, 0, 0, 0x55]), 0.0);
    }

    #[test]
    fn rgbe_and_direction_codes_decode() {
        let f = decode_rgbe([185, 151, 101, 116]);
        assert_eq!(f, [185.5 * 2f32.powi(-20), 151.5 * 2f32.powi(-20), 101.5 * 2f32.powi(-20)]);
        let d = decode_dir(0x1afc2f00);
        let want = [0.149079, 0.032457, 0.988293];
        assert!((0..3).all(|k| (d[k] - want[k]).abs() < 1e-6), "{d:?}");
    }

    #[test]
    fn version_strings_name_their_variant() {
        assert_eq!(Variant::parse("3.1kPD").map(|v| v.primary_size()), Some(21));
        assert!(Variant::parse("3.1o").is_some_and(|v| v.out_of_core));
        assert!(Variant::parse("3.0k").is_none());
        assert!(Variant::parse("3.1kX").is_none());
    }
}
