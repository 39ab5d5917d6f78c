//! The comparison report's pictures: the error-versus-time plot and the grid of images and
//! error maps (feature `plots`, on in the command-line build).

use plotters::prelude::*;

use super::compare::{CompareError, MethodKind, Row, Target};
use super::metrics::{Region, luminance, percentile_luminance};
use super::report::{Run, series};
use crate::render::image::srgb8;

/// The font the plots and the grid's labels are drawn with (embedded, so no system fonts
/// are needed).
fn register_font() -> Result<(), CompareError> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT)
        .map_err(|_| CompareError::Invalid("the embedded font could not be read".into()))
}

fn png_bytes(rgb: &[u8], w: u32, h: u32) -> Result<Vec<u8>, CompareError> {
    let mut out = Vec::new();
    let err = |e: png::EncodingError| CompareError::Invalid(format!("PNG encoding: {e}"));
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().map_err(err)?;
    wr.write_image_data(rgb).map_err(err)?;
    wr.finish().map_err(err)?;
    Ok(out)
}

/// A tick label with at most three significant digits (log axes land on values like
/// 0.30000000000000004).
fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s }
}

/// Colours of the methods in the plot.
fn colour(m: MethodKind) -> RGBColor {
    match m {
        MethodKind::StandardPm => RGBColor(90, 90, 90),
        MethodKind::Relaxation2009 => RGBColor(31, 119, 180),
        MethodKind::DiffusionPm => RGBColor(44, 160, 44),
        MethodKind::Ours => RGBColor(214, 39, 40),
        MethodKind::Progressive => RGBColor(148, 103, 189),
        MethodKind::OursProgressive => RGBColor(140, 86, 75),
    }
}

/// A distinct colour per series: the method's, lighter for each further series of it.
fn series_colour(m: MethodKind, nth: usize) -> RGBColor {
    let RGBColor(r, g, b) = colour(m);
    let f = |c: u8| (c as f64 + (255.0 - c as f64) * (0.35 * nth as f64).min(0.7)) as u8;
    RGBColor(f(r), f(g), f(b))
}

/// The ticks of a log axis over `lo..hi`: labelled at 1, 2 and 5 times the powers of ten inside
/// it, or at every whole multiple when those are fewer than three (an error axis that stays
/// within one decade would otherwise carry no label); light lines at every whole multiple.
fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut bold, mut light) = (Vec::new(), Vec::new());
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        return (bold, light);
    }
    let mut decade = lo.log10().floor() as i32;
    while 10f64.powi(decade) <= hi * (1.0 + 1e-9) {
        for m in 1..=9 {
            let v = m as f64 * 10f64.powi(decade);
            if (lo * (1.0 - 1e-9)..=hi * (1.0 + 1e-9)).contains(&v) {
                light.push(v);
                if matches!(m, 1 | 2 | 5) {
                    bold.push(v);
                }
            }
        }
        decade += 1;
    }
    if bold.len() < 3 {
        bold = light.clone();
    }
    (bold, light)
}

/// The power of ten at or below `x` (the time axis spans whole decades, so that it has a tick
/// label in each).
fn decade_below(x: f64) -> f64 {
    10f64.powf(x.log10().floor())
}

/// The power of ten at or above `x`.
fn decade_above(x: f64) -> f64 {
    10f64.powf(x.log10().ceil())
}

/// The error-versus-time plot as PNG: log–log, total seconds against NRMSE (over the whole
/// truth's mean), one panel per region (the whole image, core, edge, smooth), a line with
/// markers per series ([`series`]), and the legend beside the panels, where it hides no point.
pub fn plot_png(runs: &[Run], title: &str) -> Result<Vec<u8>, CompareError> {
    loglog_png(runs, title, &|r| Some(r.times.total), "total time per view, s")
}

/// The error-versus-passes plot as PNG, like [`plot_png`] with passes on the x axis: the
/// progressive series only (progressive photon mapping, the refined map), so each line's slope
/// is its convergence rate.
pub fn passes_plot_png(runs: &[Run], title: &str) -> Result<Vec<u8>, CompareError> {
    loglog_png(runs, title, &|r| r.passes.map(|p| p as f64), "passes")
}

/// A log–log plot of NRMSE against `x` of each row (rows without one left out), one panel per
/// region, a line per series.
fn loglog_png(
    runs: &[Run],
    title: &str,
    x: &dyn Fn(&Row) -> Option<f64>,
    x_desc: &str,
) -> Result<Vec<u8>, CompareError> {
    register_font()?;
    let (w, h) = (1400u32, 900u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut all_series = series(runs);
    for (_, _, rows) in &mut all_series {
        rows.retain(|r| x(r).is_some());
        rows.sort_by(|a, b| x(a).unwrap_or(0.0).total_cmp(&x(b).unwrap_or(0.0)));
    }
    all_series.retain(|(_, _, rows)| !rows.is_empty());
    let mut nth = std::collections::HashMap::new();
    let styled: Vec<(String, RGBColor, Vec<&Row>)> = all_series
        .into_iter()
        .map(|(name, m, rows)| {
            let k = nth.entry(m).or_insert(0usize);
            let c = series_colour(m, *k);
            *k += 1;
            (name, c, rows)
        })
        .collect();
    let panels = [None, Some(Region::Core), Some(Region::Edge), Some(Region::Smooth)];
    let point = |r: &Row, g: Option<Region>| {
        r.regions
            .iter()
            .find(|e| e.region == g)
            .and_then(|e| Some((x(r)?, e.nrmse)))
            .filter(|&(t, e)| t > 0.0 && e > 0.0 && e.is_finite())
    };
    let draw = |buf: &mut [u8]| -> Result<(), Box<dyn std::error::Error + '_>> {
        let root = BitMapBackend::with_buffer(buf, (w, h)).into_drawing_area();
        let root = root.titled(title, ("sans-serif", 24))?;
        let (plots, legend) = root.split_horizontally(w - 300);
        for (area, &g) in plots.split_evenly((2, 2)).iter().zip(&panels) {
            let name = g.map_or("whole image", Region::name);
            let pts: Vec<(f64, f64)> =
                styled.iter().flat_map(|(_, _, rows)| rows.iter().filter_map(|r| point(r, g))).collect();
            if pts.is_empty() {
                area.draw(&Text::new(
                    format!("{name}: no pixels of this region"),
                    (60, 60),
                    ("sans-serif", 18).into_font(),
                ))?;
                continue;
            }
            let (t0, t1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
            let (e0, e1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
            let mut chart = ChartBuilder::on(area)
                .caption(name, ("sans-serif", 18))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d((decade_below(t0)..decade_above(t1)).log_scale(), {
                    let (bold, light) = log_ticks(e0 / 1.3, e1 * 1.3);
                    (e0 / 1.3..e1 * 1.3).log_scale().with_key_points(bold).with_light_points(light)
                })?;
            chart
                .configure_mesh()
                .x_labels(12)
                .y_labels(10)
                .x_desc(x_desc)
                .y_desc("NRMSE")
                .x_label_formatter(&|v| tick(*v))
                .y_label_formatter(&|v| tick(*v))
                .label_style(("sans-serif", 13))
                .draw()?;
            for (_, c, rows) in &styled {
                let p: Vec<(f64, f64)> = rows.iter().filter_map(|r| point(r, g)).collect();
                chart.draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(2)))?;
                chart.draw_series(p.iter().map(|&(x, y)| Circle::new((x, y), 4, c.filled())))?;
            }
        }
        // The legend: a line and marker per series, beside the panels.
        for (i, (name, c, _)) in styled.iter().enumerate() {
            let y = 40 + 26 * i as i32;
            legend.draw(&PathElement::new(vec![(10, y), (40, y)], c.stroke_width(3)))?;
            legend.draw(&Circle::new((25, y), 4, c.filled()))?;
            legend.draw(&Text::new(name.clone(), (48, y - 8), ("sans-serif", 14).into_font()))?;
        }
        root.present()?;
        Ok(())
    };
    draw(&mut buf).map_err(|e| CompareError::Invalid(format!("drawing the plot: {e}")))?;
    png_bytes(&buf, w, h)
}

/// The image grid: the truth and each method's image on the top row (one exposure for all:
/// the truth's automatic one, with the preview's tone curve), and below each image its signed
/// luminance error (red: too bright, blue: too dark, full colour at a quarter of that
/// percentile).
pub fn grid_png(target: &Target, rows: &[Row]) -> Result<Vec<u8>, CompareError> {
    register_font()?;
    let (iw, ih) = (target.width(), target.height());
    // Small images are enlarged (nearest neighbour) so the tiles are readable.
    let zoom = (256 / iw.max(ih)).max(1);
    let (tw, th) = (iw * zoom, ih * zoom);
    let label_h = 24;
    let cols = rows.len() + 1;
    let (w, h) = (cols * tw, 2 * (th + label_h));
    let mut buf = vec![255u8; w * h * 3];
    let p99 = percentile_luminance(&target.truth, 0.99).max(f64::MIN_POSITIVE);
    let mut put = |col: usize, row: usize, f: &dyn Fn(usize) -> [u8; 3]| {
        let (x0, y0) = (col * tw, row * (th + label_h) + label_h);
        for y in 0..th {
            for x in 0..tw {
                let px = f((y / zoom) * iw + x / zoom);
                let o = ((y0 + y) * w + x0 + x) * 3;
                buf[o..o + 3].copy_from_slice(&px);
            }
        }
    };
    // The truth's automatic exposure for every tile, and the preview's hue-keeping shoulder
    // (crate::render::tone), so the images compare as they are.
    let truth = crate::render::image::Image {
        width: iw as u32,
        height: ih as u32,
        pixels: target.truth.iter().map(|p| glam::DVec3::from_array(*p).as_vec3()).collect(),
        metered: None,
        samples: None,
    };
    let scale = crate::render::tone::auto_exposure(&truth).exp2();
    let tone = |p: [f64; 3]| {
        crate::render::tone::tone_map(glam::DVec3::from_array(p).as_vec3(), scale).to_array().map(srgb8)
    };
    put(0, 0, &|i| tone(target.truth[i]));
    for (c, r) in rows.iter().enumerate() {
        let img = &r.image.pixels;
        put(c + 1, 0, &|i| tone(img[i].as_dvec3().to_array()));
        put(c + 1, 1, &|i| {
            let e = (luminance(img[i].as_dvec3().to_array()) - luminance(target.truth[i])) / (0.25 * p99);
            let e = e.clamp(-1.0, 1.0);
            let fade = (255.0 * (1.0 - e.abs())) as u8;
            if e >= 0.0 { [255, fade, fade] } else { [fade, fade, 255] }
        });
    }
    let mut labels: Vec<String> = vec!["truth".into()];
    labels.extend(rows.iter().map(|r| {
        if r.method == MethodKind::Progressive {
            format!("PPM {}", r.setting.split(' ').next().unwrap_or(""))
        } else if r.method == MethodKind::StandardPm {
            format!("PM, {}", r.setting)
        } else {
            r.method.label().into()
        }
    }));
    let draw = |buf: &mut [u8]| -> Result<(), Box<dyn std::error::Error + '_>> {
        let root = BitMapBackend::with_buffer(buf, (w as u32, h as u32)).into_drawing_area();
        let style = ("sans-serif", 16).into_font().color(&BLACK);
        for (c, l) in labels.iter().enumerate() {
            root.draw(&Text::new(l.clone(), ((c * tw + 4) as i32, 4), style.clone()))?;
            if c > 0 {
                root.draw(&Text::new(
                    format!("{l}: error"),
                    ((c * tw + 4) as i32, (th + label_h + 4) as i32),
                    style.clone(),
                ))?;
            }
        }
        root.present()?;
        Ok(())
    };
    draw(&mut buf).map_err(|e| CompareError::Invalid(format!("drawing the grid labels: {e}")))?;
    png_bytes(&buf, w as u32, h as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_keep_three_significant_digits() {
        assert_eq!(tick(0.30000000000000004), "0.3");
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(1.5), "1.5");
        assert_eq!(tick(100.0), "100");
        assert_eq!(tick(0.1234567), "0.123");
        assert_eq!(tick(12.345), "12.3");
    }

    #[test]
    fn log_axis_ticks_label_every_range() {
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12 * y)
        };
        // Within one decade: 1, 2, 5 give fewer than three, so every whole multiple is labelled.
        let (bold, light) = log_ticks(0.0123, 0.097);
        assert!(close(&bold, &[0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09]), "{bold:?}");
        assert_eq!(bold, light);
        // Across decades: 1, 2 and 5 times the powers of ten, light lines at every multiple.
        let (bold, light) = log_ticks(0.014, 1.3);
        assert!(close(&bold, &[0.02, 0.05, 0.1, 0.2, 0.5, 1.0]), "{bold:?}");
        assert_eq!(light.len(), 8 + 9 + 1);
        // The range's ends count when they fall on a tick; an empty or invalid range has none.
        assert!(close(&log_ticks(0.1, 1.0).0, &[0.1, 0.2, 0.5, 1.0]));
        assert!(log_ticks(0.0, 1.0).0.is_empty());
        assert!(log_ticks(1.0, f64::INFINITY).0.is_empty());
    }
}
