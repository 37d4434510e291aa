//! Range checks of settings that name the field in their error
//! (`invalid setting `lm.max_tries`: must be ≥ 1, got 0`).

use crate::base::error::Error;

fn bad(name: &'static str, reason: String) -> Result<(), Error> {
    Err(Error::InvalidSetting { name, reason })
}

/// A positive finite number.
pub fn positive(name: &'static str, v: f64) -> Result<(), Error> {
    if v > 0.0 && v.is_finite() {
        return Ok(());
    }
    bad(name, format!("must be a positive finite number, got {v}"))
}

/// A finite number ≥ 0.
pub fn non_negative(name: &'static str, v: f64) -> Result<(), Error> {
    if v >= 0.0 && v.is_finite() {
        return Ok(());
    }
    bad(name, format!("must be a finite number ≥ 0, got {v}"))
}

/// A finite number ≥ `min`.
pub fn at_least(name: &'static str, v: f64, min: f64) -> Result<(), Error> {
    if v >= min && v.is_finite() {
        return Ok(());
    }
    bad(name, format!("must be a finite number ≥ {min}, got {v}"))
}

/// 0 (which means `off`) or a finite number ≥ `min`.
pub fn off_or_at_least(name: &'static str, v: f64, min: f64, off: &str) -> Result<(), Error> {
    if v == 0.0 || (v >= min && v.is_finite()) {
        return Ok(());
    }
    bad(
        name,
        format!("must be 0 ({off}) or a finite number ≥ {min}, got {v}"),
    )
}

/// A number in [0, 1].
pub fn in_unit_interval(name: &'static str, v: f64) -> Result<(), Error> {
    if (0.0..=1.0).contains(&v) {
        return Ok(());
    }
    bad(name, format!("must be in [0, 1], got {v}"))
}

/// A number in [0, 1).
pub fn fraction_below_one(name: &'static str, v: f64) -> Result<(), Error> {
    if (0.0..1.0).contains(&v) {
        return Ok(());
    }
    bad(name, format!("must be in [0, 1), got {v}"))
}

/// A count ≥ `min`.
pub fn count_at_least(name: &'static str, v: usize, min: usize) -> Result<(), Error> {
    if v >= min {
        return Ok(());
    }
    bad(name, format!("must be ≥ {min}, got {v}"))
}
