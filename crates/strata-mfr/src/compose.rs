//! Composition of the two clients' frames: deep (strata) and digital (the seed's colour + depth).
//!
//! Per pixel `p`, with `F` the ids the FC draws this frame:
//!
//! ```text
//! run(p) = merge( [f ∈ run_sc(p) : f.object ∉ F],  run_fc(p) )      (both sorted front to back)
//! ```
//!
//! Every run is sorted by [`strata_core::Fragment::order_key`] (depth, object, colour), so merging
//! two sorted runs gives exactly the sorted union. If every object is rendered by exactly one of
//! the two sides at the FC's transforms and through the same view, the result is the run the whole
//! scene rendered at once would hold, bit for bit — whatever the timing. The SC's fragments of an
//! object in `F` are stale (the object moved, or is being handed over) and are dropped; that is
//! what removes the seed's selection and release artefacts and lets transparent objects cross
//! between the clients.

use strata_core::composite::resolve_pixel;
use strata_core::{DeepFrame, DeepFrameError, Fragment, ObjectId, Rgb8Image, Run};

use crate::window::DeepWindow;

/// How the FC combines its fragments with the SC buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Composition {
    /// Merge fragment lists, dropping the SC's fragments of the objects the FC draws (exact).
    Deep,
    /// The seed's digital composition (Springer 2008 §3.2): the SC's resolved colour and the
    /// depth of its front fragment; FC fragments in front of that depth are blended over the
    /// colour, the others are lost. Stale SC copies cannot be removed.
    Digital,
}

/// `fc`'s width, height and pixel count, if `sc` has the same size.
fn same_size(sc: &DeepFrame, fc: &DeepFrame) -> Result<(u32, u32, usize), DeepFrameError> {
    let (w, h) = (fc.width(), fc.height());
    let pixels = w as usize * h as usize;
    if sc.width() != w || sc.height() != h {
        return Err(DeepFrameError::PixelCount {
            width: w,
            height: h,
            expected: pixels as u64,
            found: u64::from(sc.width()) * u64::from(sc.height()),
        });
    }
    Ok((w, h, pixels))
}

/// The deep composition of `sc` minus the objects in `fc_objects` (sorted ids) with `fc`.
///
/// # Errors
/// When the frames differ in size or the result holds more fragments than a DeepFrame can.
pub fn compose_deep(
    sc: &DeepFrame,
    fc: &DeepFrame,
    fc_objects: &[ObjectId],
) -> Result<DeepFrame, DeepFrameError> {
    let (w, h, pixels) = same_size(sc, fc)?;
    let dropped = |o: &ObjectId| fc_objects.binary_search(o).is_ok();
    let counts: Vec<u32> = (0..pixels)
        .map(|p| {
            let kept = sc.run(p).object.iter().filter(|o| !dropped(o)).count();
            (kept + fc.run(p).len()) as u32
        })
        .collect();
    DeepFrame::build(w, h, &counts, |p, out| {
        out.extend(sc.run(p).iter().filter(|f| !dropped(&f.object)));
        out.extend(fc.run(p).iter());
    })
}

/// The deep composition's image, at a cost that follows the FC's footprint: the SC's resolved
/// image, with only the pixels that change re-resolved — those the FC covers (inside its
/// window) and, when the FC draws objects the SC buffer holds, those holding fragments of them.
/// Equal, pixel for pixel, to `compose_deep(sc, &fc.to_full()?, fc_objects)?.resolve(background)`
/// (tested).
pub fn compose_image(
    sc: &DeepFrame,
    sc_image: &Rgb8Image,
    fc: &DeepWindow,
    fc_objects: &[ObjectId],
    sc_holds_fc_objects: bool,
    background: [f32; 3],
) -> Rgb8Image {
    let mut image = sc_image.clone();
    let dropped = |o: &ObjectId| fc_objects.binary_search(o).is_ok();
    let width = sc.width();
    let bytes = image.as_bytes_mut();
    let mut resolve_at = |p: usize, own: Run<'_>| {
        let mut kept = sc.run(p).iter().filter(|x| !dropped(&x.object)).peekable();
        let mut own = own.iter().peekable();
        let merged = std::iter::from_fn(|| {
            let take_sc = match (kept.peek(), own.peek()) {
                (Some(a), Some(b)) => Fragment::order_key(a) <= Fragment::order_key(b),
                (Some(_), None) => true,
                (None, Some(_)) => false,
                (None, None) => return None,
            };
            let next = if take_sc { kept.next() } else { own.next() };
            next.map(|x| x.color)
        });
        let rgb = resolve_pixel(merged, background);
        let at = 3 * p;
        bytes[at..at + 3].copy_from_slice(&rgb);
    };
    let rect = fc.rect();
    for q in 0..rect.pixel_count() {
        let own = fc.frame().run(q);
        if !own.is_empty() {
            resolve_at(rect.frame_index(q, width), own);
        }
    }
    if sc_holds_fc_objects {
        // Stale SC copies of the FC's objects, wherever they are (re-resolving a pixel twice
        // gives the same colour).
        for p in 0..sc.offsets().len().saturating_sub(1) {
            if sc.run(p).object.iter().any(dropped) {
                let (x, y) = ((p as u32) % width, (p as u32) / width);
                let none = Run {
                    depth: &[],
                    color: &[],
                    object: &[],
                };
                resolve_at(p, fc.run_at(x, y).unwrap_or(none));
            }
        }
    }
    image
}

/// The seed's digital composition as the run it shows: per pixel, the FC fragments in front of
/// the SC's front fragment (`D_sc`; 1 where the SC has none; a transparent fragment writes depth,
/// as in GL), then the whole SC run. Resolving it gives `resolve_over(C_sc, kept FC fragments)`,
/// the seed's image, and the audit can see which objects it shows.
///
/// # Errors
/// When the frames differ in size.
pub fn compose_digital(sc: &DeepFrame, fc: &DeepFrame) -> Result<DeepFrame, DeepFrameError> {
    let (w, h, pixels) = same_size(sc, fc)?;
    let front = |p: usize| sc.run(p).depth.first().copied().unwrap_or(f32::INFINITY);
    let counts: Vec<u32> = (0..pixels)
        .map(|p| {
            let d = front(p);
            let kept = fc.run(p).depth.iter().filter(|&&z| z < d).count();
            (kept + sc.run(p).len()) as u32
        })
        .collect();
    DeepFrame::build(w, h, &counts, |p, out| {
        let d = front(p);
        out.extend(fc.run(p).iter().filter(|f| f.depth < d));
        out.extend(sc.run(p).iter());
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use strata_core::{Fragment, Rgba8};

    fn fragment() -> impl Strategy<Value = Fragment> {
        (0u32..64, 0u32..6, any::<[u8; 4]>()).prop_map(|(d, o, c)| Fragment {
            depth: d as f32 / 64.0,
            color: Rgba8(c),
            object: ObjectId(o),
        })
    }

    fn lists(pixels: usize) -> impl Strategy<Value = Vec<Vec<Fragment>>> {
        prop::collection::vec(prop::collection::vec(fragment(), 0..6), pixels)
    }

    proptest! {
        /// The merge equals sorting the union of the SC's kept fragments and the FC's, for any
        /// runs (ties included) and any set of dropped objects, across chunk boundaries.
        #[test]
        fn merging_equals_sorting_the_union(
            sc in lists(37),
            fc in lists(37),
            dropped in prop::collection::btree_set(0u32..6, 0..4),
        ) {
            let (w, h) = (37, 1);
            let ids: Vec<ObjectId> = dropped.iter().map(|&o| ObjectId(o)).collect();
            let a = DeepFrame::from_pixel_lists(w, h, &sc).expect("sc");
            let b = DeepFrame::from_pixel_lists(w, h, &fc).expect("fc");
            let union: Vec<Vec<Fragment>> = sc
                .iter()
                .zip(&fc)
                .map(|(s, f)| {
                    s.iter()
                        .filter(|x| !dropped.contains(&x.object.0))
                        .chain(f)
                        .copied()
                        .collect()
                })
                .collect();
            let expected = DeepFrame::from_pixel_lists(w, h, &union).expect("union");
            prop_assert_eq!(compose_deep(&a, &b, &ids).expect("composed"), expected);
        }

        /// The footprint-only image equals resolving the full composition, for an FC window
        /// anywhere in the frame, whether or not the SC buffer holds the FC's objects.
        #[test]
        fn the_image_re_resolves_exactly_what_changes(
            sc in lists(6 * 5),
            window in lists(3 * 2),
            (x, y) in (0u32..4, 0u32..4),
            dropped in prop::collection::btree_set(0u32..6, 0..3),
        ) {
            let (w, h) = (6u32, 5u32);
            let rect = strata_core::PixelRect { x, y, width: 3, height: 2 };
            let ids: Vec<ObjectId> = dropped.iter().map(|&o| ObjectId(o)).collect();
            let sc = DeepFrame::from_pixel_lists(w, h, &sc).expect("sc");
            let part = DeepFrame::from_pixel_lists(3, 2, &window).expect("window");
            let fc = DeepWindow::new(rect, (w, h), part).expect("fits");
            let bg = [0.25, 0.5, 1.0];
            let expected = compose_deep(&sc, &fc.to_full().expect("full"), &ids)
                .expect("composed")
                .resolve(bg);
            let holds = sc.objects().iter().any(|o| ids.contains(o));
            let image = compose_image(&sc, &sc.resolve(bg), &fc, &ids, holds, bg);
            prop_assert_eq!(image, expected);
        }
    }

    #[test]
    fn merging_across_chunks_of_pixels() {
        // More pixels than one parallel task holds, so chunk boundaries are crossed.
        let (w, h) = (4099u32, 3u32);
        let pixels = (w * h) as usize;
        let frag = |p: usize, k: u32, o: u32| Fragment {
            depth: ((p as u32 * 7 + k * 13) % 97) as f32 / 97.0,
            color: Rgba8([k as u8, o as u8, p as u8, 200]),
            object: ObjectId(o),
        };
        let sc: Vec<Vec<Fragment>> = (0..pixels)
            .map(|p| (0..(p % 4) as u32).map(|k| frag(p, k, k % 3)).collect())
            .collect();
        let fc: Vec<Vec<Fragment>> = (0..pixels)
            .map(|p| (0..(p % 3) as u32).map(|k| frag(p, k + 5, 4)).collect())
            .collect();
        let ids = [ObjectId(1)];
        let a = DeepFrame::from_pixel_lists(w, h, &sc).expect("sc");
        let b = DeepFrame::from_pixel_lists(w, h, &fc).expect("fc");
        let union: Vec<Vec<Fragment>> = sc
            .iter()
            .zip(&fc)
            .map(|(s, f)| {
                s.iter()
                    .filter(|x| x.object != ObjectId(1))
                    .chain(f)
                    .copied()
                    .collect()
            })
            .collect();
        let expected = DeepFrame::from_pixel_lists(w, h, &union).expect("union");
        assert_eq!(compose_deep(&a, &b, &ids).expect("composed"), expected);
    }
}
