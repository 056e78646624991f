//! The node's choice of fragments for the `depth-limited` transfer (Jähne 2014 ch. 3,
//! Algorithms A.2–A.3) applied to a whole frame, and [`restrict`], which keeps only some pixels'
//! runs.
//!
//! The rule is [`RunLimit`]'s: runs are sorted front to back, so "the N nearest" is a prefix of
//! each run, and so is "until the accumulated opacity reaches T". A render node applies it as
//! its store exports the frame ([`strata_stores::export_frame`]); [`depth_limit`] applies it to
//! a frame exported whole.
//!
//! [`restrict`] builds its output with `gather`: per pixel, a span of some source frame's
//! columns; counted in parallel chunks, prefix-summed, then copied in parallel chunks into
//! columns allocated once — no per-pixel allocation and no re-sorting (spans of sorted runs are
//! sorted).

use std::borrow::Cow;
use std::ops::Range;

use rayon::prelude::*;
use strata_core::{DeepFrame, ObjectId, Rgba8, RunLimit};
use strata_wire::PixelMask;

/// Pixels per parallel task.
const CHUNK: usize = 16 * 1024;

/// Builds a `width × height` frame whose pixel `p` holds fragments `span(p).1` (indices into the
/// columns of frame `span(p).0`, within one run of it).
pub(crate) fn gather<'a, F>(width: u32, height: u32, span: F) -> DeepFrame
where
    F: Fn(usize) -> (&'a DeepFrame, Range<usize>) + Sync,
{
    let pixels = width as usize * height as usize;
    let mut counts = vec![0u32; pixels];
    counts
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, out)| {
            for (i, n) in out.iter_mut().enumerate() {
                *n = span(c * CHUNK + i).1.len() as u32;
            }
        });
    let mut offsets = Vec::with_capacity(pixels + 1);
    let mut total = 0u32;
    offsets.push(0);
    for &n in &counts {
        total += n;
        offsets.push(total);
    }
    let n = total as usize;
    let (mut depth, mut color, mut object) = (
        vec![0f32; n],
        vec![Rgba8::default(); n],
        vec![ObjectId::default(); n],
    );
    let mut tasks = Vec::with_capacity(pixels / CHUNK + 1);
    {
        let (mut d, mut c, mut o) = (&mut depth[..], &mut color[..], &mut object[..]);
        for p0 in (0..pixels).step_by(CHUNK) {
            let p1 = (p0 + CHUNK).min(pixels);
            let len = (offsets[p1] - offsets[p0]) as usize;
            let (dh, dt) = std::mem::take(&mut d).split_at_mut(len);
            let (ch, ct) = std::mem::take(&mut c).split_at_mut(len);
            let (oh, ot) = std::mem::take(&mut o).split_at_mut(len);
            tasks.push((p0..p1, dh, ch, oh));
            (d, c, o) = (dt, ct, ot);
        }
    }
    tasks.into_par_iter().for_each(|(range, d, c, o)| {
        let mut at = 0;
        for p in range {
            let (src, r) = span(p);
            let len = r.len();
            d[at..at + len].copy_from_slice(&src.depths()[r.clone()]);
            c[at..at + len].copy_from_slice(&src.colors()[r.clone()]);
            o[at..at + len].copy_from_slice(&src.objects()[r]);
            at += len;
        }
    });
    DeepFrame::from_parts(width, height, offsets, depth, color, object)
        .expect("runs copied from valid frames form a valid frame")
}

/// The fragment range of pixel `p`'s whole run.
pub(crate) fn run_range(frame: &DeepFrame, p: usize) -> Range<usize> {
    frame.offsets()[p] as usize..frame.offsets()[p + 1] as usize
}

/// Keeps at most `layers` nearest fragments of every pixel, stopping early where the opacity
/// in front reaches `opacity_threshold` ([`RunLimit`]); borrows `frame` when that keeps
/// everything.
pub fn depth_limit(
    frame: &DeepFrame,
    layers: u32,
    opacity_threshold: Option<f32>,
) -> Cow<'_, DeepFrame> {
    let limit = RunLimit::new(layers, opacity_threshold);
    let offsets = frame.offsets();
    let colors = frame.colors();
    let keeps_all = offsets.par_windows(2).all(|w| {
        let (start, len) = (w[0] as usize, (w[1] - w[0]) as usize);
        limit.keep(len, |i| colors[start + i].0[3]) == len
    });
    if keeps_all {
        Cow::Borrowed(frame)
    } else {
        Cow::Owned(frame.clone().limit_runs(limit))
    }
}

/// The runs of `frame` at the pixels of `mask`; every other pixel is empty.
pub fn restrict(frame: &DeepFrame, mask: &PixelMask) -> DeepFrame {
    let flags = mask.to_flags();
    gather(frame.width(), frame.height(), |p| {
        if flags[p] {
            (frame, run_range(frame, p))
        } else {
            (frame, 0..0)
        }
    })
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
        assert!(
            matches!(depth_limit(&f, 100, None), Cow::Borrowed(_)),
            "nothing to cut"
        );
        assert_eq!(*depth_limit(&f, 10, None), f);
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
