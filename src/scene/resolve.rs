//! Which scene a photon map was traced from: the one place every stage that needs the scene
//! (render, relax on curved receivers, the reference) finds it.

use std::path::{Path, PathBuf};

use super::{DEFAULT_SCENE_NAME, Scene, SceneError, SceneFile};
use crate::format::MapView;

/// The CRC-32 of a scene file's content ([`SceneFile::content`]: a TOML file's text) as the
/// trace record's `scene_crc32` holds it (8 hex digits): how later stages tell whether a scene
/// file is the one the map was traced from.
pub fn scene_crc32(content: impl AsRef<[u8]>) -> String {
    format!("{:08x}", crc32fast::hash(content.as_ref()))
}

/// A scene found for a map, and what the user should be told about how it was found.
#[derive(Debug)]
pub struct ResolvedScene {
    /// The scene, built.
    pub scene: Scene,
    /// The scene file's path as found, or the embedded default's name.
    pub name: String,
    /// Whether the map's trace record names this scene (or it was given): `false` when the
    /// embedded default stands in for a map that names none.
    pub recorded: bool,
    /// Notes for the user (the scene file changed since the trace, or none was named).
    pub notes: Vec<String>,
    /// What the scene file holds and the tracer does not honour ([`SceneFile::unsupported`]).
    pub unsupported: Vec<String>,
    /// What the scene was read from ([`SceneFile::content`]).
    pub content: Vec<u8>,
}

/// The scene of `map`: `given` if set; else the file its trace record names, as recorded
/// (relative to the trace's working directory), where the trace recorded it relative to the
/// map's folder, or beside the map; the embedded default scene when the record names it or
/// names none (with a note). A named file that is found nowhere is an error; one whose text
/// changed since the trace (its CRC-32 differs) is used with a note.
pub fn for_map(map: Option<&MapView>, given: Option<&Path>) -> Result<ResolvedScene, SceneError> {
    let resolved = |f: SceneFile, recorded, mut notes: Vec<String>| {
        notes.extend(f.notes);
        ResolvedScene {
            scene: f.scene,
            name: f.name,
            recorded,
            notes,
            unsupported: f.unsupported,
            content: f.content,
        }
    };
    if let Some(p) = given {
        return Ok(resolved(SceneFile::read(p)?, true, Vec::new()));
    }
    let record = map.and_then(|m| m.info().trace_record());
    let Some((map, record)) = map.zip(record) else {
        let notes = map
            .map(|m| {
                format!(
                    "{} does not name the scene it was traced from: using the embedded default scene",
                    m.file_name()
                )
            })
            .into_iter()
            .collect();
        return Ok(resolved(SceneFile::default_scene(), false, notes));
    };
    let path = record.parameters.scene.as_str();
    if path == DEFAULT_SCENE_NAME {
        return Ok(resolved(SceneFile::default_scene(), true, Vec::new()));
    }
    let map_dir = crate::format::folder_of(Path::new(map.file_name()));
    let from_map = record.report.scene_from_map.as_ref().map(|rel| map_dir.join(rel));
    let found = std::iter::once(PathBuf::from(path))
        .chain(from_map)
        .chain(std::iter::once(map_dir.join(path)))
        .find(|p| p.is_file())
        .ok_or_else(|| SceneError::NotFound { map: map.file_name().to_string(), scene: path.to_string() })?;
    let file = SceneFile::read(&found)?;
    let crc = file.crc32();
    let mut notes = Vec::new();
    let recorded = &record.parameters.scene_crc32;
    if !recorded.is_empty() && *recorded != crc {
        notes.push(format!(
            "{} has changed since the map was traced (CRC-32 {crc}, recorded {recorded})",
            found.display()
        ));
    }
    Ok(resolved(file, true, notes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{MapInfo, PhotonTable, State, TraceParameters, TraceRecord, TraceReport};

    /// A map (in memory, named as if at `file`) whose trace record names `scene`.
    fn map_naming(file: &str, scene: &str, crc: &str, from_map: Option<&str>) -> PhotonTable<'static> {
        let mut info = MapInfo::new(vec![], State::Traced);
        let parameters =
            TraceParameters { scene: scene.into(), scene_crc32: crc.into(), ..TraceParameters::default() };
        let report = TraceReport { scene_from_map: from_map.map(String::from), ..TraceReport::default() };
        info.history.push(TraceRecord { parameters, report }.to_stage_record());
        PhotonTable::new(file, info, &[[0.0; 3]], &[[1.0; 3]]).unwrap()
    }

    #[test]
    fn a_map_finds_the_scene_its_trace_record_names() {
        let dir = tempfile::tempdir().unwrap();
        let scene_path = dir.path().join("s.toml");
        std::fs::write(&scene_path, super::super::DEFAULT_SCENE).unwrap();
        let crc = scene_crc32(super::super::DEFAULT_SCENE);
        std::fs::create_dir(dir.path().join("maps")).unwrap();
        let map_file = dir.path().join("maps/m.phm");
        let map_file = map_file.to_str().unwrap();
        // Named by a path that resolves as recorded: found, no note.
        let m = map_naming(map_file, scene_path.to_str().unwrap(), &crc, None);
        let r = for_map(Some(&m.view()), None).unwrap();
        assert!(r.recorded && r.notes.is_empty() && r.name == scene_path.display().to_string());
        // Named relative to another working directory, but recorded relative to the map.
        let m = map_naming(map_file, "elsewhere/s.toml", &crc, Some("../s.toml"));
        assert!(for_map(Some(&m.view()), None).unwrap().recorded);
        // Changed since the trace: used, with a note.
        let m = map_naming(map_file, scene_path.to_str().unwrap(), "00000000", None);
        let r = for_map(Some(&m.view()), None).unwrap();
        assert!(r.recorded && r.notes[0].contains("has changed"), "{:?}", r.notes);
        // Found nowhere: an error naming the map and the scene.
        let m = map_naming(map_file, "gone.toml", &crc, None);
        let e = for_map(Some(&m.view()), None).unwrap_err().to_string();
        assert!(e.contains("m.phm") && e.contains("gone.toml") && e.contains("--scene"), "{e}");
        // The embedded default, named or standing in (with a note) for a map naming none.
        let m = map_naming(map_file, DEFAULT_SCENE_NAME, "", None);
        assert!(for_map(Some(&m.view()), None).unwrap().recorded);
        let bare =
            PhotonTable::new("b.phm", MapInfo::new(vec![], State::Traced), &[[0.0; 3]], &[[1.0; 3]]).unwrap();
        let r = for_map(Some(&bare.view()), None).unwrap();
        assert!(!r.recorded && r.name == DEFAULT_SCENE_NAME && r.notes[0].contains("b.phm"));
        // Given: used whatever the map says.
        let r = for_map(Some(&m.view()), Some(&scene_path)).unwrap();
        assert_eq!(r.name, scene_path.display().to_string());
    }
}
