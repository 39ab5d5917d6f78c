//! Feeds arbitrary bytes to the glTF 2.0 scene reader (JSON `.gltf` or binary `.glb`, buffers as
//! data URIs, the GLB chunk, or `glass-sphere.bin` beside it) and builds what it reads: a scene
//! or an error naming the element, never a panic or an allocation the input's bytes do not back.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // A folder with one buffer file the sample `glass-sphere.gltf` refers to, so external
    // buffers are reached as well as embedded ones.
    let dir = std::env::temp_dir().join(format!("photonkit-fuzz-gltf-{}", std::process::id()));
    if !dir.join("glass-sphere.bin").is_file() {
        let _ = std::fs::create_dir_all(&dir);
        let bin = concat!(env!("CARGO_MANIFEST_DIR"), "/../samples/scenes/gltf/glass-sphere.bin");
        let _ = std::fs::copy(bin, dir.join("glass-sphere.bin"));
    }
    if let Ok(g) = photonkit::scene::gltf::parse(data, "fuzz.gltf", &dir) {
        let _ = g.description.build();
    }
});
