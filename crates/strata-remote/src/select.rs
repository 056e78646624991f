//! The node's choice of fragments for the `full` and `depth-limited` transfers (seed 000 ch. 3,
//! Algorithms A.2–A.3), and [`restrict`], which keeps only some pixels' runs.
//!
//! Runs are sorted front to back, so "the N nearest" is a prefix of each run, and so is "until
//! the accumulated opacity reaches T": a fragment is kept while fewer than N came before it and
//! the opacity in front of it, `1 − Π(1 − αᵢ)`, is still below T. The first fragment is always
//! kept; the one that crosses T is kept too (it is what makes the pixel reach T).
//!
//! Both build the output columns directly from the input's (`DeepFrame::from_parts`), one pass
//! over the pixels and one copy of each kept fragment.

use strata_core::{DeepFrame, ObjectId, Rgba8};
use strata_wire::PixelMask;

/// Keeps at most `layers` nearest fragments of every pixel, stopping early where the opacity
/// in front reaches `opacity_threshold`.
pub fn depth_limit(frame: &DeepFrame, layers: u32, opacity_threshold: Option<f32>) -> DeepFrame {
    let threshold = opacity_threshold.unwrap_or(f32::INFINITY);
    let pixels = frame.width() as usize * frame.height() as usize;
    let mut out = Columns::with_capacity(pixels, frame.fragment_count());
    for p in 0..pixels {
        let run = frame.run(p);
        let mut keep = run.len().min(layers as usize);
        if opacity_threshold.is_some() {
            let mut transparency = 1.0f32;
            for (i, c) in run.color.iter().take(keep).enumerate() {
                if 1.0 - transparency >= threshold {
                    keep = i;
                    break;
                }
                transparency *= 1.0 - f32::from(c.0[3]) / 255.0;
            }
        }
        out.push_run(frame, p, 0..keep);
    }
    out.finish(frame.width(), frame.height())
}

/// The runs of `frame` at the pixels of `mask`; every other pixel is empty.
pub fn restrict(frame: &DeepFrame, mask: &PixelMask) -> DeepFrame {
    let pixels = frame.width() as usize * frame.height() as usize;
    let offsets = frame.offsets();
    let inside: usize = mask
        .runs()
        .iter()
        .map(|&(s, l)| (offsets[(s + l) as usize] - offsets[s as usize]) as usize)
        .sum();
    let mut out = Columns::with_capacity(pixels, inside);
    let mut p = 0usize;
    for &(s, l) in mask.runs() {
        out.push_empty(s as usize - p);
        out.push_span(frame, s as usize, (s + l) as usize);
        p = (s + l) as usize;
    }
    out.push_empty(pixels - p);
    out.finish(frame.width(), frame.height())
}

/// The columns of a DeepFrame under construction, pixel by pixel.
pub(crate) struct Columns {
    offsets: Vec<u32>,
    depth: Vec<f32>,
    color: Vec<Rgba8>,
    object: Vec<ObjectId>,
}

impl Columns {
    pub(crate) fn with_capacity(pixels: usize, fragments: usize) -> Self {
        let mut offsets = Vec::with_capacity(pixels + 1);
        offsets.push(0);
        Columns {
            offsets,
            depth: Vec::with_capacity(fragments),
            color: Vec::with_capacity(fragments),
            object: Vec::with_capacity(fragments),
        }
    }

    /// Fragments `range` of pixel `p`'s run of `frame`, as the next pixel.
    pub(crate) fn push_run(&mut self, frame: &DeepFrame, p: usize, range: std::ops::Range<usize>) {
        let start = frame.offsets()[p] as usize;
        let (a, b) = (start + range.start, start + range.end);
        self.depth.extend_from_slice(&frame.depths()[a..b]);
        self.color.extend_from_slice(&frame.colors()[a..b]);
        self.object.extend_from_slice(&frame.objects()[a..b]);
        self.offsets.push(self.depth.len() as u32);
    }

    /// Pixels `p0..p1` of `frame`, whole runs, as the next pixels.
    pub(crate) fn push_span(&mut self, frame: &DeepFrame, p0: usize, p1: usize) {
        let offsets = frame.offsets();
        let (a, b) = (offsets[p0] as usize, offsets[p1] as usize);
        let base = self.depth.len() as u32;
        self.depth.extend_from_slice(&frame.depths()[a..b]);
        self.color.extend_from_slice(&frame.colors()[a..b]);
        self.object.extend_from_slice(&frame.objects()[a..b]);
        let shift = base.wrapping_sub(offsets[p0]);
        self.offsets
            .extend(offsets[p0 + 1..=p1].iter().map(|&o| o.wrapping_add(shift)));
    }

    /// `n` empty pixels.
    pub(crate) fn push_empty(&mut self, n: usize) {
        let end = self.depth.len() as u32;
        self.offsets.extend(std::iter::repeat_n(end, n));
    }

    /// The frame; the runs came from valid frames, so its invariants hold.
    pub(crate) fn finish(self, width: u32, height: u32) -> DeepFrame {
        DeepFrame::from_parts(
            width,
            height,
            self.offsets,
            self.depth,
            self.color,
            self.object,
        )
        .expect("runs copied from valid frames form a valid frame")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::Fragment;

    fn frag(depth: f32, alpha: u8) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([200, 100, 50, alpha]),
            object: ObjectId(1),
        }
    }

    fn sample() -> DeepFrame {
        let deep: Vec<Fragment> = (0..10).map(|i| frag(0.05 * i as f32, 128)).collect();
        DeepFrame::from_pixel_lists(
            3,
            1,
            &[
                deep,
                vec![],
                vec![frag(0.5, 255), frag(0.6, 255), frag(0.7, 10)],
            ],
        )
        .unwrap()
    }

    #[test]
    fn depth_limit_keeps_the_nearest_prefix() {
        let f = sample();
        for n in [1, 2, 6, 10, 50] {
            let l = depth_limit(&f, n, None);
            for p in 0..3 {
                let want: Vec<_> = f.run(p).iter().take(n as usize).collect();
                assert_eq!(l.run(p).iter().collect::<Vec<_>>(), want, "n {n} pixel {p}");
            }
        }
        assert_eq!(depth_limit(&f, 100, None), f);
    }

    #[test]
    fn the_opacity_threshold_stops_after_the_fragment_that_reaches_it() {
        let f = sample();
        // Alpha 128/255 ≈ 0.502: opacity after 1, 2, 3 fragments ≈ 0.502, 0.752, 0.876.
        let l = depth_limit(&f, 10, Some(0.75));
        assert_eq!(l.run(0).len(), 2);
        assert_eq!(
            l.run(2).len(),
            1,
            "an opaque first fragment is all it takes"
        );
        let l = depth_limit(&f, 10, Some(0.8));
        assert_eq!(l.run(0).len(), 3);
        let l = depth_limit(&f, 10, Some(1.0));
        assert_eq!(l.run(0).len(), 10);
        assert_eq!(l.run(2).len(), 1);
    }

    #[test]
    fn restrict_keeps_masked_runs_only() {
        let f = sample();
        let m = PixelMask::from_fn(3, |p| p != 0);
        let r = restrict(&f, &m);
        assert!(r.run(0).is_empty());
        assert_eq!(
            r.run(2).iter().collect::<Vec<_>>(),
            f.run(2).iter().collect::<Vec<_>>()
        );
        assert_eq!(restrict(&f, &PixelMask::full(3)), f);
        assert_eq!(restrict(&f, &PixelMask::empty(3)), DeepFrame::empty(3, 1));
    }
}
