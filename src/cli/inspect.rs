//! `photonkit inspect`: what is in a photon map, and is it sound.

use std::io::Write;
use std::process::ExitCode;

use anyhow::{Context, bail};
use photonkit::format::{Output, PhotonMap};
use photonkit::inspect;

/// Summarise a photon map: version, emitters, column table, stage history, per-column
/// statistics (min, max, mean, NaN and Inf counts), total flux and bounding box.
#[derive(clap::Args)]
pub struct Args {
    /// The PHM file (`-` for standard input).
    file: String,
    /// Print the summary as JSON (the same fields tools/phm.py prints).
    #[arg(long, conflicts_with_all = ["dump", "head", "sample", "check"])]
    json: bool,
    /// Print every photon as TSV with a header row (columns named as in format-spec §7).
    #[arg(long, conflicts_with_all = ["head", "sample", "check"])]
    dump: bool,
    /// Print the first N photons as TSV.
    #[arg(long, value_name = "N", conflicts_with_all = ["sample", "check"])]
    head: Option<usize>,
    /// Write a uniform random subset of N photons to --output, flux scaled to keep the total.
    #[arg(long, value_name = "N", requires = "output", conflicts_with = "check")]
    sample: Option<usize>,
    /// Seed for --sample.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output file for --sample (`-` for standard output).
    #[arg(short, long, value_name = "FILE")]
    output: Option<String>,
    /// Verify checksums and invariants (finite values, unit normals, parameters in range,
    /// bounding box); exit with status 1 on any violation.
    #[arg(long)]
    check: bool,
    /// Also show where each column lies in the file: its byte offset, length and CRC-32.
    #[arg(long, conflicts_with_all = ["json", "dump", "head", "sample", "check"])]
    layout: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    // Checksums are verified by --check (and every stage), reported among its findings.
    let map = PhotonMap::open_unverified(&a.file)?;
    if let Some(o) = &a.output {
        super::refuse_input_as_output(o)?;
    }
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    if a.json {
        serde_json::to_writer_pretty(&mut out, &inspect::summarize(&map))?;
        writeln!(out)?;
    } else if a.dump || a.head.is_some() {
        inspect::dump_tsv(&map, a.head, &mut out).context("writing TSV")?;
    } else if let Some(n) = a.sample {
        // The sample is a new file: never from a corrupt map.
        map.verify_checksums()?;
        let target = Output::parse(a.output.as_deref().expect("clap requires --output"));
        if map.is_empty() {
            bail!("{}: the map holds no photons to sample", map.file_name());
        }
        inspect::sample(&map, n, a.seed, target)?;
    } else if a.check {
        let violations = inspect::check(&map);
        if violations.is_empty() {
            writeln!(out, "{}: ok ({} photons, checksums and invariants hold)", map.file_name(), map.len())?;
        } else {
            for v in &violations {
                match v.first {
                    Some(i) => eprintln!(
                        "{}: {} photons break: {} (first: photon {i})",
                        map.file_name(),
                        v.photons,
                        v.rule
                    ),
                    None => eprintln!("{}: broken: {}", map.file_name(), v.rule),
                }
            }
            return Ok(ExitCode::FAILURE);
        }
    } else {
        print_summary(&inspect::summarize(&map), a.layout, &mut out)?;
    }
    out.flush()?;
    Ok(ExitCode::SUCCESS)
}

fn print_summary(s: &inspect::Summary, show_layout: bool, o: &mut dyn Write) -> std::io::Result<()> {
    writeln!(o, "{}: PHM {}, {} photons, state {}", s.file, s.version, s.photon_count, s.state)?;
    writeln!(o, "units: length {}, flux {}", s.units.length, s.units.flux)?;
    match &s.bounding_box {
        Some(b) => writeln!(o, "bounding box: {b}")?,
        None => writeln!(o, "bounding box: (empty map)")?,
    }
    let t = s.total_flux_w;
    writeln!(o, "total flux: {:.6} W (r {:.6}, g {:.6}, b {:.6})", t[0] + t[1] + t[2], t[0], t[1], t[2])?;
    writeln!(o, "\nemitters:")?;
    if s.emitters.is_empty() {
        writeln!(o, "  (none recorded)")?;
    }
    for e in &s.emitters {
        writeln!(
            o,
            "  {:>3}  {:<10} {:<10} {} param dims  {} W  colour ({}, {}, {})",
            e.id,
            serde_json::to_value(e.kind)?.as_str().unwrap_or("?").to_string(),
            serde_json::to_value(e.parameterisation)?.as_str().unwrap_or("?").to_string(),
            e.param_dims,
            e.power_w,
            e.colour[0],
            e.colour[1],
            e.colour[2]
        )?;
        if let Some(k) = e.parameterisation.spectral_component() {
            let d = &e.dimensions()[k];
            let [lo, hi] = d.range.unwrap_or([f64::NAN; 2]);
            writeln!(
                o,
                "       param_{k}: wavelength, {lo}–{hi} {}, distance scale {:.4e} per {}{}",
                d.unit.as_deref().unwrap_or("?"),
                d.distance_scale(),
                d.unit.as_deref().unwrap_or("unit"),
                if d.scale.is_some() { " (set by detect)" } else { " (default: the range spans 1)" }
            )?;
        }
    }
    writeln!(o, "\ncolumns:")?;
    // The file layout (offset, length, CRC-32) only on request: it serves format work, not
    // a look at the photons.
    let layout = |o: &mut dyn Write, cells: [&str; 3]| -> std::io::Result<()> {
        if show_layout { write!(o, " {:>12} {:>12} {:>10}", cells[0], cells[1], cells[2]) } else { Ok(()) }
    };
    write!(o, "  {:<16} {:<7}", "name", "type")?;
    layout(o, ["offset", "bytes", "crc32"])?;
    writeln!(o, "  {:>14} {:>14} {:>14} {:>5} {:>5}", "min", "max", "mean", "nan", "inf")?;
    for c in &s.columns {
        // Integer columns print as integers (a mean to 6 significant digits), floats in
        // scientific notation.
        let integer = c.dtype != photonkit::format::DType::F32;
        let f = |v: Option<f64>, exact: bool| match v {
            None => "-".to_string(),
            Some(x) if integer && exact => format!("{x:.0}"),
            Some(x) if integer => format!("{}", format!("{x:.6e}").parse::<f64>().unwrap_or(x)),
            Some(x) => format!("{x:.6e}"),
        };
        for (k, st) in c.stats.iter().enumerate() {
            let label =
                photonkit::format::columns::text_names_in(&s.emitters, &c.name, c.components)[k].clone();
            if k == 0 {
                write!(o, "  {:<16} {:<7}", c.name, format!("{}×{}", c.dtype.name(), c.components))?;
                layout(o, [&c.offset.to_string(), &c.length.to_string(), &format!("{:08x}", c.crc32)])?;
            } else {
                write!(o, "  {:<16} {:<7}", "", "")?;
                layout(o, ["", "", ""])?;
            }
            writeln!(
                o,
                "  {:>14} {:>14} {:>14} {:>5} {:>5}  {label}",
                f(st.min, true),
                f(st.max, true),
                f(st.mean, false),
                st.nan,
                st.inf
            )?;
        }
    }
    writeln!(o, "\nhistory:")?;
    for h in &s.history {
        writeln!(o, "  {}  {} (photonkit {})  {}", h.time, h.stage, h.version, h.parameters)?;
    }
    Ok(())
}
