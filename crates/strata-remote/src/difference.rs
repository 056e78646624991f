//! The `difference` transfer (Jähne 2014 ch. 4, Algorithms A.4–A.5), made exact.
//!
//! # What the thesis did, and why it could be wrong
//!
//! The thesis's render node resolved each frame, compared the colours with its previous frame and
//! sent the whole fragment list of every pixel whose colour changed; the display replaced those
//! lists. That is right for a pixel only one node draws: the display's colour there is the
//! node's colour. Where two nodes' objects overlap, the display interleaves their fragments by
//! depth, and a list whose colour did not change may still hold stale depths — an object moving
//! through another one composites in the wrong order (the thesis's fig. 4.3).
//!
//! # What strata does
//!
//! **Node** ([`DiffEncoder`]): keeps, per pixel, the *key* of what the display holds of it — the
//! 8-bit colour the node's own run resolves to over the scene background, plus whether the run is
//! empty. A pixel is sent when its key changed; an empty run sent is a deletion. Since the display
//! resolves a pixel only this node covers exactly as the node does, such pixels are exact.
//!
//! With a *tolerance* of `t` steps, a pixel whose colour moved by at most `t` in every channel
//! from the colour the display shows is not sent (coverage changes always are), and the key keeps
//! the colour the display shows, so the error never exceeds `t` and never accumulates. With
//! `t = 2` the display has no bad pixels by strata's definition (more than 2/255), which is
//! what Jähne 2014's "visual" difference aims at; `t = 0` is exact. The bound is for pixels one
//! node draws: a fixup replaces a shared pixel's run without the node updating its key, so where
//! nodes overlap a pixel that stops being shared may be off by up to `2t` until it next changes.
//!
//! The node also compares each unsent run with its previous frame's bit for bit: where they
//! differ (the surface moved in depth, the colour did not), the display's copy becomes *stale*,
//! and the delta says so in a second pixel mask.
//!
//! **Display** ([`NodeCopy`], [`stale_shared`]): holds one copy per node, applies each delta and
//! keeps a stale flag per pixel (set by the stale mask, cleared when the pixel is replaced). A
//! stale run is harmless where no other node has fragments. After all deltas of a frame, the
//! display asks each node for exact copies of its stale pixels that another node also covers
//! (a *fixup* of that frame), and resolves only then. So the merged image equals the exact render
//! of the whole scene; nodes that do not overlap, or overlap where nothing moves, never pay the
//! extra round, and a static scene sends nothing after its first frame.
//!
//! A fixup does not change what the node believes the display holds: the pixel's key is the same
//! by construction (that is why it was not sent), only the depths become current.
//!
//! # Layout
//!
//! Keys are one `u32` per pixel (`rgb | covered << 24`), compared in parallel chunks. Copies are
//! DeepFrames, rebuilt by one pass that copies unchanged spans of the old copy and changed runs of
//! the delta (`select::Columns`), so their runs stay sorted and contiguous for the merge.

use std::sync::Arc;

use rayon::prelude::*;
use strata_core::DeepFrame;
use strata_core::composite::resolve_pixel;
use strata_wire::{MaskBuilder, PixelMask};

use crate::select::{gather, restrict, run_range};

/// Pixels per parallel task when computing keys.
const CHUNK: usize = 16 * 1024;

/// The key of an empty run (no coverage bit).
const EMPTY: u32 = 0;

/// What decides whether the display must be told about a pixel: its resolved colour and coverage.
fn key(frame: &DeepFrame, p: usize, background: [f32; 3]) -> u32 {
    let run = frame.run(p);
    if run.is_empty() {
        return EMPTY;
    }
    let [r, g, b] = resolve_pixel(run.color.iter().copied(), background);
    u32::from_le_bytes([r, g, b, 1])
}

/// The node's side: what the display holds, and the delta that brings it to a new frame.
#[derive(Debug, Clone)]
pub struct DiffEncoder {
    background: [f32; 3],
    tolerance: u8,
    /// Per pixel, the key of the run the display holds; empty after a reset.
    keys: Vec<u32>,
    scratch: Vec<u32>,
    /// The previous frame, to find runs that changed without changing their key.
    previous: Option<Arc<DeepFrame>>,
}

/// A delta: what the display must replace, and where its copy became stale.
#[derive(Debug, Clone, PartialEq)]
pub struct Delta {
    /// Pixels whose runs `runs` replaces.
    pub changed: PixelMask,
    /// Pixels not replaced whose run differs from the previous frame's.
    pub stale: PixelMask,
    /// The runs at `changed`; empty elsewhere.
    pub runs: DeepFrame,
}

/// True when pixel `p` holds the same fragments, bit for bit, in both frames.
fn same_run(a: &DeepFrame, b: &DeepFrame, p: usize) -> bool {
    let (x, y) = (a.run(p), b.run(p));
    x.len() == y.len()
        && x.object == y.object
        && x.color == y.color
        && x.depth
            .iter()
            .zip(y.depth)
            .all(|(d, e)| d.to_bits() == e.to_bits())
}

impl DiffEncoder {
    /// A node whose display holds nothing yet; colour changes of at most `tolerance` 8-bit steps
    /// are not sent.
    pub fn new(background: [f32; 3], tolerance: u8) -> Self {
        DiffEncoder {
            background,
            tolerance,
            keys: Vec::new(),
            scratch: Vec::new(),
            previous: None,
        }
    }

    /// Forgets what the display holds (a new connection, or the display asked for a reset).
    pub fn reset(&mut self) {
        self.keys.clear();
        self.previous = None;
    }

    /// The pixels whose key changed since the last delta with their runs of `frame` (an empty
    /// masked run is a deletion), and the pixels whose held copy became stale. Afterwards the
    /// display is assumed to hold them.
    pub fn diff(&mut self, frame: Arc<DeepFrame>) -> Delta {
        let pixels = frame.width() as usize * frame.height() as usize;
        if self.keys.len() != pixels {
            // A new size or a reset: the display holds nothing.
            self.keys.clear();
            self.keys.resize(pixels, EMPTY);
            self.previous = None;
        }
        let frame_ref: &DeepFrame = &frame;
        self.scratch.resize(pixels, EMPTY);
        let bg = self.background;
        self.scratch
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (i, k) in out.iter_mut().enumerate() {
                    *k = key(frame_ref, c * CHUNK + i, bg);
                }
            });
        let tol = self.tolerance;
        let differs = move |new: u32, old: u32| -> bool {
            let (a, b) = (new.to_le_bytes(), old.to_le_bytes());
            a[3] != b[3] || (0..3).any(|c| a[c].abs_diff(b[c]) > tol)
        };
        let mut changed = MaskBuilder::new(pixels as u32);
        for (p, (new, old)) in self.scratch.iter().zip(&self.keys).enumerate() {
            if differs(*new, *old) {
                changed.push(p as u32);
            }
        }
        // Unsent covered pixels whose run moved: compare with the previous frame in parallel
        // chunks (flags, then runs of them).
        let mut moved = vec![false; pixels];
        if let Some(prev) = &self.previous {
            let (keys_new, keys_old) = (&self.scratch, &self.keys);
            moved
                .par_chunks_mut(CHUNK)
                .enumerate()
                .for_each(|(c, out)| {
                    for (i, m) in out.iter_mut().enumerate() {
                        let p = c * CHUNK + i;
                        *m = !differs(keys_new[p], keys_old[p])
                            && keys_new[p] != EMPTY
                            && !same_run(prev, frame_ref, p);
                    }
                });
        }
        // The display now shows the new colour where the pixel was sent, the old one elsewhere.
        for (new, old) in self.scratch.iter().zip(self.keys.iter_mut()) {
            if differs(*new, *old) {
                *old = *new;
            }
        }
        let changed = changed.finish();
        let stale = PixelMask::from_flags(&moved);
        let runs = restrict(frame_ref, &changed);
        self.previous = Some(frame);
        Delta {
            changed,
            stale,
            runs,
        }
    }
}

/// The display's copy of one node's runs, and which of them may hold stale depths.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeCopy {
    frame: DeepFrame,
    stale: Vec<bool>,
}

impl NodeCopy {
    /// Nothing held, for a `width × height` display.
    pub fn empty(width: u32, height: u32) -> Self {
        NodeCopy {
            frame: DeepFrame::empty(width, height),
            stale: vec![false; width as usize * height as usize],
        }
    }

    /// Pixels whose runs may hold stale depths.
    pub fn stale(&self) -> &[bool] {
        &self.stale
    }

    /// The runs held.
    pub fn frame(&self) -> &DeepFrame {
        &self.frame
    }

    /// Replaces everything (the `full` and `depth-limited` transfers); returns the frame it
    /// held, for its memory to be reused.
    pub fn replace(&mut self, frame: DeepFrame) -> DeepFrame {
        self.stale.fill(false);
        std::mem::replace(&mut self.frame, frame)
    }

    /// Applies a delta: marks `stale`, then replaces the runs at `changed` by those of `runs`
    /// (the same size; checked by the caller against the display's size).
    pub fn apply_delta(&mut self, changed: &PixelMask, stale: &PixelMask, runs: &DeepFrame) {
        for p in stale.iter() {
            self.stale[p as usize] = true;
        }
        self.apply(changed, runs);
    }

    /// Replaces the runs at the pixels of `changed` by those of `delta`, which are exact.
    pub fn apply(&mut self, changed: &PixelMask, delta: &DeepFrame) {
        for &(s, l) in changed.runs() {
            self.stale[s as usize..(s + l) as usize].fill(false);
        }
        let flags = changed.to_flags();
        let old = &self.frame;
        let frame = gather(old.width(), old.height(), |p| {
            let src = if flags[p] { delta } else { old };
            (src, run_range(src, p))
        });
        self.frame = frame;
    }
}

/// For each node, the pixels it must resend exactly: stale in its copy and covered by at least
/// one other node's copy. Nodes not taking part this frame (`taking_part[i]` false) are asked for
/// nothing.
pub fn stale_shared(copies: &[&NodeCopy], taking_part: &[bool]) -> Vec<PixelMask> {
    assert_eq!(copies.len(), taking_part.len());
    let Some(first) = copies.first() else {
        return Vec::new();
    };
    let pixels = first.stale.len();
    let mut builders: Vec<MaskBuilder> = (0..copies.len())
        .map(|_| MaskBuilder::new(pixels as u32))
        .collect();
    for p in 0..pixels {
        if !copies
            .iter()
            .zip(taking_part)
            .any(|(c, &t)| t && c.stale[p])
        {
            continue;
        }
        let covering = copies.iter().filter(|c| !c.frame.run(p).is_empty()).count();
        if covering < 2 {
            continue;
        }
        for (i, c) in copies.iter().enumerate() {
            if taking_part[i] && c.stale[p] {
                builders[i].push(p as u32);
            }
        }
    }
    builders.into_iter().map(MaskBuilder::finish).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{Fragment, ObjectId, Rgba8};

    fn frag(depth: f32, object: u32, r: u8) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([r, 0, 0, 128]),
            object: ObjectId(object),
        }
    }

    const BG: [f32; 3] = [1.0, 1.0, 1.0];

    #[test]
    fn only_changed_pixels_are_sent_and_the_copy_follows() {
        let f0 = DeepFrame::from_pixel_lists(
            4,
            1,
            &[
                vec![frag(0.5, 1, 10)],
                vec![frag(0.5, 1, 20)],
                vec![],
                vec![frag(0.2, 1, 30)],
            ],
        )
        .unwrap();
        // Pixel 0 moves in depth only (same colour), 1 changes colour, 2 appears, 3 disappears.
        let f1 = DeepFrame::from_pixel_lists(
            4,
            1,
            &[
                vec![frag(0.6, 1, 10)],
                vec![frag(0.5, 1, 99)],
                vec![frag(0.1, 1, 5)],
                vec![],
            ],
        )
        .unwrap();
        let (f0, f1) = (Arc::new(f0), Arc::new(f1));
        let mut enc = DiffEncoder::new(BG, 0);
        let mut copy = NodeCopy::empty(4, 1);
        let d0 = enc.diff(f0.clone());
        assert_eq!(d0.changed.iter().collect::<Vec<_>>(), vec![0, 1, 3]);
        assert!(d0.stale.is_empty());
        copy.apply_delta(&d0.changed, &d0.stale, &d0.runs);
        assert_eq!(copy.frame(), &*f0);
        let d1 = enc.diff(f1.clone());
        assert_eq!(d1.changed.iter().collect::<Vec<_>>(), vec![1, 2, 3]);
        assert_eq!(
            d1.stale.iter().collect::<Vec<_>>(),
            vec![0],
            "pixel 0 moved in depth"
        );
        copy.apply_delta(&d1.changed, &d1.stale, &d1.runs);
        // The copy resolves exactly like the frame although pixel 0's depth is stale.
        assert_eq!(copy.frame().resolve(BG), f1.resolve(BG));
        assert_eq!(copy.frame().run(0).depth, &[0.5]);
        assert_eq!(copy.stale(), &[true, false, false, false]);
        // Unchanged input sends nothing and marks nothing; a reset sends every covered pixel.
        let d2 = enc.diff(f1.clone());
        assert!(d2.changed.is_empty() && d2.stale.is_empty());
        enc.reset();
        assert_eq!(
            enc.diff(f1).changed.iter().collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
    }

    #[test]
    fn a_tolerance_bounds_the_error_without_drift() {
        // One pixel whose colour creeps up by one step per frame.
        let frames: Vec<Arc<DeepFrame>> = (0..10u8)
            .map(|i| {
                let f = Fragment {
                    depth: 0.5,
                    color: Rgba8([100 + i, 50, 50, 255]),
                    object: ObjectId(1),
                };
                Arc::new(DeepFrame::from_pixel_lists(1, 1, &[vec![f]]).unwrap())
            })
            .collect();
        let mut enc = DiffEncoder::new(BG, 2);
        let mut copy = NodeCopy::empty(1, 1);
        let mut sent = Vec::new();
        for (i, f) in frames.iter().enumerate() {
            let d = enc.diff(f.clone());
            copy.apply_delta(&d.changed, &d.stale, &d.runs);
            if !d.changed.is_empty() {
                sent.push(i);
            }
            let shown = copy.frame().resolve(BG).pixel(0, 0)[0];
            assert!(
                shown.abs_diff(100 + i as u8) <= 2,
                "frame {i}: shows {shown}"
            );
        }
        // Sent at 0, then whenever the drift would exceed 2: 3, 6, 9.
        assert_eq!(sent, vec![0, 3, 6, 9]);
    }

    #[test]
    fn stale_shared_pixels_are_those_another_node_also_covers() {
        let a = DeepFrame::from_pixel_lists(
            3,
            1,
            &[vec![frag(0.5, 1, 1)], vec![frag(0.5, 1, 1)], vec![]],
        )
        .unwrap();
        let b = DeepFrame::from_pixel_lists(
            3,
            1,
            &[vec![], vec![frag(0.4, 2, 1)], vec![frag(0.4, 2, 1)]],
        )
        .unwrap();
        let (mut ca, mut cb) = (NodeCopy::empty(3, 1), NodeCopy::empty(3, 1));
        ca.replace(a);
        cb.replace(b);
        let all = PixelMask::full(3);
        // Node a's pixels 0 and 1 went stale; only 1 is shared with b.
        ca.apply_delta(
            &PixelMask::empty(3),
            &PixelMask::from_fn(3, |p| p < 2),
            &DeepFrame::empty(3, 1),
        );
        let s = stale_shared(&[&ca, &cb], &[true, true]);
        assert_eq!(s[0].iter().collect::<Vec<_>>(), vec![1]);
        assert!(s[1].is_empty(), "b's copy is exact");
        let s = stale_shared(&[&ca, &cb], &[false, true]);
        assert!(s[0].is_empty(), "an absent node is asked for nothing");
        // Replacing clears the flags.
        let runs = ca.frame().clone();
        ca.apply(&all, &runs);
        assert!(
            stale_shared(&[&ca, &cb], &[true, true])
                .iter()
                .all(PixelMask::is_empty)
        );
    }
}
