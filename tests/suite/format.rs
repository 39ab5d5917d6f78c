//! Bad input and round trips for the PHM format (issue 2, "Bad input" and "Done when"):
//! proptest round trips, truncation at every offset, every metadata field corrupted in turn,
//! newer minor versions, fuzz regressions, and `photonkit inspect` on broken files.

use std::path::Path;
use std::sync::OnceLock;

use photonkit::format::preamble::{PREAMBLE_LEN, Preamble, align_up};
use photonkit::format::{
    ColumnSpec, DType, Emitter, EmitterKind, MapInfo, Output, Parameterisation, PhotonMap, PhotonWriter,
    StageRecord, State, Units, columns::text_names, name, write_map,
};
use proptest::prelude::*;
use serde_json::{Map, Value, json};

use super::common::*;

// ---------------------------------------------------------------------------------------------
// Taking files apart and putting them back together.

/// Photons in [`sample`]: odd, so the last column is followed by padding.
const SAMPLE_N: usize = 25;

/// A small valid map with every column a tracer writes: two emitters, an `emitter` column,
/// 3-component `params`.
fn sample() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| synthetic_bytes(&photonkit::synthetic::two_emitters(SAMPLE_N, 7)))
}

fn preamble(bytes: &[u8]) -> Preamble {
    Preamble::from_bytes(bytes[..PREAMBLE_LEN].try_into().unwrap()).expect("magic")
}

fn meta_json(bytes: &[u8]) -> Value {
    let end = PREAMBLE_LEN + preamble(bytes).metadata_len as usize;
    serde_json::from_slice(&bytes[PREAMBLE_LEN..end]).unwrap()
}

/// Puts `text` into the existing metadata region (space-padded) and recomputes its CRC, so the
/// reader gets past the checksum and has to judge the content.
fn with_region(bytes: &[u8], text: &[u8]) -> Vec<u8> {
    let pre = preamble(bytes);
    let len = pre.metadata_len as usize;
    assert!(
        text.len() <= len,
        "test helper: edited metadata ({} bytes) outgrew its region ({len})",
        text.len()
    );
    let mut region = text.to_vec();
    region.resize(len, b' ');
    let mut out = bytes.to_vec();
    out[PREAMBLE_LEN..PREAMBLE_LEN + len].copy_from_slice(&region);
    out[..PREAMBLE_LEN]
        .copy_from_slice(&Preamble { metadata_crc32: crc32fast::hash(&region), ..pre }.to_bytes());
    out
}

/// Edits the metadata as JSON and re-serialises it (compactly) into the same region, or, when
/// it no longer fits, into a grown region with the columns moved along.
fn edit_meta(bytes: &[u8], f: impl FnOnce(&mut Value)) -> Vec<u8> {
    let mut meta = meta_json(bytes);
    f(&mut meta);
    let text = serde_json::to_vec(&meta).unwrap();
    if text.len() <= preamble(bytes).metadata_len as usize {
        with_region(bytes, &text)
    } else {
        relayout(bytes, meta, data_of(bytes))
    }
}

/// Rewrites preamble fields, leaving everything else (including the metadata CRC) alone.
fn edit_preamble(bytes: &[u8], f: impl FnOnce(&mut Preamble)) -> Vec<u8> {
    let mut pre = preamble(bytes);
    f(&mut pre);
    let mut out = bytes.to_vec();
    out[..PREAMBLE_LEN].copy_from_slice(&pre.to_bytes());
    out
}

/// Rebuilds the file around new metadata of any size: the region is resized (to keep the data
/// 64-aligned) and every column offset shifted to match. `data` replaces what follows the
/// metadata region.
fn relayout(bytes: &[u8], mut meta: Value, data: &[u8]) -> Vec<u8> {
    let old_start = (PREAMBLE_LEN as u64 + preamble(bytes).metadata_len) as i64;
    // 64 bytes of slack cover offsets that gain digits when shifted.
    let text_len = serde_json::to_vec(&meta).unwrap().len() as u64 + 64;
    let new_start = align_up(PREAMBLE_LEN as u64 + text_len);
    let delta = new_start as i64 - old_start;
    for c in meta["columns"].as_array_mut().unwrap() {
        c["offset"] = json!((c["offset"].as_u64().unwrap() as i64 + delta) as u64);
    }
    let text = serde_json::to_vec(&meta).unwrap();
    let mut region = text;
    region.resize(new_start as usize - PREAMBLE_LEN, b' ');
    let pre = Preamble {
        version_major: 1,
        version_minor: preamble(bytes).version_minor,
        metadata_crc32: crc32fast::hash(&region),
        metadata_len: region.len() as u64,
        file_len: new_start + data.len() as u64,
    };
    let mut out = pre.to_bytes().to_vec();
    out.extend_from_slice(&region);
    out.extend_from_slice(data);
    out
}

fn data_of(bytes: &[u8]) -> &[u8] {
    &bytes[PREAMBLE_LEN + preamble(bytes).metadata_len as usize..]
}

/// Appends a column (with `extra` keys in its table entry) at the end of the file.
fn append_column(bytes: &[u8], spec: &ColumnSpec, column: &[u8], extra: Value) -> Vec<u8> {
    let mut meta = meta_json(bytes);
    let mut data = data_of(bytes).to_vec();
    let offset = bytes.len() as u64;
    assert_eq!(offset % 64, 0);
    data.extend_from_slice(column);
    data.resize(align_up(data.len() as u64) as usize, 0);
    let mut entry = json!({
        "name": spec.name, "dtype": spec.dtype.name(), "components": spec.components,
        "offset": offset, "length": column.len(), "crc32": crc32fast::hash(column),
    });
    entry.as_object_mut().unwrap().extend(extra.as_object().unwrap().clone());
    meta["columns"].as_array_mut().unwrap().push(entry);
    relayout(bytes, meta, &data)
}

fn column_index(meta: &Value, column: &str) -> usize {
    meta["columns"].as_array().unwrap().iter().position(|c| c["name"] == column).unwrap()
}

fn col<'a>(meta: &'a mut Value, column: &str) -> &'a mut Value {
    let i = column_index(meta, column);
    &mut meta["columns"][i]
}

/// Changes a column's bytes in place and records its new CRC-32, so the file stays sound
/// apart from the change.
fn patch_column(bytes: &[u8], column: &str, f: impl FnOnce(&mut [u8])) -> Vec<u8> {
    let meta = meta_json(bytes);
    let c = &meta["columns"][column_index(&meta, column)];
    let (off, len) = (c["offset"].as_u64().unwrap() as usize, c["length"].as_u64().unwrap() as usize);
    let mut out = bytes.to_vec();
    f(&mut out[off..off + len]);
    let crc = crc32fast::hash(&out[off..off + len]);
    edit_meta(&out, |m| col(m, column)["crc32"] = json!(crc))
}

/// Why the reader's answer to `bytes` is wrong, if it is: it must refuse them with a message
/// naming the file and containing `needle`.
fn refusal_problem(what: &str, bytes: &[u8], needle: &str) -> Option<String> {
    match PhotonMap::from_bytes("corrupt.phm", bytes) {
        Ok(_) => Some(format!("{what}: the reader accepted it")),
        Err(e) => {
            let m = e.to_string();
            (!m.starts_with("corrupt.phm: ") || !m.contains(needle))
                .then(|| format!("{what}: message does not name the file or say {needle:?}: {m}"))
        }
    }
}

#[track_caller]
fn assert_refused(what: &str, bytes: &[u8], needle: &str) {
    if let Some(p) = refusal_problem(what, bytes, needle) {
        panic!("{p}");
    }
}

#[track_caller]
fn assert_all_refused(cases: &[(&str, Vec<u8>, &str)]) {
    let problems: Vec<String> = cases.iter().filter_map(|(w, b, n)| refusal_problem(w, b, n)).collect();
    assert!(
        problems.is_empty(),
        "{} of {} cases wrong:\n{}",
        problems.len(),
        cases.len(),
        problems.join("\n")
    );
}

// ---------------------------------------------------------------------------------------------
// Round trips of random photon maps.

/// The optional columns PHM 1.0 defines that carry free data (emitter and params are generated
/// separately because the emitters constrain them).
const OPTIONAL: &[(&str, DType, u32)] = &[
    (name::NORMAL, DType::F32, 3),
    (name::INCIDENT, DType::F32, 3),
    (name::PATH_LENGTH, DType::F32, 1),
    (name::BOUNCES, DType::U8, 1),
    (name::EMISSION_INDEX, DType::U64, 1),
    (name::SURFACE, DType::U32, 1),
    (name::BASIS_U, DType::F32, 3),
    (name::BASIS_V, DType::F32, 3),
    (name::LAMBDA2, DType::F32, 1),
    (name::R_PARAM, DType::F32, 1),
];

const DTYPES: [DType; 10] = [
    DType::U8,
    DType::U16,
    DType::U32,
    DType::U64,
    DType::I8,
    DType::I16,
    DType::I32,
    DType::I64,
    DType::F32,
    DType::F64,
];

/// Enough random bytes for every column of a case; columns take consecutive slices.
const POOL_PER_PHOTON: usize = 1024;

#[derive(Clone, Debug)]
struct Case {
    info: MapInfo,
    columns: Vec<(ColumnSpec, Vec<u8>)>,
}

fn finite_f32() -> impl Strategy<Value = f32> {
    use proptest::num::f32::*;
    POSITIVE | NEGATIVE | NORMAL | SUBNORMAL | ZERO
}

fn finite_f64() -> impl Strategy<Value = f64> {
    use proptest::num::f64::*;
    POSITIVE | NEGATIVE | NORMAL | SUBNORMAL | ZERO
}

fn json_value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        any::<u64>().prop_map(Value::from),
        finite_f64().prop_map(Value::from),
        ".{0,8}".prop_map(Value::String),
    ];
    leaf.prop_recursive(3, 12, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(Value::Array),
            prop::collection::btree_map("[a-z_]{1,6}", inner, 0..4)
                .prop_map(|m| Value::Object(m.into_iter().collect())),
        ]
    })
}

/// Keys no version of the format defines (the `x_` prefix keeps them clear of real keys).
fn extra_keys() -> impl Strategy<Value = Map<String, Value>> {
    prop::collection::btree_map("x_[a-z0-9]{1,8}", json_value(), 0..3).prop_map(|m| m.into_iter().collect())
}

fn emitter(id: u32) -> impl Strategy<Value = Emitter> {
    let kinds = prop::sample::select(vec![
        (EmitterKind::Collimated, Parameterisation::RectUv, 2),
        (EmitterKind::Point, Parameterisation::Direction, 3),
        (EmitterKind::Spot, Parameterisation::Direction, 3),
        (EmitterKind::External, Parameterisation::None, 0),
        (EmitterKind::Collimated, Parameterisation::RectUvSpectral, 3),
        (EmitterKind::Point, Parameterisation::DirectionSpectral, 4),
    ]);
    let power = {
        use proptest::num::f64::*;
        POSITIVE | NORMAL | SUBNORMAL | ZERO
    };
    let measure = {
        use proptest::num::f64::*;
        prop::option::of(POSITIVE | NORMAL | SUBNORMAL)
    };
    // A spectral dimension's scale as detect writes it: an f32 value, or none.
    let scale = prop::option::of(proptest::num::f32::POSITIVE | proptest::num::f32::NORMAL);
    (kinds, power, [finite_f32(), finite_f32(), finite_f32()], measure, json_value(), extra_keys(), scale)
        .prop_map(
            move |(
                (kind, parameterisation, param_dims),
                power_w,
                colour,
                param_measure,
                geometry,
                extra,
                scale,
            )| {
                let mut dimensions = Vec::new();
                if let Some(k) = parameterisation.spectral_component() {
                    dimensions = parameterisation.dimensions();
                    dimensions[k].scale = scale.map(|s| s.abs() as f64).filter(|s| *s > 0.0);
                }
                Emitter {
                    id,
                    kind,
                    parameterisation,
                    param_dims,
                    power_w,
                    colour,
                    param_measure,
                    geometry,
                    dimensions,
                    extra,
                }
            },
        )
}

fn stage_record() -> impl Strategy<Value = StageRecord> {
    ("[a-z]{1,8}", "[0-9.]{1,8}", ".{0,20}", json_value(), json_value(), extra_keys()).prop_map(
        |(stage, version, time, parameters, report, extra)| StageRecord {
            stage,
            version,
            time,
            parameters,
            report,
            extra,
        },
    )
}

fn case() -> impl Strategy<Value = Case> {
    (prop_oneof![Just(0usize), Just(1usize), 0..40usize], 0..=3u32).prop_flat_map(|(n, emitters)| {
        let meta = (
            (0..emitters).map(emitter).collect::<Vec<_>>(),
            prop::sample::select(vec![State::Traced, State::Detected, State::Collapsed]),
            prop::collection::vec(stage_record(), 0..3),
            ("[a-zA-Z]{0,3}", "[a-zA-Z]{0,3}", extra_keys()),
            extra_keys(),
        );
        let columns = (
            prop::collection::vec([finite_f32(), finite_f32(), finite_f32()], n),
            prop::collection::vec([finite_f32(), finite_f32(), finite_f32()], n),
            prop::sample::subsequence(OPTIONAL.to_vec(), 0..=OPTIONAL.len()),
            prop::collection::vec(("x_[a-z]{1,8}", prop::sample::select(DTYPES.to_vec()), 1..=6u32), 0..3),
            any::<bool>(),
            prop::collection::vec(any::<u8>(), n * POOL_PER_PHOTON),
            prop::collection::vec(any::<u32>(), 16),
        );
        (meta, columns).prop_map(move |(meta, columns)| build_case(n, meta, columns))
    })
}

type MetaParts =
    (Vec<Emitter>, State, Vec<StageRecord>, (String, String, Map<String, Value>), Map<String, Value>);
type ColumnParts = (
    Vec<[f32; 3]>,
    Vec<[f32; 3]>,
    Vec<(&'static str, DType, u32)>,
    Vec<(String, DType, u32)>,
    bool,
    Vec<u8>,
    Vec<u32>,
);

fn build_case(n: usize, meta: MetaParts, columns: ColumnParts) -> Case {
    let (emitters, state, history, (length, flux_unit, unit_extra), extra) = meta;
    let (position, flux, optional, unknown, emitter_column_for_one, pool, order) = columns;
    let mut pool = pool.as_slice();
    let mut take = |len: usize| {
        let (a, b) = pool.split_at(len);
        pool = b;
        a.to_vec()
    };
    let mut cols: Vec<(ColumnSpec, Vec<u8>)> = vec![
        (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&position).to_vec()),
        (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&flux).to_vec()),
    ];
    for (column, dtype, components) in optional {
        let spec = ColumnSpec::new(column, dtype, components);
        let bytes = take(n * spec.stride() as usize);
        cols.push((spec, bytes));
    }
    let ne = emitters.len();
    if ne > 1 || (ne == 1 && emitter_column_for_one) {
        let ids: Vec<u16> = take(n).iter().map(|&b| b as u16 % ne as u16).collect();
        cols.push((ColumnSpec::of::<u16>(name::EMITTER), bytemuck::cast_slice(&ids).to_vec()));
    }
    let dims = emitters.iter().map(|e| e.param_dims).max().unwrap_or(0);
    if dims > 0 {
        let spec = ColumnSpec::new(name::PARAMS, DType::F32, dims);
        let bytes = take(n * spec.stride() as usize);
        cols.push((spec, bytes));
    }
    let mut seen = std::collections::HashSet::new();
    for (column, dtype, components) in unknown {
        if seen.insert(column.clone()) {
            let spec = ColumnSpec::new(&column, dtype, components);
            let bytes = take(n * spec.stride() as usize);
            cols.push((spec, bytes));
        }
    }
    // Any order: readers must use the table, never assume one.
    let mut keyed: Vec<_> =
        cols.into_iter().enumerate().map(|(i, c)| (order[i % order.len()], i, c)).collect();
    keyed.sort_by_key(|(k, i, _)| (*k, *i));
    let info = MapInfo {
        emitters,
        units: Units { length, flux: flux_unit, extra: unit_extra },
        state,
        history,
        extra,
    };
    Case { info, columns: keyed.into_iter().map(|(_, _, c)| c).collect() }
}

fn write_case(path: &Path, info: MapInfo, columns: &[(ColumnSpec, Vec<u8>)]) -> Vec<u8> {
    let cols: Vec<(ColumnSpec, &[u8])> = columns.iter().map(|(s, b)| (s.clone(), b.as_slice())).collect();
    write_map(Output::Path(path.to_path_buf()), info, &cols).unwrap();
    std::fs::read(path).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Random photon sets and column subsets (known, unknown, any order) survive a write and a
    /// read byte-exact, and writing what was read reproduces the file bit for bit.
    #[test]
    fn random_maps_round_trip_byte_exact(case in case()) {
        let dir = tempfile::tempdir().unwrap();
        let first = write_case(&dir.path().join("a.phm"), case.info.clone(), &case.columns);
        let map = PhotonMap::from_bytes("a.phm", &first).unwrap();
        let n = case.columns[0].1.len() / case.columns[0].0.stride() as usize;
        prop_assert_eq!(map.len(), n);
        // 1.1 exactly when an emitter has a wavelength dimension (format-spec §8).
        let spectral = case.info.emitters.iter().any(|e| e.parameterisation.spectral_component().is_some());
        prop_assert_eq!(map.version(), (1, u16::from(spectral)));
        prop_assert_eq!(map.columns().len(), case.columns.len());
        for ((spec, bytes), (rspec, rbytes)) in case.columns.iter().zip(map.columns()) {
            prop_assert_eq!(spec, &rspec);
            prop_assert!(bytes.as_slice() == rbytes, "column {} differs", spec.name);
        }
        let m = map.meta();
        prop_assert_eq!(&m.emitters, &case.info.emitters);
        prop_assert_eq!(m.state, case.info.state);
        prop_assert_eq!(&m.history, &case.info.history);
        prop_assert_eq!(&m.units, &case.info.units);
        prop_assert_eq!(&m.extra, &case.info.extra);
        prop_assert!(map.verify_checksums().is_ok());
        // The box is the positions' own: every bound is some photon's coordinate.
        match m.bounding_box {
            None => prop_assert_eq!(n, 0),
            Some(b) => for k in 0..3 {
                let xs: Vec<f32> = map.positions().iter().map(|p| p[k]).collect();
                prop_assert!(xs.iter().all(|&x| b.min[k] <= x && x <= b.max[k]));
                prop_assert!(xs.contains(&b.min[k]) && xs.contains(&b.max[k]));
            },
        }
        let second = write_case(
            &dir.path().join("b.phm"),
            m.info(),
            &map.columns().into_iter().map(|(s, b)| (s, b.to_vec())).collect::<Vec<_>>(),
        );
        prop_assert!(first == second, "rewriting what was read changed the file");
    }
}

// ---------------------------------------------------------------------------------------------
// Truncation.

#[test]
fn truncation_at_every_offset_is_an_error() {
    let bytes = sample();
    for len in 0..bytes.len() {
        let e = PhotonMap::from_bytes("cut.phm", &bytes[..len]).expect_err("truncated file accepted");
        let m = e.to_string();
        assert!(m.starts_with("cut.phm: ") && m.contains("truncated"), "at {len}: {m}");
    }
    assert!(PhotonMap::from_bytes("whole.phm", bytes).is_ok());
}

/// A truncated file whose preamble was "fixed" to its new length must still be refused by the
/// column bounds check, up to the end of the last column; past it only padding was lost.
#[test]
fn truncation_with_a_consistent_file_len_is_caught_by_the_column_table() {
    let bytes = sample();
    let meta = meta_json(bytes);
    let data_start = PREAMBLE_LEN + preamble(bytes).metadata_len as usize;
    let last_end = meta["columns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["offset"].as_u64().unwrap() + c["length"].as_u64().unwrap()) as usize)
        .max()
        .unwrap();
    assert!(last_end < bytes.len(), "the sample should end with padding");
    for len in PREAMBLE_LEN..bytes.len() {
        let cut = edit_preamble(&bytes[..len], |p| p.file_len = len as u64);
        let got = PhotonMap::from_bytes("cut.phm", &cut);
        if len < data_start {
            let m = got.expect_err("metadata cut short").to_string();
            assert!(m.contains("truncated: the metadata needs"), "at {len}: {m}");
        } else if len < last_end {
            let m = got.expect_err("column cut short").to_string();
            assert!(m.contains("lie outside the") || m.contains("overlaps"), "at {len}: {m}");
        } else {
            let map = got.unwrap_or_else(|e| panic!("only padding lost at {len}, yet: {e}"));
            assert!(map.verify_checksums().is_ok());
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Corruption: raw bytes.

#[test]
fn every_corrupted_metadata_byte_fails_the_checksum() {
    let bytes = sample();
    let end = PREAMBLE_LEN + preamble(bytes).metadata_len as usize;
    for i in PREAMBLE_LEN..end {
        for flip in [0x01u8, 0x80] {
            let mut b = bytes.to_vec();
            b[i] ^= flip;
            assert_refused(&format!("byte {i} ^ {flip:#x}"), &b, "metadata checksum mismatch");
        }
    }
}

#[test]
fn every_corrupted_preamble_byte_is_refused_except_the_minor_version() {
    let bytes = sample();
    for i in 0..PREAMBLE_LEN {
        let mut b = bytes.to_vec();
        b[i] ^= 0x04;
        let got = PhotonMap::from_bytes("corrupt.phm", &b);
        if (10..12).contains(&i) {
            assert_eq!(got.expect("a newer minor version reads").version().1, if i == 10 { 4 } else { 1024 });
        } else {
            let m = got.expect_err("corrupt preamble accepted").to_string();
            let needle = match i {
                0..8 => "not a PHM photon map",
                8..10 => "is not supported",
                12..16 => "metadata checksum mismatch",
                16..24 => "metadata",
                _ => "bytes",
            };
            assert!(m.contains(needle), "byte {i}: {m}");
        }
    }
}

#[test]
fn corrupted_column_data_opens_but_fails_verification_naming_the_column() {
    let bytes = sample();
    let meta = meta_json(bytes);
    for c in meta["columns"].as_array().unwrap() {
        let (off, len) = (c["offset"].as_u64().unwrap() as usize, c["length"].as_u64().unwrap() as usize);
        for i in off..off + len {
            let mut b = bytes.to_vec();
            b[i] ^= 0x10;
            let map = PhotonMap::from_bytes("corrupt.phm", &b).expect("data is not read on open");
            let m = map.verify_checksums().expect_err("corrupt column verified").to_string();
            assert!(
                m.contains(&format!("column '{}' fails its checksum", c["name"].as_str().unwrap())),
                "{m}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Corruption: every metadata field, with the metadata CRC recomputed.

// Long because it is a table: one row per corrupted field, each with the error it must give.
#[test]
fn every_metadata_field_corrupted_in_turn_is_refused() {
    let b = sample();
    let m0 = meta_json(b);
    let pre = preamble(b);
    let data_start = PREAMBLE_LEN as u64 + pre.metadata_len;
    let n = m0["photon_count"].as_u64().unwrap();
    let off = |c: &str| m0["columns"][column_index(&m0, c)]["offset"].as_u64().unwrap();
    let e = |f: &dyn Fn(&mut Value)| edit_meta(b, f);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        // photon_count
        ("photon_count + 1", e(&|m| m["photon_count"] = json!(n + 1)), "need"),
        ("photon_count - 1", e(&|m| m["photon_count"] = json!(n - 1)), "length is"),
        ("photon_count 0", e(&|m| m["photon_count"] = json!(0)), "length is"),
        ("photon_count u64::MAX", e(&|m| m["photon_count"] = json!(u64::MAX)), "overflows its length"),
        ("photon_count 2^40", e(&|m| m["photon_count"] = json!(1u64 << 40)), "length is"),
        (
            "photon_count 2^40 with matching lengths",
            e(&|m| {
                m["photon_count"] = json!(1u64 << 40);
                for c in m["columns"].as_array_mut().unwrap() {
                    let stride = c["length"].as_u64().unwrap() / n;
                    c["length"] = json!(stride << 40);
                }
            }),
            "lie outside the",
        ),
        (
            "photon_count 2^64",
            with_region(b, &num_text(b, "photon_count", "18446744073709551616")),
            "expected u64",
        ),
        (
            "photon_count -1",
            e(&|m| m["photon_count"] = json!(-1)),
            "invalid value: integer `-1`, expected u64",
        ),
        (
            "photon_count 1.5",
            e(&|m| m["photon_count"] = json!(1.5)),
            "invalid type: floating point `1.5`, expected u64",
        ),
        (
            "photon_count \"NaN\"",
            e(&|m| m["photon_count"] = json!("NaN")),
            "invalid type: string \"NaN\", expected u64",
        ),
        (
            "photon_count missing",
            e(&|m| drop(m.as_object_mut().unwrap().remove("photon_count"))),
            "photon_count",
        ),
        // column offsets
        (
            "offset misaligned",
            e(&|m| col(m, "position")["offset"] = json!(off("position") + 4)),
            "not a multiple of 64",
        ),
        ("offset overlapping", e(&|m| col(m, "normal")["offset"] = json!(off("position"))), "overlap"),
        ("offset overlapping partly", e(&|m| col(m, "flux")["offset"] = json!(off("flux") - 64)), "overlap"),
        ("offset past the end", e(&|m| col(m, "flux")["offset"] = json!(pre.file_len)), "lie outside the"),
        ("offset near u64::MAX", e(&|m| col(m, "flux")["offset"] = json!(u64::MAX - 63)), "lie outside the"),
        (
            "offset 0 (inside the preamble)",
            e(&|m| col(m, "flux")["offset"] = json!(0)),
            "overlaps the header",
        ),
        (
            "offset inside the metadata",
            e(&|m| col(m, "flux")["offset"] = json!(data_start - 64)),
            "overlaps the header",
        ),
        ("offset negative", e(&|m| col(m, "flux")["offset"] = json!(-64)), "expected u64"),
        ("offset \"NaN\"", e(&|m| col(m, "flux")["offset"] = json!("NaN")), "invalid type"),
        // lengths
        ("length + 4", e(&|m| col(m, "position")["length"] = json!(n * 12 + 4)), "length is"),
        ("length 0", e(&|m| col(m, "emitter")["length"] = json!(0)), "length is"),
        ("length u64::MAX", e(&|m| col(m, "bounces")["length"] = json!(u64::MAX)), "length is"),
        // types and shapes
        ("position as f64", e(&|m| col(m, "position")["dtype"] = json!("f64")), "PHM 1 defines it as f32"),
        ("emitter as u32", e(&|m| col(m, "emitter")["dtype"] = json!("u32")), "PHM 1 defines it as u16"),
        ("bounces as i8", e(&|m| col(m, "bounces")["dtype"] = json!("i8")), "PHM 1 defines it as u8"),
        ("dtype f16", e(&|m| col(m, "flux")["dtype"] = json!("f16")), "unknown variant"),
        ("components 0", e(&|m| col(m, "flux")["components"] = json!(0)), "has 0 components"),
        ("components 65", e(&|m| col(m, "flux")["components"] = json!(65)), "has 65 components"),
        ("components u32::MAX", e(&|m| col(m, "normal")["components"] = json!(u32::MAX)), "components"),
        ("components 2^40", e(&|m| col(m, "normal")["components"] = json!(1u64 << 40)), "expected u32"),
        ("position with 2 components", e(&|m| col(m, "position")["components"] = json!(2)), "PHM 1 defines"),
        ("params with 5 components", e(&|m| col(m, "params")["components"] = json!(5)), "PHM 1 defines"),
        // names
        ("duplicate column name", e(&|m| col(m, "normal")["name"] = json!("position")), "appears twice"),
        ("empty column name", e(&|m| col(m, "normal")["name"] = json!("")), "empty or longer"),
        ("long column name", e(&|m| col(m, "normal")["name"] = json!("n".repeat(257))), "empty or longer"),
        ("position missing", e(&|m| col(m, "position")["name"] = json!("place")), "'position' is missing"),
        ("flux missing", e(&|m| remove_column(m, "flux")), "'flux' is missing"),
        ("crc32 > u32", e(&|m| col(m, "flux")["crc32"] = json!(1u64 << 32)), "expected u32"),
        ("columns not an array", e(&|m| m["columns"] = json!({})), "expected a sequence"),
        // emitters
        ("emitter id != index", e(&|m| m["emitters"][1]["id"] = json!(0)), "ids must equal their index"),
        ("emitter id huge", e(&|m| m["emitters"][0]["id"] = json!(70000)), "ids must equal their index"),
        ("param_dims 3 for rect_uv", e(&|m| m["emitters"][0]["param_dims"] = json!(3)), "param_dims"),
        ("param_dims 2 for direction", e(&|m| m["emitters"][1]["param_dims"] = json!(2)), "param_dims"),
        ("params wider than any emitter", e(&|m| set_rect_uv(&mut m["emitters"][1])), "largest param_dims"),
        (
            "params narrower than an emitter",
            e(&|m| {
                col(m, "params")["components"] = json!(2);
                col(m, "params")["length"] = json!(n * 8);
            }),
            "largest param_dims",
        ),
        ("several emitters, no emitter column", e(&|m| remove_column(m, "emitter")), "several emitters"),
        ("power_w \"NaN\"", e(&|m| m["emitters"][0]["power_w"] = json!("NaN")), "invalid type"),
        ("power_w negative", e(&|m| m["emitters"][0]["power_w"] = json!(-1.0)), "power"),
        (
            "colour overflows f32",
            e(&|m| m["emitters"][0]["colour"] = json!([1e39, 1, 1])),
            "number out of range",
        ),
        (
            "colour \"Infinity\"",
            e(&|m| m["emitters"][0]["colour"] = json!(["Infinity", 1, 1])),
            "invalid type",
        ),
        ("colour of 2", e(&|m| m["emitters"][0]["colour"] = json!([1, 1])), "invalid length"),
        ("param_measure 0", e(&|m| m["emitters"][0]["param_measure"] = json!(0.0)), "param_measure"),
        ("kind a number", e(&|m| m["emitters"][0]["kind"] = json!(3)), "field 'emitters[0].kind'"),
        ("emitters null", e(&|m| m["emitters"] = Value::Null), "expected a sequence"),
        // bounding box
        ("bounding_box null", e(&|m| m["bounding_box"] = Value::Null), "bounding_box is missing"),
        ("bounding_box min > max", e(&|m| swap_box(m)), "min ≤ max"),
        ("bounding_box \"NaN\"", e(&|m| m["bounding_box"]["min"][0] = json!("NaN")), "invalid type"),
        ("bounding_box 1e39", e(&|m| m["bounding_box"]["max"][2] = json!(1e39)), "number out of range"),
        (
            "bounding_box missing",
            e(&|m| drop(m.as_object_mut().unwrap().remove("bounding_box"))),
            "bounding_box",
        ),
        // units, state, history
        ("units missing", e(&|m| drop(m.as_object_mut().unwrap().remove("units"))), "units"),
        ("state a number", e(&|m| m["state"] = json!(1)), "field 'state'"),
        ("history an object", e(&|m| m["history"] = json!({})), "invalid type"),
        (
            "history record without time",
            e(&|m| drop(m["history"][0].as_object_mut().unwrap().remove("time"))),
            "time",
        ),
        // the JSON text itself
        ("metadata not an object", with_region(b, b"[1, 2, 3]"), "invalid type"),
        ("metadata empty", with_region(b, b""), "EOF"),
        (
            "trailing characters",
            with_region(b, &[serde_json::to_vec(&m0).unwrap(), b" }".to_vec()].concat()),
            "trailing",
        ),
        ("NaN literal", with_region(b, &num_text(b, "power_w", "NaN")), "not valid JSON"),
        ("not UTF-8", with_region(b, &[b"{\"x\": \"\xff\"}".as_slice()].concat()), "not UTF-8"),
        (
            "NUL padding",
            with_region(b, &[serde_json::to_vec(&m0).unwrap(), vec![0; 8]].concat()),
            "not valid JSON",
        ),
        ("deep nesting", deep_nesting(b), "nested deeper than 128 levels"),
    ];
    assert_all_refused(&cases);
}

/// The metadata text with one key's value replaced by raw text that JSON serialisers would not
/// produce.
fn num_text(bytes: &[u8], key: &str, raw: &str) -> Vec<u8> {
    let mut meta = meta_json(bytes);
    let marker = "\"@@marker@@\"";
    replace_key(&mut meta, key, json!("@@marker@@"));
    serde_json::to_string(&meta).unwrap().replacen(marker, raw, 1).into_bytes()
}

fn replace_key(v: &mut Value, key: &str, to: Value) -> bool {
    match v {
        Value::Object(o) => {
            if let Some(x) = o.get_mut(key) {
                *x = to;
                return true;
            }
            o.values_mut().any(|x| replace_key(x, key, to.clone()))
        }
        Value::Array(a) => a.iter_mut().any(|x| replace_key(x, key, to.clone())),
        _ => false,
    }
}

fn remove_column(m: &mut Value, column: &str) {
    let i = column_index(m, column);
    m["columns"].as_array_mut().unwrap().remove(i);
}

fn set_rect_uv(e: &mut Value) {
    e["kind"] = json!("collimated");
    e["parameterisation"] = json!("rect_uv");
    e["param_dims"] = json!(2);
}

fn swap_box(m: &mut Value) {
    let b = m["bounding_box"].take();
    m["bounding_box"] = json!({ "min": b["max"], "max": b["min"] });
}

/// An unknown key nested far deeper than serde_json's recursion limit (the region is grown).
fn deep_nesting(bytes: &[u8]) -> Vec<u8> {
    let text = serde_json::to_string(&meta_json(bytes)).unwrap();
    let deep = format!("{}{}", "[".repeat(5000), "]".repeat(5000));
    let text = format!("{{\"x_deep\": {deep}, {}", &text[1..]);
    // Grow the region to hold it, keeping the data 64-aligned and the offsets right.
    let meta = meta_json(bytes);
    let grown = relayout(bytes, meta, data_of(bytes));
    let region = align_up((PREAMBLE_LEN + text.len() + 64) as u64) as usize - PREAMBLE_LEN;
    let extra = region as u64 - preamble(&grown).metadata_len;
    let mut meta = meta_json(&grown);
    for c in meta["columns"].as_array_mut().unwrap() {
        c["offset"] = json!(c["offset"].as_u64().unwrap() + extra);
    }
    let text = format!("{{\"x_deep\": {deep}, {}", &serde_json::to_string(&meta).unwrap()[1..]);
    let mut padded = text.into_bytes();
    padded.resize(region, b' ');
    let pre = Preamble {
        metadata_crc32: crc32fast::hash(&padded),
        metadata_len: region as u64,
        file_len: (PREAMBLE_LEN + region + data_of(bytes).len()) as u64,
        ..preamble(bytes)
    };
    [pre.to_bytes().as_slice(), &padded, data_of(bytes)].concat()
}

#[test]
fn deep_nesting_helper_builds_a_file_that_is_otherwise_sound() {
    // Without the nesting the same construction must read, or the test above proves nothing.
    let b = deep_nesting(sample());
    let text = String::from_utf8(b[PREAMBLE_LEN..PREAMBLE_LEN + preamble(&b).metadata_len as usize].to_vec())
        .unwrap();
    let shallow = text.replacen(&format!("{}{}", "[".repeat(5000), "]".repeat(5000)), "[[]]", 1);
    let fixed = with_region(&b, shallow.trim_end().as_bytes());
    let map = PhotonMap::from_bytes("shallow.phm", &fixed).unwrap();
    assert_eq!(map.meta().extra["x_deep"], json!([[]]));
    assert!(map.verify_checksums().is_ok());
    // Nesting within the documented limit (128 levels, the object itself included) is an
    // unknown key like any other, and is ignored.
    let within = text.replacen(
        &format!("{}{}", "[".repeat(5000), "]".repeat(5000)),
        &format!("{}{}", "[".repeat(120), "]".repeat(120)),
        1,
    );
    let map = PhotonMap::from_bytes("within.phm", &with_region(&b, within.trim_end().as_bytes())).unwrap();
    assert!(map.meta().extra.contains_key("x_deep"));
}

#[test]
fn every_preamble_field_corrupted_in_turn_is_refused() {
    let b = sample();
    let pre = preamble(b);
    let p = |f: &dyn Fn(&mut Preamble)| edit_preamble(b, f);
    let mut wrong_magic = b.to_vec();
    wrong_magic[1] = b'Q';
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("wrong magic", wrong_magic, "not a PHM photon map"),
        ("PNG magic", [b"\x89PNG\r\n\x1a\n".as_slice(), &b[8..]].concat(), "not a PHM photon map"),
        ("short and wrong magic", b"PK\x03\x04".to_vec(), "not a PHM photon map"),
        ("major 2", p(&|p| p.version_major = 2), "PHM version 2.0 is not supported"),
        ("major 0", p(&|p| p.version_major = 0), "PHM version 0.0 is not supported"),
        ("major u16::MAX", p(&|p| p.version_major = u16::MAX), "reads major version 1"),
        ("metadata_len 2^40", p(&|p| p.metadata_len = 1 << 40), "exceeds the limit"),
        ("metadata_len u64::MAX", p(&|p| p.metadata_len = u64::MAX), "exceeds the limit"),
        ("metadata_len = file_len", p(&|p| p.metadata_len = pre.file_len), "truncated: the metadata"),
        ("metadata_len + 64", p(&|p| p.metadata_len += 64), "metadata checksum mismatch"),
        ("metadata_len - 1", p(&|p| p.metadata_len -= 1), "metadata checksum mismatch"),
        ("metadata_len 0", p(&|p| p.metadata_len = 0), "metadata checksum mismatch"),
        ("metadata_crc32 wrong", p(&|p| p.metadata_crc32 ^= 1), "metadata checksum mismatch"),
        ("file_len + 1", p(&|p| p.file_len += 1), "truncated"),
        ("file_len - 1", p(&|p| p.file_len -= 1), "trailing data"),
        ("file_len 0", p(&|p| p.file_len = 0), "trailing data"),
        ("file_len u64::MAX", p(&|p| p.file_len = u64::MAX), "truncated"),
        ("trailing bytes", [b, &[0u8; 64][..]].concat(), "trailing data"),
    ];
    assert_all_refused(&cases);
    let m = PhotonMap::from_bytes("new.phm", &p(&|p| p.version_major = 2)).unwrap_err().to_string();
    assert!(m.contains("newer major version"), "{m}");
}

#[test]
fn an_empty_map_must_have_a_null_bounding_box() {
    let empty = synthetic_bytes(&photonkit::synthetic::collimated_cusp(0, 1));
    assert!(open_bytes(&empty).is_empty());
    let boxed = edit_meta(&empty, |m| m["bounding_box"] = json!({ "min": [0, 0, 0], "max": [0, 0, 0] }));
    assert_refused("box on an empty map", &boxed, "bounding_box must be null");
}

// ---------------------------------------------------------------------------------------------
// Newer minor versions.

#[test]
fn a_newer_minor_version_with_unknown_columns_and_keys_reads_and_is_carried_through() {
    let n = SAMPLE_N;
    let weights: Vec<f64> = (0..n * 2).map(|i| i as f64 * 0.25 - 3.0).collect();
    let spec = ColumnSpec::new("x_weight", DType::F64, 2);
    let b = append_column(sample(), &spec, bytemuck::cast_slice(&weights), json!({ "x_unit": "sr" }));
    let b = edit_meta(&b, |m| {
        m["x_future"] = json!({ "spectral": [400, 700], "note": "from 1.9" });
        m["emitters"][0]["x_spectrum"] = json!("d65");
        m["units"]["x_time"] = json!("s");
        m["history"][0]["x_host"] = json!("farm-7");
        col(m, "position")["x_compression"] = json!(null);
    });
    let b = edit_preamble(&b, |p| p.version_minor = 9);
    let map = PhotonMap::from_bytes("new.phm", &b).expect("a newer minor version reads");
    assert_eq!(map.version(), (1, 9));
    assert!(map.verify_checksums().is_ok());
    assert_eq!(
        map.column::<[f64; 2]>("x_weight").unwrap().unwrap(),
        bytemuck::cast_slice::<f64, [f64; 2]>(&weights)
    );
    assert_eq!(map.meta().column("x_weight").unwrap().extra["x_unit"], json!("sr"));
    assert!(photonkit::inspect::check(&map).is_empty(), "{:?}", photonkit::inspect::check(&map));

    // A stage passes everything it does not know through unchanged.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.phm");
    write_map(Output::Path(out.clone()), map.meta().info(), &map.columns()).unwrap();
    let back = PhotonMap::open_path(&out).unwrap();
    assert_eq!(back.version(), (1, 0), "photonkit writes minor version 0");
    for (a, b) in map.columns().iter().zip(back.columns()) {
        assert_eq!(a.0, b.0);
        assert!(a.1 == b.1, "column {} changed", a.0.name);
    }
    let (m, mb) = (map.meta(), back.meta());
    assert_eq!(mb.extra["x_future"], m.extra["x_future"]);
    assert_eq!(mb.emitters[0].extra["x_spectrum"], json!("d65"));
    assert_eq!(mb.units.extra["x_time"], json!("s"));
    assert_eq!(mb.history[0].extra["x_host"], json!("farm-7"));
    assert_eq!(mb.column("x_weight").unwrap().extra["x_unit"], json!("sr"), "column keys are carried");
    assert!(mb.column("position").unwrap().extra.contains_key("x_compression"));
    assert_eq!(m.columns.len(), mb.columns.len());
}

#[test]
fn unknown_kinds_parameterisations_and_states_read_as_unknown() {
    let b = edit_meta(sample(), |m| {
        m["state"] = json!("relaxed_twice");
        m["emitters"][1]["kind"] = json!("laser");
        m["emitters"][1]["parameterisation"] = json!("polar");
    });
    let map = PhotonMap::from_bytes("new.phm", &b).unwrap();
    assert_eq!(map.meta().state, State::Unknown);
    assert_eq!(map.meta().emitters[1].kind, EmitterKind::Unknown);
    assert_eq!(map.meta().emitters[1].parameterisation, Parameterisation::Unknown);
    let s = photonkit::inspect::summarize(&map);
    assert_eq!(s.state, "unknown");
}

// ---------------------------------------------------------------------------------------------
// Fuzz regressions: every input the fuzzer (fuzz/, target read_phm) crashed on.

#[test]
fn fuzz_regressions_do_not_panic() {
    let dir = root().join("tests/fuzz-regressions");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        // The other parsers' regressions (`.gltf`) have their own test.
        if path.extension().is_none_or(|e| e != "phm") {
            continue;
        }
        let bytes = std::fs::read(&path).unwrap();
        // What the fuzz target does: open, then everything inspect does with an opened map.
        if let Ok(map) = PhotonMap::from_bytes("fuzz.phm", &bytes) {
            let _ = map.verify_checksums();
            assert_eq!(photonkit::inspect::summarize(&map).photon_count as usize, map.len());
            let _ = photonkit::inspect::check(&map);
        }
        seen += 1;
    }
    assert!(seen > 0, "no regression inputs in {}", dir.display());
}

// ---------------------------------------------------------------------------------------------
// The writer refuses bad photons and leaves nothing behind.

fn assert_dir_empty(dir: &Path) {
    let left: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.is_empty(), "files left behind: {left:?}");
}

#[test]
fn the_writer_refuses_non_finite_positions_and_flux_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.phm");
    let ok = [[0.5f32, 0.25, 0.0]; 4];
    for (column, bad) in [("position", f32::NAN), ("position", f32::NEG_INFINITY), ("flux", f32::INFINITY)] {
        let mut pos = ok;
        let mut flux = [[0.1f32; 3]; 4];
        if column == "position" {
            pos[2][1] = bad
        } else {
            flux[2][0] = bad
        }
        let err = write_map(
            Output::Path(target.clone()),
            MapInfo::new(vec![], State::Traced),
            &[
                (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&pos)),
                (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&flux)),
            ],
        )
        .expect_err("non-finite photon written");
        let m = err.to_string();
        assert!(m.contains(&format!("photon 2 has a non-finite value in column '{column}'")), "{m}");
        assert!(m.contains("out.phm"), "{m}");
        assert_dir_empty(dir.path());
    }

    // Streaming: a bad photon in a later chunk still leaves nothing, and so does a writer
    // dropped before `finish`.
    let specs = [ColumnSpec::of::<[f32; 3]>(name::POSITION), ColumnSpec::of::<[f32; 3]>(name::FLUX)];
    let info = MapInfo::new(vec![], State::Traced);
    let mut w = PhotonWriter::create(Output::Path(target.clone()), info.clone(), &specs, 4).unwrap();
    w.push(&[bytemuck::cast_slice(&ok[..2]), bytemuck::cast_slice(&[[1.0f32; 3]; 2])]).unwrap();
    let err = w.push(&[bytemuck::cast_slice(&ok[..2]), bytemuck::cast_slice(&[[1.0f32, f32::NAN, 1.0]; 2])]);
    assert!(err.unwrap_err().to_string().contains("photon 2 has a non-finite value in column 'flux'"));
    drop(w);
    assert_dir_empty(dir.path());
    let mut w = PhotonWriter::create(Output::Path(target.clone()), info.clone(), &specs, 4).unwrap();
    w.push(&[bytemuck::cast_slice(&ok[..2]), bytemuck::cast_slice(&[[1.0f32; 3]; 2])]).unwrap();
    let err = w.finish().expect_err("2 of 4 photons");
    assert!(err.to_string().contains("2 photons pushed, 4 declared"));
    assert_dir_empty(dir.path());
}

/// The writer must not produce a file its own reader refuses.
#[test]
fn the_writer_refuses_metadata_the_reader_would_refuse() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.phm");
    let m = photonkit::synthetic::two_emitters(10, 3);
    let without_emitter: Vec<_> = m.columns().into_iter().filter(|(s, _)| s.name != name::EMITTER).collect();
    let mut bad_dims = m.info("t", 0, SAMPLE_TIME);
    bad_dims.emitters[0].param_dims = 3;
    let mut negative = m.info("t", 0, SAMPLE_TIME);
    negative.emitters[1].power_w = -1.0;
    let cases = [
        ("no emitter column", m.info("t", 0, SAMPLE_TIME), without_emitter, "several emitters"),
        ("param_dims", bad_dims, m.columns(), "param_dims"),
        ("negative power", negative, m.columns(), "power"),
    ];
    for (what, info, cols, needle) in cases {
        let err = write_map(Output::Path(target.clone()), info, &cols).expect_err(what).to_string();
        assert!(err.contains(needle) && err.contains("out.phm"), "{what}: {err}");
        assert_dir_empty(dir.path());
    }
}

// ---------------------------------------------------------------------------------------------
// `photonkit inspect` on bad input, and its outputs.

fn write_tmp(dir: &Path, file: &str, bytes: &[u8]) -> String {
    let p = dir.join(file);
    std::fs::write(&p, bytes).unwrap();
    p.display().to_string()
}

#[track_caller]
fn assert_cli_fails(args: &[&str], file: &str, needle: &str) {
    let o = photonkit(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    assert!(err.contains(file), "{args:?}: the message does not name {file}: {err}");
    assert!(err.contains(needle), "{args:?}: the message does not say {needle:?}: {err}");
}

#[test]
fn inspect_refuses_broken_files_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut flipped = sample().to_vec();
    flipped[100] ^= 1;
    let corrupt = write_tmp(d, "corrupt.phm", &flipped);
    let truncated = write_tmp(d, "truncated.phm", &sample()[..sample().len() / 2]);
    let empty = write_tmp(d, "empty.phm", b"");
    let newer = write_tmp(d, "newer.phm", &edit_preamble(sample(), |p| p.version_major = 2));
    let text = write_tmp(d, "text.phm", b"x,y,z\n1,2,3\n");
    let missing = d.join("missing.phm").display().to_string();
    let folder = d.display().to_string();
    for flags in [&[][..], &["--json"], &["--check"], &["--dump"]] {
        for (file, needle) in [
            (&corrupt, "metadata checksum mismatch"),
            (&truncated, "truncated"),
            (&empty, "truncated"),
            (&newer, "PHM version 2.0 is not supported"),
            (&text, "not a PHM photon map"),
            (&missing, "No such file"),
            (&folder, ""),
        ] {
            let args: Vec<&str> = ["inspect"].iter().chain(flags).copied().chain([file.as_str()]).collect();
            assert_cli_fails(&args, file, needle);
        }
    }
}

#[test]
fn inspect_check_finds_a_nan_position_naming_the_rule() {
    let dir = tempfile::tempdir().unwrap();
    let nan = patch_column(sample(), "position", |b| {
        b[3 * 12 + 4..3 * 12 + 8].copy_from_slice(&f32::NAN.to_le_bytes())
    });
    // The checksums hold (the CRC was recomputed): only the invariant catches it.
    let map = PhotonMap::from_bytes("nan.phm", &nan).unwrap();
    assert!(map.verify_checksums().is_ok());
    let file = write_tmp(dir.path(), "nan.phm", &nan);
    let o = photonkit(&["inspect", "--check", &file]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"));
    assert!(err.contains(&file) && err.contains("column 'position' holds only finite values"), "{err}");
    assert!(err.contains("first: photon 3"), "{err}");
    // The summary still opens it and counts the NaN.
    let o = photonkit(&["inspect", "--json", &file]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(s["columns"][0]["name"], "position");
    assert_eq!(s["columns"][0]["stats"][1]["nan"], 1);
    // And the sound original passes.
    let good = write_tmp(dir.path(), "good.phm", sample());
    let o = photonkit(&["inspect", "--check", &good]);
    assert!(o.status.success(), "{}", stderr(&o));
    // A corrupt column (CRC not recomputed) is reported as such.
    let mut flipped = sample().to_vec();
    let off = meta_json(sample())["columns"][0]["offset"].as_u64().unwrap() as usize;
    flipped[off] ^= 1;
    let bad = write_tmp(dir.path(), "bad.phm", &flipped);
    assert_cli_fails(&["inspect", "--check", &bad], &bad, "fails its checksum");
}

fn total_flux(map: &PhotonMap) -> [f64; 3] {
    let mut t = [0.0f64; 3];
    for f in map.flux() {
        (0..3).for_each(|k| t[k] += f[k] as f64);
    }
    t
}

#[test]
fn inspect_sample_keeps_the_total_flux_and_the_count() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("src.phm");
    write_synthetic(&photonkit::synthetic::two_emitters(900, 5), "two", &src);
    let input = PhotonMap::open_path(&src).unwrap();
    let out = dir.path().join("out.phm").display().to_string();
    let o = photonkit(&["inspect", "--sample", "120", "--seed", "4", "-o", &out, src.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = PhotonMap::open(&out).unwrap();
    assert_eq!(s.len(), 120);
    assert!(s.verify_checksums().is_ok());
    let (a, b) = (total_flux(&input), total_flux(&s));
    for k in 0..3 {
        assert!(((a[k] - b[k]) / a[k]).abs() < 1e-6, "channel {k}: {} vs {}", a[k], b[k]);
    }
    assert_eq!(s.meta().history.last().unwrap().stage, "sample");
    // Every kept photon is one of the input's, positions unchanged.
    let all: std::collections::HashSet<[u32; 3]> =
        input.positions().iter().map(|p| p.map(f32::to_bits)).collect();
    assert!(s.positions().iter().all(|p| all.contains(&p.map(f32::to_bits))));
    assert!(photonkit::inspect::check(&s).is_empty(), "{:?}", photonkit::inspect::check(&s));

    // As a pipe: standard output read back.
    let o = photonkit(&["inspect", "--sample", "100", "-o", "-", src.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let piped = PhotonMap::from_bytes("<stdout>", &o.stdout).unwrap();
    assert_eq!(piped.len(), 100);
    assert!(piped.verify_checksums().is_ok());
    let c = total_flux(&piped);
    assert!((0..3).all(|k| ((a[k] - c[k]) / a[k]).abs() < 1e-6));

    // A failed sample leaves no file.
    let nowhere = dir.path().join("no-such-dir").join("out.phm").display().to_string();
    assert_cli_fails(&["inspect", "--sample", "10", "-o", &nowhere, src.to_str().unwrap()], "out.phm", "");
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "{left:?}");
}

#[test]
fn inspect_dump_round_trips_every_value_exactly() {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(17);
    let n = 50;
    let finite32 = |rng: &mut rand_pcg::Pcg64Mcg| loop {
        let x = f32::from_bits(rng.random());
        if x.is_finite() {
            return x;
        }
    };
    let mut pos: Vec<f32> = (0..n * 3).map(|_| finite32(&mut rng)).collect();
    pos[..6].copy_from_slice(&[-0.0, 0.0, f32::MIN_POSITIVE / 8.0, f32::MAX, f32::MIN, 0.1]);
    let flux: Vec<f32> = (0..n * 3).map(|_| finite32(&mut rng)).collect();
    let mut cols: Vec<(ColumnSpec, Vec<u8>)> = vec![
        (ColumnSpec::of::<[f32; 3]>(name::POSITION), bytemuck::cast_slice(&pos).to_vec()),
        (ColumnSpec::of::<[f32; 3]>(name::FLUX), bytemuck::cast_slice(&flux).to_vec()),
    ];
    for (i, dtype) in DTYPES.into_iter().enumerate() {
        let spec = ColumnSpec::new(&format!("x_{}", dtype.name()), dtype, 1 + i as u32 % 3);
        let mut bytes: Vec<u8> = (0..n * spec.stride() as usize).map(|_| rng.random()).collect();
        if dtype.is_float() {
            // Keep floats finite: "NaN" parses back, but not to the same payload.
            let s = dtype.size() as usize;
            for c in bytes.chunks_exact_mut(s) {
                if !dtype.value_f64(c, 0).is_finite() {
                    c[s - 1] &= 0x80;
                }
            }
        } else {
            // The extremes of every integer type.
            bytes[..dtype.size() as usize].fill(0xFF);
            bytes[dtype.size() as usize..2 * dtype.size() as usize].fill(0);
        }
        cols.push((spec, bytes));
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("dump.phm");
    write_case(&file, MapInfo::new(vec![], State::Traced), &cols);
    let o = photonkit(&["inspect", "--dump", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split('\t').collect();
    let names: Vec<String> = cols.iter().flat_map(|(s, _)| text_names(&s.name, s.components)).collect();
    assert_eq!(header, names);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split('\t').collect()).collect();
    assert_eq!(rows.len(), n);
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), names.len());
        let mut field = row.iter();
        for (spec, bytes) in &cols {
            let s = spec.dtype.size() as usize;
            for k in 0..spec.components as usize {
                let at = (i * spec.components as usize + k) * s;
                let raw = &bytes[at..at + s];
                let t = field.next().unwrap();
                let parsed: Vec<u8> = match spec.dtype {
                    DType::F32 => t.parse::<f32>().unwrap().to_le_bytes().to_vec(),
                    DType::F64 => t.parse::<f64>().unwrap().to_le_bytes().to_vec(),
                    DType::U8 | DType::U16 | DType::U32 | DType::U64 => {
                        t.parse::<u64>().unwrap().to_le_bytes()[..s].to_vec()
                    }
                    _ => t.parse::<i64>().unwrap().to_le_bytes()[..s].to_vec(),
                };
                assert_eq!(parsed, raw, "photon {i}, {} component {k}: {t:?}", spec.name);
            }
        }
    }
    // --head N prints the same first N rows.
    let o = photonkit(&["inspect", "--head", "3", file.to_str().unwrap()]);
    let head: Vec<String> = stdout(&o).lines().map(String::from).collect();
    assert_eq!(head, text.lines().take(4).map(String::from).collect::<Vec<_>>());
}

/// The summary shows the photons, not the file layout (issue 29): integer columns print as
/// integers, and offsets, lengths and CRCs appear only with `--layout`.
#[test]
fn inspect_summary_prints_integers_as_integers_and_the_layout_on_request() {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/collimated-cusp.phm");
    let file = file.to_str().unwrap();
    let plain = stdout(&photonkit(&["inspect", file]));
    let row = |text: &str, name: &str| -> Vec<String> {
        let line =
            text.lines().find(|l| l.trim_start().starts_with(name)).unwrap_or_else(|| panic!("{text}"));
        line.split_whitespace().map(str::to_string).collect()
    };
    // name, type, min, max, mean, nan, inf, label.
    assert_eq!(row(&plain, "bounces")[..5], ["bounces", "u8×1", "1", "1", "1"], "{plain}");
    assert_eq!(
        row(&plain, "emission_index")[..5],
        ["emission_index", "u64×1", "0", "1999", "999.5"],
        "{plain}"
    );
    assert_eq!(row(&plain, "position")[2], "-2.995529e-1", "{plain}");
    assert!(!plain.contains("crc32") && !plain.contains("offset"), "{plain}");
    let layout = stdout(&photonkit(&["inspect", "--layout", file]));
    assert!(layout.contains("crc32") && layout.contains("offset"), "{layout}");
    assert_eq!(row(&layout, "bounces")[2..5], ["122752", "2000", "50727c8b"], "{layout}");
}
