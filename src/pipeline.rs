//! The paper's Algorithm 1 after the trace, in memory: detect → relax in world + parameter
//! space → collapse → relax in world space.
//!
//! Each stage reads the previous one's [`PhotonTable`] through its view and returns its own,
//! which borrows every column it passes on unchanged, so the chain copies only what a stage
//! computes. After each stage the caller's `on_stage` sees the new map: `photonkit pipeline`
//! and `compare` write it to a file there, a library user may keep it or ignore it. The same
//! function runs the 2009 relaxation (gradient constraints, no parameter-space phase).

use std::time::Instant;

use crate::detect::{self, DetectError, DetectParams, Method};
use crate::format::{FormatError, MapView, PhotonTable};
use crate::relax::{self, IterationMeasure, RelaxError, RelaxParams};
use crate::scene::Scene;

/// A stage of [`run`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Feature detection: each photon's constraint basis (Eq. 1–7).
    Detect,
    /// Relaxation before the collapse (in world + parameter space when the map has
    /// trajectory parameters).
    RelaxParams,
    /// The trajectory parameters dropped: the map back to world space.
    Collapse,
    /// Relaxation after the collapse, in world space.
    RelaxWorld,
}

impl Stage {
    /// How the stage table of `photonkit pipeline` names it.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Detect => "detect",
            Stage::RelaxParams => "relax (params)",
            Stage::Collapse => "collapse",
            Stage::RelaxWorld => "relax (world)",
        }
    }
}

/// The settings of [`run`] (the paper's: param-pca where the map has trajectory parameters,
/// Kc = 50, β = 3, Kf = 16, 7 + 7 iterations).
#[derive(Clone, Debug)]
pub struct PipelineParams {
    /// Feature detection's settings.
    pub detect: DetectParams,
    /// The detection method; `None` chooses ([`detect::choose_method`]), overriding
    /// `detect.method`.
    pub method: Option<Method>,
    /// Kf and the rest of relaxation's settings; its `iterations` are ignored for
    /// `iterations` below.
    pub relax: RelaxParams,
    /// Relaxation iterations before and after the collapse; a phase of 0 iterations is
    /// skipped (the 2009 relaxation: [0, R]).
    pub iterations: [usize; 2],
}

impl Default for PipelineParams {
    fn default() -> Self {
        let relax = RelaxParams::default();
        PipelineParams {
            detect: DetectParams::default(),
            method: None,
            iterations: [relax.iterations, relax.iterations],
            relax,
        }
    }
}

/// What a stage did, for the caller's table.
#[derive(Clone, Debug)]
pub struct StageDone {
    /// The stage.
    pub stage: Stage,
    /// Wall-clock time of the stage, seconds.
    pub seconds: f64,
    /// Photons in the stage's map.
    pub photons: usize,
    /// A short description of the result (method and constrained share, the spread of
    /// nearest-neighbour distances before and after), empty for the collapse.
    pub summary: String,
}

/// What [`run`] made: the relaxed map, and the detection method it chose.
#[derive(Debug)]
pub struct Outcome {
    /// The map after the last stage run.
    pub map: PhotonTable<'static>,
    /// The detection method used.
    pub method: Method,
}

/// What [`run`] reports as it goes.
#[derive(Debug)]
pub enum Progress<'a> {
    /// A stage has begun.
    Started(Stage),
    /// A relaxation iteration finished (0-based).
    Iteration(Stage, &'a IterationMeasure),
    /// A note for the user (e.g. that the map has no trajectory parameters).
    Note(&'a str),
}

/// Everything that can go wrong in [`run`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// Feature detection failed.
    #[error(transparent)]
    Detect(#[from] DetectError),
    /// Relaxation or the collapse failed.
    #[error(transparent)]
    Relax(#[from] RelaxError),
    /// A map could not be read or built.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The caller's `on_stage` failed (e.g. writing the stage's map).
    #[error("{0}")]
    Caller(String),
}

/// Runs detect → relax → collapse → relax on `traced` (a traced or imported map); with a
/// scene, relaxed photons are returned to their surfaces ([`relax::relax_map_on`]).
/// `on_stage` receives each stage's map as soon as it is made.
///
/// ```
/// use photonkit::format::{Output, PhotonMap, PhotonTable};
/// use photonkit::pipeline::{self, PipelineParams, StageDone};
///
/// // 2 000 photons of a cusp caustic, with their (u, v) on a collimated emitter.
/// let cusp = photonkit::synthetic::collimated_cusp(2_000, 7);
/// let info = cusp.info("collimated_cusp", 7, "2026-01-01T00:00:00Z");
/// let traced = PhotonTable::from_columns("cusp", info, &cusp.columns())?;
/// let dir = tempfile::tempdir()?;
/// // Keep the detected map as a file; let the others pass.
/// let mut on_stage = |done: &StageDone, map: &PhotonTable| {
///     if done.stage == pipeline::Stage::Detect {
///         map.write(Output::Path(dir.path().join("detected.phm")))?;
///     }
///     Ok(())
/// };
/// let out = pipeline::run(&traced.view(), None, &PipelineParams::default(), &mut on_stage, &|_| {})?;
/// assert_eq!(out.map.len(), 2_000);
/// assert_eq!(out.method.name(), "param-pca");
/// assert_eq!(PhotonMap::open_path(&dir.path().join("detected.phm"))?.len(), 2_000);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn run(
    traced: &MapView,
    scene: Option<&Scene>,
    p: &PipelineParams,
    on_stage: &mut dyn FnMut(&StageDone, &PhotonTable) -> Result<(), PipelineError>,
    progress: &dyn Fn(Progress),
) -> Result<Outcome, PipelineError> {
    let (method, note) = detect::choose_method(traced, p.method)?;
    if let Some(note) = note {
        progress(Progress::Note(&note));
    }
    let dp = DetectParams { method, ..p.detect };
    progress(Progress::Started(Stage::Detect));
    let t = Instant::now();
    let d = detect::detect_map(traced, &dp, &|_| {})?;
    let seconds = t.elapsed().as_secs_f64();
    let summary = format!("{}, {:.1} % constrained", method.name(), 100.0 * d.summary.constrained_fraction());
    let detected = detect::detected_map(traced, d, &dp, seconds)?;
    on_stage(&StageDone { stage: Stage::Detect, seconds, photons: traced.len(), summary }, &detected)?;

    let [before, after] = p.iterations;
    let relaxed_params = match before {
        0 => None,
        n => {
            let (table, done) = relax_stage(&detected.view(), scene, p, Stage::RelaxParams, n, progress)?;
            on_stage(&done, &table)?;
            Some(table)
        }
    };
    let collapse_input = relaxed_params.as_ref().map_or_else(|| detected.view(), |t| t.view());
    progress(Progress::Started(Stage::Collapse));
    let t = Instant::now();
    let collapsed = relax::collapse(&collapse_input)?;
    let done = StageDone {
        stage: Stage::Collapse,
        seconds: t.elapsed().as_secs_f64(),
        photons: collapsed.len(),
        summary: String::new(),
    };
    on_stage(&done, &collapsed)?;
    if after == 0 {
        return Ok(Outcome { map: collapsed.into_owned(), method });
    }
    let (relaxed, done) = relax_stage(&collapsed.view(), scene, p, Stage::RelaxWorld, after, progress)?;
    on_stage(&done, &relaxed)?;
    Ok(Outcome { map: relaxed.into_owned(), method })
}

/// One relaxation phase of [`run`]: the relaxed map and what the phase did.
fn relax_stage<'a>(
    input: &MapView<'a>,
    scene: Option<&Scene>,
    p: &PipelineParams,
    stage: Stage,
    iterations: usize,
    progress: &dyn Fn(Progress),
) -> Result<(PhotonTable<'a>, StageDone), PipelineError> {
    let rp = RelaxParams { iterations, ..p.relax };
    progress(Progress::Started(stage));
    let t = Instant::now();
    let r = relax::relax_map_on(input, &rp, scene, |m| progress(Progress::Iteration(stage, m)))?;
    let seconds = t.elapsed().as_secs_f64();
    let cv = |i: usize| r.measures.get(i).map_or(f64::NAN, |m| m.local_nn_cv);
    let summary = format!(
        "local nearest-neighbour spread {:.3} → {:.3}",
        cv(0),
        cv(r.measures.len().saturating_sub(1))
    );
    let done = StageDone { stage, seconds, photons: input.len(), summary };
    Ok((relax::relaxed_map(input, r, &rp, seconds)?, done))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{Output, PhotonMap};

    /// The chain in memory makes the same maps, byte for byte, as the stages run one after
    /// another through files (each written, then opened again): a cusp caustic with (u, v)
    /// parameters, with the paper's phases and with the 2009 relaxation's.
    #[test]
    fn in_memory_stages_make_the_maps_the_files_make() {
        let dir = tempfile::tempdir().unwrap();
        let synthetic = crate::synthetic::collimated_cusp(3_000, 5);
        let traced_path = dir.path().join("traced.phm");
        let info = synthetic.info("collimated_cusp", 5, "2026-01-01T00:00:00Z");
        crate::format::write_map(Output::Path(traced_path.clone()), info, &synthetic.columns()).unwrap();
        let traced = PhotonMap::open_path(&traced_path).unwrap();
        let bytes_of = |table: &PhotonTable, name: &str| {
            let path = dir.path().join(name);
            table.write(Output::Path(path.clone())).unwrap();
            std::fs::read(path).unwrap()
        };
        for (method, iterations) in [(None, [3, 2]), (Some(Method::Gradient), [0, 4])] {
            let p = PipelineParams { method, iterations, ..PipelineParams::default() };
            // In memory.
            let mut stages = Vec::new();
            let mut on_stage = |done: &StageDone, table: &PhotonTable| {
                stages.push((done.stage, bytes_of(table, "memory.phm")));
                Ok(())
            };
            let outcome = run(&traced.view(), None, &p, &mut on_stage, &|_| {}).unwrap();
            // Through files.
            let (chosen, _) = detect::choose_method(&traced.view(), method).unwrap();
            assert_eq!(outcome.method, chosen);
            let dp = DetectParams { method: chosen, ..p.detect };
            let d = detect::detect_map(&traced.view(), &dp, &|_| {}).unwrap();
            let reopen = |table: PhotonTable, name: &str| {
                let path = dir.path().join(name);
                table.write(Output::Path(path.clone())).unwrap();
                PhotonMap::open_path(&path).unwrap()
            };
            let mut map = reopen(detect::detected_map(&traced.view(), d, &dp, 0.0).unwrap(), "d.phm");
            let mut files = vec![(Stage::Detect, std::fs::read(dir.path().join("d.phm")).unwrap())];
            let relax_file = |map: &PhotonMap, n: usize, name: &str| {
                let rp = RelaxParams { iterations: n, ..p.relax };
                let r = relax::relax_map(&map.view(), &rp, |_| {}).unwrap();
                let t = relax::relaxed_map(&map.view(), r, &rp, 0.0).unwrap();
                reopen(t, name)
            };
            if iterations[0] > 0 {
                map = relax_file(&map, iterations[0], "r1.phm");
                files.push((Stage::RelaxParams, std::fs::read(dir.path().join("r1.phm")).unwrap()));
            }
            map = reopen(relax::collapse(&map.view()).unwrap(), "c.phm");
            files.push((Stage::Collapse, std::fs::read(dir.path().join("c.phm")).unwrap()));
            relax_file(&map, iterations[1], "r2.phm");
            files.push((Stage::RelaxWorld, std::fs::read(dir.path().join("r2.phm")).unwrap()));
            assert_eq!(stages.len(), files.len());
            for ((s, a), (t, b)) in stages.iter().zip(&files) {
                assert_eq!(s, t);
                // Equal but for the records' times and durations.
                let (ma, mb) =
                    (PhotonMap::from_bytes("a", a).unwrap(), PhotonMap::from_bytes("b", b).unwrap());
                assert_eq!(ma.view().columns(), mb.view().columns(), "{s:?}");
                assert_eq!(ma.meta().emitters, mb.meta().emitters, "{s:?}");
                assert_eq!(ma.meta().state, mb.meta().state, "{s:?}");
                let stages_of =
                    |m: &PhotonMap| m.meta().history.iter().map(|r| r.stage.clone()).collect::<Vec<_>>();
                assert_eq!(stages_of(&ma), stages_of(&mb), "{s:?}");
            }
            assert_eq!(
                outcome.map.view().positions(),
                PhotonMap::from_bytes("b", &files.last().unwrap().1).unwrap().positions()
            );
        }
    }
}
