//! The transfer function: piecewise-linear colour and opacity over the normalised scalar value.
//!
//! Points are `(value, colour, alpha)` with strictly increasing values in [0, 1]; between points
//! colour and alpha are interpolated linearly, outside them the end points hold. `alpha` is the
//! opacity of a slab `unit_length` thick (world units): a step of length `d` gets the corrected
//! opacity `1 − (1 − alpha)^(d / unit_length)`, so the image does not depend on the step size.
//! In extinction terms `σ = −ln(1 − alpha) / unit_length`, and a constant medium of thickness `L`
//! transmits `exp(−σ·L)`.
//!
//! [`StepTable`] bakes the function for one step length into a table of 4096 entries (colour and
//! corrected opacity, linearly interpolated), so the inner loop does no `powf`.

/// One point of a transfer function.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TfPoint {
    /// The normalised scalar value, in [0, 1].
    pub value: f32,
    /// Linear RGB colour, each in [0, 1].
    pub color: [f32; 3],
    /// Opacity of a slab one `unit_length` thick, in [0, 1].
    pub alpha: f32,
}

/// Why a transfer function was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum TransferError {
    /// No points were given.
    #[error("the transfer function has no points; give at least one `[[volume.points]]` entry")]
    NoPoints,
    /// A point's value, colour or alpha is outside [0, 1] or not a number.
    #[error("transfer function point {index}: {what} must be a number in [0, 1]")]
    OutOfRange {
        /// The point's index.
        index: usize,
        /// Which field.
        what: &'static str,
    },
    /// Values do not increase strictly.
    #[error(
        "transfer function point {index}: value {value} does not follow the previous point's {previous}; values must increase"
    )]
    NotIncreasing {
        /// The point's index.
        index: usize,
        /// Its value.
        value: f32,
        /// The previous point's value.
        previous: f32,
    },
    /// The unit length is not a positive number.
    #[error("transfer function unit length {0} must be a positive number")]
    BadUnit(f32),
}

/// A piecewise-linear transfer function.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferFunction {
    points: Vec<TfPoint>,
    unit_length: f32,
}

impl TransferFunction {
    /// Checks and keeps `points`; `unit_length` is the thickness the points' alpha refers to.
    pub fn new(points: Vec<TfPoint>, unit_length: f32) -> Result<Self, TransferError> {
        if points.is_empty() {
            return Err(TransferError::NoPoints);
        }
        if !(unit_length.is_finite() && unit_length > 0.0) {
            return Err(TransferError::BadUnit(unit_length));
        }
        let unit = |v: f32| (0.0..=1.0).contains(&v);
        for (index, p) in points.iter().enumerate() {
            let bad = if !unit(p.value) {
                Some("value")
            } else if !p.color.iter().all(|&c| unit(c)) {
                Some("colour")
            } else if !unit(p.alpha) {
                Some("alpha")
            } else {
                None
            };
            if let Some(what) = bad {
                return Err(TransferError::OutOfRange { index, what });
            }
            if index > 0 && p.value <= points[index - 1].value {
                return Err(TransferError::NotIncreasing {
                    index,
                    value: p.value,
                    previous: points[index - 1].value,
                });
            }
        }
        Ok(TransferFunction {
            points,
            unit_length,
        })
    }

    /// The points.
    pub fn points(&self) -> &[TfPoint] {
        &self.points
    }

    /// The thickness the points' alpha refers to.
    pub fn unit_length(&self) -> f32 {
        self.unit_length
    }

    /// Colour and (uncorrected) alpha at `value`.
    pub fn eval(&self, value: f32) -> ([f32; 3], f32) {
        let pts = &self.points;
        let i = pts.partition_point(|p| p.value <= value);
        if i == 0 {
            return (pts[0].color, pts[0].alpha);
        }
        if i == pts.len() {
            let last = pts[pts.len() - 1];
            return (last.color, last.alpha);
        }
        let (a, b) = (pts[i - 1], pts[i]);
        let t = (value - a.value) / (b.value - a.value);
        let lerp = |x: f32, y: f32| x + (y - x) * t;
        (
            [0, 1, 2].map(|c| lerp(a.color[c], b.color[c])),
            lerp(a.alpha, b.alpha),
        )
    }
}

/// Entries in a [`StepTable`].
const TABLE_LEN: usize = 4096;

/// A transfer function baked for one step length: premultiplied colour and corrected opacity.
#[derive(Clone, Debug)]
pub struct StepTable {
    /// `[r·a, g·a, b·a, a]` per entry, entry `i` at value `i / (TABLE_LEN − 1)`.
    entries: Vec<[f32; 4]>,
}

impl StepTable {
    /// Bakes `tf` for steps of length `step`.
    pub fn new(tf: &TransferFunction, step: f32) -> StepTable {
        let exponent = step / tf.unit_length;
        let entries = (0..TABLE_LEN)
            .map(|i| {
                let (c, a) = tf.eval(i as f32 / (TABLE_LEN - 1) as f32);
                let a = corrected_alpha(a, exponent);
                [c[0] * a, c[1] * a, c[2] * a, a]
            })
            .collect();
        StepTable { entries }
    }

    /// Premultiplied colour and corrected opacity at `value` in [0, 1].
    #[inline]
    pub fn lookup(&self, value: f32) -> [f32; 4] {
        let p = value.clamp(0.0, 1.0) * (TABLE_LEN - 1) as f32;
        let i = (p as usize).min(TABLE_LEN - 2);
        let t = p - i as f32;
        let (a, b) = (self.entries[i], self.entries[i + 1]);
        [0, 1, 2, 3].map(|k| a[k] + (b[k] - a[k]) * t)
    }
}

/// Opacity of a step `exponent` unit lengths long, for a unit opacity `alpha`.
pub fn corrected_alpha(alpha: f32, exponent: f32) -> f32 {
    if alpha >= 1.0 {
        1.0
    } else {
        1.0 - (1.0 - alpha).powf(exponent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(value: f32, alpha: f32) -> TfPoint {
        TfPoint {
            value,
            color: [value, 0.5, 1.0 - value],
            alpha,
        }
    }

    #[test]
    fn no_points_is_an_error_that_says_what_to_add() {
        let e = TransferFunction::new(vec![], 1.0).expect_err("empty");
        assert_eq!(e, TransferError::NoPoints);
        assert!(e.to_string().contains("no points"));
    }

    #[test]
    fn values_must_increase_and_lie_in_range() {
        let e = TransferFunction::new(vec![point(0.5, 0.1), point(0.5, 0.2)], 1.0);
        assert!(matches!(
            e,
            Err(TransferError::NotIncreasing { index: 1, .. })
        ));
        let e = TransferFunction::new(vec![point(0.5, 1.5)], 1.0);
        assert_eq!(
            e,
            Err(TransferError::OutOfRange {
                index: 0,
                what: "alpha"
            })
        );
        assert!(TransferFunction::new(vec![point(0.5, 0.5)], 0.0).is_err());
    }

    #[test]
    fn eval_interpolates_between_points_and_holds_outside() {
        let tf = TransferFunction::new(vec![point(0.2, 0.0), point(0.6, 0.8)], 1.0).expect("ok");
        let (c, a) = tf.eval(0.4);
        assert!((a - 0.4).abs() < 1e-6);
        assert!((c[0] - 0.4).abs() < 1e-6);
        assert_eq!(tf.eval(0.0).1, 0.0);
        assert_eq!(tf.eval(1.0).1, 0.8);
    }

    #[test]
    fn corrected_alpha_composes_over_steps() {
        // Two half steps transmit what one full step does.
        let half = corrected_alpha(0.6, 0.5);
        assert!(((1.0 - half) * (1.0 - half) - 0.4).abs() < 1e-6);
    }
}
