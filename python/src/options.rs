//! Keyword arguments as the command line reads its options: the same spellings, the same
//! checks and the same messages.

use std::path::PathBuf;

use pyo3::prelude::*;

use crate::errors::Failure;

/// A path given as `str` or `os.PathLike`.
pub fn path(value: &Bound<'_, PyAny>) -> PyResult<PathBuf> {
    value.extract::<PathBuf>()
}

/// An optional path.
pub fn opt_path(value: Option<&Bound<'_, PyAny>>) -> PyResult<Option<PathBuf>> {
    value.map(path).transpose()
}

/// A path as the library's messages name it (as `photonkit` prints a path given on its
/// command line).
pub fn text(p: &std::path::Path) -> String {
    p.display().to_string()
}

/// One of `choices` (the command line's spellings; `_` may stand for `-`), as `option` takes it.
pub fn choice<'c>(option: &str, value: &str, choices: &[&'c str]) -> Result<&'c str, Failure> {
    let wanted = value.replace('_', "-");
    choices.iter().find(|c| **c == wanted).copied().ok_or_else(|| {
        Failure::value(format!(
            "invalid value '{value}' for '{option}': expected one of {}",
            choices.join(", ")
        ))
    })
}

/// A photon count: a whole number, as an int or a float such as `1e6` (the command line's
/// `20000000` or `2e7`).
pub fn count(value: &Bound<'_, PyAny>) -> PyResult<u64> {
    if let Ok(n) = value.extract::<u64>() {
        return Ok(n);
    }
    match value.extract::<f64>() {
        Ok(x) if x >= 0.0 && x.fract() == 0.0 && x < 1.8e19 => Ok(x as u64),
        _ => Err(Failure::value(format!("'{}' is not a whole number of photons", value.str()?)).into()),
    }
}

/// A size in bytes: an int, or text as people write it (`512M`, `4G`, `2GiB`), as `trace
/// --memory` reads it.
pub fn memory(value: &Bound<'_, PyAny>) -> PyResult<u64> {
    let parsed = match value.extract::<u64>() {
        Ok(n) => Ok(n),
        Err(_) => {
            let s: String = value.extract()?;
            parse_size::parse_size(&s)
                .map_err(|e| format!("'{s}' is not a size such as 512M, 4G or 2GiB ({e})"))
        }
    };
    match parsed {
        Ok(0) => Err(Failure::value(format!("'{}': needs more than 0 bytes", value.str()?)).into()),
        Ok(n) => Ok(n),
        Err(message) => Err(Failure::value(message).into()),
    }
}

/// A finite number, as the command line's `finite_f32` takes it.
pub fn finite(option: &str, x: f32) -> Result<f32, Failure> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(Failure::value(format!("invalid value '{x}' for '{option}': '{x}' is not a finite number")))
    }
}

/// Three finite numbers x, y, z (a sequence, or the command line's text `x,y,z`).
pub fn vec3(option: &str, value: &Bound<'_, PyAny>) -> PyResult<glam::Vec3> {
    let v: Vec<f32> = match value.extract::<String>() {
        Ok(s) => s.split(',').map(|x| x.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| {
            Failure::value(format!("invalid value '{s}' for '{option}': expected three finite numbers x,y,z"))
        })?,
        Err(_) => value.extract()?,
    };
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(glam::Vec3::new(x, y, z)),
        _ => Err(Failure::value(format!(
            "invalid value '{}' for '{option}': expected three finite numbers x,y,z",
            value.str()?
        ))
        .into()),
    }
}
