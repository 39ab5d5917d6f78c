//! The photon map object: a PHM file's columns as read-only numpy arrays that view its memory
//! map (or an in-memory map's own columns), its header as a dict; and `write` from numpy.

use std::path::PathBuf;

use numpy::ndarray::{ArrayViewD, IxDyn};
use numpy::{
    Element as NpElement, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use photonkit::format::{
    self, ColumnSpec, DType, Emitter, EmitterKind, MapInfo, MapView, Output, Parameterisation, PhotonTable,
    StageRecord, State, Units, name,
};
use pyo3::exceptions::PyKeyError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use serde_json::{Value, json};

use crate::errors::{Failure, Kind};
use crate::{options, run};

/// Where a map's photons are.
pub enum Source {
    /// A PHM file, memory-mapped and validated (boxed: its header is large, and a map is
    /// made once per stage).
    File(Box<format::PhotonMap>),
    /// A stage's result kept in memory (every column owned; boxed like a file's map).
    Memory(Box<PhotonTable<'static>>),
}

impl Source {
    pub fn view(&self) -> MapView<'_> {
        match self {
            Source::File(m) => m.view(),
            Source::Memory(t) => t.view(),
        }
    }
}

/// A photon map: a PHM file or a stage's result in memory.
///
/// Columns are numpy arrays viewing the map's own memory (for a file, the memory map: no
/// copy), read-only, whose base is this object: `m["position"]` is float32 (N, 3),
/// `m["emitter"]` uint16 (N,). `len(m)` is the photon count; `m.metadata` the JSON header.
#[pyclass(frozen, module = "photonkit", name = "PhotonMap")]
pub struct PhotonMap {
    pub source: Source,
}

impl PhotonMap {
    pub fn view(&self) -> MapView<'_> {
        self.source.view()
    }
}

/// `column` as a numpy array viewing `bytes` (which `owner` keeps alive), read-only.
fn array<'py>(owner: &Bound<'py, PhotonMap>, spec: &ColumnSpec, bytes: &[u8]) -> PyResult<Bound<'py, PyAny>> {
    fn typed<'py, T: NpElement + bytemuck::Pod>(
        owner: &Bound<'py, PhotonMap>,
        spec: &ColumnSpec,
        bytes: &[u8],
    ) -> PyResult<Bound<'py, PyAny>> {
        let values: &[T] = bytemuck::try_cast_slice(bytes).map_err(|e| {
            Failure::runtime(format!("column '{}' can not be viewed in place: {e}", spec.name))
        })?;
        let components = spec.components as usize;
        let shape = match components {
            1 => IxDyn(&[values.len()]),
            c => IxDyn(&[values.len() / c, c]),
        };
        let view = ArrayViewD::from_shape(shape, values)
            .map_err(|e| Failure::runtime(format!("column '{}': {e}", spec.name)))?;
        // SAFETY: the bytes are the map's (a memory map or a table's owned words), which the
        // frozen `owner` never changes and keeps until it is dropped; the array holds `owner`
        // as its base, so it is dropped last.
        let a = unsafe { PyArrayDyn::<T>::borrow_from_array(&view, owner.clone().into_any()) };
        drop(a.readwrite().make_nonwriteable());
        Ok(a.into_any())
    }
    match spec.dtype {
        DType::U8 => typed::<u8>(owner, spec, bytes),
        DType::U16 => typed::<u16>(owner, spec, bytes),
        DType::U32 => typed::<u32>(owner, spec, bytes),
        DType::U64 => typed::<u64>(owner, spec, bytes),
        DType::I8 => typed::<i8>(owner, spec, bytes),
        DType::I16 => typed::<i16>(owner, spec, bytes),
        DType::I32 => typed::<i32>(owner, spec, bytes),
        DType::I64 => typed::<i64>(owner, spec, bytes),
        DType::F32 => typed::<f32>(owner, spec, bytes),
        DType::F64 => typed::<f64>(owner, spec, bytes),
    }
}

/// `value` as the Python object `json.loads` makes of its JSON (serialised directly, so f32
/// values keep their shortest text, as in a file's header).
pub fn to_python<'py, T: serde::Serialize + ?Sized>(
    py: Python<'py>,
    value: &T,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| Failure::runtime(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// A Python object (dicts, lists, numbers, strings) as JSON, through `json.dumps`.
pub fn from_python(what: &str, value: &Bound<'_, PyAny>) -> PyResult<Value> {
    let text: String = value.py().import("json")?.call_method1("dumps", (value,))?.extract()?;
    serde_json::from_str(&text).map_err(|e| Failure::value(format!("{what}: {e}")).into())
}

/// A column's row of the header of a map in memory.
#[derive(serde::Serialize)]
struct ColumnRow {
    name: String,
    dtype: DType,
    components: u32,
}

/// The header of a map in memory, as a file would hold it but for what only writing fixes
/// (column offsets and checksums, the bounding box).
#[derive(serde::Serialize)]
struct MemoryHeader<'a> {
    photon_count: usize,
    columns: Vec<ColumnRow>,
    emitters: &'a [Emitter],
    units: &'a Units,
    state: State,
    history: &'a [StageRecord],
    #[serde(flatten)]
    extra: &'a serde_json::Map<String, Value>,
}

impl<'a> MemoryHeader<'a> {
    fn of(view: &MapView<'a>) -> Self {
        let info = view.info();
        MemoryHeader {
            photon_count: view.len(),
            columns: view
                .columns()
                .iter()
                .map(|(s, _)| ColumnRow { name: s.name.clone(), dtype: s.dtype, components: s.components })
                .collect(),
            emitters: &info.emitters,
            units: &info.units,
            state: info.state,
            history: &info.history,
            extra: &info.extra,
        }
    }
}

/// A file's JSON header as it is written in the file (between the preamble and the columns).
fn file_header(m: &format::PhotonMap) -> &str {
    let bytes = m.bytes();
    let len = bytes
        .first_chunk::<{ format::preamble::PREAMBLE_LEN }>()
        .and_then(format::preamble::Preamble::from_bytes)
        .map_or(0, |p| p.metadata_len as usize);
    let start = format::preamble::PREAMBLE_LEN;
    // Validated on open: the region is in the file and UTF-8.
    std::str::from_utf8(&bytes[start..start + len]).unwrap_or("{}")
}

#[pymethods]
impl PhotonMap {
    fn __len__(&self) -> usize {
        self.view().len()
    }

    /// The column `column` as a read-only numpy array viewing the map; KeyError if absent.
    fn __getitem__<'py>(slf: &Bound<'py, Self>, column: &str) -> PyResult<Bound<'py, PyAny>> {
        let view = slf.get().view();
        match view.columns().iter().find(|(s, _)| s.name == column) {
            Some((spec, bytes)) => array(slf, spec, bytes),
            None => Err(PyKeyError::new_err(format!(
                "{}: no column '{column}' (it has {})",
                view.file_name(),
                names(&view).join(", ")
            ))),
        }
    }

    fn __contains__(&self, column: &str) -> bool {
        self.view().spec(column).is_some()
    }

    fn __iter__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyAny>> {
        PyList::new(slf.py(), slf.get().keys())?.try_iter().map(Bound::into_any)
    }

    /// The column `column` as a read-only array, or `default` if the map has no such column.
    #[pyo3(signature = (column, default=None))]
    fn get<'py>(
        slf: &Bound<'py, Self>,
        column: &str,
        default: Option<Bound<'py, PyAny>>,
    ) -> PyResult<Option<Bound<'py, PyAny>>> {
        let view = slf.get().view();
        match view.columns().iter().find(|(s, _)| s.name == column) {
            Some((spec, bytes)) => array(slf, spec, bytes).map(Some),
            None => Ok(default),
        }
    }

    /// The column names, in file order.
    fn keys(&self) -> Vec<String> {
        names(&self.view())
    }

    /// Every column as a dict of read-only arrays viewing the map, in file order.
    #[getter]
    fn columns<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyDict>> {
        let dict = PyDict::new(slf.py());
        for (spec, bytes) in slf.get().view().columns() {
            dict.set_item(&spec.name, array(slf, spec, bytes)?)?;
        }
        Ok(dict)
    }

    /// The JSON header as a dict (photon_count, columns, emitters, units, bounding_box, state,
    /// history, …). A map in memory has no offsets, checksums or bounding box until written.
    #[getter]
    fn metadata<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.source {
            Source::File(m) => py.import("json")?.call_method1("loads", (file_header(m),)),
            Source::Memory(t) => to_python(py, &MemoryHeader::of(&t.view())),
        }
    }

    /// The emitters, as dicts (the header's `emitters`).
    #[getter]
    fn emitters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.source {
            Source::File(_) => self.metadata(py)?.get_item("emitters"),
            Source::Memory(t) => to_python(py, &t.info.emitters),
        }
    }

    /// Where the map is in the pipeline: "traced", "detected" or "collapsed".
    #[getter]
    fn state(&self) -> &'static str {
        self.view().info().state.name()
    }

    /// The stages that made the map, oldest first, as dicts (stage, version, time,
    /// parameters, report).
    #[getter]
    fn history<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        match &self.source {
            Source::File(_) => self.metadata(py)?.get_item("history"),
            Source::Memory(t) => to_python(py, &t.info.history),
        }
    }

    /// The file's path, or None for a map in memory.
    #[getter]
    fn path(&self) -> Option<String> {
        match &self.source {
            Source::File(m) => Some(m.file_name().to_string()),
            Source::Memory(_) => None,
        }
    }

    /// The name messages use: the path, or the name of the map a stage in memory started from.
    #[getter]
    fn name(&self) -> String {
        self.view().file_name().to_string()
    }

    /// (major, minor) version of the file as written; None for a map in memory.
    #[getter]
    fn version(&self) -> Option<(u16, u16)> {
        match &self.source {
            Source::File(m) => Some(m.version()),
            Source::Memory(_) => None,
        }
    }

    /// The addresses [start, end) of the file's bytes in this process (its memory map), which
    /// every column array lies inside; None for a map in memory.
    #[getter]
    fn mapping(&self) -> Option<(usize, usize)> {
        match &self.source {
            Source::File(m) => {
                let start = m.bytes().as_ptr() as usize;
                Some((start, start + m.bytes().len()))
            }
            Source::Memory(_) => None,
        }
    }

    /// Writes the map as a PHM file at `path` (written beside it and renamed into place; never
    /// over one of the maps open in this process) and returns it opened from there.
    fn write(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<PhotonMap> {
        let path = options::path(path)?;
        let source = run(py, None, || {
            let view = self.view();
            write_view(&PhotonTable::carrying(&view, view.info().clone()), path, None)
        })?;
        Ok(PhotonMap { source })
    }

    fn __repr__(&self) -> String {
        let view = self.view();
        let at = match &self.source {
            Source::File(m) => format!("'{}'", m.file_name()),
            Source::Memory(_) => format!("in memory, from '{}'", view.file_name()),
        };
        format!(
            "<photonkit.PhotonMap {at}: {} photons, {}, columns {}>",
            view.len(),
            view.info().state.name(),
            names(&view).join(", ")
        )
    }
}

fn names(view: &MapView) -> Vec<String> {
    view.columns().iter().map(|(s, _)| s.name.clone()).collect()
}

/// Writes `table` to `path` and opens the file written. `context` prefixes an error's message
/// as the command line's context does (e.g. "writing the detected map").
pub fn write_view(table: &PhotonTable, path: PathBuf, context: Option<&str>) -> Result<Source, Failure> {
    table.write(Output::Path(path.clone())).map_err(|e| {
        let mut f = Failure::from(e);
        if let Some(c) = context {
            f.message = format!("{c}: {}", f.message);
        }
        f
    })?;
    Ok(Source::File(Box::new(format::PhotonMap::open_path(&path)?)))
}

/// Opens a PHM file: validates its header and verifies every column's checksum, then maps it
/// into memory; the columns are viewed in place.
#[pyfunction]
pub fn open(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<PhotonMap> {
    let path = options::path(path)?;
    let map = run(py, None, || Ok(format::PhotonMap::open_path(&path)?))?;
    Ok(PhotonMap { source: Source::File(Box::new(map)) })
}

/// A map argument: a PhotonMap, or the path of a PHM file to open.
pub fn input<'py>(value: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PhotonMap>> {
    if let Ok(m) = value.cast::<PhotonMap>() {
        return Ok(m.clone());
    }
    Bound::new(value.py(), open(value.py(), value)?)
}

/// The element type of a numpy dtype, if PHM has it.
fn dtype_of(descr: &Bound<'_, numpy::PyArrayDescr>) -> Option<DType> {
    Some(match (descr.kind(), descr.itemsize()) {
        (b'u', 1) => DType::U8,
        (b'u', 2) => DType::U16,
        (b'u', 4) => DType::U32,
        (b'u', 8) => DType::U64,
        (b'i', 1) => DType::I8,
        (b'i', 2) => DType::I16,
        (b'i', 4) => DType::I32,
        (b'i', 8) => DType::I64,
        (b'f', 4) => DType::F32,
        (b'f', 8) => DType::F64,
        _ => return None,
    })
}

/// One emitter that stands for photons whose source is not described: no trajectory
/// parameters, power the photons' total flux (what `import` records for such photons).
fn external_emitter(flux: &[[f32; 3]]) -> Emitter {
    let total =
        flux.iter().fold([0f64; 3], |t, f| [t[0] + f[0] as f64, t[1] + f[1] as f64, t[2] + f[2] as f64]);
    let max = total.iter().copied().fold(0.0f64, f64::max);
    let value = json!({
        "id": 0,
        "kind": EmitterKind::External,
        "parameterisation": Parameterisation::None,
        "param_dims": 0,
        "power_w": total.iter().sum::<f64>(),
        "colour": if max > 0.0 { total.map(|c| c / max) } else { [1.0; 3] },
    });
    serde_json::from_value(value).expect("a valid emitter record")
}

/// Emitters from dicts as the header holds them; `id` (the index), `param_dims` (the
/// parameterisation's) and `colour` (white) may be left out.
fn emitters_from(value: &Bound<'_, PyAny>) -> PyResult<Vec<Emitter>> {
    let Value::Array(mut list) = from_python("emitters", value)? else {
        return Err(Failure::value("emitters: expected a list of dicts".into()).into());
    };
    for (i, e) in list.iter_mut().enumerate() {
        let Some(e) = e.as_object_mut() else {
            return Err(Failure::value(format!("emitters[{i}]: expected a dict")).into());
        };
        e.entry("id").or_insert(json!(i));
        e.entry("colour").or_insert(json!([1.0, 1.0, 1.0]));
        if !e.contains_key("param_dims") {
            let p: Option<Parameterisation> =
                e.get("parameterisation").and_then(|p| serde_json::from_value(p.clone()).ok());
            e.insert("param_dims".into(), json!(p.and_then(Parameterisation::dims).unwrap_or(0)));
        }
    }
    list.into_iter()
        .enumerate()
        .map(|(i, e)| {
            serde_json::from_value(e).map_err(|e| Failure::value(format!("emitters[{i}]: {e}")).into())
        })
        .collect()
}

/// Writes a PHM file from numpy arrays, one per column (`position` and `flux` float32 (N, 3)
/// required), and returns it opened. Arrays are written as they are, without a copy when
/// C-contiguous; they must not change while the call runs (the interpreter is released).
#[pyfunction]
#[pyo3(signature = (path, columns, *, emitters=None, state="traced", history=None, units=None))]
pub fn write(
    py: Python<'_>,
    path: &Bound<'_, PyAny>,
    columns: &Bound<'_, PyAny>,
    emitters: Option<&Bound<'_, PyAny>>,
    state: &str,
    history: Option<&Bound<'_, PyAny>>,
    units: Option<&Bound<'_, PyAny>>,
) -> PyResult<PhotonMap> {
    let path = options::path(path)?;
    let numpy = py.import("numpy")?;
    let items = columns
        .call_method0("items")
        .map_err(|_| Failure::value("columns: expected a mapping of column names to arrays".into()))?;
    // Each column as a C-contiguous array, kept alive (and its bytes viewed) to the end.
    let mut arrays: Vec<(ColumnSpec, Bound<'_, PyUntypedArray>)> = Vec::new();
    for item in items.try_iter()? {
        let item = item?;
        let pair = item.cast::<PyTuple>()?;
        let column: String = pair.get_item(0)?.extract()?;
        let a = numpy.call_method1("ascontiguousarray", (pair.get_item(1)?,))?;
        let a =
            a.cast_into::<PyUntypedArray>().map_err(|e| Failure::value(format!("column '{column}': {e}")))?;
        let descr = a.dtype();
        let bad = |what: String| Failure::value(format!("column '{column}': {what}"));
        let dtype = dtype_of(&descr).ok_or_else(|| {
            bad(format!(
                "dtype {} is not one of PHM's (u)int8–64, float32, float64",
                descr.str().map_or_else(|_| "?".into(), |s| s.to_string())
            ))
        })?;
        if descr.is_native_byteorder() == Some(false) {
            return Err(bad("big-endian arrays are not written: convert with .astype('<…')".into()).into());
        }
        let components = match a.shape() {
            [_] => 1,
            [_, c] => *c as u32,
            s => return Err(bad(format!("shape {s:?}: expected (N,) or (N, components)")).into()),
        };
        arrays.push((ColumnSpec::new(&column, dtype, components), a));
    }
    let bytes: Vec<(ColumnSpec, &[u8])> = arrays
        .iter()
        .map(|(spec, a)| {
            let len = a.len() * a.dtype().itemsize();
            // SAFETY: a C-contiguous array of `len` bytes, alive (held in `arrays`) while the
            // slice is used; the caller keeps it unchanged during the call.
            let data = unsafe { (*a.as_array_ptr()).fields.data as *const u8 };
            let slice = if len == 0 { &[][..] } else { unsafe { std::slice::from_raw_parts(data, len) } };
            (spec.clone(), slice)
        })
        .collect();
    let state = match options::choice("state", state, &["traced", "detected", "collapsed"])? {
        "traced" => State::Traced,
        "detected" => State::Detected,
        _ => State::Collapsed,
    };
    let emitters = emitters.map(emitters_from).transpose()?;
    let mut records: Vec<StageRecord> = match history {
        Some(h) => serde_json::from_value(from_python("history", h)?)
            .map_err(|e| Failure::value(format!("history: {e}")))?,
        None => Vec::new(),
    };
    let units: Units = match units {
        Some(u) => serde_json::from_value(from_python("units", u)?)
            .map_err(|e| Failure::value(format!("units: {e}")))?,
        None => Units::default(),
    };
    let columns_written: Vec<&str> = bytes.iter().map(|(s, _)| s.name.as_str()).collect();
    records.push(StageRecord::now(
        "write",
        json!({ "from": "python", "photonkit_python": env!("CARGO_PKG_VERSION"), "columns": columns_written }),
    ));
    let file = options::text(&path);
    let source = run(py, None, move || {
        // The library's own checks, as `ValueError`s: these are the caller's arguments.
        let value = |e: format::FormatError| {
            let f = Failure::from(e);
            if f.kind == Kind::Runtime { Failure::value(f.message) } else { f }
        };
        let info = MapInfo { units, history: records, ..MapInfo::new(Vec::new(), state) };
        let mut table = PhotonTable::from_columns(&file, info, &bytes).map_err(value)?;
        table.info.emitters = match emitters {
            Some(e) => e,
            None if table.view().spec(name::PARAMS).is_some() => {
                return Err(Failure::value(
                    "a 'params' column needs emitters=[…] saying what the trajectory parameters are \
                     (e.g. {'kind': 'collimated', 'parameterisation': 'rect_uv', 'power_w': 1.0})"
                        .into(),
                ));
            }
            None => vec![external_emitter(table.view().flux())],
        };
        table.write(Output::Path(path.clone())).map_err(value)?;
        Ok(Source::File(Box::new(format::PhotonMap::open_path(&path)?)))
    })?;
    Ok(PhotonMap { source })
}
