//! Algorithm 1 after the trace, without a file: a synthetic cusp caustic (a collimated emitter's
//! (u, v) folded onto the floor) is detected, relaxed, collapsed and relaxed again in memory
//! with the paper's settings; the constrained share and the evenness of the photons are
//! printed, and nothing is written.
//!
//! ```text
//! cargo run --release --example detect_relax_in_memory
//! ```

use photonkit::format::{PhotonTable, name};
use photonkit::pipeline::{self, PipelineParams, Progress, StageDone};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cusp = photonkit::synthetic::collimated_cusp(20_000, 1);
    let traced = PhotonTable::from_columns(
        "cusp",
        cusp.info("collimated_cusp", 1, "2026-01-01T00:00:00Z"),
        &cusp.columns(),
    )?;
    // Each stage's map arrives here as it is made; a program could write it
    // (`table.write(Output::Path(...))`), keep it, or look at a column, as here.
    let mut on_stage = |done: &StageDone, table: &PhotonTable| {
        let view = table.view();
        let lambda2 = view.column::<f32>(name::LAMBDA2)?.unwrap_or_default();
        let mean = lambda2.iter().map(|&l| l as f64).sum::<f64>() / lambda2.len().max(1) as f64;
        println!(
            "{:<15} {:>7.3} s  {} photons, mean λ2 {mean:.3}  {}",
            done.stage.label(),
            done.seconds,
            view.len(),
            done.summary
        );
        Ok(())
    };
    let note = |p: Progress| {
        if let Progress::Note(n) = p {
            println!("note: {n}");
        }
    };
    let relaxed = pipeline::run(&traced.view(), None, &PipelineParams::default(), &mut on_stage, &note)?;
    let moved = relaxed.map.view().positions().iter().zip(&cusp.position).filter(|(a, b)| a != b).count();
    println!("{} method; {moved} of {} photons moved", relaxed.method.name(), cusp.len());
    Ok(())
}
