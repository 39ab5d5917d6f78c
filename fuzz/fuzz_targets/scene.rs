//! Feeds arbitrary text to the scene parser (TOML, with OBJ meshes written beside it when the
//! input asks for one): a scene or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use photonkit::scene::Scene;

fuzz_target!(|data: &[u8]| {
    // The first byte chooses: TOML scene text, or OBJ text loaded as a mesh.
    let Some((&kind, rest)) = data.split_first() else { return };
    if kind % 2 == 0 {
        if let Ok(text) = std::str::from_utf8(rest) {
            let _ = Scene::parse(text, "fuzz.toml", std::path::Path::new("/nonexistent"));
        }
    } else {
        let dir = std::env::temp_dir().join(format!("photonkit-fuzz-{}", std::process::id()));
        let _ = std::fs::create_dir_all(&dir);
        let path = dir.join("mesh.obj");
        if std::fs::write(&path, rest).is_ok() {
            let _ = photonkit::scene::mesh::load_obj(&path);
        }
    }
});
