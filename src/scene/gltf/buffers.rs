//! A glTF file's buffers and the accessors that read them, checked against the bytes that are
//! really there: every length, offset, stride and count taken from the file is bounded before
//! anything is allocated or indexed, so a hostile file gets an error naming its element.

use std::path::Path;

use base64::Engine;
use glam::Vec3;
use gltf::accessor::{DataType, Dimensions};

use super::Cx;
use crate::scene::SceneError;

/// The largest buffer read, bytes (its declared `byteLength`, or a file or data URI's size).
pub const MAX_BUFFER_BYTES: u64 = 1 << 31;
/// The largest element count of one accessor.
pub const MAX_ACCESSOR_COUNT: usize = 1 << 26;
/// The largest vertex coordinate accepted, metres before scaling (as for OBJ files).
pub const MAX_COORDINATE: f32 = crate::scene::mesh::MAX_OBJ_COORDINATE;

/// Loads every buffer of the document: the GLB binary chunk, a `data:` URI, or a file beside
/// the glTF file. Each is cut to its declared `byteLength`, which must be there.
pub(super) fn load(
    cx: &Cx,
    doc: &gltf::Document,
    mut blob: Option<Vec<u8>>,
    dir: &Path,
    files: &mut Vec<Vec<u8>>,
) -> Result<Vec<Vec<u8>>, SceneError> {
    let mut out = Vec::new();
    for b in doc.buffers() {
        let what = format!("buffers[{}]", b.index());
        let want = b.length() as u64;
        if want > MAX_BUFFER_BYTES {
            return Err(cx.err(&what, format!("byteLength {want} is over the {MAX_BUFFER_BYTES} bytes read")));
        }
        let mut data = match b.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                cx.err(
                    &what,
                    "has no uri and the file has no binary chunk (only the first buffer of a .glb may)",
                )
            })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => data_uri(cx, &what, uri)?,
            gltf::buffer::Source::Uri(uri) => {
                let bytes = external(cx, &what, uri, dir, want)?;
                files.push(bytes.clone());
                bytes
            }
        };
        if (data.len() as u64) < want {
            return Err(
                cx.err(&what, format!("byteLength is {want} but only {} bytes are there", data.len()))
            );
        }
        data.truncate(want as usize);
        out.push(data);
    }
    Ok(out)
}

/// The bytes of a base64 `data:` URI.
fn data_uri(cx: &Cx, what: &str, uri: &str) -> Result<Vec<u8>, SceneError> {
    let (head, payload) = uri.split_once(',').ok_or_else(|| cx.err(what, "a data: URI without a comma"))?;
    if !head.ends_with(";base64") {
        return Err(cx.err(what, "a data: URI that is not base64"));
    }
    if payload.len() as u64 / 4 * 3 > MAX_BUFFER_BYTES {
        return Err(cx.err(what, format!("a data: URI of over {MAX_BUFFER_BYTES} bytes")));
    }
    base64::engine::general_purpose::STANDARD
        .decode(payload)
        .map_err(|e| cx.err(what, format!("the data: URI is not valid base64: {e}")))
}

/// The first `want` bytes of a buffer file named by a relative URI, beside the glTF file.
fn external(cx: &Cx, what: &str, uri: &str, dir: &Path, want: u64) -> Result<Vec<u8>, SceneError> {
    let name = percent_decode(uri)
        .ok_or_else(|| cx.err(what, format!("uri '{uri}' is not valid UTF-8 once decoded")))?;
    if name.contains("://") || name.starts_with('/') || name.starts_with('\\') {
        return Err(cx.err(
            what,
            format!("uri '{uri}': only data: URIs and paths relative to the glTF file are read"),
        ));
    }
    let path = dir.join(&name);
    crate::format::guard::register_input(&path);
    let file = std::fs::File::open(&path)
        .map_err(|e| cx.err(what, format!("cannot open {} (uri '{uri}'): {e}", path.display())))?;
    let have = file.metadata().map(|m| m.len()).unwrap_or(0);
    if have < want {
        return Err(cx.err(what, format!("{} has {have} bytes, byteLength says {want}", path.display())));
    }
    let mut data = Vec::with_capacity(want as usize);
    use std::io::Read;
    file.take(want)
        .read_to_end(&mut data)
        .map_err(|e| cx.err(what, format!("reading {}: {e}", path.display())))?;
    Ok(data)
}

/// `%20` and the like decoded; `None` when the result is not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (b[i], b.get(i + 1).copied().and_then(hex), b.get(i + 2).copied().and_then(hex)) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

/// The bytes of each element of an accessor, checked to lie inside its buffer view and buffer.
fn elements<'b>(
    cx: &Cx,
    acc: &gltf::Accessor,
    buffers: &'b [Vec<u8>],
    size: usize,
) -> Result<impl Iterator<Item = &'b [u8]>, SceneError> {
    let what = format!("accessors[{}]", acc.index());
    if acc.sparse().is_some() {
        return Err(cx.err(&what, "sparse accessors are not read"));
    }
    let count = acc.count();
    if count > MAX_ACCESSOR_COUNT {
        return Err(cx.err(&what, format!("count {count} is over the {MAX_ACCESSOR_COUNT} elements read")));
    }
    let view =
        acc.view().ok_or_else(|| cx.err(&what, "has no bufferView (zero-filled accessors are not read)"))?;
    let vwhat = format!("bufferViews[{}]", view.index());
    let data = buffers
        .get(view.buffer().index())
        .ok_or_else(|| cx.err(&vwhat, format!("buffer {} is missing", view.buffer().index())))?;
    let view_end =
        view.offset().checked_add(view.length()).filter(|&e| e <= data.len()).ok_or_else(|| {
            cx.err(
                &vwhat,
                format!(
                    "bytes {}..+{} lie outside buffers[{}] ({} bytes)",
                    view.offset(),
                    view.length(),
                    view.buffer().index(),
                    data.len()
                ),
            )
        })?;
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(cx.err(&vwhat, format!("byteStride {stride} is less than the element's {size} bytes")));
    }
    let start = view.offset().checked_add(acc.offset());
    let end = match count {
        0 => start,
        n => start.and_then(|s| (n - 1).checked_mul(stride)?.checked_add(s)?.checked_add(size)),
    };
    let (Some(start), Some(end)) = (start, end) else {
        return Err(cx.err(&what, "its byte range overflows"));
    };
    if end > view_end {
        return Err(cx.err(
            &what,
            format!(
                "{count} elements from byte {} run past its bufferView's end ({vwhat}, byte {view_end})",
                acc.offset()
            ),
        ));
    }
    Ok((0..count).map(move |i| &data[start + i * stride..start + i * stride + size]))
}

/// A `VEC3` `FLOAT` accessor (positions, normals), every component finite and at most
/// [`MAX_COORDINATE`] in size.
pub(super) fn vec3s(cx: &Cx, acc: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<Vec3>, SceneError> {
    let what = format!("accessors[{}]", acc.index());
    if acc.dimensions() != Dimensions::Vec3 || acc.data_type() != DataType::F32 {
        return Err(cx.err(
            &what,
            format!("needs VEC3 of FLOAT, found {:?} of {:?}", acc.dimensions(), acc.data_type()),
        ));
    }
    let f = |b: &[u8], k: usize| f32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
    // Bounded by the bytes there: elements() has checked the count against its buffer view.
    let elems = elements(cx, acc, buffers, 12)?;
    let mut out = Vec::with_capacity(acc.count());
    for (i, b) in elems.enumerate() {
        let v = Vec3::new(f(b, 0), f(b, 1), f(b, 2));
        if !v.is_finite() || v.abs().max_element() > MAX_COORDINATE {
            return Err(cx.err(
                &what,
                format!("element {i} is {v}: needs finite values of at most {MAX_COORDINATE:e}"),
            ));
        }
        out.push(v);
    }
    Ok(out)
}

/// A `SCALAR` accessor of unsigned bytes, shorts or ints (triangle indices).
pub(super) fn indices(cx: &Cx, acc: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<u32>, SceneError> {
    let what = format!("accessors[{}]", acc.index());
    let size = match acc.data_type() {
        DataType::U8 => 1,
        DataType::U16 => 2,
        DataType::U32 => 4,
        t => return Err(cx.err(&what, format!("indices need an unsigned integer type, found {t:?}"))),
    };
    if acc.dimensions() != Dimensions::Scalar {
        return Err(cx.err(&what, format!("indices need SCALAR, found {:?}", acc.dimensions())));
    }
    Ok(elements(cx, acc, buffers, size)?
        .map(|b| match b.len() {
            1 => b[0] as u32,
            2 => u16::from_le_bytes([b[0], b[1]]) as u32,
            _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_escapes_are_decoded() {
        assert_eq!(percent_decode("my%20scene.bin").as_deref(), Some("my scene.bin"));
        assert_eq!(percent_decode("100%").as_deref(), Some("100%"));
        assert_eq!(percent_decode("%ff"), None);
    }
}
