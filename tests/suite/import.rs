//! `photonkit import` and `export`: round trips, hand-written PLY, Radiance maps against
//! pmapdump, and bad input.

use std::path::{Path, PathBuf};

use photonkit::export::{self, ExportFormat};
use photonkit::format::{EmitterKind, Output, Parameterisation, PhotonMap};
use photonkit::import::{self, Imported, Options, SourceFormat};

use super::common::*;

fn fixture(rel: &str) -> PathBuf {
    root().join("tests/fixtures").join(rel)
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}

fn import_bytes(name: &str, bytes: &[u8]) -> Result<Imported, import::ImportError> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    import::import(&p, &Options::default())
}

fn import_err(name: &str, bytes: &[u8]) -> String {
    import_bytes(name, bytes).expect_err("input must be refused").to_string()
}

// ---------------------------------------------------------------------------------------------
// Round trips

/// Every column of `m` (every column of the samples) comes back byte for byte.
fn assert_same_columns(original: &PhotonMap, back: &Imported, how: &str) {
    let cols = original.columns();
    assert_eq!(back.columns.len(), cols.len(), "{how}: column count");
    for ((s, b), (s2, b2)) in cols.iter().zip(&back.columns) {
        assert_eq!(s, s2, "{how}: column spec");
        assert!(*b == b2.as_slice(), "{how}: column '{}' differs", s.name);
    }
}

#[test]
fn phm_to_ply_csv_and_tsv_and_back_is_byte_exact() {
    let dir = tempfile::tempdir().unwrap();
    for file in ["collimated-cusp.phm", "point-ring.phm", "two-emitters.phm", "minimal.phm"] {
        let map = PhotonMap::open_path(&sample_path(file)).unwrap();
        for (to, ext) in [(ExportFormat::Ply, "ply"), (ExportFormat::Csv, "csv")] {
            let out = dir.path().join(format!("{file}.{ext}"));
            export::export(&map, to, &Output::Path(out.clone())).unwrap();
            let back = import::import(&out, &Options::default()).unwrap();
            assert_same_columns(&map, &back, &format!("{file} via {ext}"));
            // Emitters come back as external ones with the same parameterisation.
            let want = map.meta().emitters.first().map_or(Parameterisation::None, |e| e.parameterisation);
            assert_eq!(back.emitters[0].parameterisation, want, "{file} via {ext}");
            assert_eq!(back.emitters.len(), map.meta().emitters.len().max(1), "{file} via {ext}");
            // And the whole chain writes a PHM file whose columns are the original's.
            let phm = dir.path().join(format!("{file}.{ext}.phm"));
            back.write(Output::Path(phm.clone()), serde_json::json!({})).unwrap();
            let again = PhotonMap::open_path(&phm).unwrap();
            for ((s, b), (s2, b2)) in map.columns().iter().zip(again.columns()) {
                assert!(s == &s2 && *b == b2, "{file} via {ext} → PHM: column '{}'", s.name);
            }
        }
        let mut tsv = Vec::new();
        photonkit::inspect::dump_tsv(&map, None, &mut tsv).unwrap();
        let back = import_bytes("dump.tsv", &tsv).unwrap();
        assert_same_columns(&map, &back, &format!("{file} via inspect --dump"));
    }
}

#[test]
fn export_ply_has_viewer_colours_and_normals() {
    let map = PhotonMap::open_path(&sample_path("point-ring.phm")).unwrap();
    let mut out = Vec::new();
    export::write(&map, ExportFormat::Ply, &mut out, "t.ply").unwrap();
    let end = out.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&out[..end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    for p in ["float nx", "float flux_r", "double emission_index", "uchar red", "uchar blue"] {
        assert!(header.contains(&format!("property {p}\n")), "{p} missing from\n{header}");
    }
    let n = map.len();
    assert_eq!((out.len() - end) % n, 0);
}

#[test]
fn unknown_columns_survive_a_round_trip() {
    let t = "x,y,z,flux_r,flux_g,flux_b,weight,tag_0,tag_1\n0,1,2,1,1,1,0.1,3,4\n5,6,7,1,1,1,2.5,-1,8\n";
    let m = import_bytes("t.csv", t.as_bytes()).unwrap();
    let specs: Vec<_> =
        m.columns.iter().map(|(s, _)| (s.name.as_str(), s.dtype.name(), s.components)).collect();
    assert_eq!(specs, [("position", "f32", 3), ("flux", "f32", 3), ("weight", "f32", 1), ("tag", "i64", 2)]);
    assert_eq!(f32s(m.column("weight").unwrap()), [0.1, 2.5]);
}

// ---------------------------------------------------------------------------------------------
// Hand-written PLY

#[test]
fn hand_written_ply_imports_in_all_three_encodings() {
    for f in ["ply/hand-ascii.ply", "ply/hand-le.ply", "ply/hand-be.ply"] {
        let m = import::import(&fixture(f), &Options::default()).unwrap();
        assert_eq!(m.format, SourceFormat::Ply);
        assert_eq!(m.len(), 3, "{f}");
        let col = |n: &str| m.column(n).unwrap_or_else(|| panic!("{f}: no column {n}"));
        assert_eq!(f32s(col("position")), [0.5, 0.25, 0.0, -1.0, 2.0, 3e-3, 100.0, -2.5, 0.125], "{f}");
        assert_eq!(f32s(col("normal")), [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.6, 0.0, 0.8], "{f}");
        assert_eq!(f32s(col("flux")), [0.01, 0.02, 0.03, 1.0, 1.0, 1.0, 0.0, 0.5, 0.25], "{f}");
        assert_eq!(f32s(col("params")), [0.1, 0.9, 0.5, 0.5, 1.0, 0.0], "{f}");
        assert_eq!(col("emitter"), [0, 0, 1, 0, 1, 0], "{f}");
        assert_eq!(col("bounces"), [1, 2, 0], "{f}");
        assert_eq!(f32s(col("path_length")), [2.5, 10.0, 0.0625], "{f}");
        assert_eq!(f32s(col("weight")), [7.25, 0.0, 1.0], "{f}");
        let tag: Vec<i32> =
            col("tag").chunks_exact(4).map(|c| i32::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(tag, [-3, 42, 0], "{f}");
        assert_eq!(m.emitters.len(), 2);
        assert!(m.emitters.iter().all(|e| e.kind == EmitterKind::External
            && e.parameterisation == Parameterisation::RectUv
            && e.param_dims == 2));
    }
}

#[test]
fn photons_without_parameters_import_with_one_external_emitter() {
    let t = "x\ty\tz\tflux_r\tflux_g\tflux_b\n0\t0\t0\t1\t2\t3\n";
    let m = import_bytes("t.tsv", t.as_bytes()).unwrap();
    assert_eq!(m.emitters.len(), 1);
    assert_eq!(m.emitters[0].parameterisation, Parameterisation::None);
    assert_eq!(m.emitters[0].param_dims, 0);
    assert_eq!(m.emitters[0].power_w, 6.0);
}

// ---------------------------------------------------------------------------------------------
// Radiance

/// C's `%g` (6 significant digits, trailing zeros removed), as pmapdump prints.
fn printf_g(v: f64) -> String {
    if v == 0.0 {
        return if v.is_sign_negative() { "-0" } else { "0" }.into();
    }
    let strip = |s: &str| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s.to_string()
        }
    };
    let sci = format!("{v:.5e}");
    let (mant, exp) = sci.split_once('e').unwrap();
    let x: i32 = exp.parse().unwrap();
    if !(-4..6).contains(&x) {
        format!("{}e{}{:02}", strip(mant), if x < 0 { '-' } else { '+' }, x.abs())
    } else {
        strip(&format!("{v:.*}", (5 - x) as usize))
    }
}

#[test]
fn printf_g_matches_c() {
    for (v, s) in [(4.78749e-17, "4.78749e-17"), (-0.207001, "-0.207001"), (100.0, "100"), (1e6, "1e+06")] {
        assert_eq!(printf_g(v), s);
    }
    assert_eq!(printf_g(123456.7), "123457");
    assert_eq!(printf_g(0.0001), "0.0001");
}

/// The text pmapdump -a -f prints for the imported photons.
fn pmapdump_text(m: &Imported) -> String {
    let pos = f32s(m.column("position").unwrap());
    let flux = f32s(m.column("flux").unwrap());
    let mut s = String::new();
    for (p, f) in pos.chunks_exact(3).zip(flux.chunks_exact(3)) {
        let v: Vec<String> = p.iter().chain(f).map(|&x| printf_g(x as f64)).collect();
        s.push_str(&v.join("\t"));
        s.push('\n');
    }
    s
}

const RADIANCE_MAPS: &[&str] = &[
    "kdt/glass_sphere_caustic_10k",
    "kdt/metal_ring_caustic_10k",
    "kdt/glass_sphere_contrib_10k",
    "kdt_PD/glass_sphere_contrib_10k",
    "ooc/glass_sphere_caustic_10k",
];

#[test]
fn radiance_maps_reproduce_pmapdump() {
    for name in RADIANCE_MAPS {
        let base = fixture(&format!("radiance/{name}"));
        let m = import::import(&base.with_extension("pm"), &Options::default()).unwrap();
        let text = pmapdump_text(&m);
        let head = std::fs::read_to_string(base.with_extension("pmapdump.head.txt")).unwrap();
        for (i, (ours, theirs)) in text.lines().zip(head.lines()).enumerate() {
            assert_eq!(ours, theirs, "{name}: photon {i}");
        }
        // The whole dump, by line count and CRC-32 (the full dumps are too big to keep).
        let sum = std::fs::read_to_string(base.with_extension("pmapdump.sum")).unwrap();
        let want: Vec<&str> = sum.split_whitespace().collect();
        assert_eq!(text.lines().count().to_string(), want[1], "{name}: photon count");
        assert_eq!(format!("{:08x}", crc32fast::hash(text.as_bytes())), want[3], "{name}: dump CRC-32");
        // Where the full dumps exist (a developer's machine), compare line by line too.
        let full = root().join("../shared/radiance").join(format!("{name}.pmapdump.txt"));
        if let Ok(full) = std::fs::read_to_string(full) {
            assert!(text == full, "{name}: differs from the full pmapdump output");
        }
        let caustic = m.column("caustic").unwrap();
        if name.contains("caustic") {
            assert!(caustic.iter().all(|&c| c == 1), "{name}: caustic maps flag every photon");
        }
    }
}

#[test]
fn radiance_pd_primaries_become_emission_directions() {
    let m =
        import::import(&fixture("radiance/kdt_PD/glass_sphere_contrib_10k.pm"), &Options::default()).unwrap();
    assert_eq!(m.emitters.len(), 1);
    assert_eq!(m.emitters[0].parameterisation, Parameterisation::Direction);
    assert_eq!(m.emitters[0].param_dims, 3);
    let params = f32s(m.column("params").unwrap());
    assert_eq!(params.len(), m.len() * 3);
    for d in params.chunks_exact(3) {
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-5, "{d:?}");
        // The lamp hangs above the floor: photons leave it downward (−z) or sideways.
    }
    let down = params.chunks_exact(3).filter(|d| d[2] < 0.0).count();
    assert!(down * 10 > m.len() * 9, "{down} of {} emission directions point down", m.len());
    // The map passes photonkit's own invariant checks once written.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("pd.phm");
    m.write(Output::Path(p.clone()), serde_json::json!({})).unwrap();
    let map = PhotonMap::open_path(&p).unwrap();
    let v = photonkit::inspect::check(&map);
    assert!(v.is_empty(), "{v:?}");
    // Caustic maps carry no primaries: no parameters.
    let c =
        import::import(&fixture("radiance/kdt/glass_sphere_caustic_10k.pm"), &Options::default()).unwrap();
    assert!(c.column("params").is_none());
    assert_eq!(c.emitters[0].parameterisation, Parameterisation::None);
}

#[test]
fn radiance_direction_codes_match_read_pmap() {
    // The first 20 primaries of the PD map as the layout notes' independent reader decoded them:
    // "i srcIdx=0 dircode=0x... dir=(x, y, z) pos=(...)", directions printed to 6 decimals.
    let text = std::fs::read_to_string(fixture(
        "radiance/kdt_PD/glass_sphere_contrib_10k.read_pmap_primaries_first20.txt",
    ))
    .unwrap();
    let mut n = 0;
    for line in text.lines() {
        let code = line.split("dircode=0x").nth(1).unwrap().split_whitespace().next().unwrap();
        let code = u32::from_str_radix(code, 16).unwrap();
        let dir = line.split("dir=(").nth(1).unwrap().split(')').next().unwrap();
        let want: Vec<f64> = dir.split(", ").map(|v| v.parse().unwrap()).collect();
        let got = import::radiance::decode_dir(code);
        assert!((0..3).all(|k| (got[k] - want[k]).abs() <= 5e-7), "{line}: {got:?}");
        n += 1;
    }
    assert_eq!(n, 20);
}

#[test]
fn imported_maps_without_parameters_detect_in_world_space() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("caustic.phm");
    let m =
        import::import(&fixture("radiance/kdt/glass_sphere_caustic_10k.pm"), &Options::default()).unwrap();
    m.write(Output::Path(p.clone()), serde_json::json!({})).unwrap();
    let map = PhotonMap::open_path(&p).unwrap();
    use photonkit::detect::{Method, choose_method};
    let (method, note) = choose_method(&map.view(), None).unwrap();
    assert_eq!(method, Method::WorldPca);
    assert!(note.unwrap().contains("no trajectory parameters"));
    let e = choose_method(&map.view(), Some(Method::ParamPca)).unwrap_err().to_string();
    assert!(e.contains("param-pca needs trajectory parameters"), "{e}");
    // The PD map's emission directions are trajectory parameters: the paper's method applies.
    let p = dir.path().join("pd.phm");
    let m =
        import::import(&fixture("radiance/kdt_PD/glass_sphere_contrib_10k.pm"), &Options::default()).unwrap();
    m.write(Output::Path(p.clone()), serde_json::json!({})).unwrap();
    let map = PhotonMap::open_path(&p).unwrap();
    assert_eq!(choose_method(&map.view(), None).unwrap().0, Method::ParamPca);
}

#[test]
fn radiance_caustic_only_keeps_flagged_photons() {
    // Every photon of the fixture maps is flagged caustic (the only diffuse receiver is a flat
    // floor, so stored photons all arrive from the glass or the metal), so clear the flag (bit 2
    // of the last byte of a kd-tree record) of a few records and see exactly those go.
    let mut b = std::fs::read(fixture("radiance/kdt/glass_sphere_contrib_10k.pm")).unwrap();
    let n = 10713;
    let records = b.len() - n * 27;
    let cleared = [0usize, 1, 7, 500, n - 1];
    for &i in &cleared {
        b[records + i * 27 + 26] &= !0b100;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.pm");
    std::fs::write(&p, &b).unwrap();
    let all = import::import(&p, &Options::default()).unwrap();
    assert_eq!(all.len(), n);
    let caustic = all.column("caustic").unwrap();
    let unflagged: Vec<usize> = (0..n).filter(|&i| caustic[i] == 0).collect();
    assert_eq!(unflagged, cleared);
    let some = import::import(&p, &Options { caustic_only: true, ..Options::default() }).unwrap();
    assert_eq!(some.len(), n - cleared.len());
    let kept: Vec<f32> = f32s(all.column("position").unwrap())
        .chunks_exact(3)
        .enumerate()
        .filter(|(i, _)| !cleared.contains(i))
        .flat_map(|(_, p)| p.to_vec())
        .collect();
    assert_eq!(f32s(some.column("position").unwrap()), kept);
    assert!(some.column("caustic").unwrap().iter().all(|&c| c == 1));
    // The option means nothing to other formats: refused rather than ignored.
    let csv = dir.path().join("t.csv");
    std::fs::write(&csv, "x,y,z,flux_r,flux_g,flux_b\n0,0,0,1,1,1\n").unwrap();
    let e =
        import::import(&csv, &Options { caustic_only: true, ..Options::default() }).unwrap_err().to_string();
    assert!(e.contains("caustic"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Bad input

fn ply_header(format: &str, count: u64, props: &str) -> String {
    format!("ply\nformat {format} 1.0\nelement vertex {count}\n{props}end_header\n")
}

const XYZ_FLUX: &str = "property float x\nproperty float y\nproperty float z\nproperty float flux_r\n\
    property float flux_g\nproperty float flux_b\n";

#[test]
fn malformed_ply_headers_name_their_line() {
    let cases: &[(&str, &str)] = &[
        ("ply\nformat ascii 2.0\nend_header\n", "line 2"),
        ("ply\nformat xml 1.0\nend_header\n", "line 2"),
        ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "line 3"),
        ("ply\nformat ascii 1.0\nelement vertex many\nend_header\n", "line 3"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n", "line 4"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "without an 'end_header'"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "line 4"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "missing: y z"),
    ];
    for (text, want) in cases {
        let e = import_err("t.ply", text.as_bytes());
        assert!(e.contains("t.ply") && e.contains(want), "{text:?}: {e}");
    }
}

#[test]
fn property_types_that_do_not_fit_are_refused() {
    let h = ply_header("ascii", 1, &format!("{XYZ_FLUX}property float emitter\n"));
    let e = import_err("t.ply", format!("{h}0 0 0 1 1 1 0\n").as_bytes());
    assert!(e.contains("line 10") && e.contains("'emitter' is f32"), "{e}");
    let h = ply_header("ascii", 1, &format!("{XYZ_FLUX}property list uchar float bounces\n"));
    let e = import_err("t.ply", format!("{h}0 0 0 1 1 1 1 0\n").as_bytes());
    assert!(e.contains("line 10") && e.contains("list"), "{e}");
    // An integer column range-checks each value.
    let h = ply_header("binary_little_endian", 1, &format!("{XYZ_FLUX}property int bounces\n"));
    let mut b = h.into_bytes();
    let at = b.len() + 24;
    for v in [0f32; 6] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&(-1i32).to_le_bytes());
    let e = import_err("t.ply", &b);
    assert!(e.contains(&format!("byte {at}")) && e.contains("-1 does not fit in u8"), "{e}");
    let e = import_err("t.csv", b"x,y,z,flux_r,flux_g,flux_b,bounces\n0,0,0,1,1,1,300\n");
    assert!(e.contains("line 2") && e.contains("300"), "{e}");
}

#[test]
fn nan_and_inf_are_refused_where_they_are() {
    let h = ply_header("binary_big_endian", 2, XYZ_FLUX);
    let mut b = h.into_bytes();
    let at = b.len() + 24 + 8;
    for v in [0f32, 0., 0., 1., 1., 1., 0., 0., f32::NAN, 1., 1., 1.] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    let e = import_err("t.ply", &b);
    assert!(e.contains(&format!("byte {at}")) && e.contains("'z'") && e.contains("NaN"), "{e}");
    // The header takes 10 lines: the first vertex is on line 11.
    let e = import_err("t.ply", format!("{}0 0 0 1 inf 1\n", ply_header("ascii", 1, XYZ_FLUX)).as_bytes());
    assert!(e.contains("line 11") && e.contains("'flux_g'"), "{e}");
    let e = import_err("t.csv", b"x,y,z,flux_r,flux_g,flux_b\n0,0,0,1,1,1\n0,1e39,0,1,1,1\n");
    assert!(e.contains("line 3") && e.contains("'y'"), "{e}");
    let e = import_err("t.tsv", b"x\ty\tz\tflux_r\tflux_g\tflux_b\tw\n0\t0\t0\t1\t1\t1\tNaN\n");
    assert!(e.contains("line 2") && e.contains("'w'"), "{e}");
}

#[test]
fn counts_that_disagree_with_the_data_are_refused() {
    // A billion photons declared, ten held: refused at once, without a billion-photon buffer.
    let t = std::time::Instant::now();
    let mut b = ply_header("binary_little_endian", 1_000_000_000, XYZ_FLUX).into_bytes();
    let at = b.len();
    b.extend(std::iter::repeat_n(0u8, 10 * 24));
    let e = import_err("t.ply", &b);
    assert!(e.contains(&format!("byte {at}")) && e.contains("hold only 10"), "{e}");
    let mut a = ply_header("ascii", 1_000_000_000, XYZ_FLUX);
    (0..10).for_each(|_| a.push_str("0 0 0 1 1 1\n"));
    let e = import_err("t.ply", a.as_bytes());
    assert!(e.contains("1000000000") && e.contains("ends after 10"), "{e}");
    // Fewer declared than held in ASCII: a row with the wrong number of values.
    // (the header takes 10 lines, so the vertex is line 11)
    let e = import_err("t.ply", format!("{}0 0 0 1 1\n", ply_header("ascii", 1, XYZ_FLUX)).as_bytes());
    assert!(e.contains("line 11") && e.contains("found 5"), "{e}");
    // More held than declared: refused too, at the first byte or line past the declared data.
    let mut b = ply_header("binary_big_endian", 1, XYZ_FLUX).into_bytes();
    let at = b.len() + 24;
    b.extend(std::iter::repeat_n(0u8, 2 * 24));
    let e = import_err("t.ply", &b);
    assert!(e.contains(&format!("byte {at}")) && e.contains("24 bytes follow"), "{e}");
    let mut a = ply_header("ascii", 1, XYZ_FLUX);
    a.push_str("0 0 0 1 1 1\n0 0 0 1 1 1\n");
    let e = import_err("t.ply", a.as_bytes());
    assert!(e.contains("line 12") && e.contains("more than its header declares"), "{e}");
    assert!(t.elapsed().as_secs_f64() < 1.0, "refusing took {:?}", t.elapsed());
}

/// The Radiance fixture map's bytes with `edit` applied.
fn radiance_variant(edit: impl Fn(&mut Vec<u8>)) -> String {
    let mut b = std::fs::read(fixture("radiance/kdt/glass_sphere_caustic_10k.pm")).unwrap();
    edit(&mut b);
    import_err("m.pm", &b)
}

fn radiance_binary_start(b: &[u8]) -> usize {
    b.windows(2).position(|w| w == b"\n\n").unwrap() + 2
}

#[test]
fn bad_radiance_maps_are_refused_with_their_offset_or_variant() {
    // Truncated: the photon records end early.
    let e = radiance_variant(|b| b.truncate(b.len() - 30));
    assert!(e.contains("byte 388") && e.contains("11850 photons") && e.contains("hold only 11848"), "{e}");
    // A billion photons declared.
    let e = radiance_variant(|b| {
        let v = radiance_binary_start(b) + 5;
        b[v..v + 8].copy_from_slice(&1_000_000_000u64.to_be_bytes());
    });
    assert!(e.contains("1000000000 photons"), "{e}");
    // An unknown build variant (other record sizes): named.
    let e = radiance_variant(|b| {
        let v = radiance_binary_start(b);
        b[v + 3] = b'x';
    });
    assert!(e.contains("'3.1x'") && e.contains("not supported"), "{e}");
    // A volume photon map: named, and refused.
    let e = radiance_variant(|b| {
        let s = String::from_utf8_lossy(b).into_owned();
        let at = s.find("Radiance_Caustic_").unwrap();
        b[at..at + 17].copy_from_slice(b"Radiance_Volume__");
    });
    assert!(e.contains("volume photon map") && e.contains("not supported"), "{e}");
    // A version string that contradicts FORMAT (kd-tree format, out-of-core version).
    let e = radiance_variant(|b| {
        let s = String::from_utf8_lossy(b).into_owned();
        let v = s.find("VERSION=3.1k").unwrap() + 11;
        b[v] = b'o';
        let start = radiance_binary_start(b);
        b[start + 3] = b'o';
    });
    assert!(e.contains("'3.1o' contradicts FORMAT="), "{e}");
    // Not a photon map at all.
    let e = import_err("p.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n");
    assert!(e.contains("32-bit_rle_rgbe") && e.contains("not supported"), "{e}");
    // The out-of-core map needs its .leaf beside it; other record sizes are refused by name.
    let dir = tempfile::tempdir().unwrap();
    let pm = dir.path().join("o.pm");
    let mut ooc = std::fs::read(fixture("radiance/ooc/glass_sphere_caustic_10k.pm")).unwrap();
    std::fs::write(&pm, &ooc).unwrap();
    let e = import::import(&pm, &Options::default()).unwrap_err().to_string();
    assert!(e.contains("o.pm.leaf"), "{e}");
    let rs = radiance_binary_start(&ooc) + 5 + 8 + 65 + 4 + 20;
    assert_eq!(ooc[rs..rs + 4], 24u32.to_be_bytes());
    ooc[rs..rs + 4].copy_from_slice(&40u32.to_be_bytes());
    std::fs::write(&pm, &ooc).unwrap();
    let e = import::import(&pm, &Options::default()).unwrap_err().to_string();
    assert!(e.contains("records of 40 bytes") && e.contains("not supported"), "{e}");
    // A leaf file of the other byte order: its photons fall outside the octree, refused.
    ooc[rs..rs + 4].copy_from_slice(&24u32.to_be_bytes());
    std::fs::write(&pm, &ooc).unwrap();
    let mut leaf = std::fs::read(fixture("radiance/ooc/glass_sphere_caustic_10k.pm.leaf")).unwrap();
    for r in leaf.chunks_exact_mut(24) {
        r[..4].reverse();
    }
    std::fs::write(dir.path().join("o.pm.leaf"), &leaf).unwrap();
    let e = import::import(&pm, &Options::default()).unwrap_err().to_string();
    assert!(e.contains("outside its octree") && e.contains("not supported"), "{e}");
}

#[test]
fn the_command_line_fails_cleanly_and_leaves_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "x,y,z,flux_r,flux_g,flux_b\n0,0,0,1,1,1\n0,0,nan,1,1,1\n").unwrap();
    let out = dir.path().join("out.phm");
    let o = photonkit(&["import", bad.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("bad.csv: line 3"), "{}", stderr(&o));
    assert!(!out.exists());
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(leftovers.len(), 1, "{leftovers:?}");

    // And the good path: import a Radiance map, export it, import the export.
    let pm = fixture("radiance/kdt/metal_ring_caustic_10k.pm");
    let o = photonkit(&["import", pm.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("9827 photons"), "{}", stderr(&o));
    let o = photonkit(&["export", out.to_str().unwrap(), "--to", "ply"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ply = out.with_extension("ply");
    let back = import::import(Path::new(&ply), &Options::default()).unwrap();
    assert_eq!(back.len(), 9827);
    let o = photonkit(&["inspect", "--check", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}{}", stdout(&o), stderr(&o));
}

#[test]
fn exports_refuse_what_would_not_read_back_and_write_nothing() {
    use photonkit::format::{ColumnSpec, DType, MapInfo, State, write_map};
    let dir = tempfile::tempdir().unwrap();
    let write = |extra: (&str, DType, Vec<u8>)| {
        // One file per map: a file still mapped is an input, and no output may replace it.
        let p = dir.path().join(format!("{}.phm", extra.0));
        let pos: Vec<u8> = [0.5f32, 0.25, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let flux: Vec<u8> = [1f32, 1.0, 1.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let cols = [
            (ColumnSpec::new("position", DType::F32, 3), pos.as_slice()),
            (ColumnSpec::new("flux", DType::F32, 3), flux.as_slice()),
            (ColumnSpec::new(extra.0, extra.1, 1), extra.2.as_slice()),
        ];
        write_map(Output::Path(p.clone()), MapInfo::new(vec![], State::Traced), &cols).unwrap();
        PhotonMap::open_path(&p).unwrap()
    };
    let spaced = write(("my weight", DType::F32, 2f32.to_le_bytes().to_vec()));
    let red = write(("red", DType::U8, vec![7]));
    let big = write(("count", DType::U64, (1u64 << 60).to_le_bytes().to_vec()));
    for (map, to, want) in [
        (&spaced, ExportFormat::Ply, "'my weight' can not be named in PLY"),
        (&spaced, ExportFormat::Csv, "'my weight' can not be named in CSV"),
        (&red, ExportFormat::Ply, "display colours"),
        (&big, ExportFormat::Ply, "exceeds 2^53"),
    ] {
        let mut out = Vec::new();
        let e = export::write(map, to, &mut out, "t").unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
        assert!(out.is_empty(), "{want}: {} bytes written before the error", out.len());
        let target = dir.path().join("out");
        assert!(export::export(map, to, &Output::Path(target.clone())).is_err());
        assert!(!target.exists());
    }
    // The same map with a CSV-safe u64 goes out as CSV, and its PLY column name 'red' as CSV too.
    let mut out = Vec::new();
    export::write(&big, ExportFormat::Csv, &mut out, "t").unwrap();
    assert!(String::from_utf8(out).unwrap().ends_with(&format!(",{}\n", 1u64 << 60)));
}

/// Radiance's `putflt`: mantissa `(long)(frexp(f) * 0x7fffffff)` (truncated), then the exponent.
fn putflt(f: f64) -> [u8; 5] {
    if f == 0.0 {
        return [0; 5];
    }
    let e = ((f.to_bits() >> 52) & 0x7ff) as i32 - 1022;
    let m = (f / 2f64.powi(e) * 2147483647.0) as i32;
    let b = m.to_be_bytes();
    [b[0], b[1], b[2], b[3], e as i8 as u8]
}

#[test]
fn radiance_float_flux_variant_reads_like_rgbe() {
    // No mkpmap build with PMAP_FLOAT_FLUX was at hand: rewrite a real map into that variant
    // (version "3.1kf", flux as 3 portable floats, 38-byte records) and expect the same photons.
    let src = std::fs::read(fixture("radiance/kdt/glass_sphere_caustic_10k.pm")).unwrap();
    let rgbe =
        import::import(&fixture("radiance/kdt/glass_sphere_caustic_10k.pm"), &Options::default()).unwrap();
    let start = radiance_binary_start(&src);
    let header =
        String::from_utf8(src[..start].to_vec()).unwrap().replace("VERSION=3.1k\n", "VERSION=3.1kf\n");
    let n = rgbe.len();
    let records = src.len() - n * 27;
    let mut b = header.into_bytes();
    b.extend_from_slice(b"3.1kf\0");
    b.extend_from_slice(&src[start + 5..records]);
    let flux = f32s(rgbe.column("flux").unwrap());
    for (i, r) in src[records..].chunks_exact(27).enumerate() {
        b.extend_from_slice(&r[..18]);
        for k in 0..3 {
            b.extend_from_slice(&putflt(flux[i * 3 + k] as f64));
        }
        b.extend_from_slice(&r[22..]);
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("f.pm");
    std::fs::write(&p, &b).unwrap();
    let float = import::import(&p, &Options::default()).unwrap();
    for c in ["position", "normal", "flux", "caustic"] {
        assert!(float.column(c) == rgbe.column(c), "column {c}");
    }
}

/// Inputs that cannot be photon files are refused after a bounded read (issue 31: `import
/// --from ply /dev/zero` grew to 2.1 GB; a 200 MB comment line took 200 MB), and standard
/// input is read like a file.
#[test]
fn endless_or_absurd_inputs_are_refused_early_and_stdin_reads() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.phm");
    let os = out.to_str().unwrap();
    for from in ["ply", "csv", "radiance"] {
        let o = photonkit(&["import", "--from", from, "/dev/zero", "-o", os]);
        assert!(!o.status.success(), "{from}");
        assert!(stderr(&o).contains("MiB"), "{from}: {}", stderr(&o));
    }
    let long = dir.path().join("long.csv");
    let mut text = String::from("x,y,z,flux_r,flux_g,flux_b\n# ");
    text.push_str(&"c".repeat(3 << 20));
    text.push_str("\n0,0,0,1,1,1\n");
    std::fs::write(&long, text).unwrap();
    let o = photonkit(&["import", long.to_str().unwrap(), "-o", os]);
    assert!(stderr(&o).contains("line 2 is longer than 1 MiB"), "{}", stderr(&o));
    assert!(!out.exists());

    use std::io::Write;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_photonkit"))
        .args(["import", "--from", "csv", "-", "-o", os])
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(b"x,y,z,flux_r,flux_g,flux_b\n1,2,3,4,5,6\n").unwrap();
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(PhotonMap::open_path(&out).unwrap().len(), 1);
}

/// What MeshLab and hand-written tables contain is made valid or refused, so an import exit 0
/// always gives a map that passes `inspect --check` (issue 31): unnormalised normals are
/// normalised, zero normals and negative flux refused, sparse emitter ids renumbered.
#[test]
fn imports_pass_their_own_check_or_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.phm");
    let os = out.to_str().unwrap();
    let csv = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_string()
    };
    let ok = csv(
        "n.csv",
        "x,y,z,flux_r,flux_g,flux_b,nx,ny,nz,emitter\n0,0,0,1,1,1,0,0,2,65535\n1,0,0,1,1,1,0,3,4,7\n",
    );
    let o = photonkit(&["import", &ok, "-o", os]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("normalised") && stderr(&o).contains("renumbered"), "{}", stderr(&o));
    let check = photonkit(&["inspect", "--check", os]);
    assert!(check.status.success(), "{}{}", stdout(&check), stderr(&check));
    let map = PhotonMap::open_path(&out).unwrap();
    assert_eq!(map.meta().emitters.len(), 2, "two emitters, not 65 536");
    let normals = map.column::<[f32; 3]>("normal").unwrap().unwrap();
    assert_eq!(normals[1], [0.0, 0.6, 0.8]);
    std::fs::remove_file(&out).unwrap();
    for (name, text, want) in [
        ("neg.csv", "x,y,z,flux_r,flux_g,flux_b\n0,0,0,1,-1,1\n", "non-negative"),
        ("zero.csv", "x,y,z,flux_r,flux_g,flux_b,nx,ny,nz\n0,0,0,1,1,1,0,0,0\n", "no direction"),
    ] {
        let o = photonkit(&["import", &csv(name, text), "-o", os]);
        assert!(!o.status.success(), "{name}");
        assert!(stderr(&o).contains(want), "{name}: {}", stderr(&o));
        assert!(!out.exists());
    }
}

/// `export` refuses a non-finite value that `import` would refuse (issue 31: NaN positions
/// were written to CSV), and writes nothing.
#[test]
fn export_refuses_what_import_refuses() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.phm");
    super::common::write_synthetic(&photonkit::synthetic::uniform_square(10, 1, 1.0), "t", &p);
    let offset = PhotonMap::open_path(&p).unwrap().meta().column("position").unwrap().offset as usize;
    let mut bytes = std::fs::read(&p).unwrap();
    bytes[offset + 12 * 3..offset + 12 * 3 + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&p, super::common::with_fixed_checksums(&bytes)).unwrap();
    let out = dir.path().join("nan.csv");
    let o = photonkit(&["export", p.to_str().unwrap(), "--to", "csv", "-o", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("photon 3") && stderr(&o).contains("position"), "{}", stderr(&o));
    assert!(!out.exists());
}

/// Issue 23: a spectral map's wavelength leaves as a `wavelength` field (PLY property, CSV
/// column) and comes back as the last trajectory parameter of a spectral parameterisation,
/// the parameters bit for bit.
#[test]
fn a_wavelength_round_trips_through_ply_and_csv() {
    let dir = tempfile::tempdir().unwrap();
    let traced = dir.path().join("prism.phm");
    let scene = root().join("samples/scenes/prism.toml");
    let o =
        photonkit(&["trace", scene.to_str().unwrap(), "--photons", "5000", "-o", traced.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = PhotonMap::open_path(&traced).unwrap();
    let want: &[u8] = m.column_bytes("params").unwrap();
    for to in ["ply", "csv"] {
        let text = dir.path().join(format!("prism.{to}"));
        let back = dir.path().join(format!("back-{to}.phm"));
        let o = photonkit(&["export", "--to", to, traced.to_str().unwrap(), "-o", text.to_str().unwrap()]);
        assert!(o.status.success(), "{}", stderr(&o));
        let o = photonkit(&["import", text.to_str().unwrap(), "-o", back.to_str().unwrap()]);
        assert!(o.status.success(), "{to}: {}", stderr(&o));
        let b = PhotonMap::open_path(&back).unwrap();
        let e = &b.meta().emitters[0];
        assert_eq!((e.parameterisation, e.param_dims), (Parameterisation::RectUvSpectral, 3), "{to}");
        assert_eq!(b.column_bytes("params").unwrap(), want, "{to}: params");
    }
}
