//! How much of a pixel's sorted run a depth-limited frame keeps (Jähne 2014 ch. 3, Algorithms
//! A.2–A.3): at most `layers` nearest fragments, and no more once the opacity in front reaches a
//! threshold.
//!
//! Runs are sorted front to back, so what is kept is always a prefix: a fragment is kept while
//! fewer than `layers` came before it and the opacity in front of it, `1 − Π(1 − αᵢ)` over the
//! fragments before it, is still below the threshold. With `layers ≥ 1` and a threshold in
//! `(0, 1]` (what the depth-limited transfer accepts) the first fragment is always kept; the one
//! that crosses the threshold is kept too, as it is what makes the pixel reach it. The rule is
//! the arithmetic of the node's earlier selection pass, in `f32`, to the bit.
//!
//! One rule, used where the prefix is taken: a render node's store applies it as each strip's
//! fragments are gathered for export ([`crate::GatherWriter::with_limit`]), and
//! [`crate::DeepFrame::limit_runs`] applies it to a whole frame.

/// A limit on each run's length; see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunLimit {
    layers: u32,
    opacity_threshold: Option<f32>,
}

impl RunLimit {
    /// Keeps every fragment.
    pub const NONE: RunLimit = RunLimit {
        layers: u32::MAX,
        opacity_threshold: None,
    };

    /// At most `layers` fragments a pixel, and none after the one that brings the opacity in
    /// front to `opacity_threshold` (which the depth-limited transfer keeps in `(0, 1]`).
    pub const fn new(layers: u32, opacity_threshold: Option<f32>) -> Self {
        RunLimit {
            layers,
            opacity_threshold,
        }
    }

    /// True if it keeps every fragment of every run.
    pub fn is_none(&self) -> bool {
        self.layers == u32::MAX && self.opacity_threshold.is_none()
    }

    /// The most fragments a pixel keeps.
    pub fn layers(&self) -> u32 {
        self.layers
    }

    /// The opacity after which a pixel keeps no more fragments, if any.
    pub fn opacity_threshold(&self) -> Option<f32> {
        self.opacity_threshold
    }

    /// How many of a sorted run of `len` fragments are kept; `alpha(i)` is the alpha byte of
    /// the `i`-th nearest.
    #[inline(always)]
    pub fn keep(&self, len: usize, alpha: impl Fn(usize) -> u8) -> usize {
        let keep = len.min(self.layers as usize);
        let Some(threshold) = self.opacity_threshold else {
            return keep;
        };
        let mut transparency = 1.0f32;
        for i in 0..keep {
            if 1.0 - transparency >= threshold {
                return i;
            }
            transparency *= 1.0 - f32::from(alpha(i)) / 255.0;
        }
        keep
    }
}

impl Default for RunLimit {
    fn default() -> Self {
        RunLimit::NONE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_cut_the_run() {
        let a = |_| 128u8;
        for (layers, len, want) in [(1, 5, 1), (6, 5, 5), (6, 10, 6), (0, 3, 0), (3, 0, 0)] {
            assert_eq!(RunLimit::new(layers, None).keep(len, a), want);
        }
        assert_eq!(RunLimit::NONE.keep(1 << 20, a), 1 << 20);
        assert!(RunLimit::NONE.is_none() && RunLimit::default().is_none());
        assert!(!RunLimit::new(6, None).is_none());
    }

    #[test]
    fn the_threshold_keeps_the_fragment_that_reaches_it() {
        // Alpha 128/255 ≈ 0.502: opacity after 1, 2, 3 fragments ≈ 0.502, 0.752, 0.876.
        let half = |_| 128u8;
        assert_eq!(RunLimit::new(10, Some(0.75)).keep(10, half), 2);
        assert_eq!(RunLimit::new(10, Some(0.8)).keep(10, half), 3);
        assert_eq!(
            RunLimit::new(2, Some(0.8)).keep(10, half),
            2,
            "layers first"
        );
        // An opaque first fragment is all it takes; a clear one never reaches anything.
        assert_eq!(RunLimit::new(10, Some(1.0)).keep(3, |_| 255), 1);
        assert_eq!(RunLimit::new(10, Some(0.01)).keep(4, |_| 0), 4);
        // Opacity exactly at the threshold stops there (the test is `>=`, before the next
        // fragment's alpha is multiplied in).
        let at = 1.0 - (1.0 - 128.0f32 / 255.0);
        assert_eq!(RunLimit::new(10, Some(at)).keep(5, half), 1);
        assert_eq!(RunLimit::new(10, Some(at.next_up())).keep(5, half), 2);
        // The alpha of the i-th fragment is asked for, in order.
        let alphas = [0u8, 0, 255, 9];
        assert_eq!(RunLimit::new(10, Some(0.5)).keep(4, |i| alphas[i]), 3);
    }
}
