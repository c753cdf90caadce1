//! Declared ranges of numeric config keys.
//!
//! Each config declares the range of every numeric key once, in
//! [`crate::Validate::ranges`], where the key is declared. Loading checks
//! them (a value outside names key, value and range), and the config sweep
//! test reads the same declarations to try NaN, +-inf and values just
//! outside each range on every stage's defaults, so a new key is covered by
//! declaring it, without editing the test.
//!
//! ```
//! use farsight_stage::{Range, Ranges, Validate};
//! struct Servo { k_linear: f64, lookahead_m: f64 }
//! impl Validate for Servo {
//!     fn ranges(&self, r: &mut Ranges) {
//!         r.key("k_linear", self.k_linear, Range::above_to(0.0, 100.0));
//!         r.key("lookahead_m", self.lookahead_m, Range::above_to(0.0, 100.0).unit("m"));
//!     }
//! }
//! let err = Servo { k_linear: f64::NAN, lookahead_m: 1.0 }.validate().unwrap_err();
//! assert_eq!(err.to_string(), "config key `k_linear` = NaN: expected 0 < x <= 100");
//! ```

use crate::{ConfigError, Validate};
use std::fmt;

/// The values a numeric key may take: an interval whose ends may be open,
/// closed or absent. NaN is never inside; an infinity only where an end is
/// a closed infinity (a lethal cost).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    pub min: f64,
    pub min_inclusive: bool,
    pub max: f64,
    pub max_inclusive: bool,
    /// Printed after the range in errors ("Hz", "m", "s").
    pub unit: &'static str,
}

impl Range {
    /// `min <= x <= max`.
    pub const fn between(min: f64, max: f64) -> Self {
        Self::new(min, true, max, true)
    }

    /// `min < x <= max`.
    pub const fn above_to(min: f64, max: f64) -> Self {
        Self::new(min, false, max, true)
    }

    /// `min <= x < max`.
    pub const fn from_below(min: f64, max: f64) -> Self {
        Self::new(min, true, max, false)
    }

    /// `min < x < max`.
    pub const fn open(min: f64, max: f64) -> Self {
        Self::new(min, false, max, false)
    }

    /// Any finite number (signed keys such as mount offsets).
    pub const fn finite() -> Self {
        Self::new(f64::NEG_INFINITY, false, f64::INFINITY, false)
    }

    /// A cost in s/m: positive, and `inf` (lethal) allowed.
    pub const fn cost_s_per_m() -> Self {
        Self::new(0.0, false, f64::INFINITY, true).unit("s/m")
    }

    const fn new(min: f64, min_inclusive: bool, max: f64, max_inclusive: bool) -> Self {
        Self {
            min,
            min_inclusive,
            max,
            max_inclusive,
            unit: "",
        }
    }

    pub const fn unit(mut self, unit: &'static str) -> Self {
        self.unit = unit;
        self
    }

    pub fn contains(&self, x: f64) -> bool {
        let above = if self.min_inclusive {
            x >= self.min
        } else {
            x > self.min
        };
        let below = if self.max_inclusive {
            x <= self.max
        } else {
            x < self.max
        };
        above && below
    }

    /// Values just outside the finite ends: the end itself where it is
    /// open, else one step past it (1 for integer keys, 0.1% of the end's
    /// size, at least 1e-3, for float keys). The config sweep tries these.
    pub fn just_outside(&self, integer: bool) -> Vec<f64> {
        let step = |end: f64| {
            if integer {
                1.0
            } else {
                (end.abs() * 1e-3).max(1e-3)
            }
        };
        let mut out = Vec::new();
        if self.min.is_finite() {
            out.push(if self.min_inclusive {
                self.min - step(self.min)
            } else {
                self.min
            });
        }
        if self.max.is_finite() {
            out.push(if self.max_inclusive {
                self.max + step(self.max)
            } else {
                self.max
            });
        }
        out
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lo = if self.min_inclusive { "<=" } else { "<" };
        let hi = if self.max_inclusive { "<=" } else { "<" };
        match (self.min.is_finite(), self.max.is_finite()) {
            (true, true) => write!(f, "{} {lo} x {hi} {}", self.min, self.max)?,
            (true, false) => write!(
                f,
                "x {} {}",
                if self.min_inclusive { ">=" } else { ">" },
                self.min
            )?,
            (false, true) => write!(f, "x {hi} {}", self.max)?,
            (false, false) => write!(f, "a finite number")?,
        }
        if !self.unit.is_empty() {
            write!(f, " {}", self.unit)?;
        }
        if self.max == f64::INFINITY && self.max_inclusive {
            write!(f, " (inf: lethal)")?;
        }
        Ok(())
    }
}

/// A rate in Hz (outputs, health, replanning): a stage waking more often
/// than 1 kHz is a typo, not a setting; one waking less than once in 1000 s
/// is no rate (a tiny positive one such as 1e-320 has a period no
/// `Duration` holds, which panicked the stages at start: found by fuzzing).
pub const RATE_HZ: Range = Range::between(1e-3, 1000.0).unit("Hz");

/// A numeric config value as a key declares it.
pub trait KeyValue: Copy + fmt::Display {
    fn as_f64(self) -> f64;
}

macro_rules! key_value {
    ($($t:ty),*) => {$(
        impl KeyValue for $t {
            fn as_f64(self) -> f64 {
                self as f64
            }
        }
    )*};
}
key_value!(f64, f32, u8, u16, u32, u64, usize, i32, i64);

/// One declared key: its full name, its value as loaded, its range.
#[derive(Debug, Clone)]
pub struct Declared {
    pub key: String,
    pub value: f64,
    pub shown: String,
    pub range: Range,
}

/// The ranges a config declares, collected by [`Validate::ranges`].
#[derive(Debug, Default)]
pub struct Ranges {
    prefix: String,
    declared: Vec<Declared>,
}

impl Ranges {
    /// Every range `config` declares, with keys as written in its file.
    pub fn of<T: Validate + ?Sized>(config: &T) -> Self {
        let mut r = Self::default();
        config.ranges(&mut r);
        r
    }

    /// Declares `key` (relative to the current table) and its range.
    pub fn key(&mut self, key: &str, value: impl KeyValue, range: Range) -> &mut Self {
        self.declared.push(Declared {
            key: self.full(key),
            value: value.as_f64(),
            shown: value.to_string(),
            range,
        });
        self
    }

    /// Declares `key` when it is set.
    pub fn optional(&mut self, key: &str, value: Option<impl KeyValue>, range: Range) -> &mut Self {
        if let Some(v) = value {
            self.key(key, v, range);
        }
        self
    }

    /// Declares each element of an array key, `key[0]`, `key[1]`, ...
    pub fn each(&mut self, key: &str, values: &[impl KeyValue], range: Range) -> &mut Self {
        for (i, v) in values.iter().enumerate() {
            self.key(&format!("{key}[{i}]"), *v, range);
        }
        self
    }

    /// Declares the ranges of a nested table (`servo`, `cameras[0]`).
    pub fn nested<T: Validate + ?Sized>(&mut self, table: &str, inner: &T) -> &mut Self {
        let inner_prefix = self.full(table);
        let outer = std::mem::replace(&mut self.prefix, inner_prefix);
        inner.ranges(self);
        self.prefix = outer;
        self
    }

    fn full(&self, key: &str) -> String {
        if self.prefix.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.prefix)
        }
    }

    pub fn declared(&self) -> &[Declared] {
        &self.declared
    }

    /// The first key outside its range, as an error naming key, value and range.
    pub fn check(&self) -> Result<(), ConfigError> {
        match self.declared.iter().find(|d| !d.range.contains(d.value)) {
            None => Ok(()),
            Some(d) => Err(ConfigError::invalid(&d.key, &d.shown, d.range.to_string())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_print_as_inequalities_with_units() {
        assert_eq!(
            Range::above_to(0.0, 1000.0).unit("Hz").to_string(),
            "0 < x <= 1000 Hz"
        );
        assert_eq!(Range::between(-1.0, 1.0).to_string(), "-1 <= x <= 1");
        assert_eq!(
            Range::new(0.0, true, f64::INFINITY, false).to_string(),
            "x >= 0"
        );
        assert_eq!(Range::finite().to_string(), "a finite number");
        assert_eq!(Range::cost_s_per_m().to_string(), "x > 0 s/m (inf: lethal)");
    }

    /// Every rate RATE_HZ accepts has a period a `Duration` holds (the
    /// stages wait `Duration::from_secs_f64(1 / rate)`).
    #[test]
    fn every_accepted_rate_has_a_period() {
        assert_eq!(RATE_HZ.to_string(), "0.001 <= x <= 1000 Hz");
        for rate in [1e-320, 1e-300, 1e-20, 0.0009, 0.0] {
            assert!(!RATE_HZ.contains(rate), "{rate}");
        }
        for rate in [1e-3, 0.5, 1000.0] {
            assert!(RATE_HZ.contains(rate), "{rate}");
            assert!(std::time::Duration::try_from_secs_f64(1.0 / rate).is_ok());
        }
    }

    #[test]
    fn nan_and_infinities_are_outside_every_range_but_a_lethal_cost() {
        for r in [
            Range::finite(),
            Range::between(-5.0, 5.0),
            Range::open(0.0, 1.0),
        ] {
            assert!(!r.contains(f64::NAN) && !r.contains(f64::INFINITY));
            assert!(!r.contains(f64::NEG_INFINITY));
        }
        let cost = Range::cost_s_per_m();
        assert!(cost.contains(f64::INFINITY) && !cost.contains(f64::NAN) && !cost.contains(0.0));
    }

    #[test]
    fn just_outside_is_outside_and_next_to_the_end() {
        let r = Range::between(1.0, 360.0);
        assert_eq!(r.just_outside(true), vec![0.0, 361.0]);
        let f = Range::above_to(0.0, 10.0).just_outside(false);
        assert_eq!(f[0], 0.0);
        assert!((f[1] - 10.01).abs() < 1e-12);
        for r in [
            Range::between(1.0, 360.0),
            Range::open(-2.0, 3.0),
            Range::above_to(0.5, 2.0),
        ] {
            for x in r.just_outside(false) {
                assert!(!r.contains(x), "{x} inside {r}");
            }
        }
        assert!(Range::finite().just_outside(false).is_empty());
    }

    struct Inner {
        width_m: f64,
    }
    impl Validate for Inner {
        fn ranges(&self, r: &mut Ranges) {
            r.key(
                "width_m",
                self.width_m,
                Range::above_to(0.0, 10.0).unit("m"),
            );
        }
    }
    struct Outer {
        rate_hz: u32,
        inner: Vec<Inner>,
    }
    impl Validate for Outer {
        fn ranges(&self, r: &mut Ranges) {
            r.key("rate_hz", self.rate_hz, Range::between(1.0, 100.0));
            for (i, c) in self.inner.iter().enumerate() {
                r.nested(&format!("inner[{i}]"), c);
            }
        }
    }

    #[test]
    fn nested_keys_carry_their_table_and_the_first_bad_one_is_named() {
        let ok = Outer {
            rate_hz: 10,
            inner: vec![Inner { width_m: 1.0 }],
        };
        let keys: Vec<_> = Ranges::of(&ok)
            .declared()
            .iter()
            .map(|d| d.key.clone())
            .collect();
        assert_eq!(keys, ["rate_hz", "inner[0].width_m"]);
        assert!(ok.validate().is_ok());
        let bad = Outer {
            rate_hz: 10,
            inner: vec![
                Inner { width_m: 1.0 },
                Inner {
                    width_m: f64::INFINITY,
                },
            ],
        };
        assert_eq!(
            bad.validate().unwrap_err().to_string(),
            "config key `inner[1].width_m` = inf: expected 0 < x <= 10 m"
        );
    }
}
