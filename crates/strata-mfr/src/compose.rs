//! Composition of the two clients' frames: deep (strata), and digital (colour + depth) and optical
//! (the FC's image over the SC's) as the seed has them.
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
//!
//! # Digital and optical composition (the seed's, kept to show their artefacts)
//!
//! *Digital* (seed 004 §3.2) keeps the SC's colour and the depth of its front fragment; FC
//! fragments behind that depth are lost ([`compose_digital`]).
//!
//! *Optical* (seed 004 §3.1) is two overlapped projectors, one per client: the user sees the two
//! images on top of each other, with no depth test between them. The seed's projectors *add*
//! light, `SC(p) + FC(p)` with the FC image on black; strata composites the FC's image **over**
//! the SC's instead, in screen space:
//!
//! ```text
//! optical(p) = resolve( run_fc(p) ++ run_sc(p) )       the FC's fragments first, whatever their depth
//!            = C_fc(p) + T_fc(p) · resolve(run_sc(p))   (C_fc premultiplied, T_fc its transmittance)
//! ```
//!
//! Why over and not the sum: the sum equals this wherever the SC image is black behind the FC's
//! objects (a projection screen in a dark room), but on any other background it washes the FC's
//! objects out towards white even where nothing hides them, so no frame could ever be right; with
//! over, an FC object in front of everything the SC draws is exact, and what remains is the
//! artefact the seed describes: no occlusion between the clients, the FC's objects always drawn
//! over the SC's (an FC object behind an SC object shows through it; one behind a transparent SC
//! object is not tinted by it). Stale SC copies cannot be removed either.
//!
//! [`compose_optical`] gives the run the user sees, for the audit: per pixel, the FC's fragments
//! in their depth order and then the whole SC run; where an FC fragment lies behind the SC's front
//! fragment, the FC's depths are scaled by the largest power of two that puts them in front of it
//! (exact, so their order is kept). [`compose_optical_image`] makes the image at the cost of the
//! FC's footprint.

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
    /// The seed's optical superposition (Springer 2008 §3.1), as the FC's image over the SC's in
    /// screen space: no depth test between the clients, FC objects always in front; exact only
    /// where the FC's objects lie in front of everything the SC draws. Stale SC copies cannot be
    /// removed.
    Optical,
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

/// The factor that puts FC fragments no deeper than `fc_back` in front of the SC's front fragment
/// at `sc_front`: 1 when they already lie in front, else the largest power of two that does
/// (multiplying by a power of two is exact, so the FC fragments keep their order). An SC front
/// fragment exactly on the near plane (depth 0) cannot be passed; the FC's depths then shrink
/// towards 0 and tie-break behind it.
fn optical_scale(fc_back: f32, sc_front: f32) -> f32 {
    let mut scale = 1.0f32;
    while fc_back * scale >= sc_front && scale > f32::MIN_POSITIVE {
        scale *= 0.5;
    }
    scale
}

/// The optical composition as the run the user sees: per pixel the FC's fragments, in their
/// order, in front of the whole SC run (their depths scaled where needed; see the module docs).
/// Resolving it gives the image [`compose_optical_image`] makes.
///
/// # Errors
/// When the frames differ in size or the result holds more fragments than a DeepFrame can.
pub fn compose_optical(sc: &DeepFrame, fc: &DeepFrame) -> Result<DeepFrame, DeepFrameError> {
    let (w, h, pixels) = same_size(sc, fc)?;
    let counts: Vec<u32> = (0..pixels)
        .map(|p| (sc.run(p).len() + fc.run(p).len()) as u32)
        .collect();
    DeepFrame::build(w, h, &counts, |p, out| {
        let (s, f) = (sc.run(p), fc.run(p));
        let front = s.depth.first().copied().unwrap_or(f32::INFINITY);
        let back = f.depth.last().copied().unwrap_or(0.0);
        let scale = optical_scale(back, front);
        out.extend(f.iter().map(|x| Fragment {
            depth: x.depth * scale,
            ..x
        }));
        out.extend(s.iter());
    })
}

/// The optical composition's image, at a cost that follows the FC's footprint: the SC's resolved
/// image, with the pixels the FC covers re-resolved from the FC's fragments followed by the SC's.
/// Equal, pixel for pixel, to `compose_optical(sc, fc)?.resolve(background)` (tested).
pub fn compose_optical_image(
    sc: &DeepFrame,
    sc_image: &Rgb8Image,
    fc: &DeepWindow,
    background: [f32; 3],
) -> Rgb8Image {
    let mut image = sc_image.clone();
    let bytes = image.as_bytes_mut();
    let rect = fc.rect();
    for q in 0..rect.pixel_count() {
        let f = fc.frame().run(q);
        if f.is_empty() {
            continue;
        }
        let p = rect.frame_index(q, sc.width());
        let colors = f.color.iter().chain(sc.run(p).color).copied();
        let at = 3 * p;
        bytes[at..at + 3].copy_from_slice(&resolve_pixel(colors, background));
    }
    image
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

    proptest! {
        /// The optical run puts every FC fragment in front of every SC fragment, keeps both
        /// sides' fragments and their order, and resolves to the footprint-only image.
        #[test]
        fn optical_puts_the_fc_in_front_and_its_image_is_the_runs_resolve(
            // No SC fragment on the near plane (depth 0), which nothing can lie in front of.
            sc in lists(23).prop_map(|l| l.into_iter().map(|run| {
                run.into_iter().map(|f| Fragment { depth: f.depth.max(1.0 / 128.0), ..f }).collect()
            }).collect::<Vec<Vec<Fragment>>>()),
            fc in lists(23),
        ) {
            let (w, h) = (23, 1);
            let a = DeepFrame::from_pixel_lists(w, h, &sc).expect("sc");
            let b = DeepFrame::from_pixel_lists(w, h, &fc).expect("fc");
            let optical = compose_optical(&a, &b).expect("composed");
            for p in 0..sc.len() {
                let (run, s, f) = (optical.run(p), a.run(p), b.run(p));
                prop_assert_eq!(run.len(), s.len() + f.len());
                prop_assert_eq!(&run.object[..f.len()], f.object);
                prop_assert_eq!(&run.color[..f.len()], f.color);
                prop_assert_eq!(&run.object[f.len()..], s.object);
                prop_assert_eq!(&run.depth[f.len()..], s.depth);
            }
            let background = [0.9, 0.8, 0.7];
            let whole = DeepWindow::whole(b.clone());
            let image = compose_optical_image(&a, &a.resolve(background), &whole, background);
            prop_assert_eq!(image, optical.resolve(background));
            // The same through a window holding the FC's fragments.
            let lists: Vec<Vec<Fragment>> = (0..23).map(|p| b.run(p).iter().collect()).collect();
            let first = lists.iter().position(|l| !l.is_empty()).unwrap_or(0);
            let last = lists.iter().rposition(|l| !l.is_empty()).unwrap_or(0);
            let rect = strata_core::PixelRect { x: first as u32, y: 0, width: (last.max(first) - first + 1) as u32, height: 1 };
            let part = DeepFrame::from_pixel_lists(rect.width, 1, &lists[first..=last.max(first)]).expect("window");
            let window = DeepWindow::new(rect, (w, h), part).expect("fits");
            let image = compose_optical_image(&a, &a.resolve(background), &window, background);
            prop_assert_eq!(image, optical.resolve(background));
        }
    }

    #[test]
    fn optical_equals_deep_where_the_fc_lies_in_front() {
        let frag = |depth: f32, object: u32, a: u8| Fragment {
            depth,
            color: Rgba8([(object * 30) as u8, 90, 200, a]),
            object: ObjectId(object),
        };
        let sc = DeepFrame::from_pixel_lists(
            2,
            1,
            &[vec![frag(0.5, 1, 100), frag(0.7, 2, 255)], vec![]],
        )
        .expect("sc");
        let fc =
            DeepFrame::from_pixel_lists(2, 1, &[vec![frag(0.3, 7, 128)], vec![frag(0.9, 7, 128)]])
                .expect("fc");
        assert_eq!(
            compose_optical(&sc, &fc).expect("optical"),
            compose_deep(&sc, &fc, &[ObjectId(7)]).expect("deep")
        );
        // Behind the SC's front fragment, the FC's fragment is still shown in front of it.
        let behind =
            DeepFrame::from_pixel_lists(2, 1, &[vec![frag(0.6, 7, 128)], vec![]]).expect("fc");
        let optical = compose_optical(&sc, &behind).expect("optical");
        assert_eq!(
            optical.run(0).object,
            [ObjectId(7), ObjectId(1), ObjectId(2)]
        );
        // 0.6 halved once lies in front of 0.5.
        assert_eq!(optical.run(0).depth[0], 0.3);
        assert_ne!(
            optical.resolve([1.0; 3]),
            compose_deep(&sc, &behind, &[ObjectId(7)])
                .expect("deep")
                .resolve([1.0; 3])
        );
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
