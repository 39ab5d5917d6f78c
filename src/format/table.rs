//! Photon maps in memory: a borrowed view every stage reads, and a column table every stage
//! returns.
//!
//! A stage reads photons through a [`MapView`], which a memory-mapped [`PhotonMap`] and an
//! in-memory [`PhotonTable`] both provide, and returns its result as a [`PhotonTable`]: the
//! header it would write and its columns, those it passes on unchanged borrowed from its input
//! (no copy) and those it computed owned. Writing the table to a file is the caller's choice
//! ([`PhotonTable::write`]), so stages chain in memory (the library's pipeline, Python) or
//! through files (the command line) alike.

use super::columns::{Element, name};
use super::meta::MapInfo;
use super::reader::PhotonMap;
use super::writer::Output;
use super::{ColumnSpec, FormatError, Result};

/// A read-only view of a photon map's header and columns, wherever they live.
///
/// ```
/// use photonkit::format::{PhotonMap, name};
///
/// let map = PhotonMap::open("samples/dispersed-beam.phm")?;
/// let view = map.view();
/// // Columns are viewed in place, typed; an absent column is `None`.
/// let params = view.column_bytes(name::PARAMS).map(|b| b.len() / 4);
/// assert_eq!(params, Some(3 * view.len()));
/// assert!(view.column::<f32>(name::LAMBDA2)?.is_none());
/// let watts: f32 = view.flux().iter().map(|f| f[0] + f[1] + f[2]).sum();
/// assert!((watts - 10.08).abs() < 0.01);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct MapView<'a> {
    file: &'a str,
    info: &'a MapInfo,
    columns: Vec<(ColumnSpec, &'a [u8])>,
    len: usize,
    /// The pages of the file the columns are read from, when they are a mapped file's.
    pages: super::Pages<'a>,
}

impl<'a> MapView<'a> {
    /// The name used in messages: the path, `<stdin>`, or what an in-memory table was named.
    pub fn file_name(&self) -> &'a str {
        self.file
    }

    /// The header a stage carries into its output (emitters, units, state, history).
    pub fn info(&self) -> &'a MapInfo {
        self.info
    }

    /// Number of photons.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the map has no photons.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The type and shape of a column, if the map has it.
    pub fn spec(&self, column: &str) -> Option<&ColumnSpec> {
        self.columns.iter().find(|(s, _)| s.name == column).map(|(s, _)| s)
    }

    /// The raw little-endian bytes of a column, if the map has it.
    pub fn column_bytes(&self, column: &str) -> Option<&'a [u8]> {
        self.columns.iter().find(|(s, _)| s.name == column).map(|(_, b)| *b)
    }

    /// Every column's spec and bytes, in order: what a stage passes on unchanged.
    pub fn columns(&self) -> &[(ColumnSpec, &'a [u8])] {
        &self.columns
    }

    /// A typed, zero-copy view of a column; `Ok(None)` if absent, an error if its type differs.
    pub fn column<T: Element>(&self, column: &str) -> Result<Option<&'a [T]>> {
        let Some((spec, bytes)) = self.columns.iter().find(|(s, _)| s.name == column) else {
            return Ok(None);
        };
        typed(self.file, spec, bytes).map(Some)
    }

    /// Photon positions (present and f32×3 in every view: see [`MapView`]'s constructors).
    pub fn positions(&self) -> &'a [[f32; 3]] {
        self.column(name::POSITION).ok().flatten().expect("a view has positions")
    }

    /// Photon flux in watts per RGB channel (present and f32×3 in every view).
    pub fn flux(&self) -> &'a [[f32; 3]] {
        self.column(name::FLUX).ok().flatten().expect("a view has flux")
    }

    /// [`super::PhotonMap::release_pages`] of the file this view reads, if it is a mapped
    /// file (nothing for a table in memory).
    pub fn release_pages(&self) {
        self.pages.release();
    }

    /// The pages of the file this view reads, to release later ([`Self::release_pages`]).
    pub fn pages(&self) -> super::Pages<'a> {
        self.pages
    }
}

fn typed<'a, T: Element>(file: &str, spec: &ColumnSpec, bytes: &'a [u8]) -> Result<&'a [T]> {
    let err =
        |message: String| FormatError::Column { file: file.to_string(), column: spec.name.clone(), message };
    if spec.dtype != T::DTYPE || spec.components != T::COMPONENTS {
        return Err(err(format!(
            "is {}×{}, expected {}×{}",
            spec.dtype.name(),
            spec.components,
            T::DTYPE.name(),
            T::COMPONENTS
        )));
    }
    bytemuck::try_cast_slice(bytes).map_err(|e| err(format!("can not be viewed in place: {e}")))
}

impl PhotonMap {
    /// The map as a [`MapView`] (its columns viewed in place).
    pub fn view(&self) -> MapView<'_> {
        MapView {
            file: self.file_name(),
            info: self.info(),
            columns: self.columns(),
            len: self.len(),
            pages: self.pages(),
        }
    }
}

/// A column's bytes: borrowed from a stage's input, computed and owned (in u64 words, so
/// every column can be viewed as any element type), or a stage's own vector of its element
/// type, moved in without a copy ([`PhotonTable::set_vec`]).
#[derive(Clone, Debug)]
enum Bytes<'a> {
    Borrowed(&'a [u8]),
    Owned { words: Vec<u64>, len: usize },
    Moved(std::sync::Arc<dyn ColumnVec>),
}

/// A vector of a column's elements, seen as bytes.
trait ColumnVec: std::fmt::Debug + Send + Sync {
    fn bytes(&self) -> &[u8];
}

impl<T: bytemuck::Pod + std::fmt::Debug + Send + Sync> ColumnVec for Vec<T> {
    fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(self)
    }
}

impl Bytes<'_> {
    fn of<T: bytemuck::Pod>(values: &[T]) -> Bytes<'static> {
        let bytes: &[u8] = bytemuck::cast_slice(values);
        let mut words = vec![0u64; bytes.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Bytes::Owned { words, len: bytes.len() }
    }

    fn get(&self) -> &[u8] {
        match self {
            Bytes::Borrowed(b) => b,
            Bytes::Owned { words, len } => &bytemuck::cast_slice(words)[..*len],
            Bytes::Moved(v) => v.bytes(),
        }
    }
}

/// A photon map held in memory: the header a stage would write ([`MapInfo`]) and its columns,
/// each either borrowed from the stage's input or owned. It always holds `position` and
/// `flux` (f32×3), and every column holds one element per photon.
#[derive(Clone, Debug)]
pub struct PhotonTable<'a> {
    file: String,
    /// The header the map will be written with.
    pub info: MapInfo,
    columns: Vec<(ColumnSpec, Bytes<'a>)>,
    len: usize,
    /// The pages of the file borrowed columns may come from, released as the table is written.
    pages: super::Pages<'a>,
}

impl<'a> PhotonTable<'a> {
    /// A table of `positions` and `flux` (one per photon); `file` names it in messages.
    pub fn new(file: &str, info: MapInfo, positions: &[[f32; 3]], flux: &[[f32; 3]]) -> Result<Self> {
        if positions.len() != flux.len() {
            return Err(FormatError::Invalid {
                file: file.to_string(),
                message: format!("{} positions but {} flux values", positions.len(), flux.len()),
            });
        }
        let mut t = PhotonTable {
            file: file.to_string(),
            info,
            columns: Vec::new(),
            len: positions.len(),
            pages: Default::default(),
        };
        t.set(name::POSITION, positions)?;
        t.set(name::FLUX, flux)?;
        Ok(t)
    }

    /// A table borrowing `columns` (one element per photon each; `position` and `flux` among
    /// them as f32×3), as a tracer outside photonkit or a test hands photons in.
    pub fn from_columns(file: &str, info: MapInfo, columns: &[(ColumnSpec, &'a [u8])]) -> Result<Self> {
        let invalid = |message: String| FormatError::Invalid { file: file.to_string(), message };
        let len = columns
            .iter()
            .find(|(s, _)| s.name == name::POSITION)
            .map(|(s, b)| b.len() / s.stride().max(1) as usize)
            .ok_or_else(|| invalid("no position column".into()))?;
        let mut t =
            PhotonTable { file: file.to_string(), info, columns: Vec::new(), len, pages: Default::default() };
        for (spec, bytes) in columns {
            t.set_bytes(spec.clone(), Bytes::Borrowed(bytes))?;
        }
        for required in [name::POSITION, name::FLUX] {
            match t.columns.iter().find(|(s, _)| s.name == required) {
                Some((s, _)) if *s == ColumnSpec::of::<[f32; 3]>(required) => {}
                Some(_) => return Err(invalid(format!("column '{required}' must be f32×3"))),
                None => return Err(invalid(format!("no {required} column"))),
            }
        }
        Ok(t)
    }

    /// Every column of `view` (borrowed, not copied) under the header `info`.
    pub fn carrying(view: &MapView<'a>, info: MapInfo) -> Self {
        PhotonTable {
            file: view.file_name().to_string(),
            info,
            columns: view.columns().iter().map(|(s, b)| (s.clone(), Bytes::Borrowed(b))).collect(),
            len: view.len(),
            pages: view.pages,
        }
    }

    /// Every column of `view` followed by `extra` more photons: `appended[c]` holds their bytes
    /// of `view`'s column c (owned, so the table copies the map's columns once).
    pub fn carrying_appended(
        view: &MapView<'a>,
        info: MapInfo,
        extra: usize,
        appended: &[Vec<u8>],
    ) -> Result<PhotonTable<'static>> {
        let invalid = |message: String| FormatError::Invalid { file: view.file_name().to_string(), message };
        if appended.len() != view.columns().len() {
            return Err(invalid(format!("{} appended columns for {}", appended.len(), view.columns().len())));
        }
        let mut columns = Vec::with_capacity(appended.len());
        for ((spec, bytes), more) in view.columns().iter().zip(appended) {
            if more.len() as u64 != extra as u64 * spec.stride() {
                return Err(invalid(format!(
                    "column '{}': {} bytes appended for {extra} photons",
                    spec.name,
                    more.len()
                )));
            }
            columns.push((spec.clone(), Bytes::of(&[*bytes, more.as_slice()].concat())));
        }
        Ok(PhotonTable {
            file: view.file_name().to_string(),
            info,
            columns,
            len: view.len() + extra,
            pages: Default::default(),
        })
    }

    /// Number of photons.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the table has no photons.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Sets column `column` to `values` (one per photon): in its place if the table has it,
    /// else after the others.
    pub fn set<T: Element>(&mut self, column: &str, values: &[T]) -> Result<()> {
        self.set_bytes(ColumnSpec::of::<T>(column), Bytes::of(values))
    }

    /// [`Self::set`] taking the values' vector, which the table keeps as the column (no copy:
    /// a stage that hands over its results does not hold them twice while the map is written).
    pub fn set_vec<T: Element + std::fmt::Debug + Send + Sync>(
        &mut self,
        column: &str,
        values: Vec<T>,
    ) -> Result<()> {
        self.set_bytes(ColumnSpec::of::<T>(column), Bytes::Moved(std::sync::Arc::new(values)))
    }

    /// [`Self::set`] for a column of `components` elements per photon given flat.
    pub fn set_flat<T: Element>(&mut self, column: &str, components: u32, values: &[T]) -> Result<()> {
        if T::COMPONENTS != 1 {
            return Err(self.invalid(format!("column '{column}': give flat values")));
        }
        self.set_bytes(ColumnSpec::new(column, T::DTYPE, components), Bytes::of(values))
    }

    fn set_bytes(&mut self, spec: ColumnSpec, bytes: Bytes<'a>) -> Result<()> {
        let want = self.len as u64 * spec.stride();
        if bytes.get().len() as u64 != want {
            return Err(self.invalid(format!(
                "column '{}' holds {} bytes, expected {want} ({} photons × {} bytes)",
                spec.name,
                bytes.get().len(),
                self.len,
                spec.stride()
            )));
        }
        match self.columns.iter_mut().find(|(s, _)| s.name == spec.name) {
            Some(slot) => {
                // A column passed on keeps its table entry's unknown keys.
                let extra = std::mem::take(&mut slot.0.extra);
                *slot = (ColumnSpec { extra, ..spec }, bytes);
            }
            None => self.columns.push((spec, bytes)),
        }
        Ok(())
    }

    /// Drops column `column` if present (`position` and `flux` stay: every map has them).
    pub fn remove(&mut self, column: &str) {
        if column != name::POSITION && column != name::FLUX {
            self.columns.retain(|(s, _)| s.name != column);
        }
    }

    fn invalid(&self, message: String) -> FormatError {
        FormatError::Invalid { file: self.file.clone(), message }
    }

    /// The table as a [`MapView`], for the next stage.
    pub fn view(&self) -> MapView<'_> {
        MapView {
            file: &self.file,
            info: &self.info,
            columns: self.columns.iter().map(|(s, b)| (s.clone(), b.get())).collect(),
            len: self.len,
            pages: Default::default(),
        }
    }

    /// The same table owning every column (so its input may be dropped).
    pub fn into_owned(self) -> PhotonTable<'static> {
        PhotonTable {
            file: self.file,
            info: self.info,
            columns: self
                .columns
                .into_iter()
                .map(|(s, b)| {
                    let b = match b {
                        Bytes::Borrowed(b) => Bytes::of(b),
                        Bytes::Owned { words, len } => Bytes::Owned { words, len },
                        Bytes::Moved(v) => Bytes::Moved(v),
                    };
                    (s, b)
                })
                .collect(),
            len: self.len,
            pages: Default::default(),
        }
    }

    /// Writes the table as a PHM file (or to standard output): see [`super::write_map`].
    pub fn write(&self, target: Output) -> Result<()> {
        let columns: Vec<(ColumnSpec, &[u8])> =
            self.columns.iter().map(|(s, b)| (s.clone(), b.get())).collect();
        super::writer::write_map_releasing(target, self.info.clone(), &columns, self.pages)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::State;

    fn table() -> PhotonTable<'static> {
        let info = MapInfo::new(vec![crate::synthetic::collimated_emitter(0, 1.0)], State::Traced);
        let pos = [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]];
        PhotonTable::new("t", info, &pos, &[[1.0; 3], [2.0; 3]]).unwrap()
    }

    /// Rows gathered from a mapped file in blocks (each block's pages released once copied)
    /// are the rows a plain indexing gives, for one element a row and for several, for no
    /// index, a few, most and every one.
    #[test]
    fn gathered_rows_are_the_indexed_rows() {
        let n = 30_000usize;
        let info = MapInfo::new(vec![crate::synthetic::collimated_emitter(0, 1.0)], State::Traced);
        let pos: Vec<[f32; 3]> = (0..n).map(|i| [i as f32, (i * 7 % 13) as f32, -(i as f32)]).collect();
        let mut t = PhotonTable::new("t", info, &pos, &vec![[1.0; 3]; n]).unwrap();
        let rows: Vec<f32> = (0..2 * n).map(|k| k as f32 * 0.5).collect();
        t.set_flat("test_rows", 2, &rows).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.phm");
        t.write(Output::Path(path.clone())).unwrap();
        let map = PhotonMap::open_path(&path).unwrap();
        let v = map.view();
        let pages = v.pages();
        let column: &[f32] = bytemuck::cast_slice(v.column_bytes("test_rows").unwrap());
        for every in [usize::MAX, 997, 3, 1] {
            let idx: Vec<u32> = (0..n as u32)
                .filter(|&i| every != usize::MAX && (i as usize).is_multiple_of(every))
                .collect();
            let want_pos: Vec<[f32; 3]> = idx.iter().map(|&i| pos[i as usize]).collect();
            let want_rows: Vec<f32> =
                idx.iter().flat_map(|&i| [rows[2 * i as usize], rows[2 * i as usize + 1]]).collect();
            assert_eq!(pages.gather(v.positions(), &idx), want_pos, "every {every}");
            assert_eq!(pages.gather_rows(column, 2, &idx), want_rows, "every {every}");
        }
    }

    /// A table written and read back is the same map, and a stage's table carried from the
    /// read map borrows its columns, replaces one in place and appends another.
    #[test]
    fn a_table_round_trips_through_a_file_and_carries_columns() {
        let mut t = table();
        t.set(name::NORMAL, &[[0.0f32, 0.0, 1.0]; 2]).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.phm");
        t.write(Output::Path(path.clone())).unwrap();
        let map = PhotonMap::open_path(&path).unwrap();
        let v = map.view();
        assert_eq!(v.positions(), t.view().positions());
        assert_eq!(v.flux(), [[1.0; 3], [2.0; 3]]);
        assert_eq!(v.column::<[f32; 3]>(name::NORMAL).unwrap().unwrap(), [[0.0, 0.0, 1.0]; 2]);
        assert!(v.column::<f32>(name::NORMAL).is_err());

        let mut next = PhotonTable::carrying(&v, v.info().clone());
        next.set(name::POSITION, &[[9.0f32; 3]; 2]).unwrap();
        next.set(name::LAMBDA2, &[0.5f32; 2]).unwrap();
        let nv = next.view();
        let names: Vec<&str> = nv.columns().iter().map(|(s, _)| s.name.as_str()).collect();
        assert_eq!(names, [name::POSITION, name::FLUX, name::NORMAL, name::LAMBDA2]);
        assert_eq!(nv.positions(), [[9.0; 3]; 2]);
        drop(nv);
        // The normal column is the map's own bytes, not a copy.
        assert_eq!(
            next.view().column_bytes(name::NORMAL).unwrap().as_ptr(),
            v.column_bytes(name::NORMAL).unwrap().as_ptr()
        );
        let owned = next.into_owned();
        drop(map);
        assert_eq!(owned.view().column::<f32>(name::LAMBDA2).unwrap().unwrap(), [0.5, 0.5]);
    }

    /// A vector handed to the table becomes the column itself (no copy): the table views the
    /// vector's own buffer, writes it like any column, refuses a wrong length, and keeps it
    /// when made owned.
    #[test]
    fn a_moved_column_is_the_vector_itself() {
        let mut t = table();
        let basis = vec![[1.0f32, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let at = basis.as_ptr() as *const u8;
        t.set_vec(name::BASIS_U, basis).unwrap();
        assert_eq!(t.view().column_bytes(name::BASIS_U).unwrap().as_ptr(), at);
        assert!(t.set_vec(name::LAMBDA2, vec![0.5f32; 3]).is_err());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.phm");
        t.write(Output::Path(path.clone())).unwrap();
        let map = PhotonMap::open_path(&path).unwrap();
        assert_eq!(
            map.view().column::<[f32; 3]>(name::BASIS_U).unwrap().unwrap(),
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
        );
        let owned = t.into_owned();
        assert_eq!(owned.view().column_bytes(name::BASIS_U).unwrap().as_ptr(), at);
    }

    #[test]
    fn a_table_from_columns_needs_positions_and_flux_of_one_length() {
        let info = || MapInfo::new(vec![], State::Traced);
        let pos = [[0.0f32; 3]; 4];
        let flux = [[1.0f32; 3]; 4];
        let short = [[1.0f32; 3]; 3];
        let col = |n: &str, v: &'static [[f32; 3]]| {
            (ColumnSpec::of::<[f32; 3]>(n), bytemuck::cast_slice::<_, u8>(v))
        };
        let pos: &'static [[f32; 3]] = Box::leak(Box::new(pos));
        let flux: &'static [[f32; 3]] = Box::leak(Box::new(flux));
        let short: &'static [[f32; 3]] = Box::leak(Box::new(short));
        let t = PhotonTable::from_columns("t", info(), &[col(name::POSITION, pos), col(name::FLUX, flux)])
            .unwrap();
        assert_eq!(t.len(), 4);
        assert!(PhotonTable::from_columns("t", info(), &[col(name::POSITION, pos)]).is_err());
        assert!(PhotonTable::from_columns("t", info(), &[col(name::FLUX, flux)]).is_err());
        let e = PhotonTable::from_columns("t", info(), &[col(name::POSITION, pos), col(name::FLUX, short)]);
        assert!(e.unwrap_err().to_string().contains("flux"));
    }

    #[test]
    fn a_column_of_the_wrong_length_is_refused() {
        let mut t = table();
        let e = t.set(name::LAMBDA2, &[0.5f32; 3]).unwrap_err().to_string();
        assert!(e.contains("lambda2") && e.contains("expected 8"), "{e}");
        t.remove(name::POSITION);
        assert_eq!(t.view().positions().len(), 2);
        let info = MapInfo::new(vec![], State::Traced);
        assert!(PhotonTable::new("t", info, &[[0.0; 3]], &[]).is_err());
    }
}
