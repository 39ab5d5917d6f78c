//! Tile parts (`photonkit STAGE --tile i/n`): their records and columns, and the order-free
//! sums that let tiles add up to the whole map's report bit for bit.

use super::TileSpec;

/// CRC-32 of a map's position column: which map a tile part was cut from (a part's record
/// carries it as `source_position_crc32`).
pub fn position_crc(map: &crate::format::MapView) -> u32 {
    crc32fast::hash(bytemuck::cast_slice(map.positions()))
}

/// What a tile part's last record says about it (`photonkit STAGE --tile`).
pub struct PartRecord<'p> {
    /// Its tile.
    pub tile: TileSpec,
    /// The stage's parameters.
    pub parameters: &'p serde_json::Value,
    /// The stage's report.
    pub report: &'p serde_json::Value,
    /// Seconds the tile took.
    pub seconds: f64,
}

/// The record of `part`, a tile part of `map` written by `stage` (`--tile` of `command`), or
/// what is wrong with it: not such a part, not a tile, or cut from another map.
pub fn part_record<'p>(
    map: &crate::format::MapView,
    part: &crate::format::MapView<'p>,
    stage: &str,
    command: &str,
) -> Result<PartRecord<'p>, String> {
    use serde_json::Value;
    let rec = part
        .info()
        .history
        .last()
        .filter(|r| r.stage == stage && r.report.get("tile").is_some())
        .ok_or_else(|| format!("not a tile part: its last record is not `{command} --tile`"))?;
    let r = &rec.report;
    let num =
        |key: &str| r.get(key).and_then(Value::as_u64).ok_or_else(|| format!("its record has no {key}"));
    let (index, count) = (num("tile")?, num("tiles")?);
    if count == 0 || index >= count {
        return Err(format!("tile {index}/{count} is not a tile"));
    }
    if num("source_photons")? != map.len() as u64 || num("source_position_crc32")? != position_crc(map) as u64
    {
        return Err(format!("cut from another map than {}", map.file_name()));
    }
    Ok(PartRecord {
        tile: TileSpec { index: index as usize, count: count as usize },
        parameters: &rec.parameters,
        report: r,
        seconds: r.get("seconds").and_then(Value::as_f64).unwrap_or(0.0),
    })
}

/// A tile part's report: the fields every part starts with (the time, the tile, its photons,
/// and which map it was cut from, which [`part_record`] reads back), then the stage's own
/// `fields` (a JSON object).
pub fn part_report(
    map: &crate::format::MapView,
    tile: TileSpec,
    photons: usize,
    seconds: f64,
    fields: serde_json::Value,
) -> serde_json::Value {
    let mut r = serde_json::Map::new();
    r.insert("seconds".into(), crate::format::meta::reported_seconds(seconds));
    r.insert("tile".into(), tile.index.into());
    r.insert("tiles".into(), tile.count.into());
    r.insert("photons".into(), photons.into());
    r.insert("source_photons".into(), map.len().into());
    r.insert("source_position_crc32".into(), position_crc(map).into());
    if let serde_json::Value::Object(own) = fields {
        r.extend(own);
    }
    r.into()
}

/// Every column of `map` but those named in `except`, for the photons `indices` (in that
/// order): a tile part's copy of the map's columns.
pub fn part_columns(
    map: &crate::format::MapView,
    indices: &[u32],
    except: &[&str],
) -> Vec<(crate::format::ColumnSpec, Vec<u8>)> {
    map.columns()
        .iter()
        .filter(|(spec, _)| !except.contains(&spec.name.as_str()))
        .map(|(spec, bytes)| {
            let w = spec.stride() as usize;
            let mut out = Vec::with_capacity(indices.len() * w);
            for &i in indices {
                out.extend_from_slice(&bytes[i as usize * w..][..w]);
            }
            // The rows are scattered over every page of the column: none is read again.
            map.release_pages();
            (spec.clone(), out)
        })
        .collect()
}

/// A sum of f64 values that does not depend on their order: a value is its integer
/// significand times a power of two, and the significands of each power are added exactly as
/// integers; the total is formed from them in a fixed order. Tiles that each sum their photons
/// and add their sums together give the whole map's sum bit for bit (docs/tiles.md).
#[derive(Clone, Debug)]
pub struct ExactSum {
    /// Per binary exponent (from the smallest subnormal's), the sum of significands.
    by_exponent: Vec<i128>,
}

impl Default for ExactSum {
    fn default() -> Self {
        ExactSum { by_exponent: vec![0; 2048] }
    }
}

impl ExactSum {
    /// Adds `x` (finite; others are ignored).
    pub fn add(&mut self, x: f64) {
        if !x.is_finite() || x == 0.0 {
            return;
        }
        let bits = x.to_bits();
        let biased = ((bits >> 52) & 0x7ff) as usize;
        let fraction = (bits & ((1u64 << 52) - 1)) as i128;
        // x = significand · 2^(biased − 1075), with the implicit bit for normal numbers.
        let (significand, slot) = if biased == 0 { (fraction, 1) } else { (fraction | 1 << 52, biased) };
        self.by_exponent[slot] += if x < 0.0 { -significand } else { significand };
    }

    /// Adds another sum's values.
    pub fn merge(&mut self, other: &ExactSum) {
        for (a, b) in self.by_exponent.iter_mut().zip(&other.by_exponent) {
            *a += b;
        }
    }

    /// The total (rounded once per exponent used, the same whatever the order of the values).
    pub fn total(&self) -> f64 {
        self.by_exponent
            .iter()
            .enumerate()
            .filter(|(_, s)| **s != 0)
            .map(|(slot, &s)| s as f64 * 2f64.powi(slot as i32 - 1075))
            .sum()
    }
}
