//! Depth-complexity statistics (how many fragments each pixel holds), and the median every
//! report of timings and sizes uses.

/// A histogram of per-pixel fragment counts and the figures derived from it.
///
/// `histogram()[n]` is the number of pixels holding exactly `n` fragments (index 0 counts the
/// uncovered pixels). Accumulate with [`DepthStats::record`], combine partial results from parallel
/// workers with [`DepthStats::merge`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DepthStats {
    histogram: Vec<u64>,
}

impl DepthStats {
    /// Statistics of a sequence of per-pixel counts.
    pub fn from_counts(counts: impl IntoIterator<Item = u32>) -> Self {
        let mut stats = DepthStats::default();
        for n in counts {
            stats.record(n);
        }
        stats
    }

    /// Counts one pixel holding `n` fragments.
    #[inline]
    pub fn record(&mut self, n: u32) {
        let n = n as usize;
        if n >= self.histogram.len() {
            self.histogram.resize(n + 1, 0);
        }
        self.histogram[n] += 1;
    }

    /// Counts `pixels` pixels holding `n` fragments each.
    #[inline]
    pub fn record_many(&mut self, n: u32, pixels: u64) {
        let n = n as usize;
        if n >= self.histogram.len() {
            self.histogram.resize(n + 1, 0);
        }
        self.histogram[n] += pixels;
    }

    /// Adds another set of pixels' statistics to these.
    pub fn merge(&mut self, other: &DepthStats) {
        if other.histogram.len() > self.histogram.len() {
            self.histogram.resize(other.histogram.len(), 0);
        }
        for (a, b) in self.histogram.iter_mut().zip(&other.histogram) {
            *a += b;
        }
    }

    /// `histogram()[n]`: pixels with exactly `n` fragments, `n = 0..=max_depth_complexity()`.
    pub fn histogram(&self) -> &[u64] {
        &self.histogram
    }

    /// Pixels counted, covered or not.
    pub fn pixels(&self) -> u64 {
        self.histogram.iter().sum()
    }

    /// Pixels with at least one fragment.
    pub fn covered_pixels(&self) -> u64 {
        self.histogram.iter().skip(1).sum()
    }

    /// Total fragments.
    pub fn fragments(&self) -> u64 {
        self.histogram
            .iter()
            .enumerate()
            .map(|(n, &count)| n as u64 * count)
            .sum()
    }

    /// The largest number of fragments in any pixel.
    pub fn max_depth_complexity(&self) -> u32 {
        self.histogram
            .iter()
            .rposition(|&c| c > 0)
            .map_or(0, |n| n as u32)
    }

    /// Mean fragments per *covered* pixel (0 when nothing is covered).
    pub fn mean_depth_complexity(&self) -> f64 {
        let covered = self.covered_pixels();
        if covered == 0 {
            0.0
        } else {
            self.fragments() as f64 / covered as f64
        }
    }

    /// The histogram trimmed after the largest non-empty count.
    pub fn trimmed_histogram(&self) -> &[u64] {
        let end = self.max_depth_complexity() as usize + 1;
        &self.histogram[..end.min(self.histogram.len())]
    }
}

/// The median of the finite values among `values` (NaN and infinities are skipped): the middle
/// one of an odd count, the mean of the two middle ones of an even count; `None` if there are
/// no finite values.
pub fn median(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some((v[n / 2 - 1] + v[n / 2]) / 2.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_counts_skipping_non_finite_values() {
        assert_eq!(median([3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median([4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median([f64::NAN, 5.0, f64::INFINITY, 1.0]), Some(3.0));
        assert_eq!(median([f64::NAN]), None);
        assert_eq!(median(Vec::new()), None);
    }

    #[test]
    fn figures_from_counts() {
        let s = DepthStats::from_counts([0, 2, 3, 0, 1, 2]);
        assert_eq!(s.histogram(), &[2, 1, 2, 1]);
        assert_eq!(s.pixels(), 6);
        assert_eq!(s.covered_pixels(), 4);
        assert_eq!(s.fragments(), 8);
        assert_eq!(s.max_depth_complexity(), 3);
        assert_eq!(s.mean_depth_complexity(), 2.0);
    }

    #[test]
    fn merge_equals_counting_together() {
        let mut a = DepthStats::from_counts([0, 5]);
        let b = DepthStats::from_counts([1, 1, 2]);
        a.merge(&b);
        assert_eq!(a, DepthStats::from_counts([0, 5, 1, 1, 2]));
    }

    #[test]
    fn empty_frame() {
        let s = DepthStats::from_counts([0, 0]);
        assert_eq!(s.covered_pixels(), 0);
        assert_eq!(s.max_depth_complexity(), 0);
        assert_eq!(s.mean_depth_complexity(), 0.0);
        assert_eq!(s.trimmed_histogram(), &[2]);
    }
}
