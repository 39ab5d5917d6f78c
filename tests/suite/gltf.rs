//! glTF 2.0 scenes: each sample traces to the same photons as its TOML twin, a glTF-traced map
//! renders, what is not honoured is listed in one warning, and malformed or hostile files are
//! refused with an error naming the element, no panic and no output file.

use std::path::{Path, PathBuf};
use std::process::Command;

use base64::Engine;
use photonkit::format::PhotonMap;
use serde_json::{Value, json};

use super::common::{photonkit, root, stderr, stdout};

fn trace(scene: &Path, out: &Path, photons: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_photonkit"))
        .args(["--quiet", "trace"])
        .arg(scene)
        .args(["--photons", photons, "--seed", "7", "-o"])
        .arg(out)
        .env("SOURCE_DATE_EPOCH", "1700000000")
        .output()
        .unwrap()
}

/// Each glTF sample and its TOML twin (tools/gltf-samples.py) give the same photons: the same
/// count, every column byte for byte, and the same emitter records (compared as values). The
/// files' headers differ only in the trace record's scene path and CRC-32, which name the
/// scene file each was traced from.
#[test]
fn gltf_samples_trace_to_the_same_photons_as_their_toml_twins() {
    let dir = tempfile::tempdir().unwrap();
    let samples = root().join("samples/scenes/gltf");
    for (file, twin) in [
        ("glass-sphere.gltf", "glass-sphere.toml"),
        ("cognac.glb", "cognac.toml"),
        ("reflector.gltf", "reflector.toml"),
    ] {
        let (a, b) = (dir.path().join(format!("{file}.phm")), dir.path().join(format!("{twin}.phm")));
        let o = trace(&samples.join(file), &a, "40000");
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        let o = trace(&samples.join("twins").join(twin), &b, "40000");
        assert!(o.status.success(), "{twin}: {}", stderr(&o));
        let (ma, mb) = (PhotonMap::open_path(&a).unwrap(), PhotonMap::open_path(&b).unwrap());
        assert!(ma.len() > 1000, "{file}: only {} photons stored", ma.len());
        assert_eq!(ma.len(), mb.len(), "{file}: photon counts");
        let (ca, cb) = (ma.columns(), mb.columns());
        assert_eq!(ca.len(), cb.len(), "{file}: columns");
        for ((sa, da), (sb, db)) in ca.iter().zip(&cb) {
            assert_eq!(sa, sb, "{file}: column layout");
            assert!(da == db, "{file}: column {} differs from the twin's", sa.name);
        }
        assert_eq!(ma.info().emitters, mb.info().emitters, "{file}: emitter records");
    }
}

/// A map traced from a glTF file names it in its history, and `render` finds it there and
/// renders through its camera; `--dry-run` describes the scene and writes nothing.
#[test]
fn a_gltf_traced_map_renders_and_dry_run_describes_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("cognac.phm");
    let o = trace(&root().join("samples/scenes/gltf/cognac.glb"), &map, "20000");
    assert!(o.status.success(), "{}", stderr(&o));
    let img = dir.path().join("cognac.exr");
    let o = photonkit(&[
        "--quiet",
        "render",
        map.to_str().unwrap(),
        "-o",
        img.to_str().unwrap(),
        "--width",
        "48",
        "--height",
        "48",
        "--spp",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(img.is_file() && img.with_extension("png").is_file());

    let scene = root().join("samples/scenes/gltf/glass-sphere.gltf");
    let o = photonkit(&["trace", scene.to_str().unwrap(), "--dry-run"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    for want in [
        "[1] ball: mesh of",
        "smooth",
        "glass: dielectric, ior 1.5",
        "[0] sun: collimated",
        "2 parameters",
        "camera: pinhole",
    ] {
        assert!(s.contains(want), "missing '{want}' in:\n{s}");
    }
    assert!(stderr(&o).contains("beam 1 × 1 m from extras.photonkit_beam_size"), "{}", stderr(&o));
}

/// A small valid scene: a floor quad and a glass tetrahedron lit by a point light, its one
/// buffer in a data: URI. Tests break it one way at a time.
fn scene_json() -> (Value, Vec<u8>) {
    let pos: [[f32; 3]; 8] = [
        [-1.0, -1.0, 0.0],
        [1.0, -1.0, 0.0],
        [1.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
        [0.0, 0.0, 0.5],
        [0.3, 0.0, 0.2],
        [-0.2, 0.3, 0.2],
        [-0.2, -0.3, 0.2],
    ];
    let idx: [u16; 18] = [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7, 4, 7, 5, 5, 7, 6];
    let mut bin: Vec<u8> = bytemuck::cast_slice(&pos).to_vec();
    bin.extend_from_slice(bytemuck::cast_slice(&idx));
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"name": "floor", "mesh": 0},
            {"name": "gem", "mesh": 1},
            {"name": "bulb", "translation": [0.0, 0.0, 2.0], "extensions": {"KHR_lights_punctual": {"light": 0}}}
        ],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2, "material": 1}]}
        ],
        "materials": [
            {"name": "floor", "pbrMetallicRoughness": {"metallicFactor": 0.0}},
            {"name": "glass", "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.0},
             "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}}}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3",
             "min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 0.5]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": 1, "byteOffset": 12, "componentType": 5123, "count": 12, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 96},
            {"buffer": 0, "byteOffset": 96, "byteLength": 36}
        ],
        "buffers": [{"byteLength": bin.len()}],
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_transmission"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 100.0}]}}
    });
    (doc, bin)
}

/// Writes `doc` with `bin` as its first buffer's data: URI (unless the test set a uri).
fn write(dir: &Path, name: &str, mut doc: Value, bin: &[u8]) -> PathBuf {
    if doc.is_object() && doc["buffers"][0].get("uri").is_none() {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(bin)
        );
        doc["buffers"][0]["uri"] = json!(uri);
    }
    let p = dir.join(name);
    std::fs::write(&p, serde_json::to_vec_pretty(&doc).unwrap()).unwrap();
    p
}

#[test]
fn the_small_scene_traces_and_lists_what_is_not_honoured_in_one_warning() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = scene_json();
    let out = dir.path().join("ok.phm");
    let p = write(dir.path(), "ok.gltf", doc.clone(), &bin);
    let o = trace(&p, &out, "5000");
    assert!(o.status.success() && out.is_file(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));

    doc["materials"][0]["emissiveFactor"] = json!([1.0, 1.0, 1.0]);
    doc["materials"][1]["pbrMetallicRoughness"]["roughnessFactor"] = json!(0.5);
    doc["materials"][1]["extensions"]["KHR_materials_clearcoat"] = json!({"clearcoatFactor": 1.0});
    doc["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_materials_clearcoat"));
    doc["nodes"][1]["scale"] = json!([1.0, 1.0, 1.0]);
    let p = write(dir.path(), "warn.gltf", doc, &bin);
    let o = trace(&p, &dir.path().join("warn.phm"), "5000");
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert_eq!(e.matches("warning").count(), 1, "{e}");
    for want in [
        "emissiveFactor",
        "rough transmission",
        "KHR_materials_clearcoat",
        "extension KHR_materials_clearcoat",
    ] {
        assert!(e.contains(want), "missing '{want}' in: {e}");
    }
}

/// A directional light without a beam size covers the mirrors and glass it can reach, from
/// upstream of the whole scene, and says so.
#[test]
fn a_directional_light_without_a_beam_size_covers_the_glass() {
    let dir = tempfile::tempdir().unwrap();
    let (mut doc, bin) = scene_json();
    doc["extensions"]["KHR_lights_punctual"]["lights"][0] =
        json!({"type": "directional", "intensity": 683.0});
    let p = write(dir.path(), "sun.gltf", doc, &bin);
    let o = photonkit(&["trace", p.to_str().unwrap(), "--dry-run"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("the bounding box of the mirrors and glass"), "{}", stderr(&o));
    // The gem spans 0.5 × 0.6 m across the beam: 683 lx on 0.3 m² is 0.3 W.
    assert!(
        stdout(&o).contains("0.5000 × 0.6000 m rectangle") && stdout(&o).contains("0.300000 W"),
        "{}",
        stdout(&o)
    );
}

/// Each broken file: refused with an error that names the element, no panic, no output.
#[test]
fn malformed_and_hostile_gltf_files_are_refused_naming_the_element() {
    let dir = tempfile::tempdir().unwrap();
    let (doc, bin) = scene_json();
    type Break = fn(&mut Value, &mut Vec<u8>);
    let cases: Vec<(&str, Break, &[&str])> = vec![
        (
            "missing-buffer",
            |d, _| d["buffers"][0]["uri"] = json!("missing.bin"),
            &["buffers[0]", "missing.bin"],
        ),
        ("short-buffer", |_, b| b.truncate(100), &["buffers[0]", "byteLength"]),
        (
            "accessor-past-view",
            |d, _| d["accessors"][2]["count"] = json!(30),
            &["accessors[2]", "bufferView"],
        ),
        ("huge-count", |d, _| d["accessors"][0]["count"] = json!(1u64 << 40), &["accessors[0]", "count"]),
        (
            "view-past-buffer",
            |d, _| d["bufferViews"][1]["byteLength"] = json!(1_000_000),
            &["bufferViews[1]", "outside buffers[0]"],
        ),
        (
            "huge-buffer",
            |d, _| d["buffers"][0]["byteLength"] = json!(1u64 << 40),
            &["buffers[0]", "byteLength"],
        ),
        ("index-past-vertices", |_, b| b[96] = 200, &["meshes[0].primitives[0]", "index 200"]),
        (
            "cyclic-nodes",
            |d, _| {
                d["nodes"][0]["children"] = json!([1]);
                d["nodes"][1]["children"] = json!([0]);
            },
            &["nodes[0] 'floor'", "cycle"],
        ),
        (
            "position-accessor-missing",
            |d, _| d["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99),
            &["meshes[0].primitives[0].attributes.POSITION", "accessor 99 does not exist"],
        ),
        ("missing-node", |d, _| d["scenes"][0]["nodes"] = json!([0, 9]), &["document", "scenes[0].nodes[1]"]),
        ("not-json", |d, _| *d = json!("not a glTF"), &["document"]),
        ("no-light", |d, _| d["nodes"][2] = json!({"name": "bulb"}), &["lights", "no light"]),
        (
            "bad-quaternion",
            |d, _| d["nodes"][1]["rotation"] = json!([0.0, 0.0, 0.0, 0.0]),
            &["nodes[1] 'gem'", "quaternion"],
        ),
        (
            "required-extension",
            |d, _| d["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]),
            &["extensionsRequired"],
        ),
    ];
    for (name, break_it, want) in cases {
        let (mut d, mut b) = (doc.clone(), bin.clone());
        break_it(&mut d, &mut b);
        let p = write(dir.path(), &format!("{name}.gltf"), d, &b);
        let out = dir.path().join(format!("{name}.phm"));
        let o = trace(&p, &out, "1000");
        let e = stderr(&o);
        assert!(!o.status.success(), "{name}: accepted");
        assert!(!e.contains("panicked"), "{name}: {e}");
        assert!(!out.exists(), "{name}: wrote {}", out.display());
        for w in want {
            assert!(e.contains(w), "{name}: '{w}' not in: {e}");
        }
    }
    // A truncated binary glTF.
    let glb = root().join("samples/scenes/gltf/cognac.glb");
    let bytes = std::fs::read(glb).unwrap();
    let p = dir.path().join("cut.glb");
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let out = dir.path().join("cut.phm");
    let o = trace(&p, &out, "1000");
    let e = stderr(&o);
    assert!(!o.status.success() && !e.contains("panicked") && !out.exists(), "{e}");
    assert!(e.contains("cut.glb: document"), "{e}");
}

/// Every glTF input the fuzzer (fuzz/, target gltf) crashed on is refused or read, never a panic.
#[test]
fn gltf_fuzz_regressions_do_not_panic() {
    let dir = root().join("tests/fuzz-regressions");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "gltf") {
            let bytes = std::fs::read(&path).unwrap();
            if let Ok(g) = photonkit::scene::gltf::parse(&bytes, "fuzz.gltf", &dir) {
                let _ = g.description.build();
            }
            seen += 1;
        }
    }
    assert!(seen > 0, "no glTF regression inputs in {}", dir.display());
}
