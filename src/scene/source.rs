//! Reading a scene file of either kind: TOML (docs/scene.md) or glTF 2.0 (`.gltf`, `.glb`),
//! chosen by the file's extension, with what the user should be told about it.

use std::path::Path;

use super::{DEFAULT_SCENE, DEFAULT_SCENE_NAME, Scene, SceneError, scene_crc32};

/// A scene file as read: the scene, its name in records and messages, the bytes it was read
/// from (which the trace record's CRC-32 covers) and what the user should be told.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// The scene, built.
    pub scene: Scene,
    /// The file's path as given, or the embedded default's name.
    pub name: String,
    /// What the scene was read from: a TOML file's text; a glTF file's bytes followed by those
    /// of each buffer file it names, in order.
    pub content: Vec<u8>,
    /// How the reader filled what the file leaves open (a glTF directional light's beam).
    pub notes: Vec<String>,
    /// What the file holds and the tracer does not honour, one element each (glTF only).
    pub unsupported: Vec<String>,
}

impl SceneFile {
    /// Reads the scene file at `path`: glTF when it ends in `.gltf` or `.glb`, else TOML.
    /// Relative paths inside it (OBJ meshes, buffer files) are resolved beside it.
    pub fn read(path: &Path) -> Result<SceneFile, SceneError> {
        let name = path.display().to_string();
        crate::format::guard::register_input(path);
        let io = |source| SceneError::Io { file: name.clone(), source };
        let dir = crate::format::folder_of(path);
        if super::gltf::is_gltf_path(path) {
            let len = std::fs::metadata(path).map_err(io)?.len();
            if len > super::gltf::MAX_FILE_BYTES {
                return Err(SceneError::Gltf {
                    file: name,
                    element: "file".into(),
                    message: format!("{len} bytes is over the {} read", super::gltf::MAX_FILE_BYTES),
                });
            }
            let mut content = std::fs::read(path).map_err(io)?;
            let g = super::gltf::parse(&content, &name, dir)?;
            g.buffer_files.iter().for_each(|b| content.extend_from_slice(b));
            let scene = g.description.build();
            return Ok(SceneFile { scene, name, content, notes: g.notes, unsupported: g.unsupported });
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        let scene = Scene::parse(&text, &name, dir)?;
        Ok(SceneFile { scene, name, content: text.into_bytes(), notes: Vec::new(), unsupported: Vec::new() })
    }

    /// The embedded default scene (`samples/scenes/glass-sphere.toml`).
    pub fn default_scene() -> SceneFile {
        SceneFile {
            scene: Scene::default_scene(),
            name: DEFAULT_SCENE_NAME.to_string(),
            content: DEFAULT_SCENE.as_bytes().to_vec(),
            notes: Vec::new(),
            unsupported: Vec::new(),
        }
    }

    /// [`SceneFile::read`] of `path`, or the embedded default without one.
    pub fn read_or_default(path: Option<&Path>) -> Result<SceneFile, SceneError> {
        path.map_or_else(|| Ok(SceneFile::default_scene()), SceneFile::read)
    }

    /// The CRC-32 of [`SceneFile::content`] as trace records hold it.
    pub fn crc32(&self) -> String {
        scene_crc32(&self.content)
    }

    /// The one warning listing everything unsupported, if anything is.
    pub fn warning(&self) -> Option<String> {
        unsupported_warning(&self.name, &self.unsupported)
    }
}

/// The one warning that lists what a scene file holds and the tracer does not honour.
pub fn unsupported_warning(name: &str, unsupported: &[String]) -> Option<String> {
    (!unsupported.is_empty()).then(|| {
        format!(
            "{name}: {} thing{} in the file {} not honoured:\n  - {}",
            unsupported.len(),
            if unsupported.len() == 1 { "" } else { "s" },
            if unsupported.len() == 1 { "is" } else { "are" },
            unsupported.join("\n  - ")
        )
    })
}
