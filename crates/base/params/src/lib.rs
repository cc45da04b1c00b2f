//! Range checks for parameter structs. Every struct a config file can reach implements
//! [`Validate`] once; a config reader calls [`Validate::validate`] on the whole tree and
//! gets the first field out of range with its path (`atlas.loops.matcher.icp.max_iterations`),
//! its value and what is allowed.

use std::fmt::Display;

/// A parameter out of its range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("invalid parameter `{field}` = {value}: {allowed}")]
pub struct ParamError {
    /// The field's path from the checked struct, e.g. `loops.matcher.icp.max_iterations`.
    pub field: String,
    /// The value given.
    pub value: String,
    /// What the field accepts, e.g. `must be in [1, 10000]`.
    pub allowed: String,
}

/// A parameter struct that checks its own ranges.
pub trait Validate {
    /// Reports every field to `check` (nested structs through [`Checker::nested`]).
    fn check(&self, check: &mut Checker);

    /// The first field out of range.
    fn validate(&self) -> Result<(), ParamError> {
        let mut checker = Checker::default();
        self.check(&mut checker);
        checker.first.map_or(Ok(()), Err)
    }
}

/// The allowed range of a real parameter; every bound excludes NaN and infinities.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Real {
    lo: f64,
    lo_open: bool,
    hi: f64,
    hi_open: bool,
}

impl Real {
    /// Any finite value.
    pub const fn finite() -> Self {
        Self::new(f64::NEG_INFINITY, true, f64::INFINITY, true)
    }
    /// Finite and > 0.
    pub const fn positive() -> Self {
        Self::new(0.0, true, f64::INFINITY, true)
    }
    /// Finite and ≥ 0.
    pub const fn non_negative() -> Self {
        Self::new(0.0, false, f64::INFINITY, true)
    }
    /// In `[lo, hi]`.
    pub const fn within(lo: f64, hi: f64) -> Self {
        Self::new(lo, false, hi, false)
    }
    /// In `[0, 1]`.
    pub const fn fraction() -> Self {
        Self::within(0.0, 1.0)
    }
    /// In `(lo, hi)`.
    pub const fn open(lo: f64, hi: f64) -> Self {
        Self::new(lo, true, hi, true)
    }
    /// In `(0, hi]`.
    pub const fn positive_up_to(hi: f64) -> Self {
        Self::new(0.0, true, hi, false)
    }
    /// Finite and ≥ `lo`.
    pub const fn at_least(lo: f64) -> Self {
        Self::new(lo, false, f64::INFINITY, true)
    }

    const fn new(lo: f64, lo_open: bool, hi: f64, hi_open: bool) -> Self {
        Self {
            lo,
            lo_open,
            hi,
            hi_open,
        }
    }

    /// Whether `value` is in the range.
    pub fn contains(&self, value: f64) -> bool {
        value.is_finite()
            && (if self.lo_open {
                value > self.lo
            } else {
                value >= self.lo
            })
            && (if self.hi_open {
                value < self.hi
            } else {
                value <= self.hi
            })
    }

    fn describe(&self) -> String {
        match (self.lo.is_finite(), self.hi.is_finite()) {
            (false, false) => "must be finite".into(),
            (true, false) => format!(
                "must be finite and {} {}",
                if self.lo_open { ">" } else { "≥" },
                self.lo
            ),
            (false, true) => format!(
                "must be finite and {} {}",
                if self.hi_open { "<" } else { "≤" },
                self.hi
            ),
            (true, true) => format!(
                "must be in {}{}, {}{}",
                if self.lo_open { "(" } else { "[" },
                self.lo,
                self.hi,
                if self.hi_open { ")" } else { "]" }
            ),
        }
    }
}

/// A standard deviation in metres: small and large enough that its information (1/σ²) and
/// its variance stay finite.
pub const SIGMA_M: Real = Real::within(1e-6, 1e3);
/// A standard deviation in radians, likewise.
pub const SIGMA_RAD: Real = Real::within(1e-6, 10.0);
/// A noise coefficient per unit of motion (m/m, rad/rad, rad/m).
pub const NOISE_PER_UNIT: Real = Real::within(0.0, 100.0);

/// Collects the first field out of range while a struct tree reports its fields.
#[derive(Debug, Default)]
pub struct Checker {
    path: Vec<String>,
    first: Option<ParamError>,
}

impl Checker {
    fn fail(&mut self, name: &str, value: impl Display, allowed: String) {
        if self.first.is_some() {
            return;
        }
        let mut field = self.path.join(".");
        if !field.is_empty() && !name.starts_with('[') {
            field.push('.');
        }
        field.push_str(name);
        self.first = Some(ParamError {
            field,
            value: value.to_string(),
            allowed,
        });
    }

    /// A real field.
    pub fn real(&mut self, name: &str, value: f64, allowed: Real) -> &mut Self {
        if !allowed.contains(value) {
            self.fail(name, value, allowed.describe());
        }
        self
    }

    /// An optional real field: checked when present.
    pub fn real_opt(&mut self, name: &str, value: Option<f64>, allowed: Real) -> &mut Self {
        if let Some(value) = value {
            self.real(name, value, allowed);
        }
        self
    }

    /// The elements of a real list or tuple, `name[k]`, each with its range.
    pub fn reals(&mut self, name: &str, values: &[(f64, Real)]) -> &mut Self {
        for (k, (value, allowed)) in values.iter().enumerate() {
            self.real(&format!("{name}[{k}]"), *value, *allowed);
        }
        self
    }

    /// A count or size in `[lo, hi]`.
    pub fn count<T: Copy + Into<u128> + Display>(
        &mut self,
        name: &str,
        value: T,
        lo: u64,
        hi: u64,
    ) -> &mut Self {
        let v: u128 = value.into();
        if v < u128::from(lo) || v > u128::from(hi) {
            self.fail(name, value, format!("must be in [{lo}, {hi}]"));
        }
        self
    }

    /// A `usize` count in `[lo, hi]`.
    pub fn size(&mut self, name: &str, value: usize, lo: u64, hi: u64) -> &mut Self {
        self.count(name, value as u64, lo, hi)
    }

    /// An optional `usize` count: checked when present.
    pub fn size_opt(&mut self, name: &str, value: Option<usize>, lo: u64, hi: u64) -> &mut Self {
        if let Some(value) = value {
            self.size(name, value, lo, hi);
        }
        self
    }

    /// A rule across fields (e.g. a minimum below its maximum); `allowed` says which.
    pub fn rule(
        &mut self,
        name: &str,
        value: impl Display,
        holds: bool,
        allowed: &str,
    ) -> &mut Self {
        if !holds {
            self.fail(name, value, allowed.to_owned());
        }
        self
    }

    /// A nested struct, its fields under `name.`.
    pub fn nested<T: Validate + ?Sized>(&mut self, name: &str, value: &T) -> &mut Self {
        self.path.push(name.to_owned());
        value.check(self);
        self.path.pop();
        self
    }

    /// An optional nested struct: checked when present.
    pub fn nested_opt<T: Validate>(&mut self, name: &str, value: Option<&T>) -> &mut Self {
        if let Some(value) = value {
            self.nested(name, value);
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Inner {
        sigma_m: f64,
        cells: u64,
    }
    impl Validate for Inner {
        fn check(&self, check: &mut Checker) {
            check.real("sigma_m", self.sigma_m, Real::positive()).count(
                "cells",
                self.cells,
                1,
                1 << 24,
            );
        }
    }
    struct Outer {
        gate: (f64, f64),
        inner: Inner,
        extra: Option<Inner>,
    }
    impl Validate for Outer {
        fn check(&self, check: &mut Checker) {
            check
                .reals(
                    "gate",
                    &[
                        (self.gate.0, Real::non_negative()),
                        (self.gate.1, Real::fraction()),
                    ],
                )
                .nested("inner", &self.inner)
                .nested_opt("extra", self.extra.as_ref());
        }
    }

    fn outer() -> Outer {
        Outer {
            gate: (1.0, 0.5),
            inner: Inner {
                sigma_m: 0.1,
                cells: 10,
            },
            extra: None,
        }
    }

    #[test]
    fn the_first_field_out_of_range_is_named_by_its_path() {
        assert_eq!(outer().validate(), Ok(()));
        let mut o = outer();
        o.inner.sigma_m = -5.0;
        o.inner.cells = 0;
        let e = o.validate().unwrap_err();
        assert_eq!(e.field, "inner.sigma_m");
        assert_eq!(
            e.to_string(),
            "invalid parameter `inner.sigma_m` = -5: must be finite and > 0"
        );
        let mut o = outer();
        o.extra = Some(Inner {
            sigma_m: 1.0,
            cells: u64::MAX,
        });
        let e = o.validate().unwrap_err();
        assert_eq!(e.field, "extra.cells");
        assert_eq!(e.allowed, "must be in [1, 16777216]");
        let mut o = outer();
        o.gate.1 = f64::NAN;
        let e = o.validate().unwrap_err();
        assert_eq!(
            e.to_string(),
            "invalid parameter `gate[1]` = NaN: must be in [0, 1]"
        );
    }

    #[test]
    fn ranges_exclude_nan_and_infinities_and_respect_open_ends() {
        for r in [
            Real::finite(),
            Real::positive(),
            Real::non_negative(),
            Real::at_least(-1.0),
        ] {
            assert!(!r.contains(f64::NAN) && !r.contains(f64::INFINITY));
            assert!(!r.contains(f64::NEG_INFINITY));
        }
        assert!(!Real::positive().contains(0.0));
        assert!(Real::non_negative().contains(0.0));
        assert!(Real::positive_up_to(1.0).contains(1.0));
        assert!(!Real::positive_up_to(1.0).contains(0.0));
        assert_eq!(Real::positive_up_to(2.0).describe(), "must be in (0, 2]");
    }
}
