//! Images and their files: linear float RGB to OpenEXR (ZIP compression), an sRGB PNG
//! preview, and reading an EXR back (the reference renderer resumes from one).
//!
//! Files are written to a temporary file beside the target and renamed into place only when
//! complete, so a failed run never leaves a damaged or partial image. The same image and notes
//! give the same bytes in every run (the EXR header's notes in the order given).

use std::path::{Path, PathBuf};

use exr::prelude::traits::*;
use exr::prelude::{AttributeValue, Encoding, Layer, LayerAttributes, SpecificChannels, Text, Vec2};
use glam::Vec3;

use super::RenderError;
// exr's image type, renamed: `Image` here is ours.
use exr::image::Image as Image_;

/// Largest image side accepted, pixels.
pub const MAX_SIDE: u32 = 1 << 15;
/// Largest image accepted, pixels (768 MiB of linear RGB).
pub const MAX_PIXELS: u64 = 1 << 26;

/// A linear RGB image, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Linear RGB, row-major from the top-left (index `y * width + x`); units as the render
    /// mode says ([`super::Mode::unit`]).
    pub pixels: Vec<Vec3>,
    /// The pixels the automatic exposure meters, when not all: a render with a background
    /// meters those that see a surface, so the sky does not set the exposure of the caustics.
    pub metered: Option<Vec<bool>>,
    /// Each pixel's samples (`spp` per pixel, pixel-major), when kept: the preview then tone-maps
    /// every sample before averaging, so a pixel half in a beam too bright for the display is
    /// half bright, not white (an edge anti-aliased after the clipping, not before).
    pub samples: Option<(u32, Vec<Vec3>)>,
}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            pixels: vec![Vec3::ZERO; width as usize * height as usize],
            metered: None,
            samples: None,
        }
    }

    /// The pixel at column `x`, row `y` (from the top).
    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// Mean of every pixel.
    pub fn mean(&self) -> Vec3 {
        let s: glam::DVec3 = self.pixels.iter().map(|p| p.as_dvec3()).sum();
        (s / self.pixels.len().max(1) as f64).as_vec3()
    }
}

/// Text attributes stored in the EXR header (units, estimator, …), as (name, value), written
/// in this order.
pub type Notes = Vec<(String, String)>;

fn image_err(path: &Path, message: impl std::fmt::Display) -> RenderError {
    RenderError::Image { file: path.display().to_string(), message: message.to_string() }
}

/// A temporary file beside `path` ([`crate::format::temp_beside`]).
fn temp_beside(path: &Path) -> Result<tempfile::NamedTempFile, RenderError> {
    crate::format::temp_beside(path, ".photonkit-")
        .map_err(|source| RenderError::Io { file: path.display().to_string(), source })
}

/// The EXR bytes of `img` in a temporary file beside `path`, not yet renamed.
fn exr_temp(path: &Path, img: &Image, notes: &Notes) -> Result<tempfile::NamedTempFile, RenderError> {
    let mut tmp = temp_beside(path)?;
    let w = img.width as usize;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = img.pixels[y * w + x];
        (p.x, p.y, p.z)
    });
    let mut attrs = LayerAttributes { software_name: Some(Text::from("photonkit")), ..Default::default() };
    // Header text is written as UTF-8 bytes, as OpenEXR's own readers expect (the exr crate's
    // `Text::from` takes Latin-1 and panics on any other character).
    let utf8 = |s: &str| Text::from_slice_unchecked(s.as_bytes());
    for (k, v) in notes {
        attrs.other.insert(utf8(k), AttributeValue::Text(utf8(v)));
    }
    let layer = Layer::new((w, img.height as usize), attrs, Encoding::SMALL_LOSSLESS, channels);
    let file = tmp.as_file_mut();
    Image_::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(std::io::BufWriter::new(&mut *file))
        .map_err(|e| image_err(path, e))?;
    order_notes(file, notes).map_err(|e| image_err(path, e))?;
    Ok(tmp)
}

/// Puts the header attributes holding `notes` in the order of `notes`, in place, so that the
/// same image gives the same bytes in every run. The exr crate keeps custom attributes in a
/// `HashMap` (`LayerAttributes::other`, with the standard library's randomly seeded hasher)
/// and writes them in its iteration order; it offers no ordered alternative. Only the order of
/// the attribute records changes, not the header's length, so the chunk offsets after it stay
/// valid.
fn order_notes(file: &mut std::fs::File, notes: &Notes) -> std::io::Result<()> {
    use std::io::{BufRead, BufReader, Read, Seek, SeekFrom, Write};
    let invalid = |m: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string());
    file.seek(SeekFrom::Start(0))?;
    let mut r = BufReader::new(&mut *file);
    let mut start = [0u8; 8];
    r.read_exact(&mut start)?;
    // The magic number, then the version field, whose bit 12 marks a multi-part file (a header
    // per part); one layer is written as a single part.
    let flags = u32::from_le_bytes([start[4], start[5], start[6], start[7]]);
    if start[..4] != [0x76, 0x2f, 0x31, 0x01] || flags & 0x1000 != 0 {
        return Err(invalid("not a single-part OpenEXR file"));
    }
    // Each attribute is `name\0type\0`, its size (i32, little-endian) and its value; an empty
    // name ends the header. Per record: the note's index (`None`: not a note) and its bytes.
    let mut records: Vec<(Option<usize>, Vec<u8>)> = Vec::new();
    loop {
        let mut record = Vec::new();
        r.read_until(0, &mut record)?;
        if record == [0] {
            break;
        }
        let name_len = record.len().saturating_sub(1);
        r.read_until(0, &mut record)?;
        if record.last() != Some(&0) || record.len() == name_len + 1 {
            return Err(invalid("truncated header"));
        }
        let mut size = [0u8; 4];
        r.read_exact(&mut size)?;
        record.extend_from_slice(&size);
        let size = u64::try_from(i32::from_le_bytes(size)).map_err(|_| invalid("negative attribute size"))?;
        if (&mut r).take(size).read_to_end(&mut record)? as u64 != size {
            return Err(invalid("truncated attribute"));
        }
        let note = notes.iter().position(|(k, _)| k.as_bytes() == &record[..name_len]);
        records.push((note, record));
    }
    drop(r);
    let mut in_order: Vec<&(Option<usize>, Vec<u8>)> = records.iter().filter(|(n, _)| n.is_some()).collect();
    in_order.sort_by_key(|(n, _)| *n);
    let mut next = in_order.into_iter();
    let mut header = Vec::new();
    for (note, record) in &records {
        let record = match note {
            Some(_) => &next.next().expect("as many notes as slots").1,
            None => record,
        };
        header.extend_from_slice(record);
    }
    file.seek(SeekFrom::Start(start.len() as u64))?;
    file.write_all(&header)
}

/// An 8-bit sRGB PNG preview of `img`, tone-mapped ([`super::tone`]), in a temporary file.
fn png_temp(path: &Path, img: &Image, out: &Outputs) -> Result<tempfile::NamedTempFile, RenderError> {
    let tmp = temp_beside(path)?;
    let data: Vec<u8> = if out.codes {
        let scale = out.exposure.exp2();
        img.pixels.iter().flat_map(|p| (*p * scale).to_array().map(srgb8)).collect()
    } else {
        let scale = out.preview_stops(img).exp2();
        let tone = |p: Vec3| super::tone::tone_map(p, scale);
        match &img.samples {
            Some((spp, s)) if *spp > 0 && s.len() == img.pixels.len() * *spp as usize => s
                .chunks_exact(*spp as usize)
                .flat_map(|px| {
                    (px.iter().map(|&v| tone(v)).sum::<Vec3>() / *spp as f32).to_array().map(srgb8)
                })
                .collect(),
            _ => img.pixels.iter().flat_map(|p| tone(*p).to_array().map(srgb8)).collect(),
        }
    };
    let mut enc = png::Encoder::new(std::io::BufWriter::new(tmp.as_file()), img.width, img.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    let mut w = enc.write_header().map_err(|e| image_err(path, e))?;
    w.write_image_data(&data).map_err(|e| image_err(path, e))?;
    w.finish().map_err(|e| image_err(path, e))?;
    Ok(tmp)
}

/// Linear value to an 8-bit sRGB code (IEC 61966-2-1 transfer curve), clamped to [0, 1].
pub fn srgb8(v: f32) -> u8 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

/// Where the outputs go: an EXR and/or a PNG preview.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Outputs {
    /// The linear float RGB image (OpenEXR, ZIP compression), with the header notes.
    pub exr: Option<PathBuf>,
    /// The 8-bit sRGB preview, exposed and tone-mapped.
    pub png: Option<PathBuf>,
    /// The preview's exposure in stops: added to the automatic exposure, or with
    /// `fixed_exposure` the whole of it (pixel values multiplied by 2^exposure).
    pub exposure: f32,
    /// Whether `exposure` is absolute rather than an offset from [`super::tone::auto_exposure`].
    pub fixed_exposure: bool,
    /// Colour codes rather than radiance (diagnostic views): the preview shows the values as
    /// they are (times 2^exposure), without automatic exposure or the shoulder.
    pub codes: bool,
}

impl Outputs {
    /// `out.exr` with its preview `out.png` beside it, automatically exposed.
    pub fn beside(exr: &Path) -> Outputs {
        Outputs { exr: Some(exr.to_path_buf()), png: Some(exr.with_extension("png")), ..Outputs::default() }
    }

    /// The preview's exposure of `img`, in stops.
    pub fn preview_stops(&self, img: &Image) -> f32 {
        if self.fixed_exposure { self.exposure } else { super::tone::auto_exposure(img) + self.exposure }
    }
}

/// Writes every requested file; none is renamed into place unless all were written.
pub fn write(img: &Image, out: &Outputs, notes: &Notes) -> Result<(), RenderError> {
    let exr = match &out.exr {
        Some(p) => Some((p, exr_temp(p, img, notes)?)),
        None => None,
    };
    let png = match &out.png {
        Some(p) => Some((p, png_temp(p, img, out)?)),
        None => None,
    };
    let mut done: Vec<&PathBuf> = Vec::new();
    for (p, tmp) in exr.into_iter().chain(png) {
        if let Err(e) = crate::format::persist(tmp, p) {
            // Leave no half-written set: remove what this call already put in place.
            for d in done {
                let _ = std::fs::remove_file(d);
            }
            return Err(RenderError::Io { file: p.display().to_string(), source: e });
        }
        done.push(p);
    }
    Ok(())
}

/// Reads the first RGB(A) layer of an EXR file as linear RGB, with its text attributes.
pub fn read_exr(path: &Path) -> Result<(Image, Notes), RenderError> {
    // The header first: refuse sizes beyond the caps before anything is allocated for them.
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| image_err(path, e))?;
    for h in &meta.headers {
        let (w, hh) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
        if w > MAX_SIDE as u64 || hh > MAX_SIDE as u64 || w * hh > MAX_PIXELS {
            return Err(image_err(path, format!("a {w}×{hh} layer exceeds the size limits")));
        }
    }
    let img = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size, _| Image::new(size.0 as u32, size.1 as u32),
            |img: &mut Image, pos, (r, g, b): (f32, f32, f32)| {
                let w = img.width as usize;
                img.pixels[pos.1 * w + pos.0] = Vec3::new(r, g, b);
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| image_err(path, e))?;
    let notes = img
        .layer_data
        .attributes
        .other
        .iter()
        .filter_map(|(k, v)| match v {
            AttributeValue::Text(t) => Some((
                String::from_utf8_lossy(k.as_slice()).into_owned(),
                String::from_utf8_lossy(t.as_slice()).into_owned(),
            )),
            _ => None,
        })
        .collect();
    Ok((img.layer_data.channel_data.pixels, notes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_reads_back_bit_for_bit_with_its_notes() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Image::new(37, 21);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = Vec3::new(i as f32 * 0.001, 1e-7 * i as f32, 123.456 + i as f32);
        }
        img.pixels[5] = Vec3::new(1e30, 0.0, f32::MIN_POSITIVE);
        let out = Outputs::beside(&dir.path().join("a.exr"));
        let notes = vec![("photonkit:units".to_string(), "W/(m^2 sr)".to_string())];
        write(&img, &out, &notes).unwrap();
        let (back, back_notes) = read_exr(&dir.path().join("a.exr")).unwrap();
        assert_eq!(back, img);
        assert!(back_notes.contains(&notes[0]), "{back_notes:?}");
        // The preview is a valid PNG of the same size, and nothing else is left behind.
        let dec = png::Decoder::new(std::io::BufReader::new(
            std::fs::File::open(dir.path().join("a.png")).unwrap(),
        ));
        let r = dec.read_info().unwrap();
        assert_eq!((r.info().width, r.info().height), (37, 21));
        let mut names: Vec<_> =
            std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        names.sort();
        assert_eq!(names, ["a.exr", "a.png"]);
    }

    /// Issue 29 item 3: a pixel whose two samples are a beam far too bright for the display
    /// and darkness is shown half bright when each sample is tone-mapped first (the shoulder
    /// maps the bright one to 1: (1 + 0)/2 = ½, sRGB code 188), where tone-mapping the mean
    /// clips it to white (255); without kept samples the mean is used.
    #[test]
    fn the_preview_tone_maps_each_sample_before_averaging() {
        let dir = tempfile::tempdir().unwrap();
        let bright = Vec3::splat(1e4);
        let mut img = Image::new(1, 1);
        img.pixels[0] = bright / 2.0;
        let out = Outputs { png: Some(dir.path().join("a.png")), fixed_exposure: true, ..Outputs::default() };
        let code = |img: &Image| {
            write(img, &out, &Vec::new()).unwrap();
            let dec = png::Decoder::new(std::io::BufReader::new(
                std::fs::File::open(dir.path().join("a.png")).unwrap(),
            ));
            let mut r = dec.read_info().unwrap();
            let mut buf = vec![0; r.output_buffer_size().unwrap()];
            r.next_frame(&mut buf).unwrap();
            buf[0]
        };
        assert_eq!(code(&img), 255);
        img.samples = Some((2, vec![bright, Vec3::ZERO]));
        assert_eq!(code(&img), srgb8(0.5));
        assert_eq!(srgb8(0.5), 188);
    }

    /// The same image and notes give the same EXR bytes on every write, the notes in the
    /// header in the order given (the exr crate alone writes them in its hash map's order,
    /// which changes from one map to the next, so from one run to the next).
    #[test]
    fn exr_bytes_do_not_depend_on_the_run() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Image::new(7, 5);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = Vec3::new(i as f32, 0.5, 1e-3 * i as f32);
        }
        let notes: Notes = (0..8).map(|i| (format!("photonkit:note{i}"), "é".repeat(i))).collect();
        let bytes = |name: &str| {
            let out = Outputs { exr: Some(dir.path().join(name)), ..Outputs::default() };
            write(&img, &out, &notes).unwrap();
            std::fs::read(dir.path().join(name)).unwrap()
        };
        let first = bytes("0.exr");
        for i in 1..4 {
            assert!(bytes(&format!("{i}.exr")) == first, "write {i} differs from the first");
        }
        let at = |name: &str| {
            let key = format!("{name}\0string\0");
            first.windows(key.len()).position(|w| w == key.as_bytes()).expect("the note is in the header")
        };
        let order: Vec<usize> = notes.iter().map(|(k, _)| at(k)).collect();
        assert!(order.is_sorted(), "notes at {order:?}");
        let (back, mut back_notes) = read_exr(&dir.path().join("0.exr")).unwrap();
        assert_eq!(back, img);
        back_notes.sort();
        assert_eq!(back_notes, notes);
    }

    #[test]
    fn srgb_curve_end_points() {
        assert_eq!(srgb8(0.0), 0);
        assert_eq!(srgb8(1.0), 255);
        assert_eq!(srgb8(7.0), 255);
        assert_eq!(srgb8(f32::NAN), 0);
        // Linear 0.2159 is sRGB 128/255; 0.0031308 is where the curve turns from linear.
        assert_eq!(srgb8(0.2159), 128);
        assert_eq!(srgb8(0.003_130_8), 10);
    }

    #[test]
    fn a_failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let img = Image::new(4, 4);
        let out = Outputs {
            exr: Some(dir.path().join("ok.exr")),
            png: Some(dir.path().join("missing-dir").join("x.png")),
            ..Outputs::default()
        };
        assert!(write(&img, &out, &Vec::new()).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
