//! Reads a photon map and prints what it holds: photons, emitters, columns, total flux, the
//! stages that made it.
//!
//! ```text
//! cargo run --example map_statistics -- samples/minimal.phm
//! ```

use photonkit::format::PhotonMap;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: map_statistics FILE.phm")?;
    let map = PhotonMap::open(&path)?;
    let view = map.view();
    let info = view.info();
    println!("{}: {} photons, state {}", view.file_name(), view.len(), info.state.name());
    for e in &info.emitters {
        println!("  emitter {}: {:?}, {} parameter dimensions, {} W", e.id, e.kind, e.param_dims, e.power_w);
    }
    for (spec, _) in view.columns() {
        println!("  column {} ({}×{})", spec.name, spec.dtype.name(), spec.components);
    }
    let total = view
        .flux()
        .iter()
        .fold([0.0f64; 3], |t, f| [t[0] + f[0] as f64, t[1] + f[1] as f64, t[2] + f[2] as f64]);
    println!(
        "  total flux {:.6} W (R {:.6}, G {:.6}, B {:.6})",
        total.iter().sum::<f64>(),
        total[0],
        total[1],
        total[2]
    );
    let stages: Vec<&str> = info.history.iter().map(|r| r.stage.as_str()).collect();
    if stages.is_empty() {
        println!("  no stage history");
    } else {
        println!("  made by: {}", stages.join(" → "));
    }
    Ok(())
}
