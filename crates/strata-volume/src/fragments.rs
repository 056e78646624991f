//! Deep fragments along each pixel's ray, and the walker that interleaves them with the volume's
//! sample grid: translucent geometry inside the volume.
//!
//! # Layout
//!
//! A [`FragmentLayer`] holds every pixel's fragments as one sorted run, the DeepFrame layout with
//! the ray distance in place of the window depth:
//!
//! ```text
//! starts:    [usize; pixels + 1]   pixel p owns fragments[starts[p] .. starts[p+1]]
//! fragments: [RayFragment; n]       t (distance along the pixel's ray), straight colour, alpha
//! ```
//!
//! Each run is sorted front to back by [`front_to_back`] — distance, then opaque before
//! translucent, then colour — a total order, so a run depends only on the set of fragments, never
//! on the order they were captured or merged in. A run ends at its first opaque fragment
//! (`alpha ≥ 1`): nothing behind it can be seen, and the ray caster stops there.
//!
//! # The walk
//!
//! [`crate::cast::Caster::cast_through`] walks a run and the fixed sample grid
//! `t_k = t_in + (k + ½)·step` together: the samples with `t_k < t_f` are composited, then the
//! fragment `f` (`C += T·α·c`, `T *= 1 − α`), then the samples up to the next fragment, and so on;
//! after the last fragment the samples run to the box's exit, and the background goes behind what
//! is left of `T` — unless the run ended at an opaque fragment, which takes all of it. The sample
//! positions are the grid's, wherever the fragments lie, so a run with only its opaque fragment is
//! exactly the opaque-geometry cast of [`crate::cast::Caster::cast`], and any two callers walking
//! the same run on the same ray compute the same pixel bit for bit.

use std::cmp::Ordering;

/// A surface crossing a pixel's ray: where, its straight (not premultiplied) colour, its opacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayFragment {
    /// Distance along the pixel's ray (the ray's direction is a unit vector).
    pub t: f32,
    /// Linear RGB, straight.
    pub color: [f32; 3],
    /// Opacity in [0, 1]; 1 is opaque.
    pub alpha: f32,
}

impl RayFragment {
    /// Whether nothing behind it shows.
    #[inline]
    pub fn is_opaque(&self) -> bool {
        self.alpha >= 1.0
    }
}

/// The front-to-back order of a run: distance, then opaque before translucent (so a fragment at
/// exactly an opaque one's distance is hidden by it), then colour bits. A total order: equal keys
/// are equal fragments, which composite the same in either order.
pub fn front_to_back(a: &RayFragment, b: &RayFragment) -> Ordering {
    a.t.total_cmp(&b.t)
        .then(b.alpha.total_cmp(&a.alpha))
        .then_with(|| a.color.map(f32::to_bits).cmp(&b.color.map(f32::to_bits)))
}

/// Sorts `run` front to back and drops everything behind its first opaque fragment and every
/// fragment whose distance is not a number.
pub fn settle(run: &mut Vec<RayFragment>) {
    run.retain(|f| !f.t.is_nan());
    run.sort_unstable_by(front_to_back);
    if let Some(first) = run.iter().position(RayFragment::is_opaque) {
        run.truncate(first + 1);
    }
}

/// Every pixel's fragments, settled (sorted, cut at the first opaque one), in one flat buffer.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FragmentLayer {
    starts: Vec<usize>,
    fragments: Vec<RayFragment>,
}

impl FragmentLayer {
    /// A layer of `pixels` pixels with no fragments.
    pub fn empty(pixels: usize) -> FragmentLayer {
        FragmentLayer {
            starts: vec![0; pixels + 1],
            fragments: Vec::new(),
        }
    }

    /// A layer from `(pixel, fragment)` pairs in any order; pixels at or beyond `pixels` are
    /// dropped.
    pub fn from_pairs(pixels: usize, pairs: &[(u32, RayFragment)]) -> FragmentLayer {
        let mut lists: Vec<Vec<RayFragment>> = Vec::new();
        lists.resize_with(pixels, Vec::new);
        for &(p, f) in pairs {
            if let Some(list) = lists.get_mut(p as usize) {
                list.push(f);
            }
        }
        FragmentLayer::from_lists(lists)
    }

    /// A layer from one list per pixel, each in any order.
    pub fn from_lists(lists: Vec<Vec<RayFragment>>) -> FragmentLayer {
        FragmentLayer::from_runs(lists.len(), |p, out| out.extend_from_slice(&lists[p]))
    }

    /// A layer of `pixels` pixels whose runs `fill(p, out)` pushes, in any order, into an empty
    /// scratch list.
    pub fn from_runs(
        pixels: usize,
        mut fill: impl FnMut(usize, &mut Vec<RayFragment>),
    ) -> FragmentLayer {
        let mut layer = LayerBuilder::new(pixels);
        for p in 0..pixels {
            layer.push(p, &mut fill);
        }
        layer.finish(pixels)
    }

    /// A layer of a `width`-pixel-wide image of `pixels` pixels whose runs `fill(p, out)` pushes
    /// for the pixels in columns `cols` of rows `rows` only; every other pixel's run is empty.
    /// Costs what the window holds plus one offset per pixel.
    pub fn from_window(
        pixels: usize,
        width: u32,
        cols: std::ops::Range<u32>,
        rows: std::ops::Range<u32>,
        mut fill: impl FnMut(usize, &mut Vec<RayFragment>),
    ) -> FragmentLayer {
        let mut layer = LayerBuilder::new(pixels);
        let cols = cols.start..cols.end.min(width);
        let width = width as usize;
        for y in rows {
            let row = y as usize * width;
            for x in cols.clone() {
                let p = row + x as usize;
                if p >= pixels {
                    break;
                }
                layer.push(p, &mut fill);
            }
        }
        layer.finish(pixels)
    }

    /// Pixels in the layer.
    pub fn pixels(&self) -> usize {
        self.starts.len().saturating_sub(1)
    }

    /// Fragments over all pixels.
    pub fn fragment_count(&self) -> usize {
        self.fragments.len()
    }

    /// Pixel `p`'s run, front to back (empty outside the layer).
    pub fn run(&self, p: usize) -> &[RayFragment] {
        match (self.starts.get(p), self.starts.get(p + 1)) {
            (Some(&a), Some(&b)) => &self.fragments[a..b],
            _ => &[],
        }
    }

    /// The distance of pixel `p`'s opaque fragment, `INFINITY` when its run has none.
    pub fn opaque_t(&self, p: usize) -> f32 {
        match self.run(p).last() {
            Some(f) if f.is_opaque() => f.t,
            _ => f32::INFINITY,
        }
    }

    /// The distance of pixel `p`'s nearest fragment, `INFINITY` when it has none.
    pub fn nearest_t(&self, p: usize) -> f32 {
        self.run(p).first().map_or(f32::INFINITY, |f| f.t)
    }

    /// Pixel `p`'s run merged with `other`'s run at the same pixel, settled, into `out`.
    pub fn merge_into(&self, other: &FragmentLayer, p: usize, out: &mut Vec<RayFragment>) {
        out.clear();
        out.extend_from_slice(self.run(p));
        out.extend_from_slice(other.run(p));
        settle(out);
    }
}

/// Builds a [`FragmentLayer`] pixel by pixel, in increasing pixel order; pixels skipped get
/// empty runs.
struct LayerBuilder {
    starts: Vec<usize>,
    fragments: Vec<RayFragment>,
    run: Vec<RayFragment>,
}

impl LayerBuilder {
    fn new(pixels: usize) -> Self {
        let mut starts = Vec::with_capacity(pixels + 1);
        starts.push(0);
        LayerBuilder {
            starts,
            fragments: Vec::new(),
            run: Vec::new(),
        }
    }

    /// Pixel `p`'s run, as `fill(p, out)` pushes it into an empty scratch list, settled.
    fn push(&mut self, p: usize, fill: &mut impl FnMut(usize, &mut Vec<RayFragment>)) {
        self.starts.resize(p + 1, self.fragments.len());
        self.run.clear();
        fill(p, &mut self.run);
        settle(&mut self.run);
        self.fragments.extend_from_slice(&self.run);
        self.starts.push(self.fragments.len());
    }

    fn finish(mut self, pixels: usize) -> FragmentLayer {
        self.starts.resize(pixels + 1, self.fragments.len());
        FragmentLayer {
            starts: self.starts,
            fragments: self.fragments,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frag(t: f32, alpha: f32, r: f32) -> RayFragment {
        RayFragment {
            t,
            color: [r, 0.5, 0.25],
            alpha,
        }
    }

    #[test]
    fn settle_sorts_and_cuts_at_the_first_opaque_fragment() {
        let mut run = vec![
            frag(3.0, 0.5, 0.1),
            frag(1.0, 0.5, 0.2),
            frag(2.0, 1.0, 0.3),
            frag(f32::NAN, 0.5, 0.4),
            frag(2.0, 0.5, 0.5),
        ];
        settle(&mut run);
        assert_eq!(run, vec![frag(1.0, 0.5, 0.2), frag(2.0, 1.0, 0.3)]);
    }

    #[test]
    fn a_layer_from_pairs_keeps_each_pixels_fragments() {
        let layer = FragmentLayer::from_pairs(
            3,
            &[
                (2, frag(2.0, 0.5, 0.0)),
                (0, frag(5.0, 1.0, 0.0)),
                (2, frag(1.0, 1.0, 0.0)),
                (7, frag(1.0, 1.0, 0.0)),
            ],
        );
        assert_eq!(layer.pixels(), 3);
        assert_eq!(layer.fragment_count(), 2);
        assert_eq!(layer.opaque_t(0), 5.0);
        assert_eq!(layer.run(1), &[]);
        assert_eq!(layer.opaque_t(1), f32::INFINITY);
        assert_eq!(layer.nearest_t(2), 1.0);
        assert_eq!(layer.run(2).len(), 1);
    }

    #[test]
    fn a_window_layer_is_the_full_layer_with_empty_runs_outside_the_window() {
        // 5 × 3 pixels, each with a fragment at t = its index; window columns 1..3, rows 1..3.
        let fill = |p: usize, out: &mut Vec<RayFragment>| out.push(frag(p as f32, 0.5, 0.0));
        let window = FragmentLayer::from_window(15, 5, 1..3, 1..3, fill);
        let full = FragmentLayer::from_runs(15, |p, out| {
            let (x, y) = (p % 5, p / 5);
            if (1..3).contains(&x) && (1..3).contains(&y) {
                fill(p, out);
            }
        });
        assert_eq!(window, full);
        assert_eq!(window.fragment_count(), 4);
        assert_eq!(window.nearest_t(12), 12.0);
        // Columns past the row's end do not spill into the next row.
        let wide = FragmentLayer::from_window(15, 5, 3..9, 0..1, fill);
        assert_eq!(wide.fragment_count(), 2);
        assert!(wide.run(5).is_empty());
    }
}
