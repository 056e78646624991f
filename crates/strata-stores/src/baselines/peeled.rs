//! The peeling methods' DeepFrame export: fragments kept pass by pass, grouped by pixel.
//!
//! Depth peeling and dual depth peeling keep every peeled fragment with its pixel index, in the
//! order the passes peeled them (`[(pixel, fragment)]`, pixels interleaved), and count per pixel
//! how many they peeled. The export is the S-buffer's gather:
//!
//! ```text
//! counts   [2, 0, 1, ...]          per pixel, from the method's state
//! offsets  [0, 2, 2, 3, ...]       exclusive prefix sum
//! grouped  [p0 f, p0 f, p2 f, ...] each fragment put at its pixel's cursor
//! ```
//!
//! then [`DeepFrame::build`] sorts each pixel's run (dual peeling peels a pixel from both ends, so
//! its fronts and backs arrive interleaved; single peeling's runs are already in order).

use strata_core::{DeepFrame, DeepFrameError, Fragment};

use crate::regions::exclusive_prefix_sum;

/// Groups `peeled` fragments by pixel into a `width` × `height` DeepFrame; `counts[p]` says how
/// many of them belong to pixel `p`. A pixel given more or fewer fragments than its count is a
/// [`DeepFrameError::CountMismatch`].
pub(crate) fn peeled_to_deep_frame<'a>(
    width: u32,
    height: u32,
    counts: &[u32],
    peeled: impl IntoIterator<Item = &'a (u32, Fragment)>,
) -> Result<DeepFrame, DeepFrameError> {
    let (offsets, total) = exclusive_prefix_sum(counts);
    if total > u64::from(u32::MAX) {
        return Err(DeepFrameError::TooManyFragments(total));
    }
    let mut grouped = vec![Fragment::default(); total as usize];
    let mut cursor = offsets[..counts.len()].to_vec();
    for &(pixel, fragment) in peeled {
        let p = pixel as usize;
        let Some(slot) = cursor.get_mut(p).filter(|slot| **slot < offsets[p + 1]) else {
            return Err(DeepFrameError::CountMismatch {
                pixel: p,
                expected: counts.get(p).copied().unwrap_or(0),
                found: counts.get(p).map_or(1, |&c| c as usize + 1),
            });
        };
        grouped[*slot as usize] = fragment;
        *slot += 1;
    }
    DeepFrame::build(width, height, counts, |p, out| {
        out.extend_from_slice(&grouped[offsets[p] as usize..cursor[p] as usize]);
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_core::{ObjectId, Rgba8};

    fn frag(depth: f32, o: u32) -> Fragment {
        Fragment {
            depth,
            color: Rgba8([10, 20, 30, 128]),
            object: ObjectId(o),
        }
    }

    #[test]
    fn groups_by_pixel_and_sorts_each_run() {
        // 2×1 frame: pixel 1 peeled from both ends (0.9 arrives before 0.5), pixel 0 once.
        let peeled = [
            (1, frag(0.1, 1)),
            (1, frag(0.9, 2)),
            (0, frag(0.3, 3)),
            (1, frag(0.5, 4)),
        ];
        let deep = peeled_to_deep_frame(2, 1, &[1, 3], &peeled).unwrap();
        let depths = |p| deep.run(p).iter().map(|f| f.depth).collect::<Vec<_>>();
        assert_eq!(depths(0), [0.3]);
        assert_eq!(depths(1), [0.1, 0.5, 0.9]);
    }

    #[test]
    fn counts_that_disagree_with_the_fragments_are_errors() {
        let peeled = [(0, frag(0.1, 1)), (0, frag(0.2, 1))];
        assert!(matches!(
            peeled_to_deep_frame(2, 1, &[1, 0], &peeled),
            Err(DeepFrameError::CountMismatch {
                pixel: 0,
                expected: 1,
                found: 2
            })
        ));
        assert!(matches!(
            peeled_to_deep_frame(2, 1, &[2, 1], &peeled),
            Err(DeepFrameError::CountMismatch {
                pixel: 1,
                expected: 1,
                found: 0
            })
        ));
        assert!(matches!(
            peeled_to_deep_frame(1, 1, &[2], &[(5, frag(0.1, 1))]),
            Err(DeepFrameError::CountMismatch { pixel: 5, .. })
        ));
    }
}
