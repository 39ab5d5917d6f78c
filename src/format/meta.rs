//! The JSON metadata of a PHM file (format-spec/phm-v1.md §3).
//!
//! Every struct keeps the keys it does not know in `extra`, so a file written by a newer minor
//! version passes through a stage with its additions intact.

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::columns::DType;

/// The whole metadata object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metadata {
    /// Number of photons: every column holds this many elements.
    pub photon_count: u64,
    /// The column table, in file order.
    pub columns: Vec<ColumnEntry>,
    /// The light sources; a photon's `emitter` value indexes this list.
    pub emitters: Vec<Emitter>,
    /// Units of length and flux.
    pub units: Units,
    /// Axis-aligned box around every photon position; `null` for an empty map.
    pub bounding_box: Option<BoundingBox>,
    /// Where the map is in the pipeline.
    pub state: State,
    /// The stages that wrote the file, oldest first.
    pub history: Vec<StageRecord>,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// One row of the column table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ColumnEntry {
    /// The column's name (§4.1 for the known ones).
    pub name: String,
    /// Its element type.
    pub dtype: DType,
    /// Components per photon.
    pub components: u32,
    /// Absolute byte offset of the column in the file; a multiple of 64.
    pub offset: u64,
    /// Length in bytes: photon_count × components × size of dtype.
    pub length: u64,
    /// CRC-32 of the column's `length` bytes.
    pub crc32: u32,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// What kind of light source an emitter is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EmitterKind {
    /// A rectangle emitting parallel rays along its normal (sunlight through a window).
    Collimated,
    /// An isotropic point light emitting over the whole sphere.
    Point,
    /// A point light emitting a cosine-weighted hemisphere or cone.
    Spot,
    /// An emitter we know nothing about (photons imported from another tracer).
    External,
    /// A kind written by a newer minor version.
    #[serde(other)]
    Unknown,
}

/// How an emitter's trajectory parameters are written in the `params` column.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Parameterisation {
    /// (u, v) ∈ \[0,1\]² across the emitter rectangle: 2 dimensions.
    RectUv,
    /// The unit emission direction: 3 dimensions, on the unit sphere.
    Direction,
    /// (u, v) and the photon's wavelength in nm: 3 dimensions (version 1.1).
    RectUvSpectral,
    /// The unit emission direction and the photon's wavelength in nm: 4 dimensions (version 1.1).
    DirectionSpectral,
    /// No trajectory parameters: 0 dimensions.
    None,
    /// A parameterisation written by a newer minor version.
    #[serde(other)]
    Unknown,
}

impl Parameterisation {
    /// Number of components this parameterisation fills in the `params` column.
    pub fn dims(self) -> Option<u32> {
        match self {
            Parameterisation::RectUv => Some(2),
            Parameterisation::Direction | Parameterisation::RectUvSpectral => Some(3),
            Parameterisation::DirectionSpectral => Some(4),
            Parameterisation::None => Some(0),
            Parameterisation::Unknown => None,
        }
    }

    /// The component holding the wavelength (the last), for the spectral parameterisations.
    pub fn spectral_component(self) -> Option<usize> {
        match self {
            Parameterisation::RectUvSpectral => Some(2),
            Parameterisation::DirectionSpectral => Some(3),
            _ => None,
        }
    }

    /// This parameterisation with a wavelength dimension added (`rect_uv` → `rect_uv_spectral`,
    /// `direction` → `direction_spectral`); the others unchanged.
    pub fn with_wavelength(self) -> Self {
        match self {
            Parameterisation::RectUv => Parameterisation::RectUvSpectral,
            Parameterisation::Direction => Parameterisation::DirectionSpectral,
            p => p,
        }
    }

    /// The dimensions this parameterisation's components stand for, in order (the default of
    /// [`Emitter::dimensions`]).
    pub fn dimensions(self) -> Vec<ParamDimension> {
        let dim = |name: &str, kind| ParamDimension::new(name, kind);
        let spectral = || {
            let (lo, hi) = WAVELENGTH_RANGE_NM;
            ParamDimension {
                unit: Some("nm".into()),
                range: Some([lo as f64, hi as f64]),
                ..dim("wavelength", DimensionKind::Spectral)
            }
        };
        let uv = || vec![dim("u", DimensionKind::Spatial), dim("v", DimensionKind::Spatial)];
        let dir = || ["x", "y", "z"].map(|n| dim(n, DimensionKind::Directional)).to_vec();
        match self {
            Parameterisation::RectUv => uv(),
            Parameterisation::Direction => dir(),
            Parameterisation::RectUvSpectral => [uv(), vec![spectral()]].concat(),
            Parameterisation::DirectionSpectral => [dir(), vec![spectral()]].concat(),
            Parameterisation::None | Parameterisation::Unknown => Vec::new(),
        }
    }

    /// Whether one photon's `params` entry (every component of the column) is valid for this
    /// parameterisation (format-spec/phm-v1.md §5): `rect_uv` in [0, 1]², `direction` of unit
    /// length within [`UNIT_TOLERANCE`], and zeros past the parameterisation's dimensions.
    /// An unknown parameterisation admits anything.
    pub fn admits(self, q: &[f32]) -> bool {
        let Some(used) = self.dims() else { return true };
        let used = used as usize;
        if q.len() < used || q[used..].iter().any(|&x| x != 0.0) {
            return false;
        }
        let wavelength = |l: f32| l > 0.0 && l.is_finite();
        let unit =
            |q: &[f32]| ((q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() - 1.0).abs() <= UNIT_TOLERANCE;
        match self {
            Parameterisation::RectUv => q[..2].iter().all(|x| (0.0..=1.0).contains(x)),
            Parameterisation::RectUvSpectral => {
                q[..2].iter().all(|x| (0.0..=1.0).contains(x)) && wavelength(q[2])
            }
            Parameterisation::Direction => unit(q),
            Parameterisation::DirectionSpectral => unit(q) && wavelength(q[3]),
            Parameterisation::None | Parameterisation::Unknown => true,
        }
    }

    /// The name written in the metadata (`rect_uv`, `direction`, `none`, `unknown`).
    pub fn name(self) -> &'static str {
        match self {
            Parameterisation::RectUv => "rect_uv",
            Parameterisation::Direction => "direction",
            Parameterisation::RectUvSpectral => "rect_uv_spectral",
            Parameterisation::DirectionSpectral => "direction_spectral",
            Parameterisation::None => "none",
            Parameterisation::Unknown => "unknown",
        }
    }
}

/// The visible range photons' wavelengths are drawn from, nm.
pub const WAVELENGTH_RANGE_NM: (f32, f32) = (380.0, 720.0);

/// Tolerance on the length of unit vectors in the data invariants (format-spec/phm-v1.md §5);
/// f32 vectors normalised in f32 are good to about 1e-6.
pub const UNIT_TOLERANCE: f32 = 1e-3;

/// A light source and the space its photons' trajectory parameters live in.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Emitter {
    /// Equal to the emitter's index in the list; the value stored in the `emitter` column.
    pub id: u32,
    /// What kind of light source it is.
    pub kind: EmitterKind,
    /// How its trajectory parameters are written in `params`.
    pub parameterisation: Parameterisation,
    /// Number of `params` components this emitter uses.
    pub param_dims: u32,
    /// Emitted power in watts (sum over RGB of the emitted flux).
    pub power_w: f64,
    /// Relative RGB colour of the emission.
    pub colour: [f32; 3],
    /// Area of the parameter manifold in world units, so parameter-space densities can be
    /// expressed per m² (collimated: the rectangle's area) or per steradian (point: 4π).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub param_measure: Option<f64>,
    /// Kind-specific placement (free form; see the spec).
    #[serde(default, skip_serializing_if = "Value::is_null")]
    pub geometry: Value,
    /// What each `params` component is (version 1.1; written for the spectral
    /// parameterisations). Empty: the parameterisation's [`Parameterisation::dimensions`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dimensions: Vec<ParamDimension>,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl Emitter {
    /// The dimensions of this emitter's parameters: the record's, else its parameterisation's.
    pub fn dimensions(&self) -> Vec<ParamDimension> {
        if self.dimensions.is_empty() { self.parameterisation.dimensions() } else { self.dimensions.clone() }
    }

    /// Per component, the factor parameter-space distances (Eq. 1) apply to it: 1 for the
    /// spatial and directional components, [`ParamDimension::scale`] for a spectral one
    /// (docs/spectral.md).
    pub fn param_scales(&self) -> Vec<f32> {
        let dims = self.dimensions();
        (0..self.param_dims as usize)
            .map(|c| dims.get(c).map_or(1.0, |d| d.distance_scale() as f32))
            .collect()
    }

    /// This emitter with its wavelength dimension's [`ParamDimension::scale`] set to `scale`
    /// (unchanged without one).
    pub fn with_spectral_scale(&self, scale: f64) -> Emitter {
        let mut e = self.clone();
        if let Some(k) = e.parameterisation.spectral_component() {
            let mut dims = e.dimensions();
            dims[k].scale = Some(scale);
            e.dimensions = dims;
        }
        e
    }

    /// Whether some component is a wavelength.
    pub fn is_spectral(&self) -> bool {
        self.parameterisation.spectral_component().is_some()
    }
}

/// What one component of the `params` column stands for (format-spec/phm-v1.md §3.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamDimension {
    /// `u`, `v`, `x`, `y`, `z` or `wavelength`.
    pub name: String,
    /// What it measures.
    pub kind: DimensionKind,
    /// Unit of the stored values (`nm` for a wavelength); absent for dimensionless ones.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<String>,
    /// The interval the values are drawn from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<[f64; 2]>,
    /// Parameter-space units per stored unit, the factor distances apply to this component
    /// (written by `detect` for a spectral dimension; absent: 1, or for a spectral dimension
    /// one over its range's width).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl ParamDimension {
    /// A dimension with no unit, range or scale.
    pub fn new(name: &str, kind: DimensionKind) -> Self {
        ParamDimension { name: name.into(), kind, unit: None, range: None, scale: None, extra: Map::new() }
    }

    /// [`Self::scale`] or its default.
    pub fn distance_scale(&self) -> f64 {
        match (self.scale, self.kind, self.range) {
            (Some(s), _, _) => s,
            (None, DimensionKind::Spectral, Some([lo, hi])) if hi > lo => 1.0 / (hi - lo),
            (None, DimensionKind::Spectral, _) => {
                let (lo, hi) = WAVELENGTH_RANGE_NM;
                1.0 / (hi - lo) as f64
            }
            (None, _, _) => 1.0,
        }
    }
}

/// The kind of quantity a parameter dimension measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DimensionKind {
    /// A position on the emitter (u or v).
    Spatial,
    /// A component of the emission direction.
    Directional,
    /// The photon's wavelength.
    Spectral,
    /// A kind written by a newer minor version.
    #[serde(other)]
    Unknown,
}

/// The units of the stored quantities (always metres and watts in version 1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Units {
    /// Unit of length of positions and path lengths: "m".
    pub length: String,
    /// Unit of flux: "W".
    pub flux: String,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl Default for Units {
    fn default() -> Self {
        Units { length: "m".into(), flux: "W".into(), extra: Map::new() }
    }
}

/// An axis-aligned box, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoundingBox {
    /// The smallest x, y and z.
    pub min: [f32; 3],
    /// The largest x, y and z.
    pub max: [f32; 3],
}

impl std::fmt::Display for BoundingBox {
    /// `(x, y, z) .. (x, y, z) m`, each number as its shortest round-trip text.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [a, b, c] = self.min;
        let [d, e, g] = self.max;
        write!(f, "({a}, {b}, {c}) .. ({d}, {e}, {g}) m")
    }
}

/// Where a photon map is in the pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Written by `trace` or `import`: photons as they landed.
    Traced,
    /// Constraint columns present; neighbours are searched in world + parameter space.
    Detected,
    /// Parameter dimensions dropped from the neighbour search (they stay in the file).
    Collapsed,
    /// A state written by a newer minor version.
    #[serde(other)]
    Unknown,
}

impl State {
    /// The state's name in the metadata.
    pub fn name(self) -> &'static str {
        match self {
            State::Traced => "traced",
            State::Detected => "detected",
            State::Collapsed => "collapsed",
            State::Unknown => "unknown",
        }
    }
}

/// One stage that wrote the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    /// Subcommand name: "trace", "detect", "relax", …
    pub stage: String,
    /// photonkit version that ran it.
    pub version: String,
    /// UTC time the stage finished, RFC 3339.
    pub time: String,
    /// The stage's parameters as it used them.
    pub parameters: Value,
    /// Measurements the stage made (per-iteration relaxation measures, timings, …).
    #[serde(default, skip_serializing_if = "Value::is_null")]
    pub report: Value,
    /// Keys this version does not know, kept.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl StageRecord {
    /// A record for `stage` stamped with this build's version and the current time (the time
    /// `SOURCE_DATE_EPOCH` gives, when set: [`source_date`]).
    pub fn now(stage: &str, parameters: Value) -> Self {
        StageRecord {
            stage: stage.to_string(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            time: source_date().unwrap_or_else(|| {
                humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()
            }),
            parameters,
            report: Value::Null,
            extra: Map::new(),
        }
    }
}

/// Everything in the metadata that a stage chooses; the writer fills in the rest
/// (count, column table, checksums, bounding box).
#[derive(Clone, Debug, PartialEq)]
pub struct MapInfo {
    /// The light sources; a photon's `emitter` value indexes this list.
    pub emitters: Vec<Emitter>,
    /// Units of length and flux.
    pub units: Units,
    /// Where the map is in the pipeline.
    pub state: State,
    /// The stages that wrote the file, oldest first (the writing stage adds its own).
    pub history: Vec<StageRecord>,
    /// Keys this version does not know, kept.
    pub extra: Map<String, Value>,
}

impl MapInfo {
    /// Per emitter, the factors on its parameter components that detection measured distances
    /// with ([`Emitter::param_scales`]); `None` when no emitter has a wavelength, where every
    /// factor is 1 and the parameters are used as they are.
    pub fn param_scales(&self) -> Option<Vec<Vec<f32>>> {
        self.emitters
            .iter()
            .any(|e| e.is_spectral())
            .then(|| self.emitters.iter().map(|e| e.param_scales()).collect())
    }

    /// A header in metres and watts with no history yet.
    pub fn new(emitters: Vec<Emitter>, state: State) -> Self {
        MapInfo { emitters, units: Units::default(), state, history: Vec::new(), extra: Map::new() }
    }
}

impl Metadata {
    /// The stage-chosen part of this metadata, to carry into the next stage's output.
    pub fn info(&self) -> MapInfo {
        MapInfo {
            emitters: self.emitters.clone(),
            units: self.units.clone(),
            state: self.state,
            history: self.history.clone(),
            extra: self.extra.clone(),
        }
    }

    /// The lowest minor version that describes this metadata: 1 when an emitter has a spectral
    /// parameterisation or a `dimensions` list (added in 1.1), else 0, so maps without a
    /// spectral dimension stay byte-identical to those of earlier builds.
    pub fn minor_version(&self) -> u16 {
        let v1_1 = self.emitters.iter().any(|e| e.is_spectral() || !e.dimensions.is_empty());
        u16::from(v1_1)
    }

    /// The column table's entry for `name`, if the map has that column.
    pub fn column(&self, name: &str) -> Option<&ColumnEntry> {
        self.columns.iter().find(|c| c.name == name)
    }
}

/// The time from `SOURCE_DATE_EPOCH` (seconds since 1970), if set: every stage then writes the
/// same bytes for the same input (reproducible-builds.org's convention).
pub fn source_date() -> Option<String> {
    let secs: u64 = std::env::var("SOURCE_DATE_EPOCH").ok()?.trim().parse().ok()?;
    let t = std::time::UNIX_EPOCH.checked_add(std::time::Duration::from_secs(secs))?;
    Some(humantime::format_rfc3339_seconds(t).to_string())
}

/// A stage's run time for its record: `null` when `SOURCE_DATE_EPOCH` asks for reproducible
/// files (a time measured differs on every run).
pub fn reported_seconds(seconds: f64) -> Value {
    if source_date().is_some() { Value::Null } else { seconds.into() }
}
