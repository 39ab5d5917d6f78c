//! The comparison's report: a Markdown table shaped like the paper's Table I with error rows
//! added, the same numbers as CSV, an image grid with error maps, and an error-versus-time
//! plot. Every file is written to a temporary file and renamed into place.

use std::fmt::Write as _;
use std::path::Path;

use super::compare::{CompareError, MethodKind, Row, Target};
use super::metrics::Region;
use crate::render::Image;

/// One run of the comparison: the rows of every method, and what was varied to get it (empty
/// for a single run; e.g. "photons = 300000" in a sweep).
#[derive(Clone, Debug)]
pub struct Run {
    /// What was varied ("photons = 300000"); empty for a single run.
    pub label: String,
    /// One row per method.
    pub rows: Vec<Row>,
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CompareError> {
    let io = |e: std::io::Error| CompareError::Io { path: path.display().to_string(), source: e };
    let mut tmp = crate::format::temp_beside(path, ".photonkit-").map_err(io)?;
    std::io::Write::write_all(&mut tmp, bytes).map_err(io)?;
    crate::format::persist(tmp, path).map_err(io)?;
    Ok(())
}

fn secs(t: Option<f64>) -> String {
    t.map_or("-".into(), |s| {
        if s >= 60.0 { format!("{}m {:.0}s", (s / 60.0) as u64, s % 60.0) } else { format!("{s:.2}s") }
    })
}

fn num(x: f64) -> String {
    if x.is_nan() { "-".into() } else { format!("{x:.4}") }
}

fn count(n: u64) -> String {
    match n {
        0 => "-".into(),
        n if n >= 1_000_000 && n % 100_000 == 0 => format!("{}M", n as f64 / 1e6),
        n if n >= 1_000_000 => format!("{:.2}M", n as f64 / 1e6),
        n if n >= 1000 => format!("{}k", (n as f64 / 1e3).round()),
        n => n.to_string(),
    }
}

/// The table of one run, transposed like Table I: a column per method, a row per quantity.
pub fn table_markdown(rows: &[Row]) -> String {
    let mut s = String::new();
    let head: Vec<String> = rows
        .iter()
        .map(|r| {
            if rows.iter().filter(|x| x.method == r.method).count() > 1 {
                format!("{} ({})", r.method.label(), r.setting)
            } else {
                r.method.label().to_string()
            }
        })
        .collect();
    let _ = writeln!(s, "| | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(rows.len()));
    let line = |s: &mut String, name: &str, f: &dyn Fn(&Row) -> String| {
        let cells: Vec<String> = rows.iter().map(f).collect();
        let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
    };
    line(&mut s, "M / absorbed M", &|r| format!("{} / {}", count(r.emitted), count(r.photons)));
    line(&mut s, "Photon cast t", &|r| secs(r.times.trace));
    line(&mut s, "Radiance K", &|r| {
        if r.radiance_k == 0 { "variable".into() } else { r.radiance_k.to_string() }
    });
    line(&mut s, "Feature detect t", &|r| secs(r.times.detect));
    line(&mut s, "Relaxation t", &|r| secs(r.times.relax));
    line(&mut s, "Render t", &|r| secs(r.times.render));
    line(&mut s, "Total t", &|r| secs(Some(r.times.total)));
    line(&mut s, "NRMSE", &|r| num(r.errors.nrmse));
    line(&mut s, "relative MSE", &|r| num(r.errors.rel_mse));
    line(&mut s, "SSIM", &|r| num(r.errors.ssim));
    line(&mut s, "edge-band NRMSE", &|r| num(r.errors.edge_nrmse));
    line(&mut s, "overlap NRMSE", &|r| num(r.errors.overlap_nrmse));
    // Per region, over the seeds: NRMSE as bias² + variance, and the typical relative error.
    for region in Region::ALL {
        let of = |r: &Row| r.regions.iter().find(|e| e.region == Some(region)).copied();
        line(&mut s, &format!("{} NRMSE (bias², variance)", region.name()), &|r| match of(r) {
            Some(e) if e.cells > 0 => {
                format!("{} ({}, {})", num(e.nrmse), sci(e.bias2), sci(e.variance))
            }
            _ => "-".into(),
        });
        line(&mut s, &format!("{} median / p90 rel. error", region.name()), &|r| match of(r) {
            Some(e) if e.cells > 0 => format!("{} / {}", num(e.median_rel), num(e.p90_rel)),
            _ => "-".into(),
        });
    }
    line(&mut s, "smooth chroma RMS (noise s.d.)", &|r| {
        r.regions.iter().find(|e| e.region == Some(Region::Smooth)).map_or("-".into(), |e| {
            if e.chroma_sd.is_nan() {
                num(e.chroma_rms)
            } else {
                format!("{} ({})", num(e.chroma_rms), num(e.chroma_sd))
            }
        })
    });
    line(&mut s, "seeds", &|r| r.seeds.to_string());
    line(&mut s, "setting", &|r| r.setting.clone());
    s
}

fn sci(x: f64) -> String {
    if x.is_nan() { "-".into() } else { format!("{x:.2e}") }
}

/// Every row of every run as CSV: per method, setting and run, one line for the whole image
/// (`region` = `all`) and one per region class. Times are means over the seeds; `nrmse`,
/// `median_rel`, `p90_rel`, `bias2`, `variance`, `chroma_rms` and `chroma_sd` are the region's ([`super::metrics::RegionErrors`]); the
/// whole-image-only measures (`rmse`, `rel_mse`, `ssim`, `edge_nrmse`, `overlap_nrmse`, means
/// over the seeds) are empty on region lines.
pub fn csv(runs: &[Run]) -> String {
    let mut s = String::from(
        "run,method,setting,emitted,photons,radiance_k,seeds,trace_s,detect_s,relax_s,render_s,total_s,seconds,\
         region,cells,nrmse,median_rel,p90_rel,bias2,variance,chroma_rms,chroma_sd,rmse,rel_mse,ssim,edge_nrmse,overlap_nrmse\n",
    );
    let opt = |t: Option<f64>| t.map_or(String::new(), |x| format!("{x:.6}"));
    let quote = |x: &str| format!("\"{}\"", x.replace('"', "\"\""));
    for run in runs {
        for r in &run.rows {
            let e = &r.errors;
            for g in &r.regions {
                let whole = g.region.is_none();
                let only = |x: f64| if whole { format!("{x:.6e}") } else { String::new() };
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{},{},{},{},{},{},{:.6},{:.6},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{},{},{},{}",
                    quote(&run.label),
                    r.method.slug(),
                    quote(&r.setting),
                    r.emitted,
                    r.photons,
                    r.radiance_k,
                    r.seeds,
                    opt(r.times.trace),
                    opt(r.times.detect),
                    opt(r.times.relax),
                    opt(r.times.render),
                    r.times.total,
                    r.times.total,
                    g.region.map_or("all", Region::name),
                    g.cells,
                    g.nrmse,
                    g.median_rel,
                    g.p90_rel,
                    g.bias2,
                    g.variance,
                    g.chroma_rms,
                    g.chroma_sd,
                    only(e.rmse),
                    only(e.rel_mse),
                    only(e.ssim),
                    only(e.edge_nrmse),
                    only(e.overlap_nrmse),
                );
            }
        }
    }
    s
}

/// A method's error at time `t`, interpolated linearly in log time and log error between its
/// two measured points that bracket `t`; `None` if its points do not reach `t`.
pub fn error_at_time(points: &[(f64, f64)], t: f64) -> Option<f64> {
    let mut p: Vec<(f64, f64)> = points.iter().copied().filter(|(x, y)| *x > 0.0 && *y > 0.0).collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some(&(_, y)) = p.iter().find(|(x, _)| (*x / t - 1.0).abs() < 1e-9) {
        return Some(y);
    }
    let i = p.iter().position(|(x, _)| *x > t)?;
    if i == 0 {
        return None;
    }
    let ((x0, y0), (x1, y1)) = (p[i - 1], p[i]);
    let f = (t.ln() - x0.ln()) / (x1.ln() - x0.ln());
    Some((y0.ln() + f * (y1.ln() - y0.ln())).exp())
}

/// The (total time, NRMSE) points of each method over every run, in method order.
fn points(runs: &[Run]) -> Vec<(MethodKind, Vec<(f64, f64)>)> {
    MethodKind::ALL
        .into_iter()
        .map(|m| {
            let p = runs
                .iter()
                .flat_map(|r| &r.rows)
                .filter(|r| r.method == m)
                .map(|r| (r.times.total, r.errors.nrmse))
                .collect::<Vec<_>>();
            (m, p)
        })
        .filter(|(_, p)| !p.is_empty())
        .collect()
}

/// A method's lowest error among its runs that took no longer than `t`, with that run's time.
pub fn best_within(points: &[(f64, f64)], t: f64) -> Option<(f64, f64)> {
    points
        .iter()
        .copied()
        .filter(|(x, y)| *x <= t * (1.0 + 1e-9) && y.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// The equal-time table: for each run of this method, every other method's NRMSE with the same
/// time budget: the lowest among its runs that took no longer than ours, and where its runs
/// bracket our time, the value interpolated at it. Ratios are its error over ours (above 1:
/// ours is better).
pub fn equal_time_markdown(runs: &[Run]) -> String {
    let pts = points(runs);
    let others: Vec<&(MethodKind, Vec<(f64, f64)>)> =
        pts.iter().filter(|(m, _)| *m != MethodKind::Ours).collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| run | our time | our NRMSE | {} |",
        others.iter().map(|(m, _)| m.label().to_string()).collect::<Vec<_>>().join(" | ")
    );
    let _ = writeln!(s, "|---|---|---|{}", "---|".repeat(others.len()));
    for run in runs {
        for r in run.rows.iter().filter(|r| r.method == MethodKind::Ours) {
            let (t, ours) = (r.times.total, r.errors.nrmse);
            let cells: Vec<String> = others
                .iter()
                .map(|(_, p)| {
                    let best = best_within(p, t)
                        .map(|(bt, e)| format!("best {:.4} ({:.2}×, {})", e, e / ours, secs(Some(bt))));
                    let interp =
                        error_at_time(p, t).map(|e| format!("at our time {:.4} ({:.2}×)", e, e / ours));
                    match (best, interp) {
                        (Some(b), Some(i)) => format!("{b}; {i}"),
                        (Some(b), None) => b,
                        (None, Some(i)) => i,
                        (None, None) => "every run slower".into(),
                    }
                })
                .collect();
            let _ =
                writeln!(s, "| {} | {} | {:.4} | {} |", run.label, secs(Some(t)), ours, cells.join(" | "));
        }
    }
    s
}

/// The cost of `views` views of the scene, seconds: a photon map is made once and rendered
/// once per view (trace, detect and relax once, render `views` times); progressive photon
/// mapping traces its own photons for each view and runs again.
pub fn cost_of_views(r: &Row, views: u32) -> f64 {
    let more = views.saturating_sub(1) as f64;
    match (r.method, r.times.render) {
        (MethodKind::Progressive, _) | (_, None) => r.times.total * views as f64,
        (_, Some(render)) => r.times.total + more * render,
    }
}

/// The views table: each row's cost for 1 and 10 views of the same scene ([`cost_of_views`]),
/// from its measured stage times.
pub fn views_markdown(runs: &[Run]) -> String {
    let mut s = String::from("| run | method | setting | 1 view | 10 views |\n|---|---|---|---|---|\n");
    for run in runs {
        for r in &run.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                run.label,
                r.method.label(),
                r.setting,
                secs(Some(cost_of_views(r, 1))),
                secs(Some(cost_of_views(r, 10)))
            );
        }
    }
    s
}

/// Relative errors the time-to-error table targets.
pub const TARGET_ERRORS: [f64; 3] = [0.10, 0.05, 0.02];

/// When a series of (time, error) points first reaches `target`: interpolated linearly in log
/// time and log error between the last point above it and the first at or below it (in time
/// order); `Err(t0)` when its first point is already there (reached no later than t0, when
/// is not known); `None` when no point reaches it. Never extrapolated.
pub fn time_to_error(points: &[(f64, f64)], target: f64) -> Option<Result<f64, f64>> {
    let mut p: Vec<(f64, f64)> = points.iter().copied().filter(|(t, e)| *t > 0.0 && e.is_finite()).collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    let i = p.iter().position(|&(_, e)| e <= target)?;
    if i == 0 {
        return Some(Err(p[0].0));
    }
    let ((t0, e0), (t1, e1)) = (p[i - 1], p[i]);
    if e1 <= 0.0 {
        return Some(Ok(t1));
    }
    let f = (target.ln() - e0.ln()) / (e1.ln() - e0.ln());
    Some(Ok((t0.ln() + f * (t1.ln() - t0.ln())).exp()))
}

/// The time-to-error table: for each method's series (one per method and radiance K: the
/// photon counts of a sweep, or progressive photon mapping's passes) and each region, when
/// its relative RMSE (over the region's own truth mean) first reaches each of
/// [`TARGET_ERRORS`].
pub fn time_to_error_markdown(runs: &[Run]) -> String {
    let series: Vec<(String, Vec<&Row>)> = series(runs).into_iter().map(|(n, _, rows)| (n, rows)).collect();
    let mut s = String::new();
    let heads: Vec<String> = TARGET_ERRORS.iter().map(|e| format!("{:.0} %", e * 100.0)).collect();
    let _ = writeln!(s, "| method | points | region | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---|---|{}", "---|".repeat(TARGET_ERRORS.len()));
    for (name, rows) in &series {
        for region in [None, Some(Region::Smooth), Some(Region::Edge), Some(Region::Core)] {
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter_map(|r| {
                    r.regions.iter().find(|g| g.region == region).map(|g| (r.times.total, g.rel_rmse))
                })
                .filter(|(_, e)| e.is_finite())
                .collect();
            if pts.is_empty() {
                continue;
            }
            let cells: Vec<String> = TARGET_ERRORS
                .iter()
                .map(|&e| match time_to_error(&pts, e) {
                    Some(Ok(t)) => secs(Some(t)),
                    Some(Err(t)) => format!("≤ {}", secs(Some(t))),
                    None => "not reached".into(),
                })
                .collect();
            let _ = writeln!(
                s,
                "| {name} | {} | {} | {} |",
                pts.len(),
                region.map_or("all", Region::name),
                cells.join(" | ")
            );
        }
    }
    s
}

/// The least-squares slope of ln y on ln x over `points` (x, y > 0): the exponent a of
/// y ∝ xᵃ, e.g. −0.5 for an error that halves with each 4× passes. `None` for fewer than two
/// distinct x or a non-positive value.
pub fn loglog_slope(points: &[(f64, f64)]) -> Option<f64> {
    if points.iter().any(|&(x, y)| !(x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite())) {
        return None;
    }
    let n = points.len() as f64;
    let (mx, my) = points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| (a + x.ln() / n, b + y.ln() / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| {
        let dx = x.ln() - mx;
        (a + dx * (y.ln() - my), b + dx * dx)
    });
    (sxx > 1e-12).then(|| sxy / sxx)
}

/// The convergence table: for each progressive series (progressive photon mapping, the refined
/// map), per region, its NRMSE at each pass count and the log–log slope of NRMSE against
/// passes ([`loglog_slope`]) over all its pass counts and over its last two. A slope of −1/3
/// is progressive photon mapping's asymptotic rate for its RMSE (α = 2/3); 0 is a plateau.
pub fn convergence_markdown(runs: &[Run]) -> String {
    let mut s = String::from(
        "| run | series | region | NRMSE by passes | slope, all | slope, last two |\n|---|---|---|---|---|---|\n",
    );
    let regions = [None, Some(Region::Core), Some(Region::Edge), Some(Region::Smooth)];
    for run in runs {
        for (name, _, rows) in series(std::slice::from_ref(run)) {
            let mut rows: Vec<&Row> = rows.into_iter().filter(|r| r.passes.is_some()).collect();
            rows.sort_by_key(|r| r.passes);
            if rows.len() < 2 {
                continue;
            }
            for g in regions {
                let pts: Vec<(f64, f64)> = rows
                    .iter()
                    .filter_map(|r| {
                        let e = r.regions.iter().find(|e| e.region == g && e.nrmse.is_finite())?;
                        Some((r.passes? as f64, e.nrmse))
                    })
                    .collect();
                // A region with no pixels (no edge in the glass sphere's truth) has no row.
                if pts.len() < 2 {
                    continue;
                }
                let by_pass: Vec<String> = pts.iter().map(|&(p, e)| format!("{p}: {}", num(e))).collect();
                let slope = |p: &[(f64, f64)]| loglog_slope(p).map_or("-".into(), |a| format!("{a:+.2}"));
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} | {} |",
                    run.label,
                    name,
                    g.map_or("all", Region::name),
                    by_pass.join(", "),
                    slope(&pts),
                    slope(&pts[pts.len() - 2..])
                );
            }
        }
    }
    s
}

/// The series of the plot and the time-to-error table: one per method, except standard photon
/// mapping (one per K) and progressive photon mapping (one per photon budget per pass, its
/// points its pass counts), each with its rows in time order (so a line never zig-zags).
pub fn series(runs: &[Run]) -> Vec<(String, MethodKind, Vec<&Row>)> {
    let mut out: Vec<(String, MethodKind, Vec<&Row>)> = Vec::new();
    for r in runs.iter().flat_map(|r| &r.rows) {
        let name = match r.method {
            MethodKind::StandardPm => format!("{} (K = {})", r.method.label(), r.radiance_k),
            MethodKind::Progressive => {
                let budget = r.setting.split_once("passes of ").map_or("", |(_, b)| b);
                let budget = budget.split(',').next().unwrap_or("");
                format!("{} ({budget} per pass)", r.method.label())
            }
            m => m.label().to_string(),
        };
        match out.iter_mut().find(|(n, _, _)| *n == name) {
            Some((_, _, rows)) => rows.push(r),
            None => out.push((name, r.method, vec![r])),
        }
    }
    for (_, _, rows) in &mut out {
        rows.sort_by(|a, b| a.times.total.total_cmp(&b.times.total));
    }
    out
}

/// Writes report.md, report.csv, grid.png (of the last run), error-vs-time.png and, when a
/// progressive method ran, error-vs-passes.png into `dir`. `spp` is the images' samples per
/// pixel: in most pixels, and in the truth's core and edge pixels.
pub fn write(
    dir: &Path,
    title: &str,
    target: &Target,
    runs: &[Run],
    command: &str,
    spp: [u32; 2],
) -> Result<(), CompareError> {
    let mut md = String::new();
    let _ = writeln!(md, "# {title}\n");
    let _ = writeln!(md, "Made by `{command}`.\n");
    let _ = writeln!(md, "Truth: {}.\n", target.description);
    let _ = writeln!(
        md,
        "Errors are over every pixel and RGB channel of a {}×{} image; NRMSE is the RMSE over the truth's mean; \
         relative MSE uses ε = 1 % of the truth's mean; SSIM is on luminance as displayed (over the truth's 99th percentile, clamped to 1; 11×11 Gaussian window, σ = 1.5); the \
         edge band is every pixel within {} pixels of a sharp rise in the truth; overlap is where the truth has \
         light from two or more separate sheets of rays.\n",
        target.width(),
        target.height(),
        super::compare::EDGE_BAND
    );
    let _ = writeln!(
        md,
        "Each pixel is the mean of {} samples on a jittered grid, {} in the core and edge pixels, where the \
         irradiance varies within a pixel and fewer samples of a narrow kernel's estimate would miss the pixel's \
         average by more than the methods differ (docs/truth.md, \"Sampling\"); progressive photon mapping \
         jitters each pass's samples afresh.\n",
        spp[0],
        spp[1].max(spp[0]),
    );
    let cells = |r: Region| target.regions.iter().filter(|&&c| c == r).count();
    let _ = writeln!(
        md,
        "Each method ran with {} seed(s); times and errors are means over them. Regions (docs/truth.md): core \
         {} pixels (the truth at least its lit pixels' 99.5th percentile and 4× their median, and their 8 \
         neighbours), edge {}, smooth {}, dark {} (truth 0). Per region: NRMSE (over the whole truth's mean) \
         with its split into bias² and variance across the seeds (NRMSE² = bias² + variance; bias² is unbiased, \
         so it may be slightly negative where noise dominates), and the median and 90th percentile of each \
         pixel's relative luminance error (in dark pixels, over the truth's mean luminance).\n",
        runs.first().and_then(|r| r.rows.first()).map_or(0, |r| r.seeds),
        cells(Region::Core),
        cells(Region::Edge),
        cells(Region::Smooth),
        cells(Region::Dark),
    );
    for run in runs {
        if !run.label.is_empty() {
            let _ = writeln!(md, "## {}\n", run.label);
        }
        md.push_str(&table_markdown(&run.rows));
        md.push('\n');
    }
    let _ = writeln!(md, "## At equal time\n");
    let _ = writeln!(
        md,
        "Each method with our method's time budget: its lowest NRMSE among its runs that took no longer than ours \
         (with that run's time), and where its runs bracket our time, its NRMSE interpolated (log–log) at it. The \
         ratio is its error over ours (above 1: ours is better).\n"
    );
    md.push_str(&equal_time_markdown(runs));
    let _ = writeln!(md, "\n## Time to error\n");
    let _ = writeln!(
        md,
        "When each method first reaches a relative RMSE (over the region's own truth mean) of 10 %, 5 % and 2 %: \
         interpolated (log–log) between its measured points in time order, never extrapolated; \"≤ t\" where its \
         fastest point is already there, \"not reached\" where none is. A method's points are its runs of a sweep \
         (one per photon count) or, for progressive photon mapping, its pass counts.\n"
    );
    md.push_str(&time_to_error_markdown(runs));
    if runs.iter().flat_map(|r| &r.rows).any(|r| r.passes.is_some()) {
        let _ = writeln!(md, "\n## Convergence with passes\n");
        let _ = writeln!(
            md,
            "Each progressive series' NRMSE (over the whole truth's mean) per region at each pass count, and the \
             log–log slope of NRMSE against passes (least squares over every count, and over the last two): −1/3 \
             is progressive photon mapping's asymptotic rate (α = 2/3), 0 a plateau, below 0 still converging.\n"
        );
        md.push_str(&convergence_markdown(runs));
        let _ = writeln!(md, "\n![error against passes](error-vs-passes.png)");
    }
    let _ = writeln!(md, "\n## One view and ten\n");
    let _ = writeln!(
        md,
        "A photon map is view-independent: made once (trace, detect, relax), it is rendered again for each view. \
         Progressive photon mapping traces its own photons for each view and runs again. Costs from the measured \
         stage times (the errors are each view's own, not shown).\n"
    );
    md.push_str(&views_markdown(runs));
    let _ = writeln!(md, "\n![error against time](error-vs-time.png)\n\n![images and error maps](grid.png)");
    write_atomic(&dir.join("report.md"), md.as_bytes())?;
    write_atomic(&dir.join("report.csv"), csv(runs).as_bytes())?;
    #[cfg(feature = "plots")]
    {
        use super::plots::{grid_png, passes_plot_png, plot_png};
        write_atomic(&dir.join("error-vs-time.png"), &plot_png(runs, title)?)?;
        if runs.iter().flat_map(|r| &r.rows).any(|r| r.passes.is_some()) {
            write_atomic(&dir.join("error-vs-passes.png"), &passes_plot_png(runs, title)?)?;
        }
        if let Some(last) = runs.last() {
            write_atomic(&dir.join("grid.png"), &grid_png(target, &last.rows)?)?;
        }
    }
    write_exrs(dir, target, runs)
}

/// A name for files from free text: lower-case letters and digits, runs of anything else one
/// hyphen.
fn file_slug(text: &str) -> String {
    let mut s = String::new();
    for c in text.chars() {
        if c.is_ascii_alphanumeric() {
            s.push(c.to_ascii_lowercase());
        } else if !s.ends_with('-') && !s.is_empty() {
            s.push('-');
        }
    }
    s.trim_end_matches('-').to_string()
}

/// The truth and every method's image (its first seed's) as EXR in `dir/images/`, with the
/// view in the header, so anyone can recompute the report's numbers without this code.
fn write_exrs(dir: &Path, target: &Target, runs: &[Run]) -> Result<(), CompareError> {
    use crate::render::image::{Notes, Outputs, write};
    let images = dir.join("images");
    std::fs::create_dir_all(&images)
        .map_err(|e| CompareError::Io { path: images.display().to_string(), source: e })?;
    let (w, h) = (target.width() as u32, target.height() as u32);
    let mut view: Notes = vec![("photonkit:truth".into(), target.description.clone())];
    if let Some(g) = &target.grid {
        view.push((
            "photonkit:grid".into(),
            format!(
                "floor z = {} m, x {} .. {} m in {} columns (column 0 at the smallest x), y {} .. {} m in {} rows (row 0 at \
                 the largest y); each pixel is one cell",
                g.z, g.min[0], g.max[0], g.cells[0], g.min[1], g.max[1], g.cells[1]
            ),
        ));
    }
    let unit = match target.mode {
        crate::render::Mode::Irradiance => "irradiance, W/m² per RGB channel, each pixel its cell's mean",
        _ => "radiance, W/(m²·sr) per RGB channel, each pixel its area's mean",
    };
    view.push(("photonkit:unit".into(), unit.into()));
    let mut truth = Image::new(w, h);
    for (p, t) in truth.pixels.iter_mut().zip(&target.truth) {
        *p = glam::DVec3::from_array(*t).as_vec3();
    }
    let out = |name: &str| Outputs {
        exr: Some(images.join(format!("{name}.exr"))),
        png: None,
        ..Outputs::default()
    };
    write(&truth, &out("truth"), &view)?;
    for run in runs {
        for r in &run.rows {
            let mut notes = view.clone();
            notes.push(("photonkit:method".into(), format!("{} ({})", r.method.label(), r.setting)));
            notes.push(("photonkit:seed".into(), "the first of the comparison's seeds".into()));
            let name = [run.label.as_str(), r.method.slug(), &r.setting]
                .iter()
                .map(|x| file_slug(x))
                .filter(|x| !x.is_empty())
                .collect::<Vec<_>>()
                .join("-");
            write(&r.image, &out(&name), &notes)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ten_views_cost_one_map_and_ten_renders_or_ten_progressive_runs() {
        let row = |method, render: Option<f64>, total| Row {
            method,
            setting: String::new(),
            emitted: 1,
            photons: 1,
            radiance_k: 15,
            passes: None,
            times: super::super::compare::StageTimes { render, total, ..Default::default() },
            errors: super::super::metrics::Errors {
                rmse: 0.0,
                nrmse: 0.0,
                rel_mse: 0.0,
                ssim: 1.0,
                edge_nrmse: 0.0,
                overlap_nrmse: 0.0,
            },
            seeds: 1,
            regions: Vec::new(),
            image: Image::new(1, 1),
        };
        let ours = row(MethodKind::Ours, Some(0.5), 8.0);
        assert_eq!((cost_of_views(&ours, 1), cost_of_views(&ours, 10)), (8.0, 12.5));
        let ppm = row(MethodKind::Progressive, None, 4.0);
        assert_eq!((cost_of_views(&ppm, 1), cost_of_views(&ppm, 10)), (4.0, 40.0));
    }

    #[test]
    fn loglog_slope_recovers_a_power_law_exponent() {
        // e = 0.4·p^(−1/3) exactly: the fit returns −1/3 over any pass counts.
        let p: Vec<(f64, f64)> = [1.0, 4.0, 16.0, 64.0].map(|x: f64| (x, 0.4 * x.powf(-1.0 / 3.0))).to_vec();
        assert!((loglog_slope(&p).unwrap() + 1.0 / 3.0).abs() < 1e-12);
        assert!((loglog_slope(&p[2..]).unwrap() + 1.0 / 3.0).abs() < 1e-12);
        // A plateau is 0; noise around a line is its least-squares fit.
        assert!(loglog_slope(&[(1.0, 0.1), (4.0, 0.1), (16.0, 0.1)]).unwrap().abs() < 1e-12);
        let q = [(1.0, 1.0), (2.0, 0.25), (4.0, 0.25)];
        // dx = (−1, 0, 1)·ln 2, dy = (4, −2, −2)·ln 2 / 3: Σ dx·dy / Σ dx² = −2 / 2 = −1.
        assert!((loglog_slope(&q).unwrap() + 1.0).abs() < 1e-12);
        assert_eq!(loglog_slope(&[(1.0, 0.1)]), None);
        assert_eq!(loglog_slope(&[(4.0, 0.1), (4.0, 0.2)]), None);
        assert_eq!(loglog_slope(&[(1.0, 0.1), (4.0, 0.0)]), None);
    }

    #[test]
    fn time_to_error_interpolates_in_log_log_and_never_extrapolates() {
        // Error halves with each 4× time: 0.2 at 1 s, 0.1 at 4 s, 0.05 at 16 s.
        let p = [(4.0, 0.1), (1.0, 0.2), (16.0, 0.05)];
        assert_eq!(time_to_error(&p, 0.1), Some(Ok(4.0)));
        let t = time_to_error(&p, 0.0707).unwrap().unwrap();
        assert!((t - 8.0).abs() < 0.01, "{t}");
        assert_eq!(time_to_error(&p, 0.3), Some(Err(1.0)));
        assert_eq!(time_to_error(&p, 0.02), None);
        // Not monotone: the first crossing in time order counts.
        let q = [(1.0, 0.2), (2.0, 0.08), (3.0, 0.15), (4.0, 0.05)];
        let t = time_to_error(&q, 0.1).unwrap().unwrap();
        assert!(t > 1.0 && t < 2.0, "{t}");
        assert_eq!(time_to_error(&[], 0.1), None);
    }

    #[test]
    fn equal_time_interpolates_in_log_log_and_refuses_to_extrapolate() {
        // e = 1/t on a log–log line: interpolation is exact.
        let p = [(1.0, 1.0), (4.0, 0.25), (16.0, 1.0 / 16.0)];
        assert!((error_at_time(&p, 2.0).unwrap() - 0.5).abs() < 1e-12);
        assert!((error_at_time(&p, 8.0).unwrap() - 0.125).abs() < 1e-12);
        assert_eq!(error_at_time(&p, 4.0), Some(0.25));
        assert_eq!(error_at_time(&p, 0.5), None);
        assert_eq!(error_at_time(&p, 17.0), None);
        assert_eq!(error_at_time(&[], 1.0), None);
        // Best within the budget: the lowest error among runs no slower than t.
        assert_eq!(best_within(&p, 5.0), Some((4.0, 0.25)));
        assert_eq!(best_within(&p, 0.5), None);
        assert_eq!(best_within(&[(1.0, 0.5), (2.0, 0.7)], 3.0), Some((1.0, 0.5)));
    }
}
